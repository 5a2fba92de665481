"""Quadrotor mazes: fixed layouts of axis-aligned wall boxes between a floor and a ceiling.

A maze is a grid of square cells of side ``cell`` (m); a wall cell is the box
``[c cell, (c + 1) cell] x [r cell, (r + 1) cell] x [0, ceiling]`` (row ``r``, column ``c``;
x east, y north, z up). The layouts are data files (``worlds/mazes/*.toml``), each with
five frozen evaluation tasks (start and goal cells).

The vehicle is a sphere of radius :data:`VEHICLE_RADIUS` for collision checks: its
centre ``p`` collides when ``dist(p, box) < radius`` for any wall box, or when
``p_z < radius`` (floor) or ``p_z > ceiling - radius`` (ceiling). Everything here is a
pure function of arrays, batched over leading dimensions.
"""

from __future__ import annotations

import functools
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aerohrl.errors import UserError

MAZE_DIR = Path(__file__).parent / "mazes"
MAZES = ("medium", "large", "giant")
# The Hummingbird's rotor centres sit 0.17 m from its centre and its rotors are ~0.1 m
# across: a 0.25 m sphere encloses the airframe with its propellers.
VEHICLE_RADIUS = 0.25  # m
_NEIGHBOURS = np.array([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)])  # 3x3 block around a cell


