"""Training configuration: one dataclass, two presets, one CLI flag per field.

``thesis`` is the setting of thesis §3.5 (MLP 512-2048-2048-512 for actor and critics,
batch 1048, 2M steps, Adam 3e-4, float32, TD3-BC alpha 2.5; a GPU job). ``cpu`` (the
dataclass defaults) trains GCSL on one CPU core: actor 512-512-512, critics 128-128,
batch 512, 30k steps under bf16 autocast where the CPU multiplies bf16 natively and float32
elsewhere (``amp = "auto"``, aerohrl.hardware), actor learning rate 1e-3 with cosine
decay, an EMA of the policy weights (0.999), critic targets bounded below by the data's discounted return,
relabelling probability 0.05 (GCSL 0.01, ``ALGO_PRESETS``) with a geometric offset of
mean 30 steps, TD3-BC and TD3-AWBC alpha 0.001 annealed linearly to 0 with an actor
update every critic update (chosen by the TD3-BC sweep, docs/results/ "algorithms
sweeps"), and a checkpoint every 1,000 steps. What these presets reach: docs/results/.
Every field maps one to one to a ``train`` flag (``batch_size`` -> ``--batch-size``);
a flag given on the command line overrides the preset.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from aerohrl.errors import UserError

ALGORITHMS = ("gcsl", "td3bc", "td3awbc", "cql")
ALPHA_SCHEDULES = ("constant", "linear")
AWR_NORMALIZE = ("std", "none")
LR_SCHEDULES = ("constant", "cosine")
from aerohrl.hardware import AMP_MODES  # auto | none | bf16
AUGMENTATIONS = ("none", "mirror")  # = augment.AUGMENTATIONS
RELABEL_OFFSETS = ("uniform", "geometric")  # = relabel.FUTURE_STRATEGIES
BC_TARGETS = ("expert", "executed")


@dataclass
class TrainConfig:
    # what to train on
    algo: str = "gcsl"
    preset: str = "cpu"
    dataset: str = ""
    seed: int = 0
    device: str = "cpu"
    # optimisation
    steps: int = 30_000
    batch_size: int = 512
    hidden: tuple[int, ...] = (512, 512, 512)  # actor MLP (and critics unless critic_hidden is set)
    critic_hidden: tuple[int, ...] = (128, 128)  # () = same as hidden
    lr_actor: float = 1e-3
    lr_critic: float = 3e-4
    lr_schedule: str = "cosine"  # constant | cosine (to 5% of the base rate at the last step)
    # auto | none | bf16: mixed-precision training (torch.autocast); weights, EMA and act() stay
    # float32. auto: bf16 where the device multiplies bf16 natively (aerohrl.hardware), float32
    # elsewhere; a run records the precision it chose, so its resume trains the same way
    amp: str = "auto"
    ema_decay: float = 0.999  # > 0: act() with an exponential moving average of the policy weights (0 = the weights as trained)
    # goal-conditioned RL (thesis Alg. 2)
    relabel_prob: float = 0.05  # delta: probability that a goal becomes a later achieved goal
    relabel_offset: str = "geometric"  # how far ahead (k - j): uniform (over the rest) | geometric (relabel.sample_future_index)
    relabel_window: int = 0  # cap on k - j in steps (0 = up to the episode's last step)
    relabel_mean_offset: float = 30.0  # geometric: mean of k - j in steps
    # OGBench's value_p_randomgoal: the critics' goal is, with this probability, the achieved
    # goal of a uniformly random dataset frame (a goal the data does not reach: a negative);
    # the actor keeps its own goals. 0 = critics and actor share the batch (the thesis).
    critic_random_goal_prob: float = 0.0
    gamma: float = 0.99
    # What GCSL and every BC term imitate on a dataset flown with action noise (DART):
    # "expert" the clean command at the flown state (column action.expert), "executed"
    # the flown action. The critics always learn from the flown action (consistent
    # transitions). Without an action.expert column both are the dataset's action.
    bc_target: str = "expert"
    augment: str = "none"  # none | mirror: reflect each transition by one of the vehicle's 4 mirror symmetries (algorithms.augment)
    mc_lower_bound: bool = True  # critic targets max(TD target, discounted return of the data) (MCAC; networks.ClippedTD0Estimator)
    tau: float = 0.005  # soft target update: phi' <- (1 - tau) phi' + tau phi  (beta = 1 - tau in Alg. 2)
    num_critics: int = 5
    # TD3-BC / TD3-AWBC
    # TD3-BC's lambda numerator (thesis preset: 2.5, the TD3-BC paper's). The cpu preset's
    # alpha 0.001, linear schedule and policy delay 1 won the TD3-BC sweep (docs/results/
    # "algorithms sweeps")
    alpha: float = 0.001
    policy_noise: float = 0.2  # in normalised action units ([-1, 1])
    noise_clip: float = 0.5
    policy_delay: int = 1  # thesis preset: 2 (TD3's)
    # TD3-BC / TD3-AWBC: "linear" anneals alpha to 0 over the run (the Q-term fades, BC stays)
    alpha_schedule: str = "linear"
    # TD3-AWBC: weight exp(A / temperature). The cpu preset's 10 (on A / std(A), weights near 1)
    # won the temperature ablation (docs/results/ "algorithms sweeps"); lower temperatures
    # weight a few transitions heavily and lost
    awr_temperature: float = 10.0
    awr_max_weight: float = 100.0
    # TD3-AWBC: "std" divides the advantage by its batch standard deviation before the
    # temperature (with Q in [0, 1] the raw advantages are ~1e-3 and exp(A) ~ 1: the weighting
    # does nothing); "none" is the thesis's exp(A / temperature)
    awr_normalize: str = "std"
    # CQL
    cql_min_q_weight: float = 5.0
    cql_num_random: int = 4  # sampled actions per state in CQL's logsumexp (thesis preset: 10)
    # CQL's Lagrange variant (Kumar et al. 2020, "CQL(H) with Lagrange"): the penalty weight is
    # tuned so that the gap logsumexp Q - Q_data stays near this threshold (0: off, fixed weight)
    cql_lagrange_thresh: float = 0.0
    # bookkeeping (steps)
    log_every: int = 200
    checkpoint_every: int = 1_000  # steps / 30: the last 10 checkpoints are the final third (Table 3.1 protocol)
    keep_checkpoints: int = 10
    eval_every: int = 5_000  # 0 = no periodic closed-loop evaluation
    eval_episodes: int = 25
    eval_horizon: int = 500


PRESETS: dict[str, dict] = {
    "cpu": {},  # the dataclass defaults
    "thesis": {
        "hidden": (512, 2048, 2048, 512),
        "critic_hidden": (),
        "cql_num_random": 10,
        "batch_size": 1048,
        "lr_actor": 3e-4,
        "lr_schedule": "constant",
        "alpha": 2.5,
        "alpha_schedule": "constant",
        "policy_delay": 2,
        "awr_normalize": "none",  # the thesis's weights exp(A / T)
        "awr_temperature": 1.0,
        "amp": "none",
        "ema_decay": 0.0,
        "mc_lower_bound": False,
        "relabel_prob": 0.5,  # the thesis gives no value
        "relabel_offset": "uniform",  # Alg. 2: "a strictly later step"; HER/WGCSL's "future"
        "steps": 2_000_000,
        "checkpoint_every": 50_000,
        "eval_every": 5_000,  # thesis §3.5: Reach-Desired every 5000 steps, 25 episodes
        "eval_episodes": 25,
        "log_every": 1_000,
    },
}

# Per-algorithm values of a preset, applied over the preset and under the flags (OGBench and
# CORL keep one config per agent the same way). GCSL's relabelling probability: the GCSL
# sweep (docs/results/ "algorithms sweeps") found delta the bound on
# Reach-Desired, 0.01 the value that keeps Reach-Intermediate; the actor-critic algorithms
# keep 0.05, the value their sweeps and 3-seed results were measured at.
ALGO_PRESETS: dict[str, dict[str, dict]] = {
    "cpu": {"gcsl": {"relabel_prob": 0.01}},
}

# fields a user must not set from the command line (identity of the run)
INTERNAL = ("preset",)


def make_config(preset: str = "cpu", **overrides: Any) -> TrainConfig:
    """The preset with ``overrides`` (None values ignored) applied; UserError on bad values."""
    if preset not in PRESETS:
        raise UserError(f"unknown preset {preset!r} (choose from {', '.join(PRESETS)})")
    values = dict(PRESETS[preset])
    algo = overrides.get("algo") or values.get("algo") or TrainConfig.algo
    values.update(ALGO_PRESETS.get(preset, {}).get(algo, {}))
    values.update({k: v for k, v in overrides.items() if v is not None})
    names = {f.name for f in fields(TrainConfig)}
    unknown = set(values) - names
    if unknown:
        raise UserError(f"unknown config field(s): {', '.join(sorted(unknown))}")
    for k in ("hidden", "critic_hidden"):
        if k in values:
            values[k] = tuple(int(h) for h in values[k])
    cfg = TrainConfig(**{**values, "preset": preset})
    check(cfg)
    return cfg


def check(cfg: TrainConfig) -> None:
    """Raise a one-line UserError for a value out of range or fields that contradict each other."""
    import math

    if cfg.algo not in ALGORITHMS:
        raise UserError(f"unknown algorithm {cfg.algo!r} (choose from {', '.join(ALGORITHMS)})")
    if cfg.steps < 1 or cfg.batch_size < 1 or not cfg.hidden or min(cfg.hidden + cfg.critic_hidden) < 1:
        raise UserError("steps, batch size and hidden sizes must be positive")
    if not 0.0 <= cfg.relabel_prob <= 1.0:
        raise UserError(f"relabel probability must be in [0, 1], got {cfg.relabel_prob}")
    if not 0.0 <= cfg.critic_random_goal_prob < 1.0:
        raise UserError(f"critic random-goal probability must be in [0, 1), got {cfg.critic_random_goal_prob}")
    if not 0.0 < cfg.gamma <= 1.0 or not 0.0 < cfg.tau <= 1.0:
        raise UserError("need 0 < gamma <= 1 and 0 < tau <= 1")
    if cfg.relabel_offset not in RELABEL_OFFSETS:
        raise UserError(f"unknown relabel offset {cfg.relabel_offset!r} (choose from {', '.join(RELABEL_OFFSETS)})")
    if cfg.relabel_window < 0:
        raise UserError(f"relabel window must be >= 0 (0 = to the episode's end), got {cfg.relabel_window}")
    if not cfg.relabel_mean_offset >= 1.0:
        raise UserError(f"relabel mean offset must be >= 1 step, got {cfg.relabel_mean_offset}")
    if cfg.lr_schedule not in LR_SCHEDULES:
        raise UserError(f"unknown lr schedule {cfg.lr_schedule!r} (choose from {', '.join(LR_SCHEDULES)})")
    if cfg.bc_target not in BC_TARGETS:
        raise UserError(f"unknown bc target {cfg.bc_target!r} (choose from {', '.join(BC_TARGETS)})")
    if cfg.augment not in AUGMENTATIONS:
        raise UserError(f"unknown augmentation {cfg.augment!r} (choose from {', '.join(AUGMENTATIONS)})")
    if cfg.amp not in AMP_MODES:
        raise UserError(f"unknown amp mode {cfg.amp!r} (choose from {', '.join(AMP_MODES)})")
    if not 0.0 <= cfg.ema_decay < 1.0:
        raise UserError(f"ema decay must be in [0, 1), got {cfg.ema_decay}")
    if cfg.num_critics < 2:
        raise UserError("need at least 2 critics")
    for name in ("log_every", "checkpoint_every", "policy_delay", "keep_checkpoints", "eval_episodes", "eval_horizon",
                 "cql_num_random"):
        if getattr(cfg, name) < 1:
            raise UserError(f"{name.replace('_', '-')} must be >= 1")
    if cfg.seed < 0 or cfg.eval_every < 0:
        raise UserError(f"seed and eval-every must be >= 0, got {cfg.seed} and {cfg.eval_every}")
    for name in ("lr_actor", "lr_critic", "awr_temperature", "awr_max_weight"):
        if not (math.isfinite(getattr(cfg, name)) and getattr(cfg, name) > 0):
            raise UserError(f"{name.replace('_', '-')} must be a positive number, got {getattr(cfg, name)}")
    if cfg.alpha_schedule not in ALPHA_SCHEDULES:
        raise UserError(f"unknown alpha schedule {cfg.alpha_schedule!r} (choose from {', '.join(ALPHA_SCHEDULES)})")
    if cfg.awr_normalize not in AWR_NORMALIZE:
        raise UserError(f"unknown advantage normalisation {cfg.awr_normalize!r} (choose from {', '.join(AWR_NORMALIZE)})")
    for name in ("alpha", "policy_noise", "noise_clip", "cql_min_q_weight", "cql_lagrange_thresh"):
        if not (math.isfinite(getattr(cfg, name)) and getattr(cfg, name) >= 0):
            raise UserError(f"{name.replace('_', '-')} must be a number >= 0, got {getattr(cfg, name)}")


def to_dict(cfg: TrainConfig) -> dict:
    """The config as a JSON-ready dict (tuples as lists)."""
    d = dataclasses.asdict(cfg)
    d["hidden"] = list(cfg.hidden)
    d["critic_hidden"] = list(cfg.critic_hidden)
    return d


def from_dict(d: dict) -> TrainConfig:
    """A :class:`TrainConfig` from :func:`to_dict`'s output; unknown keys are dropped and
    the defaults of runs saved before a field existed are filled in."""
    names = {f.name for f in fields(TrainConfig)}
    d = {k: v for k, v in d.items() if k in names}
    if "relabel_prob" in d:  # a run saved before relabel_offset existed drew uniformly over the rest of the episode
        d.setdefault("relabel_offset", "uniform")
        d.setdefault("relabel_window", 0)
    if "steps" in d:  # a run saved before these options existed trained without them
        for k, v in (("ema_decay", 0.0), ("mc_lower_bound", False), ("amp", "none"), ("augment", "none"),
                     ("critic_random_goal_prob", 0.0), ("alpha_schedule", "constant"), ("awr_normalize", "none"),
                     ("cql_lagrange_thresh", 0.0)):
            d.setdefault(k, v)
    for k in ("hidden", "critic_hidden"):
        if k in d:
            d[k] = tuple(d[k])
    return TrainConfig(**d)


def lr_factor(cfg: TrainConfig, step: int) -> float:
    """Learning-rate multiplier at ``step`` (a pure function of the step: resumable)."""
    if cfg.lr_schedule == "cosine":
        import math

        frac = min(step / max(cfg.steps, 1), 1.0)
        return 0.05 + 0.95 * 0.5 * (1.0 + math.cos(math.pi * frac))
    return 1.0


def critic_sizes(cfg: TrainConfig) -> tuple[int, ...]:
    """The critics' hidden sizes: ``critic_hidden``, else the policy's ``hidden``."""
    return cfg.critic_hidden or cfg.hidden


def relabel_future(cfg: TrainConfig) -> dict:
    """Keyword arguments of ``relabel.sample_future_index`` for this config."""
    return {"strategy": cfg.relabel_offset, "window": cfg.relabel_window, "mean": cfg.relabel_mean_offset}


__all__ = ["TrainConfig", "PRESETS", "ALGO_PRESETS", "ALGORITHMS", "make_config", "check", "to_dict", "from_dict", "field"]


# ----------------------------------------------------------------------------- run.toml

TOML_NAME = "run.toml"  # beside config.json in every run folder; `train --config RUN/run.toml` trains it again


def to_toml(cfg: TrainConfig) -> str:
    """The config as a flat TOML file (every field, preset included), readable by :func:`load_toml`."""
    from aerohrl.cli_common import to_toml as flat_toml

    return flat_toml(to_dict(cfg), header="aerohrl train config (written by `train`); train it again with "
                                          "`train --config run.toml`, flags override its values")


def _coerce(name: str, default, value, where: str):
    """A TOML value as the field's type (ints for floats are fine); UserError naming the key otherwise."""
    def bad(kind):
        return UserError(f"{where}: {name} must be {kind}, got {value!r}")

    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise bad("true or false")
        return value
    if isinstance(default, tuple):
        if not isinstance(value, list) or not all(isinstance(x, int) and not isinstance(x, bool) for x in value):
            raise bad("a list of integers")
        return tuple(value)
    if isinstance(default, int):
        if not isinstance(value, int) or isinstance(value, bool):
            raise bad("an integer")
        return value
    if isinstance(default, float):
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise bad("a number")
        return float(value)
    if not isinstance(value, str):
        raise bad("a string")
    return value


def load_toml(path: str | Path) -> dict:
    """The values of a ``--config`` TOML file, by field name, typed as the fields (preset
    included when the file has it). UserError (one line) on a missing or malformed file,
    an unknown key or a value of the wrong type; ranges are checked by :func:`make_config`."""
    import tomllib
    from pathlib import Path

    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise UserError(f"no config file at {path}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise UserError(f"cannot read {path}: {getattr(e, 'strerror', None) or e}") from None
    except tomllib.TOMLDecodeError as e:
        raise UserError(f"{path} is not valid TOML: {e}") from None
    defaults = {f.name: f.default for f in fields(TrainConfig)}
    unknown = sorted(set(raw) - set(defaults))
    if unknown:
        import difflib

        near = sorted({m for k in unknown for m in difflib.get_close_matches(k, defaults, n=3)})
        hint = f"did you mean {', '.join(near)}?" if near else "the keys are train's flags with _ for - (train --help)"
        raise UserError(f"{path}: unknown key(s) {', '.join(unknown)} ({hint})")
    return {k: _coerce(k, defaults[k], v, str(path)) for k, v in raw.items()}
