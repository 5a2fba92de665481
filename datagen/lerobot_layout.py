"""Where the files of a LeRobot v3.0 dataset (low-dimensional, no video) live, and how a
feature is stored as a parquet column: what the writer, the reader and the validator share.

The layout mirrors lerobot's own recorder (``lerobot/datasets/utils.py``,
``dataset_metadata.py``, lerobot 0.6.1)::

    meta/info.json                               codebase_version "v3.0", features, totals
    meta/stats.json                              per-feature min/max/mean/std/count/q01..q99
    meta/tasks.parquet                           pandas frame: index "task", column task_index
    meta/episodes/chunk-CCC/file-FFF.parquet     one row per episode (+ stats/<feature>/<stat>)
    data/chunk-CCC/file-FFF.parquet              one row per frame

Per-frame columns are the caller's features in the given order, then lerobot's
``DEFAULT_FEATURES`` (:data:`INDEX_FEATURES`). A feature of shape ``(n,)`` is a
``fixed_size_list<element>[n]`` column, shape ``(1,)`` a scalar column.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pyarrow as pa

CODEBASE_VERSION = "v3.0"
DEFAULT_CHUNK_SIZE = 1000  # files per chunk directory (lerobot DEFAULT_CHUNK_SIZE)
DEFAULT_DATA_FILE_SIZE_IN_MB = 100  # lerobot DEFAULT_DATA_FILE_SIZE_IN_MB
DEFAULT_VIDEO_FILE_SIZE_IN_MB = 200
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
# lerobot's DEFAULT_FEATURES, in its order, appended after the caller's features.
INDEX_FEATURES = {
    "timestamp": "float32",
    "frame_index": "int64",
    "episode_index": "int64",
    "index": "int64",
    "task_index": "int64",
}
_FILE_RE = re.compile(r"^chunk-(\d{3,})/file-(\d{3,})\.parquet$")


class DatasetLayout:
    """The paths of the files of the LeRobot v3.0 dataset at ``root`` (which need not exist yet)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    @property
    def info(self) -> Path:
        """``meta/info.json``."""
        return self.root / INFO_PATH

    @property
    def stats(self) -> Path:
        """``meta/stats.json``."""
        return self.root / STATS_PATH

    @property
    def tasks(self) -> Path:
        """``meta/tasks.parquet``."""
        return self.root / TASKS_PATH

    def data_file(self, chunk: int, file: int) -> Path:
        """The data file ``data/chunk-CCC/file-FFF.parquet``."""
        return self.root / DATA_PATH.format(chunk_index=chunk, file_index=file)

    def episodes_file(self, chunk: int, file: int) -> Path:
        """The episodes-metadata file ``meta/episodes/chunk-CCC/file-FFF.parquet``."""
        return self.root / EPISODES_PATH.format(chunk_index=chunk, file_index=file)

    def data_files(self) -> list[Path]:
        """The data files present, in (chunk, file) order."""
        return self._files("data")

    def episodes_files(self) -> list[Path]:
        """The episodes-metadata files present, in (chunk, file) order."""
        return self._files("meta/episodes")

    def _files(self, sub: str) -> list[Path]:
        base = self.root / sub
        return sorted(p for p in base.glob("*/*.parquet") if p.is_file()) if base.is_dir() else []

    def stray_files(self, sub: str) -> list[str]:
        """Files under ``sub`` (``data`` or ``meta/episodes``) other than
        chunk-NNN/file-NNN.parquet, which lerobot would pick up (it globs */*.parquet)."""
        base = self.root / sub
        out = []
        if base.is_dir():
            for p in sorted(base.rglob("*")):
                if p.is_file() and not _FILE_RE.match(p.relative_to(base).as_posix()):
                    out.append(f"unexpected file {p.relative_to(self.root).as_posix()}")
        return out

    @staticmethod
    def chunk_file(path: Path) -> tuple[int, int]:
        """(chunk, file) indices named by a ``chunk-CCC/file-FFF.parquet`` path; (-1, -1) otherwise."""
        m = _FILE_RE.match(f"{path.parent.name}/{path.name}")
        return (int(m.group(1)), int(m.group(2))) if m else (-1, -1)


def arrow_column(a: np.ndarray) -> pa.Array:
    """The parquet column of a feature's ``(F,)`` or ``(F, n)`` array."""
    if a.ndim == 1:
        return pa.array(a)
    return pa.FixedSizeListArray.from_arrays(pa.array(a.reshape(-1)), int(a.shape[1]))


def column_to_numpy(col: pa.ChunkedArray, shape: list[int]) -> np.ndarray:
    """A feature's column back as numpy: ``(F, n)`` for a list column, ``(F,)`` for a
    scalar one; ValueError on null values or rows of the wrong length."""
    arr = col.combine_chunks() if col.num_chunks != 1 else col.chunk(0)
    if arr.null_count:
        raise ValueError("null values")
    if pa.types.is_fixed_size_list(arr.type) or pa.types.is_list(arr.type):
        n = int(shape[0])
        values = arr.flatten().to_numpy(zero_copy_only=False)
        if values.size != len(arr) * n:
            raise ValueError(f"rows do not all have {n} values")
        return values.reshape(len(arr), n)
    return arr.to_numpy(zero_copy_only=False)


def expected_arrow_type(ft: dict) -> pa.DataType | None:
    """The column type a feature of info.json (``{"dtype", "shape"}``) is stored as; None
    when the feature is not one this layout stores."""
    try:
        dt = pa.from_numpy_dtype(np.dtype(ft["dtype"]))
    except (TypeError, pa.ArrowException):
        return None
    shape = list(ft.get("shape") or [])
    if shape == [1]:
        return dt
    if len(shape) == 1:
        return pa.list_(dt, int(shape[0]))
    return None


__all__ = [
    "DatasetLayout",
    "CODEBASE_VERSION",
    "DATA_PATH",
    "EPISODES_PATH",
    "INFO_PATH",
    "STATS_PATH",
    "TASKS_PATH",
    "INDEX_FEATURES",
    "arrow_column",
    "column_to_numpy",
    "expected_arrow_type",
]
