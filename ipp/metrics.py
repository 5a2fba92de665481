"""Table 2.1 metrics: summaries, the thesis's numbers, Markdown/CSV tables, the KL plot,
the metric-vs-budget plot.

Per environment (computed by :meth:`aerohrl.ipp.env.SearchEnv.metrics`, in %): coverage
= covered cells / cells and entropy reduction = ``1 - H_T / H_0`` (Eq. 2.4), each over
the inner 30 x 30 map (900 cells) and over the original code's padded 40 x 40 world
(1,600 cells, ``*_padded``; the thesis divides so); search efficiency = targets found /
targets. The thesis's numbers are printed beside the padded columns only (target
search); the flight the budget bought (primitives, path cells, seconds) beside them.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path
from typing import Collection

import numpy as np

from aerohrl.atomic import atomic_path

METRICS = ("coverage", "entropy_reduction", "search_efficiency")
PADDED = ("coverage_padded", "entropy_reduction_padded")
FLIGHT = ("primitives", "path_cells", "flight_s")
ALL_METRICS = METRICS + PADDED + FLIGHT

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
    """The thesis's reference figures (Table 2.1, or 2.2 for ``semantic``) by planner."""
    return THESIS_TABLE_2_2 if kind == "semantic" else THESIS_TABLE


def summarise(per_env: dict[str, np.ndarray]) -> dict[str, tuple[float, float]]:
    """(mean, std) of every metric present in ``per_env``."""
    return {k: (float(np.mean(per_env[k])), float(np.std(per_env[k]))) for k in ALL_METRICS if k in per_env}


def _ms(s, k):
    return f"{s[k][0]:.1f} ± {s[k][1]:.1f}"


def markdown_table(results: dict[str, dict], names: dict[str, str], kind: str = "targets") -> str:
    """``results[planner] = {"summary": ..., "ms_per_decision": ..., "n": ...}``.

    Target search (``kind="targets"``): coverage and entropy reduction over the inner
    900 cells and over the padded 1,600, the thesis's Table 2.1 value beside the padded
    one (its denominator), search efficiency beside the thesis's, and the flight bought
    (primitives, path cells, seconds). Semantic: Table 2.2 columns as before."""
    if kind == "semantic":
        head = (
            "| planner | coverage % | entropy red. % | search eff. % | thesis cov / ent / eff "
            "| ms/decision | envs |\n|---|---|---|---|---|---|---|\n"
        )
        rows = []
        for p, r in results.items():
            s = r["summary"]
            th = thesis_table(kind).get(p)
            ths = " / ".join(f"{m:.1f}±{sd:.1f}" for m, sd in th) if th else "—"
            rows.append(
                f"| {names.get(p, p)} | "
                + " | ".join(_ms(s, k) for k in METRICS)
                + f" | {ths} | {r['ms_per_decision']:.2f} | {r['n']} |"
            )
        return head + "\n".join(rows) + "\n"
    head = (
        "| planner | coverage % (900) | coverage % (1600) | thesis cov (1600) "
        "| entropy red. % (900) | entropy red. % (1600) | thesis ent (1600) "
        "| search eff. % | thesis eff | primitives | path cells | flight s "
        "| ms/decision | envs |\n|" + "---|" * 14 + "\n"
    )
    rows = []
    for p, r in results.items():
        s = r["summary"]
        th = thesis_table(kind).get(p)
        t = [f"{m:.1f}±{sd:.1f}" for m, sd in th] if th else ["—"] * 3
        fl = [f"{s[k][0]:.1f}" if k in s else "—" for k in FLIGHT]
        rows.append(
            f"| {names.get(p, p)} | {_ms(s, 'coverage')} | {_ms(s, 'coverage_padded')} "
            f"| {t[0]} | {_ms(s, 'entropy_reduction')} "
            f"| {_ms(s, 'entropy_reduction_padded')} | {t[1]} "
            f"| {_ms(s, 'search_efficiency')} | {t[2]} | " + " | ".join(fl) + f" | {r['ms_per_decision']:.2f} | {r['n']} |"
        )
    return head + "\n".join(rows) + "\n"


def _standard_error(d: np.ndarray) -> float:
    """Standard error of the mean of paired differences ``d`` (nan below 2 worlds)."""
    return float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else float("nan")


def _best(results: dict[str, dict], rows: list[str], metric: str) -> str:
    """The row of ``rows`` with the highest mean ``metric`` (the best baseline)."""
    return max(rows, key=lambda p: float(np.mean(results[p]["per_env"][metric])))


