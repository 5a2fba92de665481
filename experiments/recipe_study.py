"""Expert-data recipes, measured: which data makes skills that generalise (eval/README.md "Recipes").

    python experiments/recipe_study.py --plan best table size      # build, train, evaluate, write the tables
    python experiments/recipe_study.py --plan best --report-only   # tables from what is there (nothing trained)
    python experiments/recipe_study.py --plan table --steps 200 --goals-scale 0.02 --runs /tmp/r --datasets /tmp/d --out /tmp/o \
        --results-dir /tmp/pages                                   # a smoke run of the same pipeline

A *row* is (recipe, goals, seed, steps): ``datagen build --goals N <recipe flags>``, then
GCSL with the cpu preset for ``steps`` gradient steps (checkpoints every steps/30), then
``aerohrl eval`` on the last K checkpoints x 250 episodes of

* Reach-Desired (the dataset's own goals), Reach-Novel (fresh goals from rho_D: the
  generalisation test), Reach-Intermediate, OOD flown straight (the thesis's set);
* the same four at half the goal tolerances (``--goal-tol 0.5``: 0.075 m, 0.175 m/s,
  0.075 rad), the precision variant;

and the critics' ROC AUC: how well the ensemble's value ``mean_j Q_j(s0, pi(s0, g), g)``
at take-off ranks the Reach-Novel episodes that succeed above those that fail (newest
checkpoint). A seed's figure is the mean over its K checkpoints; a recipe's is the mean
± std over seeds with every seed's value.

Every stage is the real command line in a subprocess with one thread (``--jobs`` rows at
a time); an existing dataset is verified, an existing run resumed (a finished one left
alone), an evaluation that covers the run's newest checkpoints kept. Interrupt it at
will and run it again. The tables go to ``OUT/recipes.md`` and the dated page
``RESULTS_DIR/YYYY-MM-DD-recipes.md`` (``--results-dir``, default docs/results).
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
import threading
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import TextIO

import numpy as np

from aerohrl.errors import UserError, run_cli
from aerohrl.eval.harness import critics_auc
from aerohrl.eval.results import evaluation_is_current, seed_cell, seed_stats, write_results_page
from study_tools import run_logged

PROG = "experiments/recipe_study.py"
STUDY = "recipes"  # the results page: RESULTS_DIR/YYYY-MM-DD-recipes.md

# The recipes: datagen build flags on top of the default spec (docs/spec.md "Expert-data recipes").
NOISE = ["--action-noise", "1.0", "0.5"]  # sigma: 1.0 m/s^2 thrust, 0.5 rad/s per body rate; tau 0.2 s
RECIPES: dict[str, list[str]] = {
    "clean": [],
    "noise": NOISE,
    "noise x0.5": ["--action-noise", "0.5", "0.25"],
    "noise x2": ["--action-noise", "2.0", "1.0"],
    "replan": ["--expert", "replan"],
    "replan + noise": ["--expert", "replan", *NOISE],
    "noise + perturbed starts": [*NOISE, "--start-states", "perturbed"],
    "noise + 4 flights per goal": [*NOISE, "--rollouts-per-goal", "4"],
    "noise, imitating the flown action": NOISE,
}
# train flags of a recipe beyond the cpu preset (the label ablation: what GCSL imitates)
TRAIN_FLAGS: dict[str, list[str]] = {"noise, imitating the flown action": ["--bc-target", "executed"]}
EVALS = [  # (column, aerohrl eval flags)
    ("reach-desired", ["--task", "reach-desired"]),
    ("reach-novel", ["--task", "reach-novel"]),
    ("reach-intermediate", ["--task", "reach-intermediate"]),
    ("ood", ["--task", "ood", "--planner", "none"]),
    ("reach-desired-goaltol0.5", ["--task", "reach-desired", "--goal-tol", "0.5"]),
    ("reach-novel-goaltol0.5", ["--task", "reach-novel", "--goal-tol", "0.5"]),
    ("reach-intermediate-goaltol0.5", ["--task", "reach-intermediate", "--goal-tol", "0.5"]),
    ("ood-goaltol0.5", ["--task", "ood", "--planner", "none", "--goal-tol", "0.5"]),
]
EVAL_DIR = {"ood": "ood-none", "ood-goaltol0.5": "ood-none-goaltol0.5"}
EPISODES = 250  # per task and checkpoint (Table 3.1 protocol)
FLOORS = ("hover", "no-goal")  # eval/floors.py: flown on the newest checkpoint of every seed-0 run
FLOOR_COLS = ("reach-desired", "reach-novel", "reach-intermediate", "ood")


@dataclass(frozen=True)
class Row:
    recipe: str
    goals: int
    seed: int
    steps: int

    @property
    def name(self) -> str:
        """The row's run name: ``RECIPE-nGOALS-sSEED-STEPSk``."""
        slug = self.recipe.replace(" + ", "+").replace(", ", "-").replace(" ", "-")
        return f"{slug}-n{self.goals}-s{self.seed}-{self.steps // 1000}k"


