"""experiments/hiql_subgoals.py: a goal-space HIQL's subgoals read back as positions, on a maze dataset."""

import numpy as np
import pytest
from conftest import load_experiment, train_tiny

hs = load_experiment("hiql_subgoals")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    from aerohrl.algorithms.synthetic import straight_columns, write_synthetic_dataset

    root = tmp_path_factory.mktemp("hiqlsub")
    maze = write_synthetic_dataset(root / "ds", straight_columns(seed=2), version="synthetic-maze", spec={"world": "maze-medium"})
    hiql = dict(algo="hiql", hiql_subgoal_space="goal", hiql_subgoal_steps=5)
    return {
        name: train_tiny(root / name, maze, pos_octaves=2, **kw) for name, kw in (("hiql", hiql), ("gcsl", dict(algo="gcsl")))
    }


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