def paired_differences(
    results: dict[str, dict], baselines: Collection[str], metric: str = "search_efficiency"
) -> tuple[dict[str, dict[str, tuple[float, float, int]]], str | None]:
    """Paired differences of ``metric`` between every non-baseline row and every baseline
    row, over the environments both ran: ``{row: {baseline: (mean, standard error, n)}}``
    plus the best baseline by mean. Rows must share their ``env_ids``."""
    base = [p for p in results if p in baselines]
    others = [p for p in results if p not in baselines]
    if not base or not others:
        return {}, None
    best = _best(results, base, metric)
    out: dict[str, dict[str, tuple[float, float, int]]] = {}
    for p in others:
        out[p] = {}
        for q in base:
            if not np.array_equal(results[p]["env_ids"], results[q]["env_ids"]):
                raise ValueError(f"{p} and {q} ran on different environments")
            d = results[p]["per_env"][metric] - results[q]["per_env"][metric]
            out[p][q] = (float(d.mean()), _standard_error(d), len(d))
    return out, best


def paired_markdown(results: dict[str, dict], names: dict[str, str], baselines: Collection[str]) -> str:
    """Markdown table of :func:`paired_differences` of search efficiency ('' if there is
    nothing to pair)."""
    diffs, best = paired_differences(results, baselines)
    if not diffs:
        return ""
    assert best is not None  # paired_differences names the best baseline whenever it pairs rows
    base = [p for p in results if p in baselines]
    head = (
        "\nPaired search-efficiency difference (row − baseline, percentage points, mean ± "
        "standard error over the same environments); best baseline: "
        f"{names.get(best, best)}\n\n| planner | "
        + " | ".join(names.get(q, q) + (" (best)" if q == best else "") for q in base)
        + " |\n|---|"
        + "---|" * len(base)
        + "\n"
    )
    rows = [
        f"| {names.get(p, p)} | " + " | ".join(f"{d[q][0]:+.2f} ± {d[q][1]:.2f}" for q in base) + " |" for p, d in diffs.items()
    ]
    return head + "\n".join(rows) + "\n"


def seeds_markdown(
    results: dict[str, dict],
    names: dict[str, str],
    groups: dict[str, list[str]],
    baselines: Collection[str],
    metric: str = "search_efficiency",
) -> str:
    """A learned recipe as a claim over seeds ('' if no group has 2 or more runs).

    ``groups`` maps a recipe's name to its rows in ``results`` (one trained run each).
    Per recipe: the per-seed means, their mean ± std over seeds (ddof 1), each seed's
    paired difference to the best baseline, and the seed-averaged policy (per world, the
    mean over seeds) paired with **every** baseline: mean ± standard error, worlds better
    / worse, paired t-test p (scipy). The last is what "ahead with paired significance
    over the same worlds" means for a recipe rather than for one lucky seed."""
    base = [p for p in results if p in baselines]
    groups = {g: ks for g, ks in groups.items() if len(ks) >= 2}
    if not base or not groups:
        return ""
    best = _best(results, base, metric)
    ids = results[best]["env_ids"]
    lines = [
        "\nOver seeds (search efficiency %; seed mean: per world, the mean over the "
        "seeds' runs, paired with each baseline: mean ± s.e., worlds better / worse, "
        "paired t-test p)\n",
        "| recipe | seeds | per seed | mean ± std over seeds | per seed − best baseline ("
        + names.get(best, best)
        + ") | "
        + " | ".join(f"seed mean − {names.get(q, q)}" for q in base)
        + " |",
        "|---|---|---|---|---|" + "---|" * len(base),
    ]
    for g, ks in groups.items():
        for k in ks:
            if not np.array_equal(results[k]["env_ids"], ids):
                raise ValueError(f"{k} and {best} ran on different environments")
        per = np.array([results[k]["per_env"][metric] for k in ks])  # (seeds, worlds)
        means = per.mean(1)
        cells = []
        for q in base:  # same env_ids (checked above): pair the arrays as they are
            c = _paired_stats(per.mean(0), results[q]["per_env"][metric])
            cells.append(f"{c['diff']:+.2f} ± {c['se']:.2f} ({c['better']}/{c['worse']}, p = {c['p_t']:.3g})")
        d_best = means - float(np.mean(results[best]["per_env"][metric]))
        lines.append(
            f"| {g} | {len(ks)} | "
            + " / ".join(f"{m:.1f}" for m in means)
            + f" | {means.mean():.1f} ± {means.std(ddof=1):.1f} | "
            + " / ".join(f"{d:+.2f}" for d in d_best)
            + " | "
            + " | ".join(cells)
            + " |"
        )
    return "\n".join(lines) + "\n"


