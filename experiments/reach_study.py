"""Reach beyond the data: OOD goal families flown straight and planned, over seeds (eval/README.md "Reach").

    python experiments/reach_study.py --runs runs/recipes/noise-n25000-s{0,1,2}-30k     # evaluate, choose margins, write tables
    python experiments/reach_study.py --runs ... --report-only                           # tables from what is there
    python experiments/reach_study.py --runs ... --families velocity --episodes 40 --heldout 20   # a smaller study

For every run (one per training seed) and every ring of every family of
eval/families.py, ``aerohrl eval --task ood --family F --ring K`` flies the newest
``--checkpoints`` checkpoints on ``--episodes`` test goals (episode-set seed 0) with each
of ``--variants`` (straight, single, single-decline, chain, chain-decline: eval/rings.py).
The decline margins are chosen on ``--heldout`` held-out goals per ring (episode-set
seed 1), never on the test goals. Feasibility (eval/feasibility.py): which test goals
the expert reaches at all, directly from rest or through one run-up waypoint; planners
are also reported on the feasible goals.

Tables and the reach curves go to ``--out`` (``SECTION.md``, ``SECTION_curves.png``,
``SECTION_paths.png``) and to the dated page ``RESULTS_DIR/YYYY-MM-DD-reach-families.md``
(``--results-dir``, default docs/results; ``--section reach-chain`` writes
``...-reach-families-chain.md``). Per run the evaluations sit in ``RUN/eval/reach/``
(``reach-nN/`` for other test sizes; the held-out ones in ``heldout/`` below it); what is
there already is not flown again.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

from aerohrl import atomic
from aerohrl.errors import UserError, run_cli
from aerohrl.eval import rings as R

PROG = "experiments/reach_study.py"


def page_name(section: str) -> str:
    """The results page's study name of a ``--section``: reach-families[-SUFFIX]."""
    suffix = section.lower().removeprefix("reach").strip("-")
    return "reach-families" + (f"-{suffix}" if suffix else "")


