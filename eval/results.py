"""Evaluation files and the thesis-style tables.

Per evaluation ``RUN/eval/<name>/`` (``<name>`` = the task, or ``ood-<planner>``)::

    episodes-step-NNNNNNNNN.csv   one row per episode and checkpoint: start state, goal,
                                  horizon, source episode/frame, outcome, first step of
                                  success / near success, final errors, planned goals
    trajectories-step-N.npz       positions (E, T+1, 3), goals, planned goals, outcomes
                                  (newest checkpoint only; what `eval plot` draws)
    summary.json                  per checkpoint rates, mean ± std over checkpoints
                                  (thesis Table 3.1 protocol), options, dataset identity

Every file is written to a temporary name and renamed. ``std`` is the population
standard deviation over the evaluated checkpoints (ddof 0; the thesis does not say).
"""

from __future__ import annotations

import csv
import io
import json
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Sequence

import numpy as np

from aerohrl import atomic, task
from aerohrl.errors import UserError

if TYPE_CHECKING:
    from aerohrl.eval.harness import EvalOptions
    from aerohrl.envs.episodes import EpisodeSet

# thesis Table 3.1 (success %, mean ± std over the last 10 checkpoints) and Table 3.2
THESIS_T31 = {
    "cql": {"reach-desired": (0.0, 0.0), "reach-intermediate": (0.0, 0.0)},
    "td3bc": {"reach-desired": (85.2, 4.29), "reach-intermediate": (67.6, 2.23)},
    "td3awbc": {"reach-desired": (82.8, 7.28), "reach-intermediate": (66.8, 3.52)},
    "gcsl": {"reach-desired": (93.2, 3.78), "reach-intermediate": (75.6, 3.78)},
}
THESIS_T32 = {"single": (11.6, 29.2), "none": (0.0, 4.4)}  # (success %, near success %)
ALGO_NAMES = {"gcsl": "GCSL", "td3bc": "TD3-BC", "td3awbc": "TD3-AWBC", "cql": "CQL"}


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (temporary, fsync, rename); returns the path."""
    return atomic.write_text(path, text)  # temporary name, fsync, rename


def episode_rows(episodes: EpisodeSet, r: dict) -> tuple[list[str], list[list]]:
    """Header and rows of the per-episode table."""
    E = len(episodes)
    head = ["episode", "kind", "source_episode", "start_frame", "steps_ahead", "horizon"]
    head += [f"start_{n}" for n in task.STATE_NAMES] + [f"goal_{n}" for n in task.GOAL_NAMES]
    head += [
        "success",
        "near_success",
        "first_success_step",
        "first_near_step",
        "steps",
        "final_pos_err",
        "final_vel_err",
        "final_rot_err",
        "min_pos_err",
    ]
    maze = episodes.task == "maze"
    if maze:  # which task, and the crash that ended an episode
        head += ["maze_task", "collision", "collision_step"]
    wp = r.get("waypoints")
    nw = 0 if wp is None else wp.shape[1]
    for k in range(nw):
        head += [f"wp{k}_frame", f"wp{k}_px", f"wp{k}_py", f"wp{k}_pz"]
    if nw:
        head += ["plan_score", "direct_score", "legs_reached"] + (["declined"] if "declined" in r else [])
    kind = episodes.kind()
    rows = []
    for i in range(E):
        row: list[Any] = [
            i,
            kind[i],
            int(episodes.source_episode[i]),
            int(episodes.start_frame[i]),
            int(episodes.steps_ahead[i]),
            int(episodes.horizons[i]),
        ]
        row += [float(x) for x in episodes.start_states[i]] + [float(x) for x in episodes.goals[i]]
        row += [
            int(r["success"][i]),
            int(r["near_success"][i]),
            int(r["first_success_step"][i]),
            int(r["first_near_step"][i]),
            int(r["steps"][i]),
            float(r["final_pos_err"][i]),
            float(r["final_vel_err"][i]),
            float(r["final_rot_err"][i]),
            float(r["min_pos_err"][i]),
        ]
        if maze:
            row += [int(episodes.meta["maze_task"][i]), int(r["collision"][i]), int(r["collision_step"][i])]
        for k in range(nw):
            assert wp is not None  # nw > 0 only with waypoints
            row += [int(r["waypoint_frame"][i, k])] + [float(x) for x in wp[i, k, :3]]
        if nw:
            row += [float(r["plan_score"][i]), float(r["direct_score"][i]), int(r["legs_reached"][i])]
            if "declined" in r:
                row.append(int(r["declined"][i]))
        rows.append(row)
    return head, rows


def to_csv(head: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """``head`` and ``rows`` as CSV text."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(head)
    w.writerows(rows)
    return buf.getvalue()


