"""The ``datagen`` command: build, inspect, validate, export and plot datasets.

Every subcommand is a thin layer over functions in this package that the tests call
directly. Bad input ends with one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import fields
from pathlib import Path
from typing import TYPE_CHECKING

from aerohrl import cli_types as T
from aerohrl.cli_common import add_common, progress, set_threads
from aerohrl.errors import ArgumentParser, UserError, run_cli, warn
from aerohrl.datagen.spec import EXPERTS, FAMILIES, SOLVERS, START_STATES, WORLDS, DatasetSpec

if TYPE_CHECKING:
    from aerohrl.datagen.dataset import DatasetHandle

PROG = "datagen"
# the spec fields whose values are a fixed set (DatasetSpec.check), shown and checked by argparse
# (vehicles: sim/params.py PRESETS, not imported here to keep --help fast; tests/test_cli_vocabulary.py checks them)
SPEC_CHOICES = {
    "vehicle": ("hummingbird", "crazyflie"),
    "solver": SOLVERS,
    "expert": EXPERTS,
    "start_states": START_STATES,
    "world": WORLDS,
    "family": FAMILIES,
}


def _spec_flags(p: argparse.ArgumentParser) -> None:
    """One flag per DatasetSpec field (``--pos-range 1 2`` for tuples), default None = spec file / default."""
    # each setting's meaning and unit as declared (aerohrl.config.param)
    helps = {
        f.name: f.metadata["help"] + (f" ({f.metadata['unit']})" if f.metadata.get("unit") else "") for f in fields(DatasetSpec)
    }
    # parse-time checks (aerohrl.cli_types); ranges are any finite LOW < HIGH (DatasetSpec.check)
    nonneg = {"seed", "continuations"}
    nonneg_float = {"replan_endgame", "start_vel", "start_tilt", "start_rate", "min_path", "settle", "explore_climb"}  # 0: off
    for f in fields(DatasetSpec):
        if f.name == "seed":  # a common flag (aerohrl.cli_common), added with them
            continue
        flag = "--" + f.name.replace("_", "-")
        default = f.default
        if isinstance(default, bool):  # a switch: absent keeps the spec file's value
            p.add_argument(flag, action="store_true", default=None, help=f"{helps[f.name]} [off]")
        elif f.name == "action_noise":
            p.add_argument(flag, type=T.nonneg_float, nargs="+", metavar="SIGMA", default=None, help=f"{helps[f.name]} [0 = off]")
        elif isinstance(default, tuple):
            p.add_argument(
                flag,
                type=T.positive_int if isinstance(default[0], int) else T.finite_float,
                nargs=2,
                metavar=("LOW", "HIGH"),
                default=None,
                help=f"{helps[f.name]} [{default[0]} {default[1]}]",
            )
        elif isinstance(default, str):
            p.add_argument(flag, default=None, choices=SPEC_CHOICES.get(f.name), help=f"{helps[f.name]} [{default}]")
        elif f.name in nonneg_float:
            p.add_argument(flag, type=T.nonneg_float, default=None, help=f"{helps[f.name]} [{default}]")
        else:
            kind = (T.nonneg_int if f.name in nonneg else T.positive_int) if isinstance(default, int) else T.positive_float
            p.add_argument(flag, type=kind, default=None, help=f"{helps[f.name]} [{default}]")


def parser() -> argparse.ArgumentParser:
    """The ``datagen`` argument parser (build, info, validate, export, push, plot)."""
    ap = ArgumentParser(prog=PROG, description="Expert quadrotor data as versioned LeRobot v3.0 datasets (thesis §3.4.1).")
    sub = ap.add_subparsers(dest="cmd", required=True, metavar="COMMAND")

    b = sub.add_parser("build", help="generate a dataset (or verify the existing version)")
    b.add_argument(
        "--spec", type=Path, default=None, help="dataset spec TOML (default: built-in defaults = datasets/quadrotor-reach.toml)"
    )
    add_common(
        b,
        out={"default": Path("datasets"), "help": "root folder: the dataset goes to OUT/NAME/VERSION [datasets]"},
        quiet=True,
        threads={"help": "OpenMP/BLAS threads of each process that flies episodes [their default]"},
        seed={"default": None, "help": "random seed of the goals and noise (>= 0) [0]"},
    )
    b.add_argument("--force", action="store_true", help="build even when the estimate exceeds the free memory or disk")
    b.add_argument(
        "--workers",
        type=T.positive_int,
        default=1,
        metavar="N",
        help="fly the blocks of 8,192 episodes in N local processes (or N Ray tasks at a time with "
        "--ray-address); byte-identical to 1 [1]",
    )
    b.add_argument(
        "--ray-address",
        default=None,
        metavar="ADDR",
        help="fly the blocks as Ray tasks on the cluster at ADDR (host:port, or auto)",
    )
    _spec_flags(b)

    i = sub.add_parser("info", help="summary, spec, checksums and expert success of a dataset")
    i.add_argument("path", type=Path, help="dataset folder (datasets/<name>/<version>)")
    i.add_argument("--json", action="store_true", help="print the full metadata as JSON")

    v = sub.add_parser("validate", help="integrity check; non-zero exit on any damage")
    v.add_argument("path", type=Path, help="dataset folder (datasets/<name>/<version>)")

    m = sub.add_parser("export-mcap", help="one episode as MCAP (Foxglove-viewable)")
    m.add_argument("path", type=Path)
    m.add_argument("--episode", type=T.nonneg_int, required=True, help="episode index (0-based)")
    add_common(m, out={"required": True, "help": "the .mcap file to write"})

    x = sub.add_parser("export", help="convert a dataset: minari (Minari dataset), ogbench (OGBench .npz), mcap (one episode)")
    x.add_argument("path", type=Path)
    x.add_argument("--format", required=True, choices=("minari", "ogbench", "mcap"), help="target format")
    add_common(
        x,
        out={
            "help": "minari: datasets root [$MINARI_DATASETS_PATH or ~/.minari/datasets]; ogbench: the .npz file "
            "[<name>-<version>.npz]; mcap: the .mcap file (required)"
        },
    )
    x.add_argument("--dataset-id", default=None, help="minari: dataset id [aerohrl/<name>/<version>-v0]")
    x.add_argument("--episode", type=T.nonneg_int, default=None, help="mcap: the episode to export")

    ps = sub.add_parser("push", help="upload a dataset to the Hugging Face Hub keeping its card, licence and metadata")
    ps.add_argument("path", type=Path)
    ps.add_argument("--repo-id", required=True, help="Hub dataset repo, OWNER/NAME")
    ps.add_argument(
        "--staging",
        type=Path,
        default=None,
        help="stage the upload in this (new or empty) folder and keep it [a temporary folder]",
    )
    ps.add_argument("--dry-run", action="store_true", help="stage only (with --staging: inspect what would be uploaded)")
    ps.add_argument("--private", action="store_true", help="create the repo private")

    pl = sub.add_parser("plot", help="3-D expert trajectories and goals (thesis Fig. 3.2 analogue)")
    pl.add_argument("path", type=Path)
    add_common(pl, out={"required": True, "help": "figure file (.png, .pdf, .svg)"})
    pl.add_argument("--max-episodes", type=T.positive_int, default=250, help="episodes drawn [250]")
    return ap


def cmd_build(a: argparse.Namespace) -> int:
    """``datagen build``: build (or verify) the dataset of the spec given; exit code."""
    set_threads(a.threads, torch=False)  # before numpy loads: the simulator is numpy, and so are the workers
    from aerohrl.datagen.build import build
    from aerohrl.datagen.spec import load_spec

    overrides = {f.name: getattr(a, f.name) for f in fields(DatasetSpec)}
    spec = load_spec(a.spec, **overrides)
    res = build(spec, a.out, progress=progress(a.quiet), force=a.force, workers=a.workers, ray_address=a.ray_address)
    if res.created:
        print(
            f"built {res.path}: {res.episodes} episodes, {res.frames} frames, "
            f"{res.resampled} goals resampled, in {res.seconds:.1f} s"
        )
    if spec.family == "explore":  # no expert: the desired goal is each episode's last achieved goal
        what = "random-walk" if spec.explore_pilot == "walk" else "random-velocity"
        print(f"explore: {res.episodes} {what} flights (no expert; see the dataset card)")
        print(res.path)
        return 0
    print(
        f"expert success rate: {100 * res.expert_success:.1f}% ({round(res.expert_success * res.episodes)}/{res.episodes} "
        "episodes reach the goal: 0.15 m, 0.35 m/s, 0.15 rad)"
    )
    if res.expert_success < 0.98:
        why = (
            "expected under action noise: the dataset labels every flown state with the clean expert command"
            if spec.noisy
            else "the expert's gains are tuned for the hummingbird preset and the default goal ranges"
        )
        print(f"{PROG}: warning: expert success below 98% on this spec ({why})", file=sys.stderr)
    print(res.path)
    return 0


def cmd_info(a: argparse.Namespace) -> int:
    """``datagen info``: print a dataset's manifest (``--json``: as JSON); exit code."""
    from aerohrl.datagen.dataset import open_dataset

    ds = open_dataset(a.path, verify=False)
    meta = ds.manifest
    if a.json:
        print(json.dumps(meta, indent=2, sort_keys=True))
        return 0
    problems = warn_if_damaged(ds)
    s = meta["spec"]
    d = meta["reference_duration_s"]
    sizes = sum((a.path / r).stat().st_size for r in meta["checksums"] if (a.path / r).exists())
    lines = [
        f"dataset      {meta['name']} / {meta['version']}   ({a.path})",
        f"generator    aerohrl.datagen v{meta['generator']['generator_version']} (aerohrl {meta['generator']['aerohrl_version']})",
        f"episodes     {meta['episodes']}   frames {meta['frames']}   fps {s['fps']}   size {sizes / 1e6:.2f} MB",
        *(
            [
                f"goals        seed {meta['seed']}; |p_i| {s['pos_range']} m, v_i {s['vel_range']} m/s, a_i {s['acc_range']} m/s^2; resampled {meta['resampled_goals']}"
            ]
            if "family" not in meta
            else [_family_line(meta)]
        ),
        *(
            [
                f"continuations {meta['continuations']['episodes']} (episodes {meta['continuations']['first_episode']}.."
                f"{meta['episodes'] - 1}: from states of the rest-start flights, moved to the origin)"
            ]
            if meta.get("continuations")
            else []
        ),
        f"reference    degree {s['degree']}, {s['solver']}, a_max {s['a_max']} m/s^2; T min/mean/max {d['min']:.2f}/{d['mean']:.2f}/{d['max']:.2f} s",
        f"vehicle      {meta['vehicle']['name']} (mass {meta['vehicle']['mass']} kg), {s['substeps']} RK4 substeps per step",
        (
            "expert       none (explore: "
            + ("a noisy random walk" if s.get("explore_pilot") == "walk" else "random velocity commands")
            + "; the desired goal is each episode's last achieved goal)"
            if meta.get("family") == "explore"
            else f"expert       {100 * meta['expert_success_rate']:.1f}% success (goal-reached test 0.15 m, 0.35 m/s, 0.15 rad)"
        ),
        f"checksums    {len(meta['checksums'])} files, SHA-256: "
        + ("all match" if not problems else f"{len(problems)} PROBLEM(S), run `datagen validate`"),
    ]
    print("\n".join(lines))
    return 0


