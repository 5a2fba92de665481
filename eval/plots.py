"""Plots of evaluations (matplotlib, Agg).

* :func:`plot_trajectories` — thesis Fig. 3.5 / 3.6 analogues: 3D flight paths of the
  newest evaluated checkpoint (``trajectories-step-N.npz``), successes and failures in
  two panels, each path drawn up to the episode's last step in its own colour, with its
  end point, its task goal (star) and its planned intermediate goals (triangles) in the
  same colour; starts in orange.
* :func:`plot_maze` — a maze evaluation from above: walls, starts and goals of the
  tasks, flown paths coloured by outcome (success, collision, out of time).
* :func:`plot_learning_curves` — thesis Fig. 3.3 / 3.4 analogues: closed-loop success
  against training steps from the runs' ``metrics.jsonl`` (the trainer's periodic
  evaluations) and, dashed, the per-checkpoint results of ``aerohrl eval`` for
  Reach-Desired and Reach-Intermediate when present. Runs that differ only in their seed
  (:func:`aerohrl.eval.results.group_runs`) are one curve: the mean over seeds at each
  step the seeds share, in a band from the lowest to the highest seed (n seeds in the label).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from aerohrl.atomic import save_figure
from aerohrl.errors import UserError

if TYPE_CHECKING:
    from aerohrl.envs.episodes import EpisodeSet


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, out: str | Path) -> Path:
    return save_figure(fig, out, dpi=110)


def _eval_dir(run, task: str, planner: str | None) -> Path:
    base = Path(run) / "eval"
    if task != "ood":
        d = base / task
    elif planner:
        d = base / f"ood-{planner}"
        if not d.is_dir():
            alt = sorted(base.glob(f"ood-{planner}*"))
            d = alt[0] if alt else d
    else:
        cands = [p for p in sorted(base.glob("ood-*")) if p.name != "ood-none"] or sorted(base.glob("ood-*"))
        if not cands:
            raise UserError(f"run {run} has no ood evaluation (run `aerohrl eval --task ood --run {run}` first)")
        d = cands[0]
    if not d.is_dir():
        raise UserError(f"run {run} has no {d.name} evaluation (run `aerohrl eval --task {task} --run {run}` first)")
    return d


def plot_maze(episodes: EpisodeSet, r: dict, out: str | Path, *, title: str = "", max_per_task: int = 10) -> Path:
    """Top-down view of a maze evaluation: the walls (grey cells), every task's start
    (circle) and goal (star) cells, and up to ``max_per_task`` flown paths per task
    (``r["positions"]`` (E, T+1, 3), each up to its last step): successes green,
    collisions red (a cross where it hit), the rest (out of time) orange."""
    from aerohrl.worlds.maze import maze_from_dict

    plt = _plt()
    maze = maze_from_dict(episodes.meta["maze"])
    rows, cols = maze.shape
    c = maze.cell
    fig, ax = plt.subplots(figsize=(1.0 + 0.45 * cols, 0.6 + 0.45 * rows))
    ax.imshow(maze.walls, cmap="Greys", vmin=0, vmax=1.6, origin="lower", extent=(0, cols * c, 0, rows * c))
    which = np.asarray(episodes.meta["maze_task"])
    pos = r["positions"]
    for k in np.unique(which):
        idx = np.flatnonzero(which == k)[:max_per_task]
        for i in idx:
            p = pos[i, : int(r["steps"][i]) + 1]
            color = "tab:green" if r["success"][i] else ("tab:red" if r["collision"][i] else "tab:orange")
            ax.plot(p[:, 0], p[:, 1], color=color, lw=0.8, alpha=0.7)
            if r["collision"][i]:
                ax.plot(p[-1, 0], p[-1, 1], "x", color="tab:red", ms=5)
        s, g = maze.tasks[int(k) - 1]
        ps, pg = maze.cell_center(np.array(s)), maze.cell_center(np.array(g))
        ax.plot(ps[0], ps[1], "o", color="tab:blue", ms=7, mec="k")
        ax.plot(pg[0], pg[1], "*", color="gold", ms=13, mec="k")
        ax.annotate(str(k), ps[:2], xytext=(4, 4), textcoords="offset points", fontsize=8)
        ax.annotate(str(k), pg[:2], xytext=(4, 4), textcoords="offset points", fontsize=8)
    ax.set_xlim(0, cols * c)
    ax.set_ylim(0, rows * c)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    rate = f"success {100 * r['success'].mean():.0f} %, collision {100 * r['collision'].mean():.0f} %"
    ax.set_title(f"{title}\n{rate}" if title else rate, fontsize=9)
    fig.tight_layout()
    out = _save(fig, out)
    plt.close(fig)
    return out


def plot_trajectories(run: str | Path, task: str, out: str | Path, planner: str | None = None, max_per_panel: int = 12) -> Path:
    """3-D flight paths of the newest evaluated checkpoint of ``run`` on ``task`` (thesis
    Fig. 3.5 / 3.6 analogues; module docstring), successes and failures in two panels of
    at most ``max_per_panel`` paths; written to ``out``, returns it."""
    from aerohrl.eval.tasks import TASKS

    if task not in TASKS:
        raise UserError(f"unknown task {task!r} (choose from {', '.join(TASKS)})")
    d = _eval_dir(run, task, planner)
    files = sorted(d.glob("trajectories-step-*.npz"))
    if not files:
        raise UserError(f"{d} holds no trajectories (re-run the evaluation)")
    z = np.load(files[-1])
    pos, goals, starts, steps, succ = z["positions"], z["goals"], z["start_states"], z["steps"], z["success"]
    wps = z["waypoints"] if "waypoints" in z.files else None
    plt = _plt()
    fig = plt.figure(figsize=(12, 5.5))
    rng = np.random.default_rng(0)
    # the view box: starts, goals and planned goals with a 1 m margin; path points outside
    # it are not drawn (a diverging failure would otherwise shrink everything else to a dot)
    marks = [starts[:, :3], goals[:, :3]] + ([wps[:, :, :3].reshape(-1, 3)] if wps is not None else [])
    lo, hi = np.min([m.min(0) for m in marks], 0) - 1.0, np.max([m.max(0) for m in marks], 0) + 1.0
    for k, (label, mask) in enumerate((("successes", succ), ("failures", ~succ))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        idx = np.flatnonzero(mask)
        if len(idx) > max_per_panel:
            idx = np.sort(rng.choice(idx, max_per_panel, replace=False))
        left = 0
        colours = plt.get_cmap("tab10" if len(idx) <= 10 else "tab20")
        for j, i in enumerate(idx):
            c = colours(j % colours.N)  # each flight, its end, its goal and its planned goals in one colour
            p = pos[i, : steps[i] + 1].astype(np.float64)
            outside = ((p < lo) | (p > hi)).any(1)
            left += bool(outside.any())
            p[outside] = np.nan
            ax.plot(p[:, 0], p[:, 1], p[:, 2], lw=1.0, alpha=0.8, color=c)
            if np.isfinite(p[-1]).all():  # where the episode ended
                ax.scatter(*p[-1], color=c, s=10, depthshade=False)
            ax.scatter(*goals[i, :3], color=c, s=70, marker="*", edgecolors="black", linewidths=0.4, depthshade=False)
            if wps is not None:
                ax.scatter(*wps[i, :, :3].T, color=c, s=30, marker="^", edgecolors="black", linewidths=0.4, depthshade=False)
        if len(idx):
            ax.scatter(*starts[idx, :3].T, c="orange", s=18, depthshade=False)
            from matplotlib.lines import Line2D

            key = [
                Line2D([], [], color="orange", marker="o", ls="", ms=4, label="start"),
                Line2D([], [], color="grey", lw=1, label="flight (one colour per episode)"),
                Line2D([], [], color="grey", marker=".", ls="", ms=5, label="where it ended"),
                Line2D([], [], color="grey", marker="*", ls="", ms=9, mec="black", mew=0.4, label="its goal"),
            ]
            if wps is not None:
                key.append(Line2D([], [], color="grey", marker="^", ls="", ms=6, mec="black", mew=0.4, label="its planned goals"))
            ax.legend(handles=key, loc="upper left", fontsize=7)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(lo[2], hi[2])
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")
        ax.set_title(f"{label}: {int(mask.sum())} of {len(mask)} (drawn {len(idx)}, {left} leave the box)", fontsize=10)
    step = files[-1].stem.split("-")[-1]
    fig.suptitle(f"{Path(run).name}: {d.name}, checkpoint step {int(step):,}")
    fig.tight_layout()
    out = _save(fig, out)
    plt.close(fig)
    return out


def _seed_band(curves: list[list[tuple[int, float]]]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(steps, mean, low, high) over the seeds' curves, at the steps every seed logged."""
    common = sorted(set.intersection(*(set(st for st, _ in c) for c in curves)))
    vals = np.array([[dict(c)[st] for st in common] for c in curves])  # (seeds, steps)
    return np.array(common), vals.mean(0), vals.min(0), vals.max(0)