def write_episodes(out_dir: str | Path, step: int, episodes: EpisodeSet, r: dict) -> Path:
    """Write the per-episode table of checkpoint ``step`` as ``OUT/episodes-step-N.csv``; returns the path."""
    return write_text(Path(out_dir) / f"episodes-step-{step:09d}.csv", to_csv(*episode_rows(episodes, r)))


def write_trajectories(out_dir: str | Path, step: int, episodes: EpisodeSet, r: dict) -> Path:
    """Write the flown positions, goals, starts and outcomes of checkpoint ``step`` as
    ``OUT/trajectories-step-N.npz`` (for the trajectory plots); returns the path."""
    path = Path(out_dir) / f"trajectories-step-{step:09d}.npz"
    buf = io.BytesIO()
    extra = {k: r[k] for k in ("waypoints", "planned_waypoints") if k in r}
    if episodes.task == "maze":
        extra.update(collision=r["collision"], maze_task=np.asarray(episodes.meta["maze_task"]))
    np.savez_compressed(
        buf,
        positions=r["positions"],
        goals=episodes.goals,
        start_states=episodes.start_states,
        success=r["success"],
        near_success=r["near_success"],
        steps=r["steps"],
        **extra,
    )
    return atomic.write_bytes(path, buf.getvalue())


FAR_AHEAD = 10  # Reach-Intermediate goals at least this many steps ahead: "far"


def kind_rates(episodes: EpisodeSet, r: dict, hover_success: np.ndarray | None = None) -> dict:
    """Success rates per episode kind (reach-intermediate: 'desired' / 'intermediate'), on
    the goals at least ``FAR_AHEAD`` steps ahead, and, given the hover floor's per-episode
    outcomes on the same episodes (``hover_success``), on the goals hovering misses
    (``success_beyond_hover``: what the policy reaches that the constant command
    ``[g, 0, 0, 0]`` does not; hover itself scores 0 there by construction); maze tasks:
    success, collision and mean time to the goal (s, None without a success) per task."""
    kind = episodes.kind()
    out: dict[str, float | None] = {}
    if episodes.task == "reach-intermediate":
        for k in ("desired", "intermediate"):
            m = kind == k
            if m.any():
                out[f"success_{k}"] = float(r["success"][m].mean())
        # goals >= 10 steps ahead. Hovering still meets some (eval/floors.py)
        far = episodes.steps_ahead >= FAR_AHEAD
        if far.any():
            out["success_intermediate_far"] = float(r["success"][far].mean())
        if hover_success is not None and not hover_success.all():
            out["success_beyond_hover"] = float(r["success"][~hover_success.astype(bool)].mean())
    if episodes.task == "maze":  # per task: success, collision, mean time to the goal of the successes (s)
        which = np.asarray(episodes.meta["maze_task"])
        fps = float(episodes.meta.get("fps", 100))
        for k in np.unique(which):
            m = which == k
            s = r["success"][m]
            out[f"success_task{k}"] = float(s.mean())
            out[f"collision_task{k}"] = float(r["collision"][m].mean())
            out[f"time_to_goal_task{k}"] = float(r["first_success_step"][m][s].mean() / fps) if s.any() else None
    return out


