"""Training configuration: :class:`TrainConfig` (the shared settings) with one section per
algorithm, presets as TOML files, one flag per setting.

Every setting is declared once with :func:`aerohrl.config.param` (its meaning, unit and
allowed values); validation, the ``train`` flags and their help, the TOML of
``train --config`` and run.toml all come from those declarations (:mod:`aerohrl.config`).

- :class:`TrainConfig`: data, optimisation, relabelling, critics and bookkeeping, shared
  by every algorithm;
- :class:`TD3BCConfig` (``cfg.td3bc``: TD3-BC, and TD3-AWBC's actor-critic part),
  :class:`TD3AWBCConfig` (``cfg.td3awbc``), :class:`CQLConfig` (``cfg.cql``),
  :class:`GCIQLConfig`, :class:`CRLConfig`, :class:`QRLConfig`, :class:`HIQLConfig`
  (``cfg.gciql`` ... ``cfg.hiql``, OGBench's reference goal-conditioned agents): each
  algorithm's own settings, re-exported by its module (``aerohrl.algorithms.td3bc``, ...).
  They are declared here rather than in the algorithm modules because those import torch
  and ``train --help`` must not.

Setting names are unique across the sections, so the flat form (flags, run.toml,
config.json's ``config`` record) names every setting by its own name (``alpha``, not
``td3bc.alpha``).

Presets are TOML files in ``algorithms/presets/`` (shipped with the package): top-level
keys over the dataclass defaults, and ``[algo.NAME]`` tables applied when the run's
algorithm is NAME. ``cpu`` is the dataclass defaults (one CPU core, GCSL in minutes);
``thesis`` the setting of thesis §3.5 (a GPU job). What these presets reach:
docs/results/.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from aerohrl.config import (
    ConfigError,
    from_mapping,
    load_preset,
    param,
    preset_names,
    section,
    to_flat_dict,
    unknown_keys,
    validate,
)
from aerohrl.config import to_toml as _flat_toml
from aerohrl.hardware import AMP_MODES  # auto | none | bf16

# the thesis's four (a 5-critic torchrl ensemble each) and OGBench's reference goal-conditioned agents
ENSEMBLE_ALGORITHMS = ("gcsl", "td3bc", "td3awbc", "cql")
GOAL_AGENTS = ("gciql", "crl", "qrl", "hiql")
ALGORITHMS = ENSEMBLE_ALGORITHMS + GOAL_AGENTS
GCIQL_ACTOR_LOSSES = ("ddpgbc", "awr")
CRL_CONTRASTIVE = ("binary", "symmetric")
QUASIMETRICS = ("iqe", "mrn")
ALPHA_SCHEDULES = ("constant", "linear")
AWR_NORMALIZE = ("std", "none")
LR_SCHEDULES = ("constant", "cosine")
AUGMENTATIONS = ("none", "mirror")  # = augment.AUGMENTATIONS
RELABEL_OFFSETS = ("uniform", "geometric")  # = relabel.FUTURE_STRATEGIES
BC_TARGETS = ("expert", "executed")
EVAL_TASKS = ("reach-desired", "reach-novel")  # the periodic hook's free-space tasks (closed_loop.py)

PRESET_DIR = Path(__file__).parent / "presets"  # cpu.toml, thesis.toml: presets are data


@dataclass
class TD3BCConfig:
    """TD3-BC's settings (TD3-AWBC uses them too): the actor's Q-term and TD3's target smoothing."""

    # The cpu preset's alpha 0.001 with a linear schedule and policy delay 1 won the TD3-BC
    # sweep (docs/results/ "algorithms sweeps"); the thesis preset keeps the paper's 2.5
    # constant with TD3's delay 2.
    alpha: float = param(0.001, "TD3-BC alpha: weight of the Q-term, lambda = alpha / mean|Q|", ge=0)
    policy_noise: float = param(0.2, "TD3 target policy smoothing noise std", unit="normalised action units, [-1, 1]", ge=0)
    noise_clip: float = param(0.5, "TD3 target policy noise clip", unit="normalised action units", ge=0)
    policy_delay: int = param(1, "TD3: actor/target update every N critic updates", ge=1)
    # linear: the Q-term shapes the start of the run and fades; the BC term stays
    alpha_schedule: str = param(
        "linear", "TD3-BC/AWBC alpha over the run: constant | linear (to 0 at the last step)", choices=ALPHA_SCHEDULES
    )


