r"""Minimum-time minimum-jerk polynomial references (thesis §3.4.1, Alg. 1; docs/spec.md).

Per axis one polynomial ``x(t) = sum_k c_k t^k`` (power basis, ``t`` in seconds from
the start) joins ``(p, v, a)`` at ``t = 0`` to ``(p, v, a)`` at ``t = T`` and minimises
the integrated squared jerk ``J = int_0^T x'''(t)^2 dt`` subject to
``|x''(t)| <= a_max``. The three axes share one duration ``T``: a reference is
feasible iff every axis is. Minimum ``T`` by bisection (Alg. 1).

Arrays: boundary states ``x0, xf`` are (N, 3, 3) indexed ``[n, axis, (p, v, a)]``;
coefficients are (N, 3, degree + 1), lowest power first.

Normalised time
---------------
Everything is solved in ``tau = t / T`` in [0, 1] with ``d_k = c_k T^k``, so that
``x(tau) = sum_k d_k tau^k``, ``dx/dtau = T v``, ``d2x/dtau2 = T^2 a`` and
``J = T^-5 int_0^1 (d3x/dtau3)^2 dtau``. The problem matrices then no longer depend on
``T`` or on the goal; only the right-hand sides do.

Closed form (degree 5; Mueller, Hehn & D'Andrea, IEEE T-RO 31(6), 2015)
----------------------------------------------------------------------
Without the bound the minimiser satisfies ``x^(6) = 0``: a quintic, fixed uniquely by
the 6 boundary conditions. Hence, for degree 5, the bounded problem has exactly one
candidate and is feasible iff that quintic respects the bound. With
``d0 = p0, d1 = v0 T, d2 = a0 T^2 / 2`` and the residuals

    r0 = pf - p0 - v0 T - a0 T^2 / 2
    r1 = (vf - v0 - a0 T) T
    r2 = (af - a0) T^2

the conditions at ``tau = 1`` read ``[[1,1,1],[3,4,5],[6,12,20]] (d3,d4,d5) = (r0,r1,r2)``,
whose inverse gives

    d3 =  10 r0 - 4 r1 + r2 / 2
    d4 = -15 r0 + 7 r1 - r2
    d5 =   6 r0 - 3 r1 + r2 / 2

(equivalently, in MHD's notation, ``alpha = 120 c5 = (720 Dp - 360 T Dv + 60 T^2 Da) / T^5``
with ``Dp = r0, Dv = r1 / T, Da = r2 / T^2``). Feasibility of the closed form is
checked *exactly*: ``a(tau) T^2 = 2 d2 + 6 d3 tau + 12 d4 tau^2 + 20 d5 tau^3`` is a
cubic whose extrema on [0, 1] are the end points and the real roots of the quadratic
jerk ``6 d3 + 24 d4 tau + 60 d5 tau^2`` (:func:`max_acceleration`); a quintic is
feasible iff ``max |a| <= a_max (1 + 1e-9)`` (round-off only).

QP (any degree >= 5; OSQP)
--------------------------
Variables ``z = d / L`` with ``L = a_max T^2`` (the bound in normalised units), so that
the acceleration bound becomes ``-1 <= d2x/dtau2 / L <= 1``:

    minimise   z^T H z,   H_jk = j(j-1)(j-2) k(k-1)(k-2) / (j+k-5)   (j, k >= 3)
    subject to 6 boundary rows (value, slope, curvature at tau = 0 and tau = 1) = rhs / L
               -1 <= sum_k k(k-1) tau_s^(k-2) z_k <= 1   at n_samples times tau_s

``H`` and the constraint matrix are constants, so one OSQP workspace per
``(degree, n_samples)`` (and axis) is set up once and each solve is only
``update(l=, u=)``. A solve counts as feasible iff OSQP returns ``solved``; primal
infeasibility, ``max_iter`` ("the optimisation times out", Alg. 1) or an inaccurate
status all count as infeasible. Each reference starts from ``z = 0, y = 0`` and
``rho = 10`` (Alg. 1 line 4), and later bisection steps warm-start from that axis's
last solved iterate; so a reference's result depends on its own inputs only, not on
the batch it came in (the dataset bytes stay a function of the spec).

Tolerances (:data:`OSQP_SETTINGS`): ``eps_abs = eps_rel = 1e-6`` on unscaled residuals
of ``z`` (i.e. ``1e-6 a_max`` on the sampled accelerations, ``<= 1e-6 a_max T^2`` m on the
end position), polishing on, ``max_iter = 4000``, ``eps_prim_inf = 1e-6``, ``rho = 10`` (fewest
iterations on sampled goals among 0.1 ... 100) and an iteration-based adaptive rho
(interval 25; OSQP's automatic interval is derived from the measured setup *time* and
would make results machine-dependent). A solved QP's coefficients then get a
minimum-norm correction of ``d_3..d_D`` (and ``d_0..d_2`` set directly) so that the six
boundary conditions hold to round-off; the correction is of the size of the OSQP
residual, so the bound is unaffected beyond ``~eps_abs``.

Sample times: ``n_samples`` interior points ``tau_s = s / (n_samples + 1)``; the end
points are fixed by the boundary conditions, and ``|a0|, |af| <= a_max`` is checked
directly. Default :data:`N_SAMPLES` = 100. Between samples spaced ``h`` a polynomial
acceleration bounded by ``a_max`` at the samples can exceed it by at most
``h^2 / 8 max |a''|``; by Markov's inequality ``max |a''| <= 96 a_max`` (cubic,
degree 5) or ``800 a_max`` (quintic, degree 7) on [0, 1], so the worst-case overshoot
is 0.12 % (degree 5) / 1 % (degree 7) of ``a_max``; on sampled goals the measured
excess is far smaller (tests/test_reference.py).

Minimum time (Alg. 1)
---------------------
Bracket ``[t_lo, t_hi] = [0, 4]`` s; ``t = (t_min + t_max) / 2``; feasible ->
``t_max = t``, infeasible -> ``t_min = t``; ``while t_max - t_min >= tol`` (0.02 s);
return ``t_max`` with its coefficients. ``t_hi`` itself is checked first: a reference
infeasible there is returned with ``feasible = False``, ``T = t_hi`` and the
*unconstrained* min-jerk quintic at ``t_hi`` (meets the boundary conditions, violates
the bound) so the caller can resample it. Like Alg. 1 this assumes feasibility is
monotone in ``T`` near the answer: ``t_max`` is always feasible and ``t_min`` infeasible
(or 0), so the result is within ``tol`` of a feasibility boundary (no non-monotone
case among 5,000 rho_D goals on a 5 ms grid). For degree 5 the QP has a single
feasible point and agrees with the closed form (the QP's ``T`` is equal or, when the
peak falls between samples, one bisection step shorter). For degree > 5 the feasible
set shrinks to a point as ``T`` approaches the minimum and ADMM needs thousands of
iterations there; a time-out counts as infeasible (Alg. 1), so the QP result can stop
a few bisection steps above the true minimum and depends (deterministically) on
``max_iter`` and the warm start.
"""