def summarize(
    per_ckpt: list[dict], *, run_dir: str | Path, meta: dict, options: EvalOptions, episodes: EpisodeSet, seconds: float
) -> dict:
    """The ``summary.json`` of an evaluation: the per-checkpoint results ``per_ckpt`` and the
    mean/std of success and near success over them, with the run, algorithm, task,
    options, dataset and timing."""
    s = np.array([c["success"] for c in per_ckpt])
    ns = np.array([c["near_success"] for c in per_ckpt])
    from dataclasses import asdict

    opts = {k: v for k, v in asdict(options).items() if k not in ("progress", "extra")}
    return {
        "format": "aerohrl-eval/1",
        "run": str(run_dir),
        "algo": (meta.get("config") or {}).get("algo"),
        "preset": (meta.get("config") or {}).get("preset"),
        "task": options.task,
        "planner": options.planner,
        "name": options.name(),
        "episodes": len(episodes),
        "horizon": int(episodes.horizons.max()),
        "checkpoints": per_ckpt,
        "success_mean": float(s.mean()),
        "success_std": float(s.std()),
        "near_success_mean": float(ns.mean()),
        "near_success_std": float(ns.std()),
        **_collision_rates(per_ckpt, episodes),
        "dataset": meta.get("dataset"),
        "options": opts,
        "seconds": seconds,
    }


def _collision_rates(per_ckpt: list[dict], episodes: EpisodeSet) -> dict:
    """Maze tasks: collision mean/std over checkpoints, the maze and its tasks' definitions."""
    if episodes.task != "maze":
        return {}
    c = np.array([x["collision"] for x in per_ckpt])
    m = episodes.meta["maze"]
    return {
        "collision_mean": float(c.mean()),
        "collision_std": float(c.std()),
        "maze": {"name": m["name"], "tasks_version": m["tasks_version"], "tasks": m["tasks"]},
        "task_horizons": {str(k): v for k, v in episodes.meta["task_horizons"].items()},
    }


def maze_table_markdown(summary: dict) -> str:
    """The per-task table of a maze evaluation (``tasks.md``): per task its start and goal
    cells, horizon, and success, collision (mean ± std over checkpoints, %) and mean time to
    the goal of the successes (s)."""
    maze = summary["maze"]
    ck = summary["checkpoints"]
    lines = [
        f"# {summary['name']}: maze {maze['name']} (tasks v{maze['tasks_version']}), {summary['algo']}, "
        f"{len(ck)} checkpoint(s), {summary['episodes']} episodes",
        "",
        "| task | start | goal | horizon (steps) | success % | collision % | time to goal (s) |",
        "|---|---|---|---|---|---|---|",
    ]

    def ms(key: str) -> str:
        v = np.array([c[key] for c in ck if c.get(key) is not None], np.float64)
        return f"{100 * v.mean():.1f} ± {100 * v.std():.1f}" if len(v) else "-"

    for k, t in enumerate(maze["tasks"], 1):
        if f"success_task{k}" not in ck[0]:
            continue
        tg = [c[f"time_to_goal_task{k}"] for c in ck if c.get(f"time_to_goal_task{k}") is not None]
        lines.append(
            f"| {k} | {tuple(t['start'])} | {tuple(t['goal'])} | {summary['task_horizons'][str(k)]} | "
            f"{ms(f'success_task{k}')} | {ms(f'collision_task{k}')} | {f'{np.mean(tg):.2f}' if tg else '-'} |"
        )
    lines.append(
        f"| all | | | | {100 * summary['success_mean']:.1f} ± {100 * summary['success_std']:.1f} | "
        f"{100 * summary['collision_mean']:.1f} ± {100 * summary['collision_std']:.1f} | |"
    )
    return "\n".join(lines) + "\n"


def write_summary(out_dir: str | Path, summary: dict) -> Path:
    """Write ``summary`` as ``OUT/summary.json`` (atomic); returns the path."""
    return write_text(Path(out_dir) / "summary.json", json.dumps(summary, indent=2, sort_keys=True) + "\n")


def read_summary(run_dir: str | Path, name: str) -> dict | None:
    """The summary of the evaluation ``name`` of a run (``RUN/eval/NAME/summary.json``);
    None when it has none."""
    p = Path(run_dir) / "eval" / name / "summary.json"
    if not p.exists():
        return None
    try:
        return json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise UserError(f"cannot read {p}: {e}") from None