# What each plan trains (equal gradient steps within a plan).
PLANS: dict[str, list[Row]] = {
    # the recommended recipe, 3 seeds (issue targets: mean over 3 seeds)
    "best": [Row("noise", 25000, s, 30000) for s in (0, 1, 2)],
    # the recipe table: every recipe on the same 2,500 goals, 15k steps
    "table": [Row(r, 2500, 0, 15000) for r in RECIPES],
    # data efficiency: Reach-Novel against dataset size at equal steps
    "size": [Row("noise", n, 0, 15000) for n in (250, 1000, 10000, 25000)]
    + [Row("clean", 10000, 0, 15000), Row("noise", 100000, 0, 15000)],
    # seeds for the leading table rows
    "seeds": [Row(r, 2500, s, 15000) for r in ("noise", "replan + noise") for s in (1, 2)],
    # the table's recipes at a second size (10,000 flights): does the ranking hold with more data?
    "sizes": [
        Row(r, 10000, 0, 15000)
        for r in ("noise x2", "replan + noise", "noise + perturbed starts", "noise + 4 flights per goal", "noise x0.5", "replan")
    ],
}
CHECKPOINTS = {"best": 10}  # last K checkpoints evaluated (others: 3)


def flights_per_goal(recipe: str) -> int:
    """The recipe's ``--rollouts-per-goal`` (1 when it has none)."""
    flags = RECIPES.get(recipe, [])
    return int(flags[flags.index("--rollouts-per-goal") + 1]) if "--rollouts-per-goal" in flags else 1


