"""The bulk LeRobot v3.0 writer: lerobot 0.6.1 loads what we write, offline, frame for frame."""

import json
import shutil
import socket
import time

import numpy as np
import pyarrow.parquet as pq
import pytest

from aerohrl import task
from aerohrl.datagen.lerobot_reader import read_columns, read_info
from aerohrl.datagen.lerobot_stats import QUANTILE_KEYS, QUANTILES
from aerohrl.datagen.lerobot_validate import check_structure
from aerohrl.datagen.lerobot_writer import write_dataset
from aerohrl.errors import UserError

REPO = "aerohrl/quadrotor-reach"
TASK = "reach the goal"
FPS = 100
LENGTHS = [7, 12, 1, 9]


def synthetic(lengths, seed=0):
    rng = np.random.default_rng(seed)
    lengths = np.asarray(lengths)
    F, E = int(lengths.sum()), len(lengths)
    ep = np.repeat(np.arange(E), lengths)
    cols = {
        "observation.state": rng.standard_normal((F, 18), dtype=np.float32),
        "action": rng.standard_normal((F, 4), dtype=np.float32),
        "observation.desired_goal": np.repeat(rng.standard_normal((E, 15), dtype=np.float32), lengths, axis=0),
        "next.observation.state": rng.standard_normal((F, 18), dtype=np.float32),
        "next.reward": rng.random(F, dtype=np.float32),
        "next.done": np.r_[ep[1:] != ep[:-1], True],
        "next.success": rng.random(F) < 0.3,
    }
    return cols, ep


def expected_index_columns(ep):
    starts = np.searchsorted(ep, np.arange(ep.max() + 1))
    fi = np.arange(len(ep)) - starts[ep]
    return {
        "frame_index": fi,
        "episode_index": ep,
        "index": np.arange(len(ep)),
        "task_index": np.zeros(len(ep), dtype=np.int64),
        "timestamp": (fi / FPS).astype(np.float32),
    }


@pytest.fixture(scope="module")
def offline(tmp_path_factory):
    """No network at all, and the HF datasets Arrow cache in a temporary directory."""
    import datasets.config

    def no_network(*a, **k):
        raise AssertionError("a network connection was attempted")

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(socket.socket, "connect", no_network)
        mp.setattr(socket, "create_connection", no_network)
        mp.setattr(datasets.config, "HF_DATASETS_CACHE", str(tmp_path_factory.mktemp("hf_cache")))
        yield


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    cols, ep = synthetic(LENGTHS)
    root = tmp_path_factory.mktemp("small") / "ds"
    write_dataset(root, cols, ep, fps=FPS, task=TASK, robot_type="quadrotor-test")
    return root, cols, ep


@pytest.fixture(scope="module")
def multi(tmp_path_factory):
    """~9,000 frames split over 3 data files in 2 chunks and 2 episodes-metadata files."""
    lengths = np.random.default_rng(3).integers(20, 41, 300)
    cols, ep = synthetic(lengths, seed=3)
    root = tmp_path_factory.mktemp("multi") / "ds"
    write_dataset(root, cols, ep, fps=FPS, task=TASK, chunks_size=2, data_files_size_in_mb=1)
    return root, cols, ep, lengths


def _load(root, **kw):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(REPO, root=root, **kw)


