"""The training presets are data (algorithms/presets/*.toml) and resolve to exactly the
configs the code-defined presets gave: every algorithm x preset, written out here."""

from __future__ import annotations

import json

import pytest

from aerohrl import config as K
from aerohrl.algorithms import config as C
from aerohrl.errors import UserError

# cpu preset with algo gcsl: TrainConfig's defaults with GCSL's relabelling probability
CPU_GCSL = {
    "algo": "gcsl",
    "preset": "cpu",
    "dataset": "",
    "seed": 0,
    "device": "cpu",
    "steps": 30000,
    "batch_size": 512,
    "hidden": [512, 512, 512],
    "critic_hidden": [128, 128],
    "lr_actor": 0.001,
    "lr_critic": 0.0003,
    "lr_schedule": "cosine",
    "amp": "auto",
    "ema_decay": 0.999,
    "pos_octaves": 0,
    "observe_disturbance": False,
    "relabel_prob": 0.01,
    "relabel_offset": "geometric",
    "relabel_window": 0,
    "relabel_mean_offset": 30.0,
    "critic_random_goal_prob": 0.0,
    "gamma": 0.99,
    "bc_target": "expert",
    "augment": "none",
    "mc_lower_bound": True,
    "tau": 0.005,
    "num_critics": 5,
    "train_critics": True,
    "alpha": 0.001,
    "policy_noise": 0.2,
    "noise_clip": 0.5,
    "policy_delay": 1,
    "alpha_schedule": "linear",
    "awr_temperature": 10.0,
    "awr_max_weight": 100.0,
    "awr_normalize": "std",
    "cql_min_q_weight": 5.0,
    "cql_num_random": 4,
    "cql_lagrange_thresh": 0.0,
    "gciql_expectile": 0.9,
    "gciql_actor_loss": "ddpgbc",
    "gciql_alpha": 0.3,
    "gciql_value_p_curgoal": 0.2,
    "gciql_value_p_trajgoal": 0.5,
    "gciql_value_p_randomgoal": 0.3,
    "gciql_value_geom_sample": True,
    "gciql_actor_p_curgoal": 0.0,
    "gciql_actor_p_trajgoal": 1.0,
    "gciql_actor_p_randomgoal": 0.0,
    "gciql_actor_geom_sample": False,
    "crl_alpha": 0.1,
    "crl_latent_dim": 64,
    "crl_contrastive": "binary",
    "crl_value_p_curgoal": 0.0,
    "crl_value_p_trajgoal": 1.0,
    "crl_value_p_randomgoal": 0.0,
    "crl_value_geom_sample": True,
    "crl_actor_p_curgoal": 0.0,
    "crl_actor_p_trajgoal": 1.0,
    "crl_actor_p_randomgoal": 0.0,
    "crl_actor_geom_sample": False,
    "qrl_alpha": 0.003,
    "qrl_quasimetric": "iqe",
    "qrl_latent_dim": 64,
    "qrl_components": 8,
    "qrl_eps": 0.05,
    "qrl_value_p_curgoal": 0.0,
    "qrl_value_p_trajgoal": 0.0,
    "qrl_value_p_randomgoal": 1.0,
    "qrl_value_geom_sample": True,
    "qrl_actor_p_curgoal": 0.0,
    "qrl_actor_p_trajgoal": 1.0,
    "qrl_actor_p_randomgoal": 0.0,
    "qrl_actor_geom_sample": False,
    "hiql_expectile": 0.7,
    "hiql_low_alpha": 3.0,
    "hiql_high_alpha": 3.0,
    "hiql_subgoal_steps": 25,
    "hiql_rep_dim": 10,
    "hiql_low_actor_rep_grad": False,
    "hiql_subgoal_space": "rep",
    "hiql_subgoal_end": "achieved",
    "hiql_low_subgoal_offset": "fixed",
    "hiql_goal_switch": False,
    "hiql_value_p_curgoal": 0.2,
    "hiql_value_p_trajgoal": 0.5,
    "hiql_value_p_randomgoal": 0.3,
    "hiql_value_geom_sample": True,
    "hiql_actor_p_curgoal": 0.0,
    "hiql_actor_p_trajgoal": 1.0,
    "hiql_actor_p_randomgoal": 0.0,
    "hiql_actor_geom_sample": False,
    "log_every": 200,
    "checkpoint_every": 1000,
    "keep_checkpoints": 10,
    "eval_every": 5000,
    "eval_start": 0,
    "eval_episodes": 25,
    "eval_horizon": 500,
    "eval_task": "reach-desired",
    "stop_success": 0.0,
}

