"""The maze dataset families and free-space exploration, flown and streamed into the
LeRobot writer of :mod:`aerohrl.datagen.build` (datagen/README.md "Maze families").

``navigate`` and ``stitch``: the maze expert (:mod:`aerohrl.datagen.maze_expert`) flies
from hover at a start cell to hover at a goal cell, with the spec's DART noise when set.
Every recorded step is checked for collisions (:meth:`aerohrl.worlds.maze.Maze.collides`);
an expert flight that collides is an error (the build stops and names the count): the
expert's legs run along corridor centre lines, so a collision means the recipe (noise,
``a_max``) is beyond what it tracks, not bad luck to be redrawn away.

``explore``: random velocity commands tracked by a stabilising velocity controller
(pilot ``velocity``), or in a maze a random walk over the cells flown on the expert's legs
with the spec's action noise, recorded as flown (pilot ``walk``); in a
maze an episode ends at its first colliding step (kept: the data show what a collision
is), in free space it runs its full length. The desired goal is the episode's last
achieved goal.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np
from tqdm.auto import tqdm

from aerohrl import task
from aerohrl.datagen import maze_expert as mx
from aerohrl.datagen import recipes
from aerohrl.datagen.expert import GeometricController
from aerohrl.datagen.spec import DatasetSpec
from aerohrl.errors import UserError
from aerohrl.sim import BatchedQuadrotor, get_preset
from aerohrl.worlds.maze import Maze, load_maze

NOISE_STREAM = 11  # the action noise: [spec.seed, 11, 0, block], as the free-space build
EXPLORE_STREAM = 17  # the exploration commands: [spec.seed, 17, block]
# A block holds at most this many episode-steps (episodes x its longest episode): bounds the
# rollout's (steps, N, .) float64 buffers (~0.2 GB) whatever the maze's path lengths.
BLOCK_STEPS = 1_000_000
# The walk pilot's moves per flight: its duration over this bound on the time a leg takes
# per cell. A rest-to-rest quintic over k cells of 2 m at a_max = 5 m/s^2 takes
# sqrt(10 / sqrt(3) * 2 / (5 k)) s a cell, above 0.4 s for runs up to 14 cells (the packaged
# mazes' longest corridor is 10); a walk that ends early leaves the vehicle hovering there.
WALK_CELL_TIME = 0.4
MAX_BLOCK_EPISODES = 8192


@dataclass
class Plan:
    """The episodes of a maze or explore spec before flying (N episodes)."""

    start: np.ndarray  # (N, 18) start state
    length: np.ndarray  # (N,) steps to record (explore: the most; a collision ends it earlier)
    goal_vec: np.ndarray | None  # (N, 15) desired goal (None for explore: the last achieved goal)
    ref: mx.PiecewiseReference | None = None  # the expert's reference (navigate, stitch)
    start_cell: np.ndarray | None = None  # (N, 2)
    goal_cell: np.ndarray | None = None  # (N, 2)
    path_cells: np.ndarray | None = None  # (N,)
    legs: np.ndarray | None = None  # (N,) legs per episode
    duration: np.ndarray | None = None  # (N,) reference duration without the settle time (s)


def world_maze(spec: DatasetSpec) -> Maze | None:
    """The spec's maze (None in free space)."""
    return load_maze(spec.maze) if spec.maze else None


def _references(spec: DatasetSpec, legs: mx.Legs) -> tuple[np.ndarray, np.ndarray]:
    """The spec's minimum-time references of ``legs`` (:func:`aerohrl.datagen.maze_expert.leg_references`)."""
    return mx.leg_references(legs.a, legs.b, a_max=spec.a_max, solver=spec.solver, degree=spec.degree, tol=spec.bisection_tol)