def evaluation_is_current(run_dir: str | Path, name: str, episodes: int, checkpoints: int) -> bool:
    """Does the evaluation ``name`` of a run (``RUN/eval/NAME/summary.json``) already cover
    the run's newest ``checkpoints`` checkpoints with ``episodes`` episodes each, and
    postdate them? What a resumable driver asks before evaluating again (``aerohrl sweep``,
    ``make results``, the recipe study); False when the summary is missing or unreadable."""
    from aerohrl.algorithms.run import Run

    f = Path(run_dir) / "eval" / name / "summary.json"
    ckpts = Run(run_dir).checkpoints()[-checkpoints:]
    if not f.exists() or not ckpts:
        return False
    try:
        s = json.loads(f.read_text())
    except (OSError, ValueError):
        return False
    done = [c.get("checkpoint") for c in s.get("checkpoints", [])]
    return (
        s.get("episodes") == episodes
        and done == [c.name for c in ckpts]
        and f.stat().st_mtime > max(c.stat().st_mtime for c in ckpts)
    )


def _algo_of(run_dir) -> str:
    from aerohrl.algorithms.run import Run

    try:
        return Run.open(run_dir).meta["config"]["algo"]
    except (UserError, KeyError, TypeError):
        return Path(run_dir).name


def _episode_success(path: Path) -> np.ndarray:
    import csv

    with open(path, newline="") as f:
        rows = csv.reader(f)
        col = next(rows).index("success")
        return np.array([r[col] in ("1", "True", "true") for r in rows], bool)


def paired_vs_none(run_dirs: Sequence[str | Path], name: str) -> dict | None:
    """OOD planner ``name`` against flying straight (``ood-none``) on the same goals and
    checkpoints, pooled over ``run_dirs`` (one run, or the seeds of one experiment):
    per-checkpoint success difference (mean, standard error over all checkpoints of all
    seeds), the episodes only one of them succeeds in, and the exact two-sided sign test
    on those (McNemar). None when no checkpoint has both."""
    from scipy.stats import binomtest

    diffs, only_planner, only_none = [], 0, 0
    for rd in [run_dirs] if isinstance(run_dirs, (str, Path)) else run_dirs:
        d = Path(rd) / "eval"
        for f in sorted((d / name).glob("episodes-step-*.csv")):
            g = d / "ood-none" / f.name
            if not g.exists():
                continue
            a, b = _episode_success(f), _episode_success(g)
            if len(a) != len(b):
                continue
            diffs.append(a.mean() - b.mean())
            only_planner += int((a & ~b).sum())
            only_none += int((b & ~a).sum())
    if not diffs:
        return None
    n = only_planner + only_none
    x = np.array(diffs)
    return {
        "diff": float(x.mean()),
        "se": float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan"),
        "only_planner": only_planner,
        "only_none": only_none,
        "p": float(binomtest(only_planner, n).pvalue) if n else 1.0,
        "checkpoints": len(x),
    }


def _paired_cell(pv: dict | None) -> str:
    if pv is None:
        return "—"
    return (
        f"{100 * pv['diff']:+.1f} ± {100 * pv['se']:.1f} (episodes {pv['only_planner']} : {pv['only_none']}, p = {pv['p']:.2f})"
    )


# ----------------------------------------------------------------------------- seeds


