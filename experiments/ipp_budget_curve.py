"""The IPP budget curve: learned planners over training seeds beside the baselines, at every
budget of ``aerohrl ipp bench --budgets`` sweeps run on the same test worlds.

Baseline sweeps hold the baselines (``--all``, with or without the learned runs as
``--run``; ``--planner detect``, the teacher);
a learned recipe is several rows (one per training seed), from that sweep or from others
(``--belief`` sweeps: one per belief seed). Per budget it writes, for search efficiency:
each baseline (mean ± standard error over the worlds), each recipe per seed and as
mean ± std over seeds, and the seed mean (per world, the mean over the seeds' rows) paired
with DP-IPP and with the budget's best baseline (mean ± standard error, worlds better /
worse, paired t-test p). The figure plots search efficiency against the budget.

    python experiments/ipp_budget_curve.py --baselines runs/curve/all runs/curve/detect \\
        --recipe "Imitation of detect (DAgger)" runs/curve/all:rl runs/curve/all:rl_2 ... \\
        --recipe "detect over the learned belief" runs/curve/belief-s7:detect ... \\
        --page docs/results/PAGE.md --figure docs/results/figures/PAGE.png
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from aerohrl.errors import UserError

METRIC = "search_efficiency"


def read_sweep(folder: str) -> dict[tuple[str, float], dict]:
    """``(planner, budget) -> {"label", "worlds": {(env, kl): value}}`` of one sweep's
    ``ipp_budgets_envs.csv``; UserError when it is missing."""
    f = Path(folder) / "ipp_budgets_envs.csv"
    if not f.is_file():
        raise UserError(f"{folder}: no ipp_budgets_envs.csv (run `aerohrl ipp bench --budgets ... -o {folder}`)")
    out: dict[tuple[str, float], dict] = {}
    with f.open(newline="") as fh:
        for r in csv.DictReader(fh):
            key = (r["planner"], float(r["budget"]))
            row = out.setdefault(key, {"label": r["label"], "worlds": {}})
            row["worlds"][(int(r["env"]), r["kl"])] = float(r[METRIC])
    return out


def aligned(rows: list[dict]) -> tuple[list, np.ndarray]:
    """The worlds every row ran, and the (rows, worlds) values; UserError if they differ."""
    worlds = sorted(rows[0]["worlds"])
    for r in rows[1:]:
        if sorted(r["worlds"]) != worlds:
            raise UserError(f"{r['label']!r} ran other worlds than {rows[0]['label']!r}: sweep them on the same suite")
    return worlds, np.array([[r["worlds"][w] for w in worlds] for r in rows])


def paired(x: np.ndarray, y: np.ndarray) -> str:
    """``x - y`` over aligned worlds: mean ± s.e. (better / worse, paired t-test p)."""
    from aerohrl.ipp.metrics import paired_comparison

    c = paired_comparison(dict(enumerate(x)), dict(enumerate(y)))
    return f"{c['diff']:+.2f} ± {c['se']:.2f} ({c['better']}/{c['worse']}, p = {c['p_t']:.2g})"


def build(baselines: list[str], recipes: list[list[str]]) -> tuple[str, dict]:
    """The page's tables (Markdown) and the curve data ``{name: {budget: (mean, spread)}}``."""
    from aerohrl.ipp.baselines import PLANNERS, THESIS_NAMES

    sweeps = {f: read_sweep(f) for f in baselines}
    base = {k: v for f in baselines for k, v in sweeps[f].items()}
    budgets = sorted({b for _, b in base})
    rec: dict[str, list[tuple[str, str]]] = {}
    for spec in recipes:
        name, given = spec[0], spec[1:]
        if len(given) < 1:
            raise UserError(f"--recipe {name!r}: give its rows as SWEEP:PLANNER")
        rows_of: list[tuple[str, str]] = []
        rec[name] = rows_of
        for m in given:
            folder, sep, planner = m.rpartition(":")
            if not sep or not folder:
                raise UserError(f"--recipe {name!r}: {m!r} is not SWEEP:PLANNER")
            sweeps.setdefault(folder, read_sweep(folder))
            rows_of.append((folder, planner))
    curves: dict[str, dict[float, tuple[float, float]]] = defaultdict(dict)
    md = []
    for b in budgets:
        bl = [p for p in PLANNERS + ("detect",) if (p, b) in base]
        if "dp" not in bl:
            raise UserError(f"no DP-IPP row at budget {b:g} in {', '.join(baselines)} (sweep with --all)")
        rows = [base[(p, b)] for p in bl]
        worlds, vals = aligned(rows)
        by = dict(zip(bl, vals))
        best = max((p for p in bl if p in PLANNERS), key=lambda p: by[p].mean())
        md += [f"\n### Budget {b:g}\n", "| planner | search eff. % (mean ± s.e. over worlds) |", "|---|---|"]
        for p in bl:
            v = by[p]
            md.append(f"| {THESIS_NAMES.get(p, p)} | {v.mean():.1f} ± {v.std(ddof=1) / np.sqrt(len(v)):.1f} |")
            curves[THESIS_NAMES.get(p, p)][b] = (float(v.mean()), float(v.std(ddof=1) / np.sqrt(len(v))))
        md += [
            "",
            f"| recipe | seeds | per seed | mean ± std over seeds | seed mean − DP-IPP | seed mean − best baseline "
            f"({THESIS_NAMES.get(best, best)}) |",
            "|---|---|---|---|---|---|",
        ]
        for name, members in rec.items():
            rs = []
            for folder, planner in members:
                if (planner, b) not in sweeps[folder]:
                    raise UserError(f"{folder}: no row {planner!r} at budget {b:g}")
                rs.append(sweeps[folder][(planner, b)])
            w2, v2 = aligned([rows[0], *rs])
            if w2 != worlds:
                raise UserError(f"recipe {name!r} ran other worlds than the baselines")
            per = v2[1:]
            means = per.mean(1)
            std = float(means.std(ddof=1)) if len(means) > 1 else float("nan")
            seed_mean = per.mean(0)
            md.append(
                f"| {name} | {len(means)} | {' / '.join(f'{m:.1f}' for m in means)} | {means.mean():.1f} ± {std:.1f} | "
                f"{paired(seed_mean, by['dp'])} | {paired(seed_mean, by[best])} |"
            )
            curves[name][b] = (float(means.mean()), std)
    return "\n".join(md) + "\n", curves


