"""Semantic feature detection (thesis §2.6.3): campus maps, raster loader, multi-class
Eq. 2.2, the batched environment, planners and the CLI."""

import numpy as np
import pytest

import aerohrl.ipp.semantic_env as semenv
from aerohrl.ipp.baselines import PLANNERS, TEACHERS, PlannerConfig, info_gain, make_planner
from aerohrl.ipp.cli import main
from aerohrl.ipp.env import TERMS, semantic_config
from aerohrl.ipp.factory import make_env
from aerohrl.ipp.lattice import semantic_lattice
from aerohrl.ipp.semantic import (
    CLASSES,
    PALETTE,
    SemanticConfig,
    _info_gain_cat_direct,
    campus_map,
    categorical_update,
    info_gain_cat,
    label_logratio,
    load_class_raster,
    measure_labels,
    sample_semantic_worlds,
    softmax,
)

SMALL = 48  # a small semantic map keeps the tests fast


@pytest.fixture(scope="module")
def lat():
    return semantic_lattice()


def test_campus_map_classes_and_seeding():
    a = campus_map(np.random.default_rng(3), 256)
    b = campus_map(np.random.default_rng(3), 256)
    np.testing.assert_array_equal(a, b)
    assert a.shape == (256, 256) and a.dtype == np.int8
    frac = np.bincount(a.ravel(), minlength=len(CLASSES)) / a.size
    assert frac[0] > 0.2 and frac[1] > 0.01 and frac[2] > 0.03 and frac[3] > 0.05
    w = sample_semantic_worlds(SemanticConfig(), 5, [0, 1])
    w1 = sample_semantic_worlds(SemanticConfig(), 5, [1])
    np.testing.assert_array_equal(w.classes[1], w1.classes[0])
    np.testing.assert_allclose(w.prior.sum(-1), 1.0, atol=1e-5)
    assert np.all(w.kl > 0)


def test_categorical_update_by_hand():
    p = np.array([0.5, 0.2, 0.1, 0.1, 0.1])
    e = 0.2
    l = categorical_update(np.log(p), 1, e)
    lik = np.full(5, e / 4)
    lik[1] = 1 - e
    np.testing.assert_allclose(softmax(l), p * lik / (p * lik).sum())
    # two classes: exactly the binary Eq. 2.2 step log((1-e)/e)
    assert label_logratio(0.11, 2) == pytest.approx(np.log(0.89 / 0.11))
    # labels: the truth unless u1 < e; a wrong label is never the truth
    t = np.array([0, 3, 4, 2])
    z = measure_labels(t, np.full(4, 0.5), np.array([0.9, 0.1, 0.1, 0.1]), np.array([0.0, 0.0, 0.99, 0.5]), 5)
    assert z[0] == 0 and np.all(z[1:] != t[1:]) and z[1] == 0 and z[2] == 3


def test_info_gain_cat():
    rng = np.random.default_rng(0)
    p = rng.dirichlet(np.ones(5), size=50)
    lam = rng.uniform(0, 8, 50)
    np.testing.assert_allclose(info_gain_cat(p, lam), _info_gain_cat_direct(p, lam), atol=1e-10)
    b = rng.uniform(0.05, 0.95, 20)
    lam2 = rng.uniform(0, 6, 20)
    np.testing.assert_allclose(info_gain_cat(np.stack([1 - b, b], -1), lam2), info_gain(b, lam2), atol=1e-10)


def _cfg(budget=1500.0):
    return semantic_config(budget=budget, map_size=SMALL)


@pytest.mark.parametrize("u,wrong", [(0.999, False), (0.0, True)])
def test_env_belief_update_equals_hand_computation(lat, monkeypatch, u, wrong):
    monkeypatch.setattr(semenv, "hashed_uniform", lambda *a: np.full(np.broadcast_shapes(*[np.shape(x) for x in a]), u))
    env, _ = make_env(_cfg(), lat, 3, [0])
    C = env.n_classes
    prior = env.worlds.prior[0].astype(float)
    truth = env.worlds.classes[0].astype(int)
    a = int(np.flatnonzero(env.valid_mask()[0])[2])
    pr = int(lat.edges[env.vert[0], a])
    x0, y0 = env.pos[0]
    env.step(np.array([a]))
    expect = np.log(prior)
    inc = label_logratio(env.err_levels, C)
    cells, lev = lat.sensed_cells(pr, (x0, y0))
    for (x, y), l in zip(cells, lev):  # one label at a time
        if 0 <= x < SMALL and 0 <= y < SMALL:
            z = truth[y, x] if not wrong else (0 if truth[y, x] != 0 else 1)  # u2 = 0
            expect[y, x, z] += inc[l]
    np.testing.assert_allclose(env.probs()[0], softmax(expect), atol=1e-5)
    # detection: feature cells whose true class reached 0.95
    P = softmax(expect)
    pt = np.take_along_axis(P, truth[..., None], -1)[..., 0]
    assert env.n_found[0] == int(((pt >= 0.95) & (truth > 0)).sum())


