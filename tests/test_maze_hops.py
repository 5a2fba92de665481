"""experiments/maze_hops.py: the one-cell hop test of a maze skill."""

import numpy as np
import pytest
from conftest import load_experiment, train_tiny

mh = load_experiment("maze_hops")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    from aerohrl.algorithms.synthetic import straight_columns, write_synthetic_dataset

    root = tmp_path_factory.mktemp("hops")
    maze = write_synthetic_dataset(root / "m", straight_columns(seed=2), version="synthetic-maze", spec={"world": "maze-medium"})
    free = write_synthetic_dataset(root / "f", straight_columns(seed=3), version="synthetic-free")
    return {name: train_tiny(root / name, ds, algo="gcsl") for name, ds in (("maze", maze), ("free", free))}


def test_adjacent_pairs_are_distinct_free_neighbours():
    from aerohrl.worlds import load_maze

    maze = load_maze("large")
    a, b = mh.adjacent_pairs(maze, np.random.default_rng(0), 40)
    assert (np.abs(a - b).sum(axis=1) == 1).all() and not maze.is_wall(a).any() and not maze.is_wall(b).any()
    assert len({(tuple(x), tuple(y)) for x, y in zip(a, b)}) == 40
    with pytest.raises(Exception, match="adjacent cell pairs"):
        mh.adjacent_pairs(maze, np.random.default_rng(0), 10**6)


def test_hops_fly_and_free_space_is_a_one_line_error(runs, capsys):
    f = mh.fly_hops(runs["maze"], hops=8, seconds=0.5, seed=0)
    assert f["hops"] == 8
    assert all(0 <= f[k] <= 1 for k in ("reached", "collided", "hovering_short"))
    assert f["closest_median"] >= 0 and f["speed_at_closest_median"] >= 0
    assert f["closest_median"] <= 2.05  # about the start at worst (2 m away; one step of drift)
    assert mh.main(["--run", str(runs["free"])]) == 2
    err = capsys.readouterr().err.strip()
    assert "needs a maze" in err and "\n" not in err
