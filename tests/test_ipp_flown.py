"""Primitives flown in the 6-DoF simulator by the geometric controller."""

import numpy as np
import pytest

from aerohrl.errors import UserError
from aerohrl.ipp.baselines import make_planner
from aerohrl.ipp.cli import main
from aerohrl.ipp.env import EnvConfig, SearchEnv, semantic_config
from aerohrl.ipp.flown import FlownEnv, create_flown_env
from aerohrl.ipp.lattice import default_lattice
from aerohrl.ipp.world import sample_worlds


@pytest.fixture(scope="module")
def lat():
    return default_lattice()


def _fresh(lat, n=1):
    cfg = EnvConfig(budget=1500.0)
    env = FlownEnv(cfg, lat)
    env.reset(sample_worlds(cfg.world, 1000, range(n)))
    return env


def _sets(env, lat, pr, samples, sval, row=0):
    off, lev = env.flown_measurements(np.array([row]), samples[[row]], sval[[row]])
    flown = sorted(map(tuple, off[0][lev[0] >= 0].tolist()))
    ideal = sorted(map(tuple, lat.meas_off[pr][lat.meas_level[pr] >= 0].astype(int).tolist()))
    return flown, ideal


def test_flown_primitives_from_hover_sense_what_the_lattice_says(lat):
    """The controller tracks every hover-start primitive to within centimetres, so the
    flown path visits exactly the cells of the lattice's sensing list (all primitives
    flown at once, one vehicle each)."""
    prims = lat.edges[0][lat.edges[0] >= 0]
    env = _fresh(lat, len(prims))
    samples, sval, emax, rms = env.fly(np.arange(len(prims)), prims)
    assert np.all(emax < 0.05) and np.all(rms <= emax)
    for j, pr in enumerate(prims):
        flown, ideal = _sets(env, lat, pr, samples, sval, j)
        assert flown == ideal, j


def test_sensing_follows_the_flown_path_not_the_ideal_one(lat):
    """Start the vehicle 1 m east of its cell: the reference pulls it back, so early
    samples are displaced and the flown measurement list differs from the ideal one."""
    env = _fresh(lat)
    s = env.state.copy()
    s[0, 0] += 1.0
    env.state = env.sim.reset(s)
    pr = next(lat.edges[0, a] for a in range(lat.n_actions) if lat.edges[0, a] >= 0)
    samples, sval, emax, _ = env.fly(np.array([0]), np.array([pr]))
    assert emax[0] > 0.5  # the 1 m offset is a tracking error
    flown, ideal = _sets(env, lat, pr, samples, sval)
    assert flown != ideal
    assert max(x for x, _ in flown) > max(x for x, _ in ideal)  # the footprint was further east


def test_flown_episode_matches_ideal_and_reports_tracking(lat):
    cfg = EnvConfig(budget=1500.0)
    out = {}
    for cls in (SearchEnv, FlownEnv):
        env = cls(cfg, lat)
        env.reset(sample_worlds(cfg.world, 1000, range(2)))
        pl = make_planner("dp", env)
        while not env.done.all():
            env.step(pl.act())
        out[cls.__name__] = env
    m_i, m_f = out["SearchEnv"].metrics(), out["FlownEnv"].metrics()
    assert np.all(np.abs(m_f["search_efficiency"] - m_i["search_efficiency"]) <= 2.0)
    assert np.all(m_f["track_max_m"] < 0.05) and np.all(m_f["track_rms_m"] > 0)
    tt = out["FlownEnv"].tracking_table()
    assert len(tt) == m_f["primitives"].sum() and np.all(tt[:, 1] >= tt[:, 2])
    # the flown vehicle ends where the lattice says (the reference is continuous)
    env = out["FlownEnv"]
    np.testing.assert_allclose(env.state[:, :2], env.pos, atol=0.05)


