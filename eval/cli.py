"""``aerohrl eval``: closed-loop evaluation, tables and plots (thesis §3.5).

::

    aerohrl eval --task reach-desired --run runs/<run>           # last 10 checkpoints, 250 episodes each
    aerohrl eval --task reach-intermediate --run runs/<run>
    aerohrl eval --task reach-desired --run runs/<run> --checkpoints 1 --mcap-episode 3   # + episode 3 as flown, for Foxglove
    aerohrl eval --task ood --run runs/<run> --planner single    # none | single (Eq. 3.7) | multi (Eq. 3.6)
    aerohrl eval --task fast --run runs/<run>                    # free space: goals at |v_i| in [3.5, 7] m/s
    aerohrl eval --task maze --run runs/<maze-run> [--planner single]   # the 5 frozen tasks of the run's maze
    aerohrl eval table runs/gcsl runs/td3bc runs/td3awbc runs/cql -o results/table   # Markdown + CSV
    aerohrl eval plot --task ood --run runs/<run> -o ood.png     # 3D trajectories (Fig. 3.5 / 3.6)
    aerohrl eval plot --curves runs/gcsl runs/td3bc -o curves.png   # learning curves (Fig. 3.3 / 3.4)
    aerohrl eval oracle --run runs/<run>                         # what any Eq. 3.7 planner could reach (planning/oracle.py)
    aerohrl eval --task reach-novel --run runs/<run> --perturb mass=1.2,latency=0.02   # on a perturbed vehicle (sim/perturb.py)
    aerohrl eval robustness --run runs/a runs/b runs/c -o results/robustness   # success against each perturbation's size

Exit status: 0 done, 2 bad input (one line ``aerohrl eval: error: ...``), 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from aerohrl import cli_types as T
from aerohrl.cli_common import add_common, progress, set_threads
from aerohrl.errors import ArgumentParser, UserError, run_cli

PROG = "aerohrl eval"


# EvalOptions settings whose flags are written here rather than by aerohrl.config.add_flags:
# --task is required, --horizon, --decline-margin and --mcap-episode are optional numbers, --family lists
# its choices (numpy-free here), and --seed, --device, --out are every command's
EVAL_OWN_FLAGS = ("task", "horizon", "family", "decline_margin", "mcap_episode", "seed", "device", "out")


def _eval_parser() -> ArgumentParser:
    from dataclasses import fields

    from aerohrl.config import add_flags, describe, to_flat_dict
    from aerohrl.eval.harness import EvalOptions
    from aerohrl.eval.tasks import TASKS

    FAMILIES = ("position", "velocity", "acceleration", "combined")  # = eval/families.py FAMILIES (numpy-free here)
    d = EvalOptions()
    f = {x.name: x for x in fields(EvalOptions)}
    ap = ArgumentParser(
        prog=PROG,
        description="Evaluate the last checkpoints of a training run in the batched simulator "
        "(subcommands: `table RUN...`, `plot ...`, `oracle ...`).",
    )
    ap.add_argument("--task", required=True, choices=tuple(TASKS), help=f["task"].metadata["help"])
    ap.add_argument("--run", required=True, type=Path, help="training run folder (runs/<run>)")
    add_flags(ap, EvalOptions, skip=EVAL_OWN_FLAGS)
    # no preset under these flags: the parsed values are the settings, defaults included
    ap.set_defaults(**{k: v for k, v in to_flat_dict(d).items() if k not in EVAL_OWN_FLAGS and f[k].metadata.get("flag", True)})
    ap.add_argument(
        "--horizon",
        type=T.positive_int,
        default=None,
        metavar="N",
        help=describe(f["horizon"], "1000; a family ring: its own, scaled to distance"),
    )
    ap.add_argument("--family", default=None, choices=FAMILIES, help=describe(f["family"], "the thesis's OOD set"))
    ap.add_argument(
        "--decline-margin",
        type=T.finite_float,
        default=None,
        metavar="M",
        help=describe(f["decline_margin"], "never: the thesis"),
    )
    ap.add_argument("--mcap-episode", type=T.nonneg_int, default=None, metavar="N", help=describe(f["mcap_episode"], "none"))
    add_common(
        ap,
        out={"help": "result folder [RUN/eval/<task>[-<planner>]]"},
        quiet=True,
        threads={"default": 1},
        seed={"default": d.seed, "help": f"episode-set seed (>= 0) [{d.seed}]"},
        device={"default": d.device},
    )
    return ap


def cmd_eval(a: argparse.Namespace) -> int:
    """``aerohrl eval RUN``: evaluate a run's last checkpoints on a task; exit code."""
    from aerohrl.config import given_flags
    from aerohrl.eval.harness import EvalOptions, evaluate_run

    set_threads(a.threads)
    opt = EvalOptions(
        task=a.task,
        horizon=a.horizon,
        family=a.family,
        decline_margin=a.decline_margin,
        mcap_episode=a.mcap_episode,
        seed=a.seed,
        device=a.device,
        out=None if a.out is None else str(a.out),
        progress=progress(a.quiet),
        **given_flags(a, EvalOptions, skip=EVAL_OWN_FLAGS),
    )
    s = evaluate_run(a.run, opt)
    print(
        f"{s['name']}: {s['algo']} {a.run}: success {100 * s['success_mean']:.1f} ± {100 * s['success_std']:.1f} %, "
        f"near success {100 * s['near_success_mean']:.1f} ± {100 * s['near_success_std']:.1f} % "
        f"({len(s['checkpoints'])} checkpoints x {s['episodes']} episodes, {s['seconds']:.0f} s)"
    )
    out = Path(a.out) if a.out else Path(a.run) / "eval" / s["name"]
    if "collision_mean" in s:  # maze tasks: crashes end episodes as failures
        print(f"collision {100 * s['collision_mean']:.1f} ± {100 * s['collision_std']:.1f} % (maze {s['maze']['name']})")
        print(f"results:   {out}/summary.json, {out}/tasks.md, {out}/maze.png, {out}/episodes-step-*.csv")
        return 0
    flown = f", {out}/flown-episode-{a.mcap_episode}-step-*.mcap" if a.mcap_episode is not None else ""
    print(f"results:   {out}/summary.json, {out}/episodes-step-*.csv{flown}")
    return 0


