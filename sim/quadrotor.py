"""Batched quadrotor simulator: N vehicles stepped at once (docs/spec.md "Vehicle and simulator").

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
import weakref
from concurrent.futures import ThreadPoolExecutor
from multiprocessing import get_context
from multiprocessing.shared_memory import SharedMemory
from typing import cast

import numpy as np

from aerohrl.sim import dynamics as dyn
from aerohrl.sim.params import QuadrotorParams
from aerohrl.sim.perturb import Perturbation, PerturbedPlant

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
        self.X = np.zeros((dyn.NX, n), dtype=model.dtype)  # stepped in place
        self.u = np.zeros((4, n), dtype=model.dtype)  # CTBR, SoA
        self.cmd = np.zeros((4, n), dtype=model.dtype)  # rotor-speed commands
        self.scratch = dyn.Scratch(n, model.dtype)

    def _rk4(self, j: int):
        # substep j > 0 starts from the rotor speeds whose wrench substep j - 1 left in scratch.w0
        dyn.rk4_step(self.X, self.cmd, self.h, self.model, self.scratch, self.X, w0_ready=j > 0)

    def step_ctbr(self):
        m, s = self.model, self.scratch
        for j in range(self.substeps):
            dyn.rate_loop(self.X[dyn.W], self.u, m, self.cmd, s)  # rate loop at every substep
            self._rk4(j)
        self._end_step()

    def step_speeds(self):
        for j in range(self.substeps):
            self._rk4(j)
        self._end_step()

    def _end_step(self):
        X = self.X
        dyn.orthonormalize_rows(X, self.scratch)
        # the exact motor solution stays between Omega and the clipped command; clip round-off
        np.clip(X[dyn.OMEGA], self.model.omega_min, self.model.omega_max, out=X[dyn.OMEGA])


class _PerturbedChunk(_Chunk):
    """The whole batch on the perturbed plant of :mod:`aerohrl.sim.perturb`: the nominal rate
    loop flies the (delayed) command, the plant integrates the perturbed physics."""

    def __init__(self, model: dyn.Model, n: int, h: float, substeps: int, plant: PerturbedPlant):
        super().__init__(model, n, h, substeps)
        self.plant = plant

    def _rk4(self, j: int):
        self.plant.rk4_step(self.X, self.cmd, self.h, self.model, self.scratch, self.X, w0_ready=j > 0)

    def step_ctbr(self):
        m, s, pl = self.model, self.scratch, self.plant
        pl.push(self.u)  # copied into the delay line: self.u is free to hold the delayed command
        if pl.delayed:
            late, early = pl.commands()
            for j in range(self.substeps):
                # substep j flies u_{k-M} from substep r on, u_{k-M-1} before it (per vehicle)
                np.copyto(self.u, late)
                np.copyto(self.u, early, where=j < pl.sub)
                dyn.rate_loop(self.X[dyn.W], self.u, m, self.cmd, s)
                self._rk4(j)
        else:
            for j in range(self.substeps):
                dyn.rate_loop(self.X[dyn.W], self.u, m, self.cmd, s)
                self._rk4(j)
        self._end_step()
        pl.end_step()

    def step_speeds(self):
        super().step_speeds()
        self.plant.end_step()


# --------------------------------------------------------------------------- processes
# Why processes and not only threads: a control step is ~1,300 short NumPy calls; two
# threads hand the GIL back and forth between them and at 2,048 vehicles per thread run
# 2x *slower* than one. A worker process has its own interpreter, so the split scales.
# The arrays live in shared memory (no copies); one byte each way per step syncs them.

_STEP = {b"c": "step_ctbr", b"s": "step_speeds"}


def _shared_arrays(buf, n: int, dtype) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Views ``X, u, cmd`` over a shared block of ``(NX + 8) n`` numbers of ``dtype``."""
    a: np.ndarray = np.ndarray((dyn.NX + 8, n), dtype=dtype, buffer=buf)
    return a[: dyn.NX], a[dyn.NX : dyn.NX + 4], a[dyn.NX + 4 :]


def _worker(conn, shm_name: str, model: dyn.Model, n: int, h: float, substeps: int) -> None:
    """Worker process: step one chunk whose arrays live in shared memory, on command."""
    shm = SharedMemory(name=shm_name)
    try:
        chunk = _Chunk(model, n, h, substeps)
        chunk.X, chunk.u, chunk.cmd = _shared_arrays(shm.buf, n, model.dtype)
        while True:
            msg = conn.recv_bytes()
            if msg == b"q":
                break
            getattr(chunk, _STEP[msg])()
            conn.send_bytes(b"0")
        del chunk
    except (EOFError, KeyboardInterrupt):
        pass
    finally:
        shm.close()


