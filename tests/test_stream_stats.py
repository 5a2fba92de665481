"""Streamed dataset statistics (``stats = "sketch"``, :class:`aerohrl.datagen.lerobot_stats.StreamStats`):
exact count/min/max and float64 mean/std against NumPy on random blocks merged in any
order; the quantile histogram within its stated bound; the spec field that selects it
and what it does to the version name; a sketch build against the exact one."""

import json

import numpy as np
import pytest

from aerohrl.datagen import build as B
from aerohrl.datagen import estimate as E
from aerohrl.datagen import lerobot_stats as LS
from aerohrl.datagen.lerobot_layout import STATS_PATH
from aerohrl.datagen.manifest import validate
from aerohrl.datagen.spec import STATS_SKETCH_EPISODES, DatasetSpec, version_name


def _data(rng, n):
    """Columns of several shapes and dtypes: offsets far from zero, heavy tails, discrete
    values, exact zeros of both signs, booleans and integers."""
    return {
        "gauss": (rng.standard_normal((n, 3)) * [1.0, 1e-3, 50.0] + [0.0, 9.81, -3e3]).astype(np.float32),
        "heavy": rng.standard_cauchy((n, 2)).astype(np.float32),
        "discrete": np.round(rng.standard_normal(n) * 2).astype(np.float32) * np.where(rng.random(n) < 0.5, -1, 1),
        "bool": rng.random(n) < 0.07,
        "ints": rng.integers(-50, 400, n),
    }


def _merged(a, cuts, order):
    parts = [LS.StreamStats.of_block(a[i:j]) for i, j in zip(cuts[:-1], cuts[1:])]
    parts = [parts[i] for i in order]
    while len(parts) > 1:  # a tree of merges, not only a running sum
        parts = [parts[i].merge(parts[i + 1]) if i + 1 < len(parts) else parts[i] for i in range(0, len(parts), 2)]
    return parts[0].result()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_count_min_max_exact_and_mean_std_to_float64_rounding_in_any_merge_order(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2_000, 30_000))
    cuts = np.unique(np.r_[0, rng.integers(0, n, 9), n])
    order = rng.permutation(len(cuts) - 1)
    for name, a in _data(rng, n).items():
        got = _merged(a, cuts, order)
        x = a.reshape(n, -1).astype(LS.stats_dtype(a.dtype)).astype(np.float64)
        assert got["count"] == [n], name
        np.testing.assert_array_equal(got["min"], x.min(axis=0), err_msg=name)
        np.testing.assert_array_equal(got["max"], x.max(axis=0), err_msg=name)
        scale = np.abs(x).max(axis=0) + 1e-300
        np.testing.assert_allclose(got["mean"], x.mean(axis=0), rtol=0, atol=1e-13 * scale.max(), err_msg=name)
        np.testing.assert_allclose(got["std"], x.std(axis=0), rtol=1e-11, atol=1e-13 * scale.max(), err_msg=name)


def _order_stat_bound(x_sorted, q):
    """The sketch's bound for quantile q of sorted values: the width of the buckets of the
    two order statistics numpy interpolates between."""
    n = len(x_sorted)
    lo = int(np.floor(q * (n - 1)))
    hi = min(lo + 1, n - 1)
    s = LS.StreamStats(1, x_sorted.dtype)
    return max(s.bucket_width(x_sorted[lo]), s.bucket_width(x_sorted[hi]))


@pytest.mark.parametrize("seed", [0, 1])
def test_quantiles_within_one_bucket_of_the_exact_ones(seed):
    rng = np.random.default_rng(seed)
    n = 40_000
    cuts = np.unique(np.r_[0, rng.integers(0, n, 6), n])
    for name, a in _data(rng, n).items():
        got = _merged(a, cuts, rng.permutation(len(cuts) - 1))
        exact = LS.global_stats(a)
        cols = a.reshape(n, -1).astype(LS.stats_dtype(a.dtype))
        for j in range(cols.shape[1]):
            xs = np.sort(cols[:, j])
            for key, q in zip(LS.QUANTILE_KEYS, LS.QUANTILES):
                err = abs(got[key][j] - exact[key][j])
                bound = _order_stat_bound(xs, q)
                assert err <= bound * (1 + 1e-12), (name, j, key, err, bound)
                if cols.dtype == np.float32:  # the stated relative bound
                    assert err <= 2.0 ** -(LS.SKETCH_BITS - 9) * max(abs(exact[key][j]), 2.0**-126), (name, j, key)
    zeros = LS.StreamStats.of_block(np.array([0.0, -0.0, 0.0, 0.0, 1.0], np.float32)).result()
    assert zeros["q10"] == [0.0] and zeros["q50"] == [0.0]  # the zero buckets give 0, not a subnormal
    flags = rng.random(10_000) < 0.3
    got, exact = LS.StreamStats.of_block(flags).result(), LS.global_stats(flags)
    for key in LS.QUANTILE_KEYS:  # 0/1 data: the zero bucket and the clip at max are exact
        assert got[key][0] == exact[key][0], key


