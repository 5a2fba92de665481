"""Our simulator against RotorPy's ``Multirotor`` on identical rotor-speed inputs.

RotorPy (installed 3.0.0) is run with ``aero=False`` (no parasitic drag, rotor drag,
flapping or translational lift: the thesis §3.3.1 model), ground contact off, motor
noise 0, the ``cmd_motor_speeds`` abstraction and the same parameters as our preset.
It integrates each 0.01 s step with ``scipy.solve_ivp`` (RK45; here rtol = atol = 1e-10
so that its error is negligible), the quaternion renormalised after each step; we use
5 fixed RK4 substeps (motor lag solved exactly). Both hold the command through the
step, so both solve the same ODE and the differences are our truncation error.

Tolerances, per step over 2 s of varying commands that tilt the vehicle by 40-60 deg
and spin it up in yaw (to 33 rad/s for the Crazyflie), measured maxima in brackets
(Hummingbird / Crazyflie): position 2e-6 m (4.3e-7 / 1e-9), velocity 2e-6 m/s
(3.8e-7 / 3e-8), rotation-matrix entries 3e-5 (7e-8 / 2.8e-6), body rates 1e-4 rad/s
(1e-7 / 8.6e-6), rotor speeds 1e-6 rad/s (4e-8 / 2e-8; we solve the motor lag exactly).
The Hummingbird's error is RK4 on its fast thrust transients (thrust time constant
tau_m / 2 = 2.5 ms against the 2 ms substep); the Crazyflie's is the fast yaw spin.
"""

import numpy as np
import pytest

rotorpy = pytest.importorskip("rotorpy")
from rotorpy.vehicles.multirotor import Multirotor  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from aerohrl.sim import BatchedQuadrotor, get_preset  # noqa: E402


def rotorpy_params(p):
    r = p.rotor_positions
    return {
        "mass": p.mass,
        "Ixx": p.inertia[0],
        "Iyy": p.inertia[1],
        "Izz": p.inertia[2],
        "Ixy": 0.0,
        "Iyz": 0.0,
        "Ixz": 0.0,
        "num_rotors": 4,
        "rotor_pos": {f"r{i + 1}": r[i] for i in range(4)},
        "rotor_directions": np.array(p.rotor_directions),
        "rI": np.zeros(3),
        "c_Dx": 0.0,
        "c_Dy": 0.0,
        "c_Dz": 0.0,
        "k_eta": p.k_eta,
        "k_m": p.k_m,
        "k_d": 0.0,
        "k_z": 0.0,
        "k_h": 0.0,
        "k_flap": 0.0,
        "tau_m": p.tau_m,
        "rotor_speed_min": p.rotor_speed_min,
        "rotor_speed_max": p.rotor_speed_max,
        "motor_noise_std": 0.0,
    }


def commands(p, steps):
    """Smoothly varying rotor speeds around hover (differential terms roll, pitch and yaw)."""
    t = np.arange(steps) * 0.01
    h = p.hover_rotor_speed
    base = h * (1.0 + 0.05 * np.sin(2.1 * t))
    roll = 0.004 * h * np.sin(3.0 * t + 0.3)
    pitch = 0.004 * h * np.sin(2.3 * t + 1.1)
    yaw = 0.04 * h * np.sin(1.7 * t)
    cmd = np.stack(
        [base + roll - pitch + yaw, base - roll - pitch - yaw, base - roll + pitch + yaw, base + roll + pitch - yaw], 1
    )
    return np.clip(cmd, 0.0, None)


@pytest.mark.parametrize("preset", ["hummingbird", "crazyflie"])
def test_matches_rotorpy_multirotor(preset):
    p = get_preset(preset)
    steps = 200  # 2 s
    cmd = commands(p, steps)
    hover = np.full(4, p.hover_rotor_speed)
    init = {
        "x": np.zeros(3),
        "v": np.zeros(3),
        "q": np.array([0.0, 0.0, 0.0, 1.0]),
        "w": np.zeros(3),
        "wind": np.zeros(3),
        "rotor_speeds": hover.copy(),
    }
    vehicle = Multirotor(
        rotorpy_params(p),
        initial_state=init,
        control_abstraction="cmd_motor_speeds",
        aero=False,
        enable_ground=False,
        integrator_kwargs={"method": "RK45", "rtol": 1e-10, "atol": 1e-10},
    )
    sim = BatchedQuadrotor(p, 1)
    sim.reset()
    state = {k: v.copy() for k, v in init.items()}
    max_tilt = 0.0
    for k in range(steps):
        state = vehicle.step(state, {"cmd_motor_speeds": cmd[k]}, 0.01)
        ours = sim.step_rotor_speeds(cmd[k : k + 1])[0]
        R_ref = Rotation.from_quat(state["q"]).as_matrix()
        np.testing.assert_allclose(ours[0:3], state["x"], atol=2e-6, rtol=0, err_msg=f"position, step {k}")
        np.testing.assert_allclose(ours[3:6], state["v"], atol=2e-6, rtol=0, err_msg=f"velocity, step {k}")
        np.testing.assert_allclose(ours[6:15], R_ref.ravel(), atol=3e-5, rtol=0, err_msg=f"rotation, step {k}")
        np.testing.assert_allclose(ours[15:18], state["w"], atol=1e-4, rtol=0, err_msg=f"body rates, step {k}")
        np.testing.assert_allclose(sim.rotor_speeds[0], state["rotor_speeds"], atol=1e-6, rtol=0, err_msg=f"rotors, step {k}")
        max_tilt = max(max_tilt, np.arccos(np.clip(R_ref[2, 2], -1, 1)))
    # the run is not trivial: the vehicle moved, tilted and turned
    assert np.linalg.norm(state["x"]) > 1.0 and max_tilt > 0.5