# what the thesis preset changes under every algorithm (its [algo.NAME] tables add the rest)
THESIS = {
    "preset": "thesis",
    "steps": 2000000,
    "batch_size": 1048,
    "hidden": [512, 2048, 2048, 512],
    "critic_hidden": [],
    "lr_actor": 0.0003,
    "lr_schedule": "constant",
    "amp": "none",
    "ema_decay": 0.0,
    "relabel_prob": 0.5,
    "relabel_offset": "uniform",
    "mc_lower_bound": False,
    "alpha": 2.5,
    "policy_delay": 2,
    "alpha_schedule": "constant",
    "awr_temperature": 1.0,
    "awr_normalize": "none",
    "cql_num_random": 10,
    "log_every": 1000,
    "checkpoint_every": 50000,
}

# what the fast preset changes under every algorithm: a shorter run (the cosine schedule
# anneals within it) evaluated on 250 episodes every 1,000 steps from 5,000, stopping at 90 %
FAST = {
    "preset": "fast",
    "steps": 9000,
    "eval_every": 1000,
    "eval_start": 5000,
    "eval_episodes": 250,
    "stop_success": 0.9,
}

# and under GCSL: the policy alone, a deeper actor, smaller batches
FAST_GCSL = {"batch_size": 128, "hidden": [512, 512, 512, 512], "train_critics": False}

# the cpu and fast presets' actors of the reference agents: a strong BC term, the episodes' desired goals
AGENT_ACTORS = {
    "gciql": {"gciql_alpha": 10.0, "gciql_actor_p_trajgoal": 0.0},
    "crl": {"crl_alpha": 100.0, "crl_actor_p_trajgoal": 0.0},
    "qrl": {"qrl_alpha": 10.0, "qrl_actor_p_trajgoal": 0.0},
}

# what every other algorithm x preset changes from CPU_GCSL
EXPECTED_CHANGES = {
    "cpu/gcsl": {},
    "cpu/td3bc": {"algo": "td3bc", "relabel_prob": 0.05},
    "cpu/td3awbc": {"algo": "td3awbc", "relabel_prob": 0.05},
    "cpu/cql": {"algo": "cql", "relabel_prob": 0.05},
    "fast/gcsl": {**FAST, **FAST_GCSL},
    "fast/td3bc": {**FAST, "algo": "td3bc", "relabel_prob": 0.05},
    "fast/cql": {**FAST, "algo": "cql", "relabel_prob": 0.05},
    "thesis/gcsl": {**THESIS},
    "thesis/td3bc": {**THESIS, "algo": "td3bc"},
    "thesis/td3awbc": {**THESIS, "algo": "td3awbc"},
    "thesis/cql": {**THESIS, "algo": "cql"},
    "cpu/gciql": {"algo": "gciql", "relabel_prob": 0.05, **AGENT_ACTORS["gciql"]},
    "cpu/crl": {"algo": "crl", "relabel_prob": 0.05, **AGENT_ACTORS["crl"]},
    "cpu/qrl": {"algo": "qrl", "relabel_prob": 0.05, **AGENT_ACTORS["qrl"]},
    "fast/qrl": {**FAST, "algo": "qrl", "relabel_prob": 0.05, **AGENT_ACTORS["qrl"]},
    "cpu/hiql": {"algo": "hiql", "relabel_prob": 0.05},
    "thesis/crl": {**THESIS, "algo": "crl", "crl_latent_dim": 512},
    "thesis/qrl": {**THESIS, "algo": "qrl", "qrl_latent_dim": 512},
}


