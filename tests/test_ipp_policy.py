"""Learned planner: losses (Eq. 2.7), GAE per reward term, a tiny training run."""

import json

import numpy as np
import pytest
import torch

from aerohrl.errors import UserError
from aerohrl.ipp.env import TERMS, EnvConfig
from aerohrl.ipp.factory import make_env
from aerohrl.ipp.lattice import default_lattice
from aerohrl.ipp.policy import RLPlanner, load_policy, valid_loss
from aerohrl.ipp.train import _gae, preset, train


def random_walk(env, rng, steps):
    """``steps`` primitives drawn uniformly from the valid ones of every environment."""
    for _ in range(steps):
        env.step(np.array([rng.choice(np.flatnonzero(m)) for m in env.valid_mask()]))


def fly_valid(env, model):
    """Fly ``model`` to the end of every episode: it only ever picks valid primitives, and
    every environment covers something."""
    pl = RLPlanner(env, model)
    while not env.done.all():
        a = pl.act()
        live = ~env.done
        assert env.valid_mask()[live, a[live]].all()
        env.step(a)
    assert np.all(env.metrics()["coverage"] > 0)


def test_valid_loss_is_eq_2_7():
    phi = torch.tensor([[2.0, -1.0, 0.5]])
    y = torch.tensor([[True, False, True]])
    s = torch.sigmoid(phi)
    b1, b2 = 1.0, 0.2
    hand = -(b1 * (1 - y.float()) * torch.log(1 - s) + b2 * y.float() * torch.log(s)).mean()
    assert valid_loss(phi, y, b1, b2).item() == pytest.approx(hand.item(), rel=1e-6)


def test_gae_reward_to_go_per_term():
    T, N = 4, 2
    rew = torch.arange(T * N * len(TERMS), dtype=torch.float).reshape(T, N, len(TERMS))
    alive = torch.ones(T, N)
    alive[3, 1] = 0  # env 1 finished after 3 steps
    adv, ret = _gae(rew, torch.zeros_like(rew), alive, 1.0, 1.0)
    np.testing.assert_allclose(ret[0, 0].numpy(), rew[:, 0].sum(0).numpy())
    np.testing.assert_allclose(ret[0, 1].numpy(), rew[:3, 1].sum(0).numpy())
    assert torch.all(adv[3, 1] == 0)


def test_tiny_training_run_and_planner(tmp_path):
    lat = default_lattice()
    cfg = preset("test")
    last = train(cfg, lat, tmp_path / "run")
    lines = (tmp_path / "run" / "metrics.jsonl").read_text().strip().splitlines()
    n = cfg.total_iterations
    assert len(lines) == n and json.loads(lines[-1])["iteration"] == n
    assert np.isfinite(last["return"])
    model = load_policy(tmp_path / "run")
    env, _ = make_env(EnvConfig(budget=1500.0), lat, 1000, range(3))
    fly_valid(env, model)


def test_bad_policy_and_preset(tmp_path):
    with pytest.raises(UserError):
        load_policy(tmp_path)
    (tmp_path / "model.pt").write_bytes(b"junk")
    with pytest.raises(UserError):
        load_policy(tmp_path)
    with pytest.raises(UserError):
        preset("gpu-cluster")


def test_action_features_by_hand():
    from aerohrl.ipp.features import EPS, N_FEAT

    lat = default_lattice()
    env, _ = make_env(EnvConfig(), lat, 4, range(2))
    rng = np.random.default_rng(0)
    random_walk(env, rng, 3)
    f = env.action_features()
    assert f.shape == (2, lat.n_actions, N_FEAT) and f.dtype == np.float32
    n = 1
    valid = env.valid_mask()[n]
    np.testing.assert_array_equal(f[n, :, 9], valid)
    b = env.belief()[n]
    cov = env.cov[n, env.pad : env.pad + 30, env.pad : env.pad + 30]
    cmean = lat.prim_cost.mean()

    def new_cells(p, origin):
        cells = np.unique(lat.sensed_cells(p, origin)[0], axis=0)
        ok = (cells >= 0).all(1) & (cells < 30).all(1)
        return cells[ok][~cov[cells[ok, 1], cells[ok, 0]]]

    for a in np.flatnonzero(valid)[:4]:
        p = int(lat.edges[env.vert[n], a])
        c = new_cells(p, env.pos[n])
        assert f[n, a, 3] == pytest.approx(len(c) / 25, rel=1e-5)
        assert f[n, a, 10] == pytest.approx((EPS + b[c[:, 1], c[:, 0]]).sum() / 25, rel=1e-4)
        # two-step feature: best next primitive's new-cell rate (overlap ignored)
        end = env.pos[n] + lat.prim_disp[p]
        v2 = lat.prim_to[p]
        best = 0.0
        for a2 in np.flatnonzero(env.ok[v2, :, end[1], end[0]]):
            p2 = int(lat.edges[v2, a2])
            best = max(best, len(new_cells(p2, end)) / 25 / (lat.prim_cost[p2] / cmean))
        assert f[n, a, 13] == pytest.approx(best, rel=1e-4)
    assert np.all(f[n, ~valid, :9] == 0)


def test_warm_start_and_mismatch(tmp_path):
    lat = default_lattice()
    train(preset("test"), lat, tmp_path / "a")
    last = train(preset("test", init=str(tmp_path / "a"), lr=1e-4), lat, tmp_path / "b")
    assert np.isfinite(last["return"])
    with pytest.raises(UserError, match="does not match"):
        train(preset("test", init=str(tmp_path / "a"), policy=preset("test").policy.__class__(hidden=16)), lat, tmp_path / "c")
    assert not (tmp_path / "c").exists()  # refused before it began: the claimed folder is removed again


def test_describe_policy_names_what_trained_it(tmp_path):
    """A learned row says what it is (imitation of detect, or RL), never
    the thesis's 'Ours-LSTM'."""
    import json

    from aerohrl.ipp.policy import ActorCritic, PolicyConfig, describe_policy, load_policy, save_policy

    dims = dict(map_ch=9, map_hw=8, vec_dim=10, n_actions=4)
    for feats, train_cfg, want in [
        (
            True,
            {"bc_iterations": 30, "teacher": "detect", "iterations": 0},
            "Imitation of detect planner (DAgger; its features, GRU)",
        ),
        (
            True,
            {"bc_iterations": 3, "teacher": "detect", "iterations": 5},
            "Imitation of detect planner + PPO 5 it. (DAgger; its features, GRU)",
        ),
        (False, {"bc_iterations": 0, "teacher": "detect", "iterations": 782}, "Actor-critic RL (map-only, GRU)"),
    ]:
        run = tmp_path / f"r{len(want)}"
        run.mkdir()
        from aerohrl.ipp.features import N_FEAT

        d = dict(dims, n_feat=N_FEAT if feats else 0)
        m = ActorCritic(**d, cfg=PolicyConfig(hidden=16, features=feats))
        save_policy(m, d, run / "model.pt")
        (run / "config.json").write_text(json.dumps({"train": train_cfg}))
        assert describe_policy(load_policy(run)) == want
