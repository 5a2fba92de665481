"""Primitives flown by the vehicle (thesis §2.6.4 analogue; issue 13, item 6).

:class:`FlownEnv` is the target search of :class:`~aerohrl.ipp.env.SearchEnv` in which
every chosen primitive is *flown* in the 6-DoF simulator (:mod:`aerohrl.sim`, the
chapter-3 Hummingbird with CTBR actions, 100 Hz, 5 RK4 substeps) by the geometric
controller of the expert (:class:`aerohrl.datagen.expert.GeometricController`, Lee /
Mellinger with flatness feed-forward), tracking the primitive's polynomial; the
sensor measures along the **flown** path, not the ideal one.

* Planning stays on the lattice: the planner sees the nominal lattice state (cell,
  vertex), as in the thesis; primitive ``k+1``'s reference starts where primitive
  ``k``'s ends, so the whole episode's reference is one continuous C2 trajectory
  (quintic pieces, zero boundary acceleration), at a fixed altitude (z = 0, 1 cell =
  1 m). The vehicle starts hovering at the start cell and is never reset to the
  reference: tracking errors carry over from primitive to primitive.
* Reference at time ``t`` of a primitive started at cell ``c``: ``p = c + P(t)``,
  ``v = P'(t)``, ``a = P''(t)``, ``j = P'''(t)`` (x, y; z = 0), yaw 0.
* Sensing (the lattice's rule, :func:`aerohrl.ipp.lattice._sensing`, applied to the
  flown positions): the vehicle's position is sampled every ``sense_dt`` = 0.1 s on
  ``(0, T]``; every distinct cell its rounded position visits yields one measurement of
  each cell of the ``(2r+1)^2`` footprint (Eq. 2.2, same noise stream as ideal).
* Tracking error per primitive: ``|p_flown(t) - p_ref(t)|`` (3-D, m) over the
  primitive's control steps: its maximum and its RMS (``track_log``).
* Batched over environments: all live environments fly their primitives together in
  one :class:`~aerohrl.sim.BatchedQuadrotor`; one Python loop over control steps
  (time integration), none over environments or cells. Primitives of different
  durations: a vehicle whose primitive ended is simulated on (holding the end point)
  until the longest one ends, and its state *at its own end time* is restored
  afterwards; vehicles are independent and the dynamics time-invariant, so this is
  exactly a pause of its clock.
"""

from __future__ import annotations

import numpy as np

from .env import EnvConfig, SearchEnv
from .lattice import Lattice, poly_eval

EXECUTIONS = ("ideal", "flown")
VEHICLE = "hummingbird"
FPS = 100
SUBSTEPS = 5