def plan(spec: DatasetSpec, n: int | None = None) -> Plan:
    """Starts, goals and expert references of the spec's episodes (the first ``n``)."""
    n = spec.goals if n is None else int(n)
    maze = world_maze(spec)
    rng = np.random.default_rng(spec.seed)
    if spec.family == "explore":
        steps = int(np.ceil(spec.explore_duration * spec.fps - 1e-9))
        if spec.explore_pilot == "walk":
            assert maze is not None  # DatasetSpec.check: the walk is a maze recipe
            s = maze.free_cells[rng.integers(0, len(maze.free_cells), size=n)]
            # enough moves for the flight: no leg covers a cell in less than WALK_CELL_TIME
            walks = mx.random_walks(maze, rng, s, int(np.ceil(spec.explore_duration / WALK_CELL_TIME)))
            legs = mx.legs_along(maze, list(walks))
            T, coeffs = _references(spec, legs)
            ep = legs.ep
            if spec.explore_stop > 0:
                ep, T, coeffs = mx.with_pauses(rng, legs, T, coeffs, spec.explore_stop, spec.explore_hold)
            ref = mx.PiecewiseReference(ep, T, coeffs, n)
            legs_n = np.bincount(legs.ep, minlength=n)
            return Plan(mx.hover_states(maze.cell_center(s)), np.full(n, steps, np.int64), None, ref, s, None, None, legs_n)
        if maze is None:
            p = np.zeros((n, 3))  # hover at the origin
        else:
            p = maze.cell_center(maze.free_cells[rng.integers(0, len(maze.free_cells), size=n)])
        return Plan(mx.hover_states(p), np.full(n, steps, np.int64), None)
    assert maze is not None  # DatasetSpec.check: navigate/stitch outside free space are maze families
    if spec.family == "stitch":
        s, g = mx.sample_pairs(maze, rng, n, hops=spec.hop_cells)
    else:
        s, g = mx.sample_pairs(maze, rng, n, min_path=spec.min_path)
    legs = mx.plan_legs(maze, s, g)
    T, coeffs = _references(spec, legs)
    ref = mx.PiecewiseReference(legs.ep, T, coeffs, n)
    length = np.ceil((ref.duration + spec.settle) * spec.fps - 1e-9).astype(np.int64)
    return Plan(
        mx.hover_states(maze.cell_center(s)),
        length,
        mx.hover_goals(maze.cell_center(g)),
        ref,
        s,
        g,
        legs.path_cells,
        np.bincount(legs.ep, minlength=n),
        ref.duration,
    )


def blocks(length: np.ndarray) -> np.ndarray:
    """Block bounds over the episodes in order: each block as many episodes as keep
    ``episodes x longest episode`` within :data:`BLOCK_STEPS` (a function of the lengths)."""
    bounds = [0]
    lo, longest = 0, 0
    for i, L in enumerate(length):
        longest2 = max(longest, int(L))
        if i > lo and ((i - lo + 1) * longest2 > BLOCK_STEPS or i - lo >= MAX_BLOCK_EPISODES):
            bounds.append(i)
            lo, longest2 = i, int(L)
        longest = longest2
    bounds.append(len(length))
    return np.array(bounds, np.int64)


def _sub(ref: mx.PiecewiseReference, rows: np.ndarray) -> mx.PiecewiseReference:
    """The episodes ``rows`` (index array) of a piecewise reference."""
    r = object.__new__(mx.PiecewiseReference)
    r.coeffs, r.T, r.start, r.duration = ref.coeffs[rows], ref.T[rows], ref.start[rows], ref.duration[rows]
    r._rows, r._falling = np.arange(len(rows)), ref._falling
    return r


