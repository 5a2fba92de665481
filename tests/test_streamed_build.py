"""``datagen build`` streams: each rollout block's frames go to the data files
as the block lands, and only per-episode results stay in memory. The bytes are those of
one bulk write; memory does not grow with the frames (the estimate, and what the writer
is handed)."""

import numpy as np
import pytest

from aerohrl.datagen import build as B
from aerohrl.datagen import estimate as E
from aerohrl.datagen import lerobot_layout as LL
from aerohrl.datagen import lerobot_stats as LS
from aerohrl.datagen import lerobot_writer as LW
from aerohrl.datagen.lerobot_reader import read_columns
from aerohrl.datagen.lerobot_validate import check_structure
from aerohrl.datagen.manifest import validate
from aerohrl.datagen.spec import DatasetSpec


def _files(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(autouse=True)
def _restore_block():
    block = B.ROLLOUT_BLOCK
    yield
    B.ROLLOUT_BLOCK = block


def test_tiny_blocks_stream_the_bytes_of_one_block(tmp_path, monkeypatch):
    """A clean spec in blocks of 7 episodes (each appended as it lands, so several row
    groups and pieces) gives the bytes of the same spec in one block; the writer never
    holds more than one block's frames."""
    spec = DatasetSpec(goals=60, seed=6)
    one = B.build(spec, tmp_path / "one", progress=False, log=lambda m: None)
    pieces = []
    real = LW.DatasetWriter.append

    def spy(self, columns, lengths, ep_stats=None):
        pieces.append(len(lengths))
        return real(self, columns, lengths, ep_stats)

    monkeypatch.setattr(LW.DatasetWriter, "append", spy)
    monkeypatch.setattr(LW, "ROW_GROUP_SIZE", 1000)  # row groups fill across pieces
    B.ROLLOUT_BLOCK = 7
    many = B.build(spec, tmp_path / "many", progress=False, log=lambda m: None)
    assert len(pieces) == 9 and max(pieces) <= 7 and sum(pieces) == 60
    monkeypatch.setattr(LW, "ROW_GROUP_SIZE", 1 << 16)
    B.ROLLOUT_BLOCK = 60
    again = B.build(spec, tmp_path / "again", progress=False, log=lambda m: None)
    a, c = _files(one.path), _files(again.path)
    assert sorted(a) == sorted(c) and all(a[k] == c[k] for k in a)
    assert validate(many.path) == []  # other row groups, same contents
    assert not any(".stats-spill" in k for k in _files(many.path))
    cols_one, cols_many = read_columns(one.path), read_columns(many.path)
    for k in cols_one:
        assert np.array_equal(cols_one[k], cols_many[k]), k
    assert (many.path / LL.STATS_PATH).read_bytes() == (one.path / LL.STATS_PATH).read_bytes()


def test_writer_pieces_give_the_bulk_bytes(tmp_path):
    """DatasetWriter fed random pieces == write_dataset at once: several data files in
    several chunks, several episodes-metadata files, row groups across pieces."""
    rng = np.random.default_rng(5)
    lengths = rng.integers(20, 120, 700)
    F = int(lengths.sum())
    ep = np.repeat(np.arange(len(lengths)), lengths)
    cols = {
        "observation.state": rng.standard_normal((F, 18), dtype=np.float32),
        "action": rng.standard_normal((F, 4), dtype=np.float32),
        "next.reward": (rng.random(F) < 0.2).astype(np.float32),
        "next.done": np.r_[ep[1:] != ep[:-1], True],
        "count": rng.integers(0, 9, F),
    }
    kw = dict(fps=50, task="t", chunks_size=2, data_files_size_in_mb=1)
    LW.write_dataset(tmp_path / "bulk", cols, ep, **kw)
    w = LW.DatasetWriter(tmp_path / "stream", **kw)
    starts = np.r_[0, np.cumsum(lengths)]
    e = 0
    while e < len(lengths):
        e1 = min(len(lengths), e + int(rng.integers(1, 90)))
        w.append({k: v[starts[e] : starts[e1]] for k, v in cols.items()}, lengths[e:e1])
        e = e1
    w.close()
    a, b = _files(tmp_path / "bulk"), _files(tmp_path / "stream")
    assert sorted(a) == sorted(b) and len([k for k in a if k.startswith("meta/episodes")]) >= 2
    assert len([k for k in a if k.startswith("data/")]) >= 3
    for k in a:
        assert a[k] == b[k], k
    assert check_structure(tmp_path / "stream") == []


@pytest.mark.parametrize("n", [1, 2, 7, 8192, 8193, 50_001])
def test_streamed_statistics_are_bit_identical_to_the_sorted_column(n):
    """_sorted_stats reads the sorted values in pieces and adds NumPy's buffer sums in
    order: the same floats as mean/std/quantiles of the whole sorted column."""
    rng = np.random.default_rng(n)
    for a in (rng.standard_normal(n).astype(np.float32) * 1e3 + 7, rng.integers(0, 400, n), rng.random(n) < 0.3):
        ref = LS.global_stats(a)
        c = np.sort(a.astype(LS.stats_dtype(a.dtype)))
        got = LS.sorted_stats(lambda i0, i1, c=c: c[i0:i1], n)
        for k in ref:
            if k != "count":
                assert got[k].tobytes() == np.float64(ref[k][0]).tobytes(), (k, got[k], ref[k])
    lengths = rng.integers(1, 300, max(1, n // 100))
    starts = np.r_[0, np.cumsum(lengths)[:-1]]
    fi = np.arange(lengths.sum()) - np.repeat(starts, lengths)
    cols = {
        "frame_index": fi,
        "episode_index": np.repeat(np.arange(len(lengths)), lengths),
        "index": np.arange(lengths.sum()),
        "task_index": np.zeros(lengths.sum(), np.int64),
        "timestamp": (fi / 50.0).astype(np.float32),
    }
    for k, a in cols.items():
        ref, got = LS.global_stats(a), LS.index_stats(k, lengths, 50)
        for s in LS.STAT_KEYS:
            assert np.asarray(got[s], dtype=np.float64).tobytes() == np.asarray(ref[s], dtype=np.float64).tobytes(), (k, s)


def test_memory_estimate_is_bounded_in_the_number_of_goals():
    """The streamed peak: one block's working set, plus per-episode and 4 bytes per frame
    terms; a million goals with noise fit a 23 GB machine (they were refused at 134 GB)
    and each added frame costs a few bytes (per-episode results, statistics) instead of 650. Continuations keep the old per-frame model."""
    small = E.estimate(DatasetSpec(goals=25_000, action_noise=(1.0, 0.5)))
    big = E.estimate(DatasetSpec(goals=1_000_000, action_noise=(1.0, 0.5)))
    assert big.frames > 35 * small.frames
    per_frame = (big.memory - small.memory) / (big.frames - small.frames)
    assert big.memory < 8e9 and per_frame < 20  # bytes per added frame (before streaming: 650)
    assert E.shortfall(big, memory=20e9, disk=float("inf")) is None
    exact = E.estimate(DatasetSpec(goals=1_000_000, action_noise=(1.0, 0.5), stats="exact"))
    assert E.shortfall(exact, memory=20e9, disk=exact.disk) is not None  # the exact statistics' spill needs scratch disk
    assert big.scratch == 0 and E.shortfall(big, memory=20e9, disk=big.disk) is None  # the streamed sketch spills nothing
    two = E.estimate(DatasetSpec(goals=1_000_000, action_noise=(1.0, 0.5)), workers=2)
    assert two.memory > big.memory
    cont = E.estimate(DatasetSpec(goals=1_000_000, continuations=10))
    assert cont.memory > big.frames * E.MEMORY_BYTES_PER_FRAME