@pytest.mark.parametrize("name", list(EXPECTED_CHANGES))
def test_presets_resolve_to_the_same_configs(name):
    preset, algo = name.split("/")
    got = C.to_dict(C.make_config(preset, algo=algo))
    want = {**CPU_GCSL, **EXPECTED_CHANGES[name]}
    assert list(got) == list(want)  # config.json's keys, in the same order
    assert json.dumps(got) == json.dumps(want)  # values and their types (1.0 vs 1)


def test_the_preset_files_are_the_presets():
    assert C.presets() == ("cpu", "fast", "thesis")
    assert C.per_algo_values("cpu") == {"gcsl": {"relabel_prob": 0.01}, **AGENT_ACTORS}
    assert C.per_algo_values("fast") == {"gcsl": {"relabel_prob": 0.01, **FAST_GCSL}, **AGENT_ACTORS}
    assert C.preset_base("cpu") == C.TrainConfig()  # the cpu preset is the dataclass defaults
    cfg = C.make_config("thesis", algo="td3awbc")
    assert (cfg.td3bc.alpha, cfg.td3bc.policy_delay, cfg.td3awbc.awr_temperature, cfg.cql.cql_num_random) == (2.5, 2, 1.0, 10)


def test_overrides_win_and_the_flat_form_round_trips():
    cfg = C.make_config("cpu", algo="td3bc", alpha=1, relabel_prob=0.2, hidden=[8])
    assert cfg.td3bc.alpha == 1.0 and isinstance(cfg.td3bc.alpha, float) and cfg.relabel_prob == 0.2 and cfg.hidden == (8,)
    assert C.from_dict(C.to_dict(cfg)) == cfg
    with pytest.raises(UserError, match=r"unknown key\(s\) alpah \(did you mean alpha\?\)"):
        C.make_config("cpu", alpah=1.0)
    with pytest.raises(UserError, match="hidden needs at least one layer size"):
        C.make_config("cpu", hidden=())


def test_runs_saved_before_a_setting_existed_keep_what_they_trained_with():
    old = {
        k: v
        for k, v in CPU_GCSL.items()
        if k
        not in ("relabel_offset", "relabel_window", "ema_decay", "amp", "alpha_schedule", "awr_normalize", "cql_lagrange_thresh")
    }
    cfg = C.from_dict({**old, "gone": 1})
    assert (
        cfg.relabel_offset,
        cfg.ema_decay,
        cfg.amp,
        cfg.td3bc.alpha_schedule,
        cfg.td3awbc.awr_normalize,
        cfg.cql.cql_lagrange_thresh,
    ) == ("uniform", 0.0, "none", "constant", "none", 0.0)


def test_a_preset_with_an_unknown_algorithm_table_is_refused(tmp_path, monkeypatch):
    (tmp_path / "p.toml").write_text("[algo.sac]\nrelabel_prob = 0.1\n")
    monkeypatch.setattr(C, "PRESET_DIR", tmp_path)
    with pytest.raises(K.ConfigError, match=r"preset p \[algo\]: unknown key\(s\) sac"):
        C.make_config("p")


def test_the_fast_preset_is_its_flags():
    """``--preset fast`` is the cpu preset with the fast preset's values given as flags, one flag per setting."""
    from aerohrl.algorithms.cli import config_from_args, parser

    fast = config_from_args(parser().parse_args(["--preset", "fast", "--dataset", "/data/ds"]))
    changes = {k: v for k, v in C.to_dict(fast).items() if k != "preset" and v != CPU_GCSL.get(k)}
    assert changes == {"dataset": "/data/ds", **{k: v for k, v in {**FAST, **FAST_GCSL}.items() if k != "preset"}}
    flags = []
    for k, v in changes.items():
        flag = "--" + k.replace("_", "-")
        if isinstance(v, bool):
            flags.append(flag if v else "--no-" + flag[2:])
        elif isinstance(v, list):
            flags += [flag, *map(str, v)]
        else:
            flags.append(f"{flag}={v}")
    assert C.to_dict(config_from_args(parser().parse_args(flags))) == {**C.to_dict(fast), "preset": "cpu"}
