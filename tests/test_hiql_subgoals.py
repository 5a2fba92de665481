"""experiments/hiql_subgoals.py: a goal-space HIQL's subgoals read back as positions, on a maze dataset."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

spec = importlib.util.spec_from_file_location("hiql_subgoals", Path(__file__).parents[1] / "experiments" / "hiql_subgoals.py")
hs = importlib.util.module_from_spec(spec)
spec.loader.exec_module(hs)

TINY = dict(hidden=(16, 16), critic_hidden=(16, 16), batch_size=32, steps=20, log_every=10, checkpoint_every=20, eval_every=0)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    from aerohrl.algorithms.config import make_config
    from aerohrl.algorithms.synthetic import straight_columns, write_synthetic_dataset
    from aerohrl.algorithms.trainer import start_run

    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("hiqlsub")
    maze = write_synthetic_dataset(root / "ds", straight_columns(seed=2), version="synthetic-maze", spec={"world": "maze-medium"})
    out = {}
    for name, kw in (("hiql", dict(algo="hiql", hiql_subgoal_space="goal", hiql_subgoal_steps=5)), ("gcsl", dict(algo="gcsl"))):
        start_run(make_config("cpu", dataset=str(maze), pos_octaves=2, **kw, **TINY), root / name, progress=False).train()
        out[name] = root / name
    return out


def test_subgoal_positions_invert_the_goal_columns(runs):
    """Handed the goal columns of a known state as its subgoal, the read-back gives that state's position."""
    from aerohrl.algorithms.base import load_policy
    from aerohrl.algorithms.run import Run
    from aerohrl.eval.harness import load_run_dataset, run_checkpoints

    run = Run.open(runs["hiql"], kind="train")
    algo, _ = load_policy(run_checkpoints(run, 1)[-1], "cpu", run)
    data, _ = load_run_dataset(run)
    state, target = data.state[:50], data.state[20:70, :15]
    algo.subgoals = lambda s, g: algo.goal_representation(s, g)  # a high level that proposes the goal itself
    got = hs.subgoal_positions(algo, state, target)
    np.testing.assert_allclose(got, target[:, :3].double().numpy(), atol=1e-4)


def test_study_gives_shares_and_refuses_other_agents(runs, capsys):
    f = hs.study(runs["hiql"], frames=60, seed=0)
    assert f["frames"] == 60 and f["k"] == 5
    assert all(0 <= f[k] <= 1 for k in ("proposed_in_wall", "data_in_wall", "moving_frames")) and f["median_error"] >= 0
    assert hs.main(["--run", str(runs["gcsl"])]) == 2
    err = capsys.readouterr().err.strip()
    assert "not a HIQL run with --hiql-subgoal-space goal" in err and "\n" not in err


def test_closed_loop_reads_the_subgoals_along_the_flights(runs):
    f = hs.closed_loop(runs["hiql"], flights=5, seed=0)
    assert f["flights"] == 5
    assert all(0 <= f[k] <= 1 for k in ("success", "crashed", "in_wall_flown"))
    assert f["crashed"] == 0 or 0 <= f["in_wall_before_crash"] <= 1
