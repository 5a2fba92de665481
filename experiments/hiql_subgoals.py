"""Where HIQL's high level puts its subgoals in a maze, against where the data went.

For a HIQL run with its subgoal in goal space (``--hiql-subgoal-space goal``) on a maze
dataset, at frames drawn from the dataset, with the flight's last state as the goal (a goal
the high level was trained on): the subgoal the high level proposes (its position, read back
from the goal columns), and the state the flight reached ``hiql_subgoal_steps`` later (the
regression target; the flight's last state when it ends sooner). Prints, over the frames:
the share of proposed subgoals whose position is inside a wall or the floor or ceiling (the
vehicle's sphere, ``Maze.collides``), the same share for the data's own subgoals, the median
distance between the two, and the share of proposed subgoals inside a wall among the frames
where the data's subgoal lies in another cell than the frame (the frames where a corridor
is chosen).

With ``--flights N`` it also flies the maze's five frozen tasks flat (``aerohrl eval --task
maze``, N episodes) and reads the same along the flown states up to each flight's end: the
share of the high level's subgoals inside a wall over all flown steps and over the last
second before each crash, and the crashes.

    python experiments/hiql_subgoals.py --run runs/hiql-maze-large-navigate-s0 [--frames 20000] [--flights 100] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from aerohrl.errors import UserError


def subgoal_positions(algo, state, goal):
    """(B, 3): the positions of the subgoals ``algo`` (a goal-space HIQL) proposes for states
    (B, 18) and goals (B, 15): the state's position plus the relative position read back
    from the subgoal's first three goal columns (``Normalizer.raw_inputs``: ``p_g - p`` at
    raw columns 15..17)."""
    import torch

    from aerohrl import task

    z = algo.subgoals(state, goal)  # (B, len(subgoal_index)) normalised goal columns
    cols = torch.tensor(algo.subgoal_index[:3])
    if cols.tolist() != list(range(task.OBS_DIM, task.OBS_DIM + 3)):
        raise UserError("the high level's first subgoal columns are not the relative position")
    norm = algo.normalizer
    rel = z[:, :3] * norm.in_std[cols] + norm.in_mean[cols]
    return (state[:, task.POS] + rel).double().numpy()


def load(run_dir: Path) -> tuple:
    """(algo, data, maze) of a goal-space HIQL run on a maze dataset: its final checkpoint,
    its dataset and the dataset's maze; UserError otherwise."""
    import torch

    from aerohrl.algorithms.base import load_policy
    from aerohrl.algorithms.run import Run
    from aerohrl.eval.harness import load_run_dataset, run_checkpoints
    from aerohrl.eval.tasks import dataset_maze

    run = Run.open(run_dir, kind="train")
    algo, _ = load_policy(run_checkpoints(run, 1)[-1], torch.device("cpu"), run)
    if getattr(algo.cfg, "algo", None) != "hiql" or algo.cfg.hiql.hiql_subgoal_space != "goal":
        raise UserError(f"{run_dir}: not a HIQL run with --hiql-subgoal-space goal")
    data, _ = load_run_dataset(run)
    maze = dataset_maze(data)
    if maze is None:
        raise UserError(f"{run_dir}: its dataset is not flown in a maze")
    return algo, data, maze


def study(run_dir: Path, frames: int, seed: int, loaded: tuple | None = None) -> dict:
    """The figures of the module doc for one run (``loaded``: its :func:`load`, when done)."""
    import torch

    from aerohrl import task

    algo, data, maze = loaded or load(run_dir)
    k = int(algo.cfg.hiql.hiql_subgoal_steps)
    rng = np.random.default_rng(seed)
    idx = torch.from_numpy(rng.choice(len(data), size=min(frames, len(data)), replace=False))
    ends = data.episode_end[idx]  # each frame's episode's last frame
    ahead = torch.minimum(idx + k, ends)
    state = data.state[idx, : task.STATE_DIM]
    goal = task.achieved_goal(data.next_state[ends])  # the flight's last state
    proposed = np.concatenate(
        [subgoal_positions(algo, state[i : i + 4096], goal[i : i + 4096]) for i in range(0, len(idx), 4096)]
    )
    target = data.state[ahead][:, task.POS].double().numpy()
    here = state[:, task.POS].double().numpy()
    in_wall = maze.collides(proposed)
    moves = np.any(maze.cell_of(target) != maze.cell_of(here), axis=-1)
    return {
        "frames": len(idx),
        "k": k,
        "proposed_in_wall": float(in_wall.mean()),
        "data_in_wall": float(maze.collides(target).mean()),
        "median_error": float(np.median(np.linalg.norm(proposed - target, axis=-1))),
        "moving_frames": float(moves.mean()),
        "proposed_in_wall_moving": float(in_wall[moves].mean()) if moves.any() else float("nan"),
    }


