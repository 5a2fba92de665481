"""Desired-goal sampling and the flatness attitude map (aerohrl.datagen.goals)."""

import numpy as np
import pytest

from aerohrl import task
from aerohrl.datagen.goals import GRAVITY, flat_attitude, goal_vectors, sample_goals
from aerohrl.errors import UserError


def test_shapes_ranges_and_dtypes():
    g = sample_goals(np.random.default_rng(0), 500)
    assert set(g) == {"pos", "vel", "acc", "R"}
    for k, shape in (("pos", (500, 3)), ("vel", (500, 3)), ("acc", (500, 3)), ("R", (500, 3, 3))):
        assert g[k].shape == shape and g[k].dtype == np.float64
    mag = np.abs(g["pos"])
    assert (mag >= 1.0).all() and (mag <= 2.0).all()
    # both signs occur on every axis, at roughly even odds
    frac_pos = (g["pos"] > 0).mean(axis=0)
    assert ((frac_pos > 0.4) & (frac_pos < 0.6)).all()
    assert (np.abs(g["vel"]) <= 2.5).all() and (np.abs(g["acc"]) <= 5.0).all()
    # the ranges are actually spanned
    assert g["vel"].min() < -2.3 and g["vel"].max() > 2.3 and g["acc"].min() < -4.5 and g["acc"].max() > 4.5


def test_deterministic_per_seed_and_ood_ranges():
    a = sample_goals(np.random.default_rng(7), 50)
    b = sample_goals(np.random.default_rng(7), 50)
    c = sample_goals(np.random.default_rng(8), 50)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    assert not np.array_equal(a["pos"], c["pos"])
    ood = sample_goals(np.random.default_rng(1), 200, pos_range=(2.0, 3.5))
    assert (np.abs(ood["pos"]) >= 2.0).all() and (np.abs(ood["pos"]) <= 3.5).all()


def test_attitude_is_flat_output_map():
    g = sample_goals(np.random.default_rng(1), 300)
    R = g["R"]
    eye = np.broadcast_to(np.eye(3), R.shape)
    np.testing.assert_allclose(np.swapaxes(R, -1, -2) @ R, eye, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    f = g["acc"] + np.array([0.0, 0.0, GRAVITY])
    np.testing.assert_allclose(R[..., :, 2], f / np.linalg.norm(f, axis=1, keepdims=True), atol=1e-12)
    # yaw 0: y_B is orthogonal to x_C = e1, and x_B points forward
    np.testing.assert_allclose(R[..., 0, 1], 0.0, atol=1e-12)
    assert (R[..., 0, 0] > 0).all()


def test_flat_attitude_special_cases():
    np.testing.assert_allclose(flat_attitude(np.zeros((1, 3)))[0], np.eye(3), atol=1e-15)
    Rz = flat_attitude(np.zeros(3), yaw=np.pi / 2)  # any leading shape, here none
    np.testing.assert_allclose(Rz, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
    # per-row yaw; pure forward acceleration pitches the nose down about y_B
    R = flat_attitude(np.array([[3.0, 0, 0], [0, 0, 0]]), yaw=np.array([0.0, 0.3]))
    assert R.shape == (2, 3, 3)
    assert R[0, 0, 2] > 0 and abs(R[0, 1, 2]) < 1e-15
    np.testing.assert_allclose(R[1, :2, 0], [np.cos(0.3), np.sin(0.3)], atol=1e-15)
    with pytest.raises(UserError, match="free fall"):
        flat_attitude(np.array([[0.0, 0.0, -GRAVITY]]))
    with pytest.raises(UserError, match="parallel"):
        flat_attitude(np.array([[1.0, 0.0, -GRAVITY]]))
    with pytest.raises(UserError):
        flat_attitude(np.zeros((2, 2)))


def test_goal_vectors_layout():
    g = sample_goals(np.random.default_rng(2), 4)
    v = goal_vectors(g)
    assert v.shape == (4, task.GOAL_DIM) and v.dtype == np.float64
    np.testing.assert_array_equal(v[:, task.POS], g["pos"])
    np.testing.assert_array_equal(v[:, task.VEL], g["vel"])
    np.testing.assert_array_equal(v[:, task.ROT], g["R"].reshape(4, 9))
    assert v[0, 6 + 1] == g["R"][0, 0, 1]  # row-major: R01 follows R00
    assert task.goal_reached(v, v).all()
    with pytest.raises(UserError, match="key"):
        goal_vectors({"pos": g["pos"], "vel": g["vel"]})
    with pytest.raises(UserError, match="disagree"):
        goal_vectors({"pos": g["pos"], "vel": g["vel"][:3], "R": g["R"]})


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(n=0), "positive integer"),
        (dict(n=-3), "positive integer"),
        (dict(n=2.5), "positive integer"),
        (dict(n=True), "positive integer"),
        (dict(n=5, pos_range=(2.0, 1.0)), "empty or inverted"),
        (dict(n=5, vel_range=(1.0, 1.0)), "empty or inverted"),
        (dict(n=5, acc_range=(0.0, float("nan"))), "finite"),
        (dict(n=5, pos_range=(-1.0, 2.0)), "non-negative"),
        (dict(n=5, pos_range=(1.0,)), "two numbers"),
        (dict(n=5, yaw=float("inf")), "yaw"),
    ],
)
def test_bad_inputs(kwargs, match):
    n = kwargs.pop("n")
    with pytest.raises(UserError, match=match) as e:
        sample_goals(np.random.default_rng(0), n, **kwargs)
    assert "\n" not in str(e.value)


def test_needs_a_generator():
    with pytest.raises(UserError, match="Generator"):
        sample_goals(0, 3)
