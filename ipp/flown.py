"""Primitives flown by the vehicle (thesis §2.6.4 analogue).

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

from typing import TYPE_CHECKING

import numpy as np

from .env import EnvConfig, SearchEnv
from .lattice import Lattice, poly_eval

if TYPE_CHECKING:
    from pathlib import Path

    from aerohrl.envs.rollout import PolicyFn
    from aerohrl.sim import BatchedQuadrotor

    from .world import Worlds

EXECUTIONS = ("ideal", "flown", "skill")
SKILL_SPACING = 1.0  # s: goals at most this far apart along a primitive (0.5-1 s apart)
SKILL_TIMEOUT = (2.0, 1.0)  # a leg gives up after 2 x its duration + 1 s
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
        self.sim: BatchedQuadrotor | None = None

    # ---------------------------------------------------------------- episodes
    def reset(self, worlds: Worlds, start: np.ndarray | None = None) -> dict:
        """Reset as :meth:`SearchEnv.reset` and put every vehicle at hover over its start cell;
        returns the observation."""
        obs = super().reset(worlds, start)
        from aerohrl.envs.episodes import hover_states
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
        self.flown_trace: list[list[np.ndarray]] | None = (
            [[self.pos[i].astype(float)[None]] for i in range(self.n)] if self.keep_trace else None
        )
        return obs

    def reset_rows(
        self,
        rows: np.ndarray,
        worlds: Worlds,  # pragma: no cover - not offered
        start: np.ndarray | None = None,
    ) -> None:
        """Not offered: a flown env restarts whole batches (:meth:`reset`)."""
        raise NotImplementedError("FlownEnv restarts whole batches (reset)")

    # ------------------------------------------------------------------ flight
    def fly(self, idx: np.ndarray, pr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
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
        assert self.sim is not None  # made by reset
        st = self.state.copy()
        rot = self.rotors.copy()
        # only the flying vehicles matter; the others are restored below
        end_state, end_rot = st.copy(), rot.copy()
        emax: np.ndarray = np.zeros(k)
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
        trace: list[np.ndarray] | None = [] if self.keep_trace else None
        # the references of every step, precomputed (k, 2, kmax + 1); derivatives are 0
        # after a primitive's end (the vehicle holds its end point until restored)
        tg = np.minimum(np.arange(kmax + 1)[None, :] * dt, T[:, None])
        after = (np.arange(kmax + 1)[None, :] >= nsteps[:, None])[:, None, :]
        P = [origin[:, :, None] + poly_eval(coef, tg[:, None, :], 0)] + [
            np.where(after, 0.0, poly_eval(coef, tg[:, None, :], d)) for d in (1, 2, 3)
        ]
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
            err = np.sqrt((d[:, 0] - P[0][:, 0, step]) ** 2 + (d[:, 1] - P[0][:, 1, step]) ** 2 + d[:, 2] ** 2)
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
            assert self.flown_trace is not None  # kept with the trace (keep_trace)
            tr = np.stack(trace, 1)  # (k, kmax, 2)
            for r, i in zip(rows, idx):
                self.flown_trace[i].append(tr[r][np.isfinite(tr[r, :, 0])])
        return samples, sval, emax, rms

    def flown_measurements(self, idx: np.ndarray, samples: np.ndarray, sval: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
        rel = np.clip(rel + self.pos[idx][:, None, :], -lim, self.S - 1 + lim) - self.pos[idx][:, None, :]
        off = (rel[:, :, None, :] + foot[None, None]).reshape(len(idx), -1, 2)
        lev = np.where(keep[:, :, None], flev[None, None], -1).reshape(len(idx), -1)
        return off, lev

    def _apply(self, idx, pr):
        samples, sval, _, _ = self.fly(idx, pr)
        off, lev = self.flown_measurements(idx, samples, sval)
        return self._apply_meas(idx, off, lev)

    def metrics(self) -> dict[str, np.ndarray]:
        """Per-env metrics of :meth:`SearchEnv.metrics` plus the tracking error: max and RMS (m)."""
        m = super().metrics()
        m["track_max_m"] = self.track_max.copy()
        m["track_rms_m"] = np.sqrt(self.track_sq / np.maximum(self.track_steps, 1))
        return m

    def tracking_table(self) -> np.ndarray:
        """(primitives flown, 4): env, max error (m), RMS error (m), duration (s)."""
        return np.concatenate(self.track_log, 0) if self.track_log else np.zeros((0, 4))


class SkillEnv(FlownEnv):
    """Primitives flown by the chapter-3 goal-conditioned policy.

    Each primitive of duration ``T`` is cut into ``n = ceil(T / SKILL_SPACING)`` legs of
    ``T / n`` s (0.5-1 s apart); leg ``l``'s goal is the primitive's state at
    ``t_l = l T / n``: position, velocity and the flat attitude of its acceleration
    (:func:`aerohrl.datagen.goals.flat_attitude`, yaw 0). The policy flies toward the
    current goal; the leg ends when the goal is reached within the near-success
    tolerance (x 2.5, a waypoint need not be hit exactly) or after ``2 x (T/n) + 1 s``,
    and the next goal follows. A leg *succeeds* when the strict goal-reached test holds
    at some step of it (``leg_success``; ``leg_near`` with x 2.5). Sensing samples the
    flown position every 0.1 s of the (variable-length) flight. Tracking error: the
    distance of the flown position to the primitive's path (nearest of 200 points on
    it), max and RMS per primitive. Batched over environments: one policy forward and
    one simulator step per control step for all of them."""

    def __init__(self, cfg: EnvConfig, lattice: Lattice, policy_fn, vehicle: str = VEHICLE):
        super().__init__(cfg, lattice, vehicle)
        self.policy = policy_fn
        self.leg_log: list[np.ndarray] = []

    def reset(self, worlds: Worlds, start: np.ndarray | None = None) -> dict:
        """Reset as :meth:`FlownEnv.reset` and clear the leg log; returns the observation."""
        obs = super().reset(worlds, start)
        self.leg_log = []  # per leg: (strict success, near success, duration s)
        return obs

    def fly(self, idx: np.ndarray, pr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Fly primitives ``pr`` of envs ``idx`` with the skill policy, leg by leg (class
        docstring); returns the flown positions at the sensing times (k, S, 2), their validity
        (k, S), and per env the maximum and RMS tracking error (m)."""
        from aerohrl import task
        from aerohrl.datagen.goals import flat_attitude

        lat, dt = self.lat, self.dt
        k = len(idx)
        T = lat.prim_T[pr]
        nleg = np.ceil(T / SKILL_SPACING - 1e-9).astype(np.int64)
        L = int(nleg.max())
        origin = self.pos[idx].astype(float)
        coef = lat.prim_coef[pr]
        # goals (k, L, 15): legs beyond nleg repeat the last one (never used)
        tl = np.minimum(np.arange(1, L + 1)[None, :], nleg[:, None]) * (T / nleg)[:, None]
        goals = np.zeros((k, L, task.GOAL_DIM))
        goals[..., 0:2] = origin[:, None, :] + np.moveaxis(poly_eval(coef, tl[:, None, :], 0), 1, 2)
        goals[..., 3:5] = np.moveaxis(poly_eval(coef, tl[:, None, :], 1), 1, 2)
        acc = np.zeros((k, L, 3))
        acc[..., 0:2] = np.moveaxis(poly_eval(coef, tl[:, None, :], 2), 1, 2)
        goals[..., 6:15] = flat_attitude(acc).reshape(k, L, 9)
        leg_len = np.rint((T / nleg) / dt).astype(np.int64)
        timeout = np.rint(SKILL_TIMEOUT[0] * leg_len + SKILL_TIMEOUT[1] / dt).astype(np.int64)
        # the primitive's path, for the path-deviation error
        tp = np.linspace(0, 1, 200)[None, :] * T[:, None]
        path = origin[:, :, None] + poly_eval(coef, tp[:, None, :], 0)  # (k, 2, 200)
        assert self.sim is not None  # made by reset
        st = self.state.copy()
        end_state, end_rot = st.copy(), self.rotors.copy()
        leg = np.zeros(k, np.int64)
        in_leg = np.zeros(k, np.int64)
        strict = np.zeros(k, bool)
        near = np.zeros(k, bool)
        flying = np.ones(k, bool)
        steps = np.zeros(k, np.int64)
        emax: np.ndarray
        emax, esq = np.zeros(k), np.zeros(k)
        every = int(round(lat.config.sense_dt / dt))
        max_steps = int((timeout * nleg).sum(0).max()) if k else 0
        samples = np.zeros((k, max_steps // every + 2, 2))
        sval = np.zeros(samples.shape[:2], bool)
        trace: list[np.ndarray] | None = [] if self.keep_trace else None
        rows = np.arange(k)
        goal_all = np.zeros((self.n, task.GOAL_DIM))
        goal_all[:] = np.concatenate([st[:, 0:6], st[:, 6:15]], 1)  # others: hold (restored)
        step = 0
        while flying.any():
            step += 1
            g = goals[rows, np.minimum(leg, L - 1)]
            goal_all[idx] = g
            a = self.policy(st, goal_all)
            st = self.sim.step(a)
            sub = st[idx]
            ag = task.achieved_goal(sub)
            hit = task.goal_reached(ag, g) & flying
            hit_near = task.near_success(ag, g) & flying
            strict |= hit
            near |= hit_near
            in_leg += flying
            steps += flying
            d = np.sqrt(((sub[:, 0:2, None] - path) ** 2).sum(1)).min(1)
            d = np.sqrt(d**2 + sub[:, 2] ** 2)
            emax = np.where(flying, np.maximum(emax, d), emax)
            esq += np.where(flying, d * d, 0.0)
            if step % every == 0:
                j = step // every
                samples[:, j] = sub[:, 0:2]
                sval[:, j] = flying
            if trace is not None:
                trace.append(np.where(flying[:, None], sub[:, 0:2], np.nan))
            end_leg = flying & (hit_near | (in_leg >= timeout))
            if end_leg.any():
                for r in np.flatnonzero(end_leg):
                    self.leg_log.append(np.array([strict[r], near[r], in_leg[r] * dt]))
                leg[end_leg] += 1
                in_leg[end_leg] = 0
                strict[end_leg] = False
                near[end_leg] = False
                done = end_leg & (leg >= nleg)
                if done.any():
                    flying &= ~done
                    end_state[idx[done]] = st[idx[done]]
                    end_rot[idx[done]] = self.sim.rotor_speeds[idx[done]]
            if not np.isfinite(st).all():
                raise RuntimeError("a skill-flown vehicle diverged")
        self.state = self.sim.reset(end_state, end_rot)
        self.rotors = end_rot
        rms = np.sqrt(esq / np.maximum(steps, 1))
        self.track_log.append(np.stack([idx.astype(float), emax, rms, steps * dt], 1))
        self.track_max[idx] = np.maximum(self.track_max[idx], emax)
        self.track_sq[idx] += esq
        self.track_steps[idx] += steps
        self.skill_time = getattr(self, "skill_time", np.zeros(self.n))
        if len(self.skill_time) != self.n:
            self.skill_time = np.zeros(self.n)
        self.skill_time[idx] += steps * dt
        if trace is not None and trace:
            assert self.flown_trace is not None  # kept with the trace (keep_trace)
            tr = np.stack(trace, 1)
            for r, i in zip(rows, idx):
                self.flown_trace[i].append(tr[r][np.isfinite(tr[r, :, 0])])
        return samples[:, : step // every + 1], sval[:, : step // every + 1], emax, rms

    def metrics(self) -> dict[str, np.ndarray]:
        """Per-env metrics of :meth:`FlownEnv.metrics` plus the skill's flight time (s)."""
        m = super().metrics()
        m["skill_flight_s"] = getattr(self, "skill_time", np.zeros(self.n)).copy()
        return m

    def leg_table(self) -> np.ndarray:
        """(legs, 3): strict success, near success, duration (s) of every leg flown."""
        return np.stack(self.leg_log, 0) if self.leg_log else np.zeros((0, 3))


def load_skill(run: str | Path | None) -> tuple:
    """The goal-conditioned policy of a chapter-3 training run (``RUN`` directory: its last
    checkpoint; or a checkpoint file) as a batched ``(states, goals) -> CTBR`` function,
    and a label. A missing run or checkpoint is a one-line error."""
    from pathlib import Path

    from aerohrl.errors import UserError

    if run is None:
        raise UserError("--execution skill needs --skill-run <chapter-3 policy run directory>")
    from aerohrl.algorithms.run import Run

    p, skill_run = Path(run), None
    if p.is_dir():
        skill_run = Run(p)  # a copied run folder may lack its config.json: the checkpoints suffice
        cks = skill_run.checkpoints()
        if not cks:
            raise UserError(f"skill run {p} has no checkpoints ({skill_run.layout.glob})")
        p = cks[-1]
    elif not p.is_file():
        raise UserError(f"no skill policy run at {run}")
    import torch

    from aerohrl.algorithms.base import load_policy
    from aerohrl.envs.rollout import PolicyFn

    torch.set_num_threads(1)
    algo, ck = load_policy(p, run=skill_run)
    return PolicyFn(algo), f"{p.parent.parent.name}/{p.name}"


def create_flown_env(cfg: EnvConfig, lattice: Lattice, execution: str, skill: PolicyFn | None = None) -> SearchEnv:
    """A :class:`SearchEnv` (``ideal``), :class:`FlownEnv` (``flown``, the geometric
    controller) or :class:`SkillEnv` (``skill``, the policy ``skill`` of
    :func:`load_skill`); target search only."""
    from aerohrl.errors import UserError

    if execution not in EXECUTIONS:
        raise UserError(f"unknown execution mode {execution!r} (choose from {', '.join(EXECUTIONS)})")
    if execution == "ideal":
        return SearchEnv(cfg, lattice)
    if cfg.kind != "targets":
        raise UserError(f"--execution {execution} is for target search (--world targets)")
    if execution == "skill":
        if skill is None:
            raise UserError("--execution skill needs --skill-run <chapter-3 policy run directory>")
        return SkillEnv(cfg, lattice, skill)
    return FlownEnv(cfg, lattice)


__all__ = ["FlownEnv", "SkillEnv", "EXECUTIONS", "create_flown_env", "load_skill"]
