"""The IPP trainer's config: presets are TOML data that resolve to the configs they
replaced, a run's config.json reads back (old runs included), declared bounds are checked."""

from __future__ import annotations

import dataclasses
import json

import pytest

from aerohrl.config import ConfigError
from aerohrl.errors import UserError
from aerohrl.ipp.env import EnvConfig, semantic_config
from aerohrl.config import from_nested
from aerohrl.ipp.train_config import PolicyConfig, TrainConfig, preset, preset_names

# The presets as TrainConfig instances, written out in code: each ipp/presets/NAME.toml must
# resolve to exactly its entry.
OLD_PRESETS = {
    "cpu": TrainConfig(
        bc_iterations=30,
        iterations=0,
        lr=3e-5,
        entropy_coef=0.001,
        adv_weights=(0.25, 0.25, 1.0, 0.0, 0.0),
        bc_anchor=0.5,
        eval_every=10,
        eval_envs=100,
    ),
    "thesis": TrainConfig(iterations=782, policy=PolicyConfig(features=False)),
    "quick": TrainConfig(n_envs=32, bc_iterations=8, iterations=0, eval_every=4, eval_envs=32),
    "semantic": TrainConfig(
        n_envs=32,
        bc_iterations=12,
        iterations=0,
        bc_buffer=4,
        log_every=4,
        lr=3e-5,
        entropy_coef=0.001,
        adv_weights=(0.25, 0.25, 1.0, 0.0, 0.0),
        bc_anchor=0.5,
        eval_every=4,
        eval_envs=30,
        env=semantic_config(start="random"),
    ),
    "test": TrainConfig(
        n_envs=4,
        iterations=1,
        epochs=1,
        minibatches=1,
        bc_iterations=2,
        bc_epochs=1,
        log_every=1,
        eval_every=2,
        eval_envs=3,
        policy=PolicyConfig(hidden=32),
        env=EnvConfig(start="random", budget=1500.0),
    ),
}
# TrainConfig's defaults, written out
OLD_DEFAULTS = dict(
    n_envs=64,
    iterations=600,
    lr=3e-4,
    gamma=0.98,
    lam=0.8,
    clip=0.2,
    epochs=4,
    minibatches=4,
    value_coef=0.5,
    entropy_coef=0.01,
    valid_coef=0.1,
    valid_beta=(1.0, 0.2),
    reward_scale=0.05,
    grad_clip=5.0,
    adv_weights=(1.0,) * 5,
    seed=7,
    threads=1,
    log_every=10,
    init=None,
    bc_iterations=0,
    teacher="detect",
    teacher_depth=None,
    teacher_belief=None,
    bc_beta0=1.0,
    bc_beta_decay=0.7,
    bc_epochs=2,
    bc_lr=1e-3,
    bc_buffer=20,
    bc_anchor=0.0,
    eval_every=0,
    eval_envs=64,
    eval_seed=500,
)


def test_defaults_are_unchanged():
    cfg = TrainConfig()
    assert {k: getattr(cfg, k) for k in OLD_DEFAULTS} == OLD_DEFAULTS
    assert cfg.policy == PolicyConfig() and dataclasses.astuple(cfg.policy) == (128, True, True, True)
    assert cfg.env == EnvConfig(start="random")


@pytest.mark.parametrize("name", sorted(OLD_PRESETS))
def test_presets_resolve_to_the_old_configs(name):
    assert preset_names() == tuple(sorted(OLD_PRESETS))
    cfg = preset(name)
    assert cfg == OLD_PRESETS[name] and dataclasses.asdict(cfg) == dataclasses.asdict(OLD_PRESETS[name])
    cfg.validate()


def test_preset_overrides_and_errors():
    cfg = preset("cpu", n_envs=8, recurrent=False, features=False, seed=None)
    assert (cfg.n_envs, cfg.seed, cfg.policy.recurrent, cfg.policy.features) == (8, 7, False, False)
    with pytest.raises(UserError, match="unknown preset 'gpu' \\(choose from cpu, quick, semantic, test, thesis\\)"):
        preset("gpu")
    with pytest.raises(UserError, match="unknown key.*n_env .*did you mean.*n_envs"):
        preset("cpu", n_env=3)