from __future__ import annotations

import math
from typing import Any
from functools import lru_cache

import numpy as np
import osqp
from scipy import sparse

from aerohrl.errors import UserError

A_MAX = 5.0
T_LO, T_HI, TOL = 0.0, 4.0, 0.02
DEGREE = 5
MAX_DEGREE = 12  # power basis on [0, 1]; higher degrees would be ill-conditioned
N_SAMPLES = 100
SOLVERS = ("closed-form", "qp")
CF_RTOL = 1e-9  # closed-form feasibility: max|a| <= a_max * (1 + CF_RTOL)

OSQP_SETTINGS = dict(
    eps_abs=1e-6,
    eps_rel=1e-6,
    eps_prim_inf=1e-6,
    eps_dual_inf=1e-6,
    max_iter=4000,
    polishing=True,
    adaptive_rho=1,  # iteration-based
    adaptive_rho_interval=25,
    check_termination=25,
    rho=10.0,
    verbose=False,
)
_RHO0 = OSQP_SETTINGS["rho"]


# --------------------------------------------------------------------------- inputs


def _states(x0, xf) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(x0, dtype=np.float64)
    b = np.asarray(xf, dtype=np.float64)
    if a.ndim != 3 or a.shape[1:] != (3, 3):
        raise UserError(f"x0 must have shape (N, 3, 3) [n, axis, (p, v, a)], got {a.shape}")
    if b.shape != a.shape:
        raise UserError(f"xf must have the shape of x0 {a.shape}, got {b.shape}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise UserError("boundary states contain NaN or inf")
    return a, b


def _durations(T, n: int) -> np.ndarray:
    t = np.asarray(T, dtype=np.float64)
    if t.ndim == 0:
        t = np.full(n, float(t))
    if t.shape != (n,):
        raise UserError(f"T must be a scalar or have shape ({n},), got {t.shape}")
    if not (np.isfinite(t).all() and (t > 0).all()):
        raise UserError("durations T must be finite and positive")
    return t


def positive_number(name: str, x: Any) -> float:
    """``x`` as a float, finite and > 0; a one-line error naming ``name`` otherwise."""
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise UserError(f"{name} must be a number, got {x!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise UserError(f"{name} must be finite and positive, got {x!r}")
    return v


def _int_at_least(name: str, x, lo: int, hi: int | None = None) -> int:
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)) or x < lo or (hi is not None and x > hi):
        rng = f">= {lo}" if hi is None else f"in {lo}..{hi}"
        raise UserError(f"{name} must be an integer {rng}, got {x!r}")
    return int(x)


