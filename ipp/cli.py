"""``aerohrl ipp``: lattice build, bench, compare, show.

    aerohrl ipp lattice build --out lattice.npz         # + lattice.png
    aerohrl ipp bench --planner dp --envs 100
    aerohrl ipp bench --all --envs 100                  # Markdown + CSV + KL plot
    aerohrl ipp train --preset cpu                      # -> runs/<run>/
    aerohrl ipp train --resume runs/<run>               # continue from its checkpoint
    aerohrl ipp curve runs/<run>                        # -> runs/<run>/learning_curve.png
    aerohrl ipp bench --all --run runs/<run>            # baselines + learned policy
    aerohrl ipp compare runs/bench-a runs/bench-b       # two benches paired over their worlds
    aerohrl ipp show --env 7 --planner dp --out path.png
    aerohrl ipp bench --all --world semantic --envs 30  # Table 2.2 analogue
    aerohrl ipp bench --all --world semantic --raster campus.png   # a user's class raster

Flags map one to one onto :class:`~aerohrl.ipp.lattice.LatticeConfig`,
:class:`~aerohrl.ipp.env.EnvConfig`, :class:`~aerohrl.ipp.baselines.PlannerConfig` and
:class:`~aerohrl.ipp.bench.BenchConfig`. Bad input exits with a one-line error.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

from aerohrl import cli_types as T
from aerohrl.cli_common import add_common, add_run, run_name, set_threads
from aerohrl.errors import ArgumentParser, UserError, run_cli

PROG = "aerohrl ipp"


class _Parser(ArgumentParser):
    def error(self, message):  # one line, exit 2, like UserError
        raise UserError(message)


# What --help shows, without importing the modules that define it (scipy.ndimage, torch:
# `--help` stays under a second); tests/test_cli_vocabulary.py checks each against its source.
PLANNERS = ("greedy", "dp", "cmaes", "coverage", "prio_coverage")  # baselines.PLANNERS
TEACHERS = ("detect",)  # baselines.TEACHERS
TEST_SEED = 1000  # bench.TEST_SEED
BUDGETS = {"default": 9250.0, "tight": 5000.0}  # env.BUDGETS
SEMANTIC_BUDGET = 30000.0  # env.SEMANTIC_BUDGET
ENV_DEFAULTS = {"map_size": 30, "budget": 9250.0, "start": "center"}  # env.EnvConfig()


def _parser() -> argparse.ArgumentParser:
    from types import SimpleNamespace

    from .lattice import LatticeConfig  # numpy only

    lc, ec = LatticeConfig(), SimpleNamespace(**ENV_DEFAULTS)
    p = _Parser(prog=PROG, description="Informative path planning on motion primitives.")
    sub = p.add_subparsers(dest="cmd", required=True, parser_class=_Parser)

    lat = sub.add_parser("lattice", help="motion-primitive lattices")
    lsub = lat.add_subparsers(dest="lcmd", required=True, parser_class=_Parser)
    b = lsub.add_parser("build", help="build a dispersion-minimising lattice")
    add_common(b, out={"required": True, "type": str, "help": "lattice file to write (.npz)"})
    b.add_argument("--plot", metavar="PATH", help="figure path [OUT with .png]")
    b.add_argument("--no-plot", action="store_true", help="no figure")
    b.add_argument(
        "--vertices",
        type=T.positive_int,
        default=lc.n_vertices,
        dest="n_vertices",
        help=f"lattice vertices (velocity states), hover included [{lc.n_vertices}]",
    )
    b.add_argument("--v-max", type=T.positive_float, default=lc.v_max, help=f"speed bound |v| (m/s) [{lc.v_max:g}]")
    b.add_argument("--a-max", type=T.positive_float, default=lc.a_max, help=f"acceleration bound |a| (m/s^2) [{lc.a_max:g}]")
    b.add_argument(
        "--rho",
        type=T.positive_float,
        default=lc.rho,
        help=f"weight of time in the primitive cost rho*T + int |jerk|^2 (1/s) [{lc.rho:g}]",
    )
    b.add_argument(
        "--reach", type=T.positive_int, default=lc.reach, help=f"displacement window |dx|, |dy| <= reach (cells) [{lc.reach}]"
    )
    b.add_argument(
        "--max-edges", type=T.positive_int, default=lc.max_edges, help=f"primitives per vertex (action slots) [{lc.max_edges}]"
    )
    b.add_argument(
        "--footprint-radius",
        type=T.nonneg_int,
        default=lc.footprint_radius,
        help=f"sensor footprint (2r+1)^2 (cells) [{lc.footprint_radius}]",
    )
    b.add_argument(
        "--sense-dt",
        type=T.positive_float,
        default=lc.sense_dt,
        help=f"sampling of the trajectory for sensing (s) [{lc.sense_dt:g}]",
    )

    def world_flags(q):
        q.add_argument(
            "--world",
            choices=("targets", "semantic"),
            default=None,
            help="target search (Table 2.1, default) or semantic feature detection (Table 2.2)",
        )
        q.add_argument(
            "--raster",
            help="semantic: class raster (.npy/.npz/.png) instead of procedural campus maps (see aerohrl.ipp.semantic)",
        )
        q.add_argument(
            "--map-size", type=T.positive_int, default=None, help=f"map side (cells) (default {ec.map_size}; semantic 256)"
        )
        q.add_argument(
            "--budget",
            type=_budget,
            default=None,
            help=f"cost budget in primitive-cost units (sum of rho*T + int |jerk|^2): a number > 0 "
            f"or a name ({_budget_names()}; "
            f"default {ec.budget:g}; semantic {SEMANTIC_BUDGET:g})",
        )

    def env_flags(q):
        q.add_argument("--lattice", help="lattice file (default: the shipped one)")
        world_flags(q)
        q.add_argument("--start", choices=("center", "random"), default=ec.start, help=f"start cell [{ec.start}]")
        add_common(q, seed={"default": TEST_SEED, "help": f"test-suite seed (>= 0) [{TEST_SEED}]"})
        q.add_argument(
            "--depth", type=T.positive_int, default=None, help="tree depth in primitives (greedy/dp/coverage) [the planner's own]"
        )
        q.add_argument("--horizon", type=T.positive_int, default=5, help="CMA-ES horizon (primitives) [5]")
        q.add_argument("--popsize", type=T.positive_int, default=12, help="CMA-ES population size [12]")
        q.add_argument("--generations", type=T.positive_int, default=15, help="CMA-ES generations [15]")
        q.add_argument(
            "--scoring",
            choices=("ratio", "additive"),
            default="ratio",
            help="planners: utility per unit cost (default) or utility - w * cost (the original's form)",
        )
        q.add_argument(
            "--cost-weight",
            type=T.nonneg_float,
            default=0.0,
            help="--scoring additive: w per cost unit (default 0: utility alone)",
        )
        q.add_argument(
            "--info-weight",
            type=T.nonneg_float,
            default=0.0,
            help="detect: + w x the information gain (bits) of the sensed cells [0: expected new detections alone]",
        )
        q.add_argument(
            "--prio-revisit",
            action=argparse.BooleanOptionalAction,
            default=True,
            help="prio_coverage scores the belief mass of covered cells too "
            "(default, the original); --no-prio-revisit: new cells only",
        )
        q.add_argument(
            "--cmaes-tol",
            type=T.nonneg_float,
            default=0.0,
            help="CMA-ES: stop when the best score's std over 10 generations is "
            "< tol (original 0.1; default 0: run every generation)",
        )
        q.add_argument(
            "--budget-aware",
            action=argparse.BooleanOptionalAction,
            default=None,
            help="tree planners: score by min(cost, remaining budget) (default: on for detect only)",
        )
        q.add_argument(
            "--run", action="append", default=None, help="trained policy run directory (planner rl); bench takes several"
        )

    tr = sub.add_parser("train", help="train the learned recurrent policy")
    _train_flags(tr)
    tr.add_argument(
        "--start", choices=("center", "random"), default=None, help="training start cells (default random; test suite: center)"
    )
    add_common(tr, out={"default": "runs", "type": str, "help": "folder of runs: the run goes to OUT/NAME [runs]"}, quiet=True)
    tr.add_argument("--name", default=None, help="run folder name, must be new [ipp-PRESET[-nornn]-sSEED-YYYYMMDD-HHMMSS-XXXXXX]")
    tr.add_argument("--lattice", help="lattice file (default: the shipped one)")
    world_flags(tr)
    tr.set_defaults(_defaults={a.dest: a.default for a in tr._actions})

    bl = sub.add_parser("belief", help="the learned target belief: train, calibrate")
    bsub = bl.add_subparsers(dest="bcmd", required=True, parser_class=_Parser)
    bt = bsub.add_parser("train", help="record states along baseline planners, fit the belief, calibrate it")
    _belief_flags(bt)
    bc = bsub.add_parser("calibrate", help="fit the temperature on the validation states: calibration.json + reliability.png")
    add_run(bc, help="belief run directory", type=str)

    cu = sub.add_parser("curve", help="learning curve of a training run (PNG)")
    add_run(cu, help="training run directory", type=str)
    add_common(cu, out={"type": str, "help": "figure path [RUN/learning_curve.png]"})

    be = sub.add_parser("bench", help="Table 2.1 analogue on the seeded test suite")
    g = be.add_mutually_exclusive_group()
    g.add_argument("--planner", help=f"one of {', '.join(PLANNERS + TEACHERS)}, rl (default dp)")
    g.add_argument("--all", action="store_true", help="every baseline (+ rl with --run)")
    be.add_argument(
        "--envs", type=T.positive_int, default=None, help="test environments (default 100; semantic 30, as the thesis)"
    )
    be.add_argument("--batch", type=T.positive_int, default=100, help="environments stepped together [100]")
    add_common(
        be,
        out={"default": "runs/ipp-bench", "type": str, "help": "Markdown, CSV and plot go here [runs/ipp-bench]"},
        quiet=True,
        threads={"help": "torch and OpenMP threads (policy rl, --execution skill) [their default]"},
    )
    be.add_argument(
        "--execution",
        type=_executions,
        default=("ideal",),
        help="ideal (the lattice's sensing, default), flown (the 6-DoF "
        "simulator and geometric controller fly each primitive; sensing along the "
        "flown path) and/or skill (the chapter-3 policy of --skill-run flies it "
        "through goals 0.5-1 s apart), comma-separated: e.g. 'ideal,flown,skill' "
        "writes ipp_execution.md",
    )
    be.add_argument(
        "--skill-run",
        default=None,
        help="--execution skill: the chapter-3 goal-conditioned policy run "
        "(directory: its last checkpoint; or a checkpoint file)",
    )
    be.add_argument(
        "--belief",
        metavar="RUN",
        default=None,
        help="plan over the learned belief of RUN (aerohrl ipp belief train) instead of the "
        "hand-written posterior; the metrics stay the environment's (planners that read a belief)",
    )
    be.add_argument(
        "--belief-temperature",
        type=float,
        default=None,
        metavar="T",
        help="--belief: temperature T > 0 [RUN's calibration.json, else 1]",
    )
    be.add_argument(
        "--budgets",
        type=_budget_list,
        default=None,
        help="sweep: comma-separated budgets (numbers or names); writes "
        "ipp_budgets.md/.csv and ipp_budgets.png (each metric against budget)",
    )
    env_flags(be)

    co = sub.add_parser("compare", help="two benches paired over the worlds both ran (e.g. two planners run apart)")
    co.add_argument("bench_a", metavar="A", help="bench folder (or its ipp_bench_envs.csv) of one planner")
    co.add_argument("bench_b", metavar="B", help="the bench it is compared with")
    co.add_argument("--metric", default="search_efficiency", help="per-world column of ipp_bench_envs.csv [search_efficiency]")

    sh = sub.add_parser("show", help="Fig. 2.3 analogue: truth, prior, path over the budget")
    sh.add_argument("--env", type=T.nonneg_int, default=0, help="test-suite world index")
    sh.add_argument("--planner", default="dp", help=f"one of {', '.join(PLANNERS + TEACHERS)}, rl [dp]")
    add_common(sh, out={"required": True, "type": str, "help": "figure file (.png)"})
    sh.add_argument(
        "--gif", help="also write an animated episode (GIF): belief, path, found and missed targets, one frame per primitive"
    )
    sh.add_argument("--execution", type=_executions, default=("ideal",), help="ideal (default), flown or skill")
    sh.add_argument("--skill-run", default=None, help="--execution skill: policy run")
    env_flags(sh)
    return p


BELIEF_OWN_FLAGS = ("seed", "threads", "env")  # --seed / --threads via add_common, env via --budget / --map-size


def _belief_skip() -> list[str]:
    from aerohrl.config import leaves

    from .belief import BeliefConfig

    return list(BELIEF_OWN_FLAGS) + [f.name for path, f, _ in leaves(BeliefConfig) if path[0] == "env"]


def _belief_flags(bt) -> None:
    """``ipp belief train``'s flags: preset, run folder, one flag per BeliefConfig setting."""
    from aerohrl.config import add_flags

    from .belief import BeliefConfig, preset, preset_names

    cpu = preset("cpu")
    bt.add_argument("--preset", default="cpu", choices=preset_names(), help="preset (ipp/presets/belief/NAME.toml) [cpu]")
    bt.add_argument(
        "--resume",
        metavar="RUN",
        help="continue RUN from its checkpoint.pt (only --epochs, --lattice, --threads, --quiet may be given)",
    )
    add_common(
        bt,
        out={"type": str, "help": "the run folder, must be new [runs/ipp-belief-PRESET-sSEED-YYYYMMDD-HHMMSS-XXXXXX]"},
        quiet=True,
        seed={"default": None, "help": f"random seed and training suite seed (>= 0) [cpu: {cpu.seed}]"},
        threads={"help": f"torch threads [cpu: {cpu.threads}]"},
    )
    bt.add_argument("--lattice", help="lattice file (default: the shipped one)")
    bt.add_argument("--map-size", type=T.positive_int, default=None, help=f"map side (cells) [{ENV_DEFAULTS['map_size']}]")
    bt.add_argument(
        "--budget", type=_budget, default=None, help=f"cost budget of the recorded episodes [{ENV_DEFAULTS['budget']:g}]"
    )
    add_flags(bt, BeliefConfig, skip=_belief_skip(), defaults=cpu, default_label="cpu")
    bt.set_defaults(_defaults={a.dest: a.default for a in bt._actions})


