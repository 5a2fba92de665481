"""Episode sets of the evaluation tasks (docs/spec.md "Evaluation tasks")."""

import numpy as np
import pytest

from aerohrl import task
from aerohrl.algorithms.data import load_dataset
from aerohrl.algorithms.synthetic import straight_columns
from aerohrl.errors import UserError
from aerohrl.eval import tasks as T


@pytest.fixture(scope="module")
def data():
    return load_dataset(straight_columns(n_eps=6, length=[80, 60, 120, 50, 90, 70]))


def test_reach_desired_flies_every_goal_once_in_order(data):
    eps = T.reach_desired(data, n=6)
    assert np.array_equal(eps.goals, data.desired_goals().numpy().astype(np.float64))
    assert (eps.horizons == 500).all() and np.allclose(eps.start_states, T.hover_states(6))
    more = T.reach_desired(data, n=10, seed=3)
    assert len(more) == 10 and set(more.source_episode[:6]) == set(range(6))
    fewer = T.reach_desired(data, n=4, seed=3)
    assert len(set(fewer.source_episode)) == 4


def test_reach_intermediate_follows_spec(data):
    eps = T.reach_intermediate(data, n=300, seed=1)
    st = data.state.numpy().astype(np.float64)
    ns = data.next_state.numpy().astype(np.float64)
    ends = np.unique(data.episode_end.numpy())
    starts = np.concatenate([[0], ends[:-1] + 1])
    frame = starts[eps.source_episode] + eps.start_frame
    assert np.array_equal(eps.start_states, st[frame])
    desired = eps.steps_ahead == 0
    assert desired.sum() == 100 and desired[:100].all()  # one third, 500 steps, the trajectory's desired goal
    assert (eps.horizons[desired] == 500).all() and (eps.horizons[~desired] == 100).all()
    assert np.array_equal(eps.goals[desired], data.goal.numpy().astype(np.float64)[frame[desired]])
    d = eps.steps_ahead[~desired]
    assert d.min() >= 1 and d.max() <= 45
    gi = frame[~desired] + d - 1
    assert (gi <= ends[eps.source_episode[~desired]]).all()  # same trajectory
    assert np.array_equal(eps.goals[~desired], task.achieved_goal(ns[gi]))
    again = T.reach_intermediate(data, n=300, seed=1)
    assert np.array_equal(again.goals, eps.goals)
    assert not np.array_equal(T.reach_intermediate(data, n=300, seed=2).goals, eps.goals)


def test_ood_goals_outside_rho_d(data):
    eps = T.ood(data, n=250, seed=0)
    p = np.abs(eps.goals[:, :3])
    assert p.min() >= 2.0 and p.max() <= 3.5
    assert (eps.goals[:, 3:6] >= -2.5).all() and (eps.goals[:, 3:6] <= 2.5).all()
    R = eps.goals[:, 6:15].reshape(-1, 3, 3)
    assert np.allclose(R @ R.transpose(0, 2, 1), np.eye(3), atol=1e-9)
    assert np.array_equal(T.ood(data, 250, 0).goals, eps.goals)
    assert not np.array_equal(T.ood(data, 250, 1).goals, eps.goals)
    assert (eps.horizons == 1000).all()  # 2 legs of 500 steps by default


def test_reach_novel_draws_new_goals_from_rho_d(tmp_path):
    """reach-novel: fresh goals from the dataset spec's own ranges, never the dataset's goals."""
    from aerohrl.algorithms.data import load_dataset as load
    from aerohrl.datagen.build import build
    from aerohrl.datagen.spec import DatasetSpec

    root = build(DatasetSpec(goals=6, seed=0), tmp_path, progress=False, log=lambda *a: None).path
    real = load(root)
    eps = T.make_episodes("reach-novel", real, 200, seed=0)
    p = np.abs(eps.goals[:, :3])
    assert p.min() >= 1.0 and p.max() <= 2.0 and (eps.horizons == 500).all()
    assert np.allclose(eps.start_states, T.hover_states(200))
    desired = real.desired_goals().numpy().astype(np.float64)
    assert np.abs(eps.goals[:, None, :] - desired[None]).max(-1).min() > 1e-3  # none is a training goal
    assert np.array_equal(T.make_episodes("reach-novel", real, 200, seed=0).goals, eps.goals)
    assert not np.array_equal(T.make_episodes("reach-novel", real, 200, seed=1).goals, eps.goals)
    assert not np.array_equal(T.ood(real, 200, 0).goals[:, 3:], eps.goals[:, 3:])  # another stream than ood


def test_bad_input(data):
    with pytest.raises(UserError, match="unknown task"):
        T.make_episodes("reach-far", data)
    with pytest.raises(UserError, match="positive"):
        T.make_episodes("reach-desired", data, n=0)
