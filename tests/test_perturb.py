"""Perturbations of the simulator (sim/perturb.py): nominal bytes, each axis's physical
effect, determinism, one-line parse errors, and ``aerohrl eval --perturb`` end to end."""

from __future__ import annotations


import numpy as np
import pytest
from conftest import assert_fingerprint

from aerohrl.errors import UserError
from aerohrl.sim import BatchedQuadrotor, Perturbation, get_preset
from aerohrl.sim.params import GRAVITY

P = get_preset("hummingbird")
HOVER = np.array([GRAVITY, 0.0, 0.0, 0.0])
# fingerprint (conftest.fingerprint) of the nominal trajectory of _trajectory() as the
# simulator gave it before perturbations existed
NOMINAL_REFERENCE = [1461.0810599770023, -1340.4075919922263, -656.5087365464003, 2050.571039727544, 11887.58120504035]


def _actions(n: int = 6, steps: int = 60) -> np.ndarray:
    rng = np.random.default_rng(7)
    return np.stack([np.column_stack([GRAVITY + rng.normal(0, 2, n), rng.normal(0, 1.5, (n, 3))]) for _ in range(steps)])


def _trajectory(**kw) -> np.ndarray:
    acts = _actions()
    sim = BatchedQuadrotor(P, acts.shape[1], **kw)
    out = [sim.state]
    for a in acts:
        out.append(sim.step(a))
    out.append(sim.rotor_speeds)
    return np.concatenate([o.ravel() for o in out])


def _fly(perturbation=None, actions=None, n=1, steps=100, seed=0, state_fn=None):
    sim = BatchedQuadrotor(P, n, perturbation=perturbation, seed=seed)
    acts = np.broadcast_to(HOVER, (steps, n, 4)) if actions is None else actions
    return np.stack([sim.state] + [sim.step(a) for a in acts]), sim


# ----------------------------------------------------------------------------- nominal bytes
def test_nominal_bytes_unchanged():
    base = _trajectory()
    assert np.array_equal(base, _trajectory(perturbation=None))
    assert np.array_equal(base, _trajectory(perturbation=Perturbation()))
    assert np.array_equal(base, _trajectory(perturbation=Perturbation.parse("")))
    # a direction without wind and a correlation time without gusts are nominal too
    assert np.array_equal(base, _trajectory(perturbation=Perturbation(wind_dir=90.0, gust_tau=3.0)))
    assert_fingerprint(base, NOMINAL_REFERENCE, "the nominal trajectory")


def test_perturbed_path_with_unit_scales_matches_nominal():
    # the perturbed code path (forced by a zero-effect bias channel) integrates the same equations
    sim_n = BatchedQuadrotor(P, 6)
    sim_p = BatchedQuadrotor(P, 6, perturbation=Perturbation(pos_bias=1e-9))
    assert sim_p.plant is not None
    for a in _actions():
        sn, sp = sim_n.step(a), sim_p.step(a)
    np.testing.assert_allclose(sp, sn, rtol=0, atol=1e-9)


# ----------------------------------------------------------------------------- physical effects
def test_heavier_vehicle_sinks_at_nominal_hover_thrust():
    traj, _ = _fly(Perturbation(mass=1.2), steps=100)
    # T = m g (the controller's belief), true mass 1.2 m: a = g / 1.2 - g
    np.testing.assert_allclose(traj[-1, 0, 5], (GRAVITY / 1.2 - GRAVITY) * 1.0, rtol=1e-6)
    nominal, _ = _fly(None, steps=100)
    assert abs(nominal[-1, 0, 2]) < 1e-9


def test_thrust_coefficient_and_inertia_and_motor():
    lo, _ = _fly(Perturbation(thrust=0.9), steps=50)
    assert lo[-1, 0, 5] < -0.4  # less thrust at the same rotor speeds
    # a roll-rate step: a heavier inertia answers slower, slow motors answer slower
    acts = np.broadcast_to(np.array([GRAVITY, 2.0, 0.0, 0.0]), (5, 1, 4))
    base, _ = _fly(None, acts)
    heavy, _ = _fly(Perturbation(inertia=2.0), acts)
    slow, _ = _fly(Perturbation(motor_tau=4.0), acts)
    assert heavy[-1, 0, 15] < base[-1, 0, 15] - 0.05
    assert slow[1, 0, 15] < base[1, 0, 15] - 0.05  # the first step: the motors lag the rate loop's demand
    # the yaw moment coefficient: a yaw-rate step with weaker rotor drag turns slower
    acts = np.broadcast_to(np.array([GRAVITY, 0.0, 0.0, 1.0]), (10, 1, 4))
    yaw, _ = _fly(None, acts)
    weak, _ = _fly(Perturbation(torque=0.5), acts)
    assert weak[-1, 0, 17] < yaw[-1, 0, 17] - 0.01