def test_adding_in_place_is_merging_and_the_histogram_counts_every_value():
    """The writer's ``add`` (row groups in file order) gives what merging their summaries in
    that order gives, bit for bit; the histogram holds each value's bucket exactly once."""
    rng = np.random.default_rng(7)
    a = _data(rng, 20_000)["gauss"]
    cuts = [0, 5_000, 5_001, 12_345, 20_000]
    running = LS.StreamStats(3, np.float32)
    merged = LS.StreamStats.of_block(a[:0])
    for i, j in zip(cuts[:-1], cuts[1:]):
        running.add(a[i:j])
        merged = merged.merge(LS.StreamStats.of_block(a[i:j]))
    assert running.result() == merged.result()
    for j in range(3):
        keys, counts = np.unique(LS._sketch_keys(a[:, j] + np.float32(0)), return_counts=True)
        b, c = running._counts(j)
        np.testing.assert_array_equal(b, keys)
        np.testing.assert_array_equal(c, counts)
    with pytest.raises(ValueError, match="different features"):
        running.add(a[:, :2])


def test_empty_and_mismatched_summaries():
    s = LS.StreamStats.of_block(np.zeros((0, 2), np.float32))
    assert s.count == 0
    with pytest.raises(ValueError):
        s.result()
    with pytest.raises(ValueError, match="different features"):
        s.merge(LS.StreamStats.of_block(np.zeros((3, 4), np.float32)))


def test_the_spec_field_resolves_and_only_a_sketch_changes_the_version():
    small = DatasetSpec(goals=250)
    assert small.stats_mode == "exact" and "stats" not in small.to_dict()
    assert version_name(small) == "n250-s0-dbb240c0"  # the thesis's dataset keeps its name
    assert version_name(DatasetSpec(goals=250, stats="exact")) == version_name(small)
    sk = DatasetSpec(goals=250, stats="sketch")
    assert sk.stats_mode == "sketch" and sk.to_dict()["stats"] == "sketch" and version_name(sk) != version_name(small)
    assert sk.to_dict()["stats_revision"] == LS.SKETCH_REVISION  # the sketch's definition names its version
    big = DatasetSpec(goals=STATS_SKETCH_EPISODES)
    assert big.stats_mode == "sketch"
    assert version_name(big) == version_name(DatasetSpec(goals=STATS_SKETCH_EPISODES, stats="sketch"))
    below = DatasetSpec(goals=STATS_SKETCH_EPISODES - 1)
    assert below.stats_mode == "exact" and "stats" not in below.to_dict()
    exact_big = DatasetSpec(goals=STATS_SKETCH_EPISODES, stats="exact")
    assert "stats" not in exact_big.to_dict() and version_name(exact_big) != version_name(big)
    assert DatasetSpec(goals=STATS_SKETCH_EPISODES // 4, rollouts_per_goal=4, action_noise=(1.0, 0.5)).stats_mode == "sketch"
    sk_est, ex_est = (
        E.estimate(DatasetSpec(goals=1_000_000, action_noise=(1.0, 0.5))),
        E.estimate(DatasetSpec(goals=1_000_000, action_noise=(1.0, 0.5), stats="exact")),
    )
    assert sk_est.scratch == 0 and ex_est.scratch > 0 and sk_est.memory < ex_est.memory


def test_a_sketch_build_has_the_exact_builds_frames_and_stats_within_the_bound(tmp_path, monkeypatch):
    """Same spec, stats exact vs sketch: every data file and the per-episode statistics
    are byte-identical; stats.json has the same count/min/max, mean/std to float64
    rounding, and quantiles within the sketch's bound. The sketch's bytes do not depend
    on the rollout blocks (its summaries are per row group)."""
    kw = dict(goals=120, seed=4, action_noise=(1.0, 0.5))
    ex = B.build(DatasetSpec(**kw, stats="exact"), tmp_path / "ex", progress=False, log=lambda m: None)
    sk = B.build(DatasetSpec(**kw, stats="sketch"), tmp_path / "sk", progress=False, log=lambda m: None)
    assert validate(sk.path) == [] and not (sk.path / ".stats-spill").exists()
    for p in sorted((ex.path / "data").rglob("*.parquet")) + sorted((ex.path / "meta" / "episodes").rglob("*.parquet")):
        assert p.read_bytes() == (sk.path / p.relative_to(ex.path)).read_bytes(), p
    a, b = json.loads((ex.path / STATS_PATH).read_text()), json.loads((sk.path / STATS_PATH).read_text())
    assert list(a) == list(b)
    for feat in a:
        assert list(a[feat]) == list(b[feat]) == list(LS.STAT_KEYS)
        for s in ("min", "max", "count"):
            assert a[feat][s] == b[feat][s], (feat, s)
        np.testing.assert_allclose(b[feat]["mean"], a[feat]["mean"], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(b[feat]["std"], a[feat]["std"], rtol=1e-10, atol=1e-12)
        for key in LS.QUANTILE_KEYS:
            x, y = np.array(a[feat][key]), np.array(b[feat][key])
            assert np.all(np.abs(x - y) <= 2.0 ** -(LS.SKETCH_BITS - 9) * np.maximum(np.abs(x), 1.0)), (feat, key)
    clean = DatasetSpec(goals=120, seed=4, stats="sketch")  # clean: the flights do not depend on the blocks
    one = B.build(clean, tmp_path / "one", progress=False, log=lambda m: None)
    monkeypatch.setattr(B, "ROLLOUT_BLOCK", 17)
    again = B.build(clean, tmp_path / "blocks", progress=False, log=lambda m: None)
    assert (again.path / STATS_PATH).read_bytes() == (one.path / STATS_PATH).read_bytes()
