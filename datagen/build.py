"""``datagen build``: goals -> minimum-time references -> expert rollouts -> dataset.

The pipeline of thesis §3.4.1 with the readings of SPEC.md "Expert data":

1. desired goals rho_D sampled from the spec's ranges (seeded); the goal attitude
   follows from flatness (:mod:`aerohrl.datagen.goals`);
2. per goal a minimum-time minimum-jerk polynomial reference per axis under the
   acceleration bound (thesis Alg. 1, :mod:`aerohrl.datagen.reference`); goals with no
   feasible reference within ``t_max`` are resampled and counted;
3. the geometric expert (:mod:`aerohrl.datagen.expert`) tracks every reference at once
   in the batched simulator (:mod:`aerohrl.sim`), recording each 100 Hz step until T;
4. the frames are written in bulk as a LeRobot v3.0 dataset
   (:mod:`aerohrl.datagen.lerobot_format`) with our own metadata and checksums
   (:mod:`aerohrl.datagen.manifest`) and a dataset card.

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

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from tqdm.auto import tqdm

from aerohrl import __version__ as AEROHRL_VERSION
from aerohrl import task
from aerohrl.errors import UserError
from aerohrl.datagen import goals as goals_mod
from aerohrl.datagen import reference
from aerohrl.datagen.expert import GeometricController
from aerohrl.datagen.lerobot_format import write_dataset
from aerohrl.datagen.manifest import read_manifest, validate, write_manifest
from aerohrl.datagen.spec import GENERATOR_VERSION, TASK, DatasetSpec, spec_hash, version_name
from aerohrl.sim import BatchedQuadrotor, get_preset

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
    timings: dict = field(default_factory=dict)

    @property
    def episode_success(self) -> np.ndarray:
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


def plan_references(spec: DatasetSpec, rng: np.random.Generator, n: int | None = None, sample_starts=None):
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


def rollout_expert(spec: DatasetSpec, goals: dict, T: np.ndarray, coeffs: np.ndarray, progress: bool = True,
                   start_state=None, rotor_speeds=None, record_rotors: bool = False):
    """Fly every reference at once with the geometric expert; record each step until T.

    Episode i records steps k = 0 .. ceil(T_i * fps) - 1: state s_k, action a_k and
    next state s_{k+1}. After its own end an episode keeps flying (it is simply not
    recorded) so the batch stays rectangular. ``start_state`` / ``rotor_speeds`` (N, 18) /
    (N, 4) replace hover at the origin; ``record_rotors`` also returns the rotor speeds
    at every step (kmax + 1, N, 4), else None.
    """
    params = get_preset(spec.vehicle)
    n = len(T)
    dt = spec.dt
    length = np.ceil(T * spec.fps - 1e-9).astype(np.int64)
    kmax = int(length.max())
    sim = BatchedQuadrotor(params, n, dt=dt, substeps=spec.substeps)
    ctrl = GeometricController(params)
    states = np.empty((kmax + 1, n, task.STATE_DIM))
    actions = np.empty((kmax, n, task.ACTION_DIM))
    rotors = np.empty((kmax + 1, n, 4)) if record_rotors else None
    states[0] = sim.reset(start_state, rotor_speeds)
    for k in tqdm(range(kmax), desc="expert rollouts", unit="step", disable=not progress, leave=False):
        if record_rotors:
            rotors[k] = sim.rotor_speeds
        t = np.minimum(k * dt, T)
        ref = [reference.evaluate(coeffs, t, order=o) for o in range(4)]
        actions[k] = ctrl(states[k], *ref, yaw=0.0)
        states[k + 1] = sim.step(actions[k])
    if record_rotors:
        rotors[kmax] = sim.rotor_speeds
    return states, actions, length, rotors


def _recorded(states: np.ndarray, actions: np.ndarray, length: np.ndarray):
    """(episode, step) of every recorded frame, episode-major, and its state, action, next state."""
    kmax = states.shape[0] - 1
    ep, k = np.nonzero(np.arange(kmax)[None, :] < length[:, None])
    return ep, k, states[k, ep], actions[k, ep], states[k + 1, ep]


def plan_continuations(spec: DatasetSpec, rng: np.random.Generator, coeffs: np.ndarray, ep: np.ndarray, k: np.ndarray,
                       state: np.ndarray):
    """Starts and references of the continuation episodes (``spec.continuations``).

    A start is a recorded frame of a rest-start flight, drawn uniformly (``ep``, ``k``,
    ``state`` of all such frames): the vehicle's state there moved to the origin
    (translation invariance, SPEC.md), and its new reference begins where that flight's
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


