"""The maze benchmark study: the suite's leaderboard, what the hierarchy buys on the stitch
data (paired with the flat skills), why the graph planner needs its connection radius, and
the data-efficiency curve.

    python experiments/maze_study.py --suite bench-out/maze-suite          # after `aerohrl bench suite ... -o bench-out/maze-suite`
    python experiments/maze_study.py --suite S --sizes-suite S2            # with a suite of NAME@EPISODES datasets

It reads a suite folder (``aerohrl bench suite``; run that first, it is resumable), then:

1. **the leaderboard** as the suite wrote it;
2. **flat against planned, paired**: for every dataset and each run of an ALGO whose
   ALGO+planner agent the suite evaluated, the per-episode outcomes of the same checkpoint
   on the same episodes, flat and planned, pooled over seeds: the success difference and
   the exact two-sided sign test on the episodes only one of them succeeds in;
3. **the planner's ablation** on the stitch dataset's runs: the graph planner without a
   connection radius, with legs between adjacent cells only, the same and no first leg to
   the vehicle's own cell, and the suite's legs along straight free corridors, each over
   the seeds (``aerohrl eval``, resumable);
4. **the critics' leg values** between the maze's free cells by path length, and for pairs
   close in space but far along the maze (a wall between them): why a planner that trusts
   learned values alone takes a shortcut through a wall;
5. **data efficiency**: with ``--sizes-suite``, that suite's leaderboard by dataset size.

Writes ``docs/results/DATE-maze-benchmark.md`` and its figures.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from datetime import date
from pathlib import Path

import numpy as np

from aerohrl.benchmark import MAZE_PLANNER_ARGS, MAZE_SUBGOALS_ARGS
from aerohrl.errors import UserError, run_cli

ABLATION = {
    "graph, no radius": ["--planner", "graph"],
    "graph, radius 2.5 m (adjacent cells)": ["--planner", "graph", "--max-edge", "2.5"],
    "graph, adjacent cells, no leg to its own cell": ["--planner", "graph", "--max-edge", "2.5", "--min-leg", "1"],
    "graph, corridor legs up to 8.5 m, no leg to its own cell (suite)": list(MAZE_PLANNER_ARGS),
}


# the high levels an agent's flat flights are paired with: the suite's ALGO+planner and
# ALGO+subgoals evaluations
HIGH_LEVELS = {"graph planner": MAZE_PLANNER_ARGS, "own subgoals": MAZE_SUBGOALS_ARGS}


def _rows(run: Path, name: str) -> list[dict] | None:
    """The per-episode rows at the newest evaluated checkpoint of ``RUN/eval/NAME``, or None."""
    files = sorted((run / "eval" / name).glob("episodes-step-*.csv"))
    if not files:
        return None
    with open(files[-1], newline="") as f:
        return list(csv.DictReader(f))


def _success(row: dict) -> bool:
    return row["success"] in ("1", "True", "true")


def _episodes(run: Path, name: str) -> np.ndarray | None:
    """Per-episode success at the newest evaluated checkpoint of ``RUN/eval/NAME``, or None."""
    rows = _rows(run, name)
    return None if rows is None else np.array([_success(r) for r in rows], bool)


def _same_option(have: object, want: str) -> bool:
    """An evaluation's recorded option ``have`` equals the flag value ``want`` (numbers as numbers)."""
    try:
        return have is not None and float(have) == float(want)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return str(have) == want


def _eval_name(run: Path, task: str, planned: bool, args: list[str] | None = None) -> str | None:
    """The folder of the run's evaluation of ``task`` (planned or not; with ``args``, those planner flags)."""
    for f in sorted((run / "eval").glob("*/summary.json")):
        s = json.loads(f.read_text())
        if s.get("task") != task or (s.get("planner", "none") != "none") != planned:
            continue
        if args is not None:
            want = {args[i].lstrip("-").replace("-", "_"): args[i + 1] for i in range(0, len(args), 2)}
            opts = s.get("options") or {}
            if any(not _same_option(opts.get(k), v) for k, v in want.items() if k != "planner"):
                continue
            if float(opts.get("max_edge", 0.0)) and "max_edge" not in want:
                continue
            if float(opts.get("min_leg", 0.0)) and "min_leg" not in want:
                continue
        return f.parent.name
    return None


def _per_task(run: Path, args: tuple[str, ...] | None) -> dict[int, np.ndarray] | None:
    """Per-episode success by frozen task (1..5) of the run's flat (``args`` None) or planned
    maze evaluation at its newest checkpoint, or None when it has none."""
    name = _eval_name(run, "maze", args is not None, None if args is None else list(args))
    rows = None if name is None else _rows(run, name)
    if rows is None:
        return None
    out: dict[int, list[bool]] = {}
    for r in rows:
        out.setdefault(int(r["maze_task"]), []).append(_success(r))
    return {t: np.array(v, bool) for t, v in out.items()}