# TrainConfig settings whose flags are written here rather than by aerohrl.config.add_flags:
# spelled otherwise (--envs, --no-rnn, --no-features, comma-separated --adv-weights), shared
# by every command (--seed, --threads), or an optional integer (--teacher-depth); the
# environment's settings come from the world flags (--world, --map-size, --budget, --start)
TRAIN_OWN_FLAGS = ("n_envs", "adv_weights", "seed", "threads", "teacher_depth")


def _train_skip() -> list[str]:
    from aerohrl.config import leaves

    from .train_config import TrainConfig

    return list(TRAIN_OWN_FLAGS) + [f.name for path, f, _ in leaves(TrainConfig) if path[0] in ("env", "policy")]


def _train_flags(tr) -> None:
    """``ipp train``'s flags: the preset and the run folder, then one flag per TrainConfig
    setting (meaning, bounds and the cpu preset's value from the declarations)."""
    from aerohrl.config import add_flags, describe

    from .train_config import TrainConfig, preset, preset_names

    cpu = preset("cpu")

    def helps(name: str) -> str:
        return describe(_train_field(name), getattr(cpu, name), default_label="cpu")

    tr.add_argument(
        "--preset",
        default=None,
        choices=preset_names(),
        help="hyper-parameter preset (ipp/presets/NAME.toml) [cpu; with --world semantic: semantic]",
    )
    tr.add_argument(
        "--resume",
        metavar="RUN",
        help="continue RUN from its checkpoint.pt with its config.json (only --iterations, --lattice, --threads, --quiet may be given)",
    )
    tr.add_argument("--envs", type=_setting("n_envs", int), default=None, dest="n_envs", metavar="N", help=helps("n_envs"))
    tr.add_argument(
        "--teacher-depth",
        type=_setting("teacher_depth", int),
        default=None,
        metavar="N",
        help=describe(_train_field("teacher_depth"), "the planner's own"),
    )
    tr.add_argument(
        "--adv-weights",
        type=_floats,
        default=None,
        metavar="W,W,W,W,W",
        help=helps("adv_weights").replace(" [", ", comma-separated [", 1),
    )
    add_common(
        tr,
        seed={"default": None, "help": f"random seed (>= 0) [cpu: {cpu.seed}]"},
        threads={"help": f"torch threads [cpu: {cpu.threads}]"},
    )
    tr.add_argument("--no-rnn", action="store_true", help="MLP core (thesis 'no-LSTM')")
    tr.add_argument("--no-features", action="store_true", help="map observations only (thesis), no per-primitive features")
    add_flags(tr, TrainConfig, skip=_train_skip(), defaults=cpu, default_label="cpu")


