"""A hierarchical agent's high level as the planner's candidate source (planning/subgoals.py)."""

from __future__ import annotations

import math

import pytest
import torch

from aerohrl.planning.subgoals import SubgoalPlanner
from test_graph_planner import LineCritics, _candidates, _state


class StepAhead(LineCritics):
    """A high level that proposes the state one metre further along x: representations are
    angles on a circle of norm sqrt(2), phi(s, g) = e(g_x / 10), z(s, G) = e((s_x + 1) / 10)."""

    @staticmethod
    def _e(x):
        return math.sqrt(2) * torch.stack([torch.cos(x / 10), torch.sin(x / 10)], -1)

    def subgoals(self, s, g):
        return self._e(s[:, 0] + 1.0)

    def goal_representation(self, s, g):
        return self._e(g[:, 0])


def test_subgoals_snap_to_the_closest_candidate_and_chain():
    planner = SubgoalPlanner(StepAhead(reach=10.0), _candidates([3.0, 1.0, 5.0, 2.0, 4.0]), n=3)
    p = planner.plan(_state([0.0, 2.0]), _state([6.0, 6.0])[:, :15])
    assert p.goals[..., 0].tolist() == [[1.0, 2.0, 3.0], [3.0, 4.0, 5.0]]
    assert p.index[0].tolist() == [1, 3, 0] and p.frame[0].tolist() == [1, 3, 0]
    # the reported score is the product of the legs' critic values: 0 -> 1 -> 2 -> 3 -> 6
    assert p.score[0] == pytest.approx(0.9**6, rel=1e-5) and p.direct_score[0] == pytest.approx(0.9**6, rel=1e-5)


class StepAheadRaw(LineCritics):
    """The same high level in an unnormalised space (``hiql_subgoal_space = "goal"``): the
    proposal is the x one metre on, a candidate's representation its own x."""

    def subgoals(self, s, g):
        return s[:, :1] + 1.0

    def goal_representation(self, s, g):
        return g[:, :1]


def test_unnormalised_subgoals_snap_to_the_nearest_candidate_not_the_largest():
    planner = SubgoalPlanner(StepAheadRaw(reach=10.0), _candidates([3.0, 1.0, 5.0, 2.0, 4.0]), n=2)
    p = planner.plan(_state([0.0, 2.0]), _state([6.0, 6.0])[:, :15])
    assert p.goals[..., 0].tolist() == [[1.0, 2.0], [3.0, 4.0]]


def test_min_leg_skips_candidates_at_the_start_for_the_first_choice_only():
    planner = SubgoalPlanner(StepAhead(reach=10.0), _candidates([1.0, 2.0, 3.0]), n=2, min_leg=1.5)
    p = planner.plan(_state([0.0]), _state([6.0])[:, :15])
    assert p.goals[0, :, 0].tolist() == [2.0, 3.0]


def test_an_agent_without_a_high_level_is_refused():
    with pytest.raises(ValueError, match="needs an agent with a high-level policy"):
        SubgoalPlanner(LineCritics(), _candidates([1.0]))
    with pytest.raises(ValueError, match="empty"):
        SubgoalPlanner(StepAhead(), _candidates([]))
