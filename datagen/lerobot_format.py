"""A fast, torch-free writer and reader of LeRobot v3.0 datasets (low-dimensional, no video).

``LeRobotDataset(repo_id, root=path)`` (lerobot 0.6.1) loads what :func:`write_dataset`
writes. The layout mirrors lerobot's own recorder (``lerobot/datasets/utils.py``,
``dataset_writer.py``, ``dataset_metadata.py``), written with pyarrow in pieces of many
episodes (:class:`DatasetWriter`, streamed: memory bounded by a piece; the bytes do not
depend on how the episodes are cut into pieces) instead of one ``save_episode`` per
episode (~66 ms each)::

    meta/info.json                               codebase_version "v3.0", features, totals
    meta/stats.json                              per-feature min/max/mean/std/count/q01..q99
    meta/tasks.parquet                           pandas frame: index "task", column task_index
    meta/episodes/chunk-CCC/file-FFF.parquet     one row per episode (+ stats/<feature>/<stat>)
    data/chunk-CCC/file-FFF.parquet              one row per frame

Format decisions (checked against lerobot 0.6.1's source and a dataset its writer made):

* Per-frame columns are the caller's features in the given order, then lerobot's
  ``DEFAULT_FEATURES`` ``timestamp`` (float32, ``frame_index / fps``), ``frame_index``,
  ``episode_index``, ``index`` (global row), ``task_index`` (int64). A feature of shape
  ``(n,)`` is a ``fixed_size_list<element>[n]`` column, shape ``(1,)`` a scalar column.
* Files: episodes never straddle files; a new data (episodes-metadata) file starts when the
  current one would reach ``data_files_size_in_mb`` (lerobot's rule), measured as the
  uncompressed column bytes so that the split is a pure function of the inputs; file
  indices roll over into a new chunk every ``chunks_size`` files
  (``update_chunk_file_indices``).
* Parquet: snappy, fixed row groups of :data:`ROW_GROUP_SIZE` rows (lerobot's recorder
  writes one row group per episode; with 10,000 short episodes that makes the footer
  megabytes and reading 3x slower, and no lerobot reader depends on it), statistics on
  (predicate push-down on ``episode_index`` when lerobot loads a subset of episodes).
  Nothing time-dependent is written: the same inputs give the same bytes (for one
  pyarrow version, whose name is in the footer's ``created_by``).
* Statistics: the keys, shapes and dtypes lerobot's ``compute_episode_stats`` produces
  (vectors ``(n,)``, scalars ``(1,)``, ``count`` ``(1,)``; bool and float32 computed in
  float32, integers in float64), for every feature including the index columns.
  ``min``/``max``/``mean``/``std``/``count`` are exact (float64 two-pass); quantiles are
  exact order statistics with linear interpolation (numpy's default) rather than
  lerobot's 5000-bin histogram approximation, and the dataset-level quantiles are those of
  all frames rather than lerobot 0.6.1's count-weighted mean of per-episode quantiles.
  Per-episode stats go into the episodes parquet as ``stats/<feature>/<stat>`` columns
  (``list<double>``, ``count`` ``list<int64>``), which lerobot's dataset tools
  (``delete_episodes``, ``split``) aggregate; its loader drops them.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from aerohrl import task as _task
from aerohrl.errors import UserError

CODEBASE_VERSION = "v3.0"
DEFAULT_CHUNK_SIZE = 1000  # files per chunk directory (lerobot DEFAULT_CHUNK_SIZE)
DEFAULT_DATA_FILE_SIZE_IN_MB = 100  # lerobot DEFAULT_DATA_FILE_SIZE_IN_MB
DEFAULT_VIDEO_FILE_SIZE_IN_MB = 200
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
ROW_GROUP_SIZE = 1 << 16
COMPRESSION = "snappy"
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
QUANTILE_KEYS = tuple(f"q{int(q * 100):02d}" for q in QUANTILES)
STAT_KEYS = ("min", "max", "mean", "std", "count") + QUANTILE_KEYS
DEFAULT_TASK = "Fly the quadrotor from hover at the origin to the desired goal state (position, velocity, attitude)."
DEFAULT_ROBOT_TYPE = "quadrotor"
# lerobot's DEFAULT_FEATURES, in its order, appended after the caller's features.
INDEX_FEATURES = {
    "timestamp": "float32",
    "frame_index": "int64",
    "episode_index": "int64",
    "index": "int64",
    "task_index": "int64",
}
DEFAULT_NAMES = {
    "observation.state": _task.STATE_NAMES,
    "next.observation.state": _task.STATE_NAMES,
    "action": _task.ACTION_NAMES,
    "observation.desired_goal": _task.GOAL_NAMES,
}
_EP_INDEX_COLUMNS = (
    "episode_index", "data/chunk_index", "data/file_index", "dataset_from_index", "dataset_to_index",
    "meta/episodes/chunk_index", "meta/episodes/file_index", "length",
)
_FILE_RE = re.compile(r"^chunk-(\d{3,})/file-(\d{3,})\.parquet$")
# Block size (padded cells per dimension) for the per-episode order statistics.
_STATS_BLOCK_CELLS = 1 << 18


# ----------------------------------------------------------------------------- writing


def write_dataset(
    root: str | Path,
    columns: dict[str, np.ndarray],
    episode_index: np.ndarray,
    *,
    fps: int = 100,
    task: str = DEFAULT_TASK,
    robot_type: str | None = DEFAULT_ROBOT_TYPE,
    names: dict[str, list[str]] | None = None,
    chunks_size: int = DEFAULT_CHUNK_SIZE,
    data_files_size_in_mb: int = DEFAULT_DATA_FILE_SIZE_IN_MB,
    episode_stats: bool = True,
) -> None:
    """Write ``columns`` (per-frame arrays, episodes contiguous and sorted) as a LeRobot
    v3.0 dataset in ``root`` (created if missing; must be empty).

    ``columns`` maps feature names to arrays of ``F`` rows: 1-D (a scalar feature, shape
    ``(1,)``) or 2-D ``(F, n)``; dtypes bool, integers or floats. ``episode_index`` is
    ``(F,)`` integers ``0..E-1``, non-decreasing in steps of one. ``names`` gives the
    per-dimension names of vector features (defaults: :data:`DEFAULT_NAMES`).
    ``episode_stats=False`` leaves the per-episode ``stats/*`` columns out.
    Bad inputs raise ``ValueError`` (a caller bug); a non-empty ``root`` raises UserError.
    The same bytes as :class:`DatasetWriter` fed the episodes in any number of pieces.
    """
    w = DatasetWriter(root, fps=fps, task=task, robot_type=robot_type, names=names, chunks_size=chunks_size,
                      data_files_size_in_mb=data_files_size_in_mb, episode_stats=episode_stats)
    _, _, lengths = _check_episode_index(episode_index)
    w.append(columns, lengths)
    w.close()


class DatasetWriter:
    """A LeRobot v3.0 dataset written as it comes: :meth:`append` takes the frames of whole
    episodes (any number at a time, in episode order), :meth:`close` writes ``meta/``.

    Memory stays bounded by the piece being appended plus one row group of frames and
    one episodes-metadata file's rows: data files are written row group by row group
    (:data:`ROW_GROUP_SIZE` rows, the same row groups as one bulk write), per-episode
    statistics are computed per piece (they depend on their own episode only), and the
    dataset-level statistics, which need every frame of a dimension in sorted order,
    are computed at :meth:`close`: one feature at a time is read back from the data files
    into a spill file per dimension (the values in their statistics dtype,
    ``<root>/.stats-spill/``, deleted as used), and each dimension is sorted in memory
    (``F`` x 4 bytes for a float32 feature; the index columns follow from the episode
    lengths). The bytes are those of :func:`write_dataset` on all the frames at once.
    """

    SPILL_DIR = ".stats-spill"

    def __init__(self, root, *, fps: int = 100, task: str = DEFAULT_TASK, robot_type: str | None = DEFAULT_ROBOT_TYPE,
                 names: dict[str, list[str]] | None = None, chunks_size: int = DEFAULT_CHUNK_SIZE,
                 data_files_size_in_mb: int = DEFAULT_DATA_FILE_SIZE_IN_MB, episode_stats: bool = True):
        self.root = Path(root)
        self.fps = _check_positive_int(fps, "fps")
        self.chunks_size = _check_positive_int(chunks_size, "chunks_size")
        self.size_mb = _check_positive_int(data_files_size_in_mb, "data_files_size_in_mb")
        if not isinstance(task, str) or not task:
            raise ValueError("task must be a non-empty string")
        self.task, self.robot_type, self.episode_stats = task, robot_type, episode_stats
        self.names = {**DEFAULT_NAMES, **(names or {})}
        self.feats: dict | None = None  # set by the first append
        self.E = self.F = 0
        self.lengths: list[np.ndarray] = []
        self._data_roller = _FileRoller(self.size_mb, self.chunks_size)
        self._meta_roller = _FileRoller(self.size_mb, self.chunks_size)
        self._data_file = None  # (chunk, file) open
        self._writer = None
        self._schema = None
        self._pending: list[dict] = []  # frames not yet in a row group
        self._pending_rows = 0
        self._meta_file = None
        self._meta_pending: list[dict] = []
        self._paths: list[Path] = []  # data files in order
        self._closed = False

    # -- frames
    def append(self, columns: dict[str, np.ndarray], lengths: np.ndarray | list[int]) -> None:
        """Append whole episodes: ``columns`` as for :func:`write_dataset`, ``lengths``
        the frames of each (their sum is the columns' length)."""
        if self._closed:
            raise ValueError("the writer is closed")
        lengths = np.asarray(lengths)
        if lengths.ndim != 1 or lengths.size == 0 or lengths.dtype.kind not in "iu" or np.any(lengths <= 0):
            raise ValueError("lengths must be a non-empty 1-D array of positive integers")
        lengths = lengths.astype(np.int64)
        Fb, Eb = int(lengths.sum()), len(lengths)
        feats, arrays = _check_columns(columns, Fb, self.names)
        if self.feats is None:
            if self.root.exists():
                if not self.root.is_dir():
                    raise UserError(f"{self.root} exists and is not a directory")
                if any(self.root.iterdir()):
                    raise UserError(f"refusing to write a dataset into the non-empty directory {self.root}")
            for k, dt in INDEX_FEATURES.items():
                feats[k] = {"dtype": dt, "shape": [1], "names": None}
            self.feats = feats
            self.root.mkdir(parents=True, exist_ok=True)
            (self.root / "meta").mkdir(exist_ok=True)
            (self.root / self.SPILL_DIR).mkdir(exist_ok=True)
            self._frame_bytes = None
            self._ep_row_bytes = 7 * 8 + len(self.task.encode()) + 8
            if self.episode_stats:
                for k, ft in feats.items():
                    for key in STAT_KEYS:
                        self._ep_row_bytes += (1 if key == "count" else ft["shape"][0]) * 8 + 4
        else:
            got = {k: v for k, v in feats.items()}
            want = {k: v for k, v in self.feats.items() if k not in INDEX_FEATURES}
            if list(got) != list(want) or got != want:
                raise ValueError("appended columns differ from the first piece's (names, dtypes or shapes)")
        starts = np.concatenate(([0], np.cumsum(lengths)[:-1])).astype(np.int64)
        frame_index = np.arange(Fb, dtype=np.int64) - np.repeat(starts, lengths)
        arrays["timestamp"] = (frame_index / float(self.fps)).astype(np.float32)  # lerobot: frame_index / fps
        arrays["frame_index"] = frame_index
        arrays["episode_index"] = np.repeat(np.arange(self.E, self.E + Eb, dtype=np.int64), lengths)
        arrays["index"] = np.arange(self.F, self.F + Fb, dtype=np.int64)
        arrays["task_index"] = np.zeros(Fb, dtype=np.int64)
        if self._frame_bytes is None:
            self._frame_bytes = sum(_row_bytes(a) for a in arrays.values())

        # statistics: per episode now, dataset-level at close (from the written files)
        ep_stats = {k: _episode_stats(arrays[k], starts, lengths) for k in self.feats} if self.episode_stats else {}

        # data files: whole episodes, lerobot's size rule on uncompressed bytes
        data_file = self._data_roller.assign(lengths * self._frame_bytes)
        for chunk, fidx, e0, e1 in _groups(data_file):
            a, b = int(starts[e0]), int(starts[e1 - 1] + lengths[e1 - 1])
            if self._data_file != (chunk, fidx):
                self._finish_data_file()
                self._data_file = (chunk, fidx)
            self._add_rows({k: arrays[k][a:b] for k in self.feats}, b - a)

        # episodes metadata rows
        gstarts = starts + self.F
        ep = {
            "episode_index": np.arange(self.E, self.E + Eb, dtype=np.int64),
            "length": lengths,
            "data/chunk_index": data_file[:, 0].copy(),
            "data/file_index": data_file[:, 1].copy(),
            "dataset_from_index": gstarts,
            "dataset_to_index": gstarts + lengths,
        }
        for feat, st in ep_stats.items():
            for key in STAT_KEYS:
                ep[f"stats/{feat}/{key}"] = st[key]
        meta_file = self._meta_roller.assign(np.full(Eb, self._ep_row_bytes))
        for chunk, fidx, e0, e1 in _groups(meta_file):
            if self._meta_file != (chunk, fidx):
                self._finish_meta_file()
                self._meta_file = (chunk, fidx)
            self._meta_pending.append({k: v[e0:e1] for k, v in ep.items()})
        self.lengths.append(lengths)
        self.E += Eb
        self.F += Fb

    def _spill(self, k: str, j: int) -> Path:
        return self.root / self.SPILL_DIR / f"{k}.{j}.bin"

    def _spill_feature(self, k: str, ft: dict, sdt) -> None:
        """Feature ``k`` read back from the data files (one row group at a time), each
        dimension's values in ``sdt`` to its own spill file: scratch disk for one
        feature at a time (``F`` x dims x 4 bytes)."""
        d = ft["shape"][0]
        files = [open(self._spill(k, j), "wb") for j in range(d)]
        try:
            for path in self._paths:
                pf = pq.ParquetFile(path)
                for i in range(pf.num_row_groups):
                    col = pf.read_row_group(i, columns=[k]).column(0)
                    v = _column_to_numpy(col, ft["shape"])
                    v = v.reshape(len(v), -1)
                    for j in range(d):
                        v[:, j].astype(sdt).tofile(files[j])
                    del v, col
        finally:
            for f in files:
                f.close()

    def _add_rows(self, piece: dict, n: int) -> None:
        """Rows of the open data file: full row groups are written straight from
        ``piece`` (views of the appended arrays), and only the last partial row group is
        kept, copied (< :data:`ROW_GROUP_SIZE` rows), for the next piece to complete."""
        if self._pending_rows:
            need = ROW_GROUP_SIZE - self._pending_rows
            if n < need:
                self._pending.append({k: v.copy() for k, v in piece.items()})
                self._pending_rows += n
                return
            head = {k: np.concatenate([*(p[k] for p in self._pending), v[:need]]) for k, v in piece.items()}
            self._pending, self._pending_rows = [], 0
            self._write_rows(head)
            piece, n = {k: v[need:] for k, v in piece.items()}, n - need
        m = n - n % ROW_GROUP_SIZE
        if m:
            self._write_rows({k: v[:m] for k, v in piece.items()})
        if n > m:
            self._pending = [{k: v[m:].copy() for k, v in piece.items()}]
            self._pending_rows = n - m

    def _write_rows(self, rows: dict) -> None:
        keys = list(self.feats)
        meta = {b"huggingface": json.dumps(_hf_features(self.feats)).encode()}
        table = pa.table([_arrow_column(np.ascontiguousarray(rows[k])) for k in keys], names=keys)
        if self._schema is None:
            self._schema = table.schema.with_metadata(meta)
        table = table.replace_schema_metadata(meta)
        if self._writer is None:
            chunk, fidx = self._data_file
            path = self.root / DATA_PATH.format(chunk_index=chunk, file_index=fidx)
            path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = pq.ParquetWriter(path, self._schema, compression=COMPRESSION,
                                            use_dictionary=["episode_index", "task_index"])
            self._paths.append(path)
        self._writer.write_table(table, row_group_size=ROW_GROUP_SIZE)

    def _finish_data_file(self) -> None:
        if self._data_file is None:
            return
        if self._pending_rows:
            keys = list(self.feats)
            self._write_rows({k: np.concatenate([p[k] for p in self._pending]) for k in keys})
            self._pending, self._pending_rows = [], 0
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def _finish_meta_file(self) -> None:
        if self._meta_file is None or not self._meta_pending:
            return
        chunk, fidx = self._meta_file
        parts = self._meta_pending
        ep = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        n = len(ep["episode_index"])
        cols = {}
        for k in ("episode_index",):
            cols[k] = pa.array(ep[k])
        cols["tasks"] = pa.ListArray.from_arrays(pa.array(np.arange(n + 1, dtype=np.int32)),
                                                 pa.array([self.task] * n, pa.string()))
        for k in ("length", "data/chunk_index", "data/file_index", "dataset_from_index", "dataset_to_index"):
            cols[k] = pa.array(ep[k])
        for k, v in ep.items():
            if k.startswith("stats/"):
                offsets = pa.array(np.arange(0, v.size + 1, v.shape[1], dtype=np.int32))
                cols[k] = pa.ListArray.from_arrays(offsets, pa.array(v.reshape(-1)))
        cols["meta/episodes/chunk_index"] = pa.array(np.full(n, chunk, dtype=np.int64))
        cols["meta/episodes/file_index"] = pa.array(np.full(n, fidx, dtype=np.int64))
        table = pa.table(list(cols.values()), names=list(cols))
        path = self.root / EPISODES_PATH.format(chunk_index=chunk, file_index=fidx)
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(table, path, compression=COMPRESSION, row_group_size=max(n, 1))
        self._meta_pending = []

    # -- meta
    def close(self) -> None:
        """Finish the data files and write ``meta/`` (episodes, tasks, stats, info)."""
        if self._closed:
            return
        if self.feats is None:
            raise ValueError("episode_index must be a non-empty 1-D array")
        self._finish_data_file()
        self._finish_meta_file()
        _write_tasks(self.root, [self.task])
        lengths = np.concatenate(self.lengths)
        stats = {}
        for k, ft in self.feats.items():
            if k in INDEX_FEATURES:
                g = _index_stats(k, lengths, self.fps)
            else:
                g = {s: [] for s in STAT_KEYS}
                sdt = _stats_dtype(np.dtype(ft["dtype"]))
                self._spill_feature(k, ft, sdt)
                for j in range(ft["shape"][0]):
                    c = np.fromfile(self._spill(k, j), dtype=sdt)
                    self._spill(k, j).unlink()
                    c.sort()
                    one = _sorted_stats(lambda i0, i1, c=c: c[i0:i1], len(c))
                    del c
                    for s in STAT_KEYS[:4] + QUANTILE_KEYS:
                        g[s].append(one[s])
                g["count"] = [self.F]
            stats[k] = {s: [float(x) for x in g[s]] if s != "count" else [int(g[s][0])] for s in STAT_KEYS}
        _write_json(self.root / STATS_PATH, stats)
        info = {
            "codebase_version": CODEBASE_VERSION,
            "fps": self.fps,
            "features": self.feats,
            "total_episodes": self.E,
            "total_frames": self.F,
            "total_tasks": 1,
            "chunks_size": self.chunks_size,
            "data_files_size_in_mb": self.size_mb,
            "video_files_size_in_mb": DEFAULT_VIDEO_FILE_SIZE_IN_MB,
            "data_path": DATA_PATH,
            "video_path": None,
            "robot_type": self.robot_type,
            "splits": {"train": f"0:{self.E}"},
        }
        _write_json(self.root / INFO_PATH, info)
        import shutil

        shutil.rmtree(self.root / self.SPILL_DIR, ignore_errors=True)
        self._closed = True

    def abort(self) -> None:
        """Close the open data file (an interrupted build: the caller removes ``root``)."""
        if self._writer is not None:
            try:
                self._writer.close()
            except Exception:  # noqa: BLE001 - best effort on the way out
                pass
            self._writer = None
        self._closed = True


def _check_positive_int(v, what: str) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
        raise ValueError(f"{what} must be a positive integer, got {v!r}")
    return int(v)


def _check_episode_index(episode_index):
    ep = np.asarray(episode_index)
    if ep.ndim != 1 or ep.size == 0:
        raise ValueError("episode_index must be a non-empty 1-D array")
    if ep.dtype.kind not in "iu":
        raise ValueError(f"episode_index must hold integers, got {ep.dtype}")
    ep = ep.astype(np.int64)
    step = np.diff(ep)
    if ep[0] != 0 or np.any((step != 0) & (step != 1)):
        raise ValueError("episode_index must run 0..E-1, contiguous and sorted (steps of 0 or 1)")
    starts = np.concatenate(([0], np.flatnonzero(step) + 1)).astype(np.int64)
    lengths = np.diff(np.append(starts, len(ep))).astype(np.int64)
    return ep, starts, lengths


def _check_columns(columns: dict, F: int, names: dict):
    if not columns:
        raise ValueError("no feature columns given")
    feats: dict[str, dict] = {}
    arrays: dict[str, np.ndarray] = {}
    for key, arr in columns.items():
        if not isinstance(key, str) or not key or "/" in key:
            raise ValueError(f"feature name {key!r} must be a non-empty string without '/' (lerobot rule)")
        if key in INDEX_FEATURES:
            raise ValueError(f"{key!r} is written by write_dataset itself; do not pass it")
        a = np.asarray(arr)
        if a.ndim == 2 and a.shape[1] == 1:
            a = a[:, 0]
        if a.ndim not in (1, 2) or a.shape[0] != F:
            raise ValueError(f"column {key!r} has shape {a.shape}; expected ({F},) or ({F}, n)")
        if a.dtype.kind not in "biuf" or a.dtype.itemsize > 8 or (a.dtype.kind == "f" and a.dtype.itemsize < 4):
            raise ValueError(f"column {key!r} has unsupported dtype {a.dtype}")
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            raise ValueError(f"column {key!r} holds non-finite values")
        a = np.ascontiguousarray(a)
        shape = [1] if a.ndim == 1 else [int(a.shape[1])]
        n = names.get(key)
        if n is not None:
            n = [str(x) for x in n]
            if len(n) != shape[0]:
                raise ValueError(f"names for {key!r} have {len(n)} entries; the feature has {shape[0]}")
        feats[key] = {"dtype": a.dtype.name, "shape": shape, "names": n}
        arrays[key] = a
    return feats, arrays


def _row_bytes(a: np.ndarray) -> int:
    return a.dtype.itemsize * (1 if a.ndim == 1 else a.shape[1])


class _FileRoller:
    """lerobot's file rule, one item at a time: items never split; a new file starts when
    the current one would reach ``limit_mb`` (``size + new >= limit``), and files roll into
    the next chunk every ``chunks_size`` files."""

    def __init__(self, limit_mb: int, chunks_size: int):
        self.limit, self.chunks_size = limit_mb * 1024**2, chunks_size
        self.chunk = self.fidx = self.cur = 0

    def assign(self, sizes) -> np.ndarray:
        out = np.empty((len(sizes), 2), dtype=np.int64)
        for i, s in enumerate(np.asarray(sizes).tolist()):
            if self.cur > 0 and self.cur + s >= self.limit:
                if self.fidx == self.chunks_size - 1:
                    self.chunk, self.fidx = self.chunk + 1, 0
                else:
                    self.fidx += 1
                self.cur = 0
            self.cur += s
            out[i] = self.chunk, self.fidx
        return out


def _arrow_column(a: np.ndarray) -> pa.Array:
    if a.ndim == 1:
        return pa.array(a)
    return pa.FixedSizeListArray.from_arrays(pa.array(a.reshape(-1)), int(a.shape[1]))


def _hf_features(feats: dict) -> dict:
    """The ``huggingface`` schema metadata lerobot's writer leaves (datasets.Features)."""
    out = {}
    for k, ft in feats.items():
        value = {"dtype": ft["dtype"], "_type": "Value"}
        out[k] = value if ft["shape"] == [1] else {"feature": value, "length": ft["shape"][0], "_type": "List"}
    return {"info": {"features": out}}


def _groups(file_of: np.ndarray):
    """Consecutive runs of equal (chunk, file) rows: [(chunk, file, first, stop)]."""
    change = np.flatnonzero(np.any(file_of[1:] != file_of[:-1], axis=1)) + 1
    bounds = np.concatenate(([0], change, [len(file_of)]))
    return [(int(file_of[a, 0]), int(file_of[a, 1]), int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]


def _write_tasks(root: Path, tasks: list[str]) -> None:
    # lerobot reads tasks with pandas and takes the task string from the *index* (named
    # "task"); a plain "task" column loads silently with item["task"] == 0.
    import pandas as pd

    df = pd.DataFrame({"task_index": np.arange(len(tasks), dtype=np.int64)}, index=pd.Index(tasks, name="task"))
    df.to_parquet(root / TASKS_PATH)


def _write_json(path: Path, obj) -> None:
    # lerobot's write_json layout (indent 4, UTF-8); repr floats are deterministic
    path.write_text(json.dumps(obj, indent=4, ensure_ascii=False, allow_nan=False), encoding="utf-8")


# ----------------------------------------------------------------------------- statistics


def _stats_dtype(dt: np.dtype) -> np.dtype:
    # lerobot RunningQuantileStats: batch.astype(np.result_type(dtype, np.float32))
    return np.result_type(dt, np.float32)


def _interp_quantiles(sorted_vals: np.ndarray, n, axis: int) -> list[np.ndarray]:
    """Linear-interpolation quantiles from values sorted along ``axis`` (first n valid)."""
    out = []
    n = np.asarray(n)
    for q in QUANTILES:
        pos = q * (n - 1)
        lo = np.floor(pos).astype(np.int64)
        hi = np.minimum(lo + 1, n - 1)
        frac = pos - lo
        vlo = np.take_along_axis(sorted_vals, _expand(lo, sorted_vals, axis), axis).astype(np.float64)
        vhi = np.take_along_axis(sorted_vals, _expand(hi, sorted_vals, axis), axis).astype(np.float64)
        f = _expand(frac, sorted_vals, axis)
        out.append(np.squeeze(vlo + (vhi - vlo) * f, axis=axis))
    return out


def _expand(idx, arr: np.ndarray, axis: int):
    """Broadcast a scalar or per-row index to take_along_axis form for ``arr``."""
    idx = np.asarray(idx)
    shape = [1] * arr.ndim
    if idx.ndim == 1:  # one per leading row (episode)
        shape[0] = idx.shape[0]
    return idx.reshape(shape)


def _global_stats(a: np.ndarray) -> dict:
    """Stats of one feature over all frames, shapes as lerobot's compute_episode_stats:
    the in-memory definition (the bulk writer's before streaming), which the streamed
    :func:`_sorted_stats` / :func:`_index_stats` reproduce bit for bit (tested)."""
    cols = a.reshape(len(a), -1)
    d = cols.shape[1]
    res = {k: np.empty(d) for k in STAT_KEYS if k != "count"}
    sdt = _stats_dtype(a.dtype)
    for j in range(d):
        c = np.sort(cols[:, j].astype(sdt))
        c64 = c.astype(np.float64)
        m = c64.mean()
        res["min"][j], res["max"][j], res["mean"][j] = c64[0], c64[-1], m
        res["std"][j] = np.sqrt(np.mean((c64 - m) ** 2))
        for key, v in zip(QUANTILE_KEYS, _interp_quantiles(c[:, None], len(c), 0)):
            res[key][j] = v[0]
    out = {k: res[k] for k in ("min", "max", "mean", "std")}
    out["count"] = np.array([len(a)], dtype=np.int64)
    out.update({k: res[k] for k in QUANTILE_KEYS})
    return out


def _episode_stats(a: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> dict:
    """Per-episode stats of one feature: {stat: (E, d)} (count (E, 1))."""
    cols = a.reshape(len(a), -1)
    E, d = len(lengths), cols.shape[1]
    sdt = _stats_dtype(a.dtype)
    out = {k: np.empty((E, d)) for k in STAT_KEYS if k != "count"}
    out["count"] = lengths.reshape(E, 1).astype(np.int64)
    e = 0
    while e < E:  # blocks of whole episodes, padded to their longest
        e1, lmax = e + 1, int(lengths[e])
        while e1 < E and (e1 - e + 1) * max(lmax, int(lengths[e1])) <= _STATS_BLOCK_CELLS:
            lmax = max(lmax, int(lengths[e1]))
            e1 += 1
        a0, b0 = int(starts[e]), int(starts[e1 - 1] + lengths[e1 - 1])
        L = lengths[e:e1]
        x = cols[a0:b0].astype(sdt)
        rel_starts = starts[e:e1] - a0
        x64 = x.astype(np.float64)
        mean = np.add.reduceat(x64, rel_starts, axis=0) / L[:, None]
        dev = x64 - np.repeat(mean, L, axis=0)
        out["mean"][e:e1] = mean
        out["std"][e:e1] = np.sqrt(np.add.reduceat(dev * dev, rel_starts, axis=0) / L[:, None])
        pad = np.full((e1 - e, lmax, d), np.inf, dtype=sdt)
        row = np.repeat(np.arange(e1 - e), L)
        pad[row, np.arange(b0 - a0) - np.repeat(rel_starts, L)] = x
        pad.sort(axis=1)  # +inf padding sorts to the end
        out["min"][e:e1] = pad[:, 0]
        out["max"][e:e1] = pad[np.arange(e1 - e), L - 1]
        for key, v in zip(QUANTILE_KEYS, _interp_quantiles(pad, L, 1)):
            out[key][e:e1] = v
        e = e1
    return out


def _sorted_stats(get, n: int) -> dict:
    """min/max/mean/std/quantiles of one dimension from its ``n`` values in ascending
    order, read in pieces (``get(i0, i1)`` -> the values in their statistics dtype), bit
    for bit what :func:`_global_stats` computes on the whole sorted column: NumPy's
    float64 sum of a contiguous array adds pairwise within buffers of ``np.getbufsize()``
    elements and sequentially across them (checked in tests/test_lerobot_format.py), so
    adding the buffers' sums in order gives the same float."""
    step = np.getbufsize()
    total = 0.0
    for i in range(0, n, step):
        total += np.add.reduce(get(i, min(i + step, n)).astype(np.float64))
    m = np.float64(total) / n
    sq = 0.0
    for i in range(0, n, step):
        d = get(i, min(i + step, n)).astype(np.float64) - m
        sq += np.add.reduce(d ** 2)
    out = {"min": np.float64(get(0, 1)[0]), "max": np.float64(get(n - 1, n)[0]), "mean": m,
           "std": np.sqrt(np.float64(sq) / n)}
    nn = np.asarray(n)
    for key, q in zip(QUANTILE_KEYS, QUANTILES):  # as _interp_quantiles
        pos = q * (nn - 1)
        lo = np.floor(pos).astype(np.int64)
        hi = np.minimum(lo + 1, nn - 1)
        frac = pos - lo
        vlo = np.asarray(get(int(lo), int(lo) + 1)[:1]).astype(np.float64)
        vhi = np.asarray(get(int(hi), int(hi) + 1)[:1]).astype(np.float64)
        out[key] = (vlo + (vhi - vlo) * frac)[0]
    return out


def _index_stats(k: str, lengths: np.ndarray, fps: int) -> dict:
    """Dataset-level stats of one of lerobot's index columns, from the episode lengths
    alone (their sorted values are known without the frames)."""
    F = int(lengths.sum())
    if k == "index":
        get = lambda i0, i1: np.arange(i0, i1, dtype=np.float64)  # noqa: E731
    elif k == "task_index":
        get = lambda i0, i1: np.zeros(i1 - i0)  # noqa: E731
    else:
        if k == "episode_index":  # sorted already: episode e repeated length[e] times
            ends = np.cumsum(lengths)
        else:  # frame_index / timestamp: value v occurs once per episode longer than v
            ends = np.cumsum(np.bincount(lengths, minlength=int(lengths.max()) + 1)[::-1])[::-1][1:]
            ends = np.cumsum(ends)

        def rank(i0, i1):
            return np.searchsorted(ends, np.arange(i0, i1), side="right")

        if k == "timestamp":
            get = lambda i0, i1: (rank(i0, i1) / float(fps)).astype(np.float32)  # noqa: E731
        else:
            get = lambda i0, i1: rank(i0, i1).astype(np.float64)  # noqa: E731
    out = _sorted_stats(get, F)
    out["count"] = F
    return {s: [out[s]] for s in STAT_KEYS}


# ----------------------------------------------------------------------------- reading


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


def _file_paths(root: Path, sub: str) -> list[Path]:
    base = root / sub
    return sorted(p for p in base.glob("*/*.parquet") if p.is_file()) if base.is_dir() else []


