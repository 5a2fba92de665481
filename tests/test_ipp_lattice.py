"""Motion-primitive lattice: dispersion (Eq. 2.3), bounds, tiling, file format."""

import json

import numpy as np
import pytest

from aerohrl.ipp.lattice import (
    DEFAULT_PATH,
    LatticeConfig,
    build_lattice,
    dispersion,
    jerk_cost,
    load_lattice,
    peak_speed_accel,
    poly_eval,
    save_lattice,
    transfer_cost,
    velocity_samples,
)

SMALL = LatticeConfig(n_vertices=6, reach=4, max_edges=10, t_step=0.2, hover_moves=(1, 3))


@pytest.fixture(scope="module")
def small():
    return build_lattice(SMALL)


@pytest.fixture(scope="module")
def default():
    return load_lattice(DEFAULT_PATH)


def test_dispersion_never_rises(small, default):
    for lat in (small, default):
        d = lat.dispersion
        assert len(d) == lat.n_vertices
        assert np.all(np.diff(d) <= 1e-9)
        assert d[-1] < d[0]
    # the stored values are Eq. 2.3 recomputed for every prefix of the vertex set
    cfg = SMALL
    X = velocity_samples(cfg.vertex_speed * cfg.v_max, cfg.velocity_samples)
    for k in range(1, small.n_vertices + 1):
        assert dispersion(X, small.vertices[:k], cfg.rho, cfg.a_max) == pytest.approx(small.dispersion[k - 1])


def test_transfer_cost_matches_quadrature():
    x, v, rho, amax = np.array([0.3, -1.0]), np.array([2.0, 0.5]), 100.0, 3.0
    J = transfer_cost(x, v, rho, amax)
    dv = np.linalg.norm(v - x)
    Ts = np.linspace(0.2, 6, 20000)
    s = np.linspace(0, 1, 2001)
    best = np.inf
    for T in Ts[::50]:
        jerk = dv * (6 - 12 * s) / T**2
        if 1.5 * dv / T > amax:
            continue
        best = min(best, rho * T + np.trapezoid(jerk**2, s * T))
    assert J == pytest.approx(best, rel=2e-3)
    assert transfer_cost(x, x, rho, amax) == 0.0


def test_primitives_respect_bounds_and_boundary_conditions(default):
    lat, cfg = default, default.config
    vpk, apk = peak_speed_accel(lat.prim_coef, lat.prim_T, 4001)
    assert np.all(vpk <= cfg.v_max * (1 + 1e-6))
    assert np.all(apk <= cfg.a_max * (1 + 1e-6))
    T = lat.prim_T[:, None, None]
    p0 = poly_eval(lat.prim_coef, np.zeros((lat.n_prims, 1, 1)))[..., 0]
    p1 = poly_eval(lat.prim_coef, T)[..., 0]
    v0 = poly_eval(lat.prim_coef, np.zeros((lat.n_prims, 1, 1)), 1)[..., 0]
    v1 = poly_eval(lat.prim_coef, T, 1)[..., 0]
    a0 = poly_eval(lat.prim_coef, np.zeros((lat.n_prims, 1, 1)), 2)[..., 0]
    a1 = poly_eval(lat.prim_coef, T, 2)[..., 0]
    np.testing.assert_allclose(p0, 0, atol=1e-9)
    np.testing.assert_allclose(p1, lat.prim_disp, atol=1e-8)
    np.testing.assert_allclose(v0, lat.vertices[lat.prim_from], atol=1e-9)
    np.testing.assert_allclose(v1, lat.vertices[lat.prim_to], atol=1e-8)
    np.testing.assert_allclose(a0, 0, atol=1e-9)
    np.testing.assert_allclose(a1, 0, atol=1e-7)
    # cost = rho*T + int |jerk|^2, the integral checked by quadrature
    t = np.linspace(0, 1, 4001)[None, None, :] * T
    jerk = poly_eval(lat.prim_coef, t, 3)
    num = np.trapezoid((jerk**2).sum(1), t[:, 0, :], axis=-1)
    np.testing.assert_allclose(lat.prim_cost, cfg.rho * lat.prim_T + num, rtol=1e-5)
    np.testing.assert_allclose(jerk_cost(lat.prim_coef, lat.prim_T), num, rtol=1e-5)


def test_edges_and_sensing_tables(default):
    lat = default
    assert lat.edges.shape == (lat.n_vertices, lat.n_actions)
    used = lat.edges[lat.edges >= 0]
    assert sorted(used.tolist()) == list(range(lat.n_prims))
    for v in range(lat.n_vertices):
        e = lat.edges[v][lat.edges[v] >= 0]
        assert len(e) > 0 and np.all(lat.prim_from[e] == v)
    # hover keeps cardinal moves of 1 and 5 cells back to hover
    hov = lat.edges[0][lat.edges[0] >= 0]
    ends = {tuple(d) for d, j in zip(lat.prim_disp[hov], lat.prim_to[hov]) if j == 0}
    for m in (1, 5):
        assert {(m, 0), (-m, 0), (0, m), (0, -m)} <= ends
    # per-cell counts aggregate the measurement list exactly
    for p in range(0, lat.n_prims, 17):
        cells, lev = lat.sensed_cells(p)
        keep = lat.cell_count[p].sum(1) > 0
        assert lat.cell_count[p].sum() == len(cells)
        for (x, y), cnt in zip(lat.cell_off[p][keep], lat.cell_count[p][keep]):
            m = (cells[:, 0] == x) & (cells[:, 1] == y)
            assert np.array_equal(np.bincount(lev[m], minlength=lat.n_levels), cnt)
        assert lev.max() <= lat.config.footprint_radius