def _coeffs(coeffs) -> np.ndarray:
    c = np.asarray(coeffs, dtype=np.float64)
    if c.ndim != 3 or c.shape[1] != 3 or c.shape[2] < 1:
        raise UserError(f"coefficients must have shape (N, 3, degree + 1), got {c.shape}")
    return c


# ------------------------------------------------------------------ closed form


def _quintic_tau(x0: np.ndarray, xf: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Normalised quintic coefficients ``d_k = c_k T^k`` (N, 3, 6)."""
    Tb = T[:, None]
    T2 = Tb * Tb
    p0, v0, a0 = x0[..., 0], x0[..., 1], x0[..., 2]
    pf, vf, af = xf[..., 0], xf[..., 1], xf[..., 2]
    r0 = pf - p0 - v0 * Tb - 0.5 * a0 * T2
    r1 = (vf - v0 - a0 * Tb) * Tb
    r2 = (af - a0) * T2
    d = np.empty(x0.shape[:2] + (6,))
    d[..., 0] = p0
    d[..., 1] = v0 * Tb
    d[..., 2] = 0.5 * a0 * T2
    d[..., 3] = 10.0 * r0 - 4.0 * r1 + 0.5 * r2
    d[..., 4] = -15.0 * r0 + 7.0 * r1 - r2
    d[..., 5] = 6.0 * r0 - 3.0 * r1 + 0.5 * r2
    return d


def _to_power(d: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``c_k = d_k / T^k`` for normalised coefficients d (N, 3, D)."""
    k = np.arange(d.shape[-1])
    return d / (T[:, None, None] ** k)


def _to_tau(c: np.ndarray, T: np.ndarray) -> np.ndarray:
    k = np.arange(c.shape[-1])
    return c * (T[:, None, None] ** k)


def _max_acc_quintic_tau(d: np.ndarray) -> np.ndarray:
    """max over tau in [0, 1] of |d2x/dtau2| for normalised quintics d (..., 6), exactly.

    The curvature ``q(tau) = 2 d2 + 6 d3 tau + 12 d4 tau^2 + 20 d5 tau^3`` is a cubic;
    its extrema are at tau = 0, 1 and the real roots in (0, 1) of
    ``q'(tau) = A tau^2 + B tau + C`` with A = 60 d5, B = 24 d4, C = 6 d3 (found with the
    cancellation-free quadratic formula; a vanishing A leaves the linear root).
    """
    d2, d3, d4, d5 = d[..., 2], d[..., 3], d[..., 4], d[..., 5]

    def q(t):
        return 2.0 * d2 + t * (6.0 * d3 + t * (12.0 * d4 + t * 20.0 * d5))

    A, B, C = 60.0 * d5, 24.0 * d4, 6.0 * d3
    best = np.maximum(np.abs(q(0.0)), np.abs(q(1.0)))
    disc = B * B - 4.0 * A * C
    ok = disc >= 0.0
    sq = np.sqrt(np.where(ok, disc, 0.0))
    qq = -0.5 * (B + np.where(B >= 0.0, sq, -sq))
    with np.errstate(divide="ignore", invalid="ignore"):
        roots = (qq / A, C / qq)
    for r in roots:
        inside = ok & np.isfinite(r) & (r > 0.0) & (r < 1.0)
        r = np.where(inside, r, 0.0)
        best = np.where(inside, np.maximum(best, np.abs(q(r))), best)
    return best


def min_jerk_closed_form(x0: np.ndarray, xf: np.ndarray, T: float | np.ndarray) -> np.ndarray:
    """Unconstrained minimum-jerk quintics (MHD 2015), batched over N and the 3 axes.

    ``x0, xf``: (N, 3, 3) ``[n, axis, (p, v, a)]``; ``T``: scalar or (N,) seconds (> 0).
    Returns power-basis coefficients (N, 3, 6), ``x(t) = sum_k c_k t^k``::

        c0 = p0,  c1 = v0,  c2 = a0 / 2,  c_k = d_k / T^k  (k = 3, 4, 5)
        r0 = pf - p0 - v0 T - a0 T^2 / 2,  r1 = (vf - v0 - a0 T) T,  r2 = (af - a0) T^2
        d3 = 10 r0 - 4 r1 + r2 / 2,  d4 = -15 r0 + 7 r1 - r2,  d5 = 6 r0 - 3 r1 + r2 / 2

    (derivation in the module docstring). The acceleration bound is *not* applied here;
    see :func:`max_acceleration` and :func:`min_time`.
    """
    x0, xf = _states(x0, xf)
    T = _durations(T, x0.shape[0])
    return _to_power(_quintic_tau(x0, xf, T), T)


def max_acceleration(coeffs: np.ndarray, T: float | np.ndarray) -> np.ndarray:
    """Exact ``max_{t in [0, T]} |a_i(t)|`` per reference and axis -> (N, 3).

    Degree <= 5: analytic (end points and the real roots of the quadratic jerk).
    Higher degrees: end points and the real roots of the jerk polynomial (numpy
    companion-matrix roots, one small eigenproblem per axis).
    """
    c = _coeffs(coeffs)
    n, _, D = c.shape
    T = _durations(T, n)
    if D <= 6:
        d = np.zeros((n, 3, 6))
        d[..., :D] = _to_tau(c, T)
        return _max_acc_quintic_tau(d) / (T * T)[:, None]
    d = _to_tau(c, T)
    k = np.arange(D)
    curv = d[..., 2:] * (k[2:] * (k[2:] - 1))  # q(tau) coefficients, powers 0..D-3
    jerk = curv[..., 1:] * np.arange(1, D - 2)  # q'(tau), powers 0..D-4
    out = np.empty((n, 3))
    P = np.polynomial.polynomial
    for i in range(n):
        for j in range(3):
            cand = [0.0, 1.0]
            jj = jerk[i, j]
            scale = np.abs(jj).max()
            if scale > 0.0:
                jj = P.polytrim(jj, tol=1e-13 * scale)
                if len(jj) > 1:
                    r: np.ndarray = P.polyroots(jj)
                    r = r.real[(np.abs(r.imag) <= 1e-9) & (r.real > 0.0) & (r.real < 1.0)]
                    cand.extend(r.tolist())
            out[i, j] = np.abs(P.polyval(np.asarray(cand), curv[i, j])).max()
    return out / (T * T)[:, None]


def jerk_cost(coeffs: np.ndarray, T: float | np.ndarray) -> np.ndarray:
    """``int_0^T x'''(t)^2 dt`` per reference and axis -> (N, 3) (exact, via the Gram matrix)."""
    c = _coeffs(coeffs)
    T = _durations(T, c.shape[0])
    d = _to_tau(c, T)
    H = _gram(c.shape[2] - 1)
    return np.einsum("naj,jk,nak->na", d, H, d) / T[:, None] ** 5


def evaluate(coeffs: np.ndarray, t: float | np.ndarray, order: int = 0) -> np.ndarray:
    """Derivative ``order`` of the polynomials at times ``t`` (s, from the start).

    ``coeffs`` (N, 3, D). ``t``: scalar or (N,) -> (N, 3); (N, K) -> (N, K, 3).
    ``order``: 0 position, 1 velocity, 2 acceleration, 3 jerk (any non-negative
    integer works). Times are not clipped to [0, T].
    """
    c = _coeffs(coeffs)
    n, _, D = c.shape
    order = _int_at_least("order", order, 0)
    tt = np.asarray(t, dtype=np.float64)
    if tt.ndim == 0:
        grid, squeeze = np.full((n, 1), float(tt)), True
    elif tt.ndim == 1 and tt.shape[0] == n:
        grid, squeeze = tt[:, None], True
    elif tt.ndim == 2 and tt.shape[0] == n:
        grid, squeeze = tt, False
    else:
        raise UserError(f"t must be a scalar, ({n},) or ({n}, K), got shape {tt.shape}")
    K = grid.shape[1]
    if order >= D:
        out = np.zeros((n, K, 3))
    else:
        k = np.arange(order, D)
        fac = np.ones(D - order)
        for i in range(order):
            fac *= k - i
        dc = c[..., order:] * fac  # (N, 3, D - order)
        g = grid[..., None]  # (N, K, 1)
        out = np.broadcast_to(dc[:, None, :, -1], (n, K, 3)).copy()
        for j in range(D - order - 2, -1, -1):
            out *= g
            out += dc[:, None, :, j]
    return out[:, 0, :] if squeeze else out


# ----------------------------------------------------------------------------- QP


@lru_cache(maxsize=None)
def _gram(degree: int) -> np.ndarray:
    """``H_jk = int_0^1 x_j''' x_k''' dtau`` for the monomials ``tau^j`` (read-only)."""
    D = degree + 1
    H = np.zeros((D, D))
    for j in range(3, D):
        for k in range(3, D):
            H[j, k] = j * (j - 1) * (j - 2) * k * (k - 1) * (k - 2) / (j + k - 5)
    H.setflags(write=False)
    return H


def _constraint_matrix(degree: int, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
    D = degree + 1
    k = np.arange(D)
    E = np.zeros((6, D))
    E[0, 0] = 1.0  # x(0)
    E[1, 1] = 1.0  # x'(0)
    E[2, 2] = 2.0  # x''(0)
    E[3] = 1.0  # x(1)
    E[4] = k  # x'(1)
    E[5] = k * (k - 1)  # x''(1)
    tau = np.arange(1, n_samples + 1) / (n_samples + 1)
    S = np.zeros((n_samples, D))
    S[:, 2:] = k[2:] * (k[2:] - 1) * tau[:, None] ** (k[2:] - 2)
    return np.vstack([E, S]), tau


class _QPWorkspace:
    """One OSQP problem per axis for a given (degree, n_samples); only l, u change."""

    def __init__(self, degree: int, n_samples: int):
        self.degree, self.n_samples = degree, n_samples
        A, self.tau = _constraint_matrix(degree, n_samples)
        H = _gram(degree)
        P = sparse.triu(sparse.csc_matrix(2.0 * H), format="csc")
        Acsc = sparse.csc_matrix(A)
        self.l = np.concatenate([np.zeros(6), -np.ones(n_samples)])
        self.u = np.concatenate([np.zeros(6), np.ones(n_samples)])
        self.solvers = []
        for _ in range(3):
            s = osqp.OSQP()
            s.setup(P, np.zeros(degree + 1), Acsc, self.l, self.u, **OSQP_SETTINGS)
            self.solvers.append(s)
        self.x0 = np.zeros(degree + 1)
        self.y0 = np.zeros(6 + n_samples)
        M = A[3:6, 3:]  # end-point rows on the free coefficients d_3..d_D
        self.end_rows = A[3:6]
        self.end_fix = M.T @ np.linalg.inv(M @ M.T)

    def enforce_bc(self, d: np.ndarray, b: np.ndarray) -> None:
        """Make d (3, D) meet the boundary values b (3, 6) (tau units) exactly, in place."""
        d[:, 0] = b[:, 0]
        d[:, 1] = b[:, 1]
        d[:, 2] = 0.5 * b[:, 2]
        r = b[:, 3:6] - d @ self.end_rows.T
        d[:, 3:] += r @ self.end_fix.T

    def reset(self, axis: int) -> None:
        s = self.solvers[axis]
        s.update_settings(rho=_RHO0)
        s.warm_start(x=self.x0, y=self.y0)

    def solve(self, axis: int, beq: np.ndarray, warm=None):
        """Solve with boundary right-hand sides ``beq`` (6,) in z units.

        Returns ``(ok, z, y)``; ``warm`` is ``None`` (cold start, see :meth:`reset`) or an
        ``(x, y)`` pair from an earlier solve of the same axis.
        """
        s = self.solvers[axis]
        self.l[:6] = beq
        self.u[:6] = beq
        s.update(l=self.l, u=self.u)
        if warm is None:
            self.reset(axis)
        else:
            s.warm_start(x=warm[0], y=warm[1])
        res = s.solve(raise_error=False)
        ok = res.info.status_val == osqp.SolverStatus.OSQP_SOLVED
        return ok, np.array(res.x, copy=True), np.array(res.y, copy=True)


@lru_cache(maxsize=8)
def _workspace(degree: int, n_samples: int) -> _QPWorkspace:
    return _QPWorkspace(degree, n_samples)


def _qp_rhs(x0n: np.ndarray, xfn: np.ndarray, T: float, a_max: float) -> np.ndarray:
    """Boundary right-hand sides (3 axes, 6) in z = d / L units."""
    L = a_max * T * T
    rhs = np.empty((3, 6))
    rhs[:, 0] = x0n[:, 0]
    rhs[:, 1] = x0n[:, 1] * T
    rhs[:, 2] = x0n[:, 2] * T * T
    rhs[:, 3] = xfn[:, 0]
    rhs[:, 4] = xfn[:, 1] * T
    rhs[:, 5] = xfn[:, 2] * T * T
    return rhs / L


def _qp_one(ws: _QPWorkspace, x0n, xfn, T: float, a_max: float, warm: list, *, stop_early: bool):
    """All three axes of one reference at duration T -> (feasible, d (3, D) or None).

    ``warm``: per-axis ``(x, y)`` or None, updated in place on success.
    """
    ends_ok = np.abs(np.concatenate([x0n[:, 2], xfn[:, 2]])).max() <= a_max * (1.0 + CF_RTOL)
    if not ends_ok:
        return False, None
    L = a_max * T * T
    rhs = _qp_rhs(x0n, xfn, T, a_max)
    d = np.empty((3, ws.degree + 1))
    feasible = True
    for ax in range(3):
        ok, z, y = ws.solve(ax, rhs[ax], warm[ax])
        if ok:
            warm[ax] = (z, y)
            d[ax] = z * L
        else:
            feasible = False
            if stop_early:
                return False, None
    if feasible:
        ws.enforce_bc(d, rhs * L)
    return feasible, d


def _check_common(a_max, degree, n_samples):
    a_max = positive_number("a_max", a_max)
    degree = _int_at_least("degree", degree, 5, MAX_DEGREE)
    n_samples = N_SAMPLES if n_samples is None else _int_at_least("n_samples", n_samples, 1)
    return a_max, degree, n_samples


def _padded_quintic(x0, xf, T, degree) -> np.ndarray:
    c = np.zeros(x0.shape[:2] + (degree + 1,))
    c[..., :6] = _to_power(_quintic_tau(x0, xf, T), T)
    return c


def min_jerk_qp(
    x0: np.ndarray,
    xf: np.ndarray,
    T: float | np.ndarray,
    *,
    degree: int = DEGREE,
    a_max: float = A_MAX,
    n_samples: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Acceleration-bounded minimum-jerk polynomials by QP (OSQP), one per reference and axis.

    Returns ``(coeffs (N, 3, degree + 1), feasible (N,))``. A reference is feasible iff
    all three axis QPs are solved (module docstring: formulation, tolerances, samples).
    For an infeasible reference the coefficients are the unconstrained min-jerk quintic
    (zero-padded), which meets the boundary conditions but not the bound.
    """
    x0, xf = _states(x0, xf)
    n = x0.shape[0]
    T = _durations(T, n)
    a_max, degree, n_samples = _check_common(a_max, degree, n_samples)
    coeffs = _padded_quintic(x0, xf, T, degree)
    feasible = np.zeros(n, dtype=bool)
    if n == 0:
        return coeffs, feasible
    ws = _workspace(degree, n_samples)
    for i in range(n):
        ok, d = _qp_one(ws, x0[i], xf[i], float(T[i]), a_max, [None, None, None], stop_early=False)
        if ok:
            feasible[i] = True
            coeffs[i] = _to_power(d[None], T[i : i + 1])[0]
    return coeffs, feasible


# ------------------------------------------------------------------- minimum time


def _bracket_steps(t_lo: float, t_hi: float, tol: float) -> int:
    """Number of Alg. 1 iterations: the bracket width halves until it is < tol."""
    w, k = t_hi - t_lo, 0
    while w >= tol:
        w *= 0.5
        k += 1
    return k


def _cf_feasible(x0, xf, T, a_max) -> np.ndarray:
    d = _quintic_tau(x0, xf, T)
    return (_max_acc_quintic_tau(d) <= (a_max * (1.0 + CF_RTOL)) * (T * T)[:, None]).all(axis=1)


def min_time(
    x0: np.ndarray,
    xf: np.ndarray,
    *,
    a_max: float = A_MAX,
    t_lo: float = T_LO,
    t_hi: float = T_HI,
    tol: float = TOL,
    solver: str = "closed-form",
    degree: int = DEGREE,
    n_samples: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum duration by bisection (thesis Alg. 1) -> ``(T (N,), coeffs (N, 3, degree+1), feasible (N,))``.

    ``T`` is the feasible end ``t_max`` of the final bracket (width < ``tol``); one ``T``
    for all three axes. ``feasible[n]`` is False iff reference n is infeasible at
    ``t_hi`` (then ``T = t_hi`` and the coefficients are the unconstrained quintic; the
    caller resamples). ``solver="closed-form"`` (degree 5 only) bisects all N at once with
    the exact closed-form feasibility test; ``solver="qp"`` runs Alg. 1 per reference with
    OSQP, reusing one workspace per (degree, n_samples).
    """
    x0, xf = _states(x0, xf)
    n = x0.shape[0]
    if solver not in SOLVERS:
        raise UserError(f"unknown solver {solver!r} (choose from {', '.join(SOLVERS)})")
    a_max, degree, n_samples = _check_common(a_max, degree, n_samples)
    if solver == "closed-form" and degree != 5:
        raise UserError(f"the closed-form solver exists for degree 5 only (got degree {degree}); use solver='qp'")
    try:
        t_lo, t_hi, tol = float(t_lo), float(t_hi), float(tol)
    except (TypeError, ValueError):
        raise UserError("t_lo, t_hi and tol must be numbers") from None
    if not (math.isfinite(t_lo) and math.isfinite(t_hi) and 0.0 <= t_lo < t_hi):
        raise UserError(f"need 0 <= t_lo < t_hi (finite), got t_lo={t_lo}, t_hi={t_hi}")
    if not (math.isfinite(tol) and tol > 0):
        raise UserError(f"tol must be finite and positive, got {tol}")
    steps = _bracket_steps(t_lo, t_hi, tol)

    if solver == "closed-form":
        hi = np.full(n, t_hi)
        lo = np.full(n, t_lo)
        feasible = _cf_feasible(x0, xf, hi, a_max)
        for _ in range(steps):
            mid = 0.5 * (lo + hi)
            f = _cf_feasible(x0, xf, mid, a_max)
            hi = np.where(f, mid, hi)
            lo = np.where(f, lo, mid)
        hi[~feasible] = t_hi
        return hi, min_jerk_closed_form(x0, xf, hi), feasible

    ws = _workspace(degree, n_samples)
    T = np.full(n, t_hi)
    coeffs = _padded_quintic(x0, xf, T, degree)
    feasible = np.zeros(n, dtype=bool)
    for i in range(n):
        warm = [None, None, None]
        ok, d = _qp_one(ws, x0[i], xf[i], t_hi, a_max, warm, stop_early=True)
        if not ok:
            continue
        feasible[i] = True
        lo_i, hi_i, d_hi = t_lo, t_hi, d
        for _ in range(steps):
            mid_i = 0.5 * (lo_i + hi_i)
            ok, d = _qp_one(ws, x0[i], xf[i], mid_i, a_max, warm, stop_early=True)
            if ok:
                hi_i, d_hi = mid_i, d
            else:
                lo_i = mid_i
        T[i] = hi_i
        coeffs[i] = _to_power(d_hi[None], T[i : i + 1])[0]
    return T, coeffs, feasible