def _read_table(path: Path, columns=None) -> pa.Table:
    try:
        return pq.read_table(path, columns=columns, use_threads=True)
    except FileNotFoundError:
        raise UserError(f"missing file {path}") from None
    except (OSError, pa.ArrowException, ValueError) as e:
        raise UserError(f"cannot read {path}: {e}") from None


def _column_to_numpy(col: pa.ChunkedArray, shape) -> np.ndarray:
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


def read_columns(root: str | Path) -> dict[str, np.ndarray]:
    """Every feature of the dataset at ``root`` as numpy arrays, without torch or lerobot:
    vector features ``(F, n)``, scalar features (shape ``(1,)``, including
    ``episode_index``, ``frame_index``, ``index``, ``timestamp``, ``task_index``) ``(F,)``,
    in the global ``index`` order. UserError on missing or unreadable files."""
    root = Path(root)
    info = read_info(root)
    feats = {k: ft for k, ft in info["features"].items() if ft.get("dtype") not in ("video", "image")}
    paths = _file_paths(root, "data")
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
                v = _column_to_numpy(t.column(k), ft["shape"])
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


# ----------------------------------------------------------------------------- checking


def _expected_arrow_type(ft: dict) -> pa.DataType | None:
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


def check_structure(root: str | Path) -> list[str]:
    """Structural problems of the LeRobot v3.0 dataset at ``root`` (empty: none found).

    Checks the files lerobot needs, info.json totals against the data and episodes
    parquet, contiguous episode/frame index ranges consistent between them, the tasks
    parquet's pandas form, per-frame schemas against the features in info.json, stats.json
    keys and shapes, and stray parquet files lerobot would pick up."""
    root = Path(root)
    problems: list[str] = []
    try:
        info = read_info(root)
    except UserError as e:
        return [str(e)]
    feats = info["features"]
    for k, ft in feats.items():
        shape = ft.get("shape") if isinstance(ft, dict) else None
        if not isinstance(ft, dict) or not isinstance(ft.get("dtype"), str) or not isinstance(shape, list) \
                or not shape or not all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in shape):
            problems.append(f"info.json: feature {k!r} lacks a dtype string or a shape list of positive integers")
        elif "/" in k:
            problems.append(f"info.json: feature name {k!r} contains '/'")
    for k in INDEX_FEATURES:
        if k not in feats:
            problems.append(f"info.json: required feature {k!r} missing")
    for k in ("total_episodes", "total_frames", "total_tasks", "chunks_size", "data_path"):
        if k not in info:
            problems.append(f"info.json: {k!r} missing")
        elif k != "data_path" and (not isinstance(info[k], int) or isinstance(info[k], bool) or info[k] < 0):
            problems.append(f"info.json: {k!r} must be a non-negative integer, got {info[k]!r}")
    if problems:
        return problems
    if info["data_path"] != DATA_PATH:
        problems.append(f"info.json: data_path {info['data_path']!r}, expected {DATA_PATH!r}")
    E, F = info["total_episodes"], info["total_frames"]
    if info.get("splits") != {"train": f"0:{E}"}:
        problems.append(f"info.json: splits {info.get('splits')!r} do not cover the {E} episodes")
    if any(ft.get("dtype") in ("video", "image") for ft in feats.values()):
        problems.append("info.json: video/image features are not supported by this checker")
        return problems

    # tasks
    T = None
    tpath = root / TASKS_PATH
    if not tpath.is_file():
        problems.append(f"missing {TASKS_PATH}")
    else:
        try:
            tt = pq.read_table(tpath)
            pmeta = json.loads((tt.schema.metadata or {}).get(b"pandas", b"{}"))
            if pmeta.get("index_columns") != ["task"] or "task" not in tt.column_names:
                problems.append(f"{TASKS_PATH}: the task strings must be the pandas index named 'task'")
            elif "task_index" not in tt.column_names:
                problems.append(f"{TASKS_PATH}: no task_index column")
            else:
                T = tt.num_rows
                if tt.column("task_index").to_pylist() != list(range(T)):
                    problems.append(f"{TASKS_PATH}: task_index is not 0..{T - 1}")
                if T != info["total_tasks"]:
                    problems.append(f"{TASKS_PATH}: {T} tasks, info.json total_tasks {info['total_tasks']}")
        except (OSError, pa.ArrowException, ValueError) as e:
            problems.append(f"cannot read {TASKS_PATH}: {e}")

    # stats (optional for loading, but always written by write_dataset)
    spath = root / STATS_PATH
    if not spath.is_file():
        problems.append(f"missing {STATS_PATH}")
    else:
        try:
            stats = json.loads(spath.read_text(encoding="utf-8"))
            for k, ft in feats.items():
                st = stats.get(k)
                if not isinstance(st, dict):
                    problems.append(f"{STATS_PATH}: no stats for {k!r}")
                    continue
                for s in STAT_KEYS:
                    v = np.asarray(st.get(s, []), dtype=np.float64)
                    want = (1,) if s == "count" else tuple(ft["shape"])
                    if v.shape != want:
                        problems.append(f"{STATS_PATH}: {k}/{s} has shape {v.shape}, expected {want}")
                    elif s == "count" and v[0] != F:
                        problems.append(f"{STATS_PATH}: {k}/count {int(v[0])} != total_frames {F}")
        except (OSError, UnicodeDecodeError, ValueError, TypeError) as e:
            problems.append(f"cannot read {STATS_PATH}: {e}")

    # episodes metadata
    ep_paths = _file_paths(root, "meta/episodes")
    problems += _stray_files(root, "meta/episodes")
    eps = None
    if not ep_paths:
        problems.append("missing meta/episodes/chunk-*/file-*.parquet")
    else:
        parts = []
        for p in ep_paths:
            rel = p.relative_to(root).as_posix()
            try:
                t = pq.read_table(p, columns=[*_EP_INDEX_COLUMNS, "tasks"])
            except (OSError, pa.ArrowException, ValueError, KeyError) as e:
                problems.append(f"cannot read {rel}: {e}")
                continue
            chunk, fidx = _chunk_file(p)
            d = {c: t.column(c).to_numpy() for c in _EP_INDEX_COLUMNS}
            if np.any(d["meta/episodes/chunk_index"] != chunk) or np.any(d["meta/episodes/file_index"] != fidx):
                problems.append(f"{rel}: meta/episodes/chunk_index/file_index do not name this file")
            if t.num_rows == 0:
                problems.append(f"{rel}: no episodes")
            tasks = t.column("tasks").to_pylist()
            if T is not None and any(not x or len(x) != len(set(x)) for x in tasks):
                problems.append(f"{rel}: an episode lists no or duplicate tasks")
            parts.append(d)
        if parts:
            eps = {c: np.concatenate([d[c] for d in parts]) for c in _EP_INDEX_COLUMNS}
            n = len(eps["episode_index"])
            if n != E:
                problems.append(f"episodes parquet has {n} episodes, info.json total_episodes {E}")
            if not np.array_equal(eps["episode_index"], np.arange(n)):
                problems.append("episodes parquet: episode_index is not 0..E-1 in file order")
            fr, to, ln = eps["dataset_from_index"], eps["dataset_to_index"], eps["length"]
            if n and (fr[0] != 0 or np.any(fr[1:] != to[:-1]) or np.any(to - fr != ln) or np.any(ln <= 0)):
                problems.append("episodes parquet: dataset_from_index/dataset_to_index/length are not contiguous ranges")
            elif n and to[-1] != F:
                problems.append(f"episodes parquet: episodes cover {int(to[-1])} frames, info.json total_frames {F}")

    # data
    data_paths = _file_paths(root, "data")
    problems += _stray_files(root, "data")
    if not data_paths:
        problems.append("missing data/chunk-*/file-*.parquet")
        return problems
    expect = {k: _expected_arrow_type(ft) for k, ft in feats.items()}
    rows = {}
    idx_parts = []
    for p in data_paths:
        rel = p.relative_to(root).as_posix()
        try:
            schema = pq.read_schema(p)
            md = pq.read_metadata(p)
        except (OSError, pa.ArrowException, ValueError) as e:
            problems.append(f"cannot read {rel}: {e}")
            continue
        names = schema.names
        if sorted(names) != sorted(feats):
            problems.append(f"{rel}: columns {sorted(set(names) ^ set(feats))} differ from info.json features")
        for k in set(names) & set(feats):
            typ, want = schema.field(k).type, expect[k]
            if want is not None and pa.types.is_fixed_size_list(want):
                ok = pa.types.is_fixed_size_list(typ) and typ.list_size == want.list_size and typ.value_type == want.value_type
            else:
                ok = want is not None and typ == want
            if not ok:
                problems.append(f"{rel}: column {k!r} is {typ}, info.json says {feats[k]['dtype']} {feats[k]['shape']}")
        rows[_chunk_file(p)] = md.num_rows
        try:
            t = pq.read_table(p, columns=["index", "episode_index", "frame_index", "timestamp", "task_index"])
            idx_parts.append({c: t.column(c).to_numpy() for c in t.column_names})
        except (OSError, pa.ArrowException, ValueError, KeyError) as e:
            problems.append(f"cannot read the index columns of {rel}: {e}")
    total = sum(rows.values())
    if total != F:
        problems.append(f"data files hold {total} frames, info.json total_frames {F}")
    if idx_parts and len(idx_parts) == len(data_paths):
        ix = {c: np.concatenate([d[c] for d in idx_parts]) for c in idx_parts[0]}
        if not np.array_equal(ix["index"], np.arange(len(ix["index"]))):
            problems.append("data: the index column is not 0..F-1 in file order")
        if T is not None and np.any((ix["task_index"] < 0) | (ix["task_index"] >= T)):
            problems.append("data: task_index outside the tasks table")
        if eps is not None and len(ix["index"]) == F and len(eps["episode_index"]) == E and E:
            ln = eps["length"]
            if ln.sum() == F and np.all(ln > 0):
                ep_expected = np.repeat(np.arange(E), ln)
                fi_expected = np.arange(F) - np.repeat(eps["dataset_from_index"], ln)
                if not np.array_equal(ix["episode_index"], ep_expected):
                    problems.append("data: episode_index disagrees with the episodes parquet ranges")
                if not np.array_equal(ix["frame_index"], fi_expected):
                    problems.append("data: frame_index does not count 0..length-1 within each episode")
                elif not np.array_equal(ix["timestamp"], (fi_expected / float(info["fps"])).astype(np.float32)):
                    problems.append("data: timestamp is not frame_index / fps")
            # every episode's data file holds its rows
            for (c, f), n in rows.items():
                sel = (eps["data/chunk_index"] == c) & (eps["data/file_index"] == f)
                if int(eps["length"][sel].sum()) != n:
                    problems.append(f"{DATA_PATH.format(chunk_index=c, file_index=f)}: {n} rows, the episodes parquet assigns {int(eps['length'][sel].sum())}")
            named = set(zip(eps["data/chunk_index"].tolist(), eps["data/file_index"].tolist()))
            for c, f in sorted(named - set(rows)):
                problems.append(f"episodes parquet refers to missing {DATA_PATH.format(chunk_index=c, file_index=f)}")
    return problems


def _chunk_file(p: Path) -> tuple[int, int]:
    m = _FILE_RE.match(f"{p.parent.name}/{p.name}")
    return (int(m.group(1)), int(m.group(2))) if m else (-1, -1)


def _stray_files(root: Path, sub: str) -> list[str]:
    """Files under ``sub`` other than chunk-NNN/file-NNN.parquet (lerobot globs */*.parquet)."""
    base = root / sub
    out = []
    if base.is_dir():
        for p in sorted(base.rglob("*")):
            if p.is_file() and not _FILE_RE.match(p.relative_to(base).as_posix()):
                out.append(f"unexpected file {p.relative_to(root).as_posix()}")
    return out


__all__ = ["write_dataset", "DatasetWriter", "read_columns", "read_info", "check_structure", "DEFAULT_TASK", "DEFAULT_NAMES"]
