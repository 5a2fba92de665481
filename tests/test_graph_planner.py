"""The graph planner: Eq. 3.6 by shortest paths over the candidates (planning/graph.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from aerohrl.planning.graph import GraphPlanner, leg_lengths
from aerohrl.planning.planner import Candidates


class LineCritics(nn.Module):
    """Critics that know a corridor along x: a leg of length d <= reach is worth 0.9^d (every
    critic alike), a longer one 0 (a wall in the way). The optimum from x = 0 to x = 6 with
    candidates at every integer is therefore a chain of unit legs."""

    def __init__(self, reach: float = 1.5, m: int = 5):
        super().__init__()
        self.w = nn.Parameter(torch.zeros(1))
        self.reach, self.m = reach, m

    def act(self, s, g):
        return torch.zeros(len(s), 4)

    def critics(self, s, g, a):
        d = (g[:, 0] - s[:, 0]).abs()
        v = torch.where(d <= self.reach, 0.9**d, torch.zeros_like(d))
        return v.expand(self.m, -1)


def _state(x):
    s = torch.zeros(len(x), 18)
    s[:, 0] = torch.as_tensor(x, dtype=torch.float32)
    s[:, 6] = s[:, 10] = s[:, 14] = 1.0
    return s


def _candidates(xs):
    st = _state(xs)
    return Candidates(st[:, :15].clone(), st, np.arange(len(xs)))


def test_leg_lengths_are_minus_log_of_the_penalised_value():
    v = torch.tensor([[0.5, 0.9], [0.7, 0.9]])  # 2 critics x 2 legs
    mean, var = torch.tensor([0.6, 0.9]), torch.tensor([0.01, 0.0])
    expect = -torch.log(mean - 2.0 * var)
    assert torch.allclose(leg_lengths(v, alpha=2.0), expect)
    assert leg_lengths(v, alpha=0.0, min_leg_value=0.7)[0].item() == float("inf")


def test_plan_is_the_chain_of_short_legs_and_beats_the_blocked_straight_leg():
    algo = LineCritics()
    planner = GraphPlanner(algo, _candidates([3.0, 1.0, 5.0, 2.0, 4.0]), n=3, alpha=0.0)
    s0, G = _state([0.0, 0.0]), _state([6.0, 2.0])[:, :15]
    p = planner.plan(s0, G)
    xs = p.goals[..., 0]
    assert xs[0].tolist() == [1.0, 2.0, 3.0]  # the first three legs of 0 -> 1 -> ... -> 5 -> 6
    assert p.score[0] == pytest.approx(0.9**6, rel=1e-5)
    assert p.direct_score[0] == pytest.approx(0.0, abs=1e-5)  # the straight leg is blocked
    # a goal 2 m away: one intermediate goal; the plan is padded by repeating it
    assert xs[1].tolist() == [1.0, 1.0, 1.0] and p.depth[1] == 1


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="empty"):
        GraphPlanner(LineCritics(), _candidates([]))
    with pytest.raises(ValueError, match=r"\[0, 1\)"):
        GraphPlanner(LineCritics(), _candidates([1.0]), min_leg_value=1.0)


def test_an_edge_filter_removes_the_legs_it_refuses():
    # any leg reaches (reach 10): the best plan is the straight leg; a filter that refuses
    # legs across x = 2.5 except from the candidate at 2 to the one at 3 forces that gate
    algo = LineCritics(reach=10.0)

    def gate(p, q):
        a, b = p[..., 0], q[..., 0]
        crosses = (np.minimum(a, b) < 2.5) & (np.maximum(a, b) > 2.5)
        return ~crosses | ((a == 2.0) & (b == 3.0))

    free = GraphPlanner(algo, _candidates([2.0, 3.0, 4.0]), n=2, alpha=0.0)
    gated = GraphPlanner(algo, _candidates([2.0, 3.0, 4.0]), n=2, alpha=0.0, edge_filter=gate)
    s0, G = _state([0.0]), _state([5.0])[:, :15]
    assert free.plan(s0, G).score[0] == pytest.approx(0.9**5, rel=1e-5)
    p = gated.plan(s0, G)
    assert p.goals[0, :, 0].tolist() == [2.0, 3.0]  # 0 -> 2 -> 3 (-> 5): through the gate
    assert p.score[0] == pytest.approx(0.9**5, rel=1e-5)  # the same length, now the only way


class DistanceCritics(nn.Module):
    """Critics blind to walls: a leg of horizontal length d is worth 0.9^d."""

    def __init__(self, m: int = 5):
        super().__init__()
        self.w = nn.Parameter(torch.zeros(1))
        self.m = m

    def act(self, s, g):
        return torch.zeros(len(s), 4)

    def critics(self, s, g, a):
        return (0.9 ** torch.linalg.norm(g[:, :2] - s[:, :2], dim=-1)).expand(self.m, -1)


def test_states_anywhere_in_a_maze_are_joined_by_clear_legs_only():
    """Waypoints at dataset-like states (scattered in the free cells): with the maze's
    segment test as the edge filter, the critics' shortcut through the walls is refused and
    every leg of the plan, the first and the last included, is clear."""
    from aerohrl.worlds.maze import load_maze

    m = load_maze("medium")
    rng = np.random.default_rng(0)
    free = np.repeat(m.free_cells, 3, axis=0)
    pts = m.cell_center(free) + np.c_[rng.uniform(-0.5, 0.5, (len(free), 2)), np.zeros(len(free))]
    st = torch.zeros(len(pts), 18)
    st[:, :3] = torch.as_tensor(pts, dtype=torch.float32)
    st[:, 6] = st[:, 10] = st[:, 14] = 1.0
    cand = Candidates(st[:, :15].clone(), st, np.arange(len(pts)))
    algo = DistanceCritics()
    (s_rc, g_rc) = m.tasks[0]
    s0 = torch.zeros(1, 18)
    s0[0, :3] = torch.as_tensor(m.cell_center(np.array(s_rc)))
    s0[0, 6] = s0[0, 10] = s0[0, 14] = 1.0
    G = torch.zeros(1, 15)
    G[0, :3] = torch.as_tensor(m.cell_center(np.array(g_rc)))
    G[0, 6] = G[0, 10] = G[0, 14] = 1.0
    blind = GraphPlanner(algo, cand, n=40, alpha=0.0, max_edge=2.5).plan(s0, G)
    p = GraphPlanner(algo, cand, n=40, alpha=0.0, max_edge=2.5, edge_filter=m.segment_clear).plan(s0, G)
    d = int(p.depth[0])
    path = np.concatenate([s0[:, :3].numpy(), p.goals[0, :d, :3], G[:, :3].numpy()])
    assert m.segment_clear(path[:-1], path[1:]).all()
    bp = np.concatenate([s0[:, :3].numpy(), blind.goals[0, : int(blind.depth[0]), :3], G[:, :3].numpy()])
    assert not m.segment_clear(bp[:-1], bp[1:]).all()  # without the filter a leg cuts through a wall
    assert p.score[0] < blind.score[0]  # the detour is longer than the wall-blind path
    # a goal no clear leg reaches: the plan is the straight leg, its waypoints the goal itself
    far = G.clone()
    far[0, 0] = -5.0
    q = GraphPlanner(algo, cand, n=3, alpha=0.0, max_edge=2.5, edge_filter=m.segment_clear).plan(s0, far)
    assert (q.frame[0] == -1).all() and np.allclose(q.goals[0], far.numpy().astype(np.float64))