def test_execution_mode_errors(lat, capsys):
    with pytest.raises(UserError, match="unknown execution mode"):
        create_flown_env(EnvConfig(), lat, "skill-free")
    with pytest.raises(UserError, match="target search"):
        create_flown_env(semantic_config(map_size=64), lat, "flown")
    assert main(["bench", "--execution", "teleport", "--envs", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "unknown execution mode 'teleport'" in err


def test_cli_ideal_vs_flown_table(tmp_path, capsys):
    assert (
        main(
            [
                "bench",
                "--planner",
                "greedy",
                "--envs",
                "2",
                "--budget",
                "1500",
                "--execution",
                "ideal,flown",
                "--out",
                str(tmp_path),
                "--quiet",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "flown − ideal" in out and "tracking max mm" in out
    assert (tmp_path / "ipp_execution.md").is_file()


class _GoalSeeker:
    """A stand-in goal-conditioned skill for CI (no trained run there): the geometric
    controller steered at the goal's position and velocity."""

    def __init__(self):
        from aerohrl.datagen.expert import GeometricController
        from aerohrl.sim import get_preset

        self.ctrl = GeometricController(get_preset("hummingbird"))
        self.calls = 0

    def __call__(self, states, goals):
        self.calls += 1
        z = np.zeros((len(states), 3))
        return self.ctrl(states, goals[:, 0:3], goals[:, 3:6], z, z)


def test_skill_execution_legs_and_tracking(lat):
    from aerohrl.ipp.flown import SKILL_SPACING, SkillEnv

    cfg = EnvConfig(budget=1200.0)
    skill = _GoalSeeker()
    env = SkillEnv(cfg, lat, skill)
    env.reset(sample_worlds(cfg.world, 1000, range(2)))
    pl = make_planner("greedy", env)
    while not env.done.all():
        env.step(pl.act())
    m = env.metrics()
    legs = env.leg_table()
    tt = env.tracking_table()
    # every primitive is cut into ceil(T / 1 s) legs, each ends near its goal or times out
    n_legs = (
        sum(int(np.ceil(lat.prim_T[int(p)] / SKILL_SPACING - 1e-9)) for row in env.trace_prim for p in row if p >= 0)
        if env.trace_prim
        else None
    )
    assert len(legs) == n_legs == len(legs)
    # a leg ends when its goal is reached (x 2.5 tolerance) or at its timeout (>= 1 s)
    assert legs[:, 1].any() and np.all(legs[:, 2] > 0)
    assert np.all((legs[:, 1] == 1) | (legs[:, 2] >= 1.0 + 1e-9))
    assert np.all(legs[:, 0] <= legs[:, 1])  # strict success implies near success
    assert len(tt) == m["primitives"].sum() and np.all(tt[:, 1] >= tt[:, 2])
    assert np.all(m["skill_flight_s"] > 0) and skill.calls > 0
    assert np.all((m["search_efficiency"] >= 0) & (m["search_efficiency"] <= 100))


def test_skill_run_errors(tmp_path, capsys):
    from aerohrl.ipp.flown import load_skill

    with pytest.raises(UserError, match="needs --skill-run"):
        load_skill(None)
    with pytest.raises(UserError, match="no skill policy run"):
        load_skill(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(UserError, match="no checkpoints"):
        load_skill(tmp_path / "empty")
    assert main(["bench", "--execution", "skill", "--skill-run", str(tmp_path / "x"), "--envs", "1"]) == 2
    assert "no skill policy run" in capsys.readouterr().err
    assert main(["bench", "--skill-run", str(tmp_path), "--envs", "1"]) == 2
    assert "--skill-run needs --execution skill" in capsys.readouterr().err


SKILL_RUN = "/work/main/runs/recipes/noise-n25000-s0-30k"


@pytest.mark.slow
@pytest.mark.skipif(not __import__("os").path.isdir(SKILL_RUN), reason="needs the chapter-3 run")
def test_learned_skill_flies_primitives(lat):
    from aerohrl.ipp.flown import SkillEnv, load_skill

    pf, _ = load_skill(SKILL_RUN)
    cfg = EnvConfig(budget=800.0)
    env = SkillEnv(cfg, lat, pf)
    env.reset(sample_worlds(cfg.world, 1000, [0]))
    pl = make_planner("greedy", env)
    while not env.done.all():
        env.step(pl.act())
    assert env.leg_table()[:, 1].mean() > 0.5 and env.tracking_table()[:, 2].max() < 0.5