def main(argv: list[str] | None = None) -> int:
    """The OOD reach study command (families flown straight and planned over seeds, decline
    margins on held-out goals, tables and figures); exit code."""
    ap = argparse.ArgumentParser(
        prog=PROG,
        description="OOD goal families flown straight and planned over seeds; decline "
        "margins chosen on held-out goals; reach tables and curves.",
    )
    ap.add_argument("--runs", nargs="+", type=Path, required=True, help="one run per training seed (same recipe and algorithm)")
    ap.add_argument("--families", nargs="+", default=None, help="families to fly [all of eval/families.py]")
    ap.add_argument(
        "--variants", nargs="+", default=None, help="straight | single | single-decline | chain | chain-decline [all]"
    )
    ap.add_argument("--episodes", type=int, default=250, help="test goals per ring [250]")
    ap.add_argument("--heldout", type=int, default=100, help="held-out goals per ring (margin choice) [100]")
    ap.add_argument("--checkpoints", type=int, default=1, help="newest checkpoints per run [1]")
    ap.add_argument("--candidates", type=int, default=1024, help="single: achieved goals scored [1024]")
    ap.add_argument("--out", type=Path, default=Path("results/reach"), help="tables and plots [results/reach]")
    ap.add_argument(
        "--results-dir",
        type=Path,
        default=Path("docs/results"),
        help="folder of the dated results page YYYY-MM-DD-reach-families[-SUFFIX].md [docs/results]",
    )
    ap.add_argument(
        "--section",
        default="reach",
        help="file names in --out and the results page's suffix "
        "(a second study with other variants or sizes gets its own) [reach]",
    )
    ap.add_argument("--report-only", action="store_true", help="tables from existing evaluations; fly nothing")
    ap.add_argument(
        "--fly-declines",
        action="store_true",
        help="fly the declining variants on the test goals too (default: composed exactly from the straight "
        "and planned flights, which they equal episode by episode; tests/test_eval_reach.py)",
    )
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args(argv)
    command = " ".join(["python", PROG, *map(shlex.quote, sys.argv[1:] if argv is None else argv)])

    def go() -> int:
        import torch

        from aerohrl.algorithms.run import read_json
        from aerohrl.datagen.dataset import open_dataset
        from aerohrl.eval.families import FAMILIES, rings as family_rings
        from aerohrl.eval.feasibility import ring_feasibility
        from aerohrl.eval.harness import EvalOptions
        from aerohrl.eval.results import write_results_page

        torch.set_num_threads(max(1, a.threads))
        if a.episodes < 1 or a.heldout < 1 or a.checkpoints < 1:
            raise UserError("--episodes, --heldout and --checkpoints must be >= 1")
        for r in a.runs:
            if not (r / "config.json").exists():
                raise UserError(f"no run at {r} (config.json missing)")
        fams = a.families or list(FAMILIES)
        rings = [r for f in fams for r in family_rings(f)]
        variants = a.variants or ["straight", "single", "single-decline", "chain", "chain-decline"]
        bad = [v for v in variants if v not in R.VARIANT_LABEL]
        if bad:
            raise UserError(f"unknown variant {bad[0]!r} (choose from {', '.join(R.VARIANT_LABEL)})")
        if not a.section.replace("-", "").isalnum():
            raise UserError(f"--section must be letters, digits and '-', got {a.section!r}")
        base = EvalOptions(
            task="ood", episodes=a.episodes, checkpoints=a.checkpoints, candidates=a.candidates, progress=sys.stderr.isatty()
        )
        a.out.mkdir(parents=True, exist_ok=True)
        logf = open(a.out / "reach.log", "a")

        def log(msg):
            line = f"{datetime.now(timezone.utc).strftime('%H:%M:%S')} {msg}"
            print(line, flush=True)
            logf.write(line + "\n")
            logf.flush()

        t0 = time.perf_counter()
        state_f = a.out / f"{a.section}-margins.json"
        if a.report_only:
            if not state_f.exists():
                raise UserError(f"{state_f} missing: run the study once without --report-only")
            state = json.loads(state_f.read_text())
        else:
            state = R.study(a.runs, rings, variants, base, a.heldout, log, a.fly_declines)
            atomic.write_text(state_f, json.dumps(state, indent=1))
        margins = {k: float(v) for k, v in state["margins"].items()}
        spec = open_dataset(read_json(a.runs[0] / "config.json")["dataset"]["path"], verify=False).spec
        feas = {}
        for ring in rings:
            t1 = time.perf_counter()
            feas[ring.slug] = f = ring_feasibility(ring, a.episodes, spec, cache=a.out)
            log(f"feasibility {ring.slug}: {100 * f['feasible'].mean():.1f} % ({time.perf_counter() - t1:.0f} s)")
        recs = R.collect(a.runs, rings, variants, base, margins, feas)
        curves = R.plot_curves(recs, variants, a.out / f"{a.section}_curves.png")
        paths = R.plot_paths(
            a.runs[0], rings, base, "chain" if "chain" in variants else "single", a.out / f"{a.section}_paths.png"
        )
        figs = [f for f in (curves, paths) if f is not None]
        stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        runs_s = " ".join(str(r) for r in a.runs)
        args = "" if a.episodes == 250 else f" --episodes {a.episodes} --heldout {a.heldout}"
        args += f" --variants {' '.join(variants)}" + (f" --section {a.section}" if a.section != "reach" else "")
        block = (
            f"Written by `python {PROG} --runs {runs_s}{args}` on {stamp}: {len(a.runs)} seeds, newest "
            f"{a.checkpoints} checkpoint(s) x {a.episodes} test goals per ring and seed; success %, mean ± std over seeds "
            f'[95 % bootstrap interval] (per-seed values); "vs straight": paired gain in points pooled over seeds '
            f"(episodes only this variant : only straight reaches, sign test).\n\n" + R.tables(recs, variants, margins)
        )
        atomic.write_text(a.out / f"{a.section}.md", block + "\n" + "\n\n".join(f"Plot: `{f}`" for f in figs) + "\n")
        page = write_results_page(
            a.results_dir, page_name(a.section), command, block, title="Reach beyond the data: goal families", figures=figs
        )
        log(f"reach tables written to {page} and {a.out / f'{a.section}.md'} ({(time.perf_counter() - t0) / 60:.1f} min)")
        return 0

    return run_cli(PROG, go)


if __name__ == "__main__":
    sys.exit(main())