def _step_command(steps: int = 12, at: int = 3) -> np.ndarray:
    a = np.broadcast_to(HOVER, (steps, 1, 4)).copy()
    a[at:, 0, 0] = GRAVITY + 5.0
    return a


def test_latency_delays_by_whole_steps():
    acts = _step_command()
    delayed, _ = _fly(Perturbation(latency=0.02), acts)
    shifted = np.concatenate([np.broadcast_to(HOVER, (2, 1, 4)), acts[:-2]])
    expected, _ = _fly(None, shifted)
    np.testing.assert_allclose(delayed, expected, rtol=0, atol=1e-9)
    assert delayed[4, 0, 5] == 0.0 and expected[6, 0, 5] > 0  # nothing moves until two steps after the command


def test_latency_substep_remainder_lies_between_whole_steps():
    acts = _step_command()
    one, _ = _fly(Perturbation(latency=0.01), acts)
    frac, _ = _fly(Perturbation(latency=0.014), acts)  # 1 step and 2 of 5 substeps
    two, _ = _fly(Perturbation(latency=0.02), acts)
    k = 6
    assert two[k, 0, 5] < frac[k, 0, 5] < one[k, 0, 5]


def test_wind_with_drag_pushes_a_hovering_vehicle_downwind():
    traj, _ = _fly(Perturbation(drag=0.5, wind=3.0, wind_dir=90.0), steps=100)
    # v_y = W (1 - e^{-d t}) at hover attitude, t = 1 s
    np.testing.assert_allclose(traj[-1, 0, 4], 3.0 * (1 - np.exp(-0.5)), rtol=1e-6)
    assert traj[-1, 0, 1] > 0.5 and abs(traj[-1, 0, 0]) < 1e-9
    still, _ = _fly(Perturbation(drag=0.5), steps=100)
    assert np.abs(still[-1, 0, :6]).max() < 1e-12  # drag alone does nothing at rest


def test_gusts_are_seeded_and_have_their_intensity():
    p = Perturbation(drag=0.5, gust=1.0, gust_tau=0.5)
    a, sim = _fly(p, n=400, steps=50, seed=3)
    b, _ = _fly(p, n=400, steps=50, seed=3)
    c, _ = _fly(p, n=400, steps=50, seed=4)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert sim.plant is not None
    assert 0.85 < sim.plant.gust.std() < 1.15  # stationary OU: std = intensity


def test_observation_noise_leaves_true_state_and_is_seeded():
    p = Perturbation(pos_noise=0.02, vel_noise=0.05, att_noise=np.deg2rad(1.0), rate_noise=0.1, pos_bias=0.1)
    true, sim = _fly(p, n=500, steps=5, seed=1)
    nominal, _ = _fly(None, n=500, steps=5)
    assert np.array_equal(true, nominal)  # the physics never sees the noise
    obs = sim.observe()
    assert np.array_equal(obs, sim.observe())  # one draw per step
    assert not np.array_equal(obs, sim.state)
    err = obs - sim.state
    np.testing.assert_allclose(np.linalg.norm(err[:, :3].mean(0)), 0.0, atol=0.02)
    assert 0.09 < np.linalg.norm(err[:, :3], axis=1).mean() < 0.12  # the 0.1 m bias dominates
    assert 0.04 < err[:, 3:6].std() < 0.06
    R = obs[:, 6:15].reshape(-1, 3, 3)
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    _, sim2 = _fly(p, n=500, steps=5, seed=1)
    assert np.array_equal(sim2.observe(), obs)


def test_per_vehicle_values():
    p = Perturbation(mass=np.array([1.0, 1.1, 1.2]))
    traj, _ = _fly(p, n=3, steps=100)
    np.testing.assert_allclose(traj[-1, :, 5], GRAVITY / np.array([1.0, 1.1, 1.2]) - GRAVITY, rtol=1e-6, atol=1e-9)
    with pytest.raises(UserError, match="one per vehicle"):
        BatchedQuadrotor(P, 2, perturbation=p)


