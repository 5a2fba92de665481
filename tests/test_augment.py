"""Mirror augmentation: reflected flights are flights of the same vehicle (checked in the
simulator, rotor saturation included), the goal test is invariant, and the sampler
reflects state, goal, next state and action together."""

import numpy as np
import pytest
import torch

from aerohrl import task
from aerohrl.algorithms.augment import draw_reflections, mirror_action, mirror_goal, mirror_state
from aerohrl.sim import GRAVITY, BatchedQuadrotor, get_preset
from scipy.spatial.transform import Rotation

ALL_M = torch.tensor([[1.0, 1, 1], [-1, 1, 1], [1, -1, 1], [-1, -1, 1]])


def _start_states(n, rng):
    s = np.zeros((n, 18))
    s[:, 0:3] = rng.uniform(-1, 1, (n, 3))
    s[:, 3:6] = rng.uniform(-2, 2, (n, 3))
    R = Rotation.from_euler("xyz", rng.uniform(-0.4, 0.4, (n, 3))).as_matrix()
    s[:, 6:15] = R.reshape(n, 9)
    s[:, 15:18] = rng.uniform(-1, 1, (n, 3))
    return s


@pytest.mark.parametrize("preset", ["hummingbird", "crazyflie"])
def test_reflected_flight_is_a_flight(preset):
    rng = np.random.default_rng(0)
    n, steps = 8, 150
    s0 = _start_states(n, rng)
    # rough CTBR commands: thrust up to 2 g, rates up to 6 rad/s (rotors saturate)
    acts = np.zeros((steps, n, 4))
    acts[..., 0] = rng.uniform(0.3, 2.0, (steps, n)) * GRAVITY
    acts[..., 1:] = np.cumsum(rng.normal(0, 0.8, (steps, n, 3)), 0).clip(-6, 6)
    params = get_preset(preset)
    for m in ALL_M:
        mm = m.expand(n, 3)
        a, b = BatchedQuadrotor(params, n), BatchedQuadrotor(params, n)
        a.reset(s0)
        b.reset(mirror_state(torch.from_numpy(s0), mm).numpy())
        for t in range(steps):
            sa = a.step(acts[t])
            sb = b.step(mirror_action(torch.from_numpy(acts[t]), mm).numpy())
        np.testing.assert_allclose(sb, mirror_state(torch.from_numpy(sa), mm).numpy(), atol=1e-8)
        assert np.abs(sa - s0).max() > 1.0  # it flew somewhere


def test_reflections_are_involutions_and_keep_rotations():
    g = torch.Generator().manual_seed(0)
    m = draw_reflections(4000, g)
    assert set(map(tuple, m.unique(dim=0).tolist())) == set(map(tuple, ALL_M.tolist()))
    assert (m[:, :2] == -1).float().mean().item() == pytest.approx(0.5, abs=0.03)
    x = torch.from_numpy(_start_states(4000, np.random.default_rng(1)))
    y = mirror_state(x, m)
    torch.testing.assert_close(mirror_state(y, m), x)
    R = y[:, 6:15].reshape(-1, 3, 3)
    torch.testing.assert_close(R @ R.transpose(1, 2), torch.eye(3, dtype=R.dtype).expand_as(R))
    assert torch.allclose(torch.linalg.det(R), torch.ones(4000, dtype=R.dtype))
    # yaw 0 goals keep yaw 0 (the dataset's rho_D): the heading stays in the x-z plane
    Rg = Rotation.from_euler("ZYX", np.c_[np.zeros(50), np.random.default_rng(2).uniform(-0.5, 0.5, (50, 2))]).as_matrix()
    gl = torch.zeros(50, 15, dtype=torch.float64)
    gl[:, 6:15] = torch.from_numpy(Rg.reshape(50, 9))
    Rm = mirror_goal(gl, m[:50]).numpy()[:, 6:15].reshape(50, 3, 3)
    np.testing.assert_allclose(Rotation.from_matrix(Rm).as_euler("ZYX")[:, 0], 0.0, atol=1e-12)
    a = torch.randn(100, 4, dtype=torch.float64)
    torch.testing.assert_close(mirror_action(mirror_action(a, m[:100]), m[:100]), a)
    assert torch.equal(mirror_action(a, m[:100])[:, 0], a[:, 0])


def test_goal_test_is_invariant():
    rng = np.random.default_rng(3)
    s = torch.from_numpy(_start_states(2000, rng))
    g = s[:, :15] + torch.from_numpy(rng.normal(0, 0.1, (2000, 15)))
    g[:, 6:15] = torch.from_numpy(Rotation.from_euler("xyz", rng.uniform(-0.4, 0.4, (2000, 3))).as_matrix().reshape(2000, 9))
    m = draw_reflections(2000, torch.Generator().manual_seed(4)).to(torch.float64)
    before = task.goal_reached(s[:, :15], g)
    after = task.goal_reached(mirror_state(s, m)[:, :15], mirror_goal(g, m))
    assert 0 < before.sum() < 2000 and torch.equal(before, after)


def test_sampler_reflects_the_whole_transition():
    from aerohrl.algorithms.data import GoalBatchSampler, fit_normalizer, load_dataset
    from aerohrl.algorithms.synthetic import straight_columns

    data = load_dataset(straight_columns(n_eps=6, length=40))
    norm = fit_normalizer(data, 0.5)
    plain = GoalBatchSampler(data, norm, 512, 0.5, torch.Generator().manual_seed(0))
    aug = GoalBatchSampler(data, norm, 512, 0.5, torch.Generator().manual_seed(0), augment="mirror")
    b = aug.sample()
    idx = b["index"]
    st, nx = data.state[idx].double(), data.next_state[idx].double()
    # recover each sample's reflection from its position, then check every field
    m = torch.ones(512, 3, dtype=torch.float64)
    m[:, :2] = torch.where(st[:, :2].abs() > 1e-6, torch.sign(b["state"][:, :2].double() * st[:, :2]), 1.0)
    flips = (m[:, :2] == -1).any(1)
    assert 0.6 < flips.float().mean().item() < 0.9  # 3 of 4 reflections flip something
    torch.testing.assert_close(b["state"].double(), mirror_state(st, m), atol=1e-6, rtol=0)
    torch.testing.assert_close(b["next_state"].double(), mirror_state(nx, m), atol=1e-6, rtol=0)
    torch.testing.assert_close(
        norm.action_from_unit(b["action"]).double(), mirror_action(data.action[idx].double(), m), atol=1e-4, rtol=0
    )
    # rewards follow the reflected transition's own goal test
    torch.testing.assert_close(
        b["next", "reward"].squeeze(-1), task.goal_reached(b["next_state"][:, :15], b["goal"]).to(b["next", "reward"].dtype)
    )
    # with augmentation off the batch is the plain one
    assert torch.equal(
        plain.sample()["index"], GoalBatchSampler(data, norm, 512, 0.5, torch.Generator().manual_seed(0)).sample()["index"]
    )
