"""Which goals of one ring the expert reaches at all: directly, and through one run-up.

    python experiments/feasibility_study.py --family velocity --ring 3 --n 250

Samples ``--n`` goals of the ring (eval/families.py, episode-set seed ``--seed``), flies
the clean expert to each (eval/feasibility.py: the minimum-time reference and slower
ones from rest, then run-up waypoints) and prints the rates: direct (minimum time),
direct, run-up, feasible and their near versions. The line also goes to the dated page
``RESULTS_DIR/YYYY-MM-DD-feasibility-FAMILY-RING.md`` (``--results-dir``, default
docs/results). Seconds to minutes per ring on one core.
"""

from __future__ import annotations

import re
import shlex
import sys

from aerohrl.errors import ArgumentParser, run_cli

PROG = "experiments/feasibility_study.py"


def parser() -> ArgumentParser:
    """The command's argument parser."""
    ap = ArgumentParser(
        prog=PROG,
        description="Direct / run-up / feasible rates of the expert on one ring of an OOD goal family (eval/families.py).",
    )
    ap.add_argument("--family", required=True, help="position | velocity | acceleration | combined")
    ap.add_argument("--ring", required=True, help="1-based step of the family, or a custom range LO:HI")
    ap.add_argument("--n", type=int, default=250, help="goals (default 250)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--vehicle", default="hummingbird")
    ap.add_argument("--a-max", type=float, default=None, help="one fixed per-axis bound (default: per-goal rule)")
    ap.add_argument("--runup", default="all", help="all | failed | none (default all)")
    ap.add_argument(
        "--results-dir",
        default="docs/results",
        help="folder of the dated results page YYYY-MM-DD-feasibility-FAMILY-RING.md [docs/results]",
    )
    return ap


def main(argv: list[str] | None = None) -> int:
    """The feasibility command: which goals the expert reaches directly and through a run-up;
    exit code."""
    argv = sys.argv[1:] if argv is None else argv
    a = parser().parse_args(argv)
    command = " ".join(["python", PROG, *map(shlex.quote, argv)])

    def go() -> int:
        from aerohrl.eval.families import parse_ring, sample_ring
        from aerohrl.eval.feasibility import feasibility
        from aerohrl.eval.results import write_results_page

        ring = parse_ring(a.family, a.ring)
        goals = sample_ring(ring, a.n, a.seed)
        r = feasibility(goals, ring.horizon(), vehicle=a.vehicle, a_max=a.a_max, runup=a.runup)
        line = (
            f"{ring.family} ring {ring.index} ({ring.label}), n={a.n}, seed={a.seed}, horizon {ring.horizon()} steps: "
            + ", ".join(f"{k} {100 * v:.1f} %" for k, v in r.rates().items())
            + f"  [{r.seconds:.1f} s]"
        )
        print(line)
        slug = re.sub(r"[^a-z0-9]+", "-", f"{ring.family}-{a.ring}".lower()).strip("-")
        write_results_page(
            a.results_dir, f"feasibility-{slug}", command, line, title=f"Expert feasibility, {ring.family} ring {a.ring}"
        )
        return 0

    return run_cli(PROG, go)


if __name__ == "__main__":
    sys.exit(main())
