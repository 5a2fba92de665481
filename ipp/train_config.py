"""The settings of ``aerohrl ipp train``: :class:`TrainConfig` with its policy and
environment sections, its presets (``ipp/presets/NAME.toml``, data read by
:func:`preset`) and :func:`aerohrl.config.from_nested`, which reads a config back from its nested
mapping (a run's ``config.json``, a preset file).

Each setting is declared once with :func:`aerohrl.config.param` (meaning, unit,
choices, bounds); :func:`aerohrl.config.validate` checks them and the ``ipp train``
flags are built from them (:func:`aerohrl.config.add_flags`). This module loads neither
torch nor scipy, so that ``--help`` stays fast.

The environment section nests sections of its own (sensor, world, semantic) whose
settings share names (``map_size`` is the environment's, the world's and the semantic
map's). :func:`aerohrl.config.from_mapping` reads configs whose settings have unique
names (flat keys); :func:`aerohrl.config.from_nested` reads the nested form, one table per section,
with the same unknown-key check and type rules.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from aerohrl import config as K
from aerohrl.config import param

from .env import TERMS, EnvConfig

PRESET_DIR = Path(__file__).parent / "presets"  # package data: one TOML file per preset
TEACHER_PLANNERS = ("detect", "dp", "prio_coverage", "coverage", "greedy")  # stateless trees
VAL_SEED = 500  # validation suite (training: TrainConfig.seed, test: bench.TEST_SEED = 1000)


@dataclass(frozen=True)
class PolicyConfig:
    """The learned planner's network (:class:`aerohrl.ipp.policy.ActorCritic`)."""

    hidden: int = param(128, "width of the trunk and the recurrent core", unit="units", ge=1)
    recurrent: bool = param(True, "GRU core (false: an MLP core, the thesis's 'no-LSTM')")
    mask_invalid: bool = param(True, "sample only valid primitives (see aerohrl.ipp.train)")
    features: bool = param(True, "read the per-primitive look-ahead features (false: map observations only)")


