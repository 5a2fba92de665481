"""Batched target-search environment: Eq. 2.2 updates, sweep, reward totals, masks."""

import numpy as np
import pytest

import aerohrl.ipp.env as envmod
from aerohrl.ipp.env import EnvConfig, SearchEnv, TERMS
from aerohrl.ipp.factory import make_env
from aerohrl.ipp.lattice import default_lattice
from aerohrl.ipp.sensor import SensorConfig, logit, logodds_step, logodds_update, sigmoid
from aerohrl.ipp.world import WorldConfig, kl_divergence, sample_worlds


@pytest.fixture(scope="module")
def lat():
    return default_lattice()


def test_eq_2_2_single_measurement():
    # prior 0.5, z = 1 with error 0.01 -> posterior 0.99; z = 0 -> 0.01
    L = logodds_update(np.zeros(2), np.array([True, False]), np.array([0.01, 0.01]))
    np.testing.assert_allclose(sigmoid(L), [0.99, 0.01])
    # sequential measurements add log-likelihood ratios to the prior log-odds
    b0 = 0.2
    L = logit(b0)
    for z, e in [(1, 0.11), (1, 0.21), (0, 0.01)]:
        L = logodds_update(L, z, e)
    odds = b0 / (1 - b0) * (0.89 / 0.11) * (0.79 / 0.21) * (0.01 / 0.99)
    assert sigmoid(L) == pytest.approx(odds / (1 + odds))


@pytest.mark.parametrize("u,flip", [(0.999, False), (0.0, True)])
def test_belief_update_equals_hand_computation(lat, monkeypatch, u, flip):
    monkeypatch.setattr(envmod, "hashed_uniform", lambda *a: np.full(np.broadcast_shapes(*[np.shape(x) for x in a]), u))
    env, _ = make_env(EnvConfig(), lat, 3, [4])
    prior = env.worlds.prior[0]
    truth = env.worlds.targets[0]
    a = int(np.flatnonzero(env.valid_mask()[0])[3])
    p = int(lat.edges[env.vert[0], a])
    x0, y0 = env.pos[0]
    env.step(np.array([a]))
    expect = logit(prior).copy()
    lam = logodds_step(SensorConfig().error_levels(lat.n_levels))
    cells, lev = lat.sensed_cells(p, (x0, y0))
    for (x, y), l in zip(cells, lev):  # hand computation, one measurement at a time
        if 0 <= x < 30 and 0 <= y < 30:
            z = bool(truth[y, x]) ^ flip
            expect[y, x] += lam[l] if z else -lam[l]
    np.testing.assert_allclose(env.belief()[0], sigmoid(np.clip(expect, -20, 20)), atol=1e-12)


def _sweep_actions(lat):
    hov = lat.edges[0]
    slot = {tuple(lat.prim_disp[p]): a for a, p in enumerate(hov) if p >= 0 and lat.prim_to[p] == 0}
    seq = []
    for row in range(6):
        step = (5, 0) if row % 2 == 0 else (-5, 0)
        seq += [slot[step]] * 5
        if row < 5:
            seq.append(slot[(0, 5)])
    return seq


def test_perfect_sensor_sweep_finds_all_and_reward_totals(lat):
    seq = _sweep_actions(lat)
    cost = 0.0
    v = 0
    for a in seq:
        cost += lat.prim_cost[lat.edges[v, a]]
    cfg = EnvConfig(budget=cost, sensor=SensorConfig(err0=1e-12, err_slope=0.0))
    env = SearchEnv(cfg, lat)
    N = 4
    env.reset(sample_worlds(cfg.world, 11, range(N)), start=np.full((N, 2), 2))
    total = np.zeros((N, len(TERMS)))
    for k, a in enumerate(seq):
        assert env.valid_mask()[:, a].all()
        _, r, terms, done = env.step(np.full(N, a))
        np.testing.assert_allclose(r, terms.sum(1))
        total += terms
        assert done.all() == (k == len(seq) - 1)
    m = env.metrics()
    np.testing.assert_allclose(m["coverage"], 100.0)
    np.testing.assert_allclose(m["search_efficiency"], 100.0)
    assert np.all(m["entropy_reduction"] > 99.999)
    t = dict(zip(TERMS, total.T))
    np.testing.assert_allclose(t["coverage"], 10.0)
    np.testing.assert_allclose(t["entropy"], 15.0, atol=1e-3)
    np.testing.assert_allclose(t["target"], 20.0 * env.n_targets)
    np.testing.assert_allclose(t["cost"], -20.0)
    np.testing.assert_allclose(t["invalid"], 0.0)


def test_reward_terms_sum_to_metrics_on_random_episodes(lat):
    env, obs = make_env(EnvConfig(), lat, 5, range(16))
    rng = np.random.default_rng(0)
    total = np.zeros((16, len(TERMS)))
    while not env.done.all():
        m = env.valid_mask()
        assert np.array_equal(m, obs["valid"])
        a = np.array([rng.choice(np.flatnonzero(r)) if r.any() else 0 for r in m])
        obs, r, terms, done = env.step(a)
        total += terms
        assert obs["maps"].shape == (16, 9, 8, 8)
        assert obs["maps"].min() >= 0 and obs["maps"].max() <= 1
    met = env.metrics()
    np.testing.assert_allclose(total[:, 0], 15 * met["entropy_reduction"] / 100, atol=1e-9)
    np.testing.assert_allclose(total[:, 1], 10 * met["coverage"] / 100, atol=1e-9)
    np.testing.assert_allclose(total[:, 2], 20 * env.n_found)
    np.testing.assert_allclose(total[:, 3], -20.0)
    np.testing.assert_allclose(total[:, 4], 0.0)
    # agents stayed on the map
    for p in env.trace:
        assert p.min() >= 0 and p.max() < 30