def test_reset_rows_restarts_only_those_vehicles():
    sim = BatchedQuadrotor(P, 2, perturbation=Perturbation(latency=0.03))
    for _ in range(5):
        sim.step(np.array([[GRAVITY + 5, 0, 0, 0]] * 2))
    sim.reset(rows=np.array([1]))
    assert sim.plant is not None
    lines = sim.plant.buf[:, 0, :]
    assert (lines[:, 1] == GRAVITY).all() and (lines[:, 0] == GRAVITY + 5).any()


# ----------------------------------------------------------------------------- parsing
@pytest.mark.parametrize(
    "text, match",
    [
        ("weight=1.2", "unknown perturbation 'weight'"),
        ("mass=-1.2", "mass must be > 0"),
        ("mass=0", "mass must be > 0"),
        ("latency=-0.01", "latency must be >= 0"),
        ("latency=0.5", "latency must be <= 0.2 s"),
        ("mass", "expected NAME=VALUE"),
        ("mass=heavy", "not a number"),
        ("mass=1.1,mass=1.2", "given twice"),
        ("wind=3", "give drag=D"),
        ("drag=nan", "finite"),
    ],
)
def test_parse_errors_are_one_line(text, match):
    with pytest.raises(UserError, match=match) as e:
        Perturbation.parse(text)
    assert "\n" not in str(e.value)


def test_parse_roundtrip_and_slug():
    p = Perturbation.parse(" mass=1.2, latency=0.02 ,drag=0.5,wind=3")
    assert p == Perturbation(mass=1.2, latency=0.02, drag=0.5, wind=3.0)
    assert Perturbation.parse(p.text()) == p
    assert p.slug() == "mass1.2-latency0.02-drag0.5-wind3"
    assert Perturbation().slug() == "nominal" and Perturbation().nominal


# ----------------------------------------------------------------------------- env and eval
def test_env_observes_noisy_state_and_judges_true_one():
    from aerohrl.envs.reach import QuadrotorReachVectorEnv

    env = QuadrotorReachVectorEnv(4, perturbation=Perturbation(pos_bias=0.5), perturb_seed=2, autoreset=False)
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(np.linalg.norm(obs["observation"][:, :3] - obs["achieved_goal"][:, :3], axis=1), 0.5)
    obs, *_ = env.step(np.tile(HOVER, (4, 1)))
    assert np.array_equal(obs["achieved_goal"], env.sim.state[:, :15])
    np.testing.assert_allclose(np.linalg.norm(obs["observation"][:, :3] - env.sim.state[:, :3], axis=1), 0.5)
    again, _ = env.reset(seed=0)  # a seeded reset replays the biases
    first, _ = QuadrotorReachVectorEnv(4, perturbation=Perturbation(pos_bias=0.5), perturb_seed=2).reset(seed=0)
    assert np.array_equal(again["observation"], first["observation"])


def test_maze_env_flies_perturbed():
    from aerohrl.envs.maze import QuadrotorMazeVectorEnv

    env = QuadrotorMazeVectorEnv(2, maze="medium", perturbation=Perturbation(mass=1.2, pos_noise=0.01), autoreset=False)
    nominal = QuadrotorMazeVectorEnv(2, maze="medium", autoreset=False)
    for e in (env, nominal):
        e.reset(seed=0)
    obs, *_ = env.step(np.tile(HOVER, (2, 1)))
    nominal.step(np.tile(HOVER, (2, 1)))
    assert (env.sim.state[:, 5] < nominal.sim.state[:, 5] - 0.01).all()  # heavier: sinks against the nominal
    assert not np.array_equal(obs["observation"], env.sim.state)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    import torch

    from aerohrl.algorithms.config import make_config
    from aerohrl.algorithms.synthetic import write_synthetic_dataset
    from aerohrl.algorithms.trainer import start_run

    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("perturb")
    ds = write_synthetic_dataset(root / "ds")
    tiny = dict(hidden=(16, 16), critic_hidden=(16, 16), batch_size=32, steps=20, log_every=10, checkpoint_every=20)
    cfg = make_config("cpu", algo="gcsl", dataset=str(ds), eval_every=20, eval_episodes=2, eval_horizon=20, **tiny)
    tr = start_run(cfg, root / "runs" / "gcsl", progress=False)
    tr.train()
    return root / "runs" / "gcsl"


