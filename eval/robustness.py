"""Robustness curves: success against the size of one perturbation at a time (``aerohrl eval robustness``).

For each axis of :data:`AXES` (or the ones asked for) and each magnitude from nominal up,
the study flies

* each group of runs' policies (a curve per group, e.g. the seeds of a nominal recipe and
  of its domain-randomised twin): ``aerohrl eval --task TASK --perturb ...`` on each run
  (newest checkpoints; the per-run results land in ``RUN/eval/<task>-perturb-<slug>/`` as
  usual), the curve being their mean success, with the per-run values kept;
* the geometric expert tracking its references (the classical reference curve): ``episodes``
  minimum-time references from hover at the origin to goals of the first run's dataset's
  rho_D, planned and flown as that dataset's expert flew them (:func:`aerohrl.datagen.build.plan_references`
  and :func:`~aerohrl.datagen.build.rollout_expert`, without action noise) on the same
  perturbed plant, success = the goal-reached test at any step within the task's horizon.

An axis stops after the first magnitude at which every curve is below :data:`BREAK` (success
< 90 %; ``full`` flies them all). A curve's breaking point is the first magnitude, going out
from nominal, at which its success is below :data:`BREAK`. Writes
``robustness.csv`` (one row per axis, magnitude and curve), ``robustness.md`` (the tables
and the breaking points) and ``robustness-<axis>.png`` under the output folder.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from aerohrl import atomic, task
from aerohrl.errors import UserError

if TYPE_CHECKING:
    from aerohrl.datagen.spec import DatasetSpec

BREAK = 0.9  # success below this is broken
WIND_DRAG = 0.5  # 1/s: the wind axis's drag (wind acts through it)
EXPERT_STREAM = 29  # seed stream of the expert's references: [seed, 29]


@dataclass(frozen=True)
class Axis:
    """One perturbation axis: its magnitudes (the first is nominal) and the fields each sets."""

    name: str
    label: str  # x-axis label, with unit
    values: tuple[float, ...]
    fields: Callable[[float], dict[str, float]]


AXES: dict[str, Axis] = {
    a.name: a
    for a in (
        Axis("mass", "mass scale", (1.0, 1.1, 1.2, 1.3, 1.5, 1.75, 2.0), lambda x: {"mass": x}),
        Axis("inertia", "inertia scale", (1.0, 1.5, 2.0, 3.0, 5.0, 8.0), lambda x: {"inertia": x}),
        Axis("thrust", "thrust coefficient scale", (1.0, 0.95, 0.9, 0.85, 0.8, 0.7, 0.6), lambda x: {"thrust": x}),
        Axis("torque", "yaw moment coefficient scale", (1.0, 0.5, 0.25, 0.1), lambda x: {"torque": x}),
        Axis("motor_tau", "motor time constant scale", (1.0, 2.0, 4.0, 8.0, 16.0), lambda x: {"motor_tau": x}),
        Axis("latency", "latency (s)", (0.0, 0.01, 0.02, 0.03, 0.05, 0.08, 0.12, 0.2), lambda x: {"latency": x}),
        Axis(
            "wind",
            f"mean wind (m/s), gusts a third of it, drag {WIND_DRAG:g} 1/s",
            (0.0, 1.0, 2.0, 3.0, 5.0, 8.0),
            lambda x: {"drag": WIND_DRAG, "wind": x, "gust": x / 3.0},
        ),
        Axis(
            "noise",
            "observation noise, multiples of (2 cm, 5 cm/s, 1 deg)",
            (0.0, 0.5, 1.0, 2.0, 4.0, 8.0),
            lambda x: {"pos_noise": 0.02 * x, "vel_noise": 0.05 * x, "att_noise": math.radians(1.0) * x},
        ),
        Axis(
            "combined",
            "every axis at once, multiples of (mass +20 %, thrust -15 %, motor tau x2, 20 ms, "
            "3 m/s wind + 1 m/s gusts, noise 2 cm / 5 cm/s / 1 deg)",
            (0.0, 0.25, 0.5, 0.75, 1.0, 1.5),
            lambda x: {
                "mass": 1.0 + 0.2 * x,
                "thrust": max(1.0 - 0.15 * x, 0.05),
                "motor_tau": 1.0 + x,
                "latency": 0.02 * x,
                "drag": WIND_DRAG,
                "wind": 3.0 * x,
                "gust": 1.0 * x,
                "pos_noise": 0.02 * x,
                "vel_noise": 0.05 * x,
                "att_noise": math.radians(1.0) * x,
            },
        ),
    )
}
EXPERT = "expert"  # the label of the geometric expert's curve


def perturbation_text(axis: Axis, x: float) -> str | None:
    """The ``--perturb`` text of magnitude ``x`` of ``axis`` (None: the nominal model)."""
    from aerohrl.sim.perturb import Perturbation

    p = Perturbation(**axis.fields(x))
    p.check()
    return None if p.nominal else p.text()


def parse_values(items: list[str] | None) -> dict[str, tuple[float, ...]]:
    """``AXIS=V1:V2:...`` items (``--values``) -> magnitudes per axis; one-line UserError when bad."""
    out: dict[str, tuple[float, ...]] = {}
    for item in items or []:
        name, eq, vals = item.partition("=")
        if not eq or name not in AXES:
            raise UserError(f"--values {item!r}: expected AXIS=V1:V2:... with AXIS one of {', '.join(AXES)}")
        try:
            out[name] = tuple(float(v) for v in vals.split(":") if v.strip())
        except ValueError:
            raise UserError(f"--values {item!r}: magnitudes must be numbers") from None
        if not out[name]:
            raise UserError(f"--values {item!r}: no magnitudes")
        for x in out[name]:
            perturbation_text(AXES[name], x)  # a one-line error for a magnitude out of range
    return out


def parse_groups(items: list[str] | None) -> dict[str, list[Path]]:
    """``LABEL=RUN[,RUN...]`` items (``--group``) -> runs per curve label; one-line UserError when bad."""
    out: dict[str, list[Path]] = {}
    for item in items or []:
        label, eq, runs = item.partition("=")
        label = label.strip()
        paths = [Path(r.strip()) for r in runs.split(",") if r.strip()]
        if not eq or not label or not paths:
            raise UserError(f"--group {item!r}: expected LABEL=RUN[,RUN...]")
        if label in out or label in ("policy", EXPERT):
            raise UserError(f"--group {item!r}: the label {label!r} is taken (policy: --run, expert: the expert's curve)")
        out[label] = paths
    return out


# ----------------------------------------------------------------------------- the expert
def expert_spec(info_spec: dict | None) -> DatasetSpec:
    """The :class:`~aerohrl.datagen.spec.DatasetSpec` of a dataset's recorded spec, its expert
    flying clean (no action noise) from rest."""
    from aerohrl.datagen.spec import DatasetSpec

    names = {f.name for f in fields(DatasetSpec)}
    vals = {k: tuple(v) if isinstance(v, list) else v for k, v in (info_spec or {}).items() if k in names}
    spec = DatasetSpec(**vals)
    return replace(spec, action_noise=(0.0, 0.0, 0.0, 0.0), start_states="rest", world="free", family="navigate")


def expert_flights(
    spec: DatasetSpec, episodes: int, seed: int, horizon: int, perturbation_text_: str | None
) -> tuple[np.ndarray, np.ndarray]:
    """The geometric expert flying min-time references of ``spec`` from hover (seeded by
    ``seed``) on the perturbed plant: its achieved goals (horizon, episodes, 15) over the
    ``horizon`` steps after take-off, and the goals (episodes, 15)."""
    from aerohrl.datagen import goals as goals_mod
    from aerohrl.datagen.build import plan_references, rollout_expert
    from aerohrl.sim.perturb import Perturbation

    rng = np.random.default_rng([seed, EXPERT_STREAM])
    goals, T, coeffs, _, _ = plan_references(spec, rng, n=episodes)
    steps = int(np.ceil(T.max() * spec.fps - 1e-9))
    p = Perturbation.parse(perturbation_text_) if perturbation_text_ else None
    r = rollout_expert(
        spec, goals, T, coeffs, progress=False, perturbation=p, perturb_seed=seed, extra_steps=max(0, horizon - steps)
    )
    return task.achieved_goal(r.states[1 : horizon + 1]), goals_mod.goal_vectors(goals)


def expert_success(
    spec: DatasetSpec,
    episodes: int,
    seed: int,
    horizon: int,
    perturbation_text_: str | None,
    tol: task.GoalTolerance = task.TOLERANCE,
) -> np.ndarray:
    """(episodes,) bool: the geometric expert reaches its goal within ``horizon`` steps on the
    perturbed plant (:func:`expert_flights`) under the goal test with tolerances ``tol``."""
    achieved, G = expert_flights(spec, episodes, seed, horizon, perturbation_text_)
    hit: np.ndarray = task.goal_reached(achieved, G[None], tol)
    return np.asarray(hit.any(axis=0))


# ----------------------------------------------------------------------------- the study
@dataclass
class Point:
    axis: str
    value: float
    curve: str  # a group of runs' label, or EXPERT
    success: float  # mean over per_run
    per_run: tuple[float, ...]
    perturb: str


def run_study(
    groups: dict[str, list[Path]],
    *,
    axes: list[str],
    task_name: str = "reach-novel",
    episodes: int = 100,
    checkpoints: int = 1,
    seed: int = 0,
    values: dict[str, tuple[float, ...]] | None = None,
    expert: bool = True,
    expert_observer: float | None = None,
    device: str = "cpu",
    full: bool = False,
    log: Callable[[str], None] = print,
) -> list[Point]:
    """The curves of ``axes`` (module doc): one per group of runs (label -> runs), each
    point's success the mean over the group's runs, and the expert's (``expert_observer``:
    its disturbance observer's time constant, else the runs' dataset's)."""
    from aerohrl.eval.harness import EvalOptions, build_episodes, evaluate_run, load_run_dataset

    unknown = [a for a in axes if a not in AXES]
    if unknown:
        raise UserError(f"unknown robustness axis {unknown[0]!r} (choose from: {', '.join(AXES)})")
    groups = {label: list(rs) for label, rs in groups.items() if rs}
    if EXPERT in groups:
        raise UserError(f"{EXPERT!r} names the expert's curve; give the runs another label")
    runs = [r for rs in groups.values() for r in rs]
    if not runs and not expert:
        raise UserError("nothing to fly: give runs, or keep the expert curve")
    if expert and task_name == "maze":
        raise UserError("the expert's curve flies free-space references; pass --no-expert with --task maze")
    shared: dict[Path, Any] = {}  # the seeds of a group share their dataset
    loaded = {run: load_run_dataset(run, cache=shared) for run in runs}
    info_spec = next(iter(loaded.values()))[0].info.get("spec") if loaded else None
    spec = expert_spec(info_spec)
    if expert_observer is not None:  # the expert with (or without) a disturbance observer
        spec = replace(spec, disturbance_observer=float(expert_observer))
    horizon = 500  # Reach-Desired's and Reach-Novel's
    if loaded:  # the task's own horizon
        eps = build_episodes(next(iter(loaded.values()))[0], EvalOptions(task=task_name, episodes=1, seed=seed))
        horizon = int(eps.horizons.max())
    points: list[Point] = []
    for name in axes:
        axis = AXES[name]
        for x in (values or {}).get(name, axis.values):
            text = perturbation_text(axis, x)
            here: list[Point] = []
            for label, members in groups.items():
                rates = []
                for run in members:
                    opt = EvalOptions(
                        task=task_name,
                        episodes=episodes,
                        checkpoints=checkpoints,
                        perturb=text,
                        seed=seed,
                        device=device,
                        record=False,
                        progress=False,
                    )
                    rates.append(float(evaluate_run(run, opt, loaded=loaded[run])["success_mean"]))
                here.append(Point(name, x, label, float(np.mean(rates)), tuple(rates), text or ""))
            if expert:
                s = float(expert_success(spec, episodes, seed, horizon, text).mean())
                here.append(Point(name, x, EXPERT, s, (s,), text or ""))
            points += here
            log(f"{name} {x:g}: " + ", ".join(f"{p.curve} {p.success:.3f}" for p in here))
            if not full and all(p.success < BREAK for p in here):
                break
    return points


