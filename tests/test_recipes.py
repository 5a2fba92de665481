"""Expert-data recipes (datagen/recipes.py): action noise (DART), the replanning expert,
perturbed starts, repeated flights; their bytes, statistics and consistency."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import assert_fingerprint

from aerohrl import task
from aerohrl.datagen import build as build_mod
from aerohrl.datagen import reference
from aerohrl.datagen.build import build, generate, plan_references
from aerohrl.datagen.expert import GeometricController
from aerohrl.datagen.lerobot_reader import read_columns
from aerohrl.datagen.recipes import OUNoise
from aerohrl.datagen.spec import DatasetSpec, load_spec, version_name
from aerohrl.errors import UserError
from aerohrl.sim import BatchedQuadrotor, get_preset

NOISE = (1.0, 0.5, 0.5, 0.5)
# fingerprints (conftest.fingerprint) of each column of the default 250-goal dataset's files
# as built before the recipes existed (commit 8edf325, `datagen build --goals 250`,
# n250-s0-dbb240c0): the recipes at their defaults must not change the thesis's dataset.
DEFAULT_250 = {
    "data/chunk-000/file-000.parquet": {
        "observation.state": [-490.7735654172298, 279.8019031295115, 1761.4334409600053, -1267.831188555967, 546706.1202132538],
        "action": [2157.266790027085, 2590.345695107102, 3391.7068828744063, -4673.033995925195, 613761.0199234481],
        "observation.desired_goal": [
            -379.46281371959407,
            -535.9156572113405,
            -18.399992677706237,
            233.60573163055153,
            655697.3967518095,
        ],
        "next.observation.state": [
            -556.5602223563567,
            268.7379240086693,
            1795.9710472652735,
            -1304.0195096538898,
            550013.5396170613,
        ],
        "next.reward": [0.6227080943026655, 46.51506183866985, 128.6722437979405, 60.94430634281249, 1472.0],
        "next.done": [-14.74008482986026, 35.02297665635521, -5.963003498316151, 18.614843491608955, 250.0],
        "next.success": [0.6227080943026655, 46.51506183866985, 128.6722437979405, 60.94430634281249, 1472.0],
        "timestamp": [90.55549527603763, 91.47473515129974, 152.74558909425673, 213.0371286453735, 58487.769955299795],
        "frame_index": [9055.549106116629, 9147.47287775154, 15274.55856537295, 21303.712428689763, 5848777.0],
        "episode_index": [-18632.701749600317, -22334.91564571013, 22195.154722843094, 13930.151588691004, 6451830.0],
        "index": [-3914552.269998486, -4838789.772247756, 4711859.648086258, 3001929.8002849664, 1379674185.0],
        "task_index": [0.0, 0.0, 0.0, 0.0, 0.0],
    },
    "meta/aerohrl_episodes.parquet": {
        "episode_index": [-1397.761091365366, -763.9774211075082, -2777.852111368394, -5791.625016310172, 31125.0],
        "goal_pos": [-93.42841916929964, -7.048378485248353, -40.75994228053471, 20.196188692789708, 1139.3407088864196],
        "goal_vel": [-6.961477749606682, 33.36447839536037, -26.82176977353244, -67.24069023727493, 977.774075536246],
        "goal_acc": [-94.77826021720304, -25.743671532380702, 20.782196275580578, -75.48671900204405, 1876.2291155763405],
        "reference_duration_s": [-5.324758729037923, -42.72666380583883, -33.23142035121333, -54.949032170163285, 524.203125],
        "length": [-531.7900424519178, -4279.626695805848, -3324.991825764312, -5504.18838650913, 52530.0],
        "expert_success": [-1.4804542119535207, -11.964495047056047, -10.019408891715734, -24.563918612261638, 250.0],
        "first_success_step": [-520.0158015267813, -4216.593481362666, -3258.5802232218807, -5381.7196553915965, 51058.0],
        "final_pos_error_m": [
            0.12195137650074478,
            -0.2769819929125347,
            -0.09320381472249392,
            -0.2719219718105937,
            4.1319403786795945,
        ],
        "final_vel_error_mps": [
            -0.028566284054184828,
            0.1670183789234863,
            -0.15000590835943733,
            -0.4042633449897274,
            7.883302938524478,
        ],
        "final_rot_error_rad": [
            0.01567505797344155,
            -0.09416248025286947,
            0.12311141751802802,
            -0.36701605413268634,
            4.138188407023053,
        ],
    },
}


@pytest.fixture(scope="module")
def noisy():
    spec = DatasetSpec(goals=12, seed=3, action_noise=NOISE)
    return spec, generate(spec, progress=False)


def test_zero_noise_and_default_recipe_keep_todays_bytes(tmp_path):
    explicit = DatasetSpec(
        action_noise=(0, 0, 0, 0),
        expert="open-loop",
        start_states="rest",
        rollouts_per_goal=1,
        noise_tau=0.7,
        replan_every=9,
        start_vel=2.0,
    )  # sub-settings of recipes that are off
    assert version_name(explicit) == version_name(DatasetSpec()) == "n250-s0-dbb240c0"
    res = build(explicit, tmp_path, progress=False)
    for f, columns in DEFAULT_250.items():
        table = pq.read_table(res.path / f)
        assert table.column_names == list(columns), f
        for name, ref in columns.items():
            col = table[name].combine_chunks()
            while pa.types.is_list(col.type) or pa.types.is_fixed_size_list(col.type):
                col = col.flatten()
            assert_fingerprint(col.to_numpy(zero_copy_only=False).astype(np.float64), ref, f"{f}:{name}")
    assert "action.expert" not in read_columns(res.path)


def test_recipes_change_the_version_and_reach_the_card(tmp_path):
    names = {
        version_name(DatasetSpec(**kw))
        for kw in (
            {},
            {"action_noise": NOISE},
            {"action_noise": NOISE, "noise_tau": 0.1},
            {"expert": "replan"},
            {"expert": "replan", "replan_every": 10},
            {"start_states": "perturbed"},
            {"action_noise": NOISE, "rollouts_per_goal": 2},
        )
    }
    assert len(names) == 7
    res = build(DatasetSpec(goals=4, seed=1, action_noise=NOISE, expert="replan"), tmp_path, progress=False)
    card = (res.path / "README.md").read_text()
    assert "action noise" in card and "replan" in card and "[1.0, 0.5, 0.5, 0.5]" in card


def test_ou_noise_has_the_stated_std_and_correlation_time():
    sigma, tau, dt = np.array([1.0, 0.5, 0.5, 0.5]), 0.2, 0.01
    noise = OUNoise(sigma, tau, dt, 4000, np.random.default_rng(0))
    x = np.stack([noise() for _ in range(200)])  # (T, N, 4)
    np.testing.assert_allclose(x.std(axis=(0, 1)), sigma, rtol=0.03)
    for lag in (1, 10, 20):
        r = (x[lag:] * x[:-lag]).mean(axis=(0, 1)) / sigma**2
        np.testing.assert_allclose(r, np.exp(-lag * dt / tau), atol=0.03)


def test_noisy_data_records_flown_and_expert_actions(noisy):
    spec, d = noisy
    assert d.action_expert is not None and d.action_expert.shape == d.action.shape
    diff = d.action - d.action_expert
    lo, hi = GeometricController(get_preset(spec.vehicle)).action_box
    inside = ((d.action > lo + 1e-9) & (d.action < hi - 1e-9)).all(1)
    assert inside.mean() > 0.9
    # away from the clip the difference is the OU noise: its std is sigma per dimension
    np.testing.assert_allclose(diff[inside].std(0), NOISE, rtol=0.15)
    assert (d.action >= lo - 1e-12).all() and (d.action <= hi + 1e-12).all()


def test_action_is_what_the_simulator_flew(noisy):
    """Replaying the recorded actions open loop, all episodes in one batch from hover at
    the origin, reproduces every recorded state exactly (float64, the same simulator)."""
    spec, d = noisy
    n, kmax = len(d.T), int(d.length.max())
    acts = np.tile([9.81, 0.0, 0.0, 0.0], (kmax, n, 1))  # after an episode ends: hover (not recorded)
    acts[d.frame_index, d.episode_index] = d.action
    sim = BatchedQuadrotor(get_preset(spec.vehicle), n, dt=spec.dt, substeps=spec.substeps)
    states = [sim.reset()]
    for k in range(kmax):
        states.append(sim.step(acts[k]))
    states = np.stack(states)
    np.testing.assert_array_equal(states[d.frame_index, d.episode_index], d.state)
    np.testing.assert_array_equal(states[d.frame_index + 1, d.episode_index], d.next_state)


def test_action_expert_is_the_controllers_output_at_the_recorded_state(noisy):
    spec, d = noisy
    goals, T, coeffs, _, _ = plan_references(spec, np.random.default_rng(spec.seed))
    ctrl = GeometricController(get_preset(spec.vehicle))
    t = np.minimum(d.frame_index * spec.dt, T[d.episode_index])
    c = coeffs[d.episode_index]
    ref = [reference.evaluate(c, t, order=o) for o in range(4)]
    np.testing.assert_allclose(ctrl(d.state, *ref), d.action_expert, rtol=0, atol=1e-9)


def test_replanning_expert_equals_the_open_loop_reference_at_take_off():
    base = DatasetSpec(goals=10, seed=2)
    rp = DatasetSpec(goals=10, seed=2, expert="replan", replan_every=5)
    a, b = generate(base, progress=False), generate(rp, progress=False)
    np.testing.assert_array_equal(a.length, b.length)
    first = a.frame_index < 5  # before the first re-plan: the same plan, the same flight
    np.testing.assert_array_equal(a.action[first], b.action[first])
    assert not np.array_equal(a.action, b.action)
    assert b.episode_success.mean() >= 0.98  # SPEC's bar for the clean replanning expert


def test_replanning_expert_with_a_qp_reference_of_higher_degree():
    d = generate(DatasetSpec(goals=3, seed=4, expert="replan", solver="qp", degree=7), progress=False)
    assert d.episode_success.all()


def test_perturbed_starts_and_repeated_flights(tmp_path):
    spec = DatasetSpec(
        goals=5, seed=1, start_states="perturbed", rollouts_per_goal=3, start_vel=1.0, start_tilt=0.3, start_rate=1.0
    )
    d = generate(spec, progress=False)
    assert len(d.T) == 15
    np.testing.assert_array_equal(d.goal_index, np.repeat(np.arange(5), 3))
    np.testing.assert_array_equal(d.goal_vec[0::3], d.goal_vec[1::3])
    s0 = d.state[d.frame_index == 0]
    assert np.abs(s0[:, task.POS]).max() == 0 and 0 < np.abs(s0[:, task.VEL]).max() <= 1.0
    assert np.abs(s0[:, task.RATE]).max() <= 1.0 and len({tuple(r) for r in s0[:, task.VEL].round(6)}) == 15
    res = build(spec, tmp_path, progress=False)
    from aerohrl.algorithms.data import load_dataset

    data = load_dataset(res.path)
    assert data.rest_start_episodes().tolist() == [0, 3, 6, 9, 12]  # one episode per goal: Reach-Desired's set


def test_clean_flights_do_not_depend_on_the_rollout_block(monkeypatch):
    """Blocks bound memory; every flight depends on its own inputs only, so the bytes of a
    clean dataset are the same for any block size (the noise streams are per block)."""
    spec = DatasetSpec(goals=100, seed=5, start_states="perturbed")
    whole = generate(spec, progress=False)
    monkeypatch.setattr(build_mod, "ROLLOUT_BLOCK", 30)  # 4 blocks of 25
    blocked = generate(spec, progress=False)
    for f in ("state", "action", "next_state"):
        np.testing.assert_array_equal(getattr(whole, f), getattr(blocked, f))


@pytest.mark.parametrize(
    "kw, msg",
    [
        ({"action_noise": (-1.0, 0.5)}, "action_noise must be >= 0"),
        ({"action_noise": (1.0, 0.5, 0.5)}, "4 numbers"),
        ({"expert": "mpc"}, "expert must be one of open-loop, replan"),
        ({"start_states": "random"}, "start_states must be one of rest, perturbed"),
        ({"noise_tau": 0.0}, "noise_tau must be > 0"),
        ({"replan_every": 0}, "replan_every must be >= 1"),
        ({"start_vel": 7.0}, "start_vel must be <= 3"),
        ({"rollouts_per_goal": 3}, "identical flights"),
        ({"action_noise": (9.0, 0.5)}, "action_noise .* is beyond what the expert flies through"),
    ],
)
def test_bad_recipes_are_one_line_errors(kw, msg):
    with pytest.raises(UserError, match=msg) as e:
        load_spec(None, **kw)
    assert "\n" not in str(e.value)


def test_cli_rejects_a_bad_recipe_in_one_line(tmp_path):
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "aerohrl.datagen.cli",
            "build",
            "--goals",
            "3",
            "--out",
            str(tmp_path),
            "--action-noise",
            "-1",
            "0.5",
        ],
        capture_output=True,
        text=True,
    )
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and "action-noise" in p.stderr


def test_lerobot_loads_the_expert_action_column(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    res = build(DatasetSpec(goals=3, seed=1, action_noise=NOISE), tmp_path, progress=False)
    ds = LeRobotDataset("aerohrl/quadrotor-reach", root=res.path)
    cols = read_columns(res.path)
    item = ds[7]
    np.testing.assert_allclose(item["action.expert"].numpy(), cols["action.expert"][7])
    np.testing.assert_allclose(item["action"].numpy(), cols["action"][7])
    assert tuple(ds.meta.features["action.expert"]["shape"]) == (4,)


def test_a_recipe_the_expert_fails_is_refused(monkeypatch):
    monkeypatch.setattr(build_mod, "MIN_EXPERT_SUCCESS", 0.99)
    with pytest.raises(UserError, match="reaches only"):
        generate(DatasetSpec(goals=20, seed=0, action_noise=(2.0, 1.0)), progress=False)


def test_bc_target_expert_imitates_the_clean_command(tmp_path):
    import torch

    from aerohrl.algorithms.base import Algorithm
    from aerohrl.algorithms.data import GoalBatchSampler, fit_normalizer, load_dataset

    res = build(DatasetSpec(goals=6, seed=2, action_noise=NOISE), tmp_path, progress=False)
    data = load_dataset(res.path)
    assert data.action_expert is not None and not torch.equal(data.action_expert, data.action)
    norm = fit_normalizer(data, 0.5, bc_target="expert")
    lo, hi = norm.act_center - norm.act_half, norm.act_center + norm.act_half
    assert (data.action_expert >= lo).all() and (data.action_expert <= hi).all()
    for target, expect in (("expert", data.action_expert), ("executed", None)):
        s = GoalBatchSampler(data, norm, 64, 0.5, torch.Generator().manual_seed(0), bc_target=target)
        b = s.sample()
        i = b["index"]
        torch.testing.assert_close(norm.action_from_unit(b["action"]), data.action[i])  # critics: what was flown
        actor = Algorithm.actor_batch(b)
        if expect is None:
            assert "bc_action" not in b.keys() and actor is b
        else:
            torch.testing.assert_close(norm.action_from_unit(actor["action"]), expect[i])
            torch.testing.assert_close(norm.action_from_unit(b["action"]), data.action[i])  # unchanged by actor_batch


def test_the_recommended_spec_is_the_measured_dataset():
    """datasets/quadrotor-reach-dart.toml is the dataset of the recipe study's best rows."""
    root = Path(__file__).resolve().parents[1]
    spec = load_spec(root / "datasets" / "quadrotor-reach-dart.toml")
    assert version_name(spec) == version_name(DatasetSpec(goals=25000, action_noise=(1.0, 0.5))) == "n25000-s0-81b96355"


def test_the_robustness_spec_is_the_measured_dataset():
    """datasets/quadrotor-reach-robust.toml is the data of the robustness page's best recipe."""
    root = Path(__file__).resolve().parents[1]
    spec = load_spec(root / "datasets" / "quadrotor-reach-robust.toml")
    fields = (spec.expert, spec.disturbance_observer, spec.observer_model, spec.terminal_disturbance, spec.endgame_retarget)
    assert fields == ("replan", 0.1, "gain", True, True)
    assert version_name(spec) == "n25000-s0-54501c05"