def _train_field(name: str):
    from dataclasses import fields

    from .train_config import TrainConfig

    return next(f for f in fields(TrainConfig) if f.name == name)


def _setting(name: str, kind: type):
    """The argparse type of TrainConfig's numeric setting ``name``: parse, then its declared bounds."""
    from aerohrl.config import ConfigError, check_value

    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not {'an integer' if kind is int else 'a number'}: {text!r}") from None
        try:
            check_value(name, v, _train_field(name))
        except ConfigError as e:
            raise argparse.ArgumentTypeError(str(e).removeprefix(f"{name} ")) from None
        return v

    parse.__name__ = "integer" if kind is int else "number"
    return parse


def _budget_names() -> str:
    return ", ".join(f"{k} = {v:g}" for k, v in BUDGETS.items())


def _budget(text: str) -> float:
    """A budget: a name of :data:`aerohrl.ipp.env.BUDGETS` or a finite number > 0."""
    from .env import BUDGETS

    if text.strip() in BUDGETS:
        return BUDGETS[text.strip()]
    return T.positive_float(text)


_budget.__name__ = "budget"


def _budget_list(text: str) -> tuple[float, ...]:
    parts = [t for t in text.split(",") if t.strip()]
    if not parts:
        raise argparse.ArgumentTypeError(f"no budgets in {text!r}")
    return tuple(_budget(t) for t in parts)


