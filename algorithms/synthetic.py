"""Hand-made datasets in read_columns' layout, for tests and benchmarks (no datagen needed)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from pathlib import Path


def straight_columns(n_eps: int = 4, length: int = 30, seed: int = 0) -> dict:
    """Constant-velocity straight-line episodes at hover attitude, in read_columns' layout.

    Episode e has ``length`` frames (the last ones of different episodes differ in
    length when ``length`` is a list)."""
    rng = np.random.default_rng(seed)
    lengths = length if isinstance(length, (list, tuple)) else [length] * n_eps
    cols: dict[str, list] = {
        k: []
        for k in (
            "observation.state",
            "action",
            "observation.desired_goal",
            "next.observation.state",
            "episode_index",
            "frame_index",
        )
    }
    dt = 0.01
    for e, L in enumerate(lengths):
        v = rng.uniform(-1.5, 1.5, 3)
        p0 = rng.uniform(-1, 1, 3)
        st = np.zeros((L + 1, 18), np.float32)
        st[:, :3] = p0 + np.arange(L + 1)[:, None] * dt * v
        st[:, 3:6] = v
        st[:, 6:15] = np.eye(3).ravel()
        # a deterministic function of the episode (learnable by BC) plus a little noise
        base = np.array([9.81 + 0.5 * v[2], 0.3 * v[0], -0.3 * v[1], 0.0], np.float32)
        act = base + np.stack([np.zeros(L), np.zeros(L), np.zeros(L), np.linspace(-0.2, 0.2, L)], 1).astype(np.float32)
        act += rng.normal(0, 0.02, (L, 4)).astype(np.float32)
        cols["observation.state"].append(st[:-1])
        cols["next.observation.state"].append(st[1:])
        cols["action"].append(act)
        cols["observation.desired_goal"].append(np.tile(st[-1, :15], (L, 1)))
        cols["episode_index"].append(np.full(L, e, np.int64))
        cols["frame_index"].append(np.arange(L, dtype=np.int64))
    out = {k: np.concatenate(v) for k, v in cols.items()}
    F = len(out["action"])
    out["index"] = np.arange(F, dtype=np.int64)
    done = np.zeros(F, bool)
    done[np.cumsum(lengths) - 1] = True
    out["next.done"] = done
    out["next.reward"] = np.zeros(F, np.float32)
    out["next.success"] = np.zeros(F, bool)
    out["timestamp"] = (out["frame_index"] * dt).astype(np.float32)
    return out


def write_synthetic_dataset(
    root: str | Path, cols: dict | None = None, version: str = "synthetic-1", fps: int = 100, spec: dict | None = None
) -> Path:
    """Write ``cols`` (default: :func:`straight_columns`) as a dataset folder the way
    ``datagen build`` does (LeRobot v3.0 files + meta/aerohrl.json with checksums);
    ``spec`` adds fields to the recorded spec (``{"world": "maze-medium"}``: a dataset flown
    in a maze, whose policies see the absolute position)."""
    from pathlib import Path

    from aerohrl.datagen.dataset import FORMAT
    from aerohrl.datagen.lerobot_writer import write_dataset
    from aerohrl.datagen.manifest import write_manifest

    cols = straight_columns() if cols is None else cols
    frame_keys = (
        "observation.state",
        "action",
        "observation.desired_goal",
        "next.observation.state",
        "next.reward",
        "next.done",
        "next.success",
    )
    write_dataset(root, {k: cols[k] for k in frame_keys}, cols["episode_index"], fps=fps)
    write_manifest(
        root,
        {
            "format": FORMAT,
            "name": "synthetic",
            "version": version,
            "spec": {"name": "synthetic", "vehicle": "hummingbird", "fps": fps, "substeps": 5, **(spec or {})},
        },
    )
    return Path(root)