def test_eval_perturb_end_to_end(tiny_run, capsys):
    import json

    from aerohrl.cli import main

    common = ["eval", "--run", str(tiny_run), "--episodes", "3", "--checkpoints", "1", "--quiet"]
    assert main([*common, "--task", "reach-desired", "--perturb", "mass=1.2,latency=0.02"]) == 0
    d = tiny_run / "eval" / "reach-desired-perturb-mass1.2-latency0.02"
    s = json.loads((d / "summary.json").read_text())
    assert s["options"]["perturb"] == "mass=1.2,latency=0.02" and s["episodes"] == 3
    assert main([*common, "--task", "ood", "--horizon", "30", "--perturb", "drag=0.5,wind=3,gust=1,pos_noise=0.02"]) == 0
    assert (tiny_run / "eval" / "ood-none-perturb-drag0.5-wind3-gust1-posnoise0.02" / "summary.json").exists()
    capsys.readouterr()
    try:
        code = main([*common, "--task", "reach-desired", "--perturb", "mass=-1"])
    except SystemExit as e:
        code = e.code
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0 and "mass must be > 0" in err


def test_robustness_study_tiny(tiny_run, tmp_path, capsys):
    import csv

    from aerohrl.cli import main

    out = tmp_path / "rob"
    argv = ["eval", "robustness", "--run", str(tiny_run), "--task", "reach-desired", "--episodes", "3", "--quiet"]
    argv += ["--axes", "mass,wind", "--values", "mass=1:1.5", "--values", "wind=0:2", "--full", "-o", str(out)]
    assert main(argv) == 0
    rows = list(csv.DictReader(open(out / "robustness.csv")))
    assert [(r["axis"], r["value"], r["curve"]) for r in rows] == [
        (a, v, c) for a, vs in (("mass", ("1", "1.5")), ("wind", ("0", "2"))) for v in vs for c in ("policy", "expert")
    ]
    assert rows[2]["perturb"] == "mass=1.5" and rows[6]["perturb"] == "drag=0.5,wind=2,gust=0.666667"
    md = (out / "robustness.md").read_text()
    assert "| mass | expert |" in md and "aerohrl eval robustness" in md
    assert (out / "robustness-mass.png").stat().st_size > 0 and (out / "robustness-wind.png").exists()
    assert (tiny_run / "eval" / "reach-desired-perturb-mass1.5" / "summary.json").exists()
    capsys.readouterr()
    try:
        code = main(["eval", "robustness", "--axes", "weight", "-o", str(out), "--quiet"])
    except SystemExit as e:
        code = e.code
    err = capsys.readouterr().err.strip()
    assert code == 2 and "unknown robustness axis 'weight'" in err and "\n" not in err


def test_robustness_groups_are_curves_with_their_runs(tiny_run, tmp_path):
    import csv

    from aerohrl.cli import main

    out = tmp_path / "rob"
    argv = ["eval", "robustness", "--group", f"nominal={tiny_run},{tiny_run}", "--no-expert", "--task", "reach-desired"]
    argv += ["--episodes", "3", "--quiet", "--axes", "combined", "--values", "combined=0:1", "--full", "-o", str(out)]
    assert main(argv) == 0
    rows = list(csv.DictReader(open(out / "robustness.csv")))
    assert [(r["axis"], r["value"], r["curve"]) for r in rows] == [("combined", "0", "nominal"), ("combined", "1", "nominal")]
    assert len(rows[1]["per_run"].split()) == 2  # one value per run of the group
    assert rows[1]["perturb"].startswith("mass=1.2,thrust=0.85,motor_tau=2,latency=0.02,drag=0.5,wind=3,gust=1")
    assert "nominal = task reach-desired, mean over 2 run(s)" in (out / "robustness.md").read_text()


@pytest.mark.parametrize(
    "items, match",
    [(["nominal"], "expected LABEL=RUN"), (["a=x", "a=y"], "is taken"), (["expert=x"], "is taken"), (["=x"], "expected")],
)
def test_robustness_group_errors_are_one_line(items, match):
    from aerohrl.eval.robustness import parse_groups

    with pytest.raises(UserError, match=match) as e:
        parse_groups(items)
    assert "\n" not in str(e.value)


def test_breaking_points():
    from aerohrl.eval.robustness import Point, breaking_points

    pts = [Point("mass", x, "expert", s, (s,), "") for x, s in ((1.0, 1.0), (1.2, 0.95), (1.3, 0.5), (1.5, 0.95))]
    assert breaking_points(pts) == {("mass", "expert"): 1.3}
    assert breaking_points(pts[:2]) == {("mass", "expert"): None}