def summary_csv(results: dict[str, dict], kind: str = "targets") -> str:
    """Per planner: the number of worlds and each metric's mean and std, as CSV."""
    buf = io.StringIO()
    w = csv.writer(buf)
    keys = [k for k in ALL_METRICS if all(k in r["summary"] for r in results.values())]
    w.writerow(
        ["planner", "n_envs"]
        + [f"{k}_{s}" for k in keys for s in ("mean", "std")]
        + [
            f"thesis_{k}{'_padded' if kind == 'targets' and k != 'search_efficiency' else ''}_{s}"
            for k in METRICS
            for s in ("mean", "std")
        ]
        + ["ms_per_decision"]
    )
    for p, r in results.items():
        th = thesis_table(kind).get(p)
        thv = [v for m in th for v in m] if th else [""] * 6
        w.writerow([p, r["n"]] + [f"{v:.4f}" for k in keys for v in r["summary"][k]] + thv + [f"{r['ms_per_decision']:.4f}"])
    return buf.getvalue()


def per_env_csv(results: dict[str, dict]) -> str:
    """Per planner and world: KL(truth || prior), every metric and the steps, as CSV."""
    buf = io.StringIO()
    w = csv.writer(buf)
    first = next(iter(results.values()))["per_env"]
    keys = [k for k in ALL_METRICS if k in first]
    w.writerow(["planner", "env", "kl"] + keys + ["steps"])
    for p, r in results.items():
        e = r["per_env"]
        for i in range(len(e["kl"])):
            w.writerow([p, int(r["env_ids"][i]), f"{e['kl'][i]:.5f}"] + [f"{e[k][i]:.3f}" for k in keys] + [int(e["steps"][i])])
    return buf.getvalue()


def budget_markdown(sweep: dict, names: dict[str, str], kind: str = "targets") -> str:
    """One row per (planner, budget) of a ``bench --budgets`` sweep: the metrics (both
    denominators on target search) and the flight each budget bought."""
    order = ("coverage", "coverage_padded", "entropy_reduction", "entropy_reduction_padded", "search_efficiency") + FLIGHT
    keys = [k for k in order if all(k in r["summary"] for r in sweep.values())]
    head = "| planner | budget | " + " | ".join(_LABEL.get(k, k) for k in keys) + " | envs |\n|" + "---|" * (len(keys) + 3) + "\n"
    rows = [
        f"| {names.get(p, p)} | {b:g} | "
        + " | ".join(f"{r['summary'][k][0]:.1f} ± {r['summary'][k][1]:.1f}" for k in keys)
        + f" | {r['n']} |"
        for (p, b), r in sweep.items()
    ]
    return head + "\n".join(rows) + "\n"


_LABEL = {
    "coverage": "coverage % (900)",
    "coverage_padded": "coverage % (1600)",
    "entropy_reduction": "entropy red. % (900)",
    "entropy_reduction_padded": "entropy red. % (1600)",
    "search_efficiency": "search eff. %",
    "primitives": "primitives",
    "path_cells": "path cells",
    "flight_s": "flight s",
}


def budget_csv(sweep: dict) -> str:
    """Per planner and budget of a budget sweep: each metric's mean and std, as CSV."""
    buf = io.StringIO()
    w = csv.writer(buf)
    keys = [k for k in ALL_METRICS if all(k in r["summary"] for r in sweep.values())]
    w.writerow(["planner", "budget", "n_envs"] + [f"{k}_{s}" for k in keys for s in ("mean", "std")])
    for (p, b), r in sweep.items():
        w.writerow([p, f"{b:g}", r["n"]] + [f"{v:.4f}" for k in keys for v in r["summary"][k]])
    return buf.getvalue()


def budget_envs_csv(sweep: dict, names: dict[str, str]) -> str:
    """Per planner, budget and world of a budget sweep: the row's label, KL(truth || prior)
    (it identifies the world), every metric and the steps, as CSV (what pairs the worlds of
    separate sweeps)."""
    buf = io.StringIO()
    w = csv.writer(buf)
    keys = [k for k in ALL_METRICS if all(k in r["per_env"] for r in sweep.values())]
    w.writerow(["planner", "label", "budget", "env", "kl"] + keys + ["steps"])
    for (p, b), r in sweep.items():
        e = r["per_env"]
        for i in range(len(e["kl"])):
            w.writerow(
                [p, names.get(p, p), f"{b:g}", int(r["env_ids"][i]), f"{e['kl'][i]:.5f}"]
                + [f"{e[k][i]:.3f}" for k in keys]
                + [int(e["steps"][i])]
            )
    return buf.getvalue()


