"""The batched simulator against results derived by hand (thesis §3.3.1 model)."""

import json
import math

import numpy as np
import pytest
from conftest import assert_fingerprint

from aerohrl.sim import GRAVITY, PRESETS, BatchedQuadrotor, get_preset
from aerohrl.sim import rotations as rot

HB = get_preset("hummingbird")
DT = 0.01


def hover_action(n, c=GRAVITY):
    a = np.zeros((n, 4))
    a[:, 0] = c
    return a


def test_presets_and_params():
    assert HB.mass == 0.5 and HB.inertia == (3.65e-3, 3.68e-3, 7.03e-3) and HB.arm_length == 0.17
    assert HB.k_eta == 5.57e-6 and HB.k_m == 1.36e-7 and HB.rotor_speed_max == 1500 and HB.tau_m == 0.005
    assert HB.hover_rotor_speed == pytest.approx(469.2, abs=0.1)
    assert HB.thrust_to_weight == pytest.approx(10.2, abs=0.05)
    cf = get_preset("crazyflie")
    assert cf.mass == 0.03 and cf.tau_m == 0.072 and cf.rotor_speed_max == 2500
    for p in PRESETS.values():
        json.dumps(p.to_dict())
        # mixer: rotor 1 at (+,+) -> positive roll moment r x f = f (y, -x)
        np.testing.assert_allclose(p.mixer[1:3, 0], p.arm_length * 0.70710678118 * np.array([1, -1]))
    with pytest.raises(ValueError, match="unknown vehicle preset 'nope'"):
        get_preset("nope")


def test_shape_validation():
    sim = BatchedQuadrotor(HB, 3)
    with pytest.raises(ValueError, match=r"shape \(3, 4\)"):
        sim.step(np.zeros((2, 4)))
    with pytest.raises(ValueError, match="NaN"):
        sim.step(np.full((3, 4), np.nan))
    with pytest.raises(ValueError, match=r"shape \(3, 18\)"):
        sim.reset(np.zeros((3, 17)))
    with pytest.raises(ValueError, match="not a rotation"):
        sim.reset(np.zeros((3, 18)))
    with pytest.raises(ValueError):
        BatchedQuadrotor(HB, 0)


def test_reset_layout():
    sim = BatchedQuadrotor(HB, 2)
    s = sim.reset()
    assert s.shape == (2, 18) and sim.state.shape == (2, 18) and sim.rotor_speeds.shape == (2, 4)
    np.testing.assert_array_equal(s[:, 6:15], np.tile(np.eye(3).ravel(), (2, 1)))
    np.testing.assert_allclose(sim.rotor_speeds, HB.hover_rotor_speed)
    st = np.zeros((2, 18))
    st[:, 6:15] = rot.from_euler("xyz", [[0.1, 0.2, 0.3], [0.0, -0.4, 1.0]]).reshape(2, 9)
    st[:, 0:3] = [[1, 2, 3], [-1, 0, 2]]
    np.testing.assert_allclose(sim.reset(st), st, atol=1e-14)
    # float32 data (R orthonormal to ~1e-7) is projected back onto the rotations
    R = sim.reset(st.astype(np.float32))[:, 6:15].reshape(2, 3, 3)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), (2, 3, 3)), atol=1e-15)


def test_hover_equilibrium():
    """At hover thrust with zero rates nothing moves, via CTBR and via rotor speeds."""
    sim = BatchedQuadrotor(HB, 2)
    s0 = sim.reset()
    for _ in range(300):
        s = sim.step(hover_action(2))
    np.testing.assert_allclose(s, s0, atol=1e-9)
    np.testing.assert_allclose(sim.rotor_speeds, HB.hover_rotor_speed, rtol=1e-12)
    sim.reset()
    for _ in range(300):
        s = sim.step_rotor_speeds(np.full((2, 4), HB.hover_rotor_speed))
    np.testing.assert_allclose(s, s0, atol=1e-9)