def test_layout_and_info(small):
    root, cols, ep = small
    files = sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())
    assert files == [
        "data/chunk-000/file-000.parquet",
        "meta/episodes/chunk-000/file-000.parquet",
        "meta/info.json",
        "meta/stats.json",
        "meta/tasks.parquet",
    ]
    info = read_info(root)
    assert info["codebase_version"] == "v3.0" and info["fps"] == FPS and info["video_path"] is None
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (4, sum(LENGTHS), 1)
    assert info["splits"] == {"train": "0:4"} and info["robot_type"] == "quadrotor-test"
    assert info["data_files_size_in_mb"] == 100 and info["chunks_size"] == 1000
    f = info["features"]
    assert list(f)[-5:] == ["timestamp", "frame_index", "episode_index", "index", "task_index"]
    assert f["observation.state"] == {"dtype": "float32", "shape": [18], "names": task.STATE_NAMES}
    assert f["next.observation.state"]["names"] == task.STATE_NAMES
    assert f["action"]["names"] == task.ACTION_NAMES and f["observation.desired_goal"]["names"] == task.GOAL_NAMES
    assert f["next.done"] == {"dtype": "bool", "shape": [1], "names": None}
    schema = pq.read_schema(root / "data/chunk-000/file-000.parquet")
    assert (
        str(schema.field("observation.state").type).startswith("fixed_size_list<") and schema.field("next.reward").type == "float"
    )
    # tasks: the string is the pandas index named "task" (lerobot reads tasks.iloc[i].name)
    import pandas as pd

    tasks = pd.read_parquet(root / "meta/tasks.parquet")
    assert tasks.index.name == "task" and list(tasks.index) == [TASK] and list(tasks["task_index"]) == [0]
    assert check_structure(root) == []


def test_lerobot_loads_every_frame_offline(offline, small):
    root, cols, ep = small
    before = sorted(p for p in root.rglob("*"))
    ds = _load(root)
    assert len(ds) == sum(LENGTHS) and ds.num_episodes == len(LENGTHS) and ds.fps == FPS
    idx = expected_index_columns(ep)
    for i in range(len(ds)):
        item = ds[i]
        assert item["task"] == TASK
        for k, v in cols.items():
            np.testing.assert_array_equal(item[k].numpy(), v[i], err_msg=f"{k} frame {i}")
        for k, v in idx.items():
            assert item[k].item() == v[i], (k, i)
    assert sorted(p for p in root.rglob("*")) == before, "loading wrote into the dataset directory"


def test_lerobot_delta_timestamps_and_padding(offline, small):
    root, cols, ep = small
    ds = _load(root, delta_timestamps={"action": [0, 0.01, 0.02], "observation.state": [-0.01, 0]})
    starts = np.r_[0, np.cumsum(LENGTHS)[:-1]]
    ends = np.cumsum(LENGTHS)
    pads = 0
    for i in range(len(ds)):
        item = ds[i]
        lo, hi = starts[ep[i]], ends[ep[i]]
        for key, deltas in (("action", [0, 1, 2]), ("observation.state", [-1, 0])):
            want_idx = [min(max(i + d, lo), hi - 1) for d in deltas]
            want_pad = [not (lo <= i + d < hi) for d in deltas]
            np.testing.assert_array_equal(item[key].numpy(), cols[key][want_idx])
            assert item[f"{key}_is_pad"].tolist() == want_pad, (key, i)
            pads += sum(want_pad)
        assert item["task"] == TASK
    assert pads > 0
    # the 1-frame episode: everything but the current frame is padding
    one = ds[int(starts[2])]
    assert one["action_is_pad"].tolist() == [False, True, True]
    assert one["observation.state_is_pad"].tolist() == [True, False]


