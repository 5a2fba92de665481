"""``datagen build``: goals -> minimum-time references -> expert rollouts -> dataset.

The pipeline of thesis §3.4.1 with the readings of docs/spec.md "Expert data":

1. desired goals rho_D sampled from the spec's ranges (seeded); the goal attitude
   follows from flatness (:mod:`aerohrl.datagen.goals`);
2. per goal a minimum-time minimum-jerk polynomial reference per axis under the
   acceleration bound (thesis Alg. 1, :mod:`aerohrl.datagen.reference`); goals with no
   feasible reference within ``t_max`` are resampled and counted;
3. the geometric expert (:mod:`aerohrl.datagen.expert`) tracks every reference at once
   in the batched simulator (:mod:`aerohrl.sim`), recording each 100 Hz step until T;
4. the frames are streamed into a LeRobot v3.0 dataset block by block as the flights
   land (:func:`stream_dataset`, :class:`aerohrl.datagen.lerobot_writer.DatasetWriter`:
   memory stays bounded by a block, the bytes are those of one bulk write), then our own
   metadata and checksums (:mod:`aerohrl.datagen.manifest`) and a dataset card.

Everything is written into a temporary directory beside the target and renamed into
place at the end, so an interrupted build leaves no half-written version.
"""

from __future__ import annotations

import os
import platform
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator, cast

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from tqdm.auto import tqdm

from aerohrl import __version__ as AEROHRL_VERSION
from aerohrl import task
from aerohrl.errors import UserError
from aerohrl.datagen import goals as goals_mod
from aerohrl.datagen import recipes, reference
from aerohrl.datagen.expert import DisturbanceObserver, GeometricController, ThrustGainObserver
from aerohrl.datagen.dataset import FORMAT
from aerohrl.datagen.lerobot_reader import read_info
from aerohrl.datagen.lerobot_writer import DatasetWriter
from aerohrl.datagen.manifest import read_manifest, validate, write_manifest
from aerohrl.datagen.spec import EXPLORE_TASK, GENERATOR_VERSION, MAZE_TASK, TASK, WALK_TASK, DatasetSpec, spec_hash, version_name
from aerohrl.sim import BatchedQuadrotor, Perturbation, get_preset

if TYPE_CHECKING:
    from concurrent.futures import ProcessPoolExecutor

EPISODES_FILE = "meta/aerohrl_episodes.parquet"
REPO_ID = "aerohrl/quadrotor-reach"
CONTINUATION_STREAM = 7  # seed stream of the continuation episodes: [spec.seed, 7]


@dataclass
class ExpertData:
    """Everything the rollout produced, frames episode-major (F = total frames)."""

    goals: dict  # pos, vel, acc (N,3), R (N,3,3)
    goal_vec: np.ndarray  # (N,15)
    T: np.ndarray  # (N,) reference durations (s)
    length: np.ndarray  # (N,) recorded steps per episode
    episode_index: np.ndarray  # (F,)
    frame_index: np.ndarray  # (F,)
    state: np.ndarray  # (F,18) float64
    action: np.ndarray  # (F,4)
    next_state: np.ndarray  # (F,18)
    success: np.ndarray  # (F,) goal reached at the next state
    resampled: int = 0
    source_episode: np.ndarray | None = None  # (N,) continuation: the rest-start episode its start is taken from (-1: rest start)
    source_frame: np.ndarray | None = None  # (N,) and the frame within it (-1: rest start)
    action_expert: np.ndarray | None = None  # (F,4) the clean expert command at each flown state (action noise)
    goal_index: np.ndarray | None = None  # (N,) the desired goal each episode flies (rollouts_per_goal > 1)
    timings: dict = field(default_factory=dict)
    perturbation: dict | None = None  # {axis: (N,)} each episode's vehicle under domain randomisation
    disturbance: np.ndarray | None = None  # (F,3) the expert's disturbance estimate (spec disturbance_observer)

    @property
    def episode_success(self) -> np.ndarray:
        """Per episode (``len(T)``): True when any of its steps reached the goal."""
        return np.bincount(self.episode_index, weights=self.success, minlength=len(self.T)) > 0


@dataclass
class BuildResult:
    path: Path
    created: bool  # False: the version existed and was verified instead
    episodes: int
    frames: int
    expert_success: float
    resampled: int
    seconds: float


def plan_references(
    spec: DatasetSpec,
    rng: np.random.Generator,
    n: int | None = None,
    sample_starts: Callable[[int], tuple[np.ndarray, np.ndarray | None]] | None = None,
) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, int, np.ndarray | None]:
    """Sample rho_D and solve each goal's minimum-time reference; resample infeasible goals.

    Returns (goals, T, coeffs, resampled, sources). Replacement goals come from the same
    generator in order, so the result is a function of the spec alone. By default every
    reference starts at rest at the origin (x0 = 0) and ``sources`` is None;
    ``sample_starts(k) -> (x0 (k, 3, 3), sources (k,))`` draws other starts instead, and an
    infeasible pair is redrawn whole (start and goal).
    """
    n = spec.goals if n is None else int(n)

    def sample(k):
        x0, src = sample_starts(k) if sample_starts is not None else (np.zeros((k, 3, 3)), None)
        g = goals_mod.sample_goals(rng, k, pos_range=spec.pos_range, vel_range=spec.vel_range, acc_range=spec.acc_range)
        return x0, src, g

    def solve(x0, g):
        xf = np.stack([g["pos"], g["vel"], g["acc"]], axis=-1)  # [n, axis, (p, v, a)]
        return reference.min_time(
            x0, xf, a_max=spec.a_max, t_lo=0.0, t_hi=spec.t_max, tol=spec.bisection_tol, solver=spec.solver, degree=spec.degree
        )

    x0, src, g = sample(n)
    T, coeffs, feasible = solve(x0, g)
    resampled = 0
    while not feasible.all():
        bad = np.flatnonzero(~feasible)
        resampled += len(bad)
        if resampled > 20 * n:
            raise UserError(
                f"almost no goal in these ranges has a reference within t_max={spec.t_max} s at a_max={spec.a_max} "
                f"(resampled {resampled}); widen --t-max or narrow the ranges"
            )
        x2, s2, g2 = sample(len(bad))
        T2, c2, f2 = solve(x2, g2)
        for key in g:
            g[key][bad] = g2[key]
        if src is not None:
            src[bad] = s2
        T[bad], coeffs[bad], feasible[bad] = T2, c2, f2
    return g, T, coeffs, resampled, src


@dataclass
class Rollout:
    """One batch of expert flights (:func:`rollout_expert`); arrays time-major."""

    states: np.ndarray  # (kmax + 1, N, 18)
    actions: np.ndarray  # (kmax, N, 4): what was flown
    length: np.ndarray  # (N,) recorded steps per episode
    rotors: np.ndarray | None = None  # (kmax + 1, N, 4) with record_rotors
    expert_actions: np.ndarray | None = None  # (kmax, N, 4): the clean command, with action noise
    disturbance: np.ndarray | None = None  # (kmax, N, 3): the observer's estimate each command used