@dataclass
class TD3AWBCConfig:
    """TD3-AWBC's advantage weighting of the BC term: w = min(exp(A / temperature), max_weight)."""

    # On A / std(A) (awr_normalize "std") a temperature of 10 keeps the weights near 1: it won
    # the temperature ablation (docs/results/ "algorithms sweeps"); lower temperatures weight
    # a few transitions heavily.
    awr_temperature: float = param(10.0, "TD3-AWBC: weights exp(A / temperature)", gt=0)
    awr_max_weight: float = param(100.0, "TD3-AWBC: weights clipped at this", gt=0)
    # With Q in [0, 1] the raw advantages are tiny and exp(A) ~ 1 (the weighting does
    # nothing) unless A is divided by its batch standard deviation first
    awr_normalize: str = param(
        "std", "TD3-AWBC: std (advantage / its batch std, then the temperature) | none (the thesis)", choices=AWR_NORMALIZE
    )


@dataclass
class CQLConfig:
    """CQL's conservative penalty (Kumar et al. 2020)."""

    cql_min_q_weight: float = param(5.0, "CQL: weight of the conservative penalty (the Lagrange variant's initial scale)", ge=0)
    cql_num_random: int = param(4, "CQL: random actions per state in the logsumexp", ge=1)
    # "CQL(H) with Lagrange": the penalty weight is tuned so that the gap stays near this
    cql_lagrange_thresh: float = param(0.0, "CQL: Lagrange variant, target gap logsumexp Q - Q_data (0: off)", ge=0)


# OGBench's goal sampling (GCDataset): the share of value (critic) and actor goals that are
# the transition's own achieved goal (curgoal), a later state of its trajectory (trajgoal,
# geometric with mean 1 / (1 - gamma) when geom_sample, else uniform over the rest of the
# episode) or a random dataset state (randomgoal); the shares sum to at most 1, the rest
# keeps the transition's own (desired or relabelled) goal. Each agent's defaults are
# OGBench's published ones for that agent (relabel.GoalMix has the index convention).


@dataclass
class GCIQLConfig:
    """GCIQL (OGBench): expectile value V(s, g), twin Q(s, a, g) with targets, actor by DDPG+BC or AWR."""

    gciql_expectile: float = param(0.9, "GCIQL: expectile of the value regression (OGBench 0.9)", gt=0, lt=1)
    gciql_actor_loss: str = param("ddpgbc", "GCIQL actor: ddpgbc (-Q/mean|Q| + alpha BC) | awr", choices=GCIQL_ACTOR_LOSSES)
    gciql_alpha: float = param(0.3, "GCIQL: ddpgbc BC weight | awr inverse temperature exp(alpha A) (OGBench 0.3)", ge=0)
    gciql_value_p_curgoal: float = param(0.2, "GCIQL value goals: share of the transition's own achieved goal", ge=0, le=1)
    gciql_value_p_trajgoal: float = param(0.5, "GCIQL value goals: share of later states of the trajectory", ge=0, le=1)
    gciql_value_p_randomgoal: float = param(0.3, "GCIQL value goals: share of random dataset states", ge=0, le=1)
    gciql_value_geom_sample: bool = param(True, "GCIQL value goals: trajectory offset geometric (mean 1/(1-gamma)), else uniform")
    gciql_actor_p_curgoal: float = param(0.0, "GCIQL actor goals: share of the transition's own achieved goal", ge=0, le=1)
    gciql_actor_p_trajgoal: float = param(1.0, "GCIQL actor goals: share of later states of the trajectory", ge=0, le=1)
    gciql_actor_p_randomgoal: float = param(0.0, "GCIQL actor goals: share of random dataset states", ge=0, le=1)
    gciql_actor_geom_sample: bool = param(False, "GCIQL actor goals: trajectory offset geometric, else uniform")