_budget_list.__name__ = "budget list"


def _executions(text: str) -> tuple[str, ...]:
    from .flown import EXECUTIONS

    modes = tuple(t.strip() for t in text.split(",") if t.strip())
    bad = [m for m in modes if m not in EXECUTIONS]
    if not modes or bad:
        raise argparse.ArgumentTypeError(f"unknown execution mode {(bad or [text])[0]!r} (choose from {', '.join(EXECUTIONS)})")
    return tuple(dict.fromkeys(modes))


_executions.__name__ = "execution"


def _floats(text: str) -> tuple[float, ...]:
    """--adv-weights: one finite number per reward term, comma-separated."""
    from aerohrl.config import ConfigError, check_value

    from .env import TERMS

    try:
        w = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of numbers: {text!r}") from None
    if len(w) != len(TERMS):
        raise argparse.ArgumentTypeError(f"needs {len(TERMS)} numbers ({', '.join(TERMS)}), got {text!r}")
    try:
        check_value("adv_weights", w, _train_field("adv_weights"))
    except ConfigError as e:
        raise argparse.ArgumentTypeError(str(e).removeprefix("adv_weights ")) from None
    return w


def _configs(a):
    from .baselines import PlannerConfig

    env = _env_config(a, a.start)
    pc = PlannerConfig(
        depth=a.depth,
        horizon=a.horizon,
        popsize=a.popsize,
        generations=a.generations,
        budget_aware=a.budget_aware,
        scoring=a.scoring,
        cost_weight=a.cost_weight,
        info_weight=a.info_weight,
        prio_revisit=a.prio_revisit,
        cmaes_tol=a.cmaes_tol,
    )
    if a.horizon < 1 or a.popsize < 2 or a.generations < 1:
        raise UserError("--horizon >= 1, --popsize >= 2 and --generations >= 1 are required")
    return env, pc


def _env_config(a, start):
    from .env import EnvConfig, semantic_config
    from .world import WorldConfig

    if a.map_size is not None and a.map_size < 1:
        raise UserError(f"map size must be positive, got {a.map_size}")
    if a.world == "semantic":
        if a.raster is not None and not Path(a.raster).is_file():
            raise UserError(f"class raster {a.raster} not found")
        env = semantic_config(budget=a.budget, raster=a.raster, start=start, map_size=a.map_size or 256)
        if a.raster is not None:  # fail early, one line, on a bad raster
            from .semantic import load_class_raster

            load_class_raster(a.raster, env.map_size, env.semantic.n_classes)
        return env
    if a.raster is not None:
        raise UserError("--raster needs --world semantic")
    size = a.map_size or EnvConfig().map_size
    return EnvConfig(
        map_size=size, budget=EnvConfig().budget if a.budget is None else a.budget, start=start, world=WorldConfig(map_size=size)
    )