def test_free_fall_with_motor_spin_down():
    """Rotors commanded to 0 from hover: Omega = Omega_h e^{-t/tau}, thrust accel g e^{-2t/tau}.

    v_z(t) = -g t + g tau/2 (1 - e^{-2t/tau}),
    z(t)   = -g t^2/2 + g tau/2 (t - tau/2 (1 - e^{-2t/tau})).
    The motor lag is solved exactly within a substep (Omega to round-off); v and z come from
    RK4 (h = 0.002 s) on the decaying thrust g e^{-2t/tau} (time constant 2.5 ms): the
    tolerances are 0.1% of the spin-down impulse g tau / 2 = 0.025 m/s.
    """
    tau, g = HB.tau_m, GRAVITY
    sim = BatchedQuadrotor(HB, 1)
    sim.reset()
    for k in range(1, 51):
        s = sim.step_rotor_speeds(np.zeros((1, 4)))
        t = k * DT
        e = math.exp(-2 * t / tau)
        np.testing.assert_allclose(sim.rotor_speeds[0], HB.hover_rotor_speed * math.exp(-t / tau), rtol=1e-12, atol=1e-300)
        assert s[0, 5] == pytest.approx(-g * t + g * tau / 2 * (1 - e), abs=2.5e-5)
        assert s[0, 2] == pytest.approx(-g * t**2 / 2 + g * tau / 2 * (t - tau / 2 * (1 - e)), abs=1e-5)
    np.testing.assert_allclose(s[0, :2], 0, atol=1e-12)
    np.testing.assert_allclose(s[0, 6:15], np.eye(3).ravel(), atol=1e-12)
    np.testing.assert_allclose(s[0, 15:], 0, atol=1e-12)


def _rate_model(t, k_w, tau, w_cmd):
    """Small-signal rate response: tau w'' + w' = k_w (w_cmd - w), from rest (module doc of params)."""
    disc = math.sqrt(1 - 4 * tau * k_w)
    s1, s2 = (-1 + disc) / (2 * tau), (-1 - disc) / (2 * tau)
    return w_cmd * (1 - (s2 * np.exp(s1 * t) - s1 * np.exp(s2 * t)) / (s2 - s1))


@pytest.mark.parametrize("axis,w_cmd", [(0, 0.5), (1, -0.5), (2, 0.1)])
def test_rate_step_response(axis, w_cmd):
    """A rate step converges with the designed dynamics: first order 1/k_w plus the motor lag.

    The linear model ignores the 500 Hz sample-and-hold of the rate loop and the Omega^2
    nonlinearity; both are small for these commands (yaw is kept to 0.1 rad/s so that the
    weak yaw lever does not saturate the rotors). Tolerance 2% of the command.
    """
    sim = BatchedQuadrotor(HB, 1)
    sim.reset()
    a = hover_action(1)
    a[0, 1 + axis] = w_cmd
    ts, ws = [], []
    for k in range(1, 31):
        s = sim.step(a)
        ts.append(k * DT)
        ws.append(s[0, 15 + axis])
    ts, ws = np.array(ts), np.array(ws)
    model = _rate_model(ts, HB.k_w, HB.tau_m, w_cmd)
    np.testing.assert_allclose(ws, model, atol=0.02 * abs(w_cmd))
    assert abs(ws[-1] - w_cmd) < 0.01 * abs(w_cmd)  # settled after 0.3 s
    others = [i for i in range(3) if i != axis]
    np.testing.assert_allclose(s[0, 15 + np.array(others)], 0, atol=1e-9)
    R = s[0, 6:15].reshape(3, 3)
    if axis == 2:
        # yaw: positive wz turns body x towards world +y (counter-clockwise seen from above)
        assert R[1, 0] > 0
        # and the "+1" rotors (1, 3), whose drag torque is +z on the body, spin faster
        om = sim.rotor_speeds[0]
        assert om[0] > om[1] and om[2] > om[3]
    if axis == 0:
        assert R[2, 1] > 0  # roll: body y tips up


def test_orthonormal_over_long_aggressive_runs():
    """20 s of flight (2000 steps, 10^4 RK4 substeps) of random aggressive commands held for
    0.1 s each (rates up to 12 rad/s): R stays orthonormal to round-off (one Gram-Schmidt pass
    per control step). Without it the RK4 drift here reaches 7.5e-7."""
    rng = np.random.default_rng(3)
    n = 16
    sim = BatchedQuadrotor(HB, n)
    sim.reset()
    for k in range(2000):
        if k % 10 == 0:
            a = np.column_stack([rng.uniform(2, 25, n), rng.uniform(-12, 12, (n, 2)), rng.uniform(-3, 3, n)])
        s = sim.step(a)
    assert np.isfinite(s).all()
    R = s[:, 6:15].reshape(n, 3, 3)
    err = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max()
    assert err < 1e-13, err
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-13)


