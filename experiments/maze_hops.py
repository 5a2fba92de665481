"""The one-cell hop: does a maze skill fly from hover at one cell's centre to hover at a
neighbouring cell's centre, 2 m away along an open corridor?

This is the shortest leg the graph planner asks for (``aerohrl eval --planner graph
--max-edge 2.5``), so a skill that fails it fails every planned task however good its
critics. For ``--hops`` adjacent free-cell pairs of the run's maze (drawn with ``--seed``),
the run's newest checkpoint flies all hops at once on the nominal vehicle for ``--seconds``;
a hop succeeds when the task's goal test passes at some step before a collision. Printed
per run: reached %, collisions %, the median closest approach to the goal, the median
speed at that closest approach (a skill that flies through the goal passes it fast), and
the share of hops that end hovering (< 0.35 m/s) more than 1 m short of the goal (a skill
that does not leave its start).

    python experiments/maze_hops.py --run runs/gcsl-maze-large-explore-s0 [--run RUN ...] [--hops 64] [--seconds 4] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from aerohrl.errors import UserError


def adjacent_pairs(maze, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` distinct (cell, free 4-neighbour) pairs of ``maze``, uniform over all such
    pairs -> ``(a (n, 2), b (n, 2))`` (row, col)."""
    from aerohrl.datagen.maze_expert import STEPS

    free = maze.free_cells
    nb = free[:, None, :] + STEPS  # (m, 4, 2)
    ok = ~maze.is_wall(nb)
    i, j = np.nonzero(ok)
    if n > len(i):
        raise UserError(f"maze {maze.name} has only {len(i)} adjacent cell pairs, asked for {n} hops")
    pick = rng.choice(len(i), size=n, replace=False)
    return free[i[pick]], nb[i[pick], j[pick]]


def fly_hops(run_dir: Path, hops: int, seconds: float, seed: int) -> dict:
    """The hop figures of one run (module docstring)."""
    import aerohrl
    from aerohrl import task
    from aerohrl.datagen.maze_expert import hover_goals, hover_states
    from aerohrl.eval.harness import open_run_dataset
    from aerohrl.sim import BatchedQuadrotor, get_preset
    from aerohrl.worlds.maze import world_maze

    ds = open_run_dataset(run_dir)  # its spec and maze: the hops fly, they read no frames
    spec = ds.spec
    maze = world_maze(spec, ds.manifest)
    if maze is None:
        raise UserError(f"run {run_dir} trained on a free-space dataset; the hop test needs a maze")
    policy = aerohrl.load_policy(run_dir)
    a, b = adjacent_pairs(maze, np.random.default_rng(seed), hops)
    goal = hover_goals(maze.cell_center(b))
    fps = int(spec.get("fps", 100))
    sim = BatchedQuadrotor(
        get_preset(spec.get("vehicle", "hummingbird")), hops, dt=1.0 / fps, substeps=int(spec.get("substeps", 5))
    )
    s = sim.reset(hover_states(maze.cell_center(a)))
    reached = np.zeros(hops, bool)
    crashed = np.zeros(hops, bool)
    closest = np.full(hops, np.inf)
    speed_at = np.zeros(hops)
    for _ in range(int(round(seconds * fps))):
        s = sim.step(np.asarray(policy(s, goal)))
        alive = ~crashed
        d = np.linalg.norm(s[:, task.POS] - goal[:, task.POS], axis=1)
        nearer = alive & (d < closest)
        closest[nearer] = d[nearer]
        speed_at[nearer] = np.linalg.norm(s[nearer][:, task.VEL], axis=1)
        reached |= alive & np.asarray(task.goal_reached(task.achieved_goal(s), goal))
        crashed |= maze.collides(s[:, task.POS])
    final_speed = np.linalg.norm(s[:, task.VEL], axis=1)
    short = np.linalg.norm(s[:, task.POS] - goal[:, task.POS], axis=1) > 1.0
    return {
        "run": str(run_dir),
        "hops": hops,
        "reached": float(reached.mean()),
        "collided": float((crashed & ~reached).mean()),
        "closest_median": float(np.median(closest)),
        "speed_at_closest_median": float(np.median(speed_at)),
        "hovering_short": float((~crashed & short & (final_speed < task.TOLERANCE.vel)).mean()),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", type=Path, action="append", required=True, help="a training run on a maze dataset (repeatable)")
    p.add_argument("--hops", type=int, default=64, help="adjacent cell pairs flown [64]")
    p.add_argument("--seconds", type=float, default=4.0, help="flight time per hop (s) [4]")
    p.add_argument("--seed", type=int, default=0, help="seed of the pairs [0]")
    a = p.parse_args(argv)
    try:
        if a.hops < 1 or a.seconds <= 0:
            raise UserError("--hops must be >= 1 and --seconds > 0")
        rows = [fly_hops(r, a.hops, a.seconds, a.seed) for r in a.run]
    except UserError as e:
        print(f"maze_hops: error: {e}", file=sys.stderr)
        return 2
    print(f"one-cell hops from hover to hover, {a.hops} pairs, {a.seconds:g} s each, seed {a.seed}\n")
    print("| run | reached % | collided % | closest approach, median (m) | speed there, median (m/s) | hovering > 1 m short % |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| `{Path(r['run']).name}` | {100 * r['reached']:.1f} | {100 * r['collided']:.1f} | {r['closest_median']:.2f} | "
            f"{r['speed_at_closest_median']:.2f} | {100 * r['hovering_short']:.1f} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
