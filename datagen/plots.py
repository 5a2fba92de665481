"""Figures of a built dataset (thesis Fig. 3.2 analogue)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from aerohrl.atomic import save_figure
from aerohrl.errors import UserError


def plot_dataset(path: str | Path, out: str | Path, max_episodes: int = 250) -> Path:
    """3-D expert trajectories from the origin to their desired goals, coloured by outcome,
    beside the distribution of reference durations. Written atomically to ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aerohrl.datagen.build import EPISODES_FILE
    from aerohrl.datagen.lerobot_reader import read_columns

    path, out = Path(path), Path(out)
    if max_episodes <= 0:
        raise UserError(f"--max-episodes must be positive, got {max_episodes}")
    cols = read_columns(path)
    try:
        eps = pq.read_table(path / EPISODES_FILE).to_pydict()
    except (OSError, ValueError) as e:
        raise UserError(f"cannot read {path / EPISODES_FILE}: {e}") from None
    ep = cols["episode_index"]
    pos = cols["observation.state"][:, :3]
    goal = np.asarray(eps["goal_pos"])
    vel = np.asarray(eps["goal_vel"])
    ok = np.asarray(eps["expert_success"])
    n = min(max_episodes, len(goal))

    fig = plt.figure(figsize=(13, 6))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    bounds = np.searchsorted(ep, np.arange(len(goal) + 1))
    for i in range(n):
        p = pos[bounds[i] : bounds[i + 1]]
        ax.plot(p[:, 0], p[:, 1], p[:, 2], lw=0.6, alpha=0.6, color="tab:blue" if ok[i] else "tab:red")
    ax.scatter(goal[:n, 0], goal[:n, 1], goal[:n, 2], s=8, c="k", depthshade=False, label="desired goals")
    ax.quiver(goal[:n, 0], goal[:n, 1], goal[:n, 2], vel[:n, 0], vel[:n, 1], vel[:n, 2], length=0.15, color="0.4", lw=0.5)
    ax.scatter([0], [0], [0], s=40, c="orange", label="start (hover)")
    ax.set(
        xlabel="x (m)",
        ylabel="y (m)",
        zlabel="z (m)",
        title=f"{n} expert trajectories ({100 * ok[:n].mean():.1f}% reach the goal; red = missed)",
    )
    ax.legend(loc="upper left", fontsize=8)

    ax2 = fig.add_subplot(1, 2, 2)
    ax2.hist(np.asarray(eps["reference_duration_s"]), bins=30, color="tab:blue")
    ax2.set(xlabel="minimum-time reference duration T (s)", ylabel="episodes", title="reference durations (thesis Alg. 1)")
    fig.tight_layout()

    try:
        save_figure(fig, out, dpi=110)
    finally:
        plt.close(fig)
    return out