def test_rotor_limit_clipping():
    sim = BatchedQuadrotor(HB, 2)
    sim.reset()
    a = np.array([[1000.0, 0, 0, 0], [-50.0, 0, 0, 0]])
    for _ in range(10):
        s = sim.step(a)
    om = sim.rotor_speeds
    np.testing.assert_allclose(om[0], HB.rotor_speed_max, rtol=1e-6)  # saturated at the top
    np.testing.assert_allclose(om[1], HB.rotor_speed_min, atol=1e-3)  # and at the bottom
    assert (om >= HB.rotor_speed_min).all() and (om <= HB.rotor_speed_max).all()
    # once the motors have settled the vertical acceleration is the maximum collective - g
    v0 = s[:, 5].copy()
    s = sim.step(a)
    assert (s[0, 5] - v0[0]) / DT == pytest.approx(HB.max_collective - GRAVITY, rel=1e-6)
    assert (s[1, 5] - v0[1]) / DT == pytest.approx(-GRAVITY, rel=1e-6)
    # direct rotor-speed commands are clipped to the range as well
    sim.reset()
    for _ in range(10):
        sim.step_rotor_speeds(np.array([[5000.0] * 4, [-5.0] * 4]))
    np.testing.assert_allclose(sim.rotor_speeds[0], HB.rotor_speed_max, rtol=1e-6)
    np.testing.assert_allclose(sim.rotor_speeds[1], 0.0, atol=1e-3)


def test_yaw_is_deprioritised_when_saturating():
    """A yaw demand that would saturate rotors is scaled down; thrust and roll/pitch stay exact."""
    from aerohrl.sim import dynamics as dyn

    m = dyn.Model.from_params(HB)
    n = 3
    s = dyn.Scratch(n)
    w = np.zeros((3, n))
    ctbr = np.array([[GRAVITY, GRAVITY, GRAVITY], [0.0, 0.5, 0.0], [0.0, 0.0, 0.0], [0.01, 5.0, -5.0]])
    om = dyn.rate_loop(w, ctbr, m, np.empty((4, n)), s)
    f = HB.k_eta * om**2
    TM = HB.mixer @ f
    np.testing.assert_allclose(TM[0], HB.mass * GRAVITY, rtol=1e-12)  # collective kept
    np.testing.assert_allclose(TM[1], HB.inertia[0] * HB.k_w * ctbr[1], atol=1e-12)  # roll kept
    np.testing.assert_allclose(TM[2], 0.0, atol=1e-12)
    Mz_full = HB.inertia[2] * HB.k_w * ctbr[3]
    assert TM[3, 0] == pytest.approx(Mz_full[0], rel=1e-9)  # small demand: unchanged
    assert 0 < TM[3, 1] < Mz_full[1] and Mz_full[2] < TM[3, 2] < 0  # large demand: scaled, same sign
    np.testing.assert_allclose(om[:, 1:].min(axis=0), 0.0, atol=1e-4)  # ... just to saturation (Omega = 0)


def test_batch_independence():
    """Vehicle i's trajectory does not depend on the others (nor on the thread split).

    Equal up to round-off: the 4x4 products (``np.einsum``: wrench and allocation) pick
    shape-dependent summation kernels, so a batch of 1 and a batch of 5 can differ in the
    last bit; 60 steps of aggressive random rates amplify that to ~1e-9. A real coupling
    would show up at the size of the states themselves. Splitting one batch across
    threads keeps the per-vehicle arithmetic and is bit-exact.
    """
    rng = np.random.default_rng(0)
    n, steps = 5, 60
    acts = np.concatenate([rng.uniform(5, 15, (steps, n, 1)), rng.uniform(-3, 3, (steps, n, 3))], axis=2)
    sim = BatchedQuadrotor(HB, n)
    sim.reset()
    for k in range(steps):
        s_all = sim.step(acts[k])
    for i in (0, 3):
        one = BatchedQuadrotor(HB, 1)
        one.reset()
        for k in range(steps):
            s_one = one.step(acts[k, i : i + 1])
        np.testing.assert_allclose(s_one[0], s_all[i], rtol=1e-7, atol=1e-7)
    # thread split
    big = 64
    a = np.column_stack([rng.uniform(5, 15, big), rng.uniform(-3, 3, (big, 3))])
    s1 = BatchedQuadrotor(HB, big, threads=1)
    s2 = BatchedQuadrotor(HB, big, threads=2)
    for _ in range(20):
        x1, x2 = s1.step(a), s2.step(a)
    np.testing.assert_array_equal(x1, x2)