@dataclass
class CRLConfig:
    """CRL (Eysenbach et al. 2022, OGBench's version): contrastive critic phi(s, a) . psi(g), actor by DDPG+BC."""

    crl_alpha: float = param(0.1, "CRL: BC weight of the DDPG+BC actor (OGBench 0.1)", ge=0)
    # OGBench: 512 with 4 x 512 networks; the cpu preset's critics are 2 x 128
    crl_latent_dim: int = param(64, "CRL: width of the phi(s, a) and psi(g) representations (OGBench 512)", ge=1)
    crl_contrastive: str = param(
        "binary",
        "CRL critic loss: binary (sigmoid cross-entropy, OGBench) | symmetric (InfoNCE both ways)",
        choices=CRL_CONTRASTIVE,
    )
    crl_value_p_curgoal: float = param(0.0, "CRL critic goals: share of the transition's own achieved goal", ge=0, le=1)
    crl_value_p_trajgoal: float = param(
        1.0, "CRL critic goals: share of later states of the trajectory (the positives)", ge=0, le=1
    )
    crl_value_p_randomgoal: float = param(0.0, "CRL critic goals: share of random dataset states", ge=0, le=1)
    crl_value_geom_sample: bool = param(True, "CRL critic goals: trajectory offset geometric (mean 1/(1-gamma)), else uniform")
    crl_actor_p_curgoal: float = param(0.0, "CRL actor goals: share of the transition's own achieved goal", ge=0, le=1)
    crl_actor_p_trajgoal: float = param(1.0, "CRL actor goals: share of later states of the trajectory", ge=0, le=1)
    crl_actor_p_randomgoal: float = param(0.0, "CRL actor goals: share of random dataset states", ge=0, le=1)
    crl_actor_geom_sample: bool = param(False, "CRL actor goals: trajectory offset geometric, else uniform")


@dataclass
class QRLConfig:
    """QRL (Wang et al. 2023, OGBench's version): quasimetric distance d(s, g), latent dynamics, DDPG+BC actor."""

    qrl_alpha: float = param(0.003, "QRL: BC weight of the DDPG+BC actor (OGBench 0.003)", ge=0)
    qrl_quasimetric: str = param("iqe", "QRL distance head: iqe (interval quasimetric embedding) | mrn", choices=QUASIMETRICS)
    # OGBench: 512 with 4 x 512 networks; the cpu preset's critics are 2 x 128
    qrl_latent_dim: int = param(64, "QRL: latent width (IQE: components x their size; OGBench 512)", ge=2)
    qrl_components: int = param(8, "QRL IQE: number of components (divides the latent width; OGBench 8)", ge=1)
    qrl_eps: float = param(0.05, "QRL: tolerance of the transition constraint E[relu(d(s, s') - 1)^2] <= eps", gt=0)
    qrl_value_p_curgoal: float = param(0.0, "QRL distance goals: share of the transition's own achieved goal", ge=0, le=1)
    qrl_value_p_trajgoal: float = param(0.0, "QRL distance goals: share of later states of the trajectory", ge=0, le=1)
    qrl_value_p_randomgoal: float = param(1.0, "QRL distance goals: share of random dataset states (pushed apart)", ge=0, le=1)
    qrl_value_geom_sample: bool = param(True, "QRL distance goals: trajectory offset geometric, else uniform")
    qrl_actor_p_curgoal: float = param(0.0, "QRL actor goals: share of the transition's own achieved goal", ge=0, le=1)
    qrl_actor_p_trajgoal: float = param(1.0, "QRL actor goals: share of later states of the trajectory", ge=0, le=1)
    qrl_actor_p_randomgoal: float = param(0.0, "QRL actor goals: share of random dataset states", ge=0, le=1)
    qrl_actor_geom_sample: bool = param(False, "QRL actor goals: trajectory offset geometric, else uniform")


