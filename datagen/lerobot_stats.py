"""Statistics of a LeRobot v3.0 dataset: ``meta/stats.json`` and the per-episode
``stats/<feature>/<stat>`` columns of the episodes parquet.

The keys, shapes and dtypes are those lerobot's ``compute_episode_stats`` produces
(vectors ``(n,)``, scalars ``(1,)``, ``count`` ``(1,)``; bool and float32 computed in
float32, integers in float64), for every feature including the index columns.
``min``/``max``/``mean``/``std``/``count`` are exact (float64 two-pass); quantiles are
exact order statistics with linear interpolation (numpy's default) rather than
lerobot's 5000-bin histogram approximation, and the dataset-level quantiles are those of
all frames rather than lerobot 0.6.1's count-weighted mean of per-episode quantiles.
Per-episode stats go into the episodes parquet as ``stats/<feature>/<stat>`` columns
(``list<double>``, ``count`` ``list<int64>``), which lerobot's dataset tools
(``delete_episodes``, ``split``) aggregate; its loader drops them.

Streamed dataset-level statistics (:class:`StreamStats`, the ``stats = "sketch"`` of a
spec): one pass over the frames in blocks, each block summarised on its own and the
summaries merged in any order, nothing read back. ``count``, ``min`` and ``max`` are
exact; ``mean`` and ``std`` are float64 (each block's by NumPy's pairwise sums over its
values in frame order, merged by Chan, Golub and LeVeque's pairwise update of count, mean
and the sum of squared deviations), exact up to float64 rounding (not bit for bit the
sorted-column sums of :func:`sorted_stats`). The quantiles come from a
histogram per dimension whose buckets are fixed in advance and cover every finite value:
the value's bits mapped to an order-preserving unsigned key, keeping its top
:data:`SKETCH_BITS` bits (sign, exponent and the leading mantissa bits), so no range has
to be known. The counts are exact and add across blocks. A quantile (linear
interpolation between the order statistics at ``floor(q (n - 1))`` and the next, as
numpy) takes each of the two order statistics from its bucket, interpolated linearly in
rank within the bucket and clipped to the exact ``[min, max]``; each lies in the same
bucket as the true order statistic, so the error is at most one bucket's width:
``|q_hat - q| <= 2**-(SKETCH_BITS - 9) * 2**floor(log2 |v|)`` for float32 values ``v``
near the quantile (relative ``2**-11`` with 20 bits), and ``2**-(SKETCH_BITS - 12)``
relative for features whose statistics dtype is float64 (integers).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
QUANTILE_KEYS = tuple(f"q{int(q * 100):02d}" for q in QUANTILES)
STAT_KEYS = ("min", "max", "mean", "std", "count") + QUANTILE_KEYS
# Block size (padded cells per dimension) for the per-episode order statistics.
_STATS_BLOCK_CELLS = 1 << 18


def stats_dtype(dt: np.dtype) -> np.dtype:
    """The dtype a feature's statistics are computed in: ``np.result_type(dt, float32)``,
    as lerobot's ``RunningQuantileStats`` (float32 for bool and float32, float64 for int64)."""
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


def global_stats(a: np.ndarray) -> dict:
    """Stats of one feature over all frames, shapes as lerobot's compute_episode_stats:
    the in-memory definition, which the streamed
    :func:`sorted_stats` / :func:`index_stats` reproduce bit for bit (tested)."""
    cols = a.reshape(len(a), -1)
    d = cols.shape[1]
    res: dict[str, np.ndarray] = {k: np.empty(d) for k in STAT_KEYS if k != "count"}
    sdt = stats_dtype(a.dtype)
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