def fly_block(spec: DatasetSpec, p: Plan, lo: int, hi: int, block: int, progress: bool = False) -> dict[str, np.ndarray]:
    """Episodes ``lo..hi-1`` of the plan flown at once -> their recorded frames,
    episode-major (``state``, ``action``, ``next_state``, ``expert_action`` with noise),
    ``length`` (N,) and ``collided`` (N,) per episode. A function of its arguments alone.

    The batch shrinks as episodes end (their lengths differ several-fold in a maze): when
    a quarter of the vehicles still flown have ended, the simulator keeps only the others
    (:meth:`aerohrl.sim.BatchedQuadrotor.select`, bit for bit), and so do the reference,
    noise and command arrays; the cost is that of the recorded steps, not of the longest."""
    maze = world_maze(spec)
    params = get_preset(spec.vehicle)
    n = hi - lo
    dt = spec.dt
    length = p.length[lo:hi].copy()
    kmax = int(length.max())
    sim = BatchedQuadrotor(params, n, dt=dt, substeps=spec.substeps)
    ctrl = GeometricController(params)
    states = np.empty((kmax + 1, n, task.STATE_DIM))
    actions = np.empty((kmax, n, task.ACTION_DIM))
    explore = spec.family == "explore"
    expert = np.empty_like(actions) if spec.noisy and not explore else None  # explore: no expert label
    collided = np.zeros(n, bool)
    s = states[0] = sim.reset(p.start[lo:hi])
    act: np.ndarray = np.arange(n)  # the episodes (of this block) in the simulator's batch, in order
    velocity = explore and spec.explore_pilot == "velocity"  # else the expert's legs (navigate, stitch, walk)
    if velocity:
        rng = np.random.default_rng([spec.seed, EXPLORE_STREAM, block])
        climb = spec.explore_climb if maze is None else 0.0
        cmds = mx.explore_commands(
            rng, n, kmax, dt, speed=spec.explore_speed, climb=climb, hold=spec.explore_hold, stop=spec.explore_stop
        )
        v_ref: np.ndarray = np.zeros((n, 3))
        bounce = maze is not None and spec.explore_wall_margin > 0
        flip: np.ndarray = np.ones((n, 2))  # per-axis sign of the horizontal command (bounces off walls)
    else:
        assert p.ref is not None
        ref = _sub(p.ref, np.arange(lo, hi))
        if spec.noisy:
            noise_rng = np.random.default_rng([spec.seed, NOISE_STREAM, 0, block])
            noise = recipes.OUNoise(spec.action_noise, spec.noise_tau, dt, n, noise_rng)
            box_lo, box_hi = ctrl.action_box
    for k in tqdm(range(kmax), desc="maze rollouts", unit="step", disable=None if progress else True, leave=False):
        ended = length[act] <= k
        if 4 * ended.sum() >= len(act):
            if ended.all():  # every episode of the block has ended (explore: by collisions)
                break
            keep = np.flatnonzero(~ended)
            sim, act, s = sim.select(keep), act[keep], s[keep]
            if velocity:
                v_ref, flip = v_ref[keep], flip[keep]
            else:
                ref = _sub(p.ref, lo + act)
                if spec.noisy:
                    noise.eta = noise.eta[keep]
        if velocity:
            cmd = cmds[k, act]
            if bounce:
                assert maze is not None
                if k > 0:  # a new segment starts with its own command's signs
                    flip[np.any(cmd != cmds[k - 1, act], axis=1)] = 1.0
                flip = mx.reflect_off_walls(maze, s[:, task.POS], v_ref, cmd, flip, spec.a_max, spec.explore_wall_margin)
                cmd = cmd.copy()
                cmd[:, :2] *= flip
            v_ref, acc = mx.velocity_reference_step(v_ref, cmd, spec.a_max, dt)
            pos_ref = s[:, task.POS].copy()  # no horizontal position term: a velocity controller
            if maze is not None:
                pos_ref[:, 2] = maze.altitude
            a = ctrl(s, pos_ref, v_ref, acc, np.zeros_like(acc), yaw=0.0)
        else:
            a = ctrl(s, *ref(k * dt), yaw=0.0)
            if spec.noisy:
                if expert is not None:
                    expert[k, act] = a
                a = np.clip(a + noise(), box_lo, box_hi)
        actions[k, act] = a
        s = sim.step(a)
        states[k + 1, act] = s
        if maze is not None:
            hit = maze.collides(s[:, task.POS]) & (k < length[act])
            collided[act[hit]] = True
            if explore:
                length[act[hit]] = k + 1  # the colliding step is the episode's last
    e = np.repeat(np.arange(n), length)
    kk = np.arange(int(length.sum())) - np.repeat(np.concatenate([[0], np.cumsum(length)[:-1]]), length)
    out = {
        "state": states[kk, e],
        "action": actions[kk, e],
        "next_state": states[kk + 1, e],
        "length": length,
        "collided": collided,
    }
    if expert is not None:
        out["expert_action"] = expert[kk, e]
    return out


def fly(spec: DatasetSpec, p: Plan, progress: bool) -> Iterator[tuple[int, int, dict[str, np.ndarray]]]:
    """:func:`fly_block` over :func:`blocks`: yields ``(lo, hi, frames)`` in episode order."""
    bounds = blocks(p.length)
    nb = len(bounds) - 1
    for b in tqdm(range(nb), desc="maze blocks", unit="block", disable=None if progress and nb >= 3 else True, leave=False):
        lo, hi = int(bounds[b]), int(bounds[b + 1])
        yield lo, hi, fly_block(spec, p, lo, hi, b, progress)