@dataclass
class HIQLConfig:
    """HIQL (Park et al. 2023, OGBench's version): value V(s, phi([s, g])), high-level subgoal policy, low-level policy."""

    hiql_expectile: float = param(0.7, "HIQL: expectile of the value regression (OGBench 0.7)", gt=0, lt=1)
    hiql_low_alpha: float = param(3.0, "HIQL: low-level AWR inverse temperature exp(alpha A) (OGBench 3)", ge=0)
    hiql_high_alpha: float = param(3.0, "HIQL: high-level AWR inverse temperature (OGBench 3)", ge=0)
    # OGBench's 25 steps are at 10-50 Hz control; at 100 Hz 25 steps are 0.25 s (see hiql.py)
    hiql_subgoal_steps: int = param(25, "HIQL: subgoal horizon k (the state k steps ahead)", unit="steps", ge=1)
    hiql_rep_dim: int = param(10, "HIQL: width of the goal representation phi([s, g]) (OGBench 10)", ge=1)
    hiql_low_actor_rep_grad: bool = param(False, "HIQL: the low-level actor's loss also trains the goal representation")
    hiql_subgoal_space: str = param(
        "rep",
        "HIQL: what the high level proposes and the low level reads: rep (phi(s, w), OGBench) | goal (the subgoal's "
        "own goal columns of the input, the HIQL paper's variant without representation)",
        choices=("rep", "goal"),
    )
    hiql_subgoal_end: str = param(
        "achieved",
        "HIQL: the subgoal where the state k steps ahead is past the episode's end: achieved (its last state, "
        "OGBench) | desired (the episode's desired goal, which the expert flew to)",
        choices=("achieved", "desired"),
    )
    hiql_low_subgoal_offset: str = param(
        "fixed",
        "HIQL: the low level's training subgoal: fixed (the state k steps ahead, OGBench) | uniform (a uniform "
        "1..k steps ahead, so it also learns to arrive at subgoals closer than k)",
        choices=("fixed", "uniform"),
    )
    hiql_goal_switch: bool = param(
        False,
        "HIQL: act with the goal itself as the low level's subgoal once the value puts it within hiql_subgoal_steps "
        "(OGBench always uses the high level's)",
    )
    hiql_value_p_curgoal: float = param(0.2, "HIQL value goals: share of the transition's own achieved goal", ge=0, le=1)
    hiql_value_p_trajgoal: float = param(0.5, "HIQL value goals: share of later states of the trajectory", ge=0, le=1)
    hiql_value_p_randomgoal: float = param(0.3, "HIQL value goals: share of random dataset states", ge=0, le=1)
    hiql_value_geom_sample: bool = param(True, "HIQL value goals: trajectory offset geometric (mean 1/(1-gamma)), else uniform")
    hiql_actor_p_curgoal: float = param(0.0, "HIQL high-level goals: share of the transition's own achieved goal", ge=0, le=1)
    hiql_actor_p_trajgoal: float = param(1.0, "HIQL high-level goals: share of later states of the trajectory", ge=0, le=1)
    hiql_actor_p_randomgoal: float = param(0.0, "HIQL high-level goals: share of random dataset states", ge=0, le=1)
    hiql_actor_geom_sample: bool = param(False, "HIQL high-level goals: trajectory offset geometric, else uniform")