CURVE_TASKS = ("reach-desired", "reach-intermediate", "reach-novel", "maze")  # flat evaluations drawn as curves


def plot_learning_curves(runs: Sequence[str | Path], out: str | Path) -> Path:
    """Closed-loop success against training steps for ``runs``; seeds of one experiment as
    a mean line with a min-max band. Written to ``out``; returns it."""
    from aerohrl.algorithms.run import read_metrics
    from aerohrl.eval.results import ALGO_NAMES, _algo_of, group_runs, read_summary

    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    drawn = 0
    for group in group_runs(runs):
        algo = ALGO_NAMES.get(_algo_of(group[0]), _algo_of(group[0]))
        name = group[0].name if len(group) == 1 else f"{group[0].name} +{len(group) - 1}"
        series: dict[tuple[str, str], list[list[tuple[int, float]]]] = {}
        for rd in group:
            metrics = read_metrics(rd)
            for k in sorted({k for r in metrics for k in r if k.startswith("eval/") and k.endswith("/success")}):
                pts = [(int(r["step"]), 100 * r[k]) for r in metrics if k in r]
                series.setdefault((k.split("/")[1].replace("_", "-"), "training log"), []).append(pts)
            for task_name in CURVE_TASKS:  # the harness's per-checkpoint results
                sm = read_summary(rd, task_name)
                if sm:
                    pts = [(int(c["step"]), 100 * c["success"]) for c in sm["checkpoints"]]
                    series.setdefault((task_name, f"aerohrl eval, {sm['episodes']} ep."), []).append(pts)
        for (task_name, source), curves in series.items():
            harness = source.startswith("aerohrl")
            if len(curves) == 1:
                (line,) = ax.plot(
                    *zip(*curves[0]),
                    marker="s" if harness else "o",
                    ms=3,
                    ls="--" if harness else "-",
                    label=f"{algo} ({name}): {task_name} ({source})",
                )
            else:
                st, mean, lo, hi = _seed_band(curves)
                if not len(st):
                    continue  # the seeds share no step (yet)
                (line,) = ax.plot(
                    st,
                    mean,
                    marker="s" if harness else "o",
                    ms=3,
                    ls="--" if harness else "-",
                    label=f"{algo} ({name}): {task_name} ({source}), mean of {len(curves)} seeds, band min-max",
                )
                ax.fill_between(st, lo, hi, color=line.get_color(), alpha=0.2, lw=0)
            drawn += 1
    if not drawn:
        raise UserError("none of the runs logged a closed-loop evaluation (train with --eval-every > 0 or run `aerohrl eval`)")
    ax.set_xlabel("training step")
    ax.set_ylabel("success rate (%)")
    ax.set_ylim(-2, 102)
    ax.set_title("closed-loop success during training (thesis Fig. 3.3/3.4)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    out = _save(fig, out)
    plt.close(fig)
    return out


__all__ = ["plot_trajectories", "plot_learning_curves", "plot_maze"]