def generate(spec: DatasetSpec, progress: bool = True) -> ExpertData:
    """Goals, references and expert rollouts for a spec (nothing written)."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(spec.seed)
    goals, T, coeffs, resampled, _ = plan_references(spec, rng)
    t1 = time.perf_counter()
    cont = spec.continuations > 0
    states, actions, length, rotors = rollout_expert(spec, goals, T, coeffs, progress, record_rotors=cont)
    ep, k, state, action, next_state = _recorded(states, actions, length)
    source_episode = np.full(len(T), -1, np.int64)
    source_frame = np.full(len(T), -1, np.int64)
    if cont:
        # Their own stream: the rest-start episodes are the same with or without them.
        crng = np.random.default_rng([spec.seed, CONTINUATION_STREAM])
        g2, T2, c2, r2, f = plan_continuations(spec, crng, coeffs, ep, k, state)
        start = state[f].copy()
        start[:, task.POS] = 0.0
        s2, a2, l2, _ = rollout_expert(spec, g2, T2, c2, progress, start_state=start, rotor_speeds=rotors[k[f], ep[f]])
        ep2, k2, st2, ac2, ns2 = _recorded(s2, a2, l2)
        n = len(T)
        goals = {key: np.concatenate([goals[key], g2[key]]) for key in goals}
        T, length, resampled = np.concatenate([T, T2]), np.concatenate([length, l2]), resampled + r2
        source_episode = np.concatenate([source_episode, ep[f]])
        source_frame = np.concatenate([source_frame, k[f]])
        ep, k = np.concatenate([ep, ep2 + n]), np.concatenate([k, k2])
        state, action, next_state = (np.concatenate(x) for x in ((state, st2), (action, ac2), (next_state, ns2)))
    t2 = time.perf_counter()

    goal_vec = goals_mod.goal_vectors(goals)
    success = np.asarray(task.goal_reached(task.achieved_goal(next_state), goal_vec[ep]))
    data = ExpertData(
        goals=goals, goal_vec=goal_vec, T=T, length=length, episode_index=ep.astype(np.int64), frame_index=k.astype(np.int64),
        state=state, action=action, next_state=next_state, success=success, resampled=resampled,
        source_episode=source_episode, source_frame=source_frame,
    )
    data.timings = {"references_s": t1 - t0, "rollout_s": t2 - t1, "frames_s": time.perf_counter() - t2}
    return data


def frame_columns(data: ExpertData) -> dict[str, np.ndarray]:
    """The LeRobot per-frame features (float32 / bool), SPEC.md "Expert data"."""
    last = np.r_[data.episode_index[1:] != data.episode_index[:-1], True]
    return {
        "observation.state": data.state.astype(np.float32),
        "action": data.action.astype(np.float32),
        "observation.desired_goal": data.goal_vec[data.episode_index].astype(np.float32),
        "next.observation.state": data.next_state.astype(np.float32),
        "next.reward": data.success.astype(np.float32),
        "next.done": last,
        "next.success": data.success.copy(),
    }


FEATURE_NAMES = {
    "observation.state": task.STATE_NAMES,
    "action": task.ACTION_NAMES,
    "observation.desired_goal": task.GOAL_NAMES,
    "next.observation.state": task.STATE_NAMES,
}


def episode_table(data: ExpertData) -> pa.Table:
    """Per-episode summary: goal, reference duration, expert outcome and final errors."""
    n = len(data.T)
    last = np.cumsum(data.length) - 1
    dp, dv, dr = task.goal_errors(task.achieved_goal(data.next_state[last]), data.goal_vec)
    succ = data.success
    first = np.full(n, np.iinfo(np.int64).max, dtype=np.int64)
    np.minimum.at(first, data.episode_index[succ], data.frame_index[succ])
    first[first == np.iinfo(np.int64).max] = -1  # never reached

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
    if data.source_episode is not None and (data.source_episode >= 0).any():  # continuation episodes only (default datasets keep their bytes)
        cols["start_source_episode"] = pa.array(data.source_episode)
        cols["start_source_frame"] = pa.array(data.source_frame)
    return pa.table(cols)


def metadata(spec: DatasetSpec, data: ExpertData, version: str) -> dict:
    params = get_preset(spec.vehicle)
    ctrl = GeometricController(params)
    succ = data.episode_success
    return {
        "format": "aerohrl-dataset",
        "repo_id": REPO_ID,
        "name": spec.name,
        "version": version,
        "generator": {"name": "aerohrl.datagen", "generator_version": GENERATOR_VERSION, "aerohrl_version": AEROHRL_VERSION},
        "spec": spec.to_dict(),
        "spec_sha256": spec_hash(spec),
        "seed": spec.seed,
        "goal_ranges": {"pos_abs": list(spec.pos_range), "vel": list(spec.vel_range), "acc": list(spec.acc_range), "yaw": 0.0},
        "start_state": "origin, zero velocity, hover attitude (R = I), zero body rates",
        **({"continuations": {
            "episodes": int(spec.continuations),
            "first_episode": int(spec.goals),
            "start_state": "a recorded state of a rest-start episode (uniform over their frames), moved to the origin; "
                           "the reference continues that episode's reference from there; goal from rho_D "
                           "(start_source_episode / start_source_frame in meta/aerohrl_episodes.parquet)",
        }} if spec.continuations else {}),
        "vehicle": params.to_dict(),
        "controller": {"name": "Lee/Mellinger geometric controller, CTBR output", "gains": ctrl.gains.to_dict()},
        "goal_tolerance": {"pos_m": task.TOLERANCE.pos, "vel_mps": task.TOLERANCE.vel, "rot_rad": task.TOLERANCE.rot},
        "resampled_goals": int(data.resampled),
        "episodes": int(len(data.T)),
        "frames": int(len(data.episode_index)),
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
        },
        "environment": {"python": platform.python_version(), "numpy": np.__version__, "pyarrow": pa.__version__},
    }


def dataset_card(meta: dict) -> str:
    s = meta["spec"]
    return f"""---