def stream(spec: DatasetSpec, writer: Any, progress: bool) -> Any:
    """Fly the spec's episodes and append their frames to ``writer`` block by block ->
    the build's :class:`aerohrl.datagen.build.EpisodeSummary` (its ``extra`` holds the
    family's metadata)."""
    from aerohrl.datagen.build import MIN_EXPERT_SUCCESS, EpisodeSummary, _pop_columns

    maze = world_maze(spec)
    p = plan(spec)
    n = len(p.length)
    length = p.length.copy()
    collided = np.zeros(n, bool)
    success = np.zeros(n, bool)
    success_end = np.zeros(n, bool)
    first = np.full(n, -1, np.int64)
    final = np.empty((n, task.STATE_DIM))
    goal_vec = np.empty((n, task.GOAL_DIM)) if p.goal_vec is None else p.goal_vec
    passes = np.zeros((n, len(maze.tasks) if maze else 0), bool)
    walk = spec.family == "explore" and spec.explore_pilot == "walk"
    for lo, hi, r in fly(spec, p, progress):
        L = r.pop("length")
        length[lo:hi] = L
        collided[lo:hi] = r.pop("collided")
        ends = np.cumsum(L)
        e = np.repeat(np.arange(hi - lo), L)
        final[lo:hi] = r["next_state"][ends - 1]
        if p.goal_vec is None:  # explore: the last achieved goal
            goal_vec[lo:hi] = task.achieved_goal(final[lo:hi])
        g = goal_vec[lo:hi][e]
        r["success"] = task.goal_reached(task.achieved_goal(r["next_state"]), g)
        hit = np.flatnonzero(r["success"])
        eps, at = np.unique(e[hit], return_index=True)  # frames ascend: the first hit of each episode
        first[lo + eps] = hit[at] - (ends - L)[eps]
        success[lo + eps] = True
        success_end[lo:hi] = r["success"][ends - 1]
        if maze is not None and (spec.family == "stitch" or walk):
            passes[lo:hi] = mx.passes_tasks(maze, r["next_state"][:, task.POS], e, hi - lo)
        last = np.zeros(len(e), bool)
        last[ends - 1] = True
        writer.append(_pop_columns(r, g.astype(np.float32), last), L)
        del r
    extra: dict[str, Any] = {"world": spec.world, "family": spec.family}
    if maze is not None:
        extra["maze"] = maze.to_dict()
        extra["collisions"] = int(collided.sum())
    if spec.family != "explore":
        if collided.any():
            raise UserError(
                f"{int(collided.sum())} of {n} expert flights collide with the maze under this recipe; "
                "lower --action-noise or --a-max"
            )
        rate = float(success.mean())
        if rate < MIN_EXPERT_SUCCESS:
            raise UserError(
                f"the maze expert reaches only {100 * rate:.1f}% of its goals (floor {100 * MIN_EXPERT_SUCCESS:.0f}%): "
                "lower --action-noise"
            )
        assert p.path_cells is not None and p.legs is not None
        extra["expert"] = {
            "success_rate": rate,
            "success_at_end_rate": float(success_end.mean()),
            "path_cells": {"min": int(p.path_cells.min()), "mean": float(p.path_cells.mean()), "max": int(p.path_cells.max())},
            "legs_per_episode": {"min": int(p.legs.min()), "mean": float(p.legs.mean()), "max": int(p.legs.max())},
        }
    if spec.family == "stitch" or walk:
        assert maze is not None
        extra["task_coverage"] = {
            "fraction": float(passes.any(axis=0).mean()),
            "per_task": [int(c) for c in passes.sum(axis=0)],
            "tolerance_m": 0.5,
            "test": "episodes passing within 0.5 m of a frozen task's start cell centre and later of its goal cell centre",
        }
    if spec.family == "explore":
        extra["explore"] = {
            "episodes_ended_by_collision": int(collided.sum()),
            "steps_flown": int(length.sum()),
            "steps_commanded": int(p.length.sum()),
        }
        if walk:
            assert p.legs is not None
            extra["explore"]["legs_per_episode"] = {
                "min": int(p.legs.min()),
                "mean": float(p.legs.mean()),
                "max": int(p.legs.max()),
            }
    vel = goal_vec[:, task.VEL]
    goals = {"pos": goal_vec[:, task.POS].copy(), "vel": vel.copy(), "acc": np.zeros((n, 3))}
    T = p.duration if p.duration is not None else length * spec.dt
    return EpisodeSummary(
        goals,
        goal_vec,
        T,
        length,
        success,
        first,
        final,
        extra=extra,
        collided=collided if maze is not None else None,
        start_cell=p.start_cell,
        goal_cell=p.goal_cell,
    )
