"""A training run's summary (config, dataset version, progress, metrics, evaluations) and
its learning curve: what ``aerohrl runs show RUN`` prints (the command: :mod:`aerohrl.runs`).

The plot (``RUN/learning_curve.png`` unless ``--out``) follows thesis Fig. 3.3/3.4: the
closed-loop success rate against training steps (one line per evaluation task: the
trainer's periodic evaluations and, when ``aerohrl eval`` has been run, its results of
every evaluated checkpoint), with the training losses beside it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from aerohrl.atomic import save_figure


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
    pts: list[tuple]
    near: Sequence[tuple | float]
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
            out.append(
                {
                    "name": f.parent.name,
                    "success": 100 * float(d["success_mean"]),
                    "std": 100 * float(d["success_std"]),
                    "near": 100 * float(d["near_success_mean"]),
                    "checkpoints": len(steps),
                    "episodes": int(d["episodes"]),
                    "steps": (min(steps), max(steps)) if steps else (0, 0),
                }
            )
        except (OSError, ValueError, KeyError, TypeError):
            out.append({"name": f.parent.name, "damaged": True})
    return out


__all__ = ["summary", "training_seconds", "plot_learning_curve", "eval_results"]
