"""The ``train`` command::

    train --algo gcsl --dataset datasets/<name>/<version> --preset cpu     # -> runs/<run>/
    train --algo td3bc --dataset ... --preset thesis --device cuda
    train --algo cql --dataset ... --steps 50000 --batch-size 512          # flags override the preset
    train --resume runs/<run>                                              # continue after a stop/kill
    train --config runs/<run>/run.toml --seed 1                            # a saved config; flags override it

One flag per :class:`~aerohrl.algorithms.config.TrainConfig` setting (sections
included: ``--alpha`` sets ``cfg.td3bc.alpha``); the common flags
(``--out``, ``--quiet``, ``--threads``, ``--seed``, ``--device``) are those of every
command (:mod:`aerohrl.cli_common`). Exit status: 0 done,
2 bad input (unknown algorithm/preset, missing/damaged dataset or run), 3 the loss
diverged (NaN/inf: the last good checkpoint is kept), 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from aerohrl import cli_types as T
from aerohrl import config as K
from aerohrl.algorithms import config as C
from aerohrl.cli_common import add_common, progress, set_threads
from aerohrl.errors import ArgumentParser, UserError, run_cli, warn

PROG = "train"
# what may change when a run is resumed (everything else defines the run)
RESUMABLE = {
    "steps",
    "device",
    "log_every",
    "checkpoint_every",
    "keep_checkpoints",
    "eval_every",
    "eval_episodes",
    "eval_horizon",
    "eval_task",
    "stop_success",
}
COMMON_FIELDS = ("seed", "device")  # TrainConfig settings that are common flags (aerohrl.cli_common)


def parser() -> ArgumentParser:
    """The ``train`` argument parser: one flag per :class:`TrainConfig` setting
    (:func:`aerohrl.config.add_flags`), its help and parse-time checks from the declaration."""
    # argparse rather than draccus or tyro: aerohrl.config generates the flags from the
    # declarations with today's spellings (--batch-size), the one-line parse-time errors of
    # errors.ArgumentParser and a --help that imports nothing heavy; draccus is only
    # installed by the [lerobot] extra.
    ap = ArgumentParser(prog=PROG, description="Offline goal-conditioned training on an expert dataset (thesis §3.4.2, Alg. 2).")
    ap.add_argument(
        "--preset", default=None, choices=C.presets(), help="hyper-parameter preset (a TOML file of algorithms/presets/) [cpu]"
    )
    ap.add_argument(
        "--config",
        type=Path,
        default=None,
        metavar="FILE",
        help=f"a TOML train config (every run saves its own as RUN/{C.TOML_NAME}); flags override its values",
    )
    ap.add_argument("--resume", type=Path, default=None, metavar="RUN", help="continue RUN from its last checkpoint")
    add_common(
        ap,
        out={"default": Path("runs"), "help": "folder of runs: the run goes to OUT/NAME [runs]"},
        quiet=True,
        threads={"help": "torch threads [torch's default: all cores]"},
        seed={"default": None, "help": "random seed (>= 0) [cpu: 0]"},
        device={"default": None, "help": "torch device: cpu | cuda | cuda:N [cpu: cpu]"},
    )
    ap.add_argument("--name", default=None, help="run folder name, must be new [ALGO-PRESET-sSEED-YYYYMMDD-HHMMSS-XXXXXX]")
    ap.add_argument(
        "--logger",
        default=None,
        metavar="NAME",
        help="where scalars go besides metrics.jsonl: tensorboard (RUN/tb) | wandb (offline, RUN/wandb; needs "
        "`pip install wandb`) | none [tensorboard; on --resume: the run's]",
    )
    ap.add_argument(
        "--progress-every",
        type=T.nonneg_float,
        default=60.0,
        metavar="SECONDS",
        help="without a progress bar (no terminal, --quiet): a progress line every SECONDS (0: none) [60]",
    )
    ap.add_argument(
        "--progress-steps", type=T.nonneg_int, default=0, metavar="N", help="... and every N steps (0: only by time) [0]"
    )
    per_algo: dict[str, list[str]] = {}
    for algo, values in C.per_algo_values("cpu").items():
        for k, v in values.items():
            per_algo.setdefault(k, []).append(f"{algo}: {v}")
    K.add_flags(
        ap,
        C.TrainConfig,
        skip=COMMON_FIELDS,
        defaults=C.preset_base("cpu"),
        default_label="cpu",
        notes={k: "; ".join(v) for k, v in per_algo.items()},
    )
    return ap


def _overrides(a: argparse.Namespace) -> dict:
    """The settings given as flags."""
    return K.given_flags(a, C.TrainConfig)


def config_from_args(a: argparse.Namespace) -> C.TrainConfig:
    """The config of a new run: the preset (``--preset``, else the ``--config`` file's,
    else cpu), the ``--config`` file's values over it, the flags given over those.
    UserError (one line) on an unknown key, a bad value or a missing ``--dataset``."""
    values: dict = {}
    if a.config is not None:
        values = K.load_toml(a.config)
        K.from_mapping(
            C.TrainConfig,
            values,
            where=str(a.config),
            check=False,  # keys and types, naming the file
            hint="the keys are train's flags with _ for - (train --help)",
        )
    preset = a.preset or values.pop("preset", None) or "cpu"
    values.pop("preset", None)
    values.update(_overrides(a))  # explicit flags win
    cfg = C.make_config(preset, **values)  # unknown preset, values not allowed
    if not cfg.dataset:
        raise UserError("--dataset is required (or --resume RUN, or a --config file with dataset = ...)")
    return cfg


def run(a: argparse.Namespace) -> int:
    """``train``: start a new run (or resume one) and train it to the end; exit code."""
    from aerohrl.algorithms.run import new_run_dir
    from aerohrl.algorithms.trainer import resolve_device, resume_run, start_run

    ov = _overrides(a)
    set_threads(a.threads)
    bar = progress(a.quiet)
    kw = {"progress_every_s": a.progress_every, "progress_every_steps": a.progress_steps}
    if a.resume is not None:
        if a.preset is not None:
            raise UserError("--preset cannot be changed on --resume")
        if a.config is not None:
            raise UserError("--config starts a new run; --resume continues one with its own config")
        fixed = sorted(set(ov) - RESUMABLE - {"dataset"})
        if fixed:
            raise UserError(
                f"--resume cannot change {', '.join('--' + k.replace('_', '-') for k in fixed)} (they define the run)"
            )
        tr = resume_run(a.resume, progress=bar, overrides=ov, logger=a.logger, **kw)
        for aside, why in tr.set_aside:
            warn(f"{why}; set aside as {aside.name}")
        fallback = " (the newest intact checkpoint)" if tr.set_aside else ""
        print(
            f"resuming {a.resume} at step {tr.step}" + (f" from {tr.resumed_from}{fallback}" if tr.resumed_from else ""),
            file=sys.stderr,
        )
    else:
        cfg = config_from_args(a)
        resolve_device(cfg.device)  # before anything is created
        run_dir = new_run_dir(cfg, a.out, a.name)
        tr = start_run(cfg, run_dir, progress=bar, logger=a.logger or "tensorboard", **kw)
        print(f"run {run_dir}: {cfg.algo}, preset {cfg.preset}, dataset {tr.dataset['version']}", file=sys.stderr)
    print(f"precision: {tr.precision}", file=sys.stderr)
    step = tr.train()
    if tr.stopped_at is not None:
        print(f"stopped: the evaluation at step {step} reached success {tr.cfg.stop_success:g} (--stop-success)", file=sys.stderr)
    print(f"done: {tr.run_dir} at step {step}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """The ``train`` command; returns the exit code."""
    args = parser().parse_args(argv)
    return run_cli(PROG, lambda: run(args))  # every UserError (bad --config, values) is one line, exit 2


if __name__ == "__main__":
    sys.exit(main())


def export_main(argv: list[str] | None = None) -> int:
    """``aerohrl export-policy --run RUN --format onnx|torchscript -o FILE``: the newest
    checkpoint's policy as one file for onboard use (algorithms/export.py); exit code."""
    from aerohrl.algorithms.export import FORMATS

    ap = ArgumentParser(
        prog="aerohrl export-policy",
        description="Export a run's newest policy (normaliser, network, action clip) as TorchScript or ONNX, with the "
        "observation layout, units and normalisation in the file's metadata (docs/export.md).",
    )
    ap.add_argument("--run", required=True, type=Path, help="training run folder (runs/<run>)")
    ap.add_argument("--format", required=True, choices=FORMATS, help="torchscript (.pt) | onnx (.onnx, needs aerohrl[export])")
    ap.add_argument("--latency", action="store_true", help="also measure single-sample inference time on one thread")
    add_common(ap, out={"required": True, "help": "the exported file"})
    a = ap.parse_args(sys.argv[1:] if argv is None else argv)

    def go() -> int:
        from aerohrl.algorithms.export import export_policy, load_exported, single_sample_latency

        import torch

        torch.set_num_threads(1)
        path, meta = export_policy(a.run, a.format, a.out)
        print(f"{meta['algorithm']} at step {meta['checkpoint_step']} -> {path} ({a.format})")
        if a.latency:
            predict, _ = load_exported(path)
            us = 1e6 * single_sample_latency(predict, state_width=meta["inputs"]["state"]["shape"][1])
            print(f"single-sample inference, one thread: {us:.1f} us (median)")
        return 0

    return run_cli("aerohrl export-policy", go)
