r"""The maze expert and the exploration flights of the maze dataset families.

Pure, batched functions over N episodes (datagen/README.md "Maze families").

Maze expert (families navigate and stitch)
------------------------------------------
For each (start cell, goal cell) pair:

1. the shortest 4-connected path on the maze's cell graph
   (:meth:`aerohrl.worlds.maze.Maze.shortest_path`, breadth-first search) and its
   corners (:func:`aerohrl.worlds.maze.corners`: the cells where it turns, with its ends);
2. one rest-to-rest minimum-jerk leg per pair of consecutive corners, from the centre of
   one corner cell to the centre of the next at flight altitude. Between two corners the
   path is a straight run of free cells, and a rest-to-rest quintic between two points
   moves along the segment joining them (every axis is the same monotone profile, scaled),
   so the leg stays on the corridor's centre line: collision-free by construction;
3. each leg's duration is its minimum time under the acceleration bound ``a_max``
   (:func:`aerohrl.datagen.reference.min_time`, the spec's solver, all legs at once);
4. the legs are chained in time into one piecewise reference per episode, followed by
   ``settle`` seconds of hover at the goal (the last leg evaluated past its end: at rest).

The legs of all episodes are flat arrays with an episode index; the piecewise reference
is evaluated for all episodes at once by gathering each episode's current leg
(:class:`PiecewiseReference`). The start state is hover at the start cell's centre;
the desired goal is hover at the goal cell's centre, ``[p_goal, 0, I]``.

Exploration (family explore)
----------------------------
Pilot ``walk`` (mazes; OGBench's explore recipe): each flight is a random walk over the
cell graph from a random free cell (:func:`random_walks`), flown as the expert flies a
path (steps 2-4 above: rest-to-rest legs between the walk's corners) with the spec's
action noise added to every command; the recorded action is the flown one and there is no
expert label. With probability ``explore_stop`` the vehicle hovers after a leg, for a time
drawn from ``explore_hold`` (:func:`with_pauses`). A flight lasts ``explore_duration``
seconds or ends at its first collision.

Pilot ``velocity``: piecewise-constant velocity commands: each held for a time drawn from ``hold`` (s); the
horizontal part has a uniform heading and a speed uniform in ``[0, speed]``; in free
space the vertical part is uniform in ``[-climb, climb]``, in a maze it is 0 and the
altitude is held. The reference velocity follows the command with its acceleration's
norm bounded by ``a_max`` (:func:`velocity_reference_step`); the geometric
controller tracks that velocity with no horizontal position term (its reference position
is the vehicle's own, so it is a stabilising velocity controller), and in a maze the
reference altitude is the maze's flight altitude.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aerohrl import task
from aerohrl.datagen import reference
from aerohrl.errors import UserError
from aerohrl.worlds.maze import Maze, corners


def sample_pairs(
    maze: Maze, rng: np.random.Generator, n: int, *, hops: tuple[int, int] | None = None, min_path: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` (start, goal) free cells -> ``(start (n, 2), goal (n, 2))`` (row, col).

    ``hops=(lo, hi)`` (stitch): a hop length ``h`` uniform in ``lo..hi`` cells, the start
    uniform over the free cells and the goal uniform over the cells exactly ``h`` cells
    away on the cell graph. Otherwise (navigate): start and goal uniform over the free
    cells with a path length of at least ``min_path`` times the maze's diameter (its
    longest shortest path). A draw with no such goal is redrawn whole; the draws come
    from ``rng`` in order, so the pairs are a function of its seed."""
    free = maze.free_cells
    dist = maze.distances()
    m = len(free)
    if hops is not None:
        if hops[0] > dist[np.isfinite(dist)].max():
            raise UserError(f"hop_cells {list(hops)}: no two cells of maze {maze.name} are {hops[0]} cells apart")
    else:
        need = np.ceil(min_path * dist[np.isfinite(dist)].max() - 1e-9)
    start = np.empty(n, np.int64)
    goal = np.empty(n, np.int64)
    todo = np.arange(n)
    for _ in range(100):
        s = rng.integers(0, m, size=todo.size)
        if hops is not None:
            h = rng.integers(hops[0], hops[1] + 1, size=todo.size)
            ok_cells = dist[s] == h[:, None]  # (k, m) cells exactly h away from each start
        else:
            ok_cells = (dist[s] >= max(need, 1)) & np.isfinite(dist[s])
        count = ok_cells.sum(axis=1)
        # the goal: the j-th allowed cell with j uniform in 0..count-1 (one uniform per draw)
        j = np.floor(rng.random(todo.size) * np.maximum(count, 1)).astype(np.int64)
        g = np.argmax(np.cumsum(ok_cells, axis=1) > j[:, None], axis=1)
        ok = count > 0
        start[todo[ok]], goal[todo[ok]] = s[ok], g[ok]
        todo = todo[~ok]
        if todo.size == 0:
            return free[start], free[goal]
    raise UserError(f"maze {maze.name}: almost no start cell has a goal cell at the asked path length")


