"""How far a dataset's streamed quantiles (``stats = "sketch"``) are from the exact ones.

    python bench/bench_stats_sketch.py DATASET        # a dataset built with the sketch

Reads one feature at a time back from the data files (the frames in memory for that
feature), computes the exact statistics (:func:`aerohrl.datagen.lerobot_stats.global_stats`,
what ``stats = "exact"`` writes) and prints, per quantile over every dimension of every
feature, the largest error of ``meta/stats.json``, the largest error relative to the
value and to the stated bound (the width of the buckets of the two order statistics),
and the largest mean and std difference. A ratio to the bound above 1 would break the
sketch's guarantee.
"""

import argparse
import json
from pathlib import Path

import numpy as np

from aerohrl.datagen import lerobot_stats as LS
from aerohrl.datagen.lerobot_layout import INDEX_FEATURES, STATS_PATH
from aerohrl.datagen.lerobot_reader import read_columns, read_info


def main() -> None:
    """Print the sketch's errors against the exact statistics of ``DATASET``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path)
    a = ap.parse_args()
    stats = json.loads((a.dataset / STATS_PATH).read_text())
    feats = [k for k in read_info(a.dataset)["features"] if k not in INDEX_FEATURES]
    worst = {k: [0.0, 0.0, 0.0] for k in LS.QUANTILE_KEYS}  # abs, relative, / bound
    mean_err = std_err = 0.0
    frames = 0
    for feat in feats:
        col = read_columns(a.dataset, [feat])[feat]
        frames = len(col)
        exact = LS.global_stats(col)
        cols = col.reshape(len(col), -1).astype(LS.stats_dtype(col.dtype))
        del col
        for j in range(cols.shape[1]):
            xs = np.sort(cols[:, j])
            n = len(xs)
            probe = LS.StreamStats(1, xs.dtype)
            for key, q in zip(LS.QUANTILE_KEYS, LS.QUANTILES):
                err = abs(stats[feat][key][j] - exact[key][j])
                lo = int(np.floor(q * (n - 1)))
                bound = max(probe.bucket_width(xs[lo]), probe.bucket_width(xs[min(lo + 1, n - 1)]))
                w = worst[key]
                w[0] = max(w[0], err)
                w[1] = max(w[1], err / max(abs(exact[key][j]), 1e-30))
                w[2] = max(w[2], err / bound if bound > 0 else (0.0 if err == 0 else np.inf))
            scale = max(abs(exact["mean"][j]), exact["std"][j], 1e-30)
            mean_err = max(mean_err, abs(stats[feat]["mean"][j] - exact["mean"][j]) / scale)
            std_err = max(std_err, abs(stats[feat]["std"][j] - exact["std"][j]) / max(exact["std"][j], 1e-30))
            assert stats[feat]["min"][j] == exact["min"][j] and stats[feat]["max"][j] == exact["max"][j], (feat, j)
        assert stats[feat]["count"] == [frames]
    print(f"{a.dataset}: {frames:,} frames, {len(feats)} features; min, max and count equal the exact ones")
    print(f"{'quantile':>8} {'max abs error':>14} {'max rel error':>14} {'max error / bound':>18}")
    for key, (ab, rel, ratio) in worst.items():
        print(f"{key:>8} {ab:>14.3g} {rel:>14.3g} {ratio:>18.3f}")
    print(f"mean: max |error| / max(|mean|, std) {mean_err:.3g}; std: max relative error {std_err:.3g}")


if __name__ == "__main__":
    main()