def test_a_run_config_reads_back_and_old_ones_too():
    cfg = preset("semantic")
    record = json.loads(json.dumps(dataclasses.asdict(cfg)))  # what config.json holds
    assert from_nested(TrainConfig, record) == cfg
    old = {k: v for k, v in record.items() if k not in ("bc_anchor", "eval_seed")}  # written before those existed
    old["env"] = {k: v for k, v in old["env"].items() if k != "semantic"}
    back = from_nested(TrainConfig, old, check=False)
    assert back.bc_anchor == 0.0 and back.env.semantic == EnvConfig().semantic and back.env.kind == "semantic"
    assert from_nested(TrainConfig, {"n_envs": 4.0, "teacher_depth": 2}).n_envs == 4  # JSON may write 4.0
    for bad, match in (
        ({"env": {"world": {"map_sise": 3}}}, r"run/config.json: env.world: unknown key\(s\) map_sise \(did you mean map_size"),
        ({"env": 3}, "env must be a table"),
        ({"n_envs": 1.5}, "n_envs must be an integer"),
        ({"adv_weights": [1, "a", 1, 1, 1]}, "adv_weights must be a list of numbers"),
        ({"teacher_depth": 9}, "teacher_depth must be <= 4"),
        ({"teacher": "oracle"}, "teacher must be one of detect"),
        ({"lr": 1.0}, "lr must be < 1"),
    ):
        with pytest.raises(ConfigError, match=match) as e:
            from_nested(TrainConfig, bad, where="run/config.json")
        assert "\n" not in str(e.value)


def test_cross_field_rules():
    for over, match in (
        ({"iterations": 0, "bc_iterations": 0}, "iterations \\+ bc_iterations must be >= 1"),
        ({"adv_weights": (1.0, 1.0)}, "adv_weights needs 5 numbers"),
        ({"eval_seed": 1000}, "seed 1000 is the test suite's"),
        ({"adv_weights": (1.0, float("nan"), 1.0, 1.0, 1.0)}, "finite"),
        ({"n_envs": 0}, "n_envs must be >= 1"),
    ):
        with pytest.raises(ConfigError, match=match):
            dataclasses.replace(TrainConfig(), **over).validate()


def test_planner_environment_lattice_and_bench_checks_come_from_the_declarations():
    from aerohrl.ipp.baselines import PlannerConfig
    from aerohrl.ipp.bench import BenchConfig
    from aerohrl.ipp.lattice import LatticeConfig, default_lattice
    from aerohrl.ipp.world import WorldConfig

    lat = default_lattice()
    cases = [
        (lambda: PlannerConfig(scoring="bogus").validate(), "scoring must be one of ratio, additive"),
        (lambda: PlannerConfig(cmaes_tol=float("nan")).validate(), "cmaes_tol must be a finite number"),
        (lambda: PlannerConfig(cost_weight=-1.0).validate(), "cost_weight must be >= 0"),
        (lambda: LatticeConfig(n_vertices=0).validate(), "lattice: n_vertices must be >= 1"),
        (lambda: LatticeConfig(vertex_speed=1.0).validate(), "lattice: vertex_speed must be <= 0.99"),
        (lambda: LatticeConfig(t_min=5.0).validate(), "lattice: need t_min < t_max"),  # cross-field
        (lambda: LatticeConfig(hover_moves=(1, 9)).validate(), "hover_moves must lie in 1..reach"),
        (lambda: EnvConfig(start="corner").validate(lat), "start must be one of center, random"),
        (lambda: EnvConfig(found_threshold=0.5).validate(lat), "found_threshold must be > 0.5"),
        (lambda: EnvConfig(map_size=600).validate(lat), "map_size must be <= 512"),
        (lambda: EnvConfig(kind="mixed").validate(lat), "kind must be one of targets, semantic"),
        (lambda: EnvConfig(map_size=40).validate(lat), "world.map_size must equal map_size"),  # cross-field
        (
            lambda: EnvConfig(map_size=40, world=WorldConfig(map_size=40), budget=1.0).validate(lat),
            "cannot pay for a single primitive",
        ),
        (
            lambda: (
                semantic_config(map_size=64)
                .__class__(**{**semantic_config(map_size=64).__dict__, "semantic": semantic_config().semantic})
                .validate(lat)
            ),
            "semantic.map_size must equal map_size",
        ),
        (lambda: BenchConfig(envs=0).validate(), "envs must be >= 1"),
        (lambda: BenchConfig(planners=("astar",)).validate(), "unknown planner 'astar'"),
        (lambda: BenchConfig(execution="teleport").validate(), "execution must be one of ideal, flown, skill"),
    ]
    for call, match in cases:
        with pytest.raises(ValueError, match=match) as e:
            call()
        assert "\n" not in str(e.value)
    for ok in (PlannerConfig(), LatticeConfig(), BenchConfig()):
        ok.validate()
    EnvConfig().validate(lat)
