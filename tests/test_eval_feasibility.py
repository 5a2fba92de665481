"""eval/feasibility.py: which goals the expert reaches directly and through a run-up (and
experiments/feasibility_study.py, one ring's rates)."""

import numpy as np
import pytest

from aerohrl.datagen import reference
from aerohrl.datagen.goals import flat_attitude
from aerohrl.errors import UserError
from aerohrl.eval import feasibility as fz
from conftest import load_experiment


def _goals(pos, vel, acc):
    pos, vel, acc = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (pos, vel, acc))
    return {"pos": pos, "vel": vel, "acc": acc, "R": flat_attitude(acc)}


# inside rho_D; |v_i| = 6 m/s 1.5 m away; a gentle second goal
IN_RHO = ([1.5, -1.2, 1.8], [1.0, -0.5, 0.8], [1.0, 0.5, -1.0])
FAST = ([1.5, 0.0, 0.0], [6.0, 0.0, 0.0], [0.0, 0.0, 0.0])
# 4.2 s. Given 4.4 s the min-time quintic from rest reaches FAST directly (it swings back
# first, a run-up of its own); within 4.2 s only a run-up waypoint's two legs do (3.9 s)
HORIZON = 420


@pytest.fixture(scope="module")
def batch():
    g = _goals(*(np.array([a, b]) for a, b in zip(IN_RHO, FAST)))
    return fz.feasibility(g, HORIZON, runup="all", record_every=1)


def test_goal_in_rho_d_is_directly_feasible(batch):
    assert batch.direct[0] and batch.direct_near[0] and batch.feasible[0]
    assert batch.direct_ref[0] and 0 < batch.T_direct[0] < HORIZON / 100
    assert batch.a_max[0] == fz.A_SPEC  # |a_i| <= 5 / 1.2: the dataset's bound


def test_fast_close_goal_needs_a_runup(batch):
    """6 m/s at 1.5 m: at the bound a_max = 5 a straight run needs 3.6 m; no min-time quintic
    from rest gets there within 4.2 s, a run-up waypoint's two legs do."""
    assert not batch.direct_ref[1] and not batch.direct[1] and batch.direct_step[1] == -1
    assert batch.runup[1] and batch.feasible[1]
    w = batch.runup_waypoint[1]
    assert w[0] <= 1.5 - 3.6 + 1e-9 and abs(w[2]) < 1e-9  # behind the goal along v (lateral: along -y)
    opt = batch.runup_option[1]
    assert 0 <= opt < len(fz.DISTANCE_FACTORS) * len(fz.LATERAL) * len(fz.RUNUP_STRETCH)
    xf = np.stack([np.array(FAST[0]), np.array(FAST[1]), np.array(FAST[2])], axis=-1)[None]
    np.testing.assert_allclose(w, fz.runup_waypoints(xf, np.array([5.0]))[0, opt // len(fz.RUNUP_STRETCH)])
    assert 0 < batch.runup_step[1] <= HORIZON
    T1, T2 = batch.runup_T[1]
    assert T1 + T2 <= HORIZON / 100
    # the recorded flight reaches the waypoint's neighbourhood, then passes the goal
    path = batch.positions_runup[:, 1]
    assert np.nanmin(np.linalg.norm(path - w, axis=1)) < 0.3
    assert np.nanmin(np.linalg.norm(path - FAST[0], axis=1)) < 0.15
    assert batch.positions_direct.shape == (HORIZON + 1, 2, 3)


def test_batch_equals_per_goal(batch):
    for i, goal in enumerate((IN_RHO, FAST)):
        one = fz.feasibility(_goals(*goal), HORIZON, runup="all")
        for k in ("direct", "direct_near", "runup", "runup_near", "feasible", "runup_option", "direct_step"):
            assert getattr(one, k)[0] == getattr(batch, k)[i], k
        np.testing.assert_allclose(one.T_direct[0], batch.T_direct[i])


def test_runup_failed_mode_skips_direct_goals():
    g = _goals(*(np.array([a, b]) for a, b in zip(IN_RHO, FAST)))
    r = fz.feasibility(g, HORIZON, runup="failed")
    assert r.direct[0] and not r.runup[0] and r.runup_option[0] == -1
    assert r.runup[1] and r.feasible.all()
    r = fz.feasibility(g, HORIZON, runup="none")
    assert not r.runup.any() and list(r.feasible) == [True, False]


def test_per_goal_bound_matches_reference_min_time():
    rng = np.random.default_rng(3)
    xf = np.stack([rng.uniform(-3, 3, (20, 3)), rng.uniform(-3, 3, (20, 3)), rng.uniform(-4, 4, (20, 3))], axis=-1)
    x0 = np.zeros_like(xf)
    T, c, ok = fz.min_time(x0, xf, np.full(20, 5.0), 4.0)
    T_ref, c_ref, ok_ref = reference.min_time(x0, xf, a_max=5.0, t_hi=4.0)
    np.testing.assert_array_equal(ok, ok_ref)
    np.testing.assert_allclose(T, T_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(c, c_ref, rtol=1e-12, atol=1e-12)


def test_goal_bounds_rule():
    acc = np.array([[1.0, 0, 0], [0, -8.0, 0], [0, 0, 20.0]])
    np.testing.assert_allclose(fz.goal_bounds(acc), [5.0, 9.6, 12.0])
    np.testing.assert_allclose(fz.goal_bounds(acc, 7.0), [7.0, 7.0, 7.0])


def test_runup_waypoints_behind_goal():
    xf = np.zeros((1, 3, 3))
    xf[0, :, 0] = [1.0, 2.0, 0.5]
    xf[0, :, 1] = [3.0, 0.0, 4.0]  # |v| = 5, max|v_i| = 4
    xf[0, :, 2] = [0.0, 2.0, 0.0]  # perpendicular to v: lateral offsets along +y
    W = fz.runup_waypoints(xf, np.array([5.0]), factors=(1.0, 2.0), lateral=(0.0, 0.5))
    d0 = 5 * 4 / (2 * 5.0)
    vhat = np.array([0.6, 0.0, 0.8])
    np.testing.assert_allclose(W[0, 0], xf[0, :, 0] - d0 * vhat)
    np.testing.assert_allclose(W[0, 1], xf[0, :, 0] - d0 * vhat + 0.5 * d0 * np.array([0, 1.0, 0]))
    np.testing.assert_allclose(W[0, 2], xf[0, :, 0] - 2 * d0 * vhat)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(horizon_steps=0), "horizon_steps"),
        (dict(horizon_steps=1.5), "horizon_steps"),
        (dict(vehicle="nope"), "vehicle"),
        (dict(a_max=-1.0), "a_max"),
        (dict(runup="some"), "runup"),
        (dict(fps=0), "fps"),
        (dict(factors=(1.0, -2.0)), "factors"),
        (dict(record_every=-1), "record_every"),
        (dict(stretch=(1.5, 2.0)), "stretch"),
        (dict(lateral=()), "lateral"),
    ],
)
def test_bad_arguments(kwargs, match):
    args = dict(goals=_goals(*IN_RHO), horizon_steps=100) | kwargs
    with pytest.raises(ValueError, match=match):
        fz.feasibility(**args)