@dataclass
class TrainConfig:
    """The settings of a training run; the dataclass defaults are the cpu preset's."""

    # what to train on
    algo: str = param("gcsl", "algorithm", choices=ALGORITHMS)
    preset: str = param("cpu", "the preset the run started from", flag=False)
    dataset: str = param("", "dataset folder (datasets/<name>/<version>); required unless --resume or a --config file names it")
    seed: int = param(0, "random seed", ge=0)
    device: str = param("cpu", "torch device: cpu | cuda | cuda:N")
    # optimisation
    steps: int = param(30_000, "gradient steps", ge=1)
    batch_size: int = param(512, "transitions per batch", ge=1)
    hidden: tuple[int, ...] = param(
        (512, 512, 512),
        "hidden layer sizes of the actor (and of the critics unless --critic-hidden)",
        unit="units per layer",
        ge=1,
    )
    critic_hidden: tuple[int, ...] = param(
        (128, 128), "hidden layer sizes of the critics (none given: as --hidden)", unit="units per layer", ge=1
    )
    lr_actor: float = param(1e-3, "actor learning rate (Adam)", gt=0)
    lr_critic: float = param(3e-4, "critic learning rate (Adam)", gt=0)
    lr_schedule: str = param(
        "cosine", "learning rate over the run: constant | cosine (to 5% of the base rate at the last step)", choices=LR_SCHEDULES
    )
    # Weights, EMA and act() stay float32 under any mode; a run records the precision "auto"
    # chose, so that its resume trains the same way
    amp: str = param(
        "auto",
        "mixed precision: auto (bf16 where the device runs it natively, else float32) | none (float32) | bf16 (autocast)",
        choices=AMP_MODES,
    )
    ema_decay: float = param(0.999, "act with an exponential moving average of the policy weights (0: off)", ge=0, lt=1)
    # In a maze the choice of corridor is a function of position with jumps at the walls;
    # Fourier features of the positions let every network fit it (networks.position_features)
    pos_octaves: int = param(
        0,
        "worlds with obstacles: sin/cos features of the state's and the goal's position at this many octaves (0: none)",
        ge=0,
        le=12,
    )
    # A vehicle off its nominal model (mass, thrust, wind) needs a correction that the state
    # alone does not show; the expert's disturbance observer estimates it (datagen/expert.py)
    observe_disturbance: bool = param(
        False,
        "the networks observe the expert's disturbance estimate d_hat (a dataset built with "
        "--disturbance-observer); evaluation runs the same observer beside the policy",
    )
    # goal-conditioned RL (thesis Alg. 2)
    relabel_prob: float = param(0.05, "delta: probability of relabelling a goal with a later achieved goal", ge=0, le=1)
    relabel_offset: str = param(
        "geometric",
        "how far ahead a relabelled goal lies: uniform (over the rest of the episode) | geometric",
        choices=RELABEL_OFFSETS,
    )
    relabel_window: int = param(0, "cap on the relabelling offset (0: to the episode's end)", unit="steps", ge=0)
    relabel_mean_offset: float = param(30.0, "geometric relabelling: mean offset", unit="steps", ge=1)
    # OGBench's value_p_randomgoal: a goal the data does not reach is a negative for the
    # critics; the actor keeps its own goals. 0: critics and actor share the batch (the thesis)
    critic_random_goal_prob: float = param(
        0.0, "critics only: probability that a goal is a random frame's achieved goal (OGBench value_p_randomgoal)", ge=0, lt=1
    )
    gamma: float = param(0.99, "discount factor per step", gt=0, le=1)
    # On a dataset flown with action noise (DART) the critics learn from the flown action
    # (consistent transitions); without an action.expert column both targets are the action
    bc_target: str = param(
        "expert",
        "what GCSL and the BC terms imitate on a noisy (DART) dataset: expert (the clean "
        "command, column action.expert) | executed (the flown action)",
        choices=BC_TARGETS,
    )
    augment: str = param(
        "none",
        "none | mirror: train on the 4 mirror images of every transition (exact symmetries of the vehicle)",
        choices=AUGMENTATIONS,
    )
    mc_lower_bound: bool = param(True, "critic targets max(clipped TD target, discounted return observed in the data)")
    tau: float = param(0.005, "soft target update rate: phi' <- (1 - tau) phi' + tau phi", gt=0, le=1)
    num_critics: int = param(5, "size of the goal-conditioned critic ensemble", ge=2)
    # GCSL's policy learns from the data alone; its critics serve the planner (Eq. 3.6/3.7)
    # and cost about as much per step as the policy, so a run that only needs the skill
    # may leave them out
    train_critics: bool = param(
        True, "GCSL: train the planner's critic ensemble beside the policy (off: the policy alone; the run cannot plan)"
    )
    # each algorithm's own settings
    td3bc: TD3BCConfig = section(TD3BCConfig, "TD3-BC and TD3-AWBC")
    td3awbc: TD3AWBCConfig = section(TD3AWBCConfig, "TD3-AWBC")
    cql: CQLConfig = section(CQLConfig, "CQL")
    gciql: GCIQLConfig = section(GCIQLConfig, "GCIQL")
    crl: CRLConfig = section(CRLConfig, "CRL")
    qrl: QRLConfig = section(QRLConfig, "QRL")
    hiql: HIQLConfig = section(HIQLConfig, "HIQL")
    # bookkeeping
    log_every: int = param(200, "metric line every N steps", ge=1)
    # a checkpoint every steps / 30: the last 10 checkpoints are the final third (Table 3.1 protocol)
    checkpoint_every: int = param(1_000, "checkpoint every N steps", ge=1)
    keep_checkpoints: int = param(10, "checkpoints kept (newest)", ge=1)
    eval_every: int = param(5_000, "closed-loop evaluation every N steps (0: none)", ge=0)
    # time to a working skill: the evaluations before a policy can succeed cost the most (every
    # episode flies the whole horizon)
    eval_start: int = param(
        0,
        "periodic evaluations from this step on (0: from the first eval_every); the last step is always evaluated",
        unit="steps",
        ge=0,
    )
    eval_episodes: int = param(25, "episodes per evaluation", ge=1)
    eval_horizon: int = param(500, "simulator steps per evaluation episode (100 Hz: 500 = 5 s)", ge=1)
    eval_task: str = param(
        "reach-desired",
        "closed-loop evaluation task: reach-desired (the dataset's goals) | reach-novel (new goals from its ranges); "
        "a maze dataset flies its maze tasks",
        choices=EVAL_TASKS,
    )
    # time to a working skill: the run ends (with a checkpoint) at the first evaluation that reaches it
    stop_success: float = param(
        0.0, "stop training once a closed-loop evaluation's success reaches this (0: train every step)", ge=0, le=1
    )


