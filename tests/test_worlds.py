"""Maze layouts, collision checks and the cell graph (aerohrl.worlds)."""

from __future__ import annotations

import numpy as np
import pytest

from aerohrl.errors import UserError
from aerohrl.worlds import MAZES, VEHICLE_RADIUS, corners, load_maze
from aerohrl.worlds.maze import parse_layout


@pytest.mark.parametrize("name", MAZES)
def test_layout_connected_and_tasks_far_apart(name):
    m = load_maze(name)
    d = m.distances()
    assert np.isfinite(d).all(), "every free cell reaches every other"
    diameter = d.max()
    assert len(m.tasks) == 5
    for s, g in m.tasks:
        i, j = m.cell_index(np.array([s, g]))
        assert d[i, j] >= 0.6 * diameter
        path = m.shortest_path(s, g)
        assert len(path) == d[i, j] + 1
        assert (np.abs(np.diff(path, axis=0)).sum(1) == 1).all(), "4-connected steps"
        assert not m.is_wall(path).any()


def test_collision_sphere_against_a_wall_floor_and_ceiling():
    m = load_maze("medium")
    free = (1, 1)
    c = m.cell_center(np.array(free))
    assert not m.collides(c)
    # (0, 1) is a wall: the cell's south face is at y = cell
    south_face = m.cell
    p = np.array([c[0], south_face + VEHICLE_RADIUS + 1e-3, c[2]])
    q = np.array([c[0], south_face + VEHICLE_RADIUS - 1e-3, c[2]])
    assert not m.collides(p) and m.collides(q)
    assert m.collides(np.array([c[0], c[1], VEHICLE_RADIUS - 0.01]))
    assert m.collides(np.array([c[0], c[1], m.ceiling - VEHICLE_RADIUS + 0.01]))
    # batched, any leading shape; outside the grid is a wall
    pts = np.stack([c, q, np.array([-5.0, -5.0, 1.5])]).reshape(1, 3, 3)
    assert m.collides(pts).tolist() == [[False, True, True]]
    # a convex wall corner: cell (2, 2)'s north and west neighbours are free, its north-west
    # neighbour (3, 1) a wall; the distance is to that box's corner point
    assert not m.walls[3, 2] and not m.walls[2, 1] and m.walls[3, 1]
    p = np.array([2 * m.cell + 0.1, 3 * m.cell - 0.1, 1.5])
    assert m.wall_distance(p) == pytest.approx(np.hypot(0.1, 0.1))


def test_corners_keep_turns_and_ends():
    path = np.array([[1, 1], [1, 2], [1, 3], [2, 3], [3, 3], [3, 4]])
    assert corners(path).tolist() == [[1, 1], [1, 3], [3, 3], [3, 4]]


def test_bad_mazes_and_cells_are_one_line_errors():
    with pytest.raises(UserError, match="unknown maze"):
        load_maze("huge")
    with pytest.raises(UserError, match="enclosed"):
        parse_layout("#.#\n###\n###")
    with pytest.raises(UserError, match="only"):
        parse_layout("###\n#x#\n###")
    m = load_maze("large")
    with pytest.raises(UserError, match="is a wall"):
        m.shortest_path((0, 0), (1, 1))


def test_metadata_round_trips_the_layout():
    m = load_maze("giant")
    d = m.to_dict()
    assert (parse_layout("\n".join(d["layout"])) == m.walls).all()
    assert d["vehicle_radius"] == VEHICLE_RADIUS and len(d["tasks"]) == 5


def test_corridor_legs_follow_free_rows_and_columns():
    m = load_maze("large")
    c = m.cell_center
    # row 1 is "#....#.....#": columns 1-4 are one free corridor, column 5 a wall
    assert m.in_corridor(c(np.array([1, 1])), c(np.array([1, 4])))
    assert not m.in_corridor(c(np.array([1, 4])), c(np.array([1, 6])))  # through the wall at (1, 5)
    assert not m.in_corridor(c(np.array([1, 1])), c(np.array([3, 2])))  # no shared row or column
    # column 1 is free from row 1 to row 7
    assert m.in_corridor(c(np.array([7, 1])), c(np.array([1, 1])))
    assert m.in_corridor(c(np.array([3, 3])), c(np.array([3, 3])))  # a cell with itself
    # batched and broadcast: (2, 1, 3) against (1, 2, 3); outside the grid is no corridor
    p = np.stack([c(np.array([1, 1])), np.array([-1.0, 3.0, 1.5])])[:, None]
    q = np.stack([c(np.array([1, 3])), c(np.array([5, 1]))])[None]
    assert m.in_corridor(p, q).tolist() == [[True, True], [False, False]]


def test_segment_clear_refuses_legs_through_walls_and_keeps_corridors():
    m = load_maze("large")
    c = m.cell_center
    # row 1 is "#....#.....#": (1, 4) -> (1, 6) passes through the wall cell (1, 5)
    assert not m.segment_clear(c(np.array([1, 4])), c(np.array([1, 6])))
    assert m.segment_clear(c(np.array([1, 1])), c(np.array([1, 4])))
    # along a corridor but 0.2 m from its wall: the 0.25 m sphere touches it
    p = c(np.array([1, 1])) + [0.0, 1.0 - 0.2, 0.0]
    assert not m.segment_clear(p, p + [4.0, 0.0, 0.0])
    assert m.segment_clear(p, p + [4.0, 0.0, 0.0], radius=0.1)
    # every corridor leg between free cells' centres is clear (the converse does not hold:
    # diagonals across open areas are clear too); batched and broadcast
    f = c(m.free_cells)
    clear, corridor = m.segment_clear(f[:, None], f[None]), m.in_corridor(f[:, None], f[None])
    assert clear.shape == corridor.shape and (clear | ~corridor).all()
    assert m.segment_clear(f[:, None], f[None], chunk=1000).tolist() == clear.tolist()