def _table_parser() -> ArgumentParser:
    ap = ArgumentParser(
        prog=f"{PROG} table",
        description="Table 3.1 / 3.2 analogues (Markdown on stdout; with -o also PREFIX.md, PREFIX-t31.csv, PREFIX-t32.csv).",
    )
    ap.add_argument("runs", nargs="+", type=Path, metavar="RUN", help="run folders (or folders of runs)")
    add_common(ap, out={"help": "file prefix: writes OUT.md, OUT-t31.csv, OUT-t32.csv [stdout only]"})
    return ap


def cmd_table(a: argparse.Namespace) -> int:
    """``aerohrl eval table``: the thesis tables (3.1, 3.2) over runs, as Markdown and CSV; exit code."""
    from aerohrl.eval import results

    t = results.tables(a.runs)
    md = results.tables_markdown(t)
    print(md, end="")
    if a.out:
        p = a.out
        results.write_text(p.with_name(p.name + ".md"), md)
        results.write_text(p.with_name(p.name + "-t31.csv"), results.to_csv(*t["t31"]))
        results.write_text(p.with_name(p.name + "-t32.csv"), results.to_csv(*t["t32"]))
    return 0


def _plot_parser() -> ArgumentParser:
    ap = ArgumentParser(
        prog=f"{PROG} plot",
        description="3D trajectories of an evaluation (thesis Fig. 3.5/3.6) or learning curves of runs (Fig. 3.3/3.4).",
    )
    from aerohrl.eval.harness import PLANNERS
    from aerohrl.eval.tasks import TASKS

    ap.add_argument("--task", default=None, choices=tuple(TASKS), help="evaluation to draw")
    ap.add_argument("--planner", default=None, choices=tuple(PLANNERS), help="ood: which evaluation [the planned one present]")
    ap.add_argument("--run", type=Path, default=None, help="training run folder (runs/<run>)")
    ap.add_argument("--curves", type=Path, nargs="+", default=None, metavar="RUN", help="learning curves of these runs")
    ap.add_argument("--max", type=T.positive_int, default=12, help="trajectories per panel [12]")
    add_common(ap, out={"required": True, "help": "figure file (.png, .pdf, .svg)"})
    return ap


def cmd_plot(a: argparse.Namespace) -> int:
    """``aerohrl eval plot``: learning curves (``--curves``) or evaluation figures; exit code."""
    from aerohrl.eval import plots

    if a.curves:
        out = plots.plot_learning_curves(a.curves, a.out)
    else:
        if a.task is None or a.run is None:
            raise UserError("plot needs --task and --run (trajectories) or --curves RUN... (learning curves)")
        out = plots.plot_trajectories(a.run, a.task, a.out, planner=a.planner, max_per_panel=a.max)
    print(f"plot: {out}")
    return 0