def plot_budgets(sweep: dict, names: dict[str, str], path: str | Path, kind: str = "targets") -> Path:
    """Each metric against the budget (mean ± standard error over the worlds), one line per
    planner; the thesis's Table 2.1 value as a dotted line of the same colour on the
    panels of its denominator (padded coverage / entropy, search efficiency)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = (
        ["coverage", "coverage_padded", "entropy_reduction", "entropy_reduction_padded", "search_efficiency", "flight_s"]
        if kind == "targets"
        else ["coverage", "entropy_reduction", "search_efficiency", "flight_s"]
    )
    thesis_of = {"coverage_padded": 0, "entropy_reduction_padded": 1, "search_efficiency": 2} if kind == "targets" else {}
    planners = list(dict.fromkeys(p for p, _ in sweep))
    fig, axes = plt.subplots(2, (len(panels) + 1) // 2, figsize=(4.2 * ((len(panels) + 1) // 2), 7))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, k in zip(axes.ravel(), panels):
        for j, p in enumerate(planners):
            bs = sorted(b for q, b in sweep if q == p)
            mu = [float(np.mean(sweep[(p, b)]["per_env"][k])) for b in bs]
            se = [float(np.std(sweep[(p, b)]["per_env"][k]) / np.sqrt(max(sweep[(p, b)]["n"], 1))) for b in bs]
            c = colours[j % len(colours)]
            ax.errorbar(bs, mu, yerr=se, marker="o", ms=4, capsize=2, color=c, label=names.get(p, p))
            th = thesis_table(kind).get(p)
            if k in thesis_of and th:
                ax.axhline(th[thesis_of[k]][0], color=c, ls=":", lw=1)
        ax.set_xlabel("budget (cost units: rho*T + int |jerk|^2)")
        ax.set_ylabel(_LABEL.get(k, k).replace("flight s", "flight time (s)"))
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(panels) :]:
        ax.axis("off")
    axes.ravel()[0].legend(fontsize=7)
    fig.suptitle(
        "Metric vs budget (dotted: thesis Table 2.1 at the original budget)" if kind == "targets" else "Metric vs budget"
    )
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)
    return path


def tracking_summary(tt: np.ndarray) -> dict[str, float]:
    """Per-primitive tracking errors (rows: world, max m, RMS m, duration s) summarised:
    mean / 95th percentile / maximum of the per-primitive maximum error, mean and maximum
    of the per-primitive RMS error, in metres, and the number of primitives."""
    if len(tt) == 0:
        return {"n": 0}
    return {
        "n": int(len(tt)),
        "max_mean": float(tt[:, 1].mean()),
        "max_p95": float(np.percentile(tt[:, 1], 95)),
        "max_max": float(tt[:, 1].max()),
        "rms_mean": float(tt[:, 2].mean()),
        "rms_max": float(tt[:, 2].max()),
    }


def execution_markdown(by_mode: dict[str, dict], names: dict[str, str]) -> str:
    """Ideal vs flown (vs skill-flown) execution, per planner: Table 2.1's metrics in each
    mode, the paired difference of search efficiency to the first mode over the same
    worlds (mean ± standard error), and per non-ideal mode the per-primitive tracking
    error (mm; skill: distance to the primitive's path) and the skill legs' success."""
    modes = list(by_mode)
    base = modes[0]
    flown = [m for m in modes if m != "ideal"]
    cols = (
        [f"{k} ({m})" for m in modes for k in ("cov. % (1600)", "ent. red. %", "search eff. %")]
        + [f"{m} − {base} (search eff., paired)" for m in modes[1:]]
        + [c for m in flown for c in (f"{m}: tracking max mm (mean / p95 / max)", f"{m}: tracking RMS mm")]
        + (["skill legs: near / strict success, s per leg"] if "skill" in modes else [])
    )
    head = "| planner | " + " | ".join(cols) + " |\n|" + "---|" * (len(cols) + 1) + "\n"
    rows = []
    for p in by_mode[base]:
        cells = []
        for m in modes:
            s = by_mode[m][p]["summary"]
            cells += [_ms(s, "coverage_padded"), _ms(s, "entropy_reduction"), _ms(s, "search_efficiency")]
        for m in modes[1:]:
            a, b = by_mode[m][p], by_mode[base][p]
            if not np.array_equal(a["env_ids"], b["env_ids"]):
                raise ValueError("execution modes ran on different worlds")
            d = a["per_env"]["search_efficiency"] - b["per_env"]["search_efficiency"]
            se = float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else float("nan")
            cells.append(f"{d.mean():+.2f} ± {se:.2f}")
        for m in flown:
            r = by_mode[m][p]
            if "tracking" in r:
                t = tracking_summary(r["tracking"])
                cells += [
                    f"{1e3 * t['max_mean']:.1f} / {1e3 * t['max_p95']:.1f} / {1e3 * t['max_max']:.1f} ({t['n']} primitives)",
                    f"{1e3 * t['rms_mean']:.1f}",
                ]
            else:
                cells += ["—", "—"]
        if "skill" in modes:
            lg = by_mode["skill"][p].get("legs", np.zeros((0, 3)))
            cells.append(
                f"{100 * lg[:, 1].mean():.1f} % / {100 * lg[:, 0].mean():.1f} %, {lg[:, 2].mean():.2f} s ({len(lg)} legs)"
                if len(lg)
                else "—"
            )
        rows.append(f"| {names.get(p, p)} | " + " | ".join(cells) + " |")
    return head + "\n".join(rows) + "\n"


def write_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (temporary, rename); returns the path."""
    with atomic_path(path) as tmp:
        with open(tmp, "w") as f:
            f.write(text)
    return Path(path)


def plot_kl(
    results: dict[str, dict],
    names: dict[str, str],
    path: str | Path,
    bins: int = 5,
    xlabel: str = "KL(truth || prior) (nats), quantile bins",
) -> Path:
    """Fig. 2.4 analogue: search efficiency against KL(truth || prior), binned, per planner."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kl = np.concatenate([r["per_env"]["kl"] for r in results.values()])
    edges = np.quantile(kl, np.linspace(0, 1, bins + 1)) if len(kl) > bins else np.linspace(kl.min(), kl.max() + 1e-9, bins + 1)
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


def read_per_env(path: str | Path, metric: str = "search_efficiency") -> tuple[str, dict[int, float], dict[int, str]]:
    """One planner's per-world ``metric`` from a bench's ``ipp_bench_envs.csv`` (or the
    bench folder holding it): ``(planner, {env id: value}, {env id: KL(truth || prior)})``,
    the KL as written (it identifies the world: the same id under another ``--seed`` is
    another world). UserError if the file is missing, lacks the metric or holds more than
    one planner."""
    from aerohrl.errors import UserError

    f = Path(path)
    f = f / "ipp_bench_envs.csv" if f.is_dir() else f
    try:
        with f.open(newline="") as fh:
            rows = list(csv.DictReader(fh))
    except OSError:
        raise UserError(f"no bench results at {path} (run `aerohrl ipp bench -o DIR` first)") from None
    for col in ("planner", "env", metric):
        if not rows or col not in rows[0]:
            raise UserError(f"{f} has no column {col!r}")
    planners = sorted({r["planner"] for r in rows})
    if len(planners) != 1:
        raise UserError(f"{f} holds {len(planners)} planners ({', '.join(planners)}); compare benches of one planner each")
    return planners[0], {int(r["env"]): float(r[metric]) for r in rows}, {int(r["env"]): r.get("kl", "") for r in rows}


def paired_comparison(a: dict[int, float], b: dict[int, float]) -> dict:
    """``a - b`` paired over the worlds both ran: mean, standard error, n, worlds better /
    worse, and the paired t-test's and Wilcoxon signed-rank test's p-values (scipy)."""
    ids = sorted(set(a) & set(b))
    if len(ids) < 2:
        raise ValueError("fewer than 2 worlds in common")
    return _paired_stats(np.array([a[i] for i in ids]), np.array([b[i] for i in ids]))


def _paired_stats(x: np.ndarray, y: np.ndarray) -> dict:
    """:func:`paired_comparison` of two arrays already aligned world by world."""
    from scipy import stats

    d = x - y
    nz = d[d != 0]
    return {
        "diff": float(d.mean()),
        "se": _standard_error(d),
        "n": len(d),
        "better": int((d > 0).sum()),
        "worse": int((d < 0).sum()),
        "p_t": float(stats.ttest_rel(x, y).pvalue) if d.std() > 0 else 1.0,
        "p_wilcoxon": float(stats.wilcoxon(nz).pvalue) if len(nz) else 1.0,
    }
