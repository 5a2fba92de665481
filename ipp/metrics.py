"""Table 2.1 metrics: summaries, the thesis's numbers, Markdown/CSV tables, the KL plot.

Per environment (computed by :meth:`aerohrl.ipp.env.SearchEnv.metrics` on the inner
map, in %): coverage = covered cells / cells; entropy reduction = ``1 - H_T / H_0``
(Eq. 2.4); search efficiency = targets found / targets.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import numpy as np

from aerohrl.atomic import atomic_path

METRICS = ("coverage", "entropy_reduction", "search_efficiency")

# thesis Table 2.1: (mean, std) of coverage, entropy reduction, search efficiency, %
THESIS_TABLE = {
    "greedy": ((40.94, 23.71), (41.76, 24.54), (54.37, 33.18)),
    "dp": ((57.84, 11.73), (60.23, 12.42), (80.24, 20.84)),
    "cmaes": ((52.10, 7.03), (55.81, 7.43), (75.52, 15.95)),
    "coverage": ((62.24, 0.28), (60.48, 1.48), (82.07, 10.53)),
    "prio_coverage": ((51.99, 10.10), (56.10, 10.56), (82.49, 18.11)),
    "rl_nolstm": ((57.72, 3.22), (61.26, 3.37), (85.73, 10.02)),
    "rl": ((60.20, 3.31), (63.75, 2.77), (88.52, 8.71)),
}


# thesis Table 2.2 (semantic feature detection, 30 environments), same layout
THESIS_TABLE_2_2 = {
    "greedy": ((14.21, 2.27), (2.57, 1.48), (6.53, 1.98)),
    "dp": ((67.83, 7.21), (30.08, 3.73), (53.03, 5.38)),
    "cmaes": ((33.64, 19.95), (8.72, 8.42), (20.54, 15.31)),
    "coverage": ((88.67, 0.0), (30.77, 4.43), (60.07, 2.47)),
    "prio_coverage": ((69.13, 11.75), (15.24, 4.91), (34.51, 8.27)),
    "rl_nolstm": ((74.88, 2.59), (32.16, 4.91), (59.56, 2.74)),
    "rl": ((83.78, 3.43), (34.24, 6.10), (63.61, 3.08)),
}


def thesis_table(kind: str = "targets") -> dict:
    return THESIS_TABLE_2_2 if kind == "semantic" else THESIS_TABLE


def summarise(per_env: dict[str, np.ndarray]) -> dict[str, tuple[float, float]]:
    return {k: (float(np.mean(per_env[k])), float(np.std(per_env[k]))) for k in METRICS}


def markdown_table(results: dict[str, dict], names: dict[str, str], kind: str = "targets") -> str:
    """``results[planner] = {"summary": ..., "ms_per_decision": ..., "n": ...}``; the
    thesis column is Table 2.1 (``kind="targets"``) or Table 2.2 (``"semantic"``)."""
    head = ("| planner | coverage % | entropy red. % | search eff. % | thesis cov / ent / eff "
            "| ms/decision | envs |\n|---|---|---|---|---|---|---|\n")
    rows = []
    for p, r in results.items():
        s = r["summary"]
        th = thesis_table(kind).get(p)
        ths = " / ".join(f"{m:.1f}±{sd:.1f}" for m, sd in th) if th else "—"
        rows.append(f"| {names.get(p, p)} | " + " | ".join(f"{s[k][0]:.1f} ± {s[k][1]:.1f}" for k in METRICS)
                    + f" | {ths} | {r['ms_per_decision']:.2f} | {r['n']} |")
    return head + "\n".join(rows) + "\n"


def paired_differences(results: dict[str, dict], baselines, metric: str = "search_efficiency"):
    """Paired differences of ``metric`` between every non-baseline row and every baseline
    row, over the environments both ran: ``{row: {baseline: (mean, standard error, n)}}``
    plus the best baseline by mean. Rows must share their ``env_ids``."""
    base = [p for p in results if p in baselines]
    others = [p for p in results if p not in baselines]
    if not base or not others:
        return {}, None
    best = max(base, key=lambda p: float(np.mean(results[p]["per_env"][metric])))
    out = {}
    for p in others:
        out[p] = {}
        for q in base:
            if not np.array_equal(results[p]["env_ids"], results[q]["env_ids"]):
                raise ValueError(f"{p} and {q} ran on different environments")
            d = results[p]["per_env"][metric] - results[q]["per_env"][metric]
            se = float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else float("nan")
            out[p][q] = (float(d.mean()), se, len(d))
    return out, best


def paired_markdown(results: dict[str, dict], names: dict[str, str], baselines) -> str:
    """Markdown table of :func:`paired_differences` of search efficiency ('' if there is
    nothing to pair)."""
    diffs, best = paired_differences(results, baselines)
    if not diffs:
        return ""
    base = [p for p in results if p in baselines]
    head = ("\nPaired search-efficiency difference (row − baseline, percentage points, mean ± "
            "standard error over the same environments); best baseline: "
            f"{names.get(best, best)}\n\n| planner | " + " | ".join(
                names.get(q, q) + (" (best)" if q == best else "") for q in base)
            + " |\n|---|" + "---|" * len(base) + "\n")
    rows = [f"| {names.get(p, p)} | " + " | ".join(f"{d[q][0]:+.2f} ± {d[q][1]:.2f}" for q in base)
            + " |" for p, d in diffs.items()]
    return head + "\n".join(rows) + "\n"


def summary_csv(results: dict[str, dict], kind: str = "targets") -> str:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["planner", "n_envs"] + [f"{k}_{s}" for k in METRICS for s in ("mean", "std")]
               + [f"thesis_{k}_{s}" for k in METRICS for s in ("mean", "std")] + ["ms_per_decision"])
    for p, r in results.items():
        th = thesis_table(kind).get(p)
        thv = [v for m in th for v in m] if th else [""] * 6
        w.writerow([p, r["n"]] + [f"{v:.4f}" for k in METRICS for v in r["summary"][k]]
                   + thv + [f"{r['ms_per_decision']:.4f}"])
    return buf.getvalue()


def per_env_csv(results: dict[str, dict]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["planner", "env", "kl"] + list(METRICS) + ["steps"])
    for p, r in results.items():
        e = r["per_env"]
        for i in range(len(e["kl"])):
            w.writerow([p, int(r["env_ids"][i]), f"{e['kl'][i]:.5f}"]
                       + [f"{e[k][i]:.3f}" for k in METRICS] + [int(e["steps"][i])])
    return buf.getvalue()


def write_atomic(path: str | os.PathLike, text: str) -> Path:
    with atomic_path(path) as tmp:
        with open(tmp, "w") as f:
            f.write(text)
    return Path(path)


def plot_kl(results: dict[str, dict], names: dict[str, str], path, bins: int = 5,
            xlabel: str = "KL(truth || prior) (nats), quantile bins") -> Path:
    """Fig. 2.4 analogue: search efficiency against KL(truth || prior), binned, per planner."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kl = np.concatenate([r["per_env"]["kl"] for r in results.values()])
    edges = np.quantile(kl, np.linspace(0, 1, bins + 1)) if len(kl) > bins else \
        np.linspace(kl.min(), kl.max() + 1e-9, bins + 1)
    edges[-1] += 1e-9
    fig, ax = plt.subplots(figsize=(6, 4))
    for j, (p, r) in enumerate(results.items()):
        k, eff = r["per_env"]["kl"], r["per_env"]["search_efficiency"]
        b = np.clip(np.digitize(k, edges) - 1, 0, bins - 1)
        centre = 0.5 * (edges[:-1] + edges[1:])
        mu = np.array([eff[b == i].mean() if (b == i).any() else np.nan for i in range(bins)])
        sd = np.array([eff[b == i].std() if (b == i).any() else np.nan for i in range(bins)])
        off = (j - len(results) / 2) * 0.01 * (edges[-1] - edges[0])
        ax.errorbar(centre + off, mu, yerr=sd, marker="o", capsize=3, label=names.get(p, p))
    ax.set_xlabel(xlabel)
    ax.set_ylabel("search efficiency (%)")
    ax.legend(fontsize=8)
    ax.set_title("Robustness to the prior (Fig. 2.4 analogue)")
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
    return path
