"""Rest-to-rest hops in maze datasets: how much of each dataset shows the vehicle coming to
rest, then resting again at least a cell away later in the same flight.

A maze task's goal, and a planner's intermediate goal, is a hover: met within the goal
test's speed and attitude tolerances (``aerohrl.task.TOLERANCE``). A dataset can only teach
a hop of a cell if its flights contain such hops. Per dataset it prints: frames, the share of
frames at rest (speed and tilt within the tolerances), the share of frames that are at rest
and from which the same episode later rests at least ``--hop`` metres away (horizontal
distance), and the episodes that contain at least one such hop.

    python experiments/rest_hops.py datasets/quadrotor-maze-large-stitch/n700-s0-12a225bc \\
        datasets/quadrotor-maze-large-explore/n1000-s0-708d56c4 [--hop 2.0]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from aerohrl.errors import UserError


def rest_mask(state: np.ndarray) -> np.ndarray:
    """(N,) bool: frames at rest, speed <= the goal test's velocity tolerance and the body z
    axis within its attitude tolerance of vertical (``state``: the dataset's 18 columns,
    positions, velocities, the row-major rotation matrix, rates)."""
    from aerohrl.task import TOLERANCE

    speed = np.linalg.norm(state[:, 3:6], axis=1)
    return (speed <= TOLERANCE.vel) & (state[:, 14] >= np.cos(TOLERANCE.rot))


def hops_from(xy: np.ndarray, hop: float) -> np.ndarray:
    """(n,) bool over one episode's rest frames in time order (``xy`` their horizontal
    positions): a later rest frame lies at least ``hop`` away."""
    n = len(xy)
    out = np.zeros(n, bool)
    for a in range(0, n, 512):  # blocks of rows keep the pairwise distances small
        d2 = ((xy[a : a + 512, None] - xy[None]) ** 2).sum(-1)
        later = np.arange(n)[None] > np.arange(a, min(a + 512, n))[:, None]
        out[a : a + 512] = ((d2 >= hop * hop) & later).any(1)
    return out


def dataset_hops(folder: Path, hop: float) -> dict:
    """The figures of one LeRobot dataset folder (module doc), read with the project's
    :func:`aerohrl.datagen.dataset.open_dataset` (checksums verified)."""
    from aerohrl.datagen.dataset import open_dataset

    cols = open_dataset(folder).columns()
    state = np.asarray(cols["observation.state"], dtype=np.float64)
    episode = np.asarray(cols["episode_index"])
    rest = rest_mask(state)
    bounds = np.flatnonzero(np.diff(episode)) + 1  # an episode's frames are contiguous and in time order
    from_hop = episodes_with = 0
    for lo, hi in zip(np.r_[0, bounds], np.r_[bounds, len(state)]):
        r = lo + np.flatnonzero(rest[lo:hi])
        h = hops_from(state[r, :2], hop)
        from_hop += int(h.sum())
        episodes_with += bool(h.any())
    return {
        "frames": len(state),
        "episodes": len(bounds) + 1,
        "at_rest": rest.mean(),
        "hop_frames": from_hop / len(state),
        "episodes_with_hop": episodes_with,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("datasets", nargs="+", type=Path, help="LeRobot dataset folders (datasets/<name>/<version>)")
    p.add_argument("--hop", type=float, default=2.0, help="the hop's least horizontal length (m) [2.0: a maze cell]")
    a = p.parse_args(argv)
    try:
        if a.hop <= 0:
            raise UserError(f"--hop must be > 0, got {a.hop:g}")
        rows = [(d, dataset_hops(d, a.hop)) for d in a.datasets]
        print(f"| dataset | frames | at rest | at rest, resting >= {a.hop:g} m away later | episodes with such a hop |")
        print("|---|---|---|---|---|")
        for d, f in rows:
            print(
                f"| `{d.parent.name}/{d.name}` | {f['frames']:,} | {f['at_rest']:.1%} | {f['hop_frames']:.2%} |"
                f" {f['episodes_with_hop']:,} of {f['episodes']:,} |"
            )
    except UserError as e:
        print(f"rest_hops: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