def test_rotation_helpers():
    rng = np.random.default_rng(1)
    w = rng.normal(size=(4, 3))
    x = rng.normal(size=(4, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", rot.hat(w), x), np.cross(w, x))
    np.testing.assert_allclose(rot.vee(rot.hat(w)), w)
    R = rot.from_euler("xyz", rng.normal(size=(4, 3)))
    np.testing.assert_allclose(rot.from_quat(rot.to_quat(R)), R, atol=1e-12)
    Rn = rot.orthonormalize(R + 1e-6 * rng.normal(size=R.shape), iterations=2)
    np.testing.assert_allclose(Rn @ np.swapaxes(Rn, 1, 2), np.broadcast_to(np.eye(3), (4, 3, 3)), atol=1e-13)
    assert rot.geodesic_angle(R, R) == pytest.approx(0.0, abs=1e-7)


def test_process_split_matches_one_process():
    """Splitting the batch over worker processes (shared memory) gives the same states,
    through reset with given states, CTBR steps and rotor-speed steps; close() stops the
    workers and frees their memory."""
    rng = np.random.default_rng(3)
    n = 97
    a = np.column_stack([rng.uniform(5, 15, n), rng.uniform(-3, 3, (n, 3))])
    ref = BatchedQuadrotor(HB, n)
    start = ref.step(a)
    x1 = ref.reset(start)
    with BatchedQuadrotor(HB, n, processes=3) as par:
        workers = [c._proc for c in par._chunks[1:]]
        assert len(workers) == 2 and all(p.is_alive() for p in workers)
        np.testing.assert_array_equal(par.reset(start), x1)
        for _k in range(7):  # several steps of the worker's shared state
            np.testing.assert_array_equal(par.step(a), ref.step(a))
        om = np.full((n, 4), HB.hover_rotor_speed * 1.05)
        np.testing.assert_array_equal(par.step_rotor_speeds(om), ref.step_rotor_speeds(om))
        np.testing.assert_array_equal(par.rotor_speeds, ref.rotor_speeds)
    for p in workers:
        p.join(timeout=5)
        assert not p.is_alive()
    with pytest.raises(ValueError, match="threads or processes"):
        BatchedQuadrotor(HB, n, threads=2, processes=2)


def test_select_keeps_a_subset_bit_for_bit():
    import numpy as np

    from aerohrl.sim import BatchedQuadrotor, get_preset

    rng = np.random.default_rng(0)
    full = BatchedQuadrotor(get_preset("hummingbird"), 10)
    u = np.tile([9.81, 0.0, 0.0, 0.0], (10, 1)) + rng.normal(0.0, 1.0, (10, 4))
    for _ in range(20):
        full.step(u)
    rows = np.array([1, 4, 7])
    part = full.select(rows)
    for _ in range(20):
        a, b = full.step(u), part.step(u[rows])
    np.testing.assert_array_equal(a[rows], b)
    np.testing.assert_array_equal(full.rotor_speeds[rows], part.rotor_speeds)


# fingerprints (conftest.fingerprint) of _aggressive_flight(kind), the reference values of the
# float64 simulator: a change to its dynamics (a term, a step fused or skipped) shows here;
# round-off (numpy's SIMD path on another CPU, a reordered sum) does not
FLIGHT_REFERENCE = {
    "ctbr": [1746.8814187445842, 40636.775268269936, -39837.39897092414, 12041.016927713641, 4809724.607800027],
    "speeds": [-59844.93519032156, 76652.26753605503, -64486.315308292025, -3281.312800045638, 7970062.559629225],
    "perturbed": [-15381.834473463043, 13538.76218813749, -5317.446149909632, 17867.131829229067, 4945742.152007398],
}


def _aggressive_flight(kind: str) -> bytes:
    """States of 64 vehicles from random poses under saturating commands (CTBR, rotor
    speeds, or CTBR on a perturbed plant), every step's state and rotor speeds."""
    from aerohrl.sim import Perturbation

    rng = np.random.default_rng(11)
    n = 64
    start = np.column_stack(
        [rng.normal(0, 3, (n, 6)), rot.from_euler("xyz", rng.uniform(-1.2, 1.2, (n, 3))).reshape(n, 9), rng.normal(0, 3, (n, 3))]
    )
    perturbation = None
    if kind == "perturbed":
        perturbation = Perturbation(
            mass=rng.uniform(0.8, 1.3, n), inertia=1.2, motor_tau=2.0, latency=0.013, drag=0.3, wind=2.0, gust=0.5
        )
    sim = BatchedQuadrotor(HB, n, perturbation=perturbation, seed=2)
    out = [sim.reset(start, rng.uniform(0, HB.rotor_speed_max, (n, 4)))]
    for _ in range(40):
        if kind == "speeds":
            out.append(sim.step_rotor_speeds(rng.uniform(-100, 1.1 * HB.rotor_speed_max, (n, 4))))
        else:
            out.append(sim.step(np.column_stack([GRAVITY + rng.normal(0, 15, n), rng.normal(0, 10, (n, 3))])))
        out.append(sim.rotor_speeds)
    return np.concatenate([o.ravel() for o in out]).tobytes()


@pytest.mark.parametrize("kind", sorted(FLIGHT_REFERENCE))
def test_float64_values_unchanged(kind):
    """Saturating flights (yaw de-prioritised both ways, rotors at both limits) keep the
    reference values, on the nominal and the perturbed plant, and are bytewise repeatable."""
    flight = _aggressive_flight(kind)
    assert flight == _aggressive_flight(kind)
    assert_fingerprint(np.frombuffer(flight), FLIGHT_REFERENCE[kind], kind)


def test_float32_mode_is_explicit_and_close_to_float64():
    """dtype=np.float32 keeps and integrates the state in float32 (the public arrays stay
    float64); over a second of aggressive flight it stays within round-off of float64."""
    rng = np.random.default_rng(4)
    n = 32
    acts = [np.column_stack([GRAVITY + rng.normal(0, 2, n), rng.normal(0, 1, (n, 3))]) for _ in range(100)]
    s64 = BatchedQuadrotor(HB, n)
    s32 = BatchedQuadrotor(HB, n, dtype=np.float32)
    assert s64.dtype is np.float64 and s32.dtype is np.float32
    assert s32._chunks[0].X.dtype == np.float32 and s32.state.dtype == np.float64
    for a in acts:
        x64, x32 = s64.step(a), s32.step(a)
    # open loop: rates up to ~3 rad/s flown for 1 s, the float32 drift stays at the mm / mrad level
    assert np.abs(x32[:, :3] - x64[:, :3]).max() < 1e-2
    R32, R64 = x32[:, 6:15].reshape(-1, 3, 3), x64[:, 6:15].reshape(-1, 3, 3)
    assert rot.geodesic_angle(R32, R64).max() < 1e-2
    np.testing.assert_allclose(R32 @ np.swapaxes(R32, 1, 2), np.broadcast_to(np.eye(3), (n, 3, 3)), atol=1e-5)
    # hover is still an equilibrium
    h = BatchedQuadrotor(HB, 2, dtype=np.float32)
    for _ in range(100):
        st = h.step(hover_action(2))
    np.testing.assert_allclose(st[:, :6], 0.0, atol=1e-3)


def test_float32_process_split_and_limits():
    rng = np.random.default_rng(5)
    n = 41
    a = np.column_stack([rng.uniform(5, 15, n), rng.uniform(-3, 3, (n, 3))])
    one = BatchedQuadrotor(HB, n, dtype=np.float32)
    with BatchedQuadrotor(HB, n, processes=2, dtype=np.float32) as two:
        for _ in range(5):
            np.testing.assert_array_equal(two.step(a), one.step(a))
    assert one.select([1, 3]).dtype is np.float32
    from aerohrl.sim import Perturbation

    with pytest.raises(ValueError, match="float64 only"):
        BatchedQuadrotor(HB, 2, dtype=np.float32, perturbation=Perturbation(mass=1.1))
    with pytest.raises(ValueError, match="float64 or float32"):
        BatchedQuadrotor(HB, 2, dtype=np.float16)
