"""The ``train`` command::

    train --algo gcsl --dataset datasets/<name>/<version> --preset cpu     # -> runs/<run>/
    train --algo td3bc --dataset ... --preset thesis --device cuda
    train --algo cql --dataset ... --steps 50000 --batch-size 512          # flags override the preset
    train --resume runs/<run>                                              # continue after a stop/kill
    train --config runs/<run>/run.toml --seed 1                            # a saved config; flags override it

One flag per :class:`~aerohrl.algorithms.config.TrainConfig` field; the common flags
(``--out``, ``--quiet``, ``--threads``, ``--seed``, ``--device``) are those of every
command (:mod:`aerohrl.cli_common`). Exit status: 0 done,
2 bad input (unknown algorithm/preset, missing/damaged dataset or run), 3 the loss
diverged (NaN/inf: the last good checkpoint is kept), 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import fields
from pathlib import Path
from typing import Any, Callable

from aerohrl import cli_types as T
from aerohrl.algorithms import config as C
from aerohrl.cli_common import add_common, progress, set_threads
from aerohrl.errors import ArgumentParser, UserError, run_cli, warn

PROG = "train"
# what may change when a run is resumed (everything else defines the run)
RESUMABLE = {"steps", "device", "log_every", "checkpoint_every", "keep_checkpoints", "eval_every", "eval_episodes", "eval_horizon"}
HELP = {
    "algo": "algorithm",
    "dataset": "dataset folder (datasets/<name>/<version>); required unless --resume or a --config file names it",
    "bc_target": "what GCSL and the BC terms imitate on a noisy (DART) dataset: expert (the clean command, column "
                 "action.expert) | executed (the flown action); critics always learn from the flown action",
    "steps": "gradient steps",
    "batch_size": "transitions per batch",
    "hidden": "hidden layer sizes of the actor (units per layer; and of the critics unless --critic-hidden)",
    "critic_hidden": "hidden layer sizes of the critics (units per layer; none given: as --hidden)",
    "lr_actor": "actor learning rate (Adam)",
    "lr_critic": "critic learning rate (Adam)",
    "lr_schedule": "learning rate over the run: constant | cosine (to 5%% of the base rate at the last step)",
    "relabel_prob": "delta: probability of relabelling a goal with a later achieved goal",
    "relabel_offset": "how far ahead a relabelled goal lies: uniform (over the rest of the episode) | geometric",
    "relabel_window": "cap on the relabelling offset (steps; 0: to the episode's end)",
    "relabel_mean_offset": "geometric relabelling: mean offset (steps)",
    "gamma": "discount factor per step",
    "policy_noise": "TD3 target policy smoothing noise std (normalised action units, [-1, 1])",
    "noise_clip": "TD3 target policy noise clip (normalised action units)",
    "critic_random_goal_prob": "critics only: probability that a goal is a random frame's achieved goal (OGBench value_p_randomgoal)",
    "augment": "none | mirror: train on the 4 mirror images of every transition (exact symmetries of the vehicle)",
    "mc_lower_bound": "critic targets max(clipped TD target, discounted return observed in the data)",
    "amp": "mixed precision: auto (bf16 where the device runs it natively, else float32) | none (float32) | bf16 (autocast)",
    "ema_decay": "act with an exponential moving average of the policy weights (0: off)",
    "tau": "soft target update rate",
    "num_critics": "size of the goal-conditioned critic ensemble",
    "alpha": "TD3-BC alpha: weight of the Q-term, lambda = alpha / mean|Q|",
    "alpha_schedule": "TD3-BC/AWBC alpha over the run: constant | linear (to 0 at the last step)",
    "awr_temperature": "TD3-AWBC: weights exp(A / temperature)",
    "awr_max_weight": "TD3-AWBC: weights clipped at this",
    "awr_normalize": "TD3-AWBC: std (advantage / its batch std, then the temperature) | none (the thesis)",
    "cql_min_q_weight": "CQL: weight of the conservative penalty (the Lagrange variant's initial scale)",
    "cql_num_random": "CQL: random actions per state in the logsumexp",
    "cql_lagrange_thresh": "CQL: Lagrange variant, target gap logsumexp Q - Q_data (0: off)",
    "policy_delay": "TD3: actor/target update every N critic updates",
    "log_every": "metric line every N steps",
    "checkpoint_every": "checkpoint every N steps",
    "keep_checkpoints": "checkpoints kept (newest)",
    "eval_every": "closed-loop evaluation every N steps (0: none)",
    "eval_episodes": "episodes per evaluation",
    "eval_horizon": "simulator steps per evaluation episode (100 Hz: 500 = 5 s)",
}
# the fields whose values are a fixed set: argparse checks them and --help lists them
CHOICES = {"algo": C.ALGORITHMS, "lr_schedule": C.LR_SCHEDULES, "amp": C.AMP_MODES, "augment": C.AUGMENTATIONS,
           "relabel_offset": C.RELABEL_OFFSETS, "bc_target": C.BC_TARGETS, "alpha_schedule": C.ALPHA_SCHEDULES,
           "awr_normalize": C.AWR_NORMALIZE}
COMMON_FIELDS = ("seed", "device")  # TrainConfig fields that are common flags (aerohrl.cli_common)


# the numeric flags that must be > 0 (counts >= 1); every other number must be >= 0
POSITIVE = {"steps", "batch_size", "hidden", "critic_hidden", "lr_actor", "lr_critic", "relabel_mean_offset", "gamma", "tau",
            "num_critics", "policy_delay", "awr_temperature", "awr_max_weight", "cql_num_random", "log_every",
            "checkpoint_every", "keep_checkpoints", "eval_episodes", "eval_horizon"}


def flag_type(name: str, default: Any) -> Callable[[str], Any]:
    """The parse-time check of a TrainConfig field's flag (aerohrl.cli_types); ranges that
    depend on other fields stay in config.check."""
    kind = int if isinstance(default, (int, tuple)) else float
    if kind is int:
        return T.positive_int if name in POSITIVE else T.nonneg_int
    return T.positive_float if name in POSITIVE else T.nonneg_float


def parser() -> ArgumentParser:
    """The ``train`` argument parser (flags generated from :class:`TrainConfig`'s fields)."""
    # argparse rather than draccus or tyro: the flags are already generated from TrainConfig's
    # fields (below), so a library would remove little code here but would change the flag
    # spellings users have (draccus: --batch_size), bypass the one-line parse-time errors of
    # aerohrl.cli_types and errors.ArgumentParser, and draccus is only installed by the
    # [lerobot] extra (lerobot requires it), which `train` does not need. run.toml is written
    # by aerohrl.cli_common.to_toml (tomllib reads TOML; tomli_w is not a dependency) and
    # read by config.load_toml.
    ap = ArgumentParser(prog=PROG, description="Offline goal-conditioned training on an expert dataset (thesis §3.4.2, Alg. 2).")
    ap.add_argument("--preset", default=None, choices=tuple(C.PRESETS), help="hyper-parameter preset [cpu]")
    ap.add_argument("--config", type=Path, default=None, metavar="FILE",
                    help=f"a TOML train config (every run saves its own as RUN/{C.TOML_NAME}); flags override its values")
    ap.add_argument("--resume", type=Path, default=None, metavar="RUN", help="continue RUN from its last checkpoint")
    add_common(ap, out={"default": Path("runs"), "help": "folder of runs: the run goes to OUT/NAME [runs]"},
               quiet=True, old_quiet=("--no-progress",),
               threads={"help": "torch threads [torch's default: all cores]"},
               seed={"default": None, "help": "random seed (>= 0) [cpu: 0]"},
               device={"default": None, "help": "torch device: cpu | cuda | cuda:N [cpu: cpu]"})
    ap.add_argument("--name", default=None, help="run folder name, must be new [ALGO-PRESET-sSEED-YYYYMMDD-HHMMSS-XXXXXX]")
    ap.add_argument("--logger", default=None, metavar="NAME",
                    help="where scalars go besides metrics.jsonl: tensorboard (RUN/tb) | wandb (offline, RUN/wandb; needs "
                         "`pip install wandb`) | none [tensorboard; on --resume: the run's]")
    ap.add_argument("--progress-every", type=T.nonneg_float, default=60.0, metavar="SECONDS",
                    help="without a progress bar (no terminal, --quiet): a progress line every SECONDS (0: none) [60]")
    ap.add_argument("--progress-steps", type=T.nonneg_int, default=0, metavar="N",
                    help="... and every N steps (0: only by time) [0]")
    for f in fields(C.TrainConfig):
        if f.name in C.INTERNAL or f.name in COMMON_FIELDS:
            continue
        flag = "--" + f.name.replace("_", "-")
        default = f.default
        h = HELP.get(f.name, f.name.replace("_", " "))
        if isinstance(default, bool):
            ap.add_argument(flag, action=argparse.BooleanOptionalAction, default=None, help=f"{h} [cpu: {default}]")
        elif isinstance(default, tuple):
            ap.add_argument(flag, type=flag_type(f.name, default), nargs="+", default=None, metavar="N",
                            help=f"{h} [cpu: {' '.join(map(str, default))}]")
        elif isinstance(default, str):
            ap.add_argument(flag, default=None, choices=CHOICES.get(f.name), help=f"{h} [cpu: {default}]" if default else h)
        else:
            per_algo = "".join(f"; {a} {v[f.name]}" for a, v in C.ALGO_PRESETS["cpu"].items() if f.name in v)
            ap.add_argument(flag, type=flag_type(f.name, default), default=None, help=f"{h} [cpu: {default}{per_algo}]")
    return ap


def _overrides(a) -> dict:
    return {f.name: getattr(a, f.name) for f in fields(C.TrainConfig) if f.name not in C.INTERNAL and getattr(a, f.name) is not None}


def config_from_args(a: argparse.Namespace) -> C.TrainConfig:
    """The config of a new run: the preset (``--preset``, else the ``--config`` file's,
    else cpu), the ``--config`` file's values over it, the flags given over those.
    UserError (one line) on an unknown key, a bad value or a missing ``--dataset``."""
    values = C.load_toml(a.config) if a.config is not None else {}
    preset = a.preset or values.pop("preset", None) or "cpu"
    values.pop("preset", None)
    values.update(_overrides(a))  # explicit flags win
    cfg = C.make_config(preset, **values)  # unknown algorithm/preset/values first
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
            raise UserError(f"--resume cannot change {', '.join('--' + k.replace('_', '-') for k in fixed)} (they define the run)")
        tr = resume_run(a.resume, progress=bar, overrides=ov, logger=a.logger, **kw)
        for aside, why in tr.set_aside:
            warn(f"{why}; set aside as {aside.name}")
        fallback = " (the newest intact checkpoint)" if tr.set_aside else ""
        print(f"resuming {a.resume} at step {tr.step}" + (f" from {tr.resumed_from}{fallback}" if tr.resumed_from else ""),
              file=sys.stderr)
    else:
        cfg = config_from_args(a)
        resolve_device(cfg.device)  # before anything is created
        run_dir = new_run_dir(cfg, a.out, a.name)
        tr = start_run(cfg, run_dir, progress=bar, logger=a.logger or "tensorboard", **kw)
        print(f"run {run_dir}: {cfg.algo}, preset {cfg.preset}, dataset {tr.dataset['version']}", file=sys.stderr)
    print(f"precision: {tr.precision}", file=sys.stderr)
    step = tr.train()
    print(f"done: {tr.run_dir} at step {step}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """The ``train`` command; returns the exit code."""
    args = parser().parse_args(argv)
    return run_cli(PROG, lambda: run(args))  # every UserError (bad --config, values) is one line, exit 2


if __name__ == "__main__":
    sys.exit(main())
