"""aerohrl/IPPSearch-v0: Gymnasium's env checker, the action mask, the vector env over
batched worlds, per-row autoreset, and a random-valid-action loop."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import aerohrl.ipp  # noqa: F401  (registers the id)
from aerohrl.ipp.gym_env import ENV_ID, IPPSearchEnv, IPPSearchVectorEnv


def test_registered_and_passes_env_checker():
    assert ENV_ID in gym.registry
    env = gym.make(ENV_ID, budget=1500.0)
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=3)
    assert env.observation_space.contains(obs)
    m = info["action_mask"]
    assert m.dtype == np.int8 and m.shape == (env.action_space.n,) and m.any()


def test_random_valid_action_loop_single():
    env = IPPSearchEnv(budget=1500.0)
    obs, info = env.reset(seed=0)
    steps, ret, rng = 0, 0.0, np.random.default_rng(0)
    while True:
        valid = np.flatnonzero(info["action_mask"])
        a = int(rng.choice(valid))
        obs, r, term, trunc, info = env.step(a)
        assert env.observation_space.contains(obs)
        assert info["terms"][4] == 0.0  # never an invalid-primitive penalty
        ret += r
        steps += 1
        if term or trunc:
            break
        assert steps < 500
    m = info["metrics"]
    assert 0 < m["coverage"] <= 100 and m["primitives"] == steps
    assert ret == pytest.approx(ret)  # finite
    # the same seed gives the same world and the same episode
    _, i2 = env.reset(seed=0)
    _, i3 = IPPSearchEnv(budget=1500.0).reset(seed=0)
    assert i2["world"] == i3["world"]


def test_invalid_action_is_penalised_not_executed():
    env = IPPSearchEnv(budget=1500.0, start="random")
    _, info = env.reset(seed=5)
    bad = np.flatnonzero(info["action_mask"] == 0)
    if len(bad) == 0:
        pytest.skip("every slot valid at this start")
    _, r, _, _, info = env.step(int(bad[0]))
    assert info["terms"][4] == -1.0


def test_vector_env_batched_autoreset_loop():
    n = 6
    venv = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point", budget=1200.0)
    assert isinstance(venv.unwrapped, IPPSearchVectorEnv)
    obs, info = venv.reset(seed=1)
    assert obs["maps"].shape[0] == n and info["action_mask"].shape[0] == n
    rng = np.random.default_rng(1)
    ended = np.zeros(n, int)
    restarted = np.zeros(n, bool)
    prev_term = np.zeros(n, bool)
    world0 = info["world"].copy()
    for _ in range(80):
        mask = info["action_mask"].astype(bool)
        a = np.array([rng.choice(np.flatnonzero(m)) if m.any() else 0 for m in mask])
        obs, r, term, trunc, info = venv.step(a)
        assert venv.observation_space.contains(obs)
        assert not trunc.any()
        # NEXT_STEP autoreset: the step after termination starts a fresh world, reward 0
        restarted |= prev_term & (info["world"] != world0)
        assert np.all(r[prev_term] == 0.0)
        if "metrics" in info:
            got = info["_metrics"]
            assert np.array_equal(got, term)
            assert np.all(info["metrics"]["search_efficiency"][got] >= 0)
        ended += term
        world0 = np.where(prev_term, info["world"], world0)
        prev_term = term
    assert ended.min() >= 2 and restarted.all()
    venv.close()


def test_bad_budget_is_one_line_error():
    with pytest.raises(ValueError, match="budget must be > 0"):
        IPPSearchVectorEnv(2, budget=0)
    with pytest.raises(ValueError, match="budget must be a number"):
        IPPSearchVectorEnv(2, budget="huge")
    assert IPPSearchVectorEnv(1, budget="tight").cfg.budget == 5000.0


def test_reset_rows_equals_a_fresh_reset():
    from aerohrl.ipp.env import EnvConfig, SearchEnv
    from aerohrl.ipp.lattice import default_lattice
    from aerohrl.ipp.world import sample_worlds

    lat, cfg = default_lattice(), EnvConfig(budget=1500.0)
    env = SearchEnv(cfg, lat)
    env.reset(sample_worlds(cfg.world, 7, [0, 1, 2]))
    for _ in range(3):
        env.step(np.argmax(env.valid_mask(), 1))
    keep_L = env.L[[0, 2]].copy()
    env.reset_rows(np.array([1]), sample_worlds(cfg.world, 7, [9]))
    ref = SearchEnv(cfg, lat)
    ref.reset(sample_worlds(cfg.world, 7, [9]))
    np.testing.assert_array_equal(env.L[1], ref.L[0])
    np.testing.assert_array_equal(env.L[[0, 2]], keep_L)
    assert env.remaining[1] == 1500.0 and env.steps[1] == 0 and not env.cov[1].any()
    assert env.worlds.seeds[1].tolist() == [7, 9]
    a = np.argmax(env.valid_mask(), 1)
    env.step(a)
    ref.step(a[[1]])
    np.testing.assert_array_equal(env.L[1], ref.L[0])  # same sensor noise as a fresh env