def test_reward_terms_match_metrics(lat):
    env, obs = make_env(_cfg(2500.0), lat, 1, range(2))
    assert obs["maps"].shape == (2, 3 * (len(CLASSES) + 2), 24, 24)
    rng = np.random.default_rng(0)
    total = np.zeros((2, len(TERMS)))
    while not env.done.all():
        m = env.valid_mask()
        _, _, terms, _ = env.step(np.array([rng.choice(np.flatnonzero(r)) if r.any() else 0 for r in m]))
        total += terms
    met = env.metrics()
    np.testing.assert_allclose(total[:, 0], 15 * met["entropy_reduction"] / 100, atol=1e-6)
    np.testing.assert_allclose(total[:, 1], 10 * met["coverage"] / 100, atol=1e-9)
    det = env.detected_by_class()
    np.testing.assert_allclose(total[:, 2], 20 * (det[:, 1:] / np.maximum(env.n_class[:, 1:], 1)).sum(1))
    np.testing.assert_allclose(total[:, 3], -20.0)
    assert np.all(met["search_efficiency"] > 0)


@pytest.mark.parametrize("name", PLANNERS + TEACHERS)
def test_planners_run_on_semantic(lat, name):
    env, _ = make_env(_cfg(1200.0), lat, 2, range(2))
    pl = make_planner(name, env, PlannerConfig(popsize=4, generations=2))
    while not env.done.all():
        a = pl.act()
        live = ~env.done
        assert env.valid_mask()[live, a[live]].all()
        env.step(a)
    m = env.metrics()
    for k in ("coverage", "entropy_reduction", "search_efficiency"):
        assert np.all((m[k] >= 0) & (m[k] <= 100))
    assert m["coverage"].min() > 0


def test_detect_teacher_and_its_feature_on_semantic(lat):
    from aerohrl.ipp.features import N_FEAT

    env, _ = make_env(_cfg(1200.0), lat, 2, range(2))
    pl = make_planner("detect", env)
    for _ in range(2):
        f, a = env.action_features(), pl.act()
        assert f.shape == (2, lat.n_actions, N_FEAT) and np.isfinite(f).all()
        top = f[..., 14].max(1) > 1e-6
        assert top.any()
        assert np.array_equal(np.where(env.valid_mask(), f[..., 14], -1).argmax(1)[top], a[top])
        env.step(a)


def test_raster_loader_formats(tmp_path):
    import matplotlib.pyplot as plt

    a = np.zeros((64, 32), np.int64)
    a[10:20, 5:9] = 1
    a[30:, :] = 2
    a[40:50, 20:30] = 4
    np.save(tmp_path / "c.npy", a)
    np.savez(tmp_path / "c.npz", classes=a, other=np.zeros(3))
    plt.imsave(tmp_path / "rgb.png", PALETTE[a])
    plt.imsave(tmp_path / "grey.png", a.astype(np.uint8), cmap="gray", vmin=0, vmax=255)
    for f in ("c.npy", "c.npz", "rgb.png", "grey.png"):
        r = load_class_raster(tmp_path / f, 64)
        assert r.shape == (64, 64)
        # nearest-neighbour: every column pair repeats the source column
        np.testing.assert_array_equal(r[:, ::2], a, err_msg=f)


@pytest.mark.parametrize(
    "case,msg",
    [
        ("missing", "not found"),
        ("ext", "unsupported"),
        ("3d", "2-D"),
        ("range", "0..4"),
        ("float", "integer"),
        ("colour", "palette"),
        ("empty", "no feature"),
        ("npzkeys", "no 'classes'"),
        ("junk", "not a numpy"),
        ("tiny", "too small"),
    ],
)
def test_raster_loader_errors_one_line(tmp_path, case, msg):
    import matplotlib.pyplot as plt

    f = tmp_path / "r.npy"
    if case == "missing":
        f = tmp_path / "nope.npy"
    elif case == "ext":
        f = tmp_path / "r.tif"
        f.write_bytes(b"x")
    elif case == "3d":
        np.save(f, np.zeros((8, 8, 2), int))
    elif case == "range":
        np.save(f, np.full((8, 8), 7))
    elif case == "float":
        np.save(f, np.full((8, 8), 1.5))
    elif case == "colour":
        f = tmp_path / "r.png"
        plt.imsave(f, np.full((8, 8, 3), 17, np.uint8) + np.array([0, 1, 2], np.uint8))
    elif case == "empty":
        np.save(f, np.zeros((8, 8), int))
    elif case == "npzkeys":
        f = tmp_path / "r.npz"
        np.savez(f, a=np.ones((8, 8), int), b=np.ones((8, 8), int))
    elif case == "junk":
        f.write_bytes(b"garbage")
    elif case == "tiny":
        np.save(f, np.ones((4, 40), int))
    with pytest.raises(ValueError) as ei:
        load_class_raster(f)
    assert msg in str(ei.value) and "\n" not in str(ei.value)


def test_cli_semantic_bench_with_raster(tmp_path, capsys):
    rast = tmp_path / "campus.npy"
    np.save(rast, campus_map(np.random.default_rng(0), SMALL))
    d = tmp_path / "b"
    assert (
        main(
            [
                "bench",
                "--planner",
                "coverage",
                "--world",
                "semantic",
                "--raster",
                str(rast),
                "--map-size",
                str(SMALL),
                "--budget",
                "1200",
                "--envs",
                "2",
                "--out",
                str(d),
                "--quiet",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "Coverage" in out and "88.7" in out  # Table 2.2 beside ours
    assert (d / "ipp_bench.csv").is_file() and (d / "ipp_kl.png").is_file()


@pytest.mark.parametrize(
    "argv,msg",
    [
        (["bench", "--world", "semantic", "--raster", "nope.png"], "not found"),
        (["bench", "--raster", "x.npy"], "--world semantic"),
        (["bench", "--world", "moon"], "invalid choice"),
    ],
)
def test_cli_semantic_errors(argv, msg, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "x.npy").write_bytes(b"")
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and "\n" not in err
