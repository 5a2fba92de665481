"""Batched quadrotor simulator (thesis §3.3.1): arrays in, arrays out.

It knows nothing of goals, datasets or learning.
"""

from aerohrl.sim.params import GRAVITY, PRESETS, QuadrotorParams, get_preset
from aerohrl.sim.perturb import Perturbation
from aerohrl.sim.quadrotor import BatchedQuadrotor
from aerohrl.sim import dynamics, rotations

__all__ = ["GRAVITY", "PRESETS", "QuadrotorParams", "get_preset", "BatchedQuadrotor", "Perturbation", "dynamics", "rotations"]
