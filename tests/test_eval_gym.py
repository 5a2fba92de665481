"""The Gymnasium environment aerohrl/QuadrotorReach-v0."""

import gymnasium as gym
import numpy as np
import pytest

import aerohrl  # noqa: F401  (registers the environments)
from aerohrl import task
from aerohrl.envs.episodes import hover_states
from aerohrl.envs.reach import ENV_ID, QuadrotorReachVectorEnv

HOVER = [9.81, 0.0, 0.0, 0.0]


def test_registered_and_single_env_passes_checker():
    from gymnasium.utils.env_checker import check_env

    env = gym.make(ENV_ID)
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert set(obs) == {"observation", "achieved_goal", "desired_goal"}
    assert obs["observation"].shape == (18,) and obs["desired_goal"].shape == (15,)
    p = np.abs(obs["desired_goal"][:3])
    assert p.min() >= 1.0 and p.max() <= 2.0  # rho_D by default


def test_vector_env_batched_reward_termination_truncation():
    env = gym.make_vec(ENV_ID, num_envs=3, vectorization_mode="vector_entry_point", horizon=4)
    assert isinstance(env.unwrapped, QuadrotorReachVectorEnv)
    goals = hover_states(3)[:, :15]
    goals[1, 0] = 5.0  # far away
    goals[2, 0] = 0.1  # within 0.15 m
    obs, _ = env.reset(seed=0, options={"goals": goals})
    seen_term, seen_trunc, rewards = [], [], []
    for _ in range(4):
        obs, r, term, trunc, info = env.step(np.tile(HOVER, (3, 1)))
        seen_term.append(term.copy())
        seen_trunc.append(trunc.copy())
        rewards.append(r.copy())
    assert rewards[0].tolist() == [1.0, 0.0, 1.0]
    assert seen_term[0].tolist() == [True, False, True]  # hover at the goal: reached at once
    assert seen_trunc[3].tolist() == [False, True, False]  # the far one runs out of steps
    # compute_reward is HER's batched relabelling reward: the goal-reached test
    ag = np.stack([obs["achieved_goal"]] * 2)
    dg = np.stack([obs["achieved_goal"], obs["achieved_goal"] + 1.0])
    assert np.array_equal(env.unwrapped.compute_reward(ag, dg, {}), [[1, 1, 1], [0, 0, 0]])
    assert np.array_equal(env.unwrapped.compute_reward(ag, dg, {}), task.goal_reached(ag, dg).astype(float))


def test_next_step_autoreset_and_disabled():
    env = QuadrotorReachVectorEnv(2, horizon=2, goals=hover_states(1)[:, :15] + np.r_[3.0, np.zeros(14)])
    env.reset(seed=1)
    for _ in range(2):
        obs, r, term, trunc, _ = env.step(np.tile(HOVER, (2, 1)))
    assert trunc.all()
    obs, r, term, trunc, _ = env.step(np.tile([30.0, 5, 5, 5], (2, 1)))  # the reset step ignores the action
    assert np.allclose(obs["observation"], hover_states(2)) and not (term | trunc).any() and (env.elapsed == 0).all()
    frozen = QuadrotorReachVectorEnv(2, horizon=2, autoreset=False)
    frozen.reset(seed=1)
    for _ in range(3):
        _, _, term, trunc, _ = frozen.step(np.tile(HOVER, (2, 1)))
    assert not trunc.any() and frozen.done.all()  # reported once; the vehicles keep flying


def test_set_desired_goals_restarts_the_leg():
    env = QuadrotorReachVectorEnv(2, horizon=3, autoreset=False)
    env.reset(seed=0, options={"goals": np.full((2, 15), 3.0)})
    for _ in range(3):
        env.step(np.tile(HOVER, (2, 1)))
    assert env.done.all()
    obs = env.set_desired_goals(hover_states(2)[:, :15], mask=np.array([True, False]), horizons=10)
    assert np.allclose(obs["desired_goal"][0], hover_states(1)[0, :15]) and env.horizons.tolist() == [10, 3]
    _, _, term, _, _ = env.step(np.tile(HOVER, (2, 1)))
    assert term.tolist() == [True, False]


@pytest.mark.parametrize("tol", [1.0, 2.5])
def test_tolerance_scale(tol):
    env = QuadrotorReachVectorEnv(1, autoreset=False, tolerance_scale=tol)
    g = hover_states(1)[:, :15].copy()
    g[0, 0] = 0.3  # 0.3 m away: reached only with tolerances x 2.5
    env.reset(options={"goals": g})
    _, _, term, _, info = env.step(np.array([HOVER]))
    assert bool(term[0]) == (tol == 2.5) and not info["is_success"][0]


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_actions_are_refused_not_turned_into_motors_off(bad):
    from aerohrl.envs.reach import NonFiniteAction

    env = QuadrotorReachVectorEnv(3, horizon=50)
    env.reset(seed=0)
    before = env.state.copy()
    a = np.tile(HOVER, (3, 1))
    a[1, 0] = bad
    with pytest.raises(NonFiniteAction, match=r"vehicle\(s\) \[1\].*step refused"):
        env.step(a)
    assert np.array_equal(env.state, before) and (env.elapsed == 0).all()  # nothing flew
    single = gym.make(ENV_ID)
    single.reset(seed=0)
    with pytest.raises(ValueError):  # NonFiniteAction is a ValueError for Gymnasium code
        single.step(np.array([bad, 0.0, 0.0, 0.0]))
    # finite but huge: clipped to the action space (full thrust), as documented
    _, _, _, _, info = env.step(np.tile([1e30, 0.0, 0.0, 0.0], (3, 1)))
    assert not info["diverged"].any() and (env.state[:, 5] > 0).all()  # climbing: the motors are on