def _lattice_build(a) -> int:
    from .lattice import LatticeConfig, build_lattice, plot_lattice, save_lattice

    cfg = replace(
        LatticeConfig(),
        n_vertices=a.n_vertices,
        v_max=a.v_max,
        a_max=a.a_max,
        rho=a.rho,
        reach=a.reach,
        max_edges=a.max_edges,
        footprint_radius=a.footprint_radius,
        sense_dt=a.sense_dt,
    )
    lat = build_lattice(cfg)
    out = save_lattice(lat, a.out)
    print(
        f"lattice: {lat.n_vertices} vertices, {lat.n_prims} primitives, "
        f"<= {lat.n_actions} per vertex, dispersion {lat.dispersion[-1]:.1f} -> {out}"
    )
    if not a.no_plot:
        fig = plot_lattice(lat, a.plot or Path(a.out).with_suffix(".png"))
        print(f"plot -> {fig}")
    return 0


def _load_models(a, kind: str = "targets") -> dict:
    """{row key: model} for the --run directories: 'rl' (GRU core) / 'rl_nolstm' (MLP)."""
    if not a.run:
        raise UserError("planner rl needs --run <trained run directory>")
    from .policy import load_policy

    out = {}
    for path in a.run:
        m = load_policy(path)
        pp = Path(path)
        m.run_label = pp.name if pp.is_dir() else f"{pp.parent.name}/{pp.name}"
        m.checkpoint_name = "model.pt" if pp.is_dir() else pp.name
        if m.env_kind != kind:
            raise UserError(f"{path}: policy was trained on {m.env_kind} worlds, not {kind}")
        key = "rl" if m.cfg.recurrent else "rl_nolstm"
        k, i = key, 2
        while k in out:
            k, i = f"{key}_{i}", i + 1
        out[k] = m
    return out


BELIEF_READERS = ("detect", "dp", "greedy", "prio_coverage", "cmaes")  # planners that read the belief


def _load_belief(a, names, probe):
    """The learned belief of ``--belief`` (None without it), checked against the bench."""
    if a.belief is None:
        if a.belief_temperature is not None:
            raise UserError("--belief-temperature needs --belief RUN")
        return None
    if a.all or any(n not in BELIEF_READERS for n in names):
        raise UserError(f"--belief plans one planner over the learned belief: --planner {'|'.join(BELIEF_READERS)}")
    if a.execution != ("ideal",):
        raise UserError("--belief runs ideal execution (drop --execution)")
    from .belief import check_temperature, load_belief

    if a.belief_temperature is not None:
        check_temperature(a.belief_temperature)
    model = load_belief(a.belief, temperature=a.belief_temperature)
    model.check_env(probe)
    return model


def _bench(a) -> int:
    from tqdm import tqdm

    from .baselines import PLANNERS, THESIS_NAMES, make_planner
    from .bench import BenchConfig, run_episodes
    from .factory import create_env
    from .lattice import get_lattice
    from .metrics import (
        markdown_table,
        paired_markdown,
        per_env_csv,
        plot_kl,
        seeds_markdown,
        summarise,
        summary_csv,
        write_atomic,
    )

    set_threads(a.threads)
    env, pc = _configs(a)
    if a.envs is None:
        a.envs = 30 if env.kind == "semantic" else 100
    names = tuple(PLANNERS) if a.all else (a.planner or "dp",)
    if a.all and a.run:
        names += ("rl",)
    cfg = BenchConfig(planners=names, envs=a.envs, seed=a.seed, batch=a.batch, env=env, planner=pc)
    cfg.validate()
    lat = get_lattice(a.lattice, env.kind)
    probe = create_env(env, lat)  # validate map size / budget / planner flags up front
    models = _load_models(a, env.kind) if "rl" in names else {}
    for name in names:
        if name != "rl":
            make_planner(name, probe, pc)
    belief = _load_belief(a, names, probe)
    rows = [(n, None) for n in names if n != "rl"] + list(models.items())
    if a.execution != ("ideal",) and env.kind != "targets":
        raise UserError("--execution flown is for target search (--world targets)")
    if a.budgets:
        if a.execution != ("ideal",):
            raise UserError("--budgets sweeps ideal execution only (drop --execution)")
        return _bench_budgets(a, cfg, lat, rows, models, pc, belief)
    skill = skill_label = None
    if "skill" in a.execution:
        from .flown import load_skill

        skill, skill_label = load_skill(a.skill_run)
    elif a.skill_run is not None:
        raise UserError("--skill-run needs --execution skill")
    by_mode = {}
    for mode in a.execution:
        mcfg = replace(cfg, execution=mode)
        res = {}
        for name, model in rows:
            bar = tqdm(
                total=a.envs, desc=f"{name} ({mode})", file=sys.stderr, disable=a.quiet or not sys.stderr.isatty(), leave=False
            )
            r = run_episodes(name, lat, mcfg, progress=bar, model=model, skill=skill, belief=belief)
            bar.close()
            r["summary"] = summarise(r["per_env"])
            res[name] = r
        by_mode[mode] = res
    results = by_mode[a.execution[-1]]
    labels = dict(THESIS_NAMES)
    labels = _variant_labels(labels, names, pc)
    if belief is not None:
        for n in names:
            labels[n] = f"{labels[n]} over the learned belief ({belief.label}, T = {belief.temperature:.3g})"
    from .policy import describe_policy

    recipes: dict[str, dict] = {}  # one recipe, several training seeds: a claim over seeds
    for k, m in models.items():  # what each policy is: never the thesis's name
        desc, it = describe_policy(m), m.train_info.get("iterations")
        labels[k] = f"{desc} ({m.run_label})"
        if it and "PPO" not in desc:  # actor-critic runs differ by their PPO iterations
            desc += f", {it} PPO it."
        seeds = recipes.setdefault(f"{desc}, {m.checkpoint_name}", {})
        seeds.setdefault(m.train_info.get("seed"), []).append(k)
    groups = {
        f"{r}, seeds {', '.join(str(s) for s in sd)}": [ks[0] for ks in sd.values()]
        for r, sd in recipes.items()
        if None not in sd
    }  # a re-run is not another seed
    md = ""
    for mode, res in by_mode.items():
        if len(by_mode) > 1 or mode != "ideal":
            md += f"\n**{mode} execution**\n\n"
        md += (
            markdown_table(res, labels, env.kind)
            + paired_markdown(res, labels, PLANNERS)
            + seeds_markdown(res, labels, groups, PLANNERS)
        )
    out = Path(a.out)
    if len(by_mode) > 1 or set(by_mode) & {"flown", "skill"}:
        from .metrics import execution_markdown

        ex = execution_markdown(by_mode, labels)
        md += "\n**Execution: " + " vs ".join(by_mode) + "**" + (f" (skill: {skill_label})" if skill_label else "") + "\n\n" + ex
        write_atomic(out / "ipp_execution.md", ex)
    print(md, end="")
    write_atomic(out / "ipp_bench.md", md)
    flat = results if len(by_mode) == 1 else {f"{k}@{m}": r for m, res in by_mode.items() for k, r in res.items()}  # every mode
    write_atomic(out / "ipp_bench.csv", summary_csv(flat, env.kind))
    write_atomic(out / "ipp_bench_envs.csv", per_env_csv(flat))
    plot_kl(
        results,
        labels,
        out / "ipp_kl.png",
        xlabel="prior cross-entropy (nats/cell), quantile bins"
        if env.kind == "semantic"
        else "KL(truth || prior) (nats), quantile bins",
    )
    print(f"wrote {out}/ipp_bench.md, ipp_bench.csv, ipp_bench_envs.csv, ipp_kl.png")
    return 0


