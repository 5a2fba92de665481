"""Batched quadrotor simulator: N vehicles stepped at once (SPEC.md "Vehicle and simulator").

The public layout is the task's: state ``[p(3), v(3), R(9, row-major), w(3)]`` (N, 18)
and CTBR action ``[c, wx, wy, wz]`` (N, 4). Internally the state is kept as a
structure of arrays (22, N) (see :mod:`aerohrl.sim.dynamics`), including the rotor
speeds (N, 4) which the public state does not show.

One control step of ``dt`` (default 0.01 s, 100 Hz) is ``substeps`` (default 5, i.e.
500 Hz) fixed RK4 steps of the rigid body (motor lag solved exactly within a substep). With CTBR input the rate loop runs at the start of every
substep and its rotor commands are held through the substep; R is re-orthonormalised
once per control step (Gram-Schmidt on its rows, see dynamics.orthonormalize_rows).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from aerohrl.sim import dynamics as dyn
from aerohrl.sim.params import QuadrotorParams

STATE_DIM = 18


_POOL: ThreadPoolExecutor | None = None


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=max(1, (os.cpu_count() or 1) - 1), thread_name_prefix="aerohrl-sim")
    return _POOL


class _Chunk:
    """A contiguous block of vehicles with its own SoA buffers (one per worker thread)."""

    def __init__(self, model: dyn.Model, n: int, h: float, substeps: int):
        self.model, self.n, self.h, self.substeps = model, n, h, substeps
        self.X = np.zeros((dyn.NX, n))
        self.spare = np.zeros((dyn.NX, n))
        self.u = np.zeros((4, n))  # CTBR, SoA
        self.cmd = np.zeros((4, n))  # rotor-speed commands
        self.scratch = dyn.Scratch(n)

    def _rk4(self):
        out = dyn.rk4_step(self.X, self.cmd, self.h, self.model, self.scratch, self.spare)
        self.X, self.spare = out, self.X  # swap instead of copying back

    def step_ctbr(self):
        m, s = self.model, self.scratch
        for _ in range(self.substeps):
            dyn.rate_loop(self.X[dyn.W], self.u, m, self.cmd, s)  # rate loop at every substep
            self._rk4()
        self._end_step()

    def step_speeds(self):
        for _ in range(self.substeps):
            self._rk4()
        self._end_step()

    def _end_step(self):
        X = self.X
        dyn.orthonormalize_rows(X, self.scratch)
        # the exact motor solution stays between Omega and the clipped command; clip round-off
        np.clip(X[dyn.OMEGA], self.model.omega_min, self.model.omega_max, out=X[dyn.OMEGA])


class BatchedQuadrotor:
    """``num_vehicles`` independent quadrotors with the same parameters.

    ``threads``: the batch is split into this many contiguous blocks stepped in
    parallel threads (NumPy releases the GIL inside its loops); the result does not depend
    on the split (bit for bit). Default 1: on the shared 2-core machine the split was
    measured 2.5x *slower* at 4096 vehicles (GIL hand-offs between ~600 short NumPy calls
    per step and competing processes); try ``threads=2`` on an idle multi-core machine.
    """

    def __init__(self, params: QuadrotorParams, num_vehicles: int, *, dt: float = 0.01, substeps: int = 5,
                 threads: int = 1):
        if int(num_vehicles) < 1:
            raise ValueError(f"num_vehicles must be >= 1, got {num_vehicles}")
        if not dt > 0 or int(substeps) < 1:
            raise ValueError(f"need dt > 0 and substeps >= 1, got dt={dt}, substeps={substeps}")
        self.params = params
        self.num_vehicles = n = int(num_vehicles)
        self.dt = float(dt)
        self.substeps = int(substeps)
        self.h = self.dt / self.substeps
        self.model = dyn.Model.from_params(params)
        threads = max(1, min(int(threads), n))
        bounds = np.linspace(0, n, threads + 1).round().astype(int)
        self._slices = [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]
        self._chunks = [_Chunk(self.model, sl.stop - sl.start, self.h, self.substeps) for sl in self._slices]
        self.threads = threads
        self.t = 0.0
        self.reset()

    # ------------------------------------------------------------------ state
    def _gather(self, rows) -> np.ndarray:
        out = np.empty((self.num_vehicles, rows.stop - rows.start))
        for sl, c in zip(self._slices, self._chunks):
            out[sl] = c.X[rows].T
        return out

    @property
    def state(self) -> np.ndarray:
        """(N, 18) ``[p, v, R row-major, w]`` (a copy)."""
        return self._gather(slice(0, STATE_DIM))

    @property
    def rotor_speeds(self) -> np.ndarray:
        """(N, 4) rotor speeds (rad/s) (a copy)."""
        return self._gather(dyn.OMEGA)

    def _check(self, a, cols: int, what: str) -> np.ndarray:
        a = np.asarray(a, dtype=np.float64)
        if a.ndim == 1 and self.num_vehicles == 1 and a.shape[0] == cols:
            a = a[None]
        if a.shape != (self.num_vehicles, cols):
            raise ValueError(f"{what} must have shape ({self.num_vehicles}, {cols}), got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"{what} contains NaN or inf")
        return a

    def reset(self, state=None, rotor_speeds=None) -> np.ndarray:
        """Set the state; ``None`` = hover at the origin (R = I, w = 0).

        ``rotor_speeds`` (N, 4) defaults to the hover speed of every rotor. A given
        state's R must be a rotation to 1e-3 (e.g. float32 data) and is projected onto
        the rotations (Gram-Schmidt) before use; otherwise ValueError.
        Returns the (N, 18) state.
        """
        st = None if state is None else self._check(state, STATE_DIM, "state")
        if st is not None:
            R = st[:, 6:15].reshape(-1, 3, 3)
            err = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(axis=(1, 2))
            if (err > 1e-3).any() or (np.linalg.det(R) < 0).any():
                bad = int(np.argmax(err))
                raise ValueError(f"state {bad}: R (entries 6:15, row-major) is not a rotation matrix "
                                 f"(|R R^T - I| = {err[bad]:.2g})")
        om = None if rotor_speeds is None else self._check(rotor_speeds, 4, "rotor_speeds")
        for sl, c in zip(self._slices, self._chunks):
            X = c.X
            if st is None:
                X[:STATE_DIM] = 0.0
                X[6] = X[10] = X[14] = 1.0
            else:
                X[:STATE_DIM] = st[sl].T
                dyn.orthonormalize_rows(X, c.scratch)
                dyn.orthonormalize_rows(X, c.scratch)
            if om is None:
                X[dyn.OMEGA] = self.params.hover_rotor_speed
            else:
                X[dyn.OMEGA] = np.clip(om[sl], self.model.omega_min, self.model.omega_max).T
            c.u[:] = 0.0
            c.cmd[:] = X[dyn.OMEGA]
        self.t = 0.0
        return self.state

    # ------------------------------------------------------------------ stepping
    def _run(self, method: str):
        if len(self._chunks) == 1:
            getattr(self._chunks[0], method)()
        else:
            futs = [_pool().submit(getattr(c, method)) for c in self._chunks[1:]]
            getattr(self._chunks[0], method)()
            for f in futs:
                f.result()
        self.t += self.dt

    def step(self, ctbr) -> np.ndarray:
        """Advance one control step with CTBR actions ``ctbr`` (N, 4) ``[c, wx, wy, wz]``.

        Returns the new (N, 18) state.
        """
        u = self._check(ctbr, 4, "ctbr action")
        for sl, c in zip(self._slices, self._chunks):
            np.copyto(c.u, u[sl].T)
        self._run("step_ctbr")
        return self.state

    def step_rotor_speeds(self, cmd) -> np.ndarray:
        """Advance one control step with rotor-speed commands ``cmd`` (N, 4) (rad/s).

        The commands are clipped to the rotor range and held for the whole step (as
        RotorPy's ``cmd_motor_speeds`` abstraction). Returns the new (N, 18) state.
        """
        c_ = self._check(cmd, 4, "rotor speed command")
        for sl, c in zip(self._slices, self._chunks):
            np.clip(c_[sl].T, self.model.omega_min, self.model.omega_max, out=c.cmd)
        self._run("step_speeds")
        return self.state

    def __repr__(self) -> str:
        return (f"BatchedQuadrotor({self.params.name!r}, num_vehicles={self.num_vehicles}, dt={self.dt}, "
                f"substeps={self.substeps}, threads={self.threads})")