def _oracle_parser() -> ArgumentParser:
    ap = ArgumentParser(
        prog=f"{PROG} oracle",
        description="Fly every first and second leg of the single-goal planner "
        "(Eq. 3.7) to bound what any planner over the achieved goals can reach with this policy.",
    )
    ap.add_argument("--run", type=Path, required=True, help="training run folder (runs/<run>): its newest checkpoint")
    ap.add_argument("--task", default="ood", choices=("ood", "reach-novel"), help="goals of this task [ood]")
    ap.add_argument("--goals", type=T.positive_int, default=40, help="task goals [40]")
    ap.add_argument(
        "--family",
        default=None,
        choices=("position", "velocity", "acceleration", "combined"),
        help="goals of an OOD family ring instead (eval/families.py) [none]",
    )
    ap.add_argument("--ring", default=None, help="--family: step 1..K or LO:HI [1]")
    ap.add_argument(
        "--candidate-source",
        default="dataset",
        choices=["dataset", "synthetic"],
        help="waypoints: the dataset's achieved goals | synthetic states within rho_D of the start [dataset]",
    )
    ap.add_argument("--candidates", type=T.positive_int, default=150, help="achieved goals (seeded subset) [150]")
    ap.add_argument("--leg-horizon", type=T.positive_int, default=500, help="simulator steps per leg (100 Hz) [500]")
    ap.add_argument("--alpha", type=T.nonneg_float, default=1.0, help="variance penalty of the Eq. 3.7 choice [1.0]")
    add_common(
        ap,
        out={"help": "report folder [RUN/eval/oracle-TASK]"},
        quiet=True,
        threads={"default": 1},
        seed={"help": "goal and candidate seed (>= 0) [0]"},
    )
    return ap


def cmd_oracle(a: argparse.Namespace) -> int:
    """``aerohrl eval oracle``: the single-goal planner's oracle on a run's checkpoint; exit code."""
    import json

    from aerohrl.algorithms.base import load_policy
    from aerohrl.eval import results
    from aerohrl.eval.harness import load_run_dataset, run_checkpoints, sim_kwargs
    from aerohrl.eval.tasks import make_episodes
    from aerohrl.planning.oracle import format_report, oracle_single

    if a.task not in ("ood", "reach-novel"):
        raise UserError(f"oracle --task must be ood or reach-novel, got {a.task!r}")
    if a.goals < 1 or a.candidates < 1 or a.leg_horizon < 1:
        raise UserError("--goals, --candidates and --leg-horizon must be >= 1")
    set_threads(a.threads)
    ckpt = run_checkpoints(a.run, 1)[-1]
    data, _ = load_run_dataset(a.run)
    algo, ck = load_policy(ckpt)
    if a.ring is not None and a.family is None:
        raise UserError("--ring needs --family")
    name = a.task
    if a.family is not None:
        from aerohrl.eval.families import parse_ring
        from aerohrl.eval.tasks import ood_family

        ring = parse_ring(a.family, a.ring or "1")
        goals = ood_family(data, a.goals, a.seed, ring=ring).goals
        name = "ood-" + ring.slug
    else:
        goals = make_episodes(a.task, data, a.goals, a.seed).goals
    cand = None
    if a.candidate_source == "synthetic":
        from aerohrl.planning.oracle import synthetic_candidates

        cand = synthetic_candidates(data.info.get("spec"), a.candidates, a.seed)
        name += "-synth"
    r = oracle_single(
        algo,
        data,
        goals,
        candidates=a.candidates,
        seed=a.seed,
        leg_horizon=a.leg_horizon,
        alpha=a.alpha,
        sim=sim_kwargs(data),
        progress=progress(a.quiet),
        cand=cand,
    )
    r.update(
        run=str(a.run), checkpoint=ckpt.name, step=int(ck["step"]), task=name, seed=a.seed, candidate_source=a.candidate_source
    )
    out = a.out or Path(a.run) / "eval" / f"oracle-{name}"
    strict = {k: None if isinstance(v, float) and v != v else v for k, v in r.items()}  # NaN AUC -> null (valid JSON)
    path = results.write_text(out / "oracle.json", json.dumps(strict, indent=2, sort_keys=True, allow_nan=False) + "\n")
    print(f"oracle, {name}, {a.run} at step {ck['step']}:\n{format_report(r)}\nreport: {path}")
    return 0


