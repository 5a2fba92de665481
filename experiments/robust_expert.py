"""The geometric expert with and without a disturbance observer on perturbed vehicles: the
robustness study's expert curve (``aerohrl eval robustness --expert-observer TAU``) for
several observer time constants, on every axis at every magnitude, and at the robustness
issue's target magnitudes. Writes a dated page under docs/results/ and one figure with a
panel per axis.

    python experiments/robust_expert.py --taus 0 0.25 0.5 --episodes 100
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from datetime import date
from pathlib import Path

import numpy as np

# the robustness issue's target magnitudes, per axis (the first mass value is the lighter vehicle)
TARGETS = {
    "mass": (0.8, 1.2),
    "thrust": (1.15, 0.85),
    "motor_tau": (2.0,),
    "latency": (0.02,),
    "wind": (3.0,),
    "noise": (1.0,),
    "combined": (1.0,),
}


def label(tau: float) -> str:
    return "expert" if tau == 0 else f"expert + observer, tau {tau:g} s"


def study(taus: list[float], episodes: int, seed: int) -> tuple[dict, dict]:
    """``(curves, targets)``: ``{tau: [Point]}`` over every axis's magnitudes, and
    ``{tau: {(axis, value): success}}`` at the target magnitudes."""
    from aerohrl.eval.robustness import AXES, run_study

    curves, targets = {}, {}
    for tau in taus:
        curves[tau] = run_study({}, axes=list(AXES), episodes=episodes, seed=seed, expert_observer=tau, full=True, log=print)
        pts = run_study(
            {},
            axes=list(TARGETS),
            episodes=episodes,
            seed=seed,
            expert_observer=tau,
            full=True,
            values={a: v for a, v in TARGETS.items()},
            log=print,
        )
        targets[tau] = {(p.axis, p.value): p.success for p in pts}
    return curves, targets


def plot(curves: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aerohrl.atomic import save_figure
    from aerohrl.eval.robustness import AXES, BREAK

    names = list(AXES)
    fig, axes = plt.subplots(3, 3, figsize=(13, 10))
    for ax, name in zip(axes.ravel(), names):
        for tau, pts in curves.items():
            xs = [p.value for p in pts if p.axis == name]
            ys = [100 * p.success for p in pts if p.axis == name]
            ax.plot(xs, ys, marker="o", ms=4, label=label(tau))
        ax.axhline(100 * BREAK, color="grey", ls=":", lw=1)
        ax.set_xlabel(textwrap.fill(AXES[name].label, 55), fontsize=8)
        ax.set_ylabel("success %")
        ax.set_title(name)
        ax.grid(alpha=0.3)
    axes.ravel()[0].legend(fontsize=8)
    fig.suptitle("The geometric expert on perturbed vehicles, with and without a disturbance observer (Reach-Novel goals)")
    fig.tight_layout()
    save_figure(fig, path, dpi=90)
    plt.close(fig)


def page(curves: dict, targets: dict, episodes: int, seed: int, figure: str, command: str) -> str:
    from aerohrl.eval.robustness import AXES, breaking_points

    taus = list(curves)
    lines = [
        f"```bash\n{command}\n```",
        "",
        f"{episodes} episodes per point (min-time references to Reach-Novel goals from hover, seed {seed}), success = the "
        "goal test within 500 steps.",
        "",
        "## At the target magnitudes",
        "",
        "| perturbation | " + " | ".join(label(t) for t in taus) + " |",
        "|---|" + "---|" * len(taus),
    ]
    for axis, value in next(iter(targets.values())):
        lines.append(f"| {axis} {value:g} | " + " | ".join(f"{100 * targets[t][(axis, value)]:.0f}" for t in taus) + " |")
    lines += ["", "## Breaking points (first magnitude with success below 90 %)", ""]
    lines += ["| axis | " + " | ".join(label(t) for t in taus) + " |", "|---|" + "---|" * len(taus)]
    bps = {t: breaking_points(curves[t]) for t in taus}
    for name in AXES:
        cells = []
        for t in taus:
            v = bps[t].get((name, "expert"))
            cells.append("not reached" if v is None else f"{v:g}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", f"![curves]({figure})", "", "## Every point", ""]
    for name in AXES:
        xs = sorted({p.value for t in taus for p in curves[t] if p.axis == name}, key=lambda x: AXES[name].values.index(x))
        lines += [f"**{name}** ({AXES[name].label})", "", "| magnitude | " + " | ".join(label(t) for t in taus) + " |"]
        lines += ["|---|" + "---|" * len(taus)]
        for x in xs:
            row = []
            for t in taus:
                v = [p.success for p in curves[t] if p.axis == name and p.value == x]
                row.append(f"{100 * v[0]:.0f}" if v else "")
            lines.append(f"| {x:g} | " + " | ".join(row) + " |")
        lines.append("")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from aerohrl.errors import run_cli

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--taus", type=float, nargs="+", default=[0.0, 0.25, 0.5], help="observer time constants, s (0: none)")
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--results-dir", type=Path, default=Path("docs/results"))
    ap.add_argument("--page", default="robust-expert-curves", help="the page's name after its date")
    a = ap.parse_args(argv)

    def go() -> int:
        from aerohrl import atomic
        from aerohrl.errors import UserError

        if any(not np.isfinite(t) or t < 0 for t in a.taus):
            raise UserError("--taus must be >= 0")
        curves, targets = study(a.taus, a.episodes, a.seed)
        stem = f"{date.today().isoformat()}-{a.page}"
        fig = a.results_dir / "figures" / f"{stem}.png"
        plot(curves, fig)
        command = "python experiments/robust_expert.py " + " ".join(argv if argv is not None else sys.argv[1:])
        text = f"# The expert's robustness curves, with and without a disturbance observer ({date.today().isoformat()})\n\n"
        text += page(curves, targets, a.episodes, a.seed, f"figures/{fig.name}", command)
        out = a.results_dir / f"{stem}.md"
        atomic.write_text(out, text)
        print(out)
        return 0

    return run_cli("experiments/robust_expert.py", go)


if __name__ == "__main__":
    sys.exit(main())