def _family_line(meta: dict) -> str:
    """``datagen info``'s line for a maze or explore dataset: world, family and what was measured."""
    parts = [f"world        {meta['world']}, family {meta['family']}, seed {meta['seed']}"]
    if "collisions" in meta:
        parts.append(f"collisions {meta['collisions']}")
    if "task_coverage" in meta:
        parts.append(f"frozen-task coverage {meta['task_coverage']['fraction']:.2f}")
    return "; ".join(parts)


def cmd_validate(a: argparse.Namespace) -> int:
    """``datagen validate``: check a dataset against its manifest; exit code 1 on problems."""
    from aerohrl.datagen.dataset import DatasetDamaged, open_dataset
    from aerohrl.datagen.manifest import validate

    try:  # a missing folder, not a dataset, another format version: one line, exit 2
        problems = open_dataset(a.path, verify=False).problems()
    except DatasetDamaged:  # its manifest or info.json: list everything found
        problems = validate(a.path)
    if problems:
        for p in problems:
            print(f"{a.path}: {p}", file=sys.stderr)
        print(f"{PROG}: error: {a.path} is damaged ({len(problems)} problem(s))", file=sys.stderr)
        return 1
    print(f"{a.path}: OK")
    return 0


def warn_if_damaged(ds: DatasetHandle) -> list[str]:
    """The dataset's integrity problems (every file's SHA-256, the LeRobot structure;
    about a second per 2 M frames), with a warning when there are any: the reading
    commands go on, but say that what they print may come from damaged files."""
    from aerohrl.datagen.dataset import DatasetDamaged

    try:
        ds.verify()
    except DatasetDamaged as e:
        warn(f"{e}; what follows may be wrong")
        return e.problems
    return []