license: mit
task_categories: [robotics]
tags: [LeRobot, quadrotor, goal-conditioned, offline-rl, aerohrl]
---
# {meta['name']} — {meta['version']}

Expert quadrotor trajectories for offline goal-conditioned RL (thesis §3.4.1), generated
by `aerohrl.datagen` (generator version {meta['generator']['generator_version']}). A
{meta['vehicle']['name']} vehicle starts at rest in hover at the origin and flies to each of
{meta['episodes']} desired goals (position, velocity, attitude){_continuation_note(meta)} under a minimum-time,
minimum-jerk reference (|a_i| <= {s['a_max']} m/s^2, {s['solver']} solver, degree {s['degree']})
tracked by a Lee/Mellinger geometric controller that outputs CTBR actions, recorded at
{s['fps']} Hz.

- episodes: {meta['episodes']}, frames: {meta['frames']}
- expert success rate (goal-reached test: 0.15 m, 0.35 m/s, 0.15 rad): {100 * meta['expert_success_rate']:.1f}%
- goals resampled for infeasibility: {meta['resampled_goals']}
- seed: {meta['seed']}; goal ranges: |p_i| in {s['pos_range']} m (random sign), v_i in {s['vel_range']} m/s, a_i in {s['acc_range']} m/s^2

## Load
```python
from lerobot.datasets.lerobot_dataset import LeRobotDataset
ds = LeRobotDataset("{meta['repo_id']}", root="<this folder>")
```
or, without torch: `aerohrl.datagen.lerobot_format.read_columns("<this folder>")`.

## Features
| key | shape | meaning |
|---|---|---|
""" + "".join(f"| `{k}` | | {v} |\n" for k, v in meta["layouts"].items()) + f"""
`meta/aerohrl.json` holds the full spec, vehicle and controller parameters and the
SHA-256 of every file; `meta/aerohrl_episodes.parquet` holds per-episode goals,
durations and expert outcomes. `datagen validate <this folder>` checks integrity.
"""


def _continuation_note(meta: dict) -> str:
    c = meta.get("continuations")
    if not c:
        return ""
    return (f" (the last {c['episodes']} episodes, from {c['first_episode']} on, are continuations: they start from a "
            "state one of the rest-start flights passes through, moved to the origin)")


def build(spec: DatasetSpec, out: str | Path = "datasets", progress: bool = True, log=print, force: bool = False) -> BuildResult:
    """Build ``<out>/<name>/<version>/`` for ``spec``; verify instead if it exists.

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

    est = estimate(spec)
    mem, disk = available_memory(), available_disk(parent)
    log(f"estimate: {est.episodes:,} episodes, {est.frames:,} frames, {human(est.disk)} on disk, "
        f"{human(est.memory)} of memory at peak ({human(disk)} disk free, {human(mem)} memory available)")
    short = shortfall(est, mem, disk)
    if short and not force:
        raise UserError(f"this build needs about {short}; build fewer goals, or pass --force to try anyway")

    data = generate(spec, progress=progress)
    tmp = atomic.temp_path(final)
    try:
        tmp.mkdir()
        columns = frame_columns(data)
        write_dataset(tmp, columns, data.episode_index, fps=spec.fps, task=TASK,
                      robot_type=f"quadrotor-{spec.vehicle}", names=FEATURE_NAMES)
        pq.write_table(episode_table(data), tmp / EPISODES_FILE)
        meta = metadata(spec, data, version)
        (tmp / "README.md").write_text(dataset_card(meta))
        write_manifest(tmp, meta)
        os.rename(tmp, final)
    except OSError as e:
        if e.errno in (errno.EEXIST, errno.ENOTEMPTY) and final.is_dir():
            log(f"another build of {version} finished first")  # the same spec gives the same bytes: keep it
            return _verified_existing(spec, final, t0, log)
        raise UserError(f"writing the dataset failed: {e}") from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return BuildResult(final, True, len(data.T), len(data.episode_index), float(data.episode_success.mean()), data.resampled,
                       time.perf_counter() - t0)


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
    return BuildResult(final, False, meta["episodes"], meta["frames"], meta["expert_success_rate"], meta["resampled_goals"],
                       time.perf_counter() - t0)


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