def rollout_expert(
    spec: DatasetSpec,
    goals: dict,
    T: np.ndarray,
    coeffs: np.ndarray,
    progress: bool = True,
    start_state: np.ndarray | None = None,
    rotor_speeds: np.ndarray | None = None,
    record_rotors: bool = False,
    noise_rng: np.random.Generator | None = None,
    perturbation: Perturbation | None = None,
    perturb_seed: int | list[int] = 0,
    extra_steps: int = 0,
    drop_ended: bool = False,
) -> Rollout:
    """Fly every reference at once with the geometric expert; record each step until T.

    Episode i records steps k = 0 .. ceil(T_i * fps) - 1: state s_k, action a_k and
    next state s_{k+1}. After its own end an episode keeps flying (it is simply not
    recorded) so the batch stays rectangular. ``start_state`` / ``rotor_speeds`` (N, 18) /
    (N, 4) replace hover at the origin; ``record_rotors`` also keeps the rotor speeds at
    every step. The spec's recipe applies (datagen/recipes.py): with ``spec.expert ==
    "replan"`` the references are re-planned from the flown state (shrinking horizon);
    with action noise (``noise_rng`` required) the vehicle flies the expert's command plus
    Ornstein-Uhlenbeck noise, clipped to the expert's action box, and ``expert_actions``
    holds the clean command at every flown state.

    ``perturbation`` flies the vehicles on a perturbed plant (:mod:`aerohrl.sim.perturb`,
    seeded by ``perturb_seed``): the expert (and re-planning) sees the observed state, the
    states recorded are the true ones. ``extra_steps``: keep flying this many steps past the
    longest reference, holding its end (robustness curves judge the goal over a horizon).

    ``drop_ended``: once a quarter of the vehicles still flown have passed their recorded
    steps, the simulator keeps only the others (:meth:`aerohrl.sim.BatchedQuadrotor.select`,
    bit for bit), and so do the reference and the command; the noise is still drawn for
    every episode, so each keeps its own stream. The cost is that of the recorded steps,
    not of the longest; ``states`` / ``actions`` past an episode's length are then left
    unset. Not with re-planning, a perturbed plant, ``extra_steps`` or ``record_rotors``.
    """
    params = get_preset(spec.vehicle)
    n = len(T)
    dt = spec.dt
    length = np.ceil(T * spec.fps - 1e-9).astype(np.int64)
    kmax = int(length.max()) + int(extra_steps)
    sim = BatchedQuadrotor(params, n, dt=dt, substeps=spec.substeps, perturbation=perturbation, seed=perturb_seed)
    ctrl = GeometricController(params)
    out = Rollout(
        np.empty((kmax + 1, n, task.STATE_DIM)),
        np.empty((kmax, n, task.ACTION_DIM)),
        length,
        np.empty((kmax + 1, n, 4)) if record_rotors else None,
    )
    states, actions = out.states, out.actions
    noise = None
    if spec.noisy:
        if noise_rng is None:
            raise ValueError("a spec with action noise needs noise_rng")
        noise = recipes.OUNoise(spec.action_noise, spec.noise_tau, dt, n, noise_rng)
        out.expert_actions = np.empty_like(actions)
        lo, hi = ctrl.action_box
    replanning = spec.expert == "replan"
    t0: np.ndarray | float
    if replanning:
        coeffs = coeffs.copy()
        t0 = np.zeros(n)  # start time of each episode's current plan
        xf = np.stack([goals["pos"], goals["vel"], goals["acc"]], axis=-1)
    else:
        t0 = 0.0
    states[0] = sim.reset(start_state, rotor_speeds)
    dob = DisturbanceObserver(n, spec.disturbance_observer, dt) if spec.disturbance_observer > 0 else None
    # the estimate the expert controls with (recorded: always the additive one, dob)
    gob = ThrustGainObserver(n, spec.disturbance_observer, dt) if spec.observer_model == "gain" else None
    if dob is not None:
        out.disturbance = np.empty((kmax, n, 3))
    drop_ended = drop_ended and not (replanning or perturbation is not None or extra_steps or record_rotors or dob or gob)
    if drop_ended:
        return _rollout_dropping_ended(out, sim, ctrl, coeffs, T, dt, noise, kmax, progress)
    for k in tqdm(range(kmax), desc="expert rollouts", unit="step", disable=None if progress else True, leave=False):
        if record_rotors:
            assert out.rotors is not None  # allocated with record_rotors
            out.rotors[k] = sim.rotor_speeds
        t = np.minimum(k * dt, T)
        seen = states[k] if sim.plant is None else sim.observe()
        if replanning and k > 0 and k % spec.replan_every == 0:
            # t0 holds each episode's plan start (an array) when replanning
            end = xf
            if spec.terminal_disturbance:  # the spec's field comment: arrive at the goal's attitude
                assert dob is not None  # DatasetSpec.check: terminal_disturbance needs the observer
                # horizontal only: a vertical estimate changes the thrust's size, not its direction
                end = xf.copy()
                end[:, :2, 2] += (dob if gob is None else gob).d_hat[:, :2]
            due = T - k * dt > spec.replan_endgame + 1e-9
            recipes.replan(coeffs, cast(np.ndarray, t0), due, k * dt, seen, end, T)
            if spec.endgame_retarget:  # the spec's field comment: only the end follows the estimate
                late = ~due & (T - k * dt > spec.replan_every * dt - 1e-9)  # at least one re-plan period left
                recipes.replan(coeffs, cast(np.ndarray, t0), late, k * dt, None, end, T)
        ref = [reference.evaluate(coeffs, t - t0, order=o) for o in range(4)]
        if dob is not None:
            assert out.disturbance is not None  # allocated with the observer
            out.disturbance[k] = dob.d_hat
        if gob is not None:
            a = ctrl(seen, *ref, yaw=0.0, disturbance=gob.d_hat, thrust_gain=gob.kappa_hat)
        else:
            a = ctrl(seen, *ref, yaw=0.0, disturbance=None if dob is None else dob.d_hat)
        if noise is not None:
            assert out.expert_actions is not None  # allocated with the noise
            out.expert_actions[k] = a
            a = np.clip(a + noise(), lo, hi)
        if dob is not None:  # with the collective flown, for the next command
            dob.update(seen, a[:, 0])
        if gob is not None:
            gob.update(seen, a[:, 0])
        actions[k] = a
        states[k + 1] = sim.step(a)
    if record_rotors:
        assert out.rotors is not None
        out.rotors[kmax] = sim.rotor_speeds
    return out


# The batch never shrinks below this many vehicles: NumPy's kernels round differently in
# the last bits for a batch of one vehicle, and the bytes must not depend on the dropping.
_MIN_FLOWN = 16


def _rollout_dropping_ended(out: Rollout, sim, ctrl, coeffs, T, dt, noise, kmax: int, progress: bool) -> Rollout:
    """:func:`rollout_expert`'s loop (open-loop expert, nominal plant) over a batch that
    shrinks as episodes pass their recorded steps: the same arithmetic per vehicle."""
    states, actions, length = out.states, out.actions, out.length
    act: np.ndarray = np.arange(len(T))  # the episodes in the simulator's batch, in order
    s = states[0]
    c, Ta = coeffs, T
    if noise is not None:
        lo, hi = ctrl.action_box
    for k in tqdm(range(kmax), desc="expert rollouts", unit="step", disable=None if progress else True, leave=False):
        ended = length[act] <= k
        if 4 * ended.sum() >= len(act) and len(act) - ended.sum() >= _MIN_FLOWN:
            keep = np.flatnonzero(~ended)
            sim, act, s = sim.select(keep), act[keep], s[keep]
            c, Ta = coeffs[act], T[act]
        t = np.minimum(k * dt, Ta)
        ref = [reference.evaluate(c, t, order=o) for o in range(4)]
        a = ctrl(s, *ref, yaw=0.0)
        if noise is not None:
            assert out.expert_actions is not None  # allocated with the noise
            out.expert_actions[k, act] = a
            a = np.clip(a + noise()[act], lo, hi)
        actions[k, act] = a
        s = sim.step(a)
        states[k + 1, act] = s
    return out


# Episodes flown per batch: bounds the rollout's (steps, N, 18) buffers (~0.5 GB at 8192).
# Every flight's result depends on its own inputs only, and the noise streams are drawn
# per block, so the bytes are a function of the spec and this constant.
ROLLOUT_BLOCK = 8192
NOISE_STREAM = 11  # seed stream of the action noise: [spec.seed, 11, part, block]
START_STREAM = 13  # seed stream of the perturbed start states: [spec.seed, 13]
RANDOMIZE_STREAM = 19  # domain randomisation: values [spec.seed, 19], gusts and noise [spec.seed, 19, part, block]


def episode_perturbations(spec: DatasetSpec, n: int) -> dict[str, np.ndarray] | None:
    """Each of ``n`` episodes' perturbation values under ``spec.randomize`` (uniform in the
    ranges, stream ``[spec.seed, 19]``): ``{axis: (n,)}``, or None without randomisation."""
    if not spec.randomize:
        return None
    from aerohrl.sim.perturb import parse_ranges, sample

    return sample(parse_ranges(spec.randomize), n, np.random.default_rng([spec.seed, RANDOMIZE_STREAM]))


# Below this a recipe is refused. Not a quality bar: the labels are the clean command at
# every flown state, and the noisiest recipe that trains best reaches well under half of its
# goals (docs/results/ "recipes"); below 20 % the flights rarely come near their goals, and
# the data would miss how a flight ends at its goal.
MIN_EXPERT_SUCCESS = 0.2


@dataclass
class _Frames:
    """Recorded frames of a set of episodes, episode-major (filled block by block)."""

    ep: np.ndarray
    k: np.ndarray
    state: np.ndarray
    action: np.ndarray
    next_state: np.ndarray
    expert_action: np.ndarray | None
    rotors: np.ndarray | None  # rotor speeds at each recorded state (record_rotors)
    success: np.ndarray  # (F,) the goal-reached test at the next state
    disturbance: np.ndarray | None = None  # (F, 3) the expert's disturbance estimate (observer)