def _shutdown(proc, conn, shm) -> None:
    try:
        conn.send_bytes(b"q")
    except (OSError, ValueError):
        pass
    proc.join(timeout=2)
    if proc.is_alive():
        proc.terminate()
    conn.close()
    shm.close()
    shm.unlink()


class _ProcChunk:
    """A block of vehicles stepped by a worker process (same attributes as :class:`_Chunk`
    for the parent: ``X``, ``u``, ``cmd``, ``scratch``), its arrays in shared memory."""

    def __init__(self, model: dyn.Model, n: int, h: float, substeps: int):
        self.model, self.n = model, n
        self.scratch = dyn.Scratch(n, model.dtype)
        self._shm = SharedMemory(create=True, size=(dyn.NX + 8) * n * np.dtype(model.dtype).itemsize)
        self.X, self.u, self.cmd = _shared_arrays(self._shm.buf, n, model.dtype)
        self.X[:] = 0.0
        self.u[:] = 0.0
        self.cmd[:] = 0.0
        # forkserver, not fork: the parent may hold torch/OpenMP threads, which fork copies badly
        ctx = get_context("forkserver")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_worker, args=(child, self._shm.name, model, n, h, substeps), daemon=True, name="aerohrl-sim"
        )
        self._proc.start()
        child.close()
        self._finalizer = weakref.finalize(self, _shutdown, self._proc, self._conn, self._shm)

    def start(self, method: str) -> None:
        self._conn.send_bytes(b"c" if method == "step_ctbr" else b"s")

    def wait(self) -> None:
        try:
            self._conn.recv_bytes()
        except EOFError:
            raise RuntimeError("a simulator worker process died") from None

    def close(self) -> None:
        self._finalizer()