def dataset_for(py: str, recipe: str, goals: int, root: str, log: TextIO) -> str:
    """Build (or verify) the dataset of ``recipe`` with ``goals`` goals; its path."""
    if recipe not in RECIPES:
        raise UserError(f"unknown recipe {recipe!r} (choose from {', '.join(RECIPES)})")
    flags = list(RECIPES[recipe])
    goals = max(1, goals // flights_per_goal(recipe))  # equal flights: k flights of goals / k goals
    out = run_logged(
        [py, "-m", "aerohrl.datagen.cli", "build", "--goals", str(goals), "--seed", "0", "--out", root, "--quiet", *flags], log
    )
    return out.strip().splitlines()[-1].strip()


def run_row(py: str, row: Row, ds: str, runs: Path, k: int, log: TextIO) -> Path:
    """Train (or resume) the row's run, then every evaluation not yet up to date."""
    rd = runs / row.name
    train = [py, "-m", "aerohrl.algorithms.cli"]
    if (rd / "config.json").exists():
        run_logged(train + ["--resume", str(rd), "--quiet", "--steps", str(row.steps)], log)
    else:
        run_logged(
            train
            + [
                "--algo",
                "gcsl",
                "--preset",
                "cpu",
                *TRAIN_FLAGS.get(row.recipe, []),
                "--dataset",
                ds,
                "--seed",
                str(row.seed),
                "--steps",
                str(row.steps),
                "--checkpoint-every",
                str(max(1, row.steps // 30)),
                "--out",
                str(runs),
                "--name",
                row.name,
                "--quiet",
            ],
            log,
        )
    todo = [(EVAL_DIR.get(col, col), flags, k) for col, flags in EVALS]
    if row.seed == 0:
        todo += [
            (f"{EVAL_DIR.get(col, col)}-floor-{f}", flags + ["--floor", f], 1)
            for f in FLOORS
            for col, flags in EVALS
            if col in FLOOR_COLS
        ]
    for name, flags, kk in todo:
        n = min(EPISODES, row.goals) if name.startswith("reach-desired") else EPISODES  # one flight per own goal at most
        if not evaluation_is_current(rd, name, n, kk):
            run_logged(
                [
                    py,
                    "-m",
                    "aerohrl.eval.cli",
                    *flags,
                    "--run",
                    str(rd),
                    "--episodes",
                    str(n),
                    "--checkpoints",
                    str(kk),
                    "--quiet",
                ],
                log,
            )
    return rd


def row_figures(rd: Path, suffix: str = "") -> dict:
    """Per evaluation column: (mean over the evaluated checkpoints, std over them, count) in %;
    ``suffix`` "-floor-hover" / "-floor-no-goal" reads a floor's evaluations instead."""
    out = {}
    for col, _ in EVALS:
        f = rd / "eval" / (EVAL_DIR.get(col, col) + suffix) / "summary.json"
        if f.exists():
            s = json.loads(f.read_text())
            rates = [100 * c["success"] for c in s["checkpoints"]]
            out[col] = (float(np.mean(rates)), float(np.std(rates)), len(rates))
    return out


def aggregate(rows: list[Row], runs: Path) -> list[dict]:
    """One record per (recipe, goals, steps): per-seed figures, mean ± std over seeds."""
    groups: dict[tuple, list[Row]] = {}
    for r in rows:
        groups.setdefault((r.recipe, r.goals, r.steps), []).append(r)
    out = []
    for (recipe, goals, steps), rs in groups.items():
        per_seed = {}
        for r in sorted(rs, key=lambda r: r.seed):
            rd = runs / r.name
            fig = row_figures(rd) if rd.is_dir() else {}
            if "reach-novel" in fig:
                fig["auc"] = (critics_auc(rd), 0.0, 1)
                per_seed[r.seed] = fig
        if not per_seed:
            continue
        rec = {"recipe": recipe, "goals": goals, "steps": steps, "seeds": sorted(per_seed), "cols": {}, "floors": {}}
        rd0 = runs / rs[0].name
        for fl in FLOORS:
            ff = row_figures(rd0, f"-floor-{fl}") if rd0.is_dir() else {}
            if ff:
                rec["floors"][fl] = {col: v[0] for col, v in ff.items()}
        for col in [c for c, _ in EVALS] + ["auc"]:
            vals = [per_seed[s][col][0] for s in rec["seeds"] if col in per_seed[s]]
            if vals:
                rec["cols"][col] = {**seed_stats(vals), "ckpts": per_seed[rec["seeds"][0]][col][2]}
        out.append(rec)
    return out


def _flights(recipe: str, goals: int) -> str:
    k = flights_per_goal(recipe)
    return f"{goals // k:,} x {k}" if k > 1 else f"{goals:,}"


def table(recs: list[dict]) -> str:
    """The recipe table as Markdown: one line per recipe/size/steps with the seeds' success on
    every task (and at half tolerance) and the critics' AUC."""
    head = (
        "| recipe | flights (goals) | steps | seeds | Reach-Desired (own goals) | Reach-Novel | Reach-Intermediate | OOD straight | "
        "critics' AUC (Reach-Novel) | RD @ half tol | RN @ half tol | RI @ half tol | OOD @ half tol |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for r in recs:
        c = r["cols"]
        auc = c.get("auc")
        auc_s = "—" if not auc or any(math.isnan(v) for v in auc["values"]) else seed_cell(auc, 3)
        lines.append(
            f"| {r['recipe']} | {_flights(r['recipe'], r['goals'])} | {r['steps'] // 1000}k | {len(r['seeds'])} | "
            + " | ".join(seed_cell(c.get(k)) for k in ("reach-desired", "reach-novel", "reach-intermediate", "ood"))
            + f" | {auc_s} | "
            + " | ".join(
                seed_cell(c.get(k))
                for k in ("reach-desired-goaltol0.5", "reach-novel-goaltol0.5", "reach-intermediate-goaltol0.5", "ood-goaltol0.5")
            )
            + " |"
        )
    floors = [(r, fl, v) for r in recs[:1] for fl, v in r["floors"].items()]
    for r, fl, v in floors:  # one set of floors per table: on the first row's data and policy
        what = (
            "hover: constant [g, 0, 0, 0]" if fl == "hover" else f"no goal: the {r['recipe']} policy, goal inputs at their mean"
        )
        lines.append(
            f"| *floor, {what}* | {_flights(r['recipe'], r['goals'])} | | | "
            + " | ".join(f"{v[k]:.1f}" if k in v else "—" for k in ("reach-desired", "reach-novel", "reach-intermediate", "ood"))
            + " | | | | | |"
        )
    return head + "\n".join(lines) + "\n"


def plot_size(recs: list[dict], path: Path) -> Path | None:
    """Left: Reach-Novel (at full and half tolerance) and OOD flown straight against dataset
    size for the clean and noise recipes (log x); right: Reach-Novel of every recipe measured
    at two sizes or more (the table's recipes at 2,500 and 10,000 flights). 15k steps each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    at15 = [r for r in recs if r["steps"] == 15000 and "reach-novel" in r["cols"]]
    by: dict[str, list[dict]] = {}
    for r in at15:
        by.setdefault(r["recipe"], []).append(r)
    if not any(k in by for k in ("noise", "clean")):
        return None
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11.5, 4.4))
    colour = {"noise": "tab:red", "clean": "tab:blue"}  # one colour per recipe, one line style per column
    for recipe in ("clean", "noise"):
        rs = sorted(by.get(recipe, []), key=lambda r: r["goals"])
        x = [r["goals"] for r in rs]
        for col, style, label in (
            ("reach-novel", "-o", "Reach-Novel"),
            ("reach-novel-goaltol0.5", ":^", "Reach-Novel @ half tol"),
            ("ood", "--s", "OOD straight"),
        ):
            y = [r["cols"].get(col, {}).get("mean", np.nan) for r in rs]
            ax.plot(x, y, style, color=colour[recipe], label=f"{recipe}: {label}")
    many = sorted((k for k, rs in by.items() if len({r["goals"] for r in rs}) >= 2), key=lambda k: (k not in colour, k))
    cmap = plt.get_cmap("tab10")
    for i, recipe in enumerate(many):
        rs = sorted(by[recipe], key=lambda r: r["goals"])
        ax2.plot(
            [r["goals"] for r in rs],
            [r["cols"]["reach-novel"]["mean"] for r in rs],
            "-o",
            color=colour.get(recipe, cmap((i + 2) % 10)),
            label=recipe,
        )
    for a, xl in ((ax, "goals in the dataset (one flight each)"), (ax2, "flights in the dataset")):
        a.axhline(95, color="grey", lw=0.8, ls="--")
        a.set_xscale("log")
        a.set_xlabel(xl)
        a.set_ylabel("success % (GCSL, cpu preset, 15k steps)")
        a.set_ylim(0, 101)
        a.grid(alpha=0.3)
        a.legend(fontsize=7, loc="lower right")
    ax.set_title("Generalisation against dataset size")
    ax2.set_title("Reach-Novel of every recipe against its size")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    """The recipe study command: build the recipe datasets, train GCSL on each, evaluate
    and write the recipe table; exit code."""
    ap = argparse.ArgumentParser(
        prog=PROG, description="Build recipe datasets, train GCSL on each, evaluate, write the recipe table."
    )
    ap.add_argument(
        "--plan",
        nargs="+",
        default=["best", "table", "size", "seeds", "sizes"],
        choices=list(PLANS),
        help="which rows to train and report [all]",
    )
    ap.add_argument("--datasets", default="datasets", help="dataset root [datasets]")
    ap.add_argument("--runs", default="runs/recipes", help="runs root [runs/recipes]")
    ap.add_argument("--out", default="results/recipes", help="tables and plots [results/recipes]")
    ap.add_argument(
        "--results-dir", default="docs/results", help="folder of the dated results page YYYY-MM-DD-recipes.md [docs/results]"
    )
    ap.add_argument("--jobs", type=int, default=2, help="rows at a time, one thread each [2]")
    ap.add_argument("--steps", type=int, default=None, help="override every row's steps (smoke runs)")
    ap.add_argument("--goals-scale", type=float, default=1.0, help="multiply every row's goal count (smoke runs) [1]")
    ap.add_argument("--report-only", action="store_true", help="write the tables from existing runs; train nothing")
    a = ap.parse_args(argv)
    command = " ".join(["python", PROG, *map(shlex.quote, sys.argv[1:] if argv is None else argv)])

    def go() -> int:
        import concurrent.futures as cf
        import io

        # everything the report needs, imported now: a study runs for hours, and modules
        # edited meanwhile must not be mixed with the ones already loaded
        import aerohrl.eval.harness  # noqa: F401
        import aerohrl.planning.oracle  # noqa: F401
        import aerohrl.eval.tasks  # noqa: F401
        import aerohrl.datagen.manifest  # noqa: F401

        if a.jobs < 1 or a.goals_scale <= 0 or (a.steps is not None and a.steps < 1):
            raise UserError("--jobs and --steps must be >= 1, --goals-scale > 0")
        py = sys.executable
        out, runs = Path(a.out), Path(a.runs)
        out.mkdir(parents=True, exist_ok=True)
        plan_rows = {
            p: [Row(r.recipe, max(1, int(r.goals * a.goals_scale)), r.seed, a.steps or r.steps) for r in PLANS[p]] for p in a.plan
        }
        t0 = time.perf_counter()
        failed = 0
        with open(out / "study.log", "a") as log:
            log.write(f"=== {datetime.now(timezone.utc).isoformat(timespec='seconds')} {' '.join(sys.argv)}\n")
            if not a.report_only:
                todo = [(r, CHECKPOINTS.get(p, 3)) for p, rs in plan_rows.items() for r in rs]
                datasets: dict = {}
                locks: dict = {}
                guard = threading.Lock()

                def dataset(r: Row) -> str:
                    """Built when a row first needs it (the first thread builds, the others wait)."""
                    key = (r.recipe, r.goals)
                    with guard:
                        lock = locks.setdefault(key, threading.Lock())
                    with lock:
                        if key not in datasets:
                            buf = io.StringIO()
                            datasets[key] = dataset_for(py, r.recipe, r.goals, a.datasets, buf)
                            with guard:
                                log.write(buf.getvalue())
                        return datasets[key]

                def one(item):
                    r, k = item
                    buf = io.StringIO()
                    s = time.perf_counter()
                    try:
                        run_row(py, r, dataset(r), runs, k, buf)
                        return r, time.perf_counter() - s, buf.getvalue(), None
                    except UserError as e:  # one row's failure is reported; the others go on
                        return r, time.perf_counter() - s, buf.getvalue(), str(e)

                with cf.ThreadPoolExecutor(max_workers=a.jobs) as ex:
                    for fut in cf.as_completed([ex.submit(one, item) for item in todo]):
                        r, dt, text, err = fut.result()
                        with guard:
                            log.write(text)
                            log.flush()
                        print(f"{r.name}: {dt / 60:.1f} min" + (f"; FAILED: {err}" if err else ""), flush=True)
                        failed += bool(err)
        sections = []
        all_recs = {}
        # a (recipe, goals, steps) experiment is reported once, in the first plan that has it,
        # with the seeds of every plan (the "seeds" plan adds seeds to the table's rows)
        seen: set = set()
        for p, rs in plan_rows.items():
            keys = [k for k in dict.fromkeys((r.recipe, r.goals, r.steps) for r in rs) if k not in seen]
            seen.update(keys)
            rows = [r for q in plan_rows.values() for r in q if (r.recipe, r.goals, r.steps) in keys]
            recs = aggregate(list(dict.fromkeys(rows)), runs)
            if not recs:
                continue
            all_recs[p] = recs
            sections.append(
                f"**{p}** (GCSL, cpu preset; last {CHECKPOINTS.get(p, 3)} checkpoints x 250 "
                f"episodes per task; success %, mean ± std over seeds [95 % bootstrap interval of the mean, "
                f"from 3 seeds] (per-seed values))\n\n" + table(recs)
            )
        pooled = [r for recs in all_recs.values() for r in recs]
        fig = plot_size(pooled, out / "reach_novel_vs_size.png")
        stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        block = (
            f"Written by `{command}` on {stamp}"
            + (f" (steps overridden: {a.steps})" if a.steps else "")
            + (f" (goals x {a.goals_scale})" if a.goals_scale != 1 else "")
            + ".\n\n"
            + "\n".join(sections)
        )
        (out / "recipes.md").write_text(block + (f"\nPlot: `{fig}`.\n" if fig else ""))
        (out / "recipes.json").write_text(json.dumps(all_recs, indent=1))
        page = write_results_page(a.results_dir, STUDY, command, block, title="Expert-data recipes", figures=[fig] if fig else [])
        print(f"recipe tables written to {page} and {out / 'recipes.md'} ({(time.perf_counter() - t0) / 60:.1f} min)")
        if failed:
            raise UserError(f"{failed} row(s) failed (see {out / 'study.log'}); the tables hold the others")
        return 0

    return run_cli(PROG, go)


if __name__ == "__main__":
    sys.exit(main())
