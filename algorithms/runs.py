"""``aerohrl runs show RUN``: config, dataset version, progress and the learning curve.

The plot (``RUN/learning_curve.png`` unless ``--out``) follows thesis Fig. 3.3/3.4: the
closed-loop success rate against training steps (one line per evaluation task: the
trainer's periodic evaluations and, when ``aerohrl eval`` has been run, its results of
every evaluated checkpoint), with the training losses beside it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from aerohrl.atomic import save_figure
from aerohrl.cli_common import add_common, add_run
from aerohrl.errors import ArgumentParser, UserError, run_cli

PROG = "aerohrl runs"


def summary(run_dir: str | Path) -> dict:
    """What ``runs show`` reports; every checkpoint is checked against its SHA-256 and the
    progress counts the newest intact one."""
    from aerohrl.algorithms.run import Run, checkpoint_problem, checkpoint_step

    run = Run.open(run_dir, kind="train")
    meta = run.meta
    ckpts = run.checkpoints()
    damaged = {p.name: why for p in ckpts if (why := checkpoint_problem(p))}
    intact = [p for p in ckpts if p.name not in damaged]
    metrics = run.metrics()
    train_recs = [r for r in metrics if not any(k.startswith("eval/") for k in r)]
    eval_recs = [r for r in metrics if any(k.startswith("eval/") for k in r)]
    return {
        "run": str(run.path),
        "config": meta.get("config", {}),
        "dataset": meta.get("dataset", {}),
        "checkpoint_step": checkpoint_step(intact[-1]) if intact else 0,
        "checkpoints": [p.name for p in ckpts],
        "damaged": damaged,
        "set_aside": run.set_aside(),
        "logged_step": train_recs[-1]["step"] if train_recs else 0,
        "last_metrics": train_recs[-1] if train_recs else {},
        "last_eval": eval_recs[-1] if eval_recs else {},
        "metrics": metrics,
        "training_s": training_seconds(train_recs, meta.get("config", {}).get("log_every", 1)),
    }


def training_seconds(train_recs: list[dict], log_every: int) -> float:
    """Time spent in gradient steps, from the logged step rates (each line covers the steps
    since the previous line; after a resume the first line covers ``log_every``). Periodic
    evaluations and checkpoint writes are not counted; interruptions are not either."""
    total, prev = 0.0, 0
    for r in train_recs:
        if "steps_per_s" not in r:
            continue
        n = r["step"] - prev if r["step"] > prev else min(log_every, r["step"])
        total += n / max(r["steps_per_s"], 1e-9)
        prev = r["step"]
    return total


def _harness_curves(run_dir) -> dict[str, list[tuple[int, float, float]]]:
    """Per-checkpoint (step, success %, near success %) of every ``aerohrl eval`` result
    of the run (``RUN/eval/<name>/summary.json``), by result name."""
    import json

    out = {}
    for f in sorted(Path(run_dir).glob("eval/*/summary.json")):
        try:
            rows = json.loads(f.read_text()).get("checkpoints", [])
            pts = sorted((int(r["step"]), 100 * float(r["success"]), 100 * float(r["near_success"])) for r in rows)
        except (OSError, ValueError, KeyError, TypeError):
            continue  # a damaged or foreign file: the plot goes on without it
        if pts:
            out[f.parent.name] = pts
    return out


def plot_learning_curve(run_dir: str | Path, out: str | Path | None = None) -> Path:
    """Plot a run's closed-loop success (training-time and ``aerohrl eval`` checkpoints) and
    training losses against the step to ``out`` (default ``RUN/learning_curve.png``); returns it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = summary(run_dir)
    out = Path(out) if out else Path(run_dir) / "learning_curve.png"
    metrics = s["metrics"]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    evals = sorted({k for r in metrics for k in r if k.startswith("eval/") and k.endswith("/success")})
    for k in evals:
        pts = [(r["step"], 100 * r[k]) for r in metrics if k in r]
        (line,) = ax1.plot(*zip(*pts), marker="o", label=k.split("/")[1].replace("_", "-"))
        kn = k[: -len("success")] + "near_success"
        near = [(r["step"], 100 * r[kn]) for r in metrics if kn in r]
        if near:
            ax1.plot(*zip(*near), ls="--", color=line.get_color(), alpha=0.6, label=f"{k.split('/')[1].replace('_', '-')} (near)")
    harness = _harness_curves(run_dir)
    for name, pts in harness.items():  # aerohrl eval: every evaluated checkpoint, all its episodes
        steps, succ, near = zip(*pts)
        (line,) = ax1.plot(steps, succ, marker="s", label=f"{name} (aerohrl eval)")
        ax1.plot(steps, near, ls=":", color=line.get_color(), alpha=0.6, label=f"{name} (aerohrl eval, near)")
    evals = evals + list(harness)
    ax1.set_xlabel("training step")
    ax1.set_ylabel("success rate (%)")
    ax1.set_ylim(-2, 102)
    ax1.set_title(f"{s['config'].get('algo', '?')}: closed-loop success")
    if evals:
        ax1.legend()
    else:
        ax1.text(0.5, 0.5, "no evaluation yet", ha="center", transform=ax1.transAxes)
    losses = sorted({k for r in metrics for k in r if k.startswith("loss")})
    for k in losses:
        pts = [(r["step"], r[k]) for r in metrics if k in r]
        ax2.plot(*zip(*pts), label=k)
    ax2.set_xlabel("training step")
    vals = [abs(r[k]) for r in metrics for k in losses if k in r and r[k] != 0]
    ax2.set_yscale("symlog", linthresh=max(min(vals), 1e-8) if vals else 1e-3)
    ax2.set_title("training losses")
    if losses:
        ax2.legend(fontsize=8)
    fig.tight_layout()
    try:
        save_figure(fig, out, dpi=110)
    finally:
        plt.close(fig)
    return out


