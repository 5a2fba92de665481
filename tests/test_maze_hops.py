"""experiments/maze_hops.py: the one-cell hop test of a maze skill."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

spec = importlib.util.spec_from_file_location("maze_hops", Path(__file__).parents[1] / "experiments" / "maze_hops.py")
mh = importlib.util.module_from_spec(spec)
spec.loader.exec_module(mh)

TINY = dict(hidden=(16, 16), critic_hidden=(16, 16), batch_size=32, steps=20, log_every=10, checkpoint_every=20, eval_every=0)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    from aerohrl.algorithms.config import make_config
    from aerohrl.algorithms.synthetic import straight_columns, write_synthetic_dataset
    from aerohrl.algorithms.trainer import start_run

    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("hops")
    maze = write_synthetic_dataset(root / "m", straight_columns(seed=2), version="synthetic-maze", spec={"world": "maze-medium"})
    free = write_synthetic_dataset(root / "f", straight_columns(seed=3), version="synthetic-free")
    out = {}
    for name, ds in (("maze", maze), ("free", free)):
        start_run(make_config("cpu", dataset=str(ds), algo="gcsl", **TINY), root / name, progress=False).train()
        out[name] = root / name
    return out


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