class FlownEnv(SearchEnv):
    """:class:`SearchEnv` whose primitives are flown by the geometric controller."""

    def __init__(self, cfg: EnvConfig, lattice: Lattice, vehicle: str = VEHICLE):
        super().__init__(cfg, lattice)
        from aerohrl.datagen.expert import GeometricController
        from aerohrl.sim import get_preset
        self.params = get_preset(vehicle)
        self.ctrl = GeometricController(self.params)
        self.dt = 1.0 / FPS
        self.sim = None

    # ---------------------------------------------------------------- episodes
    def reset(self, worlds, start=None) -> dict:
        obs = super().reset(worlds, start)
        from aerohrl.eval.tasks import hover_states
        from aerohrl.sim import BatchedQuadrotor
        if self.sim is None or self.sim.num_vehicles != self.n:
            self.sim = BatchedQuadrotor(self.params, self.n, dt=self.dt, substeps=SUBSTEPS)
        s = hover_states(self.n)
        s[:, 0:2] = self.pos  # hover over the start cell centre, z = 0
        self.state = self.sim.reset(s)
        self.rotors = self.sim.rotor_speeds
        self.track_log: list[np.ndarray] = []  # per flown primitive: (env, max m, rms m, T s)
        self.track_max = np.zeros(self.n)
        self.track_sq = np.zeros(self.n)
        self.track_steps = np.zeros(self.n, np.int64)
        self.flown_trace = [[self.pos[i].astype(float)[None]] for i in range(self.n)] \
            if self.keep_trace else None
        return obs

    def reset_rows(self, rows, worlds, start=None) -> None:  # pragma: no cover - not offered
        raise NotImplementedError("FlownEnv restarts whole batches (reset)")

    # ------------------------------------------------------------------ flight
    def fly(self, idx: np.ndarray, pr: np.ndarray):
        """Fly primitives ``pr`` from the nominal cells of envs ``idx``; returns the flown
        positions at the sensing times (k, S, 2), their validity (k, S), and per env the
        maximum and RMS tracking error (m)."""
        lat, dt = self.lat, self.dt
        k = len(idx)
        T = lat.prim_T[pr]
        nsteps = np.rint(T / dt).astype(np.int64)  # T is on a 0.1 s grid
        every = int(round(lat.config.sense_dt / dt))
        kmax = int(nsteps.max())
        coef = lat.prim_coef[pr]  # (k, 2, 6)
        origin = self.pos[idx].astype(float)  # nominal start cells (before the step)
        st = self.state.copy()
        rot = self.rotors.copy()
        # only the flying vehicles matter; the others are restored below
        end_state, end_rot = st.copy(), rot.copy()
        emax = np.zeros(k)
        esq = np.zeros(k)
        n_s = kmax // every + 1
        samples = np.zeros((k, n_s, 2))
        sval = np.zeros((k, n_s), bool)
        ref_p = np.zeros((self.n, 3))
        ref_v = np.zeros((self.n, 3))
        ref_a = np.zeros((self.n, 3))
        ref_j = np.zeros((self.n, 3))
        # vehicles not flying hold their own position (they are restored anyway)
        ref_p[:] = st[:, 0:3]
        ref_p[idx, 2] = 0.0
        rows = np.arange(k)
        trace = [] if self.keep_trace else None
        # the references of every step, precomputed (k, 2, kmax + 1); derivatives are 0
        # after a primitive's end (the vehicle holds its end point until restored)
        tg = np.minimum(np.arange(kmax + 1)[None, :] * dt, T[:, None])
        after = (np.arange(kmax + 1)[None, :] >= nsteps[:, None])[:, None, :]
        P = [origin[:, :, None] + poly_eval(coef, tg[:, None, :], 0)] + \
            [np.where(after, 0.0, poly_eval(coef, tg[:, None, :], d)) for d in (1, 2, 3)]
        for step in range(1, kmax + 1):
            live = step <= nsteps
            ref_p[idx, :2] = P[0][:, :, step - 1]  # reference at the step's start
            ref_v[idx, :2] = P[1][:, :, step - 1]
            ref_a[idx, :2] = P[2][:, :, step - 1]
            ref_j[idx, :2] = P[3][:, :, step - 1]
            a = self.ctrl(st, ref_p, ref_v, ref_a, ref_j, yaw=0.0)
            st = self.sim.step(a)
            # error against the reference at the end of the step
            d = st[idx, 0:3]
            err = np.sqrt((d[:, 0] - P[0][:, 0, step]) ** 2 + (d[:, 1] - P[0][:, 1, step]) ** 2
                          + d[:, 2] ** 2)
            emax = np.where(live, np.maximum(emax, err), emax)
            esq = esq + np.where(live, err * err, 0.0)
            if step % every == 0:
                j = step // every
                samples[:, j, :] = st[idx, 0:2]
                sval[:, j] = live
            if trace is not None:
                trace.append(np.where(live[:, None], st[idx, 0:2], np.nan))
            ended = step == nsteps
            if ended.any():
                end_state[idx[ended]] = st[idx[ended]]
                end_rot[idx[ended]] = self.sim.rotor_speeds[idx[ended]]
        self.state = self.sim.reset(end_state, end_rot)
        self.rotors = end_rot
        rms = np.sqrt(esq / np.maximum(nsteps, 1))
        self.track_log.append(np.stack([idx.astype(float), emax, rms, T], 1))
        self.track_max[idx] = np.maximum(self.track_max[idx], emax)
        self.track_sq[idx] += esq
        self.track_steps[idx] += nsteps
        if trace is not None and trace:
            tr = np.stack(trace, 1)  # (k, kmax, 2)
            for r, i in zip(rows, idx):
                self.flown_trace[i].append(tr[r][np.isfinite(tr[r, :, 0])])
        return samples, sval, emax, rms

    def flown_measurements(self, idx, samples, sval):
        """Measurement lists (offsets from the nominal start cells, levels) of the flown
        sample positions: distinct visited centre cells x the footprint (batched)."""
        r = self.lat.config.footprint_radius
        cells = np.floor(samples + 0.5).astype(np.int64)  # (k, S, 2) global cells
        # distinct cells per env: sort codes per row and drop repeats
        big = 1 << 20
        code = np.where(sval, (cells[..., 1] + big // 2) * big + cells[..., 0] + big // 2, -1)
        order = np.argsort(code, axis=1, kind="stable")
        sc = np.take_along_axis(code, order, 1)
        dup_sorted = np.zeros_like(sc, bool)
        dup_sorted[:, 1:] = sc[:, 1:] == sc[:, :-1]
        dup = np.zeros_like(dup_sorted)
        np.put_along_axis(dup, order, dup_sorted, 1)
        keep = sval & ~dup
        fx, fy = np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1), indexing="xy")
        foot = np.stack([fx.ravel(), fy.ravel()], 1)  # (F, 2)
        flev = np.maximum(np.abs(foot[:, 0]), np.abs(foot[:, 1]))
        rel = cells - self.pos[idx][:, None, :]  # offsets from the nominal start cell
        lim = self.pad - r - 1  # stay inside the padded arrays whatever the error
        rel = np.clip(rel + self.pos[idx][:, None, :], -lim, self.S - 1 + lim) \
            - self.pos[idx][:, None, :]
        off = (rel[:, :, None, :] + foot[None, None]).reshape(len(idx), -1, 2)
        lev = np.where(keep[:, :, None], flev[None, None], -1).reshape(len(idx), -1)
        return off, lev

    def _apply(self, idx, pr):
        samples, sval, _, _ = self.fly(idx, pr)
        off, lev = self.flown_measurements(idx, samples, sval)
        return self._apply_meas(idx, off, lev)

    def metrics(self):
        m = super().metrics()
        m["track_max_m"] = self.track_max.copy()
        m["track_rms_m"] = np.sqrt(self.track_sq / np.maximum(self.track_steps, 1))
        return m

    def tracking_table(self) -> np.ndarray:
        """(primitives flown, 4): env, max error (m), RMS error (m), duration (s)."""
        return np.concatenate(self.track_log, 0) if self.track_log else np.zeros((0, 4))


def create_flown_env(cfg: EnvConfig, lattice: Lattice, execution: str) -> SearchEnv:
    """A :class:`SearchEnv` (``ideal``) or :class:`FlownEnv` (``flown``), target search."""
    from aerohrl.errors import UserError
    if execution not in EXECUTIONS:
        raise UserError(f"unknown execution mode {execution!r} (choose from {', '.join(EXECUTIONS)})")
    if execution == "ideal":
        return SearchEnv(cfg, lattice)
    if cfg.kind != "targets":
        raise UserError("--execution flown is for target search (--world targets)")
    return FlownEnv(cfg, lattice)


__all__ = ["FlownEnv", "EXECUTIONS", "create_flown_env"]