# ----------------------------------------------------------------------------- domain randomisation
def test_randomized_build_records_each_episodes_vehicle(tmp_path):
    from aerohrl.datagen.build import ExpertData, build, episode_perturbations, episode_table, generate
    from aerohrl.datagen.spec import DatasetSpec, spec_hash

    nominal = DatasetSpec(goals=6, seed=3)
    spec = DatasetSpec(goals=6, seed=3, randomize="mass=0.8:1.2,latency=0:0.02,drag=0.2:0.5,wind=0:2")
    assert "randomize" not in nominal.to_dict() and spec_hash(spec) != spec_hash(nominal)  # earlier specs keep their hash
    pert = episode_perturbations(spec, 6)
    assert pert is not None and list(pert) == ["mass", "latency", "drag", "wind"]
    assert (0.8 <= pert["mass"]).all() and (pert["mass"] <= 1.2).all() and len(set(pert["mass"])) == 6
    a, b, c = generate(spec, progress=False), generate(spec, progress=False), generate(nominal, progress=False)
    assert isinstance(a, ExpertData) and np.array_equal(a.state, b.state)  # seeded
    assert not np.array_equal(a.state, c.state) and np.array_equal(a.goal_vec, c.goal_vec)  # same goals, other vehicles
    table = episode_table(a)
    np.testing.assert_array_equal(table["perturb_mass"].to_numpy(), pert["mass"])
    assert "perturb_mass" not in episode_table(c).column_names
    res = build(spec, tmp_path, progress=False, log=lambda *x: None)
    assert res.created and res.episodes == 6
    import pyarrow.parquet as pq

    from aerohrl.datagen.build import EPISODES_FILE

    written = pq.read_table(res.path / EPISODES_FILE)
    np.testing.assert_array_equal(written["perturb_latency"].to_numpy(), pert["latency"])


@pytest.mark.parametrize(
    "text, match",
    [
        ("weight=0.8:1.2", "unknown perturbation 'weight'"),
        ("mass=1.2:0.8", "need LO <= HI"),
        ("mass=-1:1", "mass must be > 0"),
        ("latency=0:0.5", "latency must be <= 0.2"),
        ("mass=a:b", "not LO:HI numbers"),
    ],
)
def test_randomize_errors_are_one_line(text, match):
    from aerohrl.datagen.spec import DatasetSpec

    with pytest.raises(UserError, match=match) as e:
        DatasetSpec(goals=4, randomize=text)
    assert "\n" not in str(e.value)


def test_randomized_dataset_card_names_the_ranges(tmp_path):
    from aerohrl.datagen.build import build
    from aerohrl.datagen.spec import DatasetSpec

    res = build(DatasetSpec(goals=3, seed=5, randomize="thrust=0.9:1.1"), tmp_path, progress=False, log=lambda *x: None)
    card = (res.path / "README.md").read_text()
    assert "domain randomisation" in card and "thrust 0.9..1.1" in card


def test_robust_bounds_relaxing_a_tolerance_never_lowers_the_expert(tiny_run, capsys):
    """experiments/robust_bounds.py: the expert under the goal test, then one tolerance x k at a time."""
    from conftest import load_experiment

    rb = load_experiment("robust_bounds")
    (row,) = rb.bounds(tiny_run, ["drag=0.5,wind=3"], 3.0, 4, 0)
    assert row["perturb"] == "drag=0.5,wind=3"
    assert all(0 <= row[k] <= 1 and row[k] >= row["as is"] for k in ("position", "velocity", "attitude"))
    assert rb.main(["--run", str(tiny_run), "--perturb", "weight=2"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("robust_bounds: error: unknown perturbation 'weight'") and "\n" not in err
    # another expert recipe on the same goals: the observer holds a heavier vehicle's goals
    (plain,) = rb.bounds(tiny_run, ["mass=1.2"], 2.0, 40, 0)
    (other,) = rb.bounds(tiny_run, ["mass=1.2"], 2.0, 40, 0, {"disturbance_observer": 0.5})
    assert other["as is"] >= plain["as is"] + 0.15
    assert rb.main(["--run", str(tiny_run), "--perturb", "mass=1.1", "--expert-set", "pilot=7"]) == 2
    assert "--expert-set pilot: not a dataset spec field" in capsys.readouterr().err


def test_runs_of_one_dataset_share_one_copy(tiny_run, tmp_path):
    """load_run_dataset with a cache: the seeds of a recipe load their dataset once."""
    import shutil

    from aerohrl.eval.harness import load_run_dataset

    twin = tmp_path / "twin"
    shutil.copytree(tiny_run, twin)
    cache: dict = {}
    a, b = load_run_dataset(tiny_run, cache=cache), load_run_dataset(twin, cache=cache)
    assert a[0] is b[0] and len(cache) == 1
    assert load_run_dataset(tiny_run)[0] is not a[0]  # no cache: a copy of its own
