"""Semantic decision-time paths: the windowed fast features equal the direct computation,
the detect teacher reads the same scores as its tree search, the slice-based
observation equals the gather, and a semantic policy trains and acts on valid
primitives."""

import json

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from aerohrl.ipp import features as F
from aerohrl.ipp.baselines import make_planner
from aerohrl.ipp.cli import main
from aerohrl.ipp.env import EnvConfig, semantic_config
from aerohrl.ipp.factory import make_env
from aerohrl.ipp.lattice import default_lattice, semantic_lattice

SMALL = 48


@pytest.fixture(scope="module")
def slat():
    return semantic_lattice()


def _cfg(budget=3000.0, size=SMALL):
    return semantic_config(budget=budget, map_size=size)


def _assert_features_close(fast, ref):
    assert fast.shape == ref.shape and fast.dtype == ref.dtype == np.float32
    scale = np.abs(ref).max((0, 1), keepdims=True) + 1e-12
    np.testing.assert_array_less(np.abs(fast.astype(float) - ref) / scale, 1e-5)
    # validity, costs and the exact detection features agree to the last bit here
    for k in (1, 4, 8, 9, 14):
        np.testing.assert_allclose(fast[..., k], ref[..., k], rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("planner", ["detect", "prio_coverage"])
def test_fast_features_equal_the_reference(slat, planner):
    env, _ = make_env(_cfg(), slat, 2, range(3))
    assert F.fast_path_applies(env)
    pl = make_planner(planner, env)
    for t in range(40):  # noqa: B007  (read after the loop)
        if env.done.all():
            break
        _assert_features_close(F.semantic_fast(env)[0], F.action_features_reference(env))
        env.step(pl.act())
    assert env.done.any() or t == 39
    # the budget-aware endgame (less budget left than any primitive) as well
    env.reset(env.worlds)
    for _ in range(5):
        env.step(pl.act())
    env.remaining[:] = [1.0, 150.0, 700.0]
    _assert_features_close(F.semantic_fast(env)[0], F.action_features_reference(env))


def test_fast_path_is_the_default_and_reads_no_truth(slat, monkeypatch):
    env, _ = make_env(_cfg(), slat, 4, range(2))
    for _ in range(3):
        env.step(make_planner("coverage", env).act())
    f = env.action_features()
    env.truth[:] = np.random.default_rng(0).integers(0, 5, env.truth.shape)
    env.found[:] = ~env.found
    env._fast_cache = None
    monkeypatch.setattr(F, "action_features_reference", lambda e: (_ for _ in ()).throw(AssertionError("slow path")))
    np.testing.assert_array_equal(env.action_features(), f)
    assert not F.fast_path_applies(make_env(EnvConfig(), default_lattice(), 1, [0])[0])


def test_cache_follows_the_state(slat):
    env, _ = make_env(_cfg(), slat, 4, range(2))
    f0 = env.action_features()
    assert env.action_features() is f0  # same state: shared by the features and the teacher
    env.step(make_planner("detect", env).act())
    f1 = env.action_features()
    assert f1 is not f0
    env.remaining[:] = 1.0  # a state edit outside step() that the key still sees
    assert env.action_features() is not f1


def test_fast_teacher_equals_the_tree_search(slat):
    env, _ = make_env(_cfg(), slat, 7, range(3))
    fast, tree = make_planner("detect", env), make_planner("detect", env)
    tree.use_fast = False
    assert fast._fast() and not tree._fast()
    n = 0
    while not env.done.all():
        a, b = fast.act(), tree.act()
        live = ~env.done
        np.testing.assert_array_equal(a[live], b[live])
        n += int(live.sum())
        env.step(a)
    assert n > 20
    # the non-default variants keep the tree search
    from aerohrl.ipp.baselines import PlannerConfig

    assert not make_planner("detect", env, PlannerConfig(depth=3))._fast()
    assert not make_planner("detect", env, PlannerConfig(budget_aware=False))._fast()


def test_plan_detect_is_the_posterior_test(slat):
    env, _ = make_env(_cfg(), slat, 1, [0])
    rng = np.random.default_rng(0)
    b = rng.dirichlet(np.full(5, 0.3), 5000).astype(np.float32)
    lam = rng.uniform(0, 60, 5000)
    C, thr = 5, env.cfg.found_threshold
    e = (1.0 / (1.0 + np.exp(np.minimum(lam, 50.0)) / (C - 1)))[:, None]
    post = b * (1 - e) / (b * (1 - e) + (1 - b) * e / (C - 1))
    hand = (b * (1 - e) * (post >= thr))[:, 1:].sum(-1)
    np.testing.assert_allclose(env.plan_detect(b, lam), hand, atol=1e-12)


def test_window_edt_equals_the_full_transform(slat):
    env, _ = make_env(_cfg(size=96), slat, 3, range(4))
    p, S = env.pad, env.S
    rng = np.random.default_rng(2)
    # covered blocks around the agents: near cells, far cells, nothing left, a corner
    env.pos[:] = [[48, 48], [40, 50], [5, 6], [90, 3]]
    env.cov[0, p + 20 : p + 76, p + 20 : p + 76] = True  # nearest outside the window
    env.cov[1, p : p + S, p : p + S] = rng.random((S, S)) < 0.9  # near ones
    env.cov[2, p : p + S, p : p + S] = True  # fully covered: capped
    env.cov[3, p : p + 30, p + 60 : p + S] = True
    ends = env.pos[:, None, :] + slat.prim_disp[np.maximum(slat.edges[0], 0)]
    ends = np.clip(ends, 0, S - 1)
    got = F._window_edt(env, np.arange(4), ends, 32)
    for n in range(4):
        unc = ~env.cov[n, p : p + S, p : p + S]
        d = distance_transform_edt(~unc) if unc.any() else np.full((S, S), 2.0 * S)
        np.testing.assert_array_equal(got[n], d[ends[n, :, 1], ends[n, :, 0]])


def _observe_by_gather(env):
    """The original observation code (fancy-index gather of the whole window)."""
    cfg, R = env.cfg, env.cfg.obs_radius
    half = R * max(cfg.obs_scales)
    g = np.arange(-half, half)
    ys = (env.pos[:, 1] + env.pad)[:, None] + g
    xs = (env.pos[:, 0] + env.pad)[:, None] + g
    C = env.planes.shape[1]
    win = env.planes[np.arange(env.n)[:, None, None], :, ys[:, :, None], xs[:, None, :]]
    outs = []
    for s in cfg.obs_scales:
        w = R * s
        crop = win[:, half - w : half + w, half - w : half + w]
        outs.append(crop.reshape(env.n, 2 * R, s, 2 * R, s, C).max(axis=4).max(axis=2))
    return np.concatenate(outs, 3).transpose(0, 3, 1, 2)


@pytest.mark.parametrize("kind", ["targets", "semantic"])
def test_observe_equals_the_gather(slat, kind):
    lat, cfg = (default_lattice(), EnvConfig()) if kind == "targets" else (slat, _cfg())
    env, obs = make_env(cfg, lat, 5, range(3))
    pl = make_planner("coverage", env)
    for _ in range(4):
        np.testing.assert_array_equal(obs["maps"], _observe_by_gather(env))
        obs, *_ = env.step(pl.act())


def test_semantic_policy_trains_and_acts_on_valid_primitives(slat, tmp_path, monkeypatch):
    from aerohrl.ipp.policy import load_policy
    from test_ipp_policy import fly_valid
    from aerohrl.ipp.train import preset, train

    cfg = preset("test", env=semantic_config(budget=1200.0, map_size=SMALL, start="random"))
    train(cfg, slat, tmp_path / "run")
    model = load_policy(tmp_path / "run")
    assert model.env_kind == "semantic"
    env, _ = make_env(_cfg(1200.0), slat, 1000, range(2))
    monkeypatch.setattr(F, "action_features_reference", lambda e: (_ for _ in ()).throw(AssertionError("slow path")))
    fly_valid(env, model)


def test_cli_semantic_train_preset_and_bench(tmp_path, capsys):
    run = tmp_path / "sem"
    assert (
        main(
            [
                "train",
                "--world",
                "semantic",
                "--map-size",
                str(SMALL),
                "--budget",
                "800",
                "--envs",
                "2",
                "--bc-iterations",
                "1",
                "--eval-every",
                "0",
                "--out",
                str(run.parent),
                "--name",
                run.name,
                "--quiet",
            ]
        )
        == 0
    )
    cfg = json.loads((run / "config.json").read_text())["train"]
    assert cfg["env"]["kind"] == "semantic" and cfg["bc_buffer"] == 4  # the semantic preset
    capsys.readouterr()
    out_dir = tmp_path / "b"
    assert (
        main(
            [
                "bench",
                "--planner",
                "rl",
                "--world",
                "semantic",
                "--run",
                str(run),
                "--map-size",
                str(SMALL),
                "--budget",
                "800",
                "--envs",
                "2",
                "--out",
                str(out_dir),
                "--quiet",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "Imitation of detect planner" in out and "63.6" in out  # beside thesis Table 2.2
    assert "Ours-LSTM" not in out
    assert main(["bench", "--planner", "rl", "--run", str(run), "--envs", "1", "--out", str(out_dir), "--quiet"]) == 2
    assert "trained on semantic worlds" in capsys.readouterr().err


def test_cli_semantic_preset_needs_semantic_worlds(capsys):
    assert main(["train", "--preset", "semantic", "--world", "targets"]) == 2
    err = capsys.readouterr().err.strip()
    assert "semantic worlds" in err and "\n" not in err


@pytest.mark.slow
def test_fast_features_equal_the_reference_on_the_full_map(slat):
    env, _ = make_env(semantic_config(), slat, 3, range(2))
    pl = make_planner("detect", env)
    for _ in range(12):
        _assert_features_close(F.semantic_fast(env)[0], F.action_features_reference(env))
        env.step(pl.act())