@dataclass(frozen=True)
class Maze:
    """One maze layout and its frozen tasks."""

    name: str
    walls: np.ndarray  # (rows, cols) bool, True = wall cell
    cell: float  # m, side of a cell
    ceiling: float  # m
    altitude: float  # m, flight altitude of starts, goals and expert paths
    tasks: tuple[tuple[tuple[int, int], tuple[int, int]], ...]  # ((start row, col), (goal row, col)) x 5
    tasks_version: int

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) of the grid."""
        return (int(self.walls.shape[0]), int(self.walls.shape[1]))

    @property
    def free_cells(self) -> np.ndarray:
        """(n, 2) int64 (row, col) of every free cell, row-major (their index in :meth:`distances`)."""
        return np.argwhere(~self.walls)

    def cell_index(self, rc: np.ndarray) -> np.ndarray:
        """Index into :attr:`free_cells` of free cells ``rc`` (..., 2); -1 for a wall or outside."""
        rc = np.asarray(rc, dtype=np.int64)
        lookup = np.full(self.walls.size, -1, dtype=np.int64)
        free = self.free_cells
        lookup[free[:, 0] * self.shape[1] + free[:, 1]] = np.arange(len(free))
        r, c = rc[..., 0], rc[..., 1]
        inside = (r >= 0) & (r < self.shape[0]) & (c >= 0) & (c < self.shape[1])
        flat = np.where(inside, r * self.shape[1] + c, 0)
        return np.where(inside, lookup[flat], -1)

    def cell_center(self, rc: np.ndarray) -> np.ndarray:
        """(..., 3) the point at flight altitude above the centre of cells ``rc`` (..., 2)."""
        rc = np.asarray(rc, dtype=np.float64)
        x = (rc[..., 1] + 0.5) * self.cell
        y = (rc[..., 0] + 0.5) * self.cell
        return np.stack([x, y, np.full_like(x, self.altitude)], axis=-1)

    def cell_of(self, p: np.ndarray) -> np.ndarray:
        """(..., 2) int64 (row, col) of the cell under points ``p`` (..., 3) (may lie outside the grid)."""
        p = np.asarray(p, dtype=np.float64)
        return np.stack([np.floor(p[..., 1] / self.cell), np.floor(p[..., 0] / self.cell)], axis=-1).astype(np.int64)

    def is_wall(self, rc: np.ndarray) -> np.ndarray:
        """Wall (or outside the grid) at cells ``rc`` (..., 2) -> bool (...)."""
        rc = np.asarray(rc, dtype=np.int64)
        r, c = rc[..., 0], rc[..., 1]
        inside = (r >= 0) & (r < self.shape[0]) & (c >= 0) & (c < self.shape[1])
        return ~inside | self.walls[np.clip(r, 0, self.shape[0] - 1), np.clip(c, 0, self.shape[1] - 1)]

    def wall_distance(self, p: np.ndarray) -> np.ndarray:
        """(...) horizontal distance (m) from points ``p`` (..., 3) to the nearest wall box.

        Distance to a box ``[lo, hi]``: ``|max(lo - p, 0, p - hi)|`` per axis. Only the 3x3
        cells around ``p``'s cell are checked: a wall farther away is at least one cell
        (``cell`` > any radius asked about) away. Inside a wall the distance is 0."""
        p = np.asarray(p, dtype=np.float64)
        rc = self.cell_of(p)
        nb = rc[..., None, :] + _NEIGHBOURS  # (..., 9, 2)
        wall = self.is_wall(nb)
        lo_x, lo_y = nb[..., 1] * self.cell, nb[..., 0] * self.cell
        dx = np.maximum(np.maximum(lo_x - p[..., None, 0], 0.0), p[..., None, 0] - (lo_x + self.cell))
        dy = np.maximum(np.maximum(lo_y - p[..., None, 1], 0.0), p[..., None, 1] - (lo_y + self.cell))
        d = np.where(wall, np.hypot(dx, dy), np.inf)
        return d.min(axis=-1)

    def collides(self, p: np.ndarray, radius: float = VEHICLE_RADIUS) -> np.ndarray:
        """(...) bool: a sphere of ``radius`` at ``p`` (..., 3) touches a wall, the floor or the ceiling."""
        p = np.asarray(p, dtype=np.float64)
        return (self.wall_distance(p) < radius) | (p[..., 2] < radius) | (p[..., 2] > self.ceiling - radius)

    @functools.cached_property
    def _distances(self) -> tuple[np.ndarray, np.ndarray]:
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import shortest_path

        free = self.free_cells
        idx = self.cell_index(free)
        rows, cols = [], []
        for d in ((0, 1), (1, 0)):  # 4-connected grid: an edge to the east and to the north neighbour
            j = self.cell_index(free + np.array(d))
            ok = j >= 0
            rows.append(idx[ok])
            cols.append(j[ok])
        r, c = np.concatenate(rows), np.concatenate(cols)
        g = coo_matrix((np.ones(len(r)), (r, c)), shape=(len(free), len(free))).tocsr()
        dist, pred = shortest_path(g, directed=False, unweighted=True, return_predecessors=True)
        return dist, pred

    def distances(self) -> np.ndarray:
        """(n, n) shortest-path length in cells between the free cells (order of :attr:`free_cells`)."""
        return self._distances[0]

    def shortest_path(self, start: tuple[int, int], goal: tuple[int, int]) -> np.ndarray:
        """(m, 2) the cells of a shortest 4-connected path from ``start`` to ``goal``, both
        included (breadth-first search: scipy's ``csgraph.shortest_path``, unweighted)."""
        i, j = (int(k) for k in self.cell_index(np.array([start, goal])))
        if i < 0 or j < 0:
            bad = start if i < 0 else goal
            raise UserError(f"cell {tuple(bad)} of maze {self.name} is a wall or outside the maze")
        pred = self._distances[1]
        path = [j]
        while path[-1] != i:
            path.append(int(pred[i, path[-1]]))
        return self.free_cells[path[::-1]]

    def to_dict(self) -> dict:
        """The layout as JSON-ready data (recorded in a maze dataset's metadata)."""
        return {
            "name": self.name,
            "layout": ["".join("#" if w else "." for w in row) for row in self.walls],
            "cell": self.cell,
            "ceiling": self.ceiling,
            "altitude": self.altitude,
            "vehicle_radius": VEHICLE_RADIUS,
            "tasks": [{"start": list(s), "goal": list(g)} for s, g in self.tasks],
            "tasks_version": self.tasks_version,
        }


def corners(path: np.ndarray) -> np.ndarray:
    """The cells of a grid path where it turns, with its first and last cell: (k, 2).
    Between two consecutive corners the path is a straight corridor run."""
    path = np.asarray(path)
    if len(path) <= 2:
        return path
    step = np.diff(path, axis=0)
    turn = np.any(step[1:] != step[:-1], axis=1)
    return np.concatenate([path[:1], path[1:-1][turn], path[-1:]])


def parse_layout(text: str) -> np.ndarray:
    """A '#'/'.' layout -> (rows, cols) bool walls; UserError on ragged rows or other characters."""
    rows = [r for r in text.strip().splitlines() if r.strip()]
    if not rows or len({len(r) for r in rows}) != 1:
        raise UserError("maze layout rows must be non-empty and of equal length")
    if set("".join(rows)) - set("#."):
        raise UserError("maze layout may hold only '#' (wall) and '.' (free)")
    walls = np.array([[ch == "#" for ch in r] for r in rows])
    if not (walls[0].all() and walls[-1].all() and walls[:, 0].all() and walls[:, -1].all()):
        raise UserError("maze layout must be enclosed by walls")
    return walls


WORLDS = ("free",) + tuple(f"maze-{m}" for m in MAZES)  # a dataset spec's `world`


def maze_from_dict(d: dict) -> Maze:
    """The maze of :meth:`Maze.to_dict` data (a maze dataset's metadata); UserError when malformed."""
    try:
        walls = parse_layout("\n".join(d["layout"]) if isinstance(d["layout"], list) else str(d["layout"]))
        tasks = tuple((tuple(int(x) for x in t["start"]), tuple(int(x) for x in t["goal"])) for t in d["tasks"])
        maze = Maze(
            name=str(d["name"]),
            walls=walls,
            cell=float(d["cell"]),
            ceiling=float(d["ceiling"]),
            altitude=float(d["altitude"]),
            tasks=tasks,  # type: ignore[arg-type]  # pairs of (row, col)
            tasks_version=int(d["tasks_version"]),
        )
    except (KeyError, TypeError, ValueError) as e:
        raise UserError(f"malformed maze metadata ({type(e).__name__}: {e})") from None
    _check_tasks(maze)
    return maze


def _check_tasks(maze: Maze) -> None:
    for s, g in maze.tasks:
        for rc in (s, g):
            if maze.is_wall(np.array(rc)):
                raise UserError(f"maze {maze.name}: task cell {tuple(rc)} is a wall")


def world_maze(spec: dict | None, metadata: dict | None = None) -> Maze | None:
    """The maze a dataset was flown in, or None for free space.

    ``spec`` is the dataset's spec (its ``world``: ``free`` (the default when absent) or
    ``maze-<name>``); the layout is the one recorded in the dataset (``maze`` in the spec
    or in ``metadata``, :meth:`Maze.to_dict` data) when there is one, else the packaged
    maze of that name. UserError for an unknown world or maze."""
    spec = spec or {}
    world = str(spec.get("world") or "free")
    if world == "free":
        return None
    if not world.startswith("maze-"):
        raise UserError(f"unknown world {world!r} (choose from {', '.join(WORLDS)})")
    recorded = spec.get("maze") or (metadata or {}).get("maze")
    if isinstance(recorded, dict):
        return maze_from_dict(recorded)
    return load_maze(world[len("maze-") :])


@functools.cache
def load_maze(name: str) -> Maze:
    """The maze ``name`` (one of :data:`MAZES`) from its data file; UserError for an unknown one."""
    path = MAZE_DIR / f"{name}.toml"
    if name not in MAZES or not path.is_file():
        raise UserError(f"unknown maze {name!r} (choose from {', '.join(MAZES)})")
    d = tomllib.loads(path.read_text())
    walls = parse_layout(d["layout"])
    tasks = tuple((tuple(t["start"]), tuple(t["goal"])) for t in d["tasks"])
    maze = Maze(
        name=name,
        walls=walls,
        cell=float(d["cell"]),
        ceiling=float(d["ceiling"]),
        altitude=float(d["altitude"]),
        tasks=tasks,  # type: ignore[arg-type]  # pairs of (row, col) read from TOML
        tasks_version=int(d["tasks_version"]),
    )
    _check_tasks(maze)
    return maze


__all__ = [
    "Maze",
    "MAZES",
    "WORLDS",
    "maze_from_dict",
    "world_maze",
    "VEHICLE_RADIUS",
    "MAZE_DIR",
    "load_maze",
    "parse_layout",
    "corners",
]