@dataclass
class Legs:
    """The legs of N episodes, flat (L legs): leg ``i`` of episode ``ep[i]`` flies from rest
    at ``a[i]`` to rest at ``b[i]`` (m); an episode's legs are consecutive and in order."""

    ep: np.ndarray  # (L,) episode of each leg
    a: np.ndarray  # (L, 3) start point
    b: np.ndarray  # (L, 3) end point
    path_cells: np.ndarray  # (N,) cells on each episode's shortest path (start and goal included)


def plan_legs(maze: Maze, start: np.ndarray, goal: np.ndarray) -> Legs:
    """The corner-to-corner legs of each episode's shortest path (module docstring, steps 1-2).
    Planning is a per-episode graph walk (predecessor lists), done once before flying."""
    return legs_along(maze, [maze.shortest_path(tuple(s), tuple(g)) for s, g in zip(start, goal)])


def legs_along(maze: Maze, paths: list[np.ndarray]) -> Legs:
    """The corner-to-corner legs of each episode's cell path ``paths[i]`` (k_i, 2), a walk
    of 4-connected free cells (module docstring, step 2)."""
    eps, pts = [], []
    for i, path in enumerate(paths):
        c = maze.cell_center(corners(path))
        pts.append(c)
        eps.append(np.full(len(c), i))
    p = np.concatenate(pts)
    e = np.concatenate(eps)
    same = e[1:] == e[:-1]  # consecutive corners of one episode form a leg
    return Legs(e[1:][same], p[:-1][same], p[1:][same], np.array([len(path) for path in paths], np.int64))


