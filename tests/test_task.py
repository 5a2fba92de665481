"""The reach-task vocabulary: one goal-reached test for numpy and torch alike."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aerohrl import task


def _goal(p=(1.0, -2.0, 1.5), v=(0.5, 0.0, -1.0), rotvec=(0.1, -0.2, 0.3)):
    R = Rotation.from_rotvec(rotvec).as_matrix().reshape(9)
    return np.concatenate([p, v, R])


def _perturb(g, dp=0.0, dv=0.0, angle=0.0):
    out = g.copy()
    out[0] += dp
    out[4] += dv
    R = Rotation.from_rotvec([0.0, 0.0, angle]).as_matrix() @ g[6:15].reshape(3, 3)
    out[6:15] = R.reshape(9)
    return out


@pytest.mark.parametrize("field,limit", [("dp", 0.15), ("dv", 0.35), ("angle", 0.15)])
def test_each_tolerance_is_the_boundary(field, limit):
    g = _goal()
    inside = _perturb(g, **{field: limit * 0.99})
    outside = _perturb(g, **{field: limit * 1.01})
    assert task.goal_reached(inside, g)
    assert not task.goal_reached(outside, g)
    # near success: every tolerance x 2.5
    assert task.near_success(_perturb(g, **{field: limit * 2.4}), g)
    assert not task.near_success(_perturb(g, **{field: limit * 2.6}), g)


def test_goal_errors_match_construction():
    g = _goal()
    a = _perturb(g, dp=0.3, dv=-0.2, angle=0.4)
    dp, dv, ang = task.goal_errors(a, g)
    assert dp == pytest.approx(0.3) and dv == pytest.approx(0.2) and ang == pytest.approx(0.4, abs=1e-7)


def test_numpy_and_torch_agree_batched():
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(0)
    g = np.stack([_goal() for _ in range(200)])
    a = np.stack([_perturb(x, dp=d, dv=e, angle=f) for x, d, e, f in zip(g, *rng.uniform(0, 0.3, (3, 200)))])
    want = task.goal_reached(a, g)
    got = task.goal_reached(torch.as_tensor(a), torch.as_tensor(g)).numpy()
    assert 0 < want.sum() < 200
    np.testing.assert_array_equal(want, got)
    np.testing.assert_allclose(
        task.goal_errors(a, g)[2], task.goal_errors(torch.as_tensor(a), torch.as_tensor(g))[2].numpy(), atol=1e-9
    )


def test_policy_inputs_are_translation_invariant():
    s = np.concatenate([[3.0, -1.0, 2.0], [0.1, 0.2, 0.3], np.eye(3).reshape(9), [0.01, 0.02, 0.03]])
    g = _goal()
    o1, r1 = task.policy_inputs(s, g)
    shift = np.r_[np.array([5.0, 5.0, -5.0]), np.zeros(15)]
    o2, r2 = task.policy_inputs(s + shift, g + shift[:15])
    np.testing.assert_allclose(o1, o2)
    np.testing.assert_allclose(r1, r2)
    assert o1.shape == (task.OBS_DIM,) and r1.shape == (task.GOAL_DIM,)
    np.testing.assert_allclose(r1[:3], g[:3] - s[:3])
    assert math.isclose(task.achieved_goal(s)[0], 3.0)
