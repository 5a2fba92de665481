"""Writing LeRobot v3.0 datasets (low-dimensional, no video), fast and without torch.

``LeRobotDataset(repo_id, root=path)`` (lerobot 0.6.1) loads what :func:`write_dataset`
writes, in the layout of :mod:`aerohrl.datagen.lerobot_layout`, which mirrors lerobot's
own recorder (``lerobot/datasets/dataset_writer.py``). It is written with pyarrow in
pieces of many episodes (:class:`DatasetWriter`, streamed: memory bounded by a piece;
the bytes do not depend on how the episodes are cut into pieces) instead of one
``save_episode`` per episode (~66 ms each); the statistics are those of
:mod:`aerohrl.datagen.lerobot_stats`.

Format decisions (checked against lerobot 0.6.1's source and a dataset its writer made):

* Per-frame columns: the caller's features in the given order, then lerobot's
  ``DEFAULT_FEATURES`` ``timestamp`` (float32, ``frame_index / fps``), ``frame_index``,
  ``episode_index``, ``index`` (global row), ``task_index`` (int64).
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
"""

from __future__ import annotations

import json
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from aerohrl import task as _task
from aerohrl.atomic import sha256_file
from aerohrl.datagen.lerobot_layout import (
    CODEBASE_VERSION,
    DATA_PATH,
    DEFAULT_CHUNK_SIZE,
    DEFAULT_DATA_FILE_SIZE_IN_MB,
    DEFAULT_VIDEO_FILE_SIZE_IN_MB,
    INDEX_FEATURES,
    DatasetLayout,
    arrow_column,
    column_to_numpy,
)
from aerohrl.datagen.lerobot_stats import (
    QUANTILE_KEYS,
    STAT_KEYS,
    StreamStats,
    episode_stats,
    index_stats,
    sorted_stats,
    stats_dtype,
)
from aerohrl.errors import UserError