class BatchedQuadrotor:
    """``num_vehicles`` independent quadrotors with the same parameters.

    ``threads``: the batch is split into this many contiguous blocks stepped in
    parallel threads (NumPy releases the GIL inside its loops); the result does not depend
    on the split (bit for bit). Default 1: on the shared 2-core machine the split was
    measured 2.5x *slower* at 4096 vehicles (GIL hand-offs between ~600 short NumPy calls
    per step and competing processes); try ``threads=2`` on an idle multi-core machine.

    ``processes``: the batch is split into this many blocks, the first stepped in this
    process and the others in worker processes over shared memory (no GIL between
    them; bit for bit the same result). Worth it from a few thousand vehicles per block
    (``bench/bench_sim.py --processes 2``); workers start in ~0.1-0.5 s and stop with
    :meth:`close` (or when the simulator is garbage collected / the program exits).

    ``perturbation``: model error of :mod:`aerohrl.sim.perturb` (one value, or one per
    vehicle), its randomness (gusts, observation noise, biases) seeded by ``seed``. A
    perturbed batch is stepped in one block (``threads``/``processes`` are ignored) and
    :meth:`observe` gives what the policy sees; None or a nominal perturbation keeps
    the nominal code path, bit for bit.

    ``dtype``: ``np.float64`` (default) or ``np.float32``, the type the state is kept
    and integrated in. float32 halves the memory traffic of a step and is faster, at
    the price of round-off drift (docs/results/2026-12-03-simulator-speed.md measures it
    against float64); it is an explicit choice, never the default, as float64 gives the
    bytes datasets are built from. The public arrays (state, rotor speeds) stay float64.
    Perturbed plants run in float64 only.
    """

    def __init__(
        self,
        params: QuadrotorParams,
        num_vehicles: int,
        *,
        dt: float = 0.01,
        substeps: int = 5,
        threads: int = 1,
        processes: int = 1,
        perturbation: Perturbation | None = None,
        seed: int | list[int] = 0,
        dtype: type = np.float64,
    ):
        if int(num_vehicles) < 1:
            raise ValueError(f"num_vehicles must be >= 1, got {num_vehicles}")
        if not dt > 0 or int(substeps) < 1:
            raise ValueError(f"need dt > 0 and substeps >= 1, got dt={dt}, substeps={substeps}")
        self.params = params
        self.num_vehicles = n = int(num_vehicles)
        self.dt = float(dt)
        self.substeps = int(substeps)
        self.h = self.dt / self.substeps
        self.model = dyn.Model.from_params(params, dtype)
        self.dtype = self.model.dtype
        self.plant: PerturbedPlant | None = None
        if perturbation is not None and not perturbation.nominal:
            if self.dtype is not np.float64:
                raise ValueError("a perturbed plant runs in float64 only (dtype=np.float64)")
            self.plant = PerturbedPlant(perturbation, n, self.dt, self.substeps, seed=seed)
            threads = processes = 1
        threads = max(1, min(int(threads), n))
        processes = max(1, min(int(processes), n))
        if threads > 1 and processes > 1:
            raise ValueError("choose threads or processes, not both")
        parts = max(threads, processes)
        bounds = np.linspace(0, n, parts + 1).round().astype(int)
        self._slices = [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]
        self._chunks: list[_Chunk | _ProcChunk]
        if self.plant is not None:
            self._chunks = [_PerturbedChunk(self.model, n, self.h, self.substeps, self.plant)]
        else:
            self._chunks = [
                (_ProcChunk if i > 0 and processes > 1 else _Chunk)(self.model, sl.stop - sl.start, self.h, self.substeps)
                for i, sl in enumerate(self._slices)
            ]
        self._observed: np.ndarray | None = None
        self.threads = threads
        self.processes = processes
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

    def reset(self, state=None, rotor_speeds=None, rows=None) -> np.ndarray:
        """Set the state; ``None`` = hover at the origin (R = I, w = 0).

        ``rows`` (index array, None = all): the vehicles starting a new episode, whose
        perturbation state (delay line, gust, observation biases) restarts; the others keep theirs.

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
                raise ValueError(
                    f"state {bad}: R (entries 6:15, row-major) is not a rotation matrix (|R R^T - I| = {err[bad]:.2g})"
                )
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
        if self.plant is not None:
            self.plant.reset(np.arange(self.num_vehicles) if rows is None else rows)
        self._observed = None
        self.t = 0.0
        return self.state

    def observe(self) -> np.ndarray:
        """(N, 18) state as the policy or controller observes it: the true :attr:`state`
        without a perturbation, else with its observation noise and bias (drawn once per
        step: calls between two steps return the same array)."""
        if self.plant is None:
            return self.state
        if self._observed is None:
            self._observed = self.plant.observe(self.state)
        return self._observed.copy()

    # ------------------------------------------------------------------ stepping
    def _run(self, method: str):
        if len(self._chunks) == 1:
            getattr(self._chunks[0], method)()
        elif self.processes > 1:
            # with processes > 1 every chunk after the first is a _ProcChunk
            for c in self._chunks[1:]:
                cast(_ProcChunk, c).start(method)
            getattr(self._chunks[0], method)()
            for c in self._chunks[1:]:
                cast(_ProcChunk, c).wait()
        else:
            futs = [_pool().submit(getattr(c, method)) for c in self._chunks[1:]]
            getattr(self._chunks[0], method)()
            for f in futs:
                f.result()
        self.t += self.dt
        self._observed = None

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

    def select(self, rows) -> "BatchedQuadrotor":
        """A new single-process simulator of the vehicles ``rows`` (index array) with their
        whole state (pose, velocities, body rates, rotor speeds) copied bit for bit: stepping
        it gives exactly what stepping them here would. Lets a batch drop finished vehicles."""
        if self.plant is not None:
            raise ValueError("select copies nominal vehicles only; this batch is perturbed")
        rows = np.asarray(rows, dtype=np.int64)
        X = np.concatenate([c.X for c in self._chunks], axis=1)[:, rows]
        new = BatchedQuadrotor(self.params, len(rows), dt=self.dt, substeps=self.substeps, dtype=self.dtype)
        new._chunks[0].X[:] = X
        new._chunks[0].cmd[:] = X[dyn.OMEGA]
        new.t = self.t
        return new

    def close(self) -> None:
        """Stop the worker processes (if any) and free their shared memory; idempotent."""
        for c in self._chunks:
            if isinstance(c, _ProcChunk):
                c.close()

    def __enter__(self) -> "BatchedQuadrotor":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return (
            f"BatchedQuadrotor({self.params.name!r}, num_vehicles={self.num_vehicles}, dt={self.dt}, "
            f"substeps={self.substeps}, threads={self.threads}, processes={self.processes}, dtype={self.dtype.__name__})"
        )
