"""``aerohrl runs show RUN``: config, dataset version, progress and the learning curve of a
training run (:mod:`aerohrl.algorithms.runs`) or of an ``aerohrl ipp train`` run
(:mod:`aerohrl.ipp.train`).

A command module: it decides which kind of run it is shown, so neither package imports
the other.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from aerohrl.algorithms.runs import eval_results, plot_learning_curve, summary
from aerohrl.cli_common import add_common, add_run
from aerohrl.errors import ArgumentParser, run_cli

PROG = "aerohrl runs"


def _print_eval_results(run_dir) -> None:
    for e in eval_results(run_dir):
        if e.get("damaged"):
            print(f"eval:      {e['name']}: summary.json unreadable (run `aerohrl eval` again)")
        else:
            print(
                f"eval:      {e['name']}: success {e['success']:.1f} ± {e['std']:.1f} %, near {e['near']:.1f} % "
                f"({e['checkpoints']} checkpoints x {e['episodes']} episodes, steps {e['steps'][0]:,}..{e['steps'][1]:,}; aerohrl eval)"
            )


def cmd_show_ipp(a: argparse.Namespace) -> int:
    """``runs show`` of an IPP run: its config, progress in iterations, the last metrics and the curve."""
    from aerohrl.ipp.curve import plot_learning_curve as ipp_curve, read_metrics as ipp_metrics
    from aerohrl.ipp.train import load_run_config

    cfg = load_run_config(a.run)
    rows = ipp_metrics(a.run)
    total = cfg.total_iterations
    done = rows[-1]["iteration"] if rows else 0
    print(f"run:       {a.run}  (informative path planning, aerohrl ipp train)")
    print(f"world:     {cfg.env.kind}; seed {cfg.seed}; {cfg.n_envs} environments per iteration")
    print(
        f"progress:  iteration {done:,} / {total:,} ({100 * done / max(total, 1):.1f}%)"
        + (f"; {rows[-1].get('time_s', 0) / 60:.1f} min" if rows else "")
    )
    if rows:
        last = rows[-1]
        print(
            "last:      " + ", ".join(f"{k} {v:.4g}" for k, v in last.items() if isinstance(v, (int, float)) and k != "iteration")
        )
    kept = [n for n in ("model.pt", "best.pt", "checkpoint.pt") if (Path(a.run) / n).exists()]
    print(f"files:     {', '.join(kept) or 'no weights yet'}")
    if not a.no_plot and rows:
        print(f"plot:      {ipp_curve(a.run, a.out)}")
    return 0


def cmd_show(a: argparse.Namespace) -> int:
    """``runs show``: config, dataset version, progress, last metrics, evaluations and the
    learning-curve plot of a training run (an IPP run: :func:`cmd_show_ipp`); exit code."""
    from aerohrl.algorithms.run import Run

    if Run.open(a.run).is_ipp:
        return cmd_show_ipp(a)
    s = summary(a.run)
    cfg, ds = s["config"], s["dataset"]
    print(f"run:       {s['run']}")
    print(f"algorithm: {cfg.get('algo')} (preset {cfg.get('preset')}, seed {cfg.get('seed')}, device {cfg.get('device')})")
    print(f"dataset:   {ds.get('path')}  version {ds.get('version')}  ({ds.get('episodes')} episodes, {ds.get('frames')} frames)")
    total = cfg.get("steps", 0)
    print(
        f"progress:  checkpoint at step {s['checkpoint_step']:,} / {total:,} ({100 * s['checkpoint_step'] / max(total, 1):.1f}%); "
        f"logged up to step {s['logged_step']:,}; {len(s['checkpoints'])} checkpoints kept; "
        f"{s['training_s'] / 60:.1f} min of gradient steps"
    )
    for name, why in s["damaged"].items():
        print(f"DAMAGED:   {name}: {why} (`train --resume` falls back to the newest intact checkpoint)")
    if s["set_aside"]:
        print(f"set aside: {', '.join(s['set_aside'])} (damaged, skipped by an earlier resume)")
    if s["last_metrics"]:
        m = s["last_metrics"]
        print("last:      " + ", ".join(f"{k} {v:.4g}" for k, v in m.items() if k != "step"))
    if s["last_eval"]:
        e = s["last_eval"]
        print(f"eval @ {e['step']:,}: " + ", ".join(f"{k[5:]} {v:.3g}" for k, v in e.items() if k != "step"))
    _print_eval_results(a.run)
    print("config:    " + " ".join(f"{k}={v}" for k, v in sorted(cfg.items()) if k not in ("algo", "preset", "seed", "device")))
    if not a.no_plot:
        print(f"plot:      {plot_learning_curve(a.run, a.out)}")
    return 0


def parser() -> ArgumentParser:
    """The ``aerohrl runs`` argument parser."""
    ap = ArgumentParser(prog=PROG, description="Inspect training runs.")
    sub = ap.add_subparsers(dest="cmd", required=True, metavar="COMMAND")
    s = sub.add_parser("show", help="config, dataset version, progress and learning-curve plot of a run")
    add_run(s, help="run folder (runs/<run>; a train or an ipp train run)")
    add_common(s, out={"help": "plot file [RUN/learning_curve.png]"})
    s.add_argument("--no-plot", action="store_true", help="no plot")
    return ap


def main(argv: list[str] | None = None) -> int:
    """The ``aerohrl runs`` command; returns the exit code."""
    args = parser().parse_args(argv)
    return run_cli(PROG, lambda: {"show": cmd_show}[args.cmd](args))


if __name__ == "__main__":
    sys.exit(main())