def _variant_labels(labels: dict, names, pc) -> dict:
    """Say so in the row name when a planner runs with a non-default option."""
    labels = dict(labels)
    for n in names:
        if n == "rl" or n not in labels:
            continue
        tags = []
        if pc.budget_aware is not None and n != "cmaes" and pc.budget_aware != (n == "detect"):
            tags.append(f"{'' if pc.budget_aware else 'not '}budget-aware")
        if pc.scoring == "additive":
            tags.append(f"additive, w = {pc.cost_weight:g}")
        if n == "detect" and pc.info_weight > 0:
            tags.append(f"+ {pc.info_weight:g} x information gain")
        if n == "prio_coverage" and not pc.prio_revisit:
            tags.append("no revisits")
        if n == "cmaes" and (pc.popsize, pc.generations) != (12, 15):
            tags.append(f"{pc.popsize} x {pc.generations}")
        if tags:
            labels[n] = f"{labels[n]} ({', '.join(tags)})"
    return labels


def _labels(names, models, pc) -> dict:
    from .baselines import THESIS_NAMES
    from .policy import describe_policy

    labels = _variant_labels(THESIS_NAMES, names, pc)
    for k, m in models.items():
        labels[k] = f"{describe_policy(m)} ({m.run_label})"
    return labels


def _bench_budgets(a, cfg, lat, rows, models, pc, belief=None) -> int:
    """``ipp bench --budgets B1,B2,...``: every row at every budget (same worlds), with
    ``belief`` (``--belief``) over the learned belief. Writes the per-world metrics too
    (``ipp_budgets_envs.csv``), so sweeps of separate benches pair world by world."""
    from dataclasses import replace as dc_replace

    from tqdm import tqdm

    from .bench import run_episodes
    from .factory import create_env
    from .metrics import budget_csv, budget_envs_csv, budget_markdown, plot_budgets, summarise, write_atomic

    for b in a.budgets:  # every budget must pay for a primitive: fail before running
        create_env(dc_replace(cfg.env, budget=b), lat)
    labels = _labels([n for n, _ in rows], models, pc)
    if belief is not None:
        for n, _ in rows:
            labels[n] = f"{labels[n]} over the learned belief ({belief.label}, T = {belief.temperature:.3g})"
    sweep = {}  # (row, budget) -> result
    for b in a.budgets:
        bc = dc_replace(cfg, env=dc_replace(cfg.env, budget=b))
        for name, model in rows:
            bar = tqdm(
                total=a.envs, desc=f"{name} @ {b:g}", file=sys.stderr, disable=a.quiet or not sys.stderr.isatty(), leave=False
            )
            r = run_episodes(name, lat, bc, progress=bar, model=model, belief=belief)
            bar.close()
            r["summary"] = summarise(r["per_env"])
            sweep[(name, b)] = r
    md = budget_markdown(sweep, labels, cfg.env.kind)
    print(md, end="")
    out = Path(a.out)
    write_atomic(out / "ipp_budgets.md", md)
    write_atomic(out / "ipp_budgets.csv", budget_csv(sweep))
    write_atomic(out / "ipp_budgets_envs.csv", budget_envs_csv(sweep, labels))
    plot_budgets(sweep, labels, out / "ipp_budgets.png", cfg.env.kind)
    print(f"wrote {out}/ipp_budgets.md, ipp_budgets.csv, ipp_budgets_envs.csv, ipp_budgets.png")
    return 0