# settings a user must not set from the command line (the identity of the run)
INTERNAL = ("preset",)


def presets() -> tuple[str, ...]:
    """The preset names (the TOML files of ``algorithms/presets/``)."""
    return preset_names(PRESET_DIR)


def _preset_tables(preset: str) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """The preset's values and its per-algorithm tables (``[algo.NAME]``)."""
    values = load_preset(PRESET_DIR, preset)
    per_algo = values.pop("algo") if isinstance(values.get("algo"), Mapping) else {}
    unknown_keys(list(per_algo), ALGORITHMS, f"preset {preset} [algo]")
    return values, dict(per_algo)


def preset_base(preset: str = "cpu") -> TrainConfig:
    """The preset without its per-algorithm tables (the defaults ``train --help`` shows)."""
    values, _ = _preset_tables(preset)
    return dataclasses.replace(from_mapping(TrainConfig, values, where=f"preset {preset}"), preset=preset)


def per_algo_values(preset: str = "cpu") -> dict[str, dict[str, Any]]:
    """The preset's per-algorithm values: ``{algo: {setting: value}}``."""
    return _preset_tables(preset)[1]


def make_config(preset: str = "cpu", **overrides: Any) -> TrainConfig:
    """The preset, its values for the algorithm, then ``overrides`` (flat setting names;
    None values ignored); :class:`~aerohrl.config.ConfigError` (a UserError, one line) on
    an unknown preset or setting or a value not allowed."""
    values, per_algo = _preset_tables(preset)
    overrides = {k: v for k, v in overrides.items() if v is not None and k != "preset"}
    where = f"preset {preset}"
    cfg = from_mapping(TrainConfig, values, where=where, check=False)
    algo = overrides.get("algo", cfg.algo)
    cfg = from_mapping(TrainConfig, per_algo.get(algo, {}), where=f"{where} [algo.{algo}]", base=cfg, check=False)
    cfg = from_mapping(
        TrainConfig,
        overrides,
        where="config",
        base=cfg,
        check=False,
        hint="the settings are train's flags with _ for - (train --help)",
    )
    cfg = dataclasses.replace(cfg, preset=preset)
    check(cfg)
    return cfg


def update(cfg: TrainConfig, **values: Any) -> TrainConfig:
    """``cfg`` with ``values`` (flat setting names, sections included) replaced, unchecked."""
    return from_mapping(TrainConfig, values, where="config", base=cfg, check=False)


def check(cfg: TrainConfig) -> None:
    """Every setting against its declaration (:func:`aerohrl.config.validate`), then the rules
    that tie settings together; a one-line :class:`~aerohrl.config.ConfigError` otherwise."""
    validate(cfg)
    if not cfg.hidden:
        raise ConfigError("hidden needs at least one layer size")
    if cfg.algo in GOAL_AGENTS and cfg.gamma >= 1:
        raise ConfigError(f"{cfg.algo} needs gamma < 1 (its values map to discounted success gamma^steps)")
    for name in GOAL_AGENTS:
        sec = getattr(cfg, name)
        for use in ("value", "actor"):
            keys = [f"{name}_{use}_p_{src}" for src in ("curgoal", "trajgoal", "randomgoal")]
            if sum(getattr(sec, k) for k in keys) > 1 + 1e-9:
                raise ConfigError(f"{' + '.join(keys)} must be at most 1 (the rest keeps the transition's own goal)")
    if not cfg.train_critics and cfg.algo != "gcsl":
        raise ConfigError(f"--no-train-critics is GCSL's: {cfg.algo} learns its policy through its critics")
    if cfg.observe_disturbance and cfg.augment != "none":
        raise ConfigError("--augment mirrors the state, not the disturbance estimate: not with --observe-disturbance")
    if cfg.qrl.qrl_quasimetric == "iqe" and cfg.qrl.qrl_latent_dim % cfg.qrl.qrl_components:
        raise ConfigError(
            f"qrl_latent_dim ({cfg.qrl.qrl_latent_dim}) must be a multiple of qrl_components ({cfg.qrl.qrl_components})"
        )