def _frame_index(T: np.ndarray, fps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A block's recorded frames, episode-major: per episode its ``length`` (steps until its
    reference ends) and first frame ``starts``; per frame its episode ``e`` and step ``kk``."""
    length = np.ceil(T * fps - 1e-9).astype(np.int64)
    starts = np.cumsum(length) - length
    e = np.repeat(np.arange(len(T)), length)
    return length, starts, e, np.arange(int(length.sum())) - np.repeat(starts, length)


def _fly_block(
    spec: DatasetSpec,
    goals: dict,
    T: np.ndarray,
    coeffs: np.ndarray,
    start_state,
    rotor_speeds,
    record_rotors: bool,
    part: int,
    block: int,
    progress: bool = False,
    perturb: dict | None = None,
) -> dict:
    """One block's flights (:func:`rollout_expert`), returned as its recorded frames,
    episode-major: what a worker process or Ray task sends back. A function of its
    arguments alone (noise stream ``[spec.seed, 11, part, block]``), so the bytes do not
    depend on where it runs. ``perturb``: each episode's perturbation values (domain
    randomisation), its gusts and noise from ``[spec.seed, 19, part, block]``."""
    length, _, e, kk = _frame_index(T, spec.fps)
    r = _block_rollout(spec, goals, T, coeffs, start_state, rotor_speeds, record_rotors, part, block, progress, perturb)
    out = {"state": r.states[kk, e], "action": r.actions[kk, e], "next_state": r.states[kk + 1, e]}
    if r.expert_actions is not None:
        out["expert_action"] = r.expert_actions[kk, e]
    if r.disturbance is not None:
        out["disturbance"] = r.disturbance[kk, e]
    if record_rotors:
        assert r.rotors is not None  # recorded with record_rotors
        out["rotors"] = r.rotors[kk, e]
    del r  # the rollout's (steps, N, .) buffers, before the goal test's temporaries
    out["success"] = task.goal_reached(task.achieved_goal(out["next_state"]), goals_mod.goal_vectors(goals)[e])
    return out


def _block_rollout(
    spec: DatasetSpec,
    goals: dict,
    T: np.ndarray,
    coeffs: np.ndarray,
    start_state,
    rotor_speeds,
    record_rotors: bool,
    part: int,
    block: int,
    progress: bool = False,
    perturb: dict | None = None,
) -> Rollout:
    """The :func:`rollout_expert` of one block, with its own noise, gust and observation
    streams (``[spec.seed, 11 | 19, part, block]``): :func:`_fly_block`'s flights."""
    rng = np.random.default_rng([spec.seed, NOISE_STREAM, part, block]) if spec.noisy else None
    pert = Perturbation(**perturb) if perturb else None
    return rollout_expert(
        spec,
        goals,
        T,
        coeffs,
        progress,
        start_state,
        rotor_speeds,
        record_rotors,
        rng,
        perturbation=pert,
        perturb_seed=[spec.seed, RANDOMIZE_STREAM, part, block],
        drop_ended=True,
    )


# Frames per piece when a block's recorded frames are gathered from the rollout: bounds
# the float64 temporaries (the pieces are equal, none tiny).
_GATHER_FRAMES = 1 << 16