def _train(a) -> int:
    from tqdm import tqdm

    from .lattice import get_lattice
    from .train import load_run_config, preset, train

    if a.resume:
        allowed = {"resume", "iterations", "lattice", "threads", "quiet", "cmd", "_defaults"}
        given = sorted(k for k, v in a._defaults.items() if k not in allowed and hasattr(a, k) and getattr(a, k) != v)
        if given:
            raise UserError(
                "--resume continues a run with its own config.json; only "
                "--iterations, --lattice, --threads and --quiet may be given (got "
                + ", ".join("--" + k.replace("_", "-") for k in given)
                + ")"
            )
        from aerohrl.algorithms.run import Run

        run = Path(a.resume)
        opened = Run.open(run, kind="ipp")
        cfg = load_run_config(opened)
        if a.iterations is not None:
            cfg = replace(cfg, iterations=a.iterations)
        if a.threads is not None:  # where it runs, not what it learns
            cfg = replace(cfg, threads=a.threads)
        lat = get_lattice(a.lattice, cfg.env.kind)
        import json
        from dataclasses import asdict

        saved = opened.meta.get("lattice")
        if saved is not None and saved != json.loads(json.dumps(asdict(lat.config))):
            raise UserError(f"{run}: trained on another lattice (pass the same --lattice)")
    else:
        if a.preset is None:
            a.preset = "semantic" if a.world == "semantic" else "cpu"
        if a.preset == "semantic":
            if a.world == "targets":
                raise UserError("preset semantic trains on semantic worlds (--world semantic)")
            a.world = "semantic"
        from aerohrl.config import given_flags

        from .train_config import TrainConfig

        cfg = preset(
            a.preset,
            n_envs=a.n_envs,
            seed=a.seed,
            threads=a.threads,
            teacher_depth=a.teacher_depth,
            adv_weights=a.adv_weights,
            recurrent=False if a.no_rnn else None,
            features=False if a.no_features else None,
            **given_flags(a, TrainConfig, skip=_train_skip()),
        )
        cfg = replace(cfg, env=_env_config(a, a.start or "random"))
        # the shape of every command's run names (aerohrl.cli_common.run_name); two runs in one second differ
        run = Path(a.out) / (a.name or run_name("ipp", a.preset, "nornn" if a.no_rnn else None, seed=cfg.seed))
        lat = get_lattice(a.lattice, cfg.env.kind)
    if a.threads is not None and a.threads < 1:
        raise UserError(f"--threads must be >= 1, got {a.threads}")
    cfg.validate()
    from .factory import create_env

    create_env(cfg.env, lat)
    bar = tqdm(total=cfg.total_iterations, desc="train", file=sys.stderr, disable=a.quiet)
    try:  # a new run claims its folder exclusively; either holds the run's lock while it trains
        last = train(cfg, lat, run, progress=bar, resume=bool(a.resume))
    finally:
        bar.close()
    print(
        f"trained {last['iteration']} iterations x {cfg.n_envs} envs "
        f"({cfg.bc_iterations} DAgger + {cfg.iterations} PPO) in {last['time_s'] / 60:.1f} min: "
        f"return {last['return']:.1f}, search eff. {last['search_efficiency']:.1f}% (train "
        f"worlds) -> {run} (model.pt, checkpoint.pt, metrics.jsonl, learning_curve.png)"
    )
    return 0


def _belief(a) -> int:
    if a.bcmd == "calibrate":
        return _belief_calibrate(a)
    from tqdm import tqdm

    from .belief import BeliefConfig, preset, read_belief_config, train_belief
    from .lattice import get_lattice

    if a.resume:
        allowed = {"resume", "epochs", "lattice", "threads", "quiet", "cmd", "bcmd", "_defaults"}
        given = sorted(k for k, v in a._defaults.items() if k not in allowed and hasattr(a, k) and getattr(a, k) != v)
        if given:
            raise UserError(
                "--resume continues a run with its own config.json; only --epochs, --lattice, --threads and --quiet may be given (got "
                + ", ".join("--" + k.replace("_", "-") for k in given)
                + ")"
            )
        run = Path(a.resume)
        cfg = read_belief_config(run)
        if a.epochs is not None:
            cfg = replace(cfg, epochs=a.epochs)
        if a.threads is not None:  # where it runs, not what it learns
            cfg = replace(cfg, threads=a.threads)
    else:
        from aerohrl.config import given_flags

        cfg = preset(a.preset, seed=a.seed, threads=a.threads, **given_flags(a, BeliefConfig, skip=_belief_skip()))
        env = cfg.env
        if a.map_size is not None:
            from .world import WorldConfig

            env = replace(env, map_size=a.map_size, world=WorldConfig(map_size=a.map_size))
        if a.budget is not None:
            env = replace(env, budget=a.budget)
        cfg = replace(cfg, env=env)
        run = Path(a.out) if a.out else Path("runs") / run_name("ipp-belief", a.preset, seed=cfg.seed)
    cfg.validate()
    lat = get_lattice(a.lattice, "targets")
    from .factory import create_env

    create_env(cfg.env, lat)
    set_threads(cfg.threads)
    bar = tqdm(total=cfg.epochs, desc="belief", file=sys.stderr, disable=a.quiet or not sys.stderr.isatty())
    try:
        last = train_belief(cfg, lat, run, progress=bar, resume=bool(a.resume))
    finally:
        bar.close()
    print(_belief_summary(last["calibration"]))
    print(
        f"trained {last['epoch']} epochs in {last['time_s'] / 60:.1f} min: validation log-loss {last['val_logloss']:.4f} "
        f"(hand-written posterior {last['val_logloss_posterior']:.4f}) -> {run} "
        "(belief.pt, checkpoint.pt, data.npz, metrics.jsonl, calibration.json, reliability.png)"
    )
    return 0