def to_dict(cfg: TrainConfig) -> dict:
    """The config as a JSON-ready flat dict (every setting by its own name, tuples as lists):
    config.json's ``config`` record."""
    return to_flat_dict(cfg)


# what runs saved before a setting existed trained with (from_dict fills them in)
_BEFORE_RELABEL_OFFSET = {"relabel_offset": "uniform", "relabel_window": 0}
_BEFORE_OPTIONS = {
    "ema_decay": 0.0,
    "mc_lower_bound": False,
    "amp": "none",
    "augment": "none",
    "critic_random_goal_prob": 0.0,
    "alpha_schedule": "constant",
    "awr_normalize": "none",
    "cql_lagrange_thresh": 0.0,
}


def from_dict(d: dict) -> TrainConfig:
    """A :class:`TrainConfig` from :func:`to_dict`'s output; unknown keys are dropped and
    the values of runs saved before a setting existed are filled in."""
    names = set(to_flat_dict(TrainConfig()))
    d = {k: v for k, v in d.items() if k in names}
    if "relabel_prob" in d:  # a run saved before relabel_offset existed drew uniformly over the rest of the episode
        for k, v in _BEFORE_RELABEL_OFFSET.items():
            d.setdefault(k, v)
    if "steps" in d:  # a run saved before these options existed trained without them
        for k, v in _BEFORE_OPTIONS.items():
            d.setdefault(k, v)
    return from_mapping(TrainConfig, d, where="config.json", check=False)


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


def goal_mix(cfg: TrainConfig, use: str) -> Any:
    """The :class:`~aerohrl.algorithms.relabel.GoalMix` of a goal-conditioned agent's
    ``use`` ("value" or "actor") goals: its ``NAME_USE_p_*`` shares, the geometric mean
    ``1 / (1 - gamma)`` as OGBench's ``geom_sample`` (``relabel_mean_offset`` when gamma is 1)."""
    from aerohrl.algorithms.relabel import GoalMix

    sec, n = getattr(cfg, cfg.algo), f"{cfg.algo}_{use}_"
    mean = 1.0 / (1.0 - cfg.gamma) if cfg.gamma < 1 else cfg.relabel_mean_offset
    return GoalMix(
        p_cur=getattr(sec, n + "p_curgoal"),
        p_traj=getattr(sec, n + "p_trajgoal"),
        p_rand=getattr(sec, n + "p_randomgoal"),
        geometric=bool(getattr(sec, n + "geom_sample")),
        mean=mean,
    )


def relabel_future(cfg: TrainConfig) -> dict:
    """Keyword arguments of ``relabel.sample_future_index`` for this config."""
    return {"strategy": cfg.relabel_offset, "window": cfg.relabel_window, "mean": cfg.relabel_mean_offset}


__all__ = [
    "TrainConfig",
    "TD3BCConfig",
    "TD3AWBCConfig",
    "CQLConfig",
    "GCIQLConfig",
    "CRLConfig",
    "QRLConfig",
    "HIQLConfig",
    "ALGORITHMS",
    "ENSEMBLE_ALGORITHMS",
    "GOAL_AGENTS",
    "goal_mix",
    "PRESET_DIR",
    "presets",
    "preset_base",
    "per_algo_values",
    "make_config",
    "update",
    "check",
    "to_dict",
    "from_dict",
    "lr_factor",
    "critic_sizes",
    "relabel_future",
    "TOML_NAME",
    "to_toml",
]


# ----------------------------------------------------------------------------- run.toml

TOML_NAME = "run.toml"  # beside config.json in every run folder; `train --config RUN/run.toml` trains it again


def to_toml(cfg: TrainConfig) -> str:
    """The config as a flat TOML file (every setting, preset included), read back by
    ``train --config`` (:func:`aerohrl.config.load_toml` and :func:`aerohrl.config.from_mapping`)."""
    return _flat_toml(
        cfg,
        header="aerohrl train config (written by `train`); train it again with "
        "`train --config run.toml`, flags override its values",
    )
