"""Checking a LeRobot v3.0 dataset's structure: what lerobot's loader needs, and that the
data, the episodes metadata, info.json, tasks and stats agree with one another."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from aerohrl.datagen.lerobot_layout import DATA_PATH, INDEX_FEATURES, STATS_PATH, TASKS_PATH, DatasetLayout, expected_arrow_type
from aerohrl.datagen.lerobot_reader import read_info
from aerohrl.datagen.lerobot_stats import STAT_KEYS
from aerohrl.errors import UserError

_EP_INDEX_COLUMNS = (
    "episode_index",
    "data/chunk_index",
    "data/file_index",
    "dataset_from_index",
    "dataset_to_index",
    "meta/episodes/chunk_index",
    "meta/episodes/file_index",
    "length",
)


def check_structure(root: str | Path) -> list[str]:
    """Structural problems of the LeRobot v3.0 dataset at ``root`` (empty: none found).

    Checks the files lerobot needs, info.json totals against the data and episodes
    parquet, contiguous episode/frame index ranges consistent between them, the tasks
    parquet's pandas form, per-frame schemas against the features in info.json, stats.json
    keys and shapes, and stray parquet files lerobot would pick up."""
    root = Path(root)
    layout = DatasetLayout(root)
    problems: list[str] = []
    try:
        info = read_info(root)
    except UserError as e:
        return [str(e)]
    feats = info["features"]
    for k, ft in feats.items():
        shape = ft.get("shape") if isinstance(ft, dict) else None
        if (
            not isinstance(ft, dict)
            or not isinstance(ft.get("dtype"), str)
            or not isinstance(shape, list)
            or not shape
            or not all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in shape)
        ):
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
    tpath = layout.tasks
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
    spath = layout.stats
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
    ep_paths = layout.episodes_files()
    problems += layout.stray_files("meta/episodes")
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
            chunk, fidx = layout.chunk_file(p)
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
    data_paths = layout.data_files()
    problems += layout.stray_files("data")
    if not data_paths:
        problems.append("missing data/chunk-*/file-*.parquet")
        return problems
    expect = {k: expected_arrow_type(ft) for k, ft in feats.items()}
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
        rows[layout.chunk_file(p)] = md.num_rows
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
                    problems.append(
                        f"{DATA_PATH.format(chunk_index=c, file_index=f)}: {n} rows, the episodes parquet assigns {int(eps['length'][sel].sum())}"
                    )
            named = set(zip(eps["data/chunk_index"].tolist(), eps["data/file_index"].tolist()))
            for c, f in sorted(named - set(rows)):
                problems.append(f"episodes parquet refers to missing {DATA_PATH.format(chunk_index=c, file_index=f)}")
    return problems


__all__ = ["check_structure"]
