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

    @functools.cached_property
    def _neighbour_walls(self) -> np.ndarray:
        """(rows * cols, 8) per cell (row-major): 0 where its neighbour (W, E, S, N, SW, SE,
        NW, NE) is a wall or outside the grid, inf where it is free."""
        rows, cols = self.shape
        rc = np.stack(np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij"), axis=-1).reshape(-1, 2)
        offsets = np.array([(0, -1), (0, 1), (-1, 0), (1, 0), (-1, -1), (-1, 1), (1, -1), (1, 1)])  # (dr, dc)
        wall = self.is_wall(rc[:, None, :] + offsets)
        return np.where(wall, 0.0, np.inf)

    def _wall_distance_sq(self, p: np.ndarray) -> np.ndarray:
        """Squared :meth:`wall_distance` (the collision test compares it with radius^2)."""
        x, y = p[..., 0] / self.cell, p[..., 1] / self.cell
        c, r = np.floor(x), np.floor(y)
        rows, cols = self.shape
        inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
        flat = np.where(inside, r * cols + c, 0).astype(np.int64)
        solid = ~inside | self.walls.reshape(-1)[flat]  # in a wall cell or outside the grid: distance 0
        # distances to the four sides of the point's cell, squared; a corner is the sum of two
        u0, v0 = (x - c) * self.cell, (y - r) * self.cell
        u1, v1 = self.cell - u0, self.cell - v0
        u0, u1, v0, v1 = u0 * u0, u1 * u1, v0 * v0, v1 * v1
        d = np.stack([u0, u1, v0, v1, u0 + v0, u1 + v0, u0 + v1, u1 + v1], axis=-1)
        return np.where(solid, 0.0, (d + self._neighbour_walls[flat]).min(axis=-1))

    def wall_distance(self, p: np.ndarray) -> np.ndarray:
        """(...) horizontal distance (m) from points ``p`` (..., 3) to the nearest wall box.

        For a point in a free cell only the 8 neighbouring cells can hold the nearest wall (a
        wall farther away is at least one cell, ``cell`` > any radius asked about, away): a
        side neighbour's box is as far as the cell's side, a corner neighbour's as the cell's
        corner. Which neighbours are walls is tabulated per cell once (:attr:`_neighbour_walls`),
        so a query is a table lookup and eight squared distances. Inside a wall the distance is 0."""
        p = np.asarray(p, dtype=np.float64)
        return np.sqrt(self._wall_distance_sq(p))

    @functools.cached_property
    def _walls_before(self) -> tuple[np.ndarray, np.ndarray]:
        """Prefix counts of wall cells along each row (rows, cols + 1) and each column (rows + 1, cols)."""
        w = self.walls.astype(np.int64)
        row = np.concatenate([np.zeros((w.shape[0], 1), np.int64), w.cumsum(1)], axis=1)
        col = np.concatenate([np.zeros((1, w.shape[1]), np.int64), w.cumsum(0)], axis=0)
        return row, col

    def in_corridor(self, p: np.ndarray, q: np.ndarray) -> np.ndarray:
        """(...) bool: the cells under ``p`` and ``q`` (..., 3, broadcast) share a row or a
        column and every cell from one to the other is free, so that a flight along the
        cells' centre line meets no wall (a straight corridor leg, as the expert flies
        between its corners). A point outside the grid is in no corridor."""
        a, b = self.cell_of(p), self.cell_of(q)
        a, b = np.broadcast_arrays(a, b)
        rows, cols = self.shape
        inside = (a[..., 0] >= 0) & (a[..., 0] < rows) & (a[..., 1] >= 0) & (a[..., 1] < cols)
        inside &= (b[..., 0] >= 0) & (b[..., 0] < rows) & (b[..., 1] >= 0) & (b[..., 1] < cols)
        r0, c0 = np.clip(a[..., 0], 0, rows - 1), np.clip(a[..., 1], 0, cols - 1)
        r1, c1 = np.clip(b[..., 0], 0, rows - 1), np.clip(b[..., 1], 0, cols - 1)
        row, col = self._walls_before
        lo, hi = np.minimum(c0, c1), np.maximum(c0, c1)
        same_row = (r0 == r1) & (row[r0, hi + 1] - row[r0, lo] == 0)
        lo, hi = np.minimum(r0, r1), np.maximum(r0, r1)
        same_col = (c0 == c1) & (col[hi + 1, c0] - col[lo, c0] == 0)
        return inside & (same_row | same_col)

    def collides(self, p: np.ndarray, radius: float = VEHICLE_RADIUS) -> np.ndarray:
        """(...) bool: a sphere of ``radius`` at ``p`` (..., 3) touches a wall, the floor or the ceiling."""
        p = np.asarray(p, dtype=np.float64)
        return (self._wall_distance_sq(p) < radius * radius) | (p[..., 2] < radius) | (p[..., 2] > self.ceiling - radius)

    def segment_clear(
        self, p: np.ndarray, q: np.ndarray, radius: float = VEHICLE_RADIUS, step: float = 0.1, chunk: int = 1 << 20
    ) -> np.ndarray:
        """(...) bool: a sphere of ``radius`` moved in a straight line from ``p`` to ``q``
        (..., 3, broadcast) touches no wall, floor or ceiling, tested at points ``step`` m
        apart along the segment (both ends included; between two samples a corner can cut
        into the sphere by at most ``step^2 / (8 radius)``). Legs between states anywhere in
        the maze, where :meth:`in_corridor` knows only the cells' centre lines. Pairs are
        tested ``chunk`` sample points at a time."""
        p, q = np.broadcast_arrays(np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64))
        shape = p.shape[:-1]
        p, q = p.reshape(-1, 3), q.reshape(-1, 3)
        length = np.linalg.norm(q - p, axis=-1)
        k = int(np.ceil(length.max(initial=0.0) / step)) + 1
        t = np.linspace(0.0, 1.0, max(k, 2))
        ok = np.empty(len(p), bool)
        rows = max(1, chunk // len(t))
        for i in range(0, len(p), rows):
            a, b = p[i : i + rows, None], q[i : i + rows, None]
            ok[i : i + rows] = ~self.collides(a + (b - a) * t[:, None], radius).any(axis=-1)
        return ok.reshape(shape)

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