def eval_results(run_dir: str | Path) -> list[dict]:
    """The ``aerohrl eval`` summaries of a run (``RUN/eval/*/summary.json``), by name."""
    import json

    out = []
    for f in sorted(Path(run_dir).glob("eval/*/summary.json")):
        try:
            d = json.loads(f.read_text())
            steps = [int(c["step"]) for c in d.get("checkpoints", [])]
            out.append({"name": f.parent.name, "success": 100 * float(d["success_mean"]), "std": 100 * float(d["success_std"]),
                        "near": 100 * float(d["near_success_mean"]), "checkpoints": len(steps), "episodes": int(d["episodes"]),
                        "steps": (min(steps), max(steps)) if steps else (0, 0)})
        except (OSError, ValueError, KeyError, TypeError):
            out.append({"name": f.parent.name, "damaged": True})
    return out


def _print_eval_results(run_dir) -> None:
    for e in eval_results(run_dir):
        if e.get("damaged"):
            print(f"eval:      {e['name']}: summary.json unreadable (run `aerohrl eval` again)")
        else:
            print(f"eval:      {e['name']}: success {e['success']:.1f} ± {e['std']:.1f} %, near {e['near']:.1f} % "
                  f"({e['checkpoints']} checkpoints x {e['episodes']} episodes, steps {e['steps'][0]:,}..{e['steps'][1]:,}; aerohrl eval)")


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
    print(f"progress:  iteration {done:,} / {total:,} ({100 * done / max(total, 1):.1f}%)"
          + (f"; {rows[-1].get('time_s', 0) / 60:.1f} min" if rows else ""))
    if rows:
        last = rows[-1]
        print("last:      " + ", ".join(f"{k} {v:.4g}" for k, v in last.items() if isinstance(v, (int, float)) and k != "iteration"))
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
    print(f"progress:  checkpoint at step {s['checkpoint_step']:,} / {total:,} ({100 * s['checkpoint_step'] / max(total, 1):.1f}%); "
          f"logged up to step {s['logged_step']:,}; {len(s['checkpoints'])} checkpoints kept; "
          f"{s['training_s'] / 60:.1f} min of gradient steps")
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
    add_common(s, out={"help": "plot file [RUN/learning_curve.png]"}, old_out=("--output",))
    s.add_argument("--no-plot", action="store_true", help="no plot")
    return ap


def main(argv: list[str] | None = None) -> int:
    """The ``aerohrl runs`` command; returns the exit code."""
    args = parser().parse_args(argv)
    return run_cli(PROG, lambda: {"show": cmd_show}[args.cmd](args))


if __name__ == "__main__":
    sys.exit(main())