def bootstrap_ci(values: Sequence[float] | np.ndarray, n: int = 10_000, seed: int = 0) -> tuple[float, float]:
    """95 % percentile bootstrap interval of the mean over seeds (nan below 2 values)."""
    v = np.asarray(values, float)
    if len(v) < 2:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    means = v[rng.integers(0, len(v), size=(n, len(v)))].mean(1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def seed_stats(values: Iterable[float]) -> dict:
    """A claim over seeds: mean, std (ddof 1; 0 for one seed), the 95 % bootstrap interval
    of the mean and every seed's value."""
    v = [float(x) for x in values]
    return {
        "mean": float(np.mean(v)),
        "std": float(np.std(v, ddof=1)) if len(v) > 1 else 0.0,
        "ci95": bootstrap_ci(v),
        "values": v,
    }


def seed_cell(st: dict | None, digits: int = 1) -> str:
    """``mean ± std [lo, hi] (v1/v2/v3)``: the interval from 3 seeds on; one seed: its value."""
    if not st:
        return "—"
    if len(st["values"]) == 1:
        return f"{st['mean']:.{digits}f}"
    vals = "/".join(f"{v:.{digits}f}" for v in st["values"])
    lo, hi = st["ci95"]
    ci = f" [{lo:.{digits}f}, {hi:.{digits}f}]" if len(st["values"]) >= 3 else ""
    return f"{st['mean']:.{digits}f} ± {st['std']:.{digits}f}{ci} ({vals})"


def group_runs(run_dirs: Sequence[str | Path]) -> list[list[Path]]:
    """The runs grouped into experiments: the same config but for the seed, on the same
    dataset version; in the order given."""
    from aerohrl.algorithms.run import Run

    groups: dict[str, list[Path]] = {}
    for rd in run_dirs:
        rd = Path(rd)
        if not rd.is_dir():
            raise UserError(f"no run at {rd}")
        try:
            meta = Run.open(rd).meta
        except UserError:  # no config.json, or a damaged one: the run is a group of its own
            meta = {}
        cfg = {k: v for k, v in (meta.get("config") or {}).items() if k not in ("seed", "dataset")}
        key = json.dumps([cfg, (meta.get("dataset") or {}).get("version"), None if cfg else str(rd)], sort_keys=True)
        groups.setdefault(key, []).append(rd)
    return list(groups.values())


def _seed_figures(runs: list[Path], name: str) -> dict | None:
    """Over the runs (seeds) with an evaluation ``name``: success (a seed's figure = the mean
    over its checkpoints), the checkpoint spread (mean over seeds of the std over
    checkpoints), near success, sizes; and Reach-Intermediate's far-goal success."""
    sums = [(rd, s) for rd in runs if (s := read_summary(rd, name))]
    if not sums:
        return None

    def over_seeds(key: str) -> dict | None:  # a per-checkpoint rate some summaries carry
        per_seed = [np.mean(f) for _, s in sums if (f := [c[key] for c in s["checkpoints"] if key in c])]
        return seed_stats([100 * x for x in per_seed]) if per_seed else None

    return {
        "success": seed_stats([100 * s["success_mean"] for _, s in sums]),
        "spread": float(np.mean([100 * s["success_std"] for _, s in sums])),
        "near": seed_stats([100 * s["near_success_mean"] for _, s in sums]),
        "near_std": float(np.mean([100 * s["near_success_std"] for _, s in sums])),
        "seeds": len(sums),
        "ckpts": len(sums[0][1]["checkpoints"]),
        "episodes": sums[0][1]["episodes"],
        "far": over_seeds("success_intermediate_far"),
        "beyond_hover": over_seeds("success_beyond_hover"),
        "planner": sums[0][1].get("planner"),
        "runs": [rd for rd, _ in sums],
    }


def _t31_row(runs: list[Path], suffix: str, th: dict) -> tuple[list[str], list[Path]] | None:
    """Table 3.1 cells of an experiment's evaluations (``suffix`` "-floor-hover" /
    "-floor-no-goal": of a floor flown on its data) and the runs that have them (make
    results flies the floors on the first seed only); None when it has neither main task."""
    cells, flown = [], []
    for name in ("reach-desired", "reach-intermediate"):
        f = _seed_figures(runs, name + suffix)
        flown += [rd for rd in (f["runs"] if f else []) if rd not in flown]
        cells += [
            seed_cell(f["success"]) if f else "—",
            f"{f['spread']:.1f}" if f else "—",
            f"{f['near']['mean']:.1f}" if f else "—",
            f"{th[name][0]:.1f} ± {th[name][1]:.2f}" if name in th else "—",
            f"{f['seeds']} x {f['ckpts']} x {f['episodes']}" if f else "0",
        ]
        if name == "reach-intermediate":  # goals >= FAR_AHEAD steps ahead; goals the hover floor misses
            cells += [seed_cell(f[k]) if f and f[k] else "—" for k in ("far", "beyond_hover")]
    nov = _seed_figures(runs, "reach-novel" + suffix)  # the generalisation diagnostic, beyond the thesis
    cells.append(f"{seed_cell(nov['success'])} (near {nov['near']['mean']:.1f})" if nov else "—")
    return (cells, flown) if any(c != "—" for c in (cells[0], cells[5])) else None


def _runs_label(runs: list[Path]) -> str:
    return (
        str(runs[0])
        if len(runs) == 1
        else f"{runs[0]} (+{len(runs) - 1} seed{'s' if len(runs) > 2 else ''}: " + ", ".join(p.name for p in runs[1:]) + ")"
    )


def floor_label(algo: str, floor: str) -> str:
    """How a table names a floor: "hover", or "<ALGO> without goal"."""
    return "hover" if floor == "hover" else f"{ALGO_NAMES.get(algo, algo)} without goal"


def _ood_variant(name: str) -> tuple[str, str | None, str | None]:
    """An OOD evaluation's folder name, ``ood-<planner>[-goaltol<x>][-floor-<floor>]``
    (EvalOptions' naming), split into (planner, goal tolerance factor, floor)."""
    m = re.fullmatch(r"ood-(.+?)(?:-goaltol([0-9.e+-]+))?(?:-floor-(.+))?", name)
    return (m.group(1), m.group(2), m.group(3)) if m else (name[4:], None, None)


def tables(run_dirs: Sequence[str | Path]) -> dict:
    """Table 3.1 / 3.2 analogues from the runs' evaluation summaries, one row per
    experiment: runs that differ only in their seed are one row, their figures over seeds
    (mean ± std, 95 % bootstrap interval, per-seed values), the checkpoint spread in a
    column of its own.

    Returns ``{"t31": (head, rows), "t32": (head, rows)}``; UserError if no run has any."""
    if not run_dirs:
        raise UserError("no runs given")
    t31, t32 = [], []
    for runs in group_runs(run_dirs):
        algo = _algo_of(runs[0])
        for suffix, label in (
            ("", ALGO_NAMES.get(algo, algo)),
            *((f"-floor-{fl}", f"floor: {floor_label(algo, fl)}") for fl in ("hover", "no-goal")),
        ):
            row = _t31_row(runs, suffix, THESIS_T31.get(algo, {}) if not suffix else {})
            if row:  # named by the runs it was flown on (a floor: the first seed's only)
                cells, flown = row
                t31.append([label, _runs_label(flown)] + cells)
        evals = sorted({p.name for rd in runs for p in (rd / "eval").glob("ood-*") if (p / "summary.json").exists()})
        for name in evals:
            f = _seed_figures(runs, name)
            assert f is not None  # evals names only evaluations some run has a summary of
            planner, tol, floor = _ood_variant(name)
            label = f"floor: {floor_label(algo, floor)}" if floor else ALGO_NAMES.get(algo, algo)
            th2 = THESIS_T32.get(planner) if algo == "gcsl" and not (tol or floor) and planner in ("none", "single") else None
            t32.append(
                [
                    label,
                    _runs_label(f["runs"]),  # the runs that have this evaluation
                    planner + (f" (goal tolerance x {tol})" if tol else ""),
                    seed_cell(f["success"]),
                    f"{f['spread']:.1f}",
                    f"{f['near']['mean']:.1f} ± {f['near_std']:.1f}" if f["seeds"] == 1 else seed_cell(f["near"]),
                    f"{th2[0]:.1f}" if th2 else "—",
                    f"{th2[1]:.1f}" if th2 else "—",
                    f"{f['seeds']} x {f['ckpts']} x {f['episodes']}",
                    # a planner against flying straight; a floor or a stricter tolerance is no planner
                    _paired_cell(paired_vs_none(runs, name)) if planner != "none" and not (tol or floor) else "—",
                ]
            )
    if not t31 and not t32:
        raise UserError("none of the runs has evaluation results (run `aerohrl eval --task ... --run RUN` first)")
    h31 = [
        "algorithm",
        "runs",
        "Reach-Desired success %",
        "ckpt spread",
        "near %",
        "thesis %",
        "seeds x ckpts x episodes",
        "Reach-Intermediate success %",
        "ckpt spread",
        "near %",
        "thesis %",
        "seeds x ckpts x episodes",
        f"RI >= {FAR_AHEAD} steps ahead %",
        "RI goals hover misses %",
        "Reach-Novel % (diagnostic)",
    ]
    h32 = [
        "algorithm",
        "runs",
        "planner",
        "success %",
        "ckpt spread",
        "near success %",
        "thesis success %",
        "thesis near %",
        "seeds x ckpts x episodes",
        "success vs none, paired: points ± s.e. (episodes won only by planner : only by none, sign test)",
    ]
    return {"t31": (h31, t31), "t32": (h32, t32)}


def markdown(head: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """``head`` and ``rows`` as a Markdown table."""
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def tables_markdown(t: dict) -> str:
    """The tables of :func:`tables` as Markdown, each with its caption."""
    out = []
    if t["t31"][1]:
        out += [
            "**Table 3.1 analogue** (success %: a seed's figure is the mean over its evaluated checkpoints; over "
            "seeds mean ± std [95 % bootstrap interval of the mean, shown with 3 or more seeds] (per-seed values); ckpt spread = the "
            "std over checkpoints, mean over seeds; near = near success, mean; thesis values beside: last 10 "
            "checkpoints x 250 episodes, one run; floors: hover, and the policy without its goal inputs)\n",
            markdown(*t["t31"]),
        ]
    if t["t32"][1]:
        out += [
            "**Table 3.2 analogue** (OOD goals; over seeds as above; thesis values for GCSL; the last column "
            "compares each planner with flying straight on the same goals and checkpoints, pooled over seeds)\n",
            markdown(*t["t32"]),
        ]
    return "\n".join(out)


def write_results_page(
    folder: str | Path,
    study: str,
    command: str,
    body: str,
    *,
    title: str | None = None,
    figures: Sequence[str | Path] = (),
    date: str | None = None,
) -> Path:
    """Write a study's result as the dated page ``FOLDER/YYYY-MM-DD-STUDY.md`` (atomic).

    The page opens with ``title`` (default: the study's name) and the command that
    produced it, then ``body`` (Markdown). Each of
    ``figures`` is copied beside the page as ``FOLDER/figures/YYYY-MM-DD-STUDY-NAME`` and
    shown below the body. ``date``: the page's day (default: today, UTC). A second run of
    the study on the same day replaces its page; the index ``FOLDER/README.md`` is kept
    by hand. Returns the page's path."""
    import datetime as _dt

    if not study or not re.fullmatch(r"[a-z0-9][a-z0-9-]*", study):
        raise UserError(f"study must be lower-case letters, digits and '-', got {study!r}")
    day = date or _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d")
    if not re.fullmatch(r"\d{4}-\d{2}-\d{2}", day):
        raise UserError(f"date must be YYYY-MM-DD, got {day!r}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"{day}-{study}"
    shown = []
    for fig in figures:
        fig = Path(fig)
        dest = folder / "figures" / f"{stem}-{fig.name}"
        dest.parent.mkdir(parents=True, exist_ok=True)
        atomic.write_bytes(dest, fig.read_bytes())
        shown.append(f"![{fig.stem}]({dest.relative_to(folder).as_posix()})")
    text = (
        f"# {title or study.replace('-', ' ').capitalize()}, {day}\n\nProduced by:\n\n```\n{command.strip()}\n```\n\n"
        + body.strip()
        + "\n"
        + "".join(f"\n{s}\n" for s in shown)
    )
    return atomic.write_text(folder / f"{stem}.md", text)


__all__ = [
    "write_episodes",
    "write_trajectories",
    "write_summary",
    "read_summary",
    "evaluation_is_current",
    "write_results_page",
    "summarize",
    "maze_table_markdown",
    "tables",
    "tables_markdown",
    "markdown",
    "to_csv",
    "group_runs",
    "seed_stats",
    "seed_cell",
    "bootstrap_ci",
    "THESIS_T31",
    "THESIS_T32",
]