def test_stats_load_and_are_the_data_stats(offline, small):
    root, cols, ep = small
    ds = _load(root)
    stats = ds.meta.stats
    assert set(stats) == set(ds.meta.features)
    all_cols = {**cols, **expected_index_columns(ep)}
    F = len(ep)
    for k, v in all_cols.items():
        x = v.reshape(F, -1).astype(np.float64)
        st = stats[k]
        assert st["count"].tolist() == [F]
        np.testing.assert_allclose(st["min"], x.min(0), rtol=0, atol=0)
        np.testing.assert_allclose(st["max"], x.max(0), rtol=0, atol=0)
        np.testing.assert_allclose(st["mean"], x.mean(0), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(st["std"], x.std(0), rtol=1e-9, atol=1e-12)
        for q, key in zip(QUANTILES, QUANTILE_KEYS):
            np.testing.assert_allclose(st[key], np.quantile(x, q, axis=0), rtol=1e-9, atol=1e-12, err_msg=f"{k} {key}")
    # per-episode stats columns (lerobot's dataset tools aggregate them)
    t = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet").to_pydict()
    assert t["tasks"] == [[TASK]] * 4 and t["length"] == LENGTHS
    for e in range(4):
        x = cols["observation.state"][ep == e].astype(np.float64)
        np.testing.assert_allclose(t["stats/observation.state/mean"][e], x.mean(0), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(t["stats/observation.state/q90"][e], np.quantile(x, 0.9, axis=0), rtol=1e-9, atol=1e-12)
        assert t["stats/next.done/count"][e] == [LENGTHS[e]]
        assert t["stats/next.done/max"][e] == [1.0]


def test_read_columns_round_trips_exactly(small):
    root, cols, ep = small
    got = read_columns(root)
    want = {**cols, **expected_index_columns(ep)}
    assert set(got) == set(want)
    for k, v in want.items():
        assert got[k].dtype == v.dtype and got[k].shape == v.shape, k
        np.testing.assert_array_equal(got[k], v, err_msg=k)


def test_writing_twice_gives_identical_bytes(tmp_path):
    cols, ep = synthetic(LENGTHS, seed=5)
    write_dataset(tmp_path / "a", cols, ep, fps=FPS, task=TASK)
    time.sleep(1.1)  # anything time-dependent would now differ
    write_dataset(tmp_path / "b", cols, ep, fps=FPS, task=TASK)
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*") if p.is_file())
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f


def test_large_data_is_split_into_files_and_chunks(offline, multi):
    root, cols, ep, lengths = multi
    data = sorted(p.relative_to(root).as_posix() for p in (root / "data").rglob("*.parquet"))
    assert data == ["data/chunk-000/file-000.parquet", "data/chunk-000/file-001.parquet", "data/chunk-001/file-000.parquet"]
    metas = sorted(p.relative_to(root).as_posix() for p in (root / "meta/episodes").rglob("*.parquet"))
    assert len(metas) >= 2
    for p in data:
        md = pq.read_metadata(root / p)
        assert md.serialized_size + sum(md.row_group(i).total_byte_size for i in range(md.num_row_groups)) < 1024**2 * 1.05
    assert check_structure(root) == []
    got = read_columns(root)
    for k, v in cols.items():
        np.testing.assert_array_equal(got[k], v, err_msg=k)

    ds = _load(root)
    assert len(ds) == len(ep) and ds.num_episodes == len(lengths)
    table = ds.hf_dataset.with_format(None).data  # bulk compare of every frame
    for k, v in {**cols, **expected_index_columns(ep)}.items():
        col = table.column(k).combine_chunks()
        arr = col.flatten().to_numpy().reshape(len(ep), -1) if v.ndim == 2 else col.to_numpy(zero_copy_only=False)
        np.testing.assert_array_equal(arr, v, err_msg=k)
    # items across a file boundary, and an episode subset (predicate push-down path)
    ep_meta = ds.meta.episodes
    for e in (0, 150, 299):
        row = ep_meta[e]
        assert row["episode_index"] == e and row["dataset_to_index"] - row["dataset_from_index"] == lengths[e]
        i = row["dataset_from_index"]
        np.testing.assert_array_equal(ds[i]["action"].numpy(), cols["action"][i])
    sub = _load(root, episodes=[0, 150, 299])
    assert len(sub) == int(lengths[[0, 150, 299]].sum())
    item = sub[int(lengths[0])]
    assert item["episode_index"].item() == 150 and item["frame_index"].item() == 0


def _copy(small, tmp_path):
    dst = tmp_path / "copy"
    shutil.copytree(small[0], dst)
    return dst


def test_check_structure_reports_damage(small, tmp_path):
    import pandas as pd

    root = _copy(small, tmp_path)
    pd.DataFrame({"task": [TASK], "task_index": [0]}).to_parquet(root / "meta/tasks.parquet", index=False)
    assert any("pandas index" in p for p in check_structure(root))

    root = _copy(small, tmp_path / "b")
    info = json.loads((root / "meta/info.json").read_text())
    info["total_frames"] += 1
    (root / "meta/info.json").write_text(json.dumps(info))
    assert any("total_frames" in p for p in check_structure(root))

    root = _copy(small, tmp_path / "c")
    (root / "meta/episodes/chunk-000/file-000.parquet").unlink()
    assert any("meta/episodes" in p for p in check_structure(root))

    root = _copy(small, tmp_path / "d")
    shutil.copy(root / "data/chunk-000/file-000.parquet", root / "data/chunk-000/file-001.parquet")
    assert any("frames" in p for p in check_structure(root))
    (root / "data/chunk-000/file-001.parquet").unlink()
    (root / "data/chunk-000/notes.txt").write_text("x")
    assert check_structure(root) == ["unexpected file data/chunk-000/notes.txt"]

    root = _copy(small, tmp_path / "e")
    t = pq.read_table(root / "data/chunk-000/file-000.parquet")
    pq.write_table(t.drop_columns(["next.success"]), root / "data/chunk-000/file-000.parquet")
    assert any("differ from info.json" in p for p in check_structure(root))

    root = _copy(small, tmp_path / "f")
    (root / "meta/info.json").unlink()
    assert check_structure(root) and "info.json" in check_structure(root)[0]


def test_read_columns_raises_user_error_on_damage(small, tmp_path):
    with pytest.raises(UserError):
        read_columns(tmp_path / "nothing")
    root = _copy(small, tmp_path)
    p = root / "data/chunk-000/file-000.parquet"
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    with pytest.raises(UserError, match="cannot read"):
        read_columns(root)
    p.unlink()
    with pytest.raises(UserError):
        read_columns(root)
    (root / "meta/info.json").write_text("{not json")
    with pytest.raises(UserError):
        read_info(root)


def test_bad_inputs_are_refused(tmp_path):
    cols, ep = synthetic([3, 4])
    with pytest.raises(ValueError, match="contiguous"):
        write_dataset(tmp_path / "a", cols, ep[::-1].copy())
    with pytest.raises(ValueError, match="contiguous"):
        write_dataset(tmp_path / "a", cols, ep + 1)
    with pytest.raises(ValueError, match="written by write_dataset"):
        write_dataset(tmp_path / "a", {**cols, "timestamp": np.zeros(7, np.float32)}, ep)
    with pytest.raises(ValueError, match="names"):
        write_dataset(tmp_path / "a", cols, ep, names={"action": ["a", "b"]})
    with pytest.raises(ValueError, match="shape"):
        write_dataset(tmp_path / "a", {**cols, "action": cols["action"][:-1]}, ep)
    with pytest.raises(ValueError, match="non-finite"):
        bad = cols["action"].copy()
        bad[0, 0] = np.nan
        write_dataset(tmp_path / "a", {**cols, "action": bad}, ep)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    with pytest.raises(UserError, match="non-empty"):
        write_dataset(tmp_path / "full", cols, ep)
    # an empty existing directory is fine (the build writes into a fresh temporary one)
    (tmp_path / "empty").mkdir()
    write_dataset(tmp_path / "empty", cols, ep)
    assert check_structure(tmp_path / "empty") == []


def test_lerobot_dataset_tools_use_our_episode_stats(offline, small, tmp_path):
    """lerobot's delete_episodes re-aggregates the per-episode stats/* columns we write."""
    from lerobot.datasets.dataset_tools import delete_episodes

    root, cols, ep = small
    new = delete_episodes(_load(root), episode_indices=[1], output_dir=tmp_path / "del", repo_id="aerohrl/del")
    keep = ep != 1
    assert len(new) == int(keep.sum()) and new.num_episodes == 3
    st = new.meta.stats["observation.state"]
    np.testing.assert_allclose(st["mean"], cols["observation.state"][keep].astype(np.float64).mean(0), rtol=1e-9, atol=1e-12)
    assert st["count"].tolist() == [int(keep.sum())]
    assert check_structure(tmp_path / "del") == []


def test_check_structure_survives_nonsense_info(small, tmp_path):
    root = _copy(small, tmp_path)
    info = json.loads((root / "meta/info.json").read_text())
    info["features"]["action"]["shape"] = "x"
    info["total_frames"] = "many"
    (root / "meta/info.json").write_text(json.dumps(info))
    problems = check_structure(root)
    assert any("'action'" in p for p in problems) and any("total_frames" in p for p in problems)