def with_pauses(
    rng: np.random.Generator, legs: Legs, T: np.ndarray, coeffs: np.ndarray, stop: float, hold: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The legs ``(T, coeffs)`` of :func:`leg_references` with a hover after each leg with
    probability ``stop``, held a time uniform in ``hold`` (s) at the leg's end ->
    ``(ep, T, coeffs)`` in episode order, for :class:`PiecewiseReference`. A hover is a
    constant reference (every derivative zero). The draws come from ``rng`` in order."""
    pause = rng.random(len(T)) < stop
    held = rng.uniform(hold[0], hold[1], size=len(T))[pause]
    still = np.zeros((int(pause.sum()),) + coeffs.shape[1:])
    still[:, :, 0] = legs.b[pause]
    order = np.argsort(np.concatenate([2 * np.arange(len(T)), 2 * np.flatnonzero(pause) + 1]), kind="stable")
    ep = np.concatenate([legs.ep, legs.ep[pause]])[order]
    return ep, np.concatenate([T, held])[order], np.concatenate([coeffs, still])[order]


STEPS = np.array([[-1, 0], [1, 0], [0, -1], [0, 1]])  # the four grid moves (row, col)


def random_walks(maze: Maze, rng: np.random.Generator, start: np.ndarray, cells: int) -> np.ndarray:
    """``(n, cells + 1, 2)`` random walks of ``cells`` moves over the maze's cell graph from
    ``start`` (n, 2), all walks at once (module docstring, "Exploration", pilot ``walk``).

    Each move goes to a free 4-neighbour drawn uniformly among those that do not turn
    back, and turns back only at a dead end: a plain random walk retraces its last move a
    quarter to a half of the time and covers little of a maze in a flight, while this one
    runs down corridors and picks a branch at random at each junction, the way OGBench's
    explore agents run in a random direction. The draws come from ``rng`` in order."""
    start = np.asarray(start, np.int64)
    n = len(start)
    walk = np.empty((n, cells + 1, 2), np.int64)
    walk[:, 0] = start
    prev = np.full(n, -1)  # the move index taken last (-1: none)
    back = np.array([1, 0, 3, 2])  # the move that undoes each move
    for k in range(cells):
        nxt = walk[:, k, None, :] + STEPS  # (n, 4, 2)
        free = ~maze.is_wall(nxt.reshape(-1, 2)).reshape(n, 4)
        forward = free.copy()
        has_prev = prev >= 0
        forward[has_prev, back[prev[has_prev]]] = False
        allowed = np.where(forward.any(axis=1, keepdims=True), forward, free)  # a dead end: turn back
        key = np.where(allowed, rng.random((n, 4)), -1.0)  # uniform among the allowed moves
        move = key.argmax(axis=1)
        walk[:, k + 1] = nxt[np.arange(n), move]
        prev = move
    return walk


def leg_references(
    a: np.ndarray, b: np.ndarray, *, a_max: float, solver: str, degree: int, tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """Rest-to-rest minimum-time minimum-jerk references from ``a`` to ``b`` (L, 3) ->
    ``(T (L,), coeffs (L, 3, degree + 1))`` (module docstring, step 3).

    The bisection bracket's upper end is twice the rest-to-rest quintic's minimum time
    over the longest leg, ``sqrt(10 / sqrt(3) * D / a_max)`` (its peak acceleration is
    ``10 / sqrt(3) * D / T^2``), so every leg is feasible within it."""
    x0 = np.zeros((len(a), 3, 3))
    xf = np.zeros((len(a), 3, 3))
    x0[:, :, 0], xf[:, :, 0] = a, b
    D = np.abs(b - a).max() if len(a) else 0.0
    t_hi = 2.0 * float(np.sqrt(10.0 / np.sqrt(3.0) * max(D, 1e-3) / a_max)) + 1.0
    T, coeffs, feasible = reference.min_time(x0, xf, a_max=a_max, t_lo=0.0, t_hi=t_hi, tol=tol, solver=solver, degree=degree)
    if not feasible.all():  # cannot happen with the bracket above, but never fly a bad leg silently
        raise UserError(f"{int((~feasible).sum())} maze legs have no reference within {t_hi:.2f} s at a_max={a_max}")
    return T, coeffs


class PiecewiseReference:
    """N episodes' chained legs, evaluated at once: ``ref(t) -> (pos, vel, acc, jerk)`` (N, 3)
    each at episode time ``t`` (s). Leg ``j`` of episode ``n`` runs from ``start[n, j]``
    for ``T[n, j]`` seconds; past its last leg an episode holds that leg's end (at rest)."""

    def __init__(self, ep: np.ndarray, T: np.ndarray, coeffs: np.ndarray, n: int):
        counts = np.bincount(ep, minlength=n)
        if (counts == 0).any():
            raise ValueError("every episode needs at least one leg")
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        slot = np.arange(len(ep)) - first[ep]  # index of each leg within its episode
        width = int(counts.max())
        self.coeffs = np.zeros((n, width) + coeffs.shape[1:])
        self.coeffs[ep, slot] = coeffs
        self.T = np.zeros((n, width))
        self.T[ep, slot] = T
        ends = np.cumsum(self.T, axis=1)
        self.start = np.where(np.arange(width) < counts[:, None], ends - self.T, np.inf)  # inf: no such leg
        self.duration = ends[:, -1]  # (n,) end of each episode's last leg
        self._rows = np.arange(n)
        k = np.arange(coeffs.shape[-1])
        # falling factorials k (k-1) ... (k-o+1): the factor of c_k t^(k-o) in derivative o
        self._falling = np.ones((4, len(k)))
        for o in range(1, 4):
            self._falling[o] = self._falling[o - 1] * np.maximum(k - (o - 1), 0)

    def __call__(self, t: float | np.ndarray) -> list[np.ndarray]:
        t = np.broadcast_to(np.asarray(t, dtype=np.float64), self._rows.shape)
        j = (self.start <= t[:, None]).sum(axis=1) - 1  # the current leg (the first one before t = 0)
        j = np.maximum(j, 0)
        c = self.coeffs[self._rows, j]  # (N, 3, D)
        Tj = self.T[self._rows, j]
        since = t - self.start[self._rows, j]
        tl = np.clip(since, 0.0, Tj)
        # derivative o of sum_k c_k t^k is sum_k c_k k!/(k-o)! t^(k-o): one basis (N, 4, D) for
        # the four orders (the same sums as reference.evaluate, in one contraction)
        D = c.shape[-1]
        powers = tl[:, None] ** np.arange(D)  # (N, D)
        basis = np.zeros((len(tl), 4, D))
        for o in range(4):
            basis[:, o, o:] = powers[:, : D - o] * self._falling[o, o:]
        out = np.einsum("nak,nok->ona", c, basis)
        # past the end the hold is at rest: the quintic's end jerk is not zero, and fed
        # forward it would tilt the vehicle off its hover point
        out[3][since > Tj] = 0.0
        return [out[0], out[1], out[2], out[3]]


def hover_states(p: np.ndarray) -> np.ndarray:
    """(N, 18) hover at points ``p`` (N, 3): zero velocity, ``R = I``, zero body rates (task.py layout)."""
    s = np.zeros((len(p), task.STATE_DIM))
    s[:, task.POS] = p
    s[:, task.ROT] = np.eye(3).reshape(-1)
    return s


def hover_goals(p: np.ndarray) -> np.ndarray:
    """(N, 15) the goal "hover at ``p``": ``[p, 0, I]`` (task.py goal layout)."""
    return hover_states(p)[:, : task.GOAL_DIM]


def explore_commands(
    rng: np.random.Generator,
    n: int,
    steps: int,
    dt: float,
    *,
    speed: float,
    climb: float,
    hold: tuple[float, float],
    stop: float = 0.0,
) -> np.ndarray:
    """(steps, n, 3) piecewise-constant velocity commands (m/s) (module docstring,
    "Exploration"). Enough segments are drawn for the longest flight; a segment's hold
    time is uniform in ``hold`` (s), rounded to whole control steps (at least one). With
    probability ``stop`` a segment is a hover (zero command): the data then shows the
    vehicle coming to rest at places no expert chose (drawn after the other draws, so
    ``stop = 0`` keeps the commands' bytes)."""
    k = int(np.ceil(steps * dt / hold[0])) + 1  # segments: more than enough at the shortest hold
    hold_steps = np.maximum(np.round(rng.uniform(hold[0], hold[1], size=(n, k)) / dt), 1).astype(np.int64)
    heading = rng.uniform(0.0, 2.0 * np.pi, size=(n, k))
    v = speed * rng.random((n, k))
    vz = climb * rng.uniform(-1.0, 1.0, size=(n, k))
    seg = np.stack([v * np.cos(heading), v * np.sin(heading), vz], axis=-1)  # (n, k, 3)
    if stop > 0:
        seg[rng.random((n, k)) < stop] = 0.0
    ends = np.cumsum(hold_steps, axis=1)  # (n, k) step at which each segment ends
    which = (np.arange(steps)[None, :, None] >= ends[:, None, :]).sum(axis=2)  # (n, steps) segment at each step
    return np.ascontiguousarray(np.take_along_axis(seg, which[..., None], axis=1).transpose(1, 0, 2))


def reflect_off_walls(
    maze: Maze, p: np.ndarray, v_ref: np.ndarray, cmd: np.ndarray, flip: np.ndarray, a_max: float, margin: float
) -> np.ndarray:
    """The per-axis signs ``flip`` (N, 2) of the horizontal command after this step's wall
    check: an axis whose commanded direction (``cmd[:, :2] * flip``) would bring the vehicle at
    ``p`` (N, 3) within ``d = v_j^2 / (2 a_max) + margin`` of a wall (its sphere touching it,
    :meth:`Maze.collides`), ``v_j`` the reference velocity along that axis, is reversed: the
    command bounces off the wall (the sign holds until the caller resets it at the next
    segment). Only a command moving toward the wall is reversed, so a reversed one is not
    reversed back while it pulls away."""
    flip = flip.copy()
    for j in (0, 1):
        c = cmd[:, j] * flip[:, j]
        toward = np.sign(c)
        d = v_ref[:, j] ** 2 / (2.0 * a_max) * (np.sign(v_ref[:, j]) == toward) + margin
        probe = p.copy()
        probe[:, j] += toward * d
        hit = (toward != 0) & maze.collides(probe)
        flip[hit, j] *= -1.0
    return flip


def velocity_reference_step(v_ref: np.ndarray, cmd: np.ndarray, a_max: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """One step of the reference velocity toward the command with its acceleration's norm
    bounded: ``acc = (cmd - v_ref) / dt`` scaled down to norm ``a_max`` if longer,
    ``v_ref' = v_ref + acc dt`` -> ``(v_ref', acc)`` (N, 3) each. A norm bound (not per
    axis) keeps the demanded tilt within ``atan(a_max / g)`` plus the feedback's share."""
    acc = (cmd - v_ref) / dt
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    acc *= np.minimum(1.0, a_max / np.maximum(norm, 1e-12))
    return v_ref + acc * dt, acc


def passes_tasks(maze: Maze, positions: np.ndarray, episode: np.ndarray, n: int, tol: float = 0.5) -> np.ndarray:
    """(n, tasks) bool: episode ``i`` passes within ``tol`` (m) of task ``t``'s start cell centre
    and, at that time or later, within ``tol`` of its goal cell centre. ``positions`` (F, 3)
    and ``episode`` (F,) are the flown frames, episode-major and in time order."""
    starts = maze.cell_center(np.array([s for s, _ in maze.tasks]))
    goals = maze.cell_center(np.array([g for _, g in maze.tasks]))
    out = np.zeros((n, len(maze.tasks)), bool)
    frame = np.arange(len(positions))
    for t in range(len(maze.tasks)):
        near_s = np.linalg.norm(positions - starts[t], axis=1) <= tol
        near_g = np.linalg.norm(positions - goals[t], axis=1) <= tol
        first_s = np.full(n, np.iinfo(np.int64).max)
        np.minimum.at(first_s, episode[near_s], frame[near_s])
        last_g = np.full(n, -1)
        np.maximum.at(last_g, episode[near_g], frame[near_g])
        out[:, t] = last_g >= first_s
    return out
