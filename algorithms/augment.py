"""Mirror augmentation: the quadrotor's exact reflection symmetries applied to a batch.

Reflecting the world in the x-z or y-z plane, ``M = diag(s_x, s_y, 1)`` with
``s_x, s_y in {+1, -1}`` (both -1: a 180-degree turn about z), maps a flight of the
vehicle onto another flight of the same vehicle:

    p' = M p,   v' = M v,   R' = M R M,   w' = det(M) M w       (state, 18)
    [p_g, v_g, R_g]' = [M p_g, M v_g, M R_g M]                    (goal, 15)
    [c, w_cmd]' = [c, det(M) M w_cmd]                             (CTBR action, 4)

because gravity is along z, the inertia is diagonal, and the "x" rotor layout maps onto
itself with every rotor's spin reversed (rotor (+x, +y) <-> (+x, -y) has the opposite
yaw-moment sign, sim/params.py), so the mixer, the rotor limits and the yaw
de-prioritisation commute with M. (``R' = M R M`` keeps R a rotation: the body axes
are reflected with the world; from ``dR/dt = R [w]x`` and ``M [w]x M = [det(M) M w]x``
the body rates transform as a pseudovector.) ``tests/test_augment.py`` flies both sides
in the simulator. The goal-reached test (distances and the geodesic angle) is invariant,
so rewards, done flags and Monte-Carlo bounds computed before the reflection stay valid.

The expert dataset's goal distribution rho_D is itself mirror symmetric (random signs of
|p_i|, symmetric velocity and acceleration ranges, yaw 0 is kept by R' = M R M), so the
4 reflections multiply the distinct trajectories a policy sees by 4 without leaving rho_D.
"""

from __future__ import annotations

import torch

AUGMENTATIONS = ("none", "mirror")


def draw_reflections(n: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """(n, 3) diagonals of ``M``: ``(s_x, s_y, 1)`` with independent fair signs."""
    s = torch.randint(0, 2, (n, 2), generator=generator).to(torch.float32) * 2.0 - 1.0
    return torch.cat([s, torch.ones(n, 1)], -1)


def mirror_goal(x: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """``[p, v, R]`` (first 15 entries of ``x``, R row-major) reflected by ``diag(m)``;
    further entries (a state's body rates) are copied unchanged."""
    m = m.to(x.dtype)
    out = x.clone()
    out[..., 0:3] = x[..., 0:3] * m
    out[..., 3:6] = x[..., 3:6] * m
    out[..., 6:15] = (x[..., 6:15].reshape(*x.shape[:-1], 3, 3) * m[..., :, None] * m[..., None, :]).reshape(*x.shape[:-1], 9)
    return out


def mirror_state(x: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """An (.., 18) state ``[p, v, R, w]`` reflected by ``diag(m)``."""
    out = mirror_goal(x, m)
    m = m.to(x.dtype)
    out[..., 15:18] = x[..., 15:18] * m * m.prod(-1, keepdim=True)
    return out


def mirror_action(a: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """A CTBR action ``[c, w_cmd]`` reflected by ``diag(m)``: thrust kept, rates as w."""
    m = m.to(a.dtype)
    out = a.clone()
    out[..., 1:4] = a[..., 1:4] * m * m.prod(-1, keepdim=True)
    return out


__all__ = ["AUGMENTATIONS", "draw_reflections", "mirror_goal", "mirror_state", "mirror_action"]