def _robustness_parser() -> ArgumentParser:
    from aerohrl.eval.robustness import AXES, BREAK

    ap = ArgumentParser(
        prog=f"{PROG} robustness",
        description="Robustness curves: success against each perturbation's magnitude, from nominal until every curve "
        f"is below {BREAK:.0%}, for the runs' policies (a curve per group, the mean over its runs) and the geometric expert "
        "tracking its references on the same perturbed vehicle (eval/robustness.py). Writes robustness.md, robustness.csv "
        "and a plot per axis.",
    )
    ap.add_argument(
        "--run", nargs="*", type=Path, default=[], help="training runs (e.g. the seeds of a recipe), the curve 'policy'"
    )
    ap.add_argument(
        "--group",
        action="append",
        default=[],
        metavar="LABEL=RUN[,RUN...]",
        help="another curve: the mean over these runs, labelled LABEL (repeatable; e.g. nominal=... dr=...)",
    )
    ap.add_argument("--axes", default=",".join(AXES), help=f"comma-separated axes of {', '.join(AXES)} [all]")
    ap.add_argument("--task", default="reach-novel", help="evaluation task of the policies [reach-novel]")
    ap.add_argument("--episodes", type=T.positive_int, default=100, help="episodes per point, policy and expert [100]")
    ap.add_argument("--checkpoints", type=T.positive_int, default=1, help="newest checkpoints per run [1]")
    ap.add_argument(
        "--values", action="append", default=None, metavar="AXIS=V1:V2:...", help="magnitudes of an axis (repeatable)"
    )
    ap.add_argument("--no-expert", dest="expert", action="store_false", help="skip the expert's curve")
    ap.add_argument(
        "--expert-observer",
        type=T.nonneg_float,
        default=None,
        metavar="TAU",
        help="time constant (s) of the expert's disturbance observer (datagen spec disturbance_observer; 0: off) "
        "[the runs' dataset's]",
    )
    ap.add_argument("--full", action="store_true", help="fly every magnitude (default: stop once every curve is broken)")
    add_common(
        ap,
        out={"required": True, "help": "report folder"},
        quiet=True,
        threads={"default": 1},
        seed={"help": "episode, reference and perturbation seed (>= 0) [0]"},
        device={},
    )
    return ap


def cmd_robustness(a: argparse.Namespace) -> int:
    """``aerohrl eval robustness``: the curves and their report; exit code."""
    import shlex

    from aerohrl.eval.robustness import parse_groups, parse_values, run_study, write_results

    set_threads(a.threads)
    groups = {"policy": list(a.run), **parse_groups(a.group)} if a.run else parse_groups(a.group)
    axes = [x.strip() for x in a.axes.split(",") if x.strip()]
    values = parse_values(a.values)
    log = (lambda m: None) if a.quiet else (lambda m: print(m, flush=True))
    points = run_study(
        groups,
        axes=axes,
        task_name=a.task,
        episodes=a.episodes,
        checkpoints=a.checkpoints,
        seed=a.seed,
        values=values,
        expert=a.expert,
        expert_observer=a.expert_observer,
        device=a.device,
        full=a.full,
        log=log,
    )
    command = "aerohrl eval robustness " + " ".join(shlex.quote(x) for x in a.argv)
    write_results(points, a.out, groups=groups, task_name=a.task, episodes=a.episodes, command=command)
    print(f"robustness curves: {a.out / 'robustness.md'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """The ``aerohrl eval`` command (``table``, ``oracle``, ``plot``, ``robustness`` or an evaluation); exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "robustness":
        a = _robustness_parser().parse_args(argv[1:])
        a.argv = argv[1:]  # the command, for the report
        return run_cli(PROG, lambda: cmd_robustness(a))
    if argv and argv[0] == "table":
        a = _table_parser().parse_args(argv[1:])
        return run_cli(PROG, lambda: cmd_table(a))
    if argv and argv[0] == "oracle":
        a = _oracle_parser().parse_args(argv[1:])
        return run_cli(PROG, lambda: cmd_oracle(a))
    if argv and argv[0] == "plot":
        a = _plot_parser().parse_args(argv[1:])
        return run_cli(PROG, lambda: cmd_plot(a))
    a = _eval_parser().parse_args(argv)
    return run_cli(PROG, lambda: cmd_eval(a))


if __name__ == "__main__":
    sys.exit(main())