def cmd_export_mcap(a: argparse.Namespace) -> int:
    """``datagen export-mcap``: episodes as MCAP files for Foxglove; exit code."""
    from aerohrl.datagen.dataset import open_dataset
    from aerohrl.datagen.mcap_export import export_mcap

    warn_if_damaged(open_dataset(a.path, verify=False))
    counts = export_mcap(a.path, a.episode, a.out)
    print(f"wrote {a.out}: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    return 0


def cmd_export(a: argparse.Namespace) -> int:
    """``datagen export --format mcap|minari|ogbench``: convert a dataset; exit code."""
    from aerohrl.datagen import exchange
    from aerohrl.datagen.dataset import open_dataset

    ds = open_dataset(a.path, verify=False)
    warn_if_damaged(ds)
    if a.format == "mcap":
        if a.episode is None or a.out is None:
            raise UserError("--format mcap needs --episode N and -o FILE.mcap")
        from aerohrl.datagen.mcap_export import export_mcap

        counts = export_mcap(a.path, a.episode, a.out)
        print(f"wrote {a.out}: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
        return 0
    if a.episode is not None:
        raise UserError(f"--episode applies to --format mcap only (--format {a.format} exports every episode)")
    if a.format == "minari":
        out = exchange.export_minari(a.path, a.dataset_id, a.out)
    else:
        if a.dataset_id is not None:
            raise UserError("--dataset-id applies to --format minari only")
        meta = ds.manifest
        out = exchange.export_ogbench(a.path, a.out or Path(f"{meta.get('name', 'dataset')}-{meta['version']}.npz"))
    print(f"wrote {out}")
    return 0


def cmd_push(a: argparse.Namespace) -> int:
    """``datagen push``: stage a dataset with our card and licence and upload it to the Hub; exit code."""
    import tempfile

    from aerohrl.datagen import exchange

    if a.repo_id.count("/") != 1 or not all(a.repo_id.split("/")):
        raise UserError(f"--repo-id must be OWNER/NAME, got {a.repo_id!r}")
    if a.dry_run and a.staging is None:
        raise UserError("--dry-run needs --staging DIR (where to leave the staged files)")
    with tempfile.TemporaryDirectory(prefix="aerohrl-push-") as tmp:
        staging = exchange.stage_push(a.path, a.staging or Path(tmp) / "dataset")
        n = sum(1 for p in staging.rglob("*") if p.is_file())
        print(f"staged {staging}: {n} files (the dataset as built, its card and metadata, LICENSE)")
        if a.dry_run:
            return 0
        try:
            url = exchange.push(staging, a.repo_id, private=a.private)
        except UserError:
            raise
        except Exception as e:  # the Hub: no network, no token, no rights
            raise UserError(
                f"upload to {a.repo_id} failed: {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
            ) from None
    print(f"pushed {url}")
    return 0


def cmd_plot(a: argparse.Namespace) -> int:
    """``datagen plot``: overview figures of a dataset; exit code."""
    from aerohrl.datagen.dataset import open_dataset
    from aerohrl.datagen.plots import plot_dataset

    warn_if_damaged(open_dataset(a.path, verify=False))
    plot_dataset(a.path, a.out, max_episodes=a.max_episodes)
    print(f"wrote {a.out}")
    return 0


COMMANDS = {
    "build": cmd_build,
    "info": cmd_info,
    "validate": cmd_validate,
    "export-mcap": cmd_export_mcap,
    "export": cmd_export,
    "push": cmd_push,
    "plot": cmd_plot,
}


def main(argv: list[str] | None = None) -> int:
    """The ``datagen`` command; returns the exit code."""
    args = parser().parse_args(argv)
    return run_cli(PROG, lambda: COMMANDS[args.cmd](args))


if __name__ == "__main__":
    sys.exit(main())