def episode_stats(a: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> dict:
    """Per-episode stats of one feature: {stat: (E, d)} (count (E, 1))."""
    cols = a.reshape(len(a), -1)
    E, d = len(lengths), cols.shape[1]
    sdt = stats_dtype(a.dtype)
    out = {k: np.empty((E, d)) for k in STAT_KEYS if k != "count"}
    out["count"] = lengths.reshape(E, 1).astype(np.int64)
    if d >= _BY_LENGTH_DIMS:
        _episode_stats_by_length(cols.astype(sdt), starts, lengths, out)
        return out
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


# Vector features of at least this many dimensions take the per-length path of
# :func:`_episode_stats_by_length` (for fewer, its per-group overhead outweighs the padding).
_BY_LENGTH_DIMS = 4


def _episode_stats_by_length(x: np.ndarray, starts: np.ndarray, lengths: np.ndarray, out: dict) -> None:
    """:func:`episode_stats` into ``out`` for ``x`` (F, d) in its statistics dtype: the
    same values (each episode's mean and std by the same float64 reductions, its order
    statistics from a sort of its values) without padding. Episodes of one length are
    sorted together, each dimension's values contiguous."""
    E, d = len(lengths), x.shape[1]
    e = 0
    while e < E:  # mean and std: blocks of whole episodes, as episode_stats
        e1 = e + 1
        while e1 < E and int(starts[e1] + lengths[e1] - starts[e]) * d <= _STATS_BLOCK_CELLS:
            e1 += 1
        a0, b0 = int(starts[e]), int(starts[e1 - 1] + lengths[e1 - 1])
        L = lengths[e:e1]
        rel_starts = starts[e:e1] - a0
        x64 = x[a0:b0].astype(np.float64)
        mean = np.add.reduceat(x64, rel_starts, axis=0) / L[:, None]
        dev = x64 - np.repeat(mean, L, axis=0)
        out["mean"][e:e1] = mean
        out["std"][e:e1] = np.sqrt(np.add.reduceat(dev * dev, rel_starts, axis=0) / L[:, None])
        e = e1
    order = np.argsort(lengths, kind="stable")
    by_len = lengths[order]
    bounds = np.flatnonzero(np.r_[True, by_len[1:] != by_len[:-1], True])
    for g0, g1 in zip(bounds[:-1], bounds[1:]):
        n = int(by_len[g0])
        step = max(1, _STATS_BLOCK_CELLS // (n * d))
        for h0 in range(g0, g1, step):
            eps = order[h0 : min(g1, h0 + step)]
            v = np.ascontiguousarray(x[starts[eps][:, None] + np.arange(n)].transpose(0, 2, 1))  # (m, d, n)
            v.sort(axis=2)
            out["min"][eps] = v[:, :, 0]
            out["max"][eps] = v[:, :, n - 1]
            for key, val in zip(QUANTILE_KEYS, _interp_quantiles(v, n, 2)):
                out[key][eps] = val


def sorted_stats(get: Callable[[int, int], np.ndarray], n: int) -> dict:
    """min/max/mean/std/quantiles of one dimension from its ``n`` values in ascending
    order, read in pieces (``get(i0, i1)`` -> the values in their statistics dtype), bit
    for bit what :func:`global_stats` computes on the whole sorted column: NumPy's
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
        sq += np.add.reduce(d**2)
    out = {"min": np.float64(get(0, 1)[0]), "max": np.float64(get(n - 1, n)[0]), "mean": m, "std": np.sqrt(np.float64(sq) / n)}
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


def index_stats(k: str, lengths: np.ndarray, fps: int) -> dict:
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
    out = sorted_stats(get, F)
    out["count"] = F
    return {s: [out[s]] for s in STAT_KEYS}


# Order-preserving key bits kept per value in the quantile histogram (2**SKETCH_BITS
# buckets per dimension); see the module docstring for the error bound.
SKETCH_BITS = 20
# The sketch's definition, part of a sketch dataset's version name (spec.to_dict). 2: each
# row group's mean and squared deviations are summed over its values in frame order. 1
# summed them in sorted order (a sort per row group and dimension); the count, min, max
# and histogram, so the quantiles, are the same, the mean and std differ in the last bits.
SKETCH_REVISION = 2


def _sketch_keys(x: np.ndarray) -> np.ndarray:
    """The bucket of each value of ``x`` (float32 or float64): its bits as an unsigned
    integer, reordered so that the integers ascend with the values (negative values'
    bits inverted, positive values' sign bit set), top :data:`SKETCH_BITS` bits."""
    bits = 8 * x.dtype.itemsize
    u = x.view(np.uint32 if bits == 32 else np.uint64)
    sign = u >> np.array(bits - 1, u.dtype)
    mask = (np.array(0, u.dtype) - sign) | (np.array(1, u.dtype) << np.array(bits - 1, u.dtype))
    return ((u ^ mask) >> np.array(bits - SKETCH_BITS, u.dtype)).astype(np.int64)


def _bucket_edges(b: np.ndarray, dtype: np.dtype) -> tuple[np.ndarray, np.ndarray]:
    """The smallest and the largest value of buckets ``b`` (float64)."""
    bits = 8 * dtype.itemsize
    ut = np.uint32 if bits == 32 else np.uint64
    shift = ut(bits - SKETCH_BITS)
    lo_key = np.left_shift(b.astype(ut), shift)
    hi_key = lo_key | ((ut(1) << shift) - ut(1))

    def value(key):
        top = ut(1) << ut(bits - 1)
        neg = (key & top) == 0  # negative values: their keys are the inverted bits
        u = np.where(neg, ~key, key ^ top).astype(ut)
        return u.view(np.float32 if bits == 32 else np.float64).astype(np.float64)

    return value(lo_key), value(hi_key)


class StreamStats:
    """Mergeable dataset-level statistics of one feature (module docstring): :meth:`add`
    blocks of frames in place (or summarise one with :meth:`of_block`) and :meth:`merge`
    summaries in any order; :meth:`result` gives the ``stats.json`` entries. The
    histogram is dense, ``2**SKETCH_BITS`` counts per dimension, allocated by the first
    block; a block's values are counted into it directly (``np.add.at``, whose cost is
    linear in the block), so nothing is sorted."""

    def __init__(self, d: int, dtype: np.dtype):
        self.d, self.dtype = int(d), np.dtype(dtype)
        self.count = 0
        self.mean: np.ndarray = np.zeros(d)
        self.m2: np.ndarray = np.zeros(d)
        self.min: np.ndarray = np.full(d, np.inf)
        self.max: np.ndarray = np.full(d, -np.inf)
        self.hist: np.ndarray | None = None  # (d, 2**SKETCH_BITS) counts, int32 while they fit

    @classmethod
    def of_block(cls, a: np.ndarray) -> "StreamStats":
        """The summary of one block of frames ``a`` ((F,) or (F, d), any dtype the
        writer accepts), values taken in their statistics dtype (:func:`stats_dtype`)."""
        s = cls(int(np.prod(a.shape[1:], dtype=np.int64)), stats_dtype(a.dtype))
        return s.add(a)

    def add(self, a: np.ndarray) -> "StreamStats":
        """Add the frames of ``a`` (as :meth:`of_block`) in place; returns self. The
        block's count, mean and sum of squared deviations (float64, NumPy's pairwise sums
        over each dimension's values in frame order) are merged as :meth:`merge` does."""
        cols = a.reshape(len(a), int(np.prod(a.shape[1:], dtype=np.int64)))
        if cols.shape[1] != self.d or stats_dtype(a.dtype) != self.dtype:
            raise ValueError("merging statistics of different features")
        n = len(cols)
        if n == 0:
            return self
        xt = np.array(cols.T, dtype=self.dtype, order="C", copy=True)  # one dimension per row
        xt += 0  # -0.0 to +0.0: one bucket for zero
        mean = np.add.reduce(xt, axis=1, dtype=np.float64) / n
        dev = xt.astype(np.float64)
        dev -= mean[:, None]
        dev *= dev
        self._merge_moments(n, mean, np.add.reduce(dev, axis=1), xt.min(axis=1), xt.max(axis=1))
        del dev
        keys = _sketch_keys(xt)
        keys += (np.arange(self.d, dtype=np.int64) << SKETCH_BITS)[:, None]  # row j counts into hist[j]
        hist = self._dense()
        # np.add.at with an increment of the histogram's own dtype takes NumPy's fast path
        np.add.at(hist.reshape(-1), keys.reshape(-1), hist.dtype.type(1))
        return self

    def _merge_moments(self, n: int, mean: np.ndarray, m2: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
        """Chan, Golub and LeVeque's update of (count, mean, m2) by another set's, and the
        exact min and max."""
        total = self.count + n
        delta = mean - self.mean
        self.m2 = self.m2 + m2 + delta * delta * (self.count * n / total)
        self.mean = self.mean + delta * (n / total)
        self.count = total
        self.min, self.max = np.minimum(self.min, lo), np.maximum(self.max, hi)

    def _dense(self) -> np.ndarray:
        """The histogram, allocated on first use; widened to int64 before a count could
        pass int32's range."""
        if self.hist is None:
            self.hist = np.zeros((self.d, 1 << SKETCH_BITS), np.int32)
        elif self.hist.dtype == np.int32 and self.count >= np.iinfo(np.int32).max:
            self.hist = self.hist.astype(np.int64)
        return self.hist

    def merge(self, other: "StreamStats") -> "StreamStats":
        """Add ``other``'s frames to this summary (in place; returns self)."""
        if other.d != self.d or other.dtype != self.dtype:
            raise ValueError("merging statistics of different features")
        if other.count == 0:
            return self
        self._merge_moments(other.count, other.mean, other.m2, other.min, other.max)
        assert other.hist is not None  # a summary with frames has its histogram
        hist = self._dense()
        hist += other.hist.astype(hist.dtype, copy=False)
        return self

    def _counts(self, j: int) -> tuple[np.ndarray, np.ndarray]:
        """(buckets, counts) of dimension ``j``, ascending, nonzero only."""
        assert self.hist is not None
        b = np.flatnonzero(self.hist[j])
        return b, self.hist[j][b]

    def quantiles(self, j: int) -> dict[str, float]:
        """Dimension ``j``'s quantiles from the histogram (module docstring)."""
        b, c = self._counts(j)
        cum = np.cumsum(c, dtype=np.int64)
        lo_edge, hi_edge = _bucket_edges(b, self.dtype)
        n = self.count

        def order_stat(r: int) -> float:
            i = int(np.searchsorted(cum, r, side="right"))  # the bucket holding rank r (0-based)
            below = int(cum[i - 1]) if i else 0
            f = (r - below + 0.5) / int(c[i])  # rank within the bucket, as a fraction of it
            if lo_edge[i] <= 0.0 <= hi_edge[i]:  # the bucket of +0 or -0 (and subnormals): 0
                return 0.0
            v = lo_edge[i] + f * (hi_edge[i] - lo_edge[i])
            return float(min(max(v, self.min[j]), self.max[j]))

        out = {}
        for key, q in zip(QUANTILE_KEYS, QUANTILES):  # as _interp_quantiles
            pos = q * (n - 1)
            lo = int(np.floor(pos))
            hi = min(lo + 1, n - 1)
            vlo, vhi = order_stat(lo), order_stat(hi)
            out[key] = vlo + (vhi - vlo) * (pos - lo)
        return out

    def result(self) -> dict[str, list]:
        """``{stat: [per dimension]}`` in :data:`STAT_KEYS` order (``count`` ``[n]``)."""
        if self.count == 0:
            raise ValueError("no frames")
        out: dict[str, list] = {
            "min": self.min.tolist(),
            "max": self.max.tolist(),
            "mean": self.mean.tolist(),
            "std": np.sqrt(np.maximum(self.m2, 0.0) / self.count).tolist(),
            "count": [int(self.count)],
        }
        qs = [self.quantiles(j) for j in range(self.d)]
        for key in QUANTILE_KEYS:
            out[key] = [q[key] for q in qs]
        return {k: out[k] for k in STAT_KEYS}

    def bucket_width(self, v: float) -> float:
        """The width of the bucket holding the value ``v``: the sketch's error bound there."""
        b = _sketch_keys(np.array([v], self.dtype))
        lo, hi = _bucket_edges(b, self.dtype)
        return float(hi[0] - lo[0])


__all__ = [
    "QUANTILES",
    "QUANTILE_KEYS",
    "STAT_KEYS",
    "stats_dtype",
    "global_stats",
    "episode_stats",
    "sorted_stats",
    "index_stats",
    "SKETCH_BITS",
    "SKETCH_REVISION",
    "StreamStats",
]