def pool_tasks(per_run: list[dict[int, np.ndarray]]) -> dict[int, np.ndarray]:
    """The runs' per-task outcomes pooled: task -> all their episodes."""
    tasks = sorted({t for d in per_run for t in d})
    return {t: np.concatenate([d[t] for d in per_run if t in d]) for t in tasks}


def paired(flat: list[np.ndarray], planned: list[np.ndarray]) -> dict:
    """Pooled over seeds: success of each (%), their difference and the exact sign test on
    the discordant episodes (McNemar)."""
    from scipy.stats import binomtest

    a, b = np.concatenate(flat), np.concatenate(planned)
    only_b, only_a = int((b & ~a).sum()), int((a & ~b).sum())
    p = binomtest(only_b, only_b + only_a).pvalue if only_a + only_b else 1.0
    return {"flat": 100 * a.mean(), "planned": 100 * b.mean(), "only_planned": only_b, "only_flat": only_a, "p": p, "n": len(a)}


def leg_values(run: Path) -> dict:
    """Mean critic leg value between free-cell hover states by path length (cells), and for
    pairs at most 2 cells apart in space but >= 6 along the maze."""
    import torch

    from aerohrl.algorithms.base import load_policy
    from aerohrl.algorithms.run import Run
    from aerohrl.planning.planner import candidates_from_maze, leg_values as legs
    from aerohrl.worlds.maze import world_maze

    torch.set_num_threads(1)
    ck = Run(run).checkpoints()[-1]
    algo, c = load_policy(ck)
    from aerohrl.datagen.dataset import open_dataset

    ds = open_dataset(c["dataset"]["path"], verify=False)
    maze = world_maze(ds.spec, {"maze": ds.maze})
    if maze is None:
        raise UserError(f"{run} was not trained in a maze")
    cand = candidates_from_maze(maze)
    d = maze.distances()
    cells = maze.free_cells
    i, j = np.nonzero(np.ones_like(d, bool))
    v = legs(algo, cand.states[torch.as_tensor(i)], cand.goals[torch.as_tensor(j)]).mean(0).numpy()
    eu = np.linalg.norm(cells[i] - cells[j], axis=1)
    path = d[i, j]
    out = {f"{k} cells": float(v[path == k].mean()) for k in range(1, 9)}
    wall = (eu <= 2.01) & (path >= 6)
    out["<= 2 cells apart, >= 6 along the maze"] = float(v[wall].mean()) if wall.any() else float("nan")
    out["2 cells, straight and open"] = float(v[(path == 2) & (eu == 2)].mean())
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="experiments/maze_study.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--suite", type=Path, required=True, help="an `aerohrl bench suite` folder")
    ap.add_argument("--sizes-suite", type=Path, default=None, help="a suite of NAME@EPISODES datasets (data efficiency)")
    ap.add_argument("--stitch", default="maze-large-stitch", help="the dataset of the planner ablation [maze-large-stitch]")
    ap.add_argument("--algo", default="gcsl", help="the skills of the ablation and the leg values [gcsl]")
    ap.add_argument("--episodes", type=int, default=250, help="evaluation episodes of the ablation [250]")
    ap.add_argument("--results-dir", type=Path, default=Path("docs/results"), help="where the page goes [docs/results]")
    ap.add_argument("--page", default="maze-benchmark", help="the page's name after its date [maze-benchmark]")
    a = ap.parse_args(argv)

    def go() -> int:
        from aerohrl.api import evaluate

        board = a.suite / "leaderboard.md"
        if not board.exists():
            raise UserError(f"{a.suite} holds no leaderboard: run `aerohrl bench suite ... -o {a.suite}` first")
        runs = sorted(p for p in (a.suite / "runs").iterdir() if p.is_dir())
        lines = [
            f"# The maze benchmark ({date.today().isoformat()})",
            "",
            f"Written by `python experiments/maze_study.py --suite {a.suite}"
            + (f" --sizes-suite {a.sizes_suite}" if a.sizes_suite else "")
            + (f" --page {a.page}" if a.page != "maze-benchmark" else "")
            + f"` from the suite in `{a.suite}` (its grid: `{a.suite}/suite.json`).",
            "",
            "## Leaderboard",
            "",
            board.read_text().split("\n", 2)[2].strip(),
            "",
            f"![leaderboard](figures/{date.today().isoformat()}-{a.page}-leaderboard.png)",
            "",
            "## Flat against planned, paired (same checkpoints, same episodes)",
            "",
            "| runs | high level | flat % | planned % | only planned | only flat | sign test p | episodes |",
            "|---|---|---|---|---|---|---|---|",
        ]
        groups: dict[str, list[Path]] = {}
        for r in runs:
            groups.setdefault(r.name.rsplit("-s", 1)[0], []).append(r)
        for g, rs in sorted(groups.items()):
            for high, high_args in HIGH_LEVELS.items():
                flat, planned = [], []
                for r in rs:
                    fn, pn = _eval_name(r, "maze", False), _eval_name(r, "maze", True, list(high_args))
                    if fn and pn:
                        f, p = _episodes(r, fn), _episodes(r, pn)
                        if f is not None and p is not None and len(f) == len(p):
                            flat.append(f)
                            planned.append(p)
                if flat:
                    st = paired(flat, planned)
                    lines.append(
                        f"| {g} ({len(flat)} seeds) | {high} | {st['flat']:.1f} | {st['planned']:.1f} | "
                        f"{st['only_planned']} | {st['only_flat']} | {st['p']:.2g} | {st['n']} |"
                    )
        lines += ["", "## Per task (pooled over seeds, final checkpoint)", ""]
        lines += [
            "| runs | high level | task 1 | task 2 | task 3 | task 4 | task 5 | seeds |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for g, rs in sorted(groups.items()):
            levels: dict[str, tuple[str, ...] | None] = {"none (flat)": None, **HIGH_LEVELS}
            for high, level_args in levels.items():
                pooled = [t for r in rs if (t := _per_task(r, level_args)) is not None]
                if pooled:
                    both = pool_tasks(pooled)
                    cells = [f"{100 * both[t].mean():.1f}" if t in both else "-" for t in range(1, 6)]
                    lines.append(f"| {g} | {high} | " + " | ".join(cells) + f" | {len(pooled)} |")
        abl_runs = [r for r in runs if r.name.startswith(f"{a.algo}-{a.stitch}-s")]
        if abl_runs:
            lines += ["", f"## The graph planner's ablation ({a.algo} on {a.stitch}, {a.episodes} episodes per seed)", ""]
            lines += ["| planner | success % per seed | mean ± std | collision % (mean) |", "|---|---|---|---|"]
        for label, args in ABLATION.items() if abl_runs else ():
            vals, coll = [], []
            for r in abl_runs:
                opts: dict = {"checkpoints": 1, "episodes": a.episodes}
                for k, v in zip(args[::2], args[1::2]):
                    key = k.lstrip("-").replace("-", "_")
                    opts[key] = v if key in ("planner", "legs") else float(v)
                s = evaluate(r, "maze", **opts)
                vals.append(100 * s["checkpoints"][-1]["success"])
                coll.append(100 * s.get("collision_mean", float("nan")))
            if vals:
                lines.append(
                    f"| {label} | {' / '.join(f'{v:.1f}' for v in vals)} | {np.mean(vals):.1f} ± "
                    f"{np.std(vals, ddof=1) if len(vals) > 1 else 0:.1f} | {np.mean(coll):.1f} |"
                )
        if abl_runs:
            lines += ["", f"## Leg values of the critics ({a.algo} on {a.stitch}, mean over free-cell pairs)", ""]
            per = [leg_values(r) for r in abl_runs]
            keys = list(per[0])
            lines += ["| pair | " + " | ".join(r.name.rsplit("-", 1)[1] for r in abl_runs) + " |"]
            lines += ["|---|" + "---|" * len(abl_runs)]
            lines += [f"| {k} | " + " | ".join(f"{p[k]:.3f}" for p in per) + " |" for k in keys]
        if a.sizes_suite is not None:
            sb = a.sizes_suite / "leaderboard.md"
            if not sb.exists():
                raise UserError(f"{a.sizes_suite} holds no leaderboard")
            lines += ["", "## Data efficiency (success against dataset episodes)", "", sb.read_text().split("\n", 2)[2].strip()]
        a.results_dir.mkdir(parents=True, exist_ok=True)
        (a.results_dir / "figures").mkdir(exist_ok=True)
        import shutil

        shutil.copyfile(
            a.suite / "leaderboard.png", a.results_dir / "figures" / f"{date.today().isoformat()}-{a.page}-leaderboard.png"
        )
        page = a.results_dir / f"{date.today().isoformat()}-{a.page}.md"
        from aerohrl import atomic

        atomic.write_text(page, "\n".join(lines) + "\n")
        print(page)
        return 0

    return run_cli("experiments/maze_study.py", go)


if __name__ == "__main__":
    sys.exit(main())