def test_invalid_primitive_penalised_and_agent_stays(lat):
    env, _ = make_env(EnvConfig(), lat, 0, [0])
    env.pos[:] = [0, 0]
    bad = np.flatnonzero(~env.valid_mask()[0])
    assert len(bad)
    _, r, terms, _ = env.step(np.array([bad[0]]))
    assert terms[0, 4] == -1.0 and terms[0, 1] == 0.0
    assert env.pos[0].tolist() == [0, 0]
    with pytest.raises(ValueError):
        env.step(np.array([lat.n_actions]))


def test_observation_layout(lat):
    env, obs = make_env(EnvConfig(), lat, 0, [0])
    maps = obs["maps"][0]
    assert maps[2].max() == 0  # scale-1 boundary channel: 8x8 around (15,15) is inside
    assert maps[8].max() == 1  # scale-4 window (32 cells) reaches beyond the map
    np.testing.assert_allclose(maps[0], env.belief()[0][11:19, 11:19], rtol=1e-6)
    vec = obs["vec"][0]
    A = lat.n_actions
    assert vec[:2].tolist() == [0.5, 0.5]
    assert vec[2 + A] == 1 and vec[3 + A] == 1 and vec[-1] == 1
    # after a few steps near the edge: every scale equals a direct block-max reference
    for _ in range(6):
        obs, *_ = env.step(np.array([np.flatnonzero(env.valid_mask()[0])[-1]]))
    x, y = env.pos[0] + env.pad
    b = np.where(env.boundary == 0, sigmoid(env.L[0]), 0.0)
    ref_planes = np.stack([b, env.cov[0], env.boundary])
    for j, sc in enumerate((1, 2, 4)):
        w = 4 * sc
        win = ref_planes[:, y - w : y + w, x - w : x + w]
        ref = win.reshape(3, 8, sc, 8, sc).max(axis=(2, 4))
        np.testing.assert_allclose(obs["maps"][0, 3 * j : 3 * j + 3], ref, rtol=1e-6, atol=1e-7)


def test_batch_independence(lat):
    rng = np.random.default_rng(1)
    big, _ = make_env(EnvConfig(), lat, 9, range(8))
    one, _ = make_env(EnvConfig(), lat, 9, [5])
    while not one.done.all():
        a = rng.choice(np.flatnonzero(one.valid_mask()[0]))
        one.step(np.array([a]))
        acts = np.array([np.flatnonzero(m)[0] if m.any() else 0 for m in big.valid_mask()])
        acts[5] = a
        big.step(acts)
    np.testing.assert_array_equal(big.L[5], one.L[0])


def test_worlds_seeded_and_kl():
    w = WorldConfig()
    a, b = sample_worlds(w, 3, [0, 1, 2]), sample_worlds(w, 3, [2])
    np.testing.assert_array_equal(a.prior[2], b.prior[0])
    assert np.all(a.kl > 0) and np.all(a.kl_sym >= a.kl)
    assert np.allclose(a.density.sum((1, 2)), 1.0)
    n = a.targets.sum((1, 2))
    assert np.all((n >= 10) & (n <= 29))
    assert kl_divergence(a.density, a.density) == pytest.approx(0.0, abs=1e-12) or np.allclose(
        kl_divergence(a.density, a.density), 0.0
    )


def test_bad_configs(lat):
    with pytest.raises(ValueError, match="budget"):
        SearchEnv(EnvConfig(budget=1.0), lat)
    with pytest.raises(ValueError, match="too small"):
        SearchEnv(EnvConfig(map_size=3, world=WorldConfig(map_size=3)), lat)
    with pytest.raises(ValueError):
        SearchEnv(EnvConfig(start="corner"), lat)


def test_viability_kernel_is_closed(lat):
    from aerohrl.ipp.env import viability

    S = 30
    ok = viability(lat, S)
    V, A = lat.edges.shape
    v, a, y, x = np.nonzero(ok)
    p = lat.edges[v, a]
    assert np.all(p >= 0)
    ex, ey = x + lat.prim_disp[p, 0], y + lat.prim_disp[p, 1]
    assert np.all((ex >= 0) & (ex < S) & (ey >= 0) & (ey < S))
    # every valid primitive ends in a state that again has a valid primitive
    assert ok[lat.prim_to[p], :, ey, ex].any(axis=1).all()
    # and its visited centres stay on the map
    bb = lat.prim_bbox[p]
    assert np.all((x + bb[:, 0] >= 0) & (x + bb[:, 1] < S) & (y + bb[:, 2] >= 0) & (y + bb[:, 3] < S))
    assert ok[0].any(axis=0)[15, 15]