def test_tiling_reproduces_the_primitive_everywhere(default):
    lat = default
    for p in (0, 33, lat.n_prims - 1):
        base = lat.positions(p)
        cells, lev = lat.sensed_cells(p)
        for origin in [(0, 0), (3, 11), (29, 0), (17, 25)]:
            np.testing.assert_allclose(lat.positions(p, origin), base + np.array(origin))
            c2, l2 = lat.sensed_cells(p, origin)
            assert np.array_equal(c2, cells + np.array(origin)) and np.array_equal(l2, lev)
    # in the environment: the same primitive senses the same pattern at every cell
    from aerohrl.ipp.env import EnvConfig, SearchEnv
    from aerohrl.ipp.world import WorldConfig, sample_worlds

    env = SearchEnv(EnvConfig(), lat)
    env.reset(sample_worlds(WorldConfig(), 0, [0, 1, 2]), start=np.array([[5, 5], [15, 9], [22, 20]]))
    p = int(lat.edges[0, 0])
    off = np.broadcast_to(lat.meas_off[p].astype(np.int64), (3,) + lat.meas_off[p].shape)
    flat = env.flat_index(off)
    local = flat - np.arange(3)[:, None] * env.Hp * env.Hp
    y, x = np.divmod(local, env.Hp)
    for n in range(3):
        np.testing.assert_array_equal(x[n] - x[n, 0], off[n, :, 0] - off[n, 0, 0])
        np.testing.assert_array_equal(y[n] - y[n, 0], off[n, :, 1] - off[n, 0, 1])
        assert x[n, 0] - env.pad - env.pos[n, 0] == off[n, 0, 0]


def test_save_load_roundtrip(small, tmp_path):
    f = save_lattice(small, tmp_path / "l.npz")
    back = load_lattice(f)
    assert back.config == small.config
    for k in ("vertices", "edges", "prim_coef", "meas_off", "cell_count", "dispersion"):
        np.testing.assert_array_equal(getattr(back, k), getattr(small, k))


def test_shipped_lattice_is_current(default):
    fresh = build_lattice(LatticeConfig())
    assert default.config == fresh.config
    for k in ("vertices", "edges", "prim_disp", "prim_to", "meas_off", "meas_level", "cell_count"):
        np.testing.assert_array_equal(getattr(default, k), getattr(fresh, k))
    assert DEFAULT_PATH.stat().st_size < 200_000


def _rewrite(src, dst, **changes):
    with np.load(src) as z:
        d = {k: z[k] for k in z.files}
    for k, v in changes.items():
        if v is None:
            d.pop(k)
        else:
            d[k] = v
    np.savez(dst, **d)
    return dst


@pytest.mark.parametrize("case", ["junk", "empty", "missing", "version", "format", "edges", "meta", "shape"])
def test_malformed_lattice_files(small, tmp_path, case):
    good = save_lattice(small, tmp_path / "good.npz")
    bad = tmp_path / "bad.npz"
    meta = json.loads(str(np.load(good)["meta"]))
    if case == "junk":
        bad.write_bytes(b"not a zip at all")
    elif case == "empty":
        bad.write_bytes(b"")
    elif case == "missing":
        _rewrite(good, bad, meas_off=None)
    elif case == "version":
        _rewrite(good, bad, meta=np.array(json.dumps({**meta, "version": 99})))
    elif case == "format":
        _rewrite(good, bad, meta=np.array(json.dumps({**meta, "format": "other"})))
    elif case == "edges":
        e = small.edges.copy()
        e[0, 0] = small.n_prims + 5
        _rewrite(good, bad, edges=e)
    elif case == "meta":
        _rewrite(good, bad, meta=np.array("{not json"))
    elif case == "shape":
        _rewrite(good, bad, prim_T=small.prim_T[:-1])
    with pytest.raises(ValueError) as ei:
        load_lattice(bad)
    assert "\n" not in str(ei.value)


def test_bad_config():
    with pytest.raises(ValueError):
        build_lattice(LatticeConfig(n_vertices=0))
    with pytest.raises(ValueError):
        build_lattice(LatticeConfig(hover_moves=(9,), reach=4))


@pytest.mark.slow
def test_shipped_semantic_lattice_is_current():
    from aerohrl.ipp.lattice import SEMANTIC_LATTICE, SEMANTIC_PATH

    shipped = load_lattice(SEMANTIC_PATH)
    fresh = build_lattice(SEMANTIC_LATTICE)
    assert shipped.config == fresh.config
    for k in ("vertices", "edges", "prim_disp", "prim_to", "meas_off", "meas_level", "cell_count"):
        np.testing.assert_array_equal(getattr(shipped, k), getattr(fresh, k))
    assert SEMANTIC_PATH.stat().st_size < 400_000