def _rows(a: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``a[k, e]`` of a (steps, episodes, ...) buffer for flat rows ``at = k * episodes + e``:
    one ``np.take`` over the buffer's rows, several times faster than indexing with the
    two index arrays."""
    return np.take(a.reshape(-1, *a.shape[2:]), at, axis=0)


def _fly_block_columns(*args: Any) -> dict[str, Any]:
    """:func:`_fly_block` (its arguments, then the block's goal vectors (n, 15)) turned into
    what the writer and the episode summary take: ``columns`` (those of :func:`frame_columns`),
    ``ep_stats`` (the per-episode statistics of those columns,
    :func:`aerohrl.datagen.lerobot_stats.episode_stats`), per episode ``success``,
    ``first`` (first frame meeting the goal test, -1: none) and ``final`` (the state after
    the last action, float64). Run where the block is flown, so a worker does this work."""
    from aerohrl.datagen.lerobot_stats import episode_stats

    *fly_args, goal_vec = args
    spec, goals, T = fly_args[0], fly_args[1], fly_args[2]
    r = _block_rollout(*fly_args)
    n = len(T)
    length, starts, e, kk = _frame_index(T, spec.fps)
    ends = starts + length
    F = int(ends[-1])
    # the frames gathered straight into their float32 columns, piece by piece (no
    # float64 copy of the block's frames); the goal test on the float64 next states
    # (in frame_columns' order)
    cols: dict[str, np.ndarray] = {
        "observation.state": np.empty((F, task.STATE_DIM), np.float32),
        "action": np.empty((F, task.ACTION_DIM), np.float32),
        "observation.desired_goal": goal_vec.astype(np.float32)[e],
        "next.observation.state": np.empty((F, task.STATE_DIM), np.float32),
    }
    success_f = np.empty(F, bool)
    expert = np.empty((F, task.ACTION_DIM), np.float32) if r.expert_actions is not None else None
    dist = np.empty((F, 3), np.float32) if r.disturbance is not None else None
    gv = goals_mod.goal_vectors(goals)
    cuts = np.linspace(0, F, -(-F // _GATHER_FRAMES) + 1).round().astype(np.int64)
    for c0, c1 in zip(cuts[:-1], cuts[1:]):
        ee, at = e[c0:c1], kk[c0:c1] * n + e[c0:c1]  # frame (k, e) of a (steps, n, .) buffer: row k n + e
        nxt = _rows(r.states, at + n)
        success_f[c0:c1] = task.goal_reached(task.achieved_goal(nxt), gv[ee])
        cols["next.observation.state"][c0:c1] = nxt
        cols["observation.state"][c0:c1] = _rows(r.states, at)
        cols["action"][c0:c1] = _rows(r.actions, at)
        if expert is not None:
            assert r.expert_actions is not None
            expert[c0:c1] = _rows(r.expert_actions, at)
        if dist is not None:
            assert r.disturbance is not None
            dist[c0:c1] = _rows(r.disturbance, at)
    final = r.states[length, np.arange(n)]  # the state after each episode's last action
    del r
    last = np.zeros(F, bool)
    last[ends - 1] = True
    cols.update({"next.reward": success_f.astype(np.float32), "next.done": last, "next.success": success_f})
    if expert is not None:
        cols["action.expert"] = expert
    if dist is not None:
        cols["observation.disturbance"] = dist
    hit = np.flatnonzero(success_f)
    eps, at = np.unique(e[hit], return_index=True)  # frames ascend: the first hit of each episode
    first = np.full(n, -1, np.int64)
    first[eps] = hit[at] - starts[eps]
    success = np.zeros(n, bool)
    success[eps] = True
    stats = {k: episode_stats(v, starts, length) for k, v in cols.items()}
    return {"columns": cols, "ep_stats": stats, "success": success, "first": first, "final": final, "length": length}


def block_bounds(n: int, block: int | None = None) -> np.ndarray:
    """ceil(n / ROLLOUT_BLOCK) blocks of equal size (+-1): no tiny remainder block (NumPy's
    kernels for a batch of 1 round differently in the last bits). The block is the unit of
    sharding: a block's bytes do not depend on the worker that flies it."""
    block = ROLLOUT_BLOCK if block is None else block
    return np.linspace(0, n, -(-n // block) + 1).round().astype(np.int64)


def fly_blocks(
    spec: DatasetSpec,
    goals: dict,
    T: np.ndarray,
    coeffs: np.ndarray,
    progress: bool,
    *,
    part: int,
    start_state: np.ndarray | None = None,
    rotor_speeds: np.ndarray | None = None,
    record_rotors: bool = False,
    runner: BlockRunner | None = None,
    perturb: dict | None = None,
    goal_vec: np.ndarray | None = None,
) -> Iterator[tuple[int, int, dict[str, Any]]]:
    """:func:`rollout_expert` over blocks of :data:`ROLLOUT_BLOCK` episodes: yields
    ``(lo, hi, frames)`` per block in block order, ``frames`` the recorded frames of
    episodes ``lo..hi-1`` (:func:`_fly_block`). ``part`` separates the noise streams of
    the goal episodes (0) and the continuations (1). ``runner`` (:class:`BlockRunner`)
    flies the blocks in worker processes or Ray tasks; they come back in block order, so
    the frames are byte-identical to flying them here. ``perturb``: each episode's
    perturbation values (domain randomisation, :func:`episode_perturbations`).
    ``goal_vec`` (N, 15): each block comes back ready to write instead
    (:func:`_fly_block_columns`: its LeRobot columns, per-episode statistics and results),
    so that work runs where the block was flown."""
    n = len(T)
    bounds = block_bounds(n)
    nb = len(bounds) - 1

    def args(b: int, prog: bool = False) -> tuple:
        sl = slice(int(bounds[b]), int(bounds[b + 1]))
        return (
            spec,
            {key: v[sl] for key, v in goals.items()},
            T[sl],
            coeffs[sl],
            None if start_state is None else start_state[sl],
            None if rotor_speeds is None else rotor_speeds[sl],
            record_rotors,
            part,
            b,
            prog,
            None if perturb is None else {k: v[sl] for k, v in perturb.items()},
            *(() if goal_vec is None else (goal_vec[sl],)),
        )

    fn = _fly_block if goal_vec is None else _fly_block_columns
    results: Iterator[dict]
    if runner is None or nb < 2:
        results = (fn(*args(b, progress)) for b in range(nb))
    else:
        results = runner.map(fn, (args(b) for b in range(nb)))
    for b, r in enumerate(
        tqdm(results, total=nb, desc="expert blocks", unit="block", disable=None if progress and nb >= 3 else True, leave=False)
    ):
        yield int(bounds[b]), int(bounds[b + 1]), r
        del r


def fly(
    spec: DatasetSpec,
    goals: dict,
    T: np.ndarray,
    coeffs: np.ndarray,
    progress: bool,
    *,
    part: int,
    start_state: np.ndarray | None = None,
    rotor_speeds: np.ndarray | None = None,
    record_rotors: bool = False,
    runner: BlockRunner | None = None,
    perturb: dict | None = None,
) -> _Frames:
    """All frames of :func:`fly_blocks` in arrays allocated once (their size is known from
    T): what :func:`generate` keeps in memory. ``datagen build`` streams the blocks to
    disk instead (:func:`stream_dataset`)."""
    n = len(T)
    length = np.ceil(T * spec.fps - 1e-9).astype(np.int64)
    F = int(length.sum())
    first = np.concatenate([[0], np.cumsum(length)[:-1]])
    ep = np.repeat(np.arange(n), length)
    k = np.arange(F) - np.repeat(first, length)
    fr = _Frames(
        ep,
        k,
        np.empty((F, task.STATE_DIM)),
        np.empty((F, task.ACTION_DIM)),
        np.empty((F, task.STATE_DIM)),
        np.empty((F, task.ACTION_DIM)) if spec.noisy else None,
        np.empty((F, 4)) if record_rotors else None,
        np.empty(F, bool),
        np.empty((F, 3)) if spec.disturbance_observer > 0 else None,
    )
    for lo, hi, r in fly_blocks(
        spec,
        goals,
        T,
        coeffs,
        progress,
        part=part,
        start_state=start_state,
        rotor_speeds=rotor_speeds,
        record_rotors=record_rotors,
        runner=runner,
        perturb=perturb,
    ):
        f0, f1 = first[lo], first[hi - 1] + length[hi - 1]
        fr.state[f0:f1] = r["state"]
        fr.action[f0:f1] = r["action"]
        fr.next_state[f0:f1] = r["next_state"]
        fr.success[f0:f1] = r["success"]
        if fr.expert_action is not None:
            fr.expert_action[f0:f1] = r["expert_action"]
        if fr.rotors is not None:
            fr.rotors[f0:f1] = r["rotors"]
        if fr.disturbance is not None:
            fr.disturbance[f0:f1] = r["disturbance"]
        del r
    return fr


class BlockRunner:
    """Flies blocks in ``workers`` local processes, or in Ray tasks on the cluster at
    ``ray_address``; :meth:`map` yields the results in submission order with at most
    ``workers + 1`` blocks in flight (memory: that many blocks' frames)."""

    def __init__(self, workers: int, ray_address: str | None = None):
        self.workers, self.ray_address = int(workers), ray_address
        self._pool: ProcessPoolExecutor | None = None
        self._ray_fn: dict | None = None  # ray remote functions, with ray_address
        if ray_address:
            from aerohrl.cluster import ray_connect

            ray = ray_connect(ray_address)
            self._ray = ray
            self._ray_fn = {}  # a remote function per function mapped
        else:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            # spawn: a clean interpreter per worker (no forked threads or locks)
            self._pool = ProcessPoolExecutor(self.workers, mp_context=mp.get_context("spawn"))

    def map(self, fn: Callable[..., Any], arg_iter: Iterable[tuple]) -> Iterator[Any]:
        """``fn(*args)`` for each ``args`` of ``arg_iter`` in the workers, at most ``workers`` in flight;
        the results in the order of ``arg_iter``."""
        from collections import deque

        window: deque = deque()
        if self._ray_fn is not None and fn not in self._ray_fn:
            self._ray_fn[fn] = self._ray.remote(num_cpus=1)(fn)
        # the pool exists whenever ray is not used (mypy does not carry the test into the lambda)
        submit = (
            (lambda a: self._ray_fn[fn].remote(*a))
            if self._ray_fn is not None
            else (lambda a: cast("ProcessPoolExecutor", self._pool).submit(fn, *a))
        )
        get = (lambda f: self._ray.get(f)) if self._ray_fn is not None else (lambda f: f.result())
        for a in arg_iter:
            window.append(submit(a))
            if len(window) > self.workers:
                yield get(window.popleft())
        while window:
            yield get(window.popleft())

    def close(self) -> None:
        """Stop the worker processes (pending blocks are cancelled)."""
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None


def plan_continuations(
    spec: DatasetSpec, rng: np.random.Generator, coeffs: np.ndarray, ep: np.ndarray, k: np.ndarray, state: np.ndarray
) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, int, np.ndarray | None]:
    """Starts and references of the continuation episodes (``spec.continuations``).

    A start is a recorded frame of a rest-start flight, drawn uniformly (``ep``, ``k``,
    ``state`` of all such frames): the vehicle's state there moved to the origin
    (translation invariance, docs/spec.md), and its new reference begins where that flight's
    reference stood at that time (position relative to the vehicle, velocity,
    acceleration), so the expert's collective thrust continues smoothly (its jerk, and
    with it the feed-forward body rates, starts afresh: degree 5 has no condition left). The goal is a fresh
    rho_D sample, relative to the start as every goal is. Returns (goals, T, coeffs,
    resampled, frames): ``frames`` indexes the source frames.
    """

    def sample_starts(m):
        f = rng.integers(0, len(ep), size=m)
        t = k[f] * spec.dt
        x0 = np.stack([reference.evaluate(coeffs[ep[f]], t, order=o) for o in range(3)], axis=-1)  # (m, axis, (p, v, a))
        x0[:, :, 0] -= state[f, task.POS]
        return x0, f

    return plan_references(spec, rng, spec.continuations, sample_starts)


def episode_starts(
    spec: DatasetSpec, goals: dict, T: np.ndarray, coeffs: np.ndarray
) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """The goal episodes of the recipe: each goal flown ``rollouts_per_goal`` times
    (goal-major), from rest or from perturbed starts. Returns (goals, T, coeffs,
    start_state or None, goal_index). A perturbed start whose reference to its goal is
    infeasible within ``t_max`` is redrawn (the goal stays: every recipe of one seed flies
    the same goals)."""
    reps = spec.rollouts_per_goal
    goal_index = np.repeat(np.arange(len(T)), reps)
    if reps > 1:
        goals = {key: v[goal_index] for key, v in goals.items()}
        T, coeffs = T[goal_index], coeffs[goal_index]
    if spec.start_states == "rest":
        return goals, T, coeffs, None, goal_index
    rng = np.random.default_rng([spec.seed, START_STREAM])
    xf = np.stack([goals["pos"], goals["vel"], goals["acc"]], axis=-1)
    m = len(T)
    start, x0 = recipes.sample_start_states(rng, m, spec.start_vel, spec.start_tilt, spec.start_rate)
    todo = np.arange(m)
    T, coeffs = T.copy(), coeffs.copy()
    for _ in range(20):
        T2, c2, ok = reference.min_time(
            x0[todo],
            xf[todo],
            a_max=spec.a_max,
            t_lo=0.0,
            t_hi=spec.t_max,
            tol=spec.bisection_tol,
            solver=spec.solver,
            degree=spec.degree,
        )
        T[todo[ok]], coeffs[todo[ok]] = T2[ok], c2[ok]
        todo = todo[~ok]
        if todo.size == 0:
            return goals, T, coeffs, start, goal_index
        start[todo], x0[todo] = recipes.sample_start_states(rng, todo.size, spec.start_vel, spec.start_tilt, spec.start_rate)
    raise UserError(
        f"{todo.size} goals have no feasible reference from 20 perturbed starts within t_max={spec.t_max} s; "
        "lower --start-vel or raise --t-max"
    )


def generate(spec: DatasetSpec, progress: bool = True, runner: "BlockRunner | None" = None) -> ExpertData:
    """Goals, references and expert rollouts for a spec (nothing written); ``runner`` flies
    the blocks elsewhere (same bytes)."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(spec.seed)
    goals, T, coeffs, resampled, _ = plan_references(spec, rng)
    goals, T, coeffs, start, goal_index = episode_starts(spec, goals, T, coeffs)
    t1 = time.perf_counter()
    cont = spec.continuations > 0
    pert = episode_perturbations(spec, len(T))
    fr = fly(spec, goals, T, coeffs, progress, part=0, start_state=start, record_rotors=cont, runner=runner, perturb=pert)
    ep, k, state, action, next_state, expert_action = fr.ep, fr.k, fr.state, fr.action, fr.next_state, fr.expert_action
    success, disturbance = fr.success, fr.disturbance
    length = np.bincount(ep, minlength=len(T))
    source_episode = np.full(len(T), -1, np.int64)
    source_frame = np.full(len(T), -1, np.int64)
    if cont:
        # Their own stream: the rest-start episodes are the same with or without them.
        crng = np.random.default_rng([spec.seed, CONTINUATION_STREAM])
        g2, T2, c2, r2, f = plan_continuations(spec, crng, coeffs, ep, k, state)
        start2 = state[f].copy()
        start2[:, task.POS] = 0.0
        assert fr.rotors is not None  # recorded with continuations (record_rotors=cont)
        fr2 = fly(spec, g2, T2, c2, progress, part=1, start_state=start2, rotor_speeds=fr.rotors[f], runner=runner)
        n = len(T)
        goals = {key: np.concatenate([goals[key], g2[key]]) for key in goals}
        T, resampled = np.concatenate([T, T2]), resampled + r2
        length = np.concatenate([length, np.bincount(fr2.ep, minlength=len(T2))])
        source_episode = np.concatenate([source_episode, ep[f]])
        source_frame = np.concatenate([source_frame, k[f]])
        goal_index = np.concatenate([goal_index, np.full(len(T2), -1, np.int64)])
        ep, k = np.concatenate([ep, fr2.ep + n]), np.concatenate([k, fr2.k])
        state, action, next_state, success = (
            np.concatenate(x)
            for x in ((state, fr2.state), (action, fr2.action), (next_state, fr2.next_state), (success, fr2.success))
        )
        if expert_action is not None:
            expert_action = np.concatenate([expert_action, fr2.expert_action])
        if disturbance is not None:
            disturbance = np.concatenate([disturbance, fr2.disturbance])
    del fr
    t2 = time.perf_counter()

    rate = float(np.bincount(ep, weights=success, minlength=len(T)).astype(bool).mean())
    if rate < MIN_EXPERT_SUCCESS:
        raise UserError(
            f"the expert reaches only {100 * rate:.1f}% of its goals under this recipe (floor "
            f"{100 * MIN_EXPERT_SUCCESS:.0f}%): lower --action-noise, the --start-* ranges or the --randomize ranges"
        )
    goal_vec = goals_mod.goal_vectors(goals)
    data = ExpertData(
        goals=goals,
        goal_vec=goal_vec,
        T=T,
        length=length,
        episode_index=ep.astype(np.int64),
        frame_index=k.astype(np.int64),
        state=state,
        action=action,
        next_state=next_state,
        success=success,
        resampled=resampled,
        source_episode=source_episode,
        source_frame=source_frame,
        action_expert=expert_action,
        goal_index=goal_index if spec.rollouts_per_goal > 1 else None,
        perturbation=pert,
        disturbance=disturbance,
    )
    data.timings = {"references_s": t1 - t0, "rollout_s": t2 - t1, "frames_s": time.perf_counter() - t2}
    return data


def stream_dataset(spec: DatasetSpec, root: Path, progress: bool = True, runner: "BlockRunner | None" = None) -> EpisodeSummary:
    """Fly ``spec`` and write its LeRobot files into ``root`` block by block (the same
    bytes as :func:`generate` + :func:`write_dataset`): each block of
    :data:`ROLLOUT_BLOCK` flights is appended to the data files as it lands
    (:class:`DatasetWriter`), and only per-episode results stay in memory, so the peak
    is a few blocks' frames whatever the number of goals. With continuations the
    rest-start flights are kept whole (their starts are drawn from those frames)."""
    if spec.reach:
        task_text = TASK
    elif spec.family == "explore":
        task_text = WALK_TASK if spec.explore_pilot == "walk" else EXPLORE_TASK
    else:
        task_text = MAZE_TASK
    writer = DatasetWriter(
        root, fps=spec.fps, task=task_text, robot_type=f"quadrotor-{spec.vehicle}", names=FEATURE_NAMES, stats=spec.stats_mode
    )
    try:
        if not spec.reach:  # the maze families and exploration (datagen/maze_build.py)
            from aerohrl.datagen import maze_build

            summary = maze_build.stream(spec, writer, progress)
        elif spec.continuations:
            data = generate(spec, progress=progress, runner=runner)
            writer.append(frame_columns(data), data.length)
            summary = summarize(data)
            del data
        else:
            summary = _stream_flights(spec, writer, progress, runner)
        writer.close()
    except BaseException:
        writer.abort()
        raise
    summary.checksums = writer.checksums()
    return summary


def _stream_flights(spec: DatasetSpec, writer: DatasetWriter, progress: bool, runner) -> EpisodeSummary:
    rng = np.random.default_rng(spec.seed)
    goals, T, coeffs, resampled, _ = plan_references(spec, rng)
    goals, T, coeffs, start, goal_index = episode_starts(spec, goals, T, coeffs)
    goal_vec = goals_mod.goal_vectors(goals)
    n = len(T)
    length = np.ceil(T * spec.fps - 1e-9).astype(np.int64)
    success = np.zeros(n, bool)
    first = np.full(n, -1, np.int64)
    final = np.empty((n, task.STATE_DIM))
    pert = episode_perturbations(spec, n)
    blocks = fly_blocks(
        spec, goals, T, coeffs, progress, part=0, start_state=start, runner=runner, perturb=pert, goal_vec=goal_vec
    )
    for lo, hi, r in blocks:
        first[lo:hi], success[lo:hi], final[lo:hi] = r["first"], r["success"], r["final"]
        writer.append(r.pop("columns"), length[lo:hi], ep_stats=r.pop("ep_stats") if writer.episode_stats else None)
        del r
    rate = float(success.mean())
    if rate < MIN_EXPERT_SUCCESS:
        raise UserError(
            f"the expert reaches only {100 * rate:.1f}% of its goals under this recipe (floor "
            f"{100 * MIN_EXPERT_SUCCESS:.0f}%): lower --action-noise, the --start-* ranges or the --randomize ranges"
        )
    return EpisodeSummary(
        goals,
        goal_vec,
        T,
        length,
        success,
        first,
        final,
        resampled,
        np.full(n, -1, np.int64),
        np.full(n, -1, np.int64),
        goal_index if spec.rollouts_per_goal > 1 else None,
        perturbation=pert,
    )


def frame_columns(data: ExpertData) -> dict[str, np.ndarray]:
    """The LeRobot per-frame features (float32 / bool), docs/spec.md "Expert data"."""
    last = np.r_[data.episode_index[1:] != data.episode_index[:-1], True]
    return _columns(
        data.state,
        data.action,
        data.goal_vec[data.episode_index],
        data.next_state,
        data.success,
        last,
        data.action_expert,
        data.disturbance,
    )


def _pop_columns(r: dict, goal_rows: np.ndarray, last: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`_columns` of one block's frames (a maze block, :mod:`aerohrl.datagen.maze_build`),
    each float64 array dropped from ``r`` as soon as its float32 copy exists (the block's peak memory)."""
    out = {
        "observation.state": r.pop("state").astype(np.float32),
        "action": r.pop("action").astype(np.float32),
        "observation.desired_goal": goal_rows,
        "next.observation.state": r.pop("next_state").astype(np.float32),
    }
    success = r.pop("success")
    out.update({"next.reward": success.astype(np.float32), "next.done": last, "next.success": success})
    if "expert_action" in r:
        out["action.expert"] = r.pop("expert_action").astype(np.float32)
    return out


def _columns(state, action, goal_rows, next_state, success, last, action_expert, disturbance=None) -> dict[str, np.ndarray]:
    return {
        "observation.state": state.astype(np.float32),
        "action": action.astype(np.float32),
        "observation.desired_goal": goal_rows.astype(np.float32),
        "next.observation.state": next_state.astype(np.float32),
        "next.reward": success.astype(np.float32),
        "next.done": last,
        "next.success": success.copy(),
        # action noise only: ``action`` is what was flown, this the clean expert command
        **({"action.expert": action_expert.astype(np.float32)} if action_expert is not None else {}),
        # the disturbance observer's estimate d_hat that the command at this state used
        **({"observation.disturbance": disturbance.astype(np.float32)} if disturbance is not None else {}),
    }


FEATURE_NAMES = {
    "observation.state": task.STATE_NAMES,
    "action": task.ACTION_NAMES,
    "action.expert": task.ACTION_NAMES,
    "observation.desired_goal": task.GOAL_NAMES,
    "next.observation.state": task.STATE_NAMES,
    "observation.disturbance": ["d_x", "d_y", "d_z"],
}


@dataclass
class EpisodeSummary:
    """What the metadata need of a build once its frames are written: per episode the
    goal, reference duration, length, outcome and final state (no frames)."""

    goals: dict
    goal_vec: np.ndarray
    T: np.ndarray
    length: np.ndarray
    episode_success: np.ndarray  # (N,) bool
    first_success: np.ndarray  # (N,) first frame whose next state meets the goal test (-1: never)
    final_next_state: np.ndarray  # (N, 18) the state after each episode's last action
    resampled: int = 0
    source_episode: np.ndarray | None = None
    source_frame: np.ndarray | None = None
    goal_index: np.ndarray | None = None
    extra: dict | None = None  # maze and explore families: world, family and their measurements (metadata)
    collided: np.ndarray | None = None  # (N,) bool, maze worlds: the episode touched a wall, floor or ceiling
    start_cell: np.ndarray | None = None  # (N, 2) maze expert families: start and goal cells (row, col)
    goal_cell: np.ndarray | None = None
    perturbation: dict | None = None  # {axis: (N,)} each episode's vehicle under domain randomisation
    checksums: dict | None = None  # SHA-256 of the data files, taken by the writer as it closed them

    @property
    def frames(self) -> int:
        """The number of recorded frames (sum of the episode lengths)."""
        return int(self.length.sum())


def summarize(data: ExpertData) -> EpisodeSummary:
    """The :class:`EpisodeSummary` of frames held in memory."""
    n = len(data.T)
    succ = data.success
    first = np.full(n, np.iinfo(np.int64).max, dtype=np.int64)
    np.minimum.at(first, data.episode_index[succ], data.frame_index[succ])
    first[first == np.iinfo(np.int64).max] = -1  # never reached
    return EpisodeSummary(
        data.goals,
        data.goal_vec,
        data.T,
        data.length,
        data.episode_success,
        first,
        data.next_state[np.cumsum(data.length) - 1],
        data.resampled,
        data.source_episode,
        data.source_frame,
        data.goal_index,
        perturbation=data.perturbation,
    )


def episode_table(data: "EpisodeSummary | ExpertData") -> pa.Table:
    """Per-episode summary: goal, reference duration, expert outcome and final errors."""
    if isinstance(data, ExpertData):
        data = summarize(data)
    n = len(data.T)
    dp, dv, dr = task.goal_errors(task.achieved_goal(data.final_next_state), data.goal_vec)
    first = data.first_success

    def fsl(a):
        a = np.ascontiguousarray(a, dtype=np.float64)
        return pa.FixedSizeListArray.from_arrays(pa.array(a.reshape(-1)), a.shape[1])

    cols = {
        "episode_index": pa.array(np.arange(n, dtype=np.int64)),
        "goal_pos": fsl(data.goals["pos"]),
        "goal_vel": fsl(data.goals["vel"]),
        "goal_acc": fsl(data.goals["acc"]),
        "reference_duration_s": pa.array(data.T.astype(np.float64)),
        "length": pa.array(data.length),
        "expert_success": pa.array(data.episode_success),
        "first_success_step": pa.array(first),
        "final_pos_error_m": pa.array(dp),
        "final_vel_error_mps": pa.array(dv),
        "final_rot_error_rad": pa.array(dr),
    }
    if (
        data.source_episode is not None and (data.source_episode >= 0).any()
    ):  # continuation episodes only (default datasets keep their bytes)
        cols["start_source_episode"] = pa.array(data.source_episode)
        cols["start_source_frame"] = pa.array(data.source_frame)
    if data.goal_index is not None:  # rollouts_per_goal > 1: several flights of one goal
        cols["goal_index"] = pa.array(data.goal_index)
    if data.start_cell is not None and data.goal_cell is not None:  # maze expert families: (row, col)
        for key, rc in (("start_cell", data.start_cell), ("goal_cell", data.goal_cell)):
            cols[key] = pa.FixedSizeListArray.from_arrays(pa.array(np.asarray(rc, np.int64).reshape(-1)), 2)
    if data.collided is not None:  # maze worlds
        cols["collided"] = pa.array(data.collided)
    for axis, v in (data.perturbation or {}).items():  # domain randomisation: each episode's vehicle
        cols[f"perturb_{axis}"] = pa.array(np.asarray(v, np.float64))
    return pa.table(cols)


def metadata(spec: DatasetSpec, data: "EpisodeSummary | ExpertData", version: str) -> dict:
    """The dataset's ``aerohrl`` metadata: spec, hash, versions, vehicle and controller
    parameters, task layout and the episode statistics of ``data``."""
    if isinstance(data, ExpertData):
        data = summarize(data)
    params = get_preset(spec.vehicle)
    ctrl = GeometricController(params)
    succ = data.episode_success
    return {
        "format": FORMAT,
        "repo_id": REPO_ID if spec.reach else f"aerohrl/{spec.name}",  # the reach datasets keep their bytes
        "name": spec.name,
        "version": version,
        "generator": {"name": "aerohrl.datagen", "generator_version": GENERATOR_VERSION, "aerohrl_version": AEROHRL_VERSION},
        "spec": spec.to_dict(),
        "spec_sha256": spec_hash(spec),
        "seed": spec.seed,
        **(
            {
                "goal_ranges": {
                    "pos_abs": list(spec.pos_range),
                    "vel": list(spec.vel_range),
                    "acc": list(spec.acc_range),
                    "yaw": 0.0,
                }
            }
            if spec.reach
            else {}
        ),
        "start_state": (
            "origin, zero velocity, hover attitude (R = I), zero body rates"
            if spec.start_states == "rest" and (spec.reach or not spec.maze)
            else "hover (zero velocity, R = I, zero body rates) at a free cell's centre at flight altitude"
            if spec.maze
            else "perturbed at the origin (recipe.start_states)"
        ),
        **(data.extra or {}),
        **(
            {
                "continuations": {
                    "episodes": int(spec.continuations),
                    "first_episode": int(spec.goals),
                    "start_state": "a recorded state of a rest-start episode (uniform over their frames), moved to the origin; "
                    "the reference continues that episode's reference from there; goal from rho_D "
                    "(start_source_episode / start_source_frame in meta/aerohrl_episodes.parquet)",
                }
            }
            if spec.continuations
            else {}
        ),
        **({"recipe": recipe_summary(spec)} if recipe_summary(spec) else {}),
        "vehicle": params.to_dict(),
        "controller": {"name": "Lee/Mellinger geometric controller, CTBR output", "gains": ctrl.gains.to_dict()},
        "goal_tolerance": {"pos_m": task.TOLERANCE.pos, "vel_mps": task.TOLERANCE.vel, "rot_rad": task.TOLERANCE.rot},
        "resampled_goals": int(data.resampled),
        "episodes": int(len(data.T)),
        "frames": data.frames,
        "expert_success_rate": float(succ.mean()),
        "reference_duration_s": {"min": float(data.T.min()), "mean": float(data.T.mean()), "max": float(data.T.max())},
        "layouts": {
            "observation.state": "[p(3), v(3), R(9, row-major), w(3, body)] absolute, SI",
            "action": "CTBR [c (m/s^2, mass-normalised collective thrust), wx, wy, wz (rad/s, body)]",
            "observation.desired_goal": "[p(3), v(3), R(9)] of the episode's desired goal, absolute",
            "next.observation.state": "the state after the action; its first 15 entries are the achieved goal",
            "next.reward": "1.0 when the next state meets the goal-reached test for the desired goal, else 0.0",
            "next.success": "the goal-reached test at the next state (bool)",
            "next.done": "last recorded step of the episode (reference end T)",
            **(
                {
                    "action": "CTBR as flown: the expert's command plus the action noise, clipped to the expert's action box",
                    "action.expert": "the clean expert CTBR command at the flown state (what to imitate; DART)",
                }
                if spec.noisy
                else {}
            ),
            **(
                {
                    "observation.disturbance": "d_hat (m/s^2, world frame): the expert's disturbance observer's estimate "
                    "of the unmodelled acceleration, which the command at this state compensated"
                }
                if spec.disturbance_observer > 0
                else {}
            ),
            **(_family_layouts(spec) if not spec.reach else {}),
        },
        "environment": {"python": platform.python_version(), "numpy": np.__version__, "pyarrow": pa.__version__},
    }


def _family_layouts(spec: DatasetSpec) -> dict:
    """The layout notes that change with a maze or explore family."""
    if spec.family == "explore":
        return {
            "action": "CTBR as flown by the velocity controller following random velocity commands (no expert)",
            "observation.desired_goal": "[p(3), v(3), R(9)] of the episode's last achieved goal, absolute",
            "next.done": "last recorded step of the episode (its length, or its first colliding step in a maze)",
        }
    return {
        "observation.desired_goal": "[p(3), 0, 0, 0, I(9)]: hover at the centre of the episode's goal cell, absolute",
        "next.done": "last recorded step of the episode (the reference's end plus the settle time)",
    }


def recipe_summary(spec: DatasetSpec) -> dict:
    """The non-default expert-data recipe of a spec, in words and numbers ({} = the thesis's)."""
    r: dict[str, Any] = {}
    if spec.expert == "replan":
        r["expert"] = (
            f"replan: shrinking-horizon minimum-jerk re-plan from the flown state every {spec.replan_every} steps, "
            f"none in the last {spec.replan_endgame} s"
            + (
                "; each re-plan ends at the goal's acceleration plus the observer's horizontal disturbance estimate "
                "(terminal_disturbance: arriving at the goal's attitude, carried by the disturbance)"
                if spec.terminal_disturbance
                else ""
            )
            + (
                "; through the endgame each re-plan starts from the reference itself, only its end following "
                "the estimate (endgame_retarget)"
                if spec.endgame_retarget
                else ""
            )
            + (
                "; the expert controls with a thrust gain and a horizontal acceleration estimated apart "
                "(observer_model gain), the recorded estimate staying the additive one"
                if spec.observer_model == "gain"
                else ""
            )
        )
    if spec.noisy:
        r["action_noise"] = {
            "sigma": list(spec.action_noise),
            "tau_s": spec.noise_tau,
            "kind": "Ornstein-Uhlenbeck added to the flown command (DART); action = flown, action.expert = clean",
        }
    if spec.start_states == "perturbed":
        r["start_states"] = {
            "vel_mps": spec.start_vel,
            "tilt_rad": spec.start_tilt,
            "rate_radps": spec.start_rate,
            "kind": "origin; v_i, rotation-vector r_i and w_i uniform in +-these bounds",
        }
    if spec.rollouts_per_goal > 1:
        r["rollouts_per_goal"] = spec.rollouts_per_goal
    if spec.randomize:
        from aerohrl.sim.perturb import parse_ranges

        r["randomize"] = {
            "ranges": {k: list(v) for k, v in parse_ranges(spec.randomize).items()},
            "kind": "each episode's expert flies its own perturbed vehicle (docs/spec.md Perturbations), values uniform "
            "per episode; perturb_<axis> in meta/aerohrl_episodes.parquet, not in the frames",
        }
    return r


def _recipe_note(meta: dict) -> str:
    r = meta.get("recipe")
    if not r:
        return ""
    lines = ["\n## Recipe (beyond the thesis)\n"]
    if "expert" in r:
        lines.append(f"- expert: {r['expert']}")
    if "action_noise" in r:
        n = r["action_noise"]
        lines.append(f"- action noise: {n['kind']}; sigma (c, wx, wy, wz) = {n['sigma']}, correlation time {n['tau_s']} s")
    if "start_states" in r:
        s = r["start_states"]
        lines.append(
            f"- start states: {s['kind']}: |v_i| <= {s['vel_mps']} m/s, |r_i| <= {s['tilt_rad']} rad, "
            f"|w_i| <= {s['rate_radps']} rad/s"
        )
    if "rollouts_per_goal" in r:
        lines.append(f"- {r['rollouts_per_goal']} flights per goal (goal-major; `goal_index` in meta/aerohrl_episodes.parquet)")
    if "randomize" in r:
        d = r["randomize"]
        ranges = ", ".join(f"{k} {lo:g}..{hi:g}" for k, (lo, hi) in d["ranges"].items())
        lines.append(f"- domain randomisation: {d['kind']}; ranges {ranges}")
    return "\n".join(lines) + "\n"


def _feature_rows(meta: dict, features: dict | None) -> str:
    """The card's feature table: dtype and shape from ``meta/info.json``'s features."""
    features = features or {}
    rows = []
    for k, v in meta["layouts"].items():
        ft = features.get(k) or {}
        shape = "(" + ", ".join(str(int(n)) for n in ft["shape"]) + ",)" if ft.get("shape") else ""
        rows.append(f"| `{k}` | {ft.get('dtype', '')} | {shape} | {v} |\n")
    return "".join(rows)


def dataset_card(meta: dict, features: dict | None = None) -> str:
    """The dataset's README.md (a Hugging Face dataset card); ``features`` (info.json's)
    fill the dtype and shape columns of the feature table."""
    # The card is one of the dataset's files, so its text is part of the version's bytes:
    # it changes only with GENERATOR_VERSION (its module path for read_columns included).
    intro = _family_intro(meta) if "family" in meta else _reach_intro(meta)
    return (
        f"""---
license: mit
task_categories: [robotics]
tags: [LeRobot, quadrotor, goal-conditioned, offline-rl, aerohrl]
---
# {meta["name"]} — {meta["version"]}

{intro}{_recipe_note(meta)}
## Load
```python
from lerobot.datasets.lerobot_dataset import LeRobotDataset
ds = LeRobotDataset("{meta["repo_id"]}", root="<this folder>", video_backend="pyav")
```
(`video_backend="pyav"`: the data hold no video, and naming a backend keeps lerobot from
probing torchcodec, which logs a long traceback on machines without FFmpeg.) Or
`aerohrl.load_dataset("<this folder>", as_="numpy" | "torch" | "lerobot")`; without torch:
`aerohrl.datagen.lerobot_format.read_columns("<this folder>")`.

## Features
| key | dtype | shape | meaning |
|---|---|---|---|
"""
        + _feature_rows(meta, features)
        + """
`meta/aerohrl.json` holds the full spec, vehicle and controller parameters and the
SHA-256 of every file; `meta/aerohrl_episodes.parquet` holds per-episode goals,
durations and expert outcomes. `datagen validate <this folder>` checks integrity.
"""
    )


def _reach_intro(meta: dict) -> str:
    s = meta["spec"]
    return f"""Expert quadrotor trajectories for offline goal-conditioned RL (thesis §3.4.1), generated
by `aerohrl.datagen` (generator version {meta["generator"]["generator_version"]}). A
{meta["vehicle"]["name"]} vehicle starts at rest in hover at the origin and flies to each of
{meta["episodes"]} desired goals (position, velocity, attitude){_continuation_note(meta)} under a minimum-time,
minimum-jerk reference (|a_i| <= {s["a_max"]} m/s^2, {s["solver"]} solver, degree {s["degree"]})
tracked by a Lee/Mellinger geometric controller that outputs CTBR actions, recorded at
{s["fps"]} Hz.

- episodes: {meta["episodes"]}, frames: {meta["frames"]}
- expert success rate (goal-reached test: 0.15 m, 0.35 m/s, 0.15 rad): {100 * meta["expert_success_rate"]:.1f}%
- goals resampled for infeasibility: {meta["resampled_goals"]}
- seed: {meta["seed"]}; goal ranges: |p_i| in {s["pos_range"]} m (random sign), v_i in {s["vel_range"]} m/s, a_i in {s["acc_range"]} m/s^2
"""


def _family_intro(meta: dict) -> str:
    """The card's opening for the maze families and exploration (datagen/README.md "Maze families")."""
    from aerohrl.datagen.spec import RECIPE_DEFAULTS

    s = {**RECIPE_DEFAULTS, **meta["spec"]}  # the spec's dict leaves out settings at their defaults
    maze = meta.get("maze")
    where = (
        f"the {maze['name']} maze ({len(maze['layout'])} x {len(maze['layout'][0])} cells of {maze['cell']} m, "
        f"ceiling {maze['ceiling']} m, flight altitude {maze['altitude']} m; layout and frozen tasks in `meta/aerohrl.json` "
        "under `maze`)"
        if maze
        else "free space"
    )
    head = (
        f"Quadrotor flights in {where} for offline goal-conditioned RL, generated by `aerohrl.datagen` "
        f"(generator version {meta['generator']['generator_version']}), family **{meta['family']}**, "
        f"{meta['vehicle']['name']} vehicle, CTBR actions recorded at {s['fps']} Hz.\n\n"
    )
    expert = (
        "The expert flies the shortest path on the maze's cell graph as rest-to-rest minimum-time minimum-jerk legs "
        f"between its corners along the corridor centre lines (|a_i| <= {s['a_max']} m/s^2, {s['solver']} solver), "
        f"chained in time, then hovers {s['settle']} s at the goal; a Lee/Mellinger geometric controller tracks it. "
        "Each episode starts in hover at its start cell's centre; its desired goal is hover at its goal cell's centre.\n\n"
    )
    if meta["family"] == "navigate":
        body = expert + (
            f"navigate: long flights between random free cells (path at least {s['min_path']} of the maze's diameter).\n"
        )
    elif meta["family"] == "stitch":
        c = meta["task_coverage"]
        body = expert + (
            f"stitch: short hops of {s['hop_cells'][0]}-{s['hop_cells'][1]} cells from random free cells, so that no "
            "single episode joins a frozen task's start to its goal (a policy must stitch them); fraction of the frozen "
            f"tasks whose start and then goal one episode passes within {c['tolerance_m']} m of: {c['fraction']}.\n"
        )
    elif s.get("explore_pilot") == "walk":
        e = meta["explore"]
        noise = s["action_noise"]
        body = (
            "explore (pilot walk): not goal-directed. Each flight is a random walk over the maze's cells from a random "
            "free cell (at each cell a free neighbour drawn uniformly, turning back only at a dead end), flown on the "
            "maze expert's rest-to-rest legs between the walk's corners with correlated action noise "
            f"(sigma c {noise[0]} m/s^2, body rates {noise[1]}/{noise[2]}/{noise[3]} rad/s, tau {s['noise_tau']} s) for "
            f"up to {s['explore_duration']} s; an episode ends at its first colliding step (kept as its last frame). "
            "`action` is what was flown (there is no `action.expert`); the desired goal is the episode's last achieved "
            f"goal (relabel for other goals). Episodes ended by a collision: {e['episodes_ended_by_collision']}.\n"
        )
        if "task_coverage" in meta:
            c = meta["task_coverage"]
            body += (
                f"- frozen-task coverage: the fraction of the maze's {len(c['per_task'])} evaluation "
                f"tasks whose start and then goal one episode passes within {c['tolerance_m']} m of: {c['fraction']}.\n"
            )
    else:
        e = meta["explore"]
        body = (
            "explore: not goal-directed. A stabilising velocity controller (the geometric controller with no position "
            f"term{' but the altitude' if maze else ''}) follows random piecewise-constant velocity commands (speed up to {s['explore_speed']} m/s, "
            f"each held {s['explore_hold'][0]}-{s['explore_hold'][1]} s"
            + (f", a hover with probability {s['explore_stop']}" if s.get("explore_stop") else "")
            + (
                f", each axis of a command reversed when it would bring the vehicle within its stopping distance "
                f"+ {s['explore_wall_margin']} m of a wall"
                if s.get("explore_wall_margin")
                else ""
            )
            + f") for up to {s['explore_duration']} s"
            + (
                ", at the maze's flight altitude; an episode ends at its first colliding step (kept as its last frame)"
                if maze
                else ""
            )
            + ("" if maze else f" (vertical commands up to {s['explore_climb']} m/s)")
            + ". `action` is what was flown (there is no `action.expert`); the desired goal is the episode's last "
            "achieved goal (relabel for other goals)."
            + (f" Episodes ended by a collision: {e['episodes_ended_by_collision']}." if maze else "")
            + "\n"
        )
    stats = f"\n- episodes: {meta['episodes']}, frames: {meta['frames']}\n"
    if "expert" in meta:
        stats += (
            f"- expert success rate (goal-reached test: 0.15 m, 0.35 m/s, 0.15 rad): {100 * meta['expert_success_rate']:.1f}%; "
            f"expert collisions: {meta['collisions']}\n"
        )
    return head + body + stats + f"- seed: {meta['seed']}\n"


def _continuation_note(meta: dict) -> str:
    c = meta.get("continuations")
    if not c:
        return ""
    return (
        f" (the last {c['episodes']} episodes, from {c['first_episode']} on, are continuations: they start from a "
        "state one of the rest-start flights passes through, moved to the origin)"
    )


def build(
    spec: DatasetSpec,
    out: str | Path = "datasets",
    progress: bool = True,
    log: Callable[[str], Any] = print,
    force: bool = False,
    workers: int = 1,
    ray_address: str | None = None,
) -> BuildResult:
    """Build ``<out>/<name>/<version>/`` for ``spec``; verify instead if it exists.

    ``workers`` > 1 flies the blocks of :data:`ROLLOUT_BLOCK` episodes in that many local
    processes (or Ray tasks on the cluster at ``ray_address``); the dataset is
    byte-identical to the single-process build (a spec of fewer goals than two blocks
    has nothing to share out).

    Before generating, the expected frames, disk and memory are logged; a build that
    would not fit in the free memory or disk is refused unless ``force``. Two builds of
    one version at once: the one that finishes second finds the first's result in
    place, verifies it and keeps it (``created`` False)."""
    import errno

    from aerohrl import atomic
    from aerohrl.datagen.estimate import available_disk, available_memory, estimate, human, shortfall

    t0 = time.perf_counter()
    version = version_name(spec)
    parent = Path(out) / spec.name
    final = parent / version
    if final.exists():
        return _verified_existing(spec, final, t0, log)
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"cannot create output directory {parent}: {e.strerror}") from None
    if not os.access(parent, os.W_OK):
        raise UserError(f"output directory {parent} is not writable")
    _remove_stale_temporaries(parent)

    est = estimate(spec, workers=workers)
    mem, disk = available_memory(), available_disk(parent)
    log(
        f"estimate: {est.episodes:,} episodes, {est.frames:,} frames, {human(est.disk)} on disk "
        f"(+{human(est.scratch)} scratch while building), "
        f"{human(est.memory)} of memory at peak ({human(disk)} disk free, {human(mem)} memory available)"
    )
    short = shortfall(est, mem, disk)
    if short and not force:
        raise UserError(f"this build needs about {short}; build fewer goals, or pass --force to try anyway")

    runner = BlockRunner(workers, ray_address) if workers > 1 or ray_address else None
    tmp = atomic.temp_path(final)
    try:
        # the frames stream into the temporary as they are flown; another build of this
        # version in this process (a thread, a test) takes the next free name
        for i in range(1, 100):
            try:
                tmp.mkdir()
                break
            except FileExistsError:
                tmp = atomic.temp_path(final).with_name(f"{atomic.temp_path(final).name}.{i}")
        try:
            summary = stream_dataset(spec, tmp, progress=progress, runner=runner)
        finally:
            if runner is not None:
                runner.close()
        pq.write_table(episode_table(summary), tmp / EPISODES_FILE)
        meta = metadata(spec, summary, version)
        (tmp / "README.md").write_text(dataset_card(meta, read_info(tmp)["features"]))
        write_manifest(tmp, meta, known=summary.checksums)
        os.rename(tmp, final)
    except OSError as e:
        if e.errno in (errno.EEXIST, errno.ENOTEMPTY) and final.is_dir():
            log(f"another build of {version} finished first")  # the same spec gives the same bytes: keep it
            return _verified_existing(spec, final, t0, log)
        raise UserError(f"writing the dataset failed: {e}") from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return BuildResult(
        final,
        True,
        len(summary.T),
        summary.frames,
        float(summary.episode_success.mean()),
        summary.resampled,
        time.perf_counter() - t0,
    )


def _verified_existing(spec: DatasetSpec, final: Path, t0: float, log) -> BuildResult:
    """The existing version at ``final``, verified (checksums, spec) instead of rebuilt."""
    problems = validate(final)
    if problems:
        more = f" (+{len(problems) - 1} more)" if len(problems) > 1 else ""
        raise UserError(f"{final} exists but is damaged: {problems[0]}{more}; delete it to rebuild")
    stored = read_manifest(final).get("spec_sha256")
    if stored != spec_hash(spec):
        raise UserError(f"{final} exists but holds another spec (spec_sha256 {stored}); delete it to rebuild")
    meta = read_manifest(final)
    log(f"{final} exists: verified {len(meta.get('checksums', {}))} files against their checksums; nothing rebuilt")
    return BuildResult(
        final,
        False,
        meta["episodes"],
        meta["frames"],
        meta["expert_success_rate"],
        meta["resampled_goals"],
        time.perf_counter() - t0,
    )


def _remove_stale_temporaries(parent: Path) -> None:
    """Delete temporaries left by builds that were killed (their process is gone): the
    current ``.VERSION.tmp-PID`` and the ``.tmp-VERSION-PID`` of earlier releases."""
    from aerohrl import atomic

    atomic.remove_stale_temporaries(parent)
    for p in parent.glob(".tmp-*"):
        try:
            pid = int(p.name.rsplit("-", 1)[1])
            os.kill(pid, 0)
        except (ValueError, IndexError, ProcessLookupError):
            shutil.rmtree(p, ignore_errors=True)
        except PermissionError:
            pass