def test_bad_goals():
    g = _goals(*IN_RHO)
    with pytest.raises(UserError, match="acc"):
        fz.feasibility({k: v for k, v in g.items() if k != "acc"}, 100)
    with pytest.raises(UserError, match="NaN"):
        fz.feasibility(g | {"pos": np.array([[np.nan, 0, 0]])}, 100)
    with pytest.raises(UserError, match="rotation"):
        fz.feasibility(g | {"R": 2 * g["R"]}, 100)
    with pytest.raises(UserError, match="disagree"):
        fz.feasibility(g | {"vel": np.zeros((2, 3))}, 100)


def test_cli(capsys, tmp_path):
    study = load_experiment("feasibility_study")
    pages = ["--results-dir", str(tmp_path)]
    assert study.main(["--family", "velocity", "--ring", "3", "--n", "4", "--runup", "none", *pages]) == 0
    out = capsys.readouterr().out
    assert "velocity ring 3" in out and "direct" in out and "feasible" in out
    (page,) = tmp_path.glob("*-feasibility-velocity-3.md")
    text = page.read_text()
    assert "python experiments/feasibility_study.py --family velocity --ring 3" in text and out.strip() in text
    assert study.main(["--family", "speed", "--ring", "1", "--n", "4", *pages]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown goal family" in err
    assert study.main(["--family", "velocity", "--ring", "9", "--n", "4", *pages]) == 2
    assert study.main(["--family", "velocity", "--ring", "1", "--n", "0", *pages]) == 2


def test_ring_feasibility_is_cached(tmp_path):
    from aerohrl.eval.families import parse_ring

    ring = parse_ring("velocity", "1")
    spec = {"fps": 100}
    a = fz.ring_feasibility(ring, 3, spec, cache=tmp_path)
    (f,) = tmp_path.glob("feasibility-*-n3.json")
    assert set(a) == {"direct", "runup", "feasible"} and all(v.shape == (3,) for v in a.values())
    assert not (a["runup"] & a["direct"]).any() and np.array_equal(a["feasible"], a["direct"] | a["runup"])
    f.write_text('{"direct": [true], "runup": [false], "feasible": [true]}')  # read back, not flown again
    assert fz.ring_feasibility(ring, 3, spec, cache=tmp_path)["direct"].tolist() == [True]