@dataclass(frozen=True)
class TrainConfig:
    """Synchronous PPO with an optional DAgger warm start (see :mod:`aerohrl.ipp.train`)."""

    n_envs: int = param(64, "environments stepped per iteration", ge=1)
    iterations: int = param(600, "PPO iterations (after the bc_iterations)", ge=0)
    lr: float = param(3e-4, "PPO learning rate (Adam)", gt=0, lt=1)
    gamma: float = param(0.98, "discount per primitive", gt=0, le=1)
    lam: float = param(0.8, "GAE lambda (thesis: 0.8)", ge=0, le=1)
    clip: float = param(0.2, "PPO ratio clip", gt=0)
    epochs: int = param(4, "PPO epochs per iteration", ge=1)
    minibatches: int = param(4, "minibatches per epoch (over environments)", ge=1)
    value_coef: float = param(0.5, "weight of the critic loss", ge=0)
    entropy_coef: float = param(0.01, "PPO entropy bonus weight", ge=0)
    valid_coef: float = param(0.1, "weight of the valid-primitive loss (Eq. 2.7)", ge=0)
    valid_beta: tuple[float, float] = param((1.0, 0.2), "Eq. 2.7 beta1 (invalid), beta2 (valid)", ge=0)
    reward_scale: float = param(0.05, "rewards are multiplied by this (1/20: one target = 1)", gt=0)
    grad_clip: float = param(5.0, "gradient norm clip", gt=0)
    adv_weights: tuple[float, ...] = param(
        (1.0, 1.0, 1.0, 1.0, 1.0), "per-term advantage weights: " + ",".join(TERMS) + " (thesis: all 1)"
    )
    seed: int = param(7, "random seed (training worlds: this suite seed)", ge=0)
    threads: int = param(1, "torch threads", ge=1)
    log_every: int = param(10, "checkpoint (and model.pt) every N iterations", ge=1)
    init: str | None = param(None, "warm start from a trained run or model.pt (fine-tuning)")
    belief_input: str | None = param(
        None,
        "observe the learned belief of this `ipp belief train` run (or belief.pt) in place of the hand-written "
        "posterior plane; saved into the policy (target search only)",
    )
    # behaviour-cloning warm start (DAgger), see aerohrl.ipp.train
    bc_iterations: int = param(0, "DAgger warm-start iterations before PPO (0: none)", ge=0)
    teacher: str = param("detect", "DAgger teacher planner", choices=TEACHER_PLANNERS)
    teacher_depth: int | None = param(None, "teacher tree depth in primitives", ge=1, le=4)
    teacher_belief: str | None = param(
        None,
        "the DAgger teacher plans over the learned belief of this `ipp belief train` run (or belief.pt) in place of "
        "the hand-written posterior (target search only)",
    )
    bc_beta0: float = param(1.0, "DAgger: probability that the teacher acts, first iteration", ge=0, le=1)
    bc_beta_decay: float = param(0.7, "DAgger: that probability's factor per iteration", ge=0, le=1)
    bc_epochs: int = param(2, "DAgger epochs over the buffer per iteration", ge=1)
    bc_lr: float = param(1e-3, "DAgger learning rate (Adam)", gt=0, lt=1)
    bc_buffer: int = param(20, "DAgger buffer: the last N iterations' batches", ge=1)
    bc_anchor: float = param(0.0, "PPO: weight of a cross entropy to the teacher (0: off)", ge=0)
    # validation on a fixed suite (never the test seed)
    eval_every: int = param(0, "validate the greedy policy every N iterations (0: never)", ge=0)
    eval_envs: int = param(64, "validation worlds", ge=1)
    eval_seed: int = param(VAL_SEED, "validation suite seed", ge=0)
    policy: PolicyConfig = K.section(PolicyConfig, "the network")
    env: EnvConfig = param(EnvConfig(start="random"), "the training environment (random starts)")

    @property
    def total_iterations(self) -> int:
        """Behaviour-cloning plus PPO iterations."""
        return self.bc_iterations + self.iterations

    def validate(self) -> None:
        """ConfigError (a UserError, one line) for a setting out of its declared range, or
        for the cross-field rules: at least one iteration, one advantage weight per reward
        term, no training or validation seed equal to the test suite's."""
        from .world import TEST_SEED

        K.validate(self)
        if self.total_iterations < 1:
            raise K.ConfigError("iterations + bc_iterations must be >= 1")
        if len(self.adv_weights) != len(TERMS):
            raise K.ConfigError(f"adv_weights needs {len(TERMS)} numbers ({', '.join(TERMS)}), got {list(self.adv_weights)}")
        if self.teacher_belief is not None and self.bc_iterations == 0 and self.bc_anchor == 0:
            raise K.ConfigError("teacher_belief is the DAgger teacher's belief: it needs bc_iterations > 0 or bc_anchor > 0")
        if TEST_SEED in (self.seed, self.eval_seed):
            raise K.ConfigError(f"seed {TEST_SEED} is the test suite's: train and validate on other seeds")


# ----------------------------------------------------------------------------- presets


def preset_names() -> tuple[str, ...]:
    """The presets shipped in ``ipp/presets`` (sorted)."""
    return K.preset_names(PRESET_DIR)


def preset(name: str, **overrides: Any) -> TrainConfig:
    """The training preset ``name`` (``ipp/presets/NAME.toml`` over the defaults) with the
    non-None ``overrides`` applied: settings of TrainConfig, whole ``policy``/``env``
    sections, or the policy's ``recurrent`` and ``features``."""
    where = f"preset {name}"
    cfg = K.from_nested(TrainConfig, K.load_preset(PRESET_DIR, name), where=where, check=False)
    over = {k: v for k, v in overrides.items() if v is not None}
    pol = {k: over.pop(k) for k in ("recurrent", "features") if k in over}
    if pol:
        cfg = dataclasses.replace(cfg, policy=dataclasses.replace(cfg.policy, **pol))
    K.unknown_keys(list(over), [f.name for f in dataclasses.fields(TrainConfig)], where)
    return dataclasses.replace(cfg, **over)


__all__ = ["PolicyConfig", "TrainConfig", "TEACHER_PLANNERS", "VAL_SEED", "PRESET_DIR", "preset", "preset_names"]
