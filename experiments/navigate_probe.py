"""Where a flat maze skill fails: a maze run flown on its own dataset's flights.

    python experiments/navigate_probe.py --run runs/<maze-run> [--episodes 200] [--threads 1]

Three probes of a run trained on a maze dataset (its dataset is the run's own), printed as
Markdown:

1. **The dataset's own flights**: the first ``--episodes`` episodes' exact start states
   and desired goals, flown by the policy in the maze with the episode's length plus 3 s
   as horizon: success and collision rates. These pairs are in the training data.
2. **Straight rest-to-rest legs**: from the last state of each episode where the expert
   was (nearly) at rest more than 1 m from its goal -- the start of the flight's last
   straight leg, a corner stop -- set to exact hover, to the episode's desired goal, over
   6 s: the skill's success per leg length. Every such leg is in the training data too.
3. **Behaviour cloning error by situation**: the mean absolute difference between the
   policy's action and the expert's clean label (``action.expert``) on the same episodes'
   frames, split into frames at rest (speed < 0.3 m/s) and in flight, and the body-rate
   command on the first frame of each episode (the decision to leave a hover).

Episodes are taken from the end of the dataset (its last ``--episodes``), the same for
every run of a dataset.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

REST_SPEED = 0.3  # m/s: the expert counts as at rest below this speed
LEG_HORIZON = 600  # steps (6 s at 100 Hz) for a straight leg


def _fly(policy, maze, starts: np.ndarray, goals: np.ndarray, horizons: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(success, collision) per episode of the policy flown in the maze (one batched closed loop)."""
    from aerohrl.envs.maze import QuadrotorMazeVectorEnv

    n = len(starts)
    env = QuadrotorMazeVectorEnv(n, maze=maze, task=1, autoreset=False)
    obs, _ = env.reset(options={"start_states": starts, "goals": goals, "horizons": horizons})
    alive, success, collision = np.ones(n, bool), np.zeros(n, bool), np.zeros(n, bool)
    for _ in range(int(horizons.max())):
        obs, _, term, trunc, info = env.step(np.asarray(policy.act(obs["observation"], obs["desired_goal"])))
        ended = alive & (term | trunc)
        success |= ended & info["is_success"]
        collision |= ended & info["collision"]
        alive &= ~(term | trunc)
        if not alive.any():
            break
    return success, collision


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", required=True, help="a training run on a maze dataset")
    p.add_argument("--episodes", type=int, default=200, help="dataset episodes probed (its last ones)")
    p.add_argument("--threads", type=int, default=1)
    a = p.parse_args(argv)

    import torch

    import aerohrl
    from aerohrl.algorithms.run import Run
    from aerohrl.datagen.dataset import open_dataset
    from aerohrl.worlds.maze import maze_from_dict

    torch.set_num_threads(a.threads)
    run = Run(a.run)
    path = run.config.dataset
    layout = open_dataset(path).maze  # the layout recorded with the data (None in free space)
    if not layout:
        print(f"navigate_probe: error: {a.run} was not trained on a maze dataset", file=sys.stderr)
        return 2
    maze = maze_from_dict(layout)
    data = aerohrl.load_dataset(path, as_="numpy")
    policy = aerohrl.load_policy(a.run)
    ep, S, G = data["episode_index"], data["observation.state"], data["observation.desired_goal"]
    last_ep = int(ep[-1])
    eps = np.arange(max(0, last_ep + 1 - a.episodes), last_ep + 1)
    first, end = np.searchsorted(ep, eps), np.searchsorted(ep, eps, side="right")

    # 1. the dataset's own flights
    succ, coll = _fly(policy, maze, S[first], G[first], (end - first) + 300)
    print(f"# Navigate probe: {a.run} (step {run.checkpoints()[-1].name}), {len(eps)} episodes of {path}\n")
    print("| probe | episodes | success % | collision % |\n|---|---|---|---|")
    print(f"| the dataset's own flights (start, goal) | {len(eps)} | {100 * succ.mean():.1f} | {100 * coll.mean():.1f} |")

    # 2. straight rest-to-rest legs: the last corner stop of each flight to its goal
    starts, lengths = [], []
    for f, e in zip(first, end):
        speed = np.linalg.norm(S[f:e, 3:6], axis=1)
        far = np.flatnonzero(np.linalg.norm(S[f:e, :3] - G[f, :3], axis=1) > 1.0)
        rest = far[speed[far] < REST_SPEED]
        s0 = S[f + (rest[-1] if len(rest) else 0)].copy()
        s0[3:6], s0[6:15], s0[15:18] = 0.0, np.eye(3).ravel(), 0.0  # exact hover
        starts.append(s0)
        lengths.append(float(np.linalg.norm(s0[:3] - G[f, :3])))
    lengths_a = np.array(lengths)
    succ, coll = _fly(policy, maze, np.array(starts), G[first], np.full(len(eps), LEG_HORIZON))
    print(f"| straight legs from the last corner stop, all | {len(eps)} | {100 * succ.mean():.1f} | {100 * coll.mean():.1f} |")
    for lo, hi in ((0.0, 2.5), (2.5, 5.0), (5.0, 1e9)):
        m = (lengths_a >= lo) & (lengths_a < hi)
        if m.any():
            label = f"{lo:g}-{hi:g} m" if hi < 1e9 else f">= {lo:g} m"
            print(f"| straight legs, {label} | {int(m.sum())} | {100 * succ[m].mean():.1f} | {100 * coll[m].mean():.1f} |")

    # 3. behaviour cloning error, at rest and in flight
    frames = np.concatenate([np.arange(f, e) for f, e in zip(first, end)])
    with torch.no_grad():
        act = np.asarray(policy.act(S[frames], G[frames]))
    err = np.abs(act - data["action.expert"][frames])
    rest = np.linalg.norm(S[frames, 3:6], axis=1) < REST_SPEED
    print("\n| frames | n | thrust error (m/s^2) | body-rate error x, y (rad/s) |\n|---|---|---|---|")
    for label, m in (("at rest", rest), ("in flight", ~rest)):
        print(f"| {label} | {int(m.sum())} | {err[m, 0].mean():.3f} | {err[m, 1:3].mean():.3f} |")
    k = np.searchsorted(frames, first)
    rate_pol = np.linalg.norm(act[k, 1:3], axis=1)
    rate_exp = np.linalg.norm(data["action.expert"][first, 1:3], axis=1)
    print(
        f"| first frame of each flight (hover) | {len(eps)} | {err[k, 0].mean():.3f} | {err[k, 1:3].mean():.3f} "
        f"(|w_xy| expert {rate_exp.mean():.2f}, policy {rate_pol.mean():.2f}) |"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