def _belief_summary(rep: dict) -> str:
    def row(k):
        r = rep[k]
        return f"log-loss {r['logloss']:.4f}, ECE {r['ece']:.4f}, Brier {r['brier']:.5f}"

    return (
        f"validation ({rep['val_worlds']} worlds, {rep['states']} states): temperature {rep['temperature']:.3f}; "
        f"hand-written posterior: {row('posterior')}; learned (T = 1): {row('learned')}; learned (T): {row('learned_T')}"
    )


def _belief_calibrate(a) -> int:
    from .belief import calibrate

    run = a.run or a.run_flag
    if run is None:
        raise UserError("belief calibrate needs RUN (a belief run directory)")
    rep = calibrate(run)
    print(_belief_summary(rep))
    print(f"wrote {run}/calibration.json, {run}/reliability.png")
    return 0


def _compare(a) -> int:
    """``aerohrl ipp compare A B``: A − B paired over the same worlds, one line."""
    from .metrics import paired_comparison, read_per_env

    (pa, va, ka), (pb, vb, kb) = read_per_env(a.bench_a, a.metric), read_per_env(a.bench_b, a.metric)
    common = set(va) & set(vb)
    if len(common) < 2:
        raise UserError(f"{a.bench_a} and {a.bench_b} share fewer than 2 worlds (same --seed and --envs?)")
    if any(ka[i] != kb[i] for i in common):  # same index, another world: a different --seed or map
        raise UserError(f"{a.bench_a} and {a.bench_b} ran different worlds under the same ids (same --seed and world flags?)")
    c = paired_comparison(va, vb)
    # p to 3 significant digits: a tiny p stays readable (1.2e-12), not "0.000"
    print(
        f"{a.metric}: {pa} ({a.bench_a}) - {pb} ({a.bench_b}) = {c['diff']:+.2f} ± {c['se']:.2f} points "
        f"(mean ± s.e. over {c['n']} worlds; better on {c['better']}, worse on {c['worse']}; "
        f"paired t-test p = {c['p_t']:.3g}, Wilcoxon p = {c['p_wilcoxon']:.3g})"
    )
    return 0


def _curve(a) -> int:
    from .curve import plot_learning_curve

    out = plot_learning_curve(a.run, a.out)
    print(f"learning curve -> {out}")
    return 0


def _show(a) -> int:
    from .baselines import PLANNERS, TEACHERS, THESIS_NAMES
    from .bench import BenchConfig, render_episode, run_episodes
    from .lattice import get_lattice

    if a.planner not in PLANNERS + TEACHERS + ("rl",):
        raise UserError(f"unknown planner {a.planner!r} (choose from {', '.join(PLANNERS + TEACHERS)}, rl)")
    if a.env < 0:
        raise UserError("--env must be >= 0")
    env, pc = _configs(a)
    if len(a.execution) != 1:
        raise UserError("show takes one --execution mode")
    if a.gif is not None and Path(a.gif).suffix.lower() != ".gif":
        raise UserError(f"--gif must end in .gif, got {a.gif}")
    cfg = BenchConfig(planners=(a.planner,), envs=1, seed=a.seed, batch=1, env=env, planner=pc, execution=a.execution[0])
    lat = get_lattice(a.lattice, env.kind)
    key, model = next(iter(_load_models(a, env.kind).items())) if a.planner == "rl" else (a.planner, None)
    skill = None
    if cfg.execution == "skill":
        from .flown import load_skill

        skill, _ = load_skill(a.skill_run)
    r = run_episodes(a.planner, lat, cfg, env_ids=[a.env], keep_env=True, model=model, skill=skill)
    m = r["per_env"]
    from .policy import describe_policy

    label = describe_policy(model) if model is not None else THESIS_NAMES.get(key, key)
    title = (
        f"{label} on test env {a.env}: coverage {m['coverage'][0]:.0f}%, "
        f"entropy red. {m['entropy_reduction'][0]:.0f}%, "
        f"search eff. {m['search_efficiency'][0]:.0f}%"
    )
    out = render_episode(r["env"], 0, a.out, title)
    print(f"{title} -> {out}")
    if a.gif:
        from .bench import animate_episode

        g = animate_episode(
            a.planner, lat, cfg, a.env, a.gif, model=model, skill=skill, title=f"{label}, test world {a.env} ({cfg.execution})"
        )
        print(f"animation -> {g}")
    return 0


def _dispatch(argv) -> int:
    a = _parser().parse_args(argv)
    if a.cmd == "lattice":
        return _lattice_build(a)
    if a.cmd == "bench":
        return _bench(a)
    if a.cmd == "show":
        return _show(a)
    if a.cmd == "train":
        return _train(a)
    if a.cmd == "curve":
        return _curve(a)
    if a.cmd == "belief":
        return _belief(a)
    if a.cmd == "compare":
        return _compare(a)
    raise UserError(f"unknown command {a.cmd!r}")


def main(argv: list[str] | None = None) -> int:
    """The ``aerohrl ipp`` command (lattice, bench, train, ...); returns the exit code."""
    return run_cli(PROG, lambda: _dispatch(sys.argv[1:] if argv is None else argv))


if __name__ == "__main__":
    sys.exit(main())