def plot(curves: dict, path: Path) -> None:
    """Search efficiency against the budget: baselines ± s.e. over worlds, recipes ± std over seeds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aerohrl.atomic import save_figure

    fig, ax = plt.subplots(figsize=(7.5, 5))
    for name, pts in curves.items():
        bs = sorted(pts)
        mu = np.array([pts[b][0] for b in bs])
        sd = np.nan_to_num(np.array([pts[b][1] for b in bs]))
        if name in BASELINE_NAMES:  # thin, with the worlds' standard error as bars
            ax.errorbar(bs, mu, yerr=sd, marker="o", ms=3, lw=1, capsize=2, alpha=0.8, label=name)
        else:  # bold, with the spread over training seeds as a band
            (line,) = ax.plot(bs, mu, marker="s", ms=5, lw=2.5, label=name)
            ax.fill_between(bs, mu - sd, mu + sd, alpha=0.2, color=line.get_color())
    ax.set_xlabel("budget (cost units: rho*T + int |jerk|^2)")
    ax.set_ylabel("search efficiency % (100 test worlds)")
    ax.set_title("IPP: search efficiency against budget\n(baselines ± s.e. over worlds; learned recipes ± std over seeds)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    plt.close(fig)


BASELINE_NAMES: set[str] = set()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--baselines", nargs="+", required=True, help="budget sweeps with the baselines (ipp bench --all --budgets ...; detect)"
    )
    p.add_argument(
        "--recipe", nargs="+", action="append", default=[], metavar="X", help="NAME SWEEP:PLANNER [...]: one row per seed"
    )
    p.add_argument("--page", type=Path, help="write the tables here (Markdown)")
    p.add_argument("--figure", type=Path, help="write the curve here (PNG)")
    a = p.parse_args(argv)
    try:
        from aerohrl.ipp.baselines import PLANNERS, THESIS_NAMES

        BASELINE_NAMES.update(THESIS_NAMES.get(q, q) for q in PLANNERS + ("detect",))
        md, curves = build(a.baselines, a.recipe)
        print(md, end="")
        if a.page:
            from aerohrl.atomic import write_text

            write_text(a.page, md)
        if a.figure:
            plot(curves, a.figure)
    except UserError as e:
        print(f"ipp_budget_curve: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