def breaking_points(points: list[Point]) -> dict[tuple[str, str], float | None]:
    """(axis, curve) -> the first magnitude from nominal whose success is below :data:`BREAK` (None: not reached)."""
    out: dict[tuple[str, str], float | None] = {}
    for p in points:
        key = (p.axis, p.curve)
        out.setdefault(key, None)
        if out[key] is None and p.success < BREAK:
            out[key] = p.value
    return out


def _cell(p: Point) -> str:
    """A table cell: the mean, with the std and the per-run values when a curve has several runs."""
    if len(p.per_run) < 2:
        return f"{p.success:.3f}"
    return f"{p.success:.3f} ± {float(np.std(p.per_run)):.3f} (" + "/".join(f"{r:.2f}" for r in p.per_run) + ")"


def write_results(
    points: list[Point], out: Path, *, groups: dict[str, list[Path]], task_name: str, episodes: int, command: str = ""
) -> None:
    """``robustness.csv``, ``robustness.md`` and one ``robustness-<axis>.png`` per axis under ``out`` (atomic)."""
    out.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["axis", "value", "curve", "success", "per_run", "perturb"])
    for p in points:
        w.writerow([p.axis, f"{p.value:g}", p.curve, f"{p.success:.4f}", " ".join(f"{r:.4f}" for r in p.per_run), p.perturb])
    atomic.write_text(out / "robustness.csv", buf.getvalue())
    bp = breaking_points(points)
    described = [
        f"{label} = task {task_name}, mean over {len(rs)} run(s) " + ", ".join(f"`{r}`" for r in rs)
        for label, rs in groups.items()
        if rs
    ]
    lines = [
        "# Robustness curves",
        "",
        f"{episodes} episodes per point; "
        + "".join(d + "; " for d in described)
        + f"{EXPERT} = the geometric controller tracking min-time references from hover on the same plant.",
        "",
    ]
    if command:
        lines += ["```", command, "```", ""]
    lines += [f"Breaking point: the first magnitude from nominal at which success < {BREAK:.0%}.", ""]
    lines += ["| axis | curve | breaking point |"]
    lines.append("|---|---|---|")
    for (axis_name, curve), v in bp.items():
        lines.append(f"| {axis_name} | {curve} | {'not reached' if v is None else f'{v:g}'} |")
    for name in dict.fromkeys(p.axis for p in points):
        axis = AXES[name]
        curves = list(dict.fromkeys(p.curve for p in points if p.axis == name))
        xs = list(dict.fromkeys(p.value for p in points if p.axis == name))
        lines += ["", f"## {name}: {axis.label}", "", "| magnitude | " + " | ".join(curves) + " |"]
        lines.append("|---" * (len(curves) + 1) + "|")
        table = {(p.value, p.curve): p for p in points if p.axis == name}
        for x in xs:
            lines.append(f"| {x:g} | " + " | ".join(_cell(table[(x, c)]) if (x, c) in table else "-" for c in curves) + " |")
        lines += ["", f"![{name}](robustness-{name}.png)"]
        _plot(points, name, out / f"robustness-{name}.png")
    atomic.write_text(out / "robustness.md", "\n".join(lines) + "\n")


def _plot(points: list[Point], name: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.4))
    for curve in dict.fromkeys(p.curve for p in points if p.axis == name):
        pts = [p for p in points if p.axis == name and p.curve == curve]
        x, y = [p.value for p in pts], [p.success for p in pts]
        line = ax.plot(x, y, "s--" if curve == EXPERT else "o-", label=curve)[0]
        if any(len(p.per_run) > 1 for p in pts):  # the spread over the runs (seeds)
            sd = np.array([float(np.std(p.per_run)) for p in pts])
            ax.fill_between(x, np.array(y) - sd, np.array(y) + sd, color=line.get_color(), alpha=0.2, lw=0)
    ax.axhline(BREAK, color="grey", lw=0.8, ls=":")
    ax.set_xlabel(AXES[name].label, fontsize=7 if len(AXES[name].label) > 60 else None)
    ax.set_ylabel("success")
    ax.set_ylim(-0.02, 1.02)
    ax.legend()
    fig.tight_layout()
    atomic.save_figure(fig, path, dpi=120)
    plt.close(fig)