def closed_loop(run_dir: Path, flights: int, seed: int, loaded: tuple | None = None) -> dict:
    """Flat flights of the maze tasks and the high level's subgoals along them (module doc;
    ``loaded``: the run's :func:`load`, when done)."""
    import torch

    from aerohrl import task
    from aerohrl.eval.harness import EvalOptions, build_episodes, fly

    algo, data, maze = loaded or load(run_dir)
    opt = EvalOptions(task="maze", episodes=flights, checkpoints=1, seed=seed, progress=False, record=False)
    r = fly(algo, build_episodes(data, opt), data, opt, record_states=True)
    states, goals = r["states"], r["policy_goals"]  # (E, T+1, 18), (E, T+1, 15)
    E, T1 = states.shape[:2]
    last = np.minimum(np.asarray(r["steps"]), T1 - 1)  # each flight's last step
    alive = np.arange(T1)[None] <= last[:, None]
    s = torch.as_tensor(states[alive], dtype=torch.float32)
    g = torch.as_tensor(goals[alive], dtype=torch.float32)
    pos = np.concatenate([subgoal_positions(algo, s[i : i + 4096], g[i : i + 4096]) for i in range(0, len(s), 4096)])
    wall = np.zeros((E, T1), bool)
    wall[alive] = maze.collides(pos)
    crashed = np.asarray(maze.collides(states[np.arange(E), last][:, task.POS]))
    fps = 100
    before = (np.arange(T1)[None] > (last - fps)[:, None]) & alive
    return {
        "flights": E,
        "success": float(np.mean(r["success"])),
        "crashed": float(crashed.mean()),
        "in_wall_flown": float(wall[alive].mean()),
        "in_wall_before_crash": float(wall[crashed][before[crashed]].mean()) if crashed.any() else float("nan"),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", type=Path, nargs="+", required=True, help="HIQL runs (goal-space subgoals) on a maze dataset")
    p.add_argument("--frames", type=int, default=20000, help="dataset frames drawn per run [20000]")
    p.add_argument("--seed", type=int, default=0, help="seed of the frames drawn and of the flights [0]")
    p.add_argument("--flights", type=int, default=0, help="also fly the maze tasks flat, N episodes per run (0: no) [0]")
    a = p.parse_args(argv)
    try:
        if a.frames < 1 or a.seed < 0:
            raise UserError("--frames must be >= 1 and --seed >= 0")
        if a.flights < 0:
            raise UserError("--flights must be >= 0")
        rows, flown = [], []
        for r in a.run:  # one load per run (a maze dataset is millions of frames)
            loaded = load(r)
            rows.append((r, study(r, a.frames, a.seed, loaded)))
            if a.flights:
                flown.append((r, closed_loop(r, a.flights, a.seed, loaded)))
    except UserError as e:
        print(f"hiql_subgoals: error: {e}", file=sys.stderr)
        return 2
    print(
        "| run | frames | k (steps) | proposed subgoal in a wall | data's subgoal in a wall | median distance proposed - data (m) | frames whose data subgoal is in another cell | proposed in a wall there |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r, f in rows:
        print(
            f"| `{r.name}` | {f['frames']:,} | {f['k']} | {f['proposed_in_wall']:.1%} | {f['data_in_wall']:.1%} |"
            f" {f['median_error']:.2f} | {f['moving_frames']:.1%} | {f['proposed_in_wall_moving']:.1%} |"
        )
    if flown:
        print("\n| run | flights | success | crashed | subgoal in a wall, flown steps | the same, last second before a crash |")
        print("|---|---|---|---|---|---|")
        for r, f in flown:
            print(
                f"| `{r.name}` | {f['flights']} | {f['success']:.1%} | {f['crashed']:.1%} | {f['in_wall_flown']:.1%} |"
                f" {f['in_wall_before_crash']:.1%} |"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
