"""The oracle bound of the single-goal planner (planning/oracle.py), with a policy that hovers
in place, so which legs succeed is known by hand."""

import numpy as np
import pytest

from aerohrl.algorithms.data import load_dataset
from aerohrl.envs.episodes import hover_states
from aerohrl.planning.oracle import oracle_single, roc_auc

from test_eval_planner import FakeAlgo


def test_roc_auc_by_hand():
    assert roc_auc(np.array([0.1, 0.4, 0.35, 0.8]), np.array([0, 0, 1, 1])) == 0.75
    assert roc_auc(np.array([1.0, 2.0]), np.array([1, 1])) != roc_auc(np.array([1.0, 2.0]), np.array([1, 1]))  # nan
    assert roc_auc(np.array([0.5, 0.5, 0.5]), np.array([0, 1, 0])) == 0.5  # ties count half


def test_oracle_with_a_hovering_policy():
    # achieved states: hover at the origin and hover at three other points
    pts = np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0], [0, 0, -1.0]])
    nxt = hover_states(4)
    nxt[:, :3] = pts
    cols = {
        "observation.state": hover_states(4),
        "action": np.tile([9.81, 0, 0, 0], (4, 1)),
        "observation.desired_goal": nxt[:, :15],
        "next.observation.state": nxt,
        "episode_index": np.zeros(4, np.int64),
    }
    data = load_dataset(cols)
    G = nxt[[0, 1, 2], :15].copy()  # goals: hover at the origin, at (1,0,0), at (0,1,0)
    r = oracle_single(FakeAlgo(), data, G, candidates=0, leg_horizon=20)
    assert r["goals"] == 3 and r["candidates"] == 4
    assert r["first_leg_success"] == pytest.approx(0.25)  # hovering reaches only the origin
    assert r["second_leg_success"] == pytest.approx(3 / 12)  # each goal from its own point only
    assert r["goals_with_a_working_second_leg"] == 1.0
    assert r["oracle"] == pytest.approx(1 / 3)  # only the origin goal has both legs working
    assert 0.0 <= r["planner"] <= r["oracle"]
    # the fake critics are exp(-k d): they rank the working (d = 0) second legs highest
    assert r["auc_second_leg_value"] == 1.0
    assert r["second_leg_by_distance"]["0-1 m"]["success"] == 1.0