ROW_GROUP_SIZE = 1 << 16
COMPRESSION = "snappy"
DEFAULT_TASK = "Fly the quadrotor from hover at the origin to the desired goal state (position, velocity, attitude)."
DEFAULT_ROBOT_TYPE = "quadrotor"
DEFAULT_NAMES = {
    "observation.state": _task.STATE_NAMES,
    "next.observation.state": _task.STATE_NAMES,
    "action": _task.ACTION_NAMES,
    "observation.desired_goal": _task.GOAL_NAMES,
}


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
    stats: str = "exact",
) -> None:
    """Write ``columns`` (per-frame arrays, episodes contiguous and sorted) as a LeRobot
    v3.0 dataset in ``root`` (created if missing; must be empty).

    ``columns`` maps feature names to arrays of ``F`` rows: 1-D (a scalar feature, shape
    ``(1,)``) or 2-D ``(F, n)``; dtypes bool, integers or floats. ``episode_index`` is
    ``(F,)`` integers ``0..E-1``, non-decreasing in steps of one. ``names`` gives the
    per-dimension names of vector features (defaults: :data:`DEFAULT_NAMES`).
    ``episode_stats=False`` leaves the per-episode ``stats/*`` columns out; ``stats``
    chooses the dataset-level statistics (``"exact"`` or ``"sketch"``, :class:`DatasetWriter`).
    Bad inputs raise ``ValueError`` (a caller bug); a non-empty ``root`` raises UserError.
    The same bytes as :class:`DatasetWriter` fed the episodes in any number of pieces.
    """
    w = DatasetWriter(
        root,
        fps=fps,
        task=task,
        robot_type=robot_type,
        names=names,
        chunks_size=chunks_size,
        data_files_size_in_mb=data_files_size_in_mb,
        episode_stats=episode_stats,
        stats=stats,
    )
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

    ``stats="sketch"`` computes the dataset-level statistics while writing instead
    (:class:`aerohrl.datagen.lerobot_stats.StreamStats`): each row group's frames are
    added to the summary as they are written, in file order, so nothing is read back or
    spilled and the
    bytes still do not depend on how the episodes are cut into pieces (row groups are
    fixed by the frames alone).
    """

    SPILL_DIR = ".stats-spill"

    def __init__(
        self,
        root,
        *,
        fps: int = 100,
        task: str = DEFAULT_TASK,
        robot_type: str | None = DEFAULT_ROBOT_TYPE,
        names: dict[str, list[str]] | None = None,
        chunks_size: int = DEFAULT_CHUNK_SIZE,
        data_files_size_in_mb: int = DEFAULT_DATA_FILE_SIZE_IN_MB,
        episode_stats: bool = True,
        stats: str = "exact",
    ):
        if stats not in ("exact", "sketch"):
            raise ValueError(f"stats must be 'exact' or 'sketch', got {stats!r}")
        self.stats_mode = stats
        self._sketch: dict[str, StreamStats] = {}
        self.root = Path(root)
        self.layout = DatasetLayout(self.root)
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
        self._data_file: tuple[int, int] | None = None  # (chunk, file) open
        self._writer: pq.ParquetWriter | None = None
        self._schema: pa.Schema | None = None
        self._pending: list[dict] = []  # frames not yet in a row group
        self._pending_rows = 0
        self._meta_file: tuple[int, int] | None = None
        self._meta_pending: list[dict] = []
        self._paths: list[Path] = []  # data files in order
        self._hashes: dict[str, Future] = {}  # each closed data file's SHA-256, taken in a thread
        self._hasher: ThreadPoolExecutor | None = None
        self._closed = False

    # -- frames
    def append(
        self, columns: dict[str, np.ndarray], lengths: np.ndarray | list[int], ep_stats: dict[str, dict] | None = None
    ) -> None:
        """Append whole episodes: ``columns`` as for :func:`write_dataset`, ``lengths``
        the frames of each (their sum is the columns' length). ``ep_stats``: per-episode
        statistics of some of the columns, already computed elsewhere
        (:func:`aerohrl.datagen.lerobot_stats.episode_stats` of exactly these frames, e.g.
        in the process that flew them); the others are computed here."""
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
            if self.stats_mode == "exact":
                (self.root / self.SPILL_DIR).mkdir(exist_ok=True)
            self._frame_bytes = None
            self._ep_row_bytes = 7 * 8 + len(self.task.encode()) + 8
            if self.episode_stats:
                for ft in feats.values():
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
        given = ep_stats or {}
        ep_stats = (
            {k: given[k] if k in given else episode_stats(arrays[k], starts, lengths) for k in self.feats}
            if self.episode_stats
            else {}
        )

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
                    v = column_to_numpy(col, ft["shape"])
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
        assert self.feats is not None  # set by the first append, before any rows
        keys = list(self.feats)
        meta = {b"huggingface": json.dumps(_hf_features(self.feats)).encode()}
        if self.stats_mode == "sketch":  # each row group added in file order
            for k in keys:
                if k in self._sketch:
                    self._sketch[k].add(rows[k])
                elif k not in INDEX_FEATURES:
                    self._sketch[k] = StreamStats.of_block(rows[k])
        table = pa.table([arrow_column(np.ascontiguousarray(rows[k])) for k in keys], names=keys)
        if self._schema is None:
            self._schema = table.schema.with_metadata(meta)
        table = table.replace_schema_metadata(meta)
        if self._writer is None:
            assert self._data_file is not None  # append opens a data file before adding rows
            chunk, fidx = self._data_file
            path = self.layout.data_file(chunk, fidx)
            path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = pq.ParquetWriter(
                path, self._schema, compression=COMPRESSION, use_dictionary=["episode_index", "task_index"]
            )
            self._paths.append(path)
        self._writer.write_table(table, row_group_size=ROW_GROUP_SIZE)

    def _finish_data_file(self) -> None:
        if self._data_file is None:
            return
        if self._pending_rows:
            assert self.feats is not None  # pending rows came through append, which sets it
            keys = list(self.feats)
            self._write_rows({k: np.concatenate([p[k] for p in self._pending]) for k in keys})
            self._pending, self._pending_rows = [], 0
        if self._writer is not None:
            self._writer.close()
            self._writer = None
            # its SHA-256 now, while its pages are cached and beside the next blocks' work
            # (hashlib and the reads release the GIL), not in a pass over every file at the end
            path = self._paths[-1]
            if self._hasher is None:
                self._hasher = ThreadPoolExecutor(1)
            self._hashes[path.relative_to(self.root).as_posix()] = self._hasher.submit(sha256_file, path)

    def checksums(self) -> dict[str, str]:
        """The SHA-256 of every data file written, by path relative to ``root`` (after
        :meth:`close`): for :func:`aerohrl.datagen.manifest.write_manifest`."""
        return {rel: f.result() for rel, f in self._hashes.items()}

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
        cols["tasks"] = pa.ListArray.from_arrays(
            pa.array(np.arange(n + 1, dtype=np.int32)), pa.array([self.task] * n, pa.string())
        )
        for k in ("length", "data/chunk_index", "data/file_index", "dataset_from_index", "dataset_to_index"):
            cols[k] = pa.array(ep[k])
        for k, v in ep.items():
            if k.startswith("stats/"):
                offsets = pa.array(np.arange(0, v.size + 1, v.shape[1], dtype=np.int32))
                cols[k] = pa.ListArray.from_arrays(offsets, pa.array(v.reshape(-1)))
        cols["meta/episodes/chunk_index"] = pa.array(np.full(n, chunk, dtype=np.int64))
        cols["meta/episodes/file_index"] = pa.array(np.full(n, fidx, dtype=np.int64))
        table = pa.table(list(cols.values()), names=list(cols))
        path = self.layout.episodes_file(chunk, fidx)
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
                g = index_stats(k, lengths, self.fps)
            elif self.stats_mode == "sketch":
                g = self._sketch.pop(k).result()
            else:
                g = {s: [] for s in STAT_KEYS}
                sdt = stats_dtype(np.dtype(ft["dtype"]))
                self._spill_feature(k, ft, sdt)
                for j in range(ft["shape"][0]):
                    c = np.fromfile(self._spill(k, j), dtype=sdt)
                    self._spill(k, j).unlink()
                    c.sort()
                    one = sorted_stats(lambda i0, i1, c=c: c[i0:i1], len(c))
                    del c
                    for s in STAT_KEYS[:4] + QUANTILE_KEYS:
                        g[s].append(one[s])
                g["count"] = [self.F]
            stats[k] = {s: [float(x) for x in g[s]] if s != "count" else [int(g[s][0])] for s in STAT_KEYS}
        _write_json(self.layout.stats, stats)
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
        _write_json(self.layout.info, info)
        import shutil

        shutil.rmtree(self.root / self.SPILL_DIR, ignore_errors=True)
        if self._hasher is not None:
            self._hasher.shutdown(wait=True)
            self._hasher = None
        self._closed = True

    def abort(self) -> None:
        """Close the open data file (an interrupted build: the caller removes ``root``)."""
        if self._writer is not None:
            try:
                self._writer.close()
            except Exception:  # noqa: BLE001 - best effort on the way out
                pass
            self._writer = None
        if self._hasher is not None:
            self._hasher.shutdown(wait=True, cancel_futures=True)
            self._hasher = None
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
    df.to_parquet(DatasetLayout(root).tasks)


def _write_json(path: Path, obj) -> None:
    # lerobot's write_json layout (indent 4, UTF-8); repr floats are deterministic
    path.write_text(json.dumps(obj, indent=4, ensure_ascii=False, allow_nan=False), encoding="utf-8")


__all__ = ["write_dataset", "DatasetWriter", "DEFAULT_TASK", "DEFAULT_NAMES"]
