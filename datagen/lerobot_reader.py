"""Reading a LeRobot v3.0 dataset without torch or lerobot: ``meta/info.json`` and the
per-frame columns as numpy arrays (one data file at a time into preallocated arrays)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from aerohrl.datagen.lerobot_layout import CODEBASE_VERSION, INFO_PATH, DatasetLayout, column_to_numpy
from aerohrl.errors import UserError


def read_info(root: str | Path) -> dict:
    """``meta/info.json`` as a dict; UserError if missing, unreadable or not v3.0."""
    path = Path(root) / INFO_PATH
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UserError(f"{Path(root)} is not a LeRobot dataset: {INFO_PATH} is missing") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise UserError(f"cannot read {path}: {e}") from None
    if not isinstance(info, dict) or not isinstance(info.get("features"), dict):
        raise UserError(f"{path} is not a LeRobot info.json (no features)")
    if info.get("codebase_version") != CODEBASE_VERSION:
        raise UserError(f"{path}: codebase_version {info.get('codebase_version')!r}, expected {CODEBASE_VERSION!r}")
    if not isinstance(info.get("fps"), int) or info["fps"] <= 0:
        raise UserError(f"{path}: fps must be a positive integer, got {info.get('fps')!r}")
    return info


def _read_table(path: Path, columns: list[str] | None = None) -> pa.Table:
    try:
        return pq.read_table(path, columns=columns, use_threads=True)
    except FileNotFoundError:
        raise UserError(f"missing file {path}") from None
    except (OSError, pa.ArrowException, ValueError) as e:
        raise UserError(f"cannot read {path}: {e}") from None


def read_columns(root: str | Path, features: Iterable[str] | None = None) -> dict[str, np.ndarray]:
    """Every feature of the dataset at ``root`` (or only those named in ``features``) as
    numpy arrays, without torch or lerobot: vector features ``(F, n)``, scalar features
    (shape ``(1,)``, including ``episode_index``, ``frame_index``, ``index``,
    ``timestamp``, ``task_index``) ``(F,)``, in the global ``index`` order. UserError on
    missing or unreadable files, or a feature the dataset does not have."""
    root = Path(root)
    info = read_info(root)
    feats = {k: ft for k, ft in info["features"].items() if ft.get("dtype") not in ("video", "image")}
    if features is not None:
        wanted = list(features)
        unknown = [k for k in wanted if k not in feats]
        if unknown:
            raise UserError(f"{root}: no feature {unknown[0]!r} (it has {', '.join(feats)})")
        feats = {k: feats[k] for k in wanted}
    paths = DatasetLayout(root).data_files()
    if not paths:
        raise UserError(f"{root}: no data files under data/")
    F = info.get("total_frames")
    if not isinstance(F, int) or F < 0:
        raise UserError(f"{root / INFO_PATH}: bad total_frames {F!r}")
    out: dict[str, np.ndarray] = {}
    a = 0
    for p in paths:  # one file at a time into preallocated arrays: no concatenation copy
        t = _read_table(p, columns=list(feats))
        b = a + t.num_rows
        if b > F:
            raise UserError(f"{root}: data files hold more than the {F} frames info.json lists")
        for k, ft in feats.items():
            try:
                v = column_to_numpy(t.column(k), ft["shape"])
            except (ValueError, pa.ArrowException) as e:
                raise UserError(f"{p}: column {k!r} is damaged: {e}") from None
            if k not in out:
                out[k] = np.empty((F,) + v.shape[1:], dtype=v.dtype)
            if out[k].shape[1:] != v.shape[1:] or out[k].dtype != v.dtype:
                raise UserError(f"{p}: column {k!r} is {v.dtype}{v.shape[1:]}, other files hold {out[k].dtype}{out[k].shape[1:]}")
            out[k][a:b] = v
        a = b
        del t
    if a != F or len(out) != len(feats):
        raise UserError(f"{root}: data files hold {a} frames, info.json says {F}")
    return out


__all__ = ["read_info", "read_columns"]
