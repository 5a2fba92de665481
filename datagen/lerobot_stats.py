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


__all__ = [
    "QUANTILES",
    "QUANTILE_KEYS",
    "STAT_KEYS",
    "stats_dtype",
    "global_stats",
    "episode_stats",
    "sorted_stats",
    "index_stats",
]
