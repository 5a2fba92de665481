"""Vehicle parameters and presets (docs/spec.md "Vehicle and simulator", thesis §3.3.1).

A :class:`QuadrotorParams` holds what the rigid-body / rotor model of
:mod:`aerohrl.sim.dynamics` needs and nothing more (no drag, no rotor aerodynamics):
mass, diagonal inertia, an "x" rotor layout as in RotorPy (rotor i at
``d * (+-0.707, +-0.707, 0)``, spinning in ``rotor_directions``), thrust and yaw-moment
coefficients (``f_i = k_eta Omega_i^2``, ``M_z,i = dir_i k_m Omega_i^2``), the rotor speed
range, the motor time constant and the P gain ``k_w`` of the CTBR body-rate loop.

Presets (:data:`PRESETS`, :func:`get_preset`):

* ``hummingbird`` - the AscTec Hummingbird numbers published with RotorPy
  (``rotorpy/vehicles/hummingbird_params.py``), as fixed by docs/spec.md;
* ``crazyflie`` - Crazyflie 2.x, RotorPy 3.0.0's ``rotorpy/vehicles/crazyflie_params.py``
  (checked against the installed source): m 0.03 kg, J diag(1.43e-5, 1.43e-5, 2.89e-5),
  d 0.043 m, k_eta 2.3e-8, k_m 7.8e-10, 0..2500 rad/s and the *new* motor time constant
  tau_m = 0.072 s (RotorPy used 0.005 s before 2026-03).

Rate gain ``k_w`` (our choice, not RotorPy's; RotorPy's CTBR loop uses k_w = 1 for the
Hummingbird, a 1 s rate time constant, and 200 for the Crazyflie, which with
tau_m = 0.072 s is a damping ratio of 0.13). With the rate loop
``M = J k_w (w_cmd - w) + w x Jw`` and a first-order motor (thrust) lag tau_m, the
small-signal rate dynamics are ``tau_m s^2 + s + k_w = 0``, damping ratio
``zeta = 1 / (2 sqrt(k_w tau_m))``. We pick ``k_w`` for a well-damped loop that is as fast
as the motors allow, leaving margin for the 500 Hz sample-and-hold of the rate loop:

* Hummingbird, tau_m 0.005 s: k_w = 40 1/s -> zeta = 1.12, poles at -55 and -145 1/s
  (dominant time constant 18 ms, nominal 1/k_w = 25 ms; no overshoot);
* Crazyflie, tau_m 0.072 s: k_w = 5 1/s -> zeta = 0.83 (the slow motors of this preset
  allow no more with a pure P rate loop).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np


GRAVITY = 9.81  # m/s^2, docs/spec.md "Units and frames"

# RotorPy writes the x-layout with this literal; kept for a like-for-like comparison.
_S = 0.70710678118


@dataclass(frozen=True)
class QuadrotorParams:
    """Physical and inner-loop parameters of one quadrotor (SI units)."""

    name: str
    mass: float  # kg
    inertia: tuple[float, float, float]  # (Ixx, Iyy, Izz) kg m^2, principal axes = body axes
    arm_length: float  # m, rotor i at arm_length * rotor_layout[i]
    k_eta: float  # thrust coefficient, N / (rad/s)^2
    k_m: float  # yaw moment coefficient, N m / (rad/s)^2
    rotor_speed_min: float  # rad/s
    rotor_speed_max: float  # rad/s
    tau_m: float  # motor time constant, s
    k_w: float  # CTBR body-rate P gain, 1/s
    rotor_layout: tuple[tuple[float, float], ...] = ((_S, _S), (_S, -_S), (-_S, -_S), (-_S, _S))
    rotor_directions: tuple[int, ...] = (1, -1, 1, -1)  # sign of each rotor's yaw moment
    source: str = ""

    def __post_init__(self):
        if self.mass <= 0 or min(self.inertia) <= 0 or self.k_eta <= 0 or self.tau_m <= 0 or self.k_w <= 0:
            raise ValueError(f"{self.name}: mass, inertia, k_eta, tau_m and k_w must be positive")
        if not 0 <= self.rotor_speed_min < self.rotor_speed_max:
            raise ValueError(f"{self.name}: need 0 <= rotor_speed_min < rotor_speed_max")
        if len(self.rotor_layout) != 4 or len(self.rotor_directions) != 4:
            raise ValueError(f"{self.name}: a quadrotor has 4 rotors")

    # ------------------------------------------------------------------ derived
    @property
    def J(self) -> np.ndarray:
        """Inertia vector (Ixx, Iyy, Izz) as an array."""
        return np.asarray(self.inertia, dtype=np.float64)

    @property
    def rotor_positions(self) -> np.ndarray:
        """(4, 3) rotor hub positions in the body frame (m)."""
        xy = self.arm_length * np.asarray(self.rotor_layout, dtype=np.float64)
        return np.column_stack([xy, np.zeros(4)])

    @property
    def mixer(self) -> np.ndarray:
        """(4, 4) matrix mapping rotor thrusts f (N) to [T, Mx, My, Mz] (N, N m).

        T = sum f_i; (Mx, My) = sum r_i x (f_i e3) = sum f_i (y_i, -x_i);
        Mz = sum dir_i (k_m / k_eta) f_i. Same construction as RotorPy's ``f_to_TM``.
        """
        r = self.rotor_positions
        return np.vstack(
            [
                np.ones(4),
                r[:, 1],
                -r[:, 0],
                (self.k_m / self.k_eta) * np.asarray(self.rotor_directions, dtype=np.float64),
            ]
        )

    @property
    def hover_rotor_speed(self) -> float:
        """Rotor speed at which the four rotors carry the weight (rad/s)."""
        return math.sqrt(self.mass * GRAVITY / (4.0 * self.k_eta))

    @property
    def max_collective(self) -> float:
        """Largest mass-normalised collective thrust (m/s^2), all rotors at maximum speed."""
        return 4.0 * self.k_eta * self.rotor_speed_max**2 / self.mass

    @property
    def thrust_to_weight(self) -> float:
        return self.max_collective / GRAVITY

    def to_dict(self) -> dict:
        """JSON-able record (written into dataset metadata)."""
        d = asdict(self)
        d["inertia"] = list(self.inertia)
        d["rotor_layout"] = [list(xy) for xy in self.rotor_layout]
        d["rotor_directions"] = list(self.rotor_directions)
        d["gravity"] = GRAVITY
        d["derived"] = {
            "hover_rotor_speed": self.hover_rotor_speed,
            "max_collective": self.max_collective,
            "thrust_to_weight": self.thrust_to_weight,
        }
        return d

    def replace(self, **changes) -> "QuadrotorParams":
        """A copy with some fields changed (e.g. ``k_w``)."""
        return replace(self, **changes)


PRESETS: dict[str, QuadrotorParams] = {
    "hummingbird": QuadrotorParams(
        name="hummingbird",
        mass=0.5,
        inertia=(3.65e-3, 3.68e-3, 7.03e-3),
        arm_length=0.17,
        k_eta=5.57e-6,
        k_m=1.36e-7,
        rotor_speed_min=0.0,
        rotor_speed_max=1500.0,
        tau_m=0.005,
        k_w=40.0,
        source="AscTec Hummingbird as published with RotorPy (rotorpy/vehicles/hummingbird_params.py); docs/spec.md",
    ),
    "crazyflie": QuadrotorParams(
        name="crazyflie",
        mass=0.03,
        inertia=(1.43e-5, 1.43e-5, 2.89e-5),
        arm_length=0.043,
        k_eta=2.3e-8,
        k_m=7.8e-10,
        rotor_speed_min=0.0,
        rotor_speed_max=2500.0,
        tau_m=0.072,
        k_w=5.0,
        source="Crazyflie 2.x, rotorpy 3.0.0 rotorpy/vehicles/crazyflie_params.py (tau_m 0.072 s)",
    ),
}


def get_preset(name: str) -> QuadrotorParams:
    """The preset called ``name``; ``ValueError`` if there is none."""
    try:
        return PRESETS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown vehicle preset {name!r} (choose from: {', '.join(sorted(PRESETS))})") from None
