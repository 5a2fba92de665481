"""The learning curve of an ``aerohrl ipp train`` run (``aerohrl ipp curve RUN``): its
iteration log ``RUN/metrics.jsonl`` read strictly, and ``learning_curve.png`` drawn from
it (search efficiency, return and per-term returns per iteration, the BC/PPO boundary).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from aerohrl import atomic
from aerohrl.errors import UserError

from .env import TERMS


def read_metrics(run_dir: str | Path) -> list[dict]:
    """The iteration log of an ``ipp train`` run (``RUN/metrics.jsonl``), in order; a one-line
    UserError when it is missing, malformed or empty."""
    p = Path(run_dir) / "metrics.jsonl"
    if not p.is_file():
        raise UserError(f"{run_dir}: no metrics.jsonl (not a training run directory)")
    out = []
    for i, ln in enumerate(p.read_text().splitlines(), 1):
        if not ln.strip():
            continue
        try:
            d = json.loads(ln)
            int(d["iteration"]), float(d["search_efficiency"]), float(d["return"])
        except (ValueError, KeyError, TypeError):
            raise UserError(f"{p}:{i}: not a metrics line") from None
        out.append(d)
    if not out:
        raise UserError(f"{p}: no iterations logged yet")
    return out


def plot_learning_curve(run_dir: str | Path, out: str | Path | None = None) -> Path:
    """``learning_curve.png`` (or ``out``): search efficiency and return per iteration on
    the training worlds (raw and a 10-iteration running mean), the greedy policy's
    validation search efficiency where logged, per-term returns, and the BC/PPO
    boundary."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = read_metrics(run_dir)
    it = np.array([r["iteration"] for r in rows])
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))

    def smooth(y, k=10):
        y = np.asarray(y, float)
        c = np.cumsum(np.insert(y, 0, 0.0))
        n = np.minimum(np.arange(1, len(y) + 1), k)
        return (c[1:] - c[np.arange(len(y)) + 1 - n]) / n

    eff = [r["search_efficiency"] for r in rows]
    ax = axes[0]
    ax.plot(it, eff, color="C0", alpha=0.3, lw=0.8)
    ax.plot(it, smooth(eff), color="C0", label="train worlds (sampled policy)")
    vi = [(r["iteration"], r["val_search_efficiency"]) for r in rows if "val_search_efficiency" in r]
    if vi:
        ax.plot(*zip(*vi), "o-", color="C3", ms=3, label="validation (greedy, centre start)")
    ax.set_title("search efficiency %")
    ax.legend(fontsize=8)
    ret = [r["return"] for r in rows]
    axes[1].plot(it, ret, color="C1", alpha=0.3, lw=0.8)
    axes[1].plot(it, smooth(ret), color="C1")
    axes[1].set_title("episode return")
    for k in TERMS:
        axes[2].plot(it, smooth([r.get(f"r_{k}", np.nan) for r in rows]), label=k)
    axes[2].set_title("return per reward term (running mean)")
    axes[2].legend(fontsize=8)
    n_bc = sum(r.get("phase") == "bc" for r in rows)
    split = 0 < n_bc < len(rows)
    for ax in axes:
        ax.set_xlabel("iteration")
        if split:
            ax.axvline(n_bc + 0.5, color="k", ls=":", lw=1)
    if split:
        axes[0].text(n_bc + 0.5, axes[0].get_ylim()[0], " BC | PPO", fontsize=8, va="bottom")
    fig.suptitle(f"{Path(run_dir).name}: {len(rows)} iterations ({n_bc} DAgger), {rows[-1].get('time_s', 0) / 60:.1f} min")
    fig.tight_layout()
    path = Path(out) if out is not None else Path(run_dir) / "learning_curve.png"
    try:
        atomic.save_figure(fig, path, dpi=90)
    finally:
        plt.close(fig)
    return path
