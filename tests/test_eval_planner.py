"""Planner (thesis Eq. 3.7, Eq. 3.6 by beam search) and the batched rollout, with a
hand-made policy/critic whose values are known in closed form."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from torch import nn

from aerohrl.envs.episodes import EpisodeSet, hover_states
from aerohrl.envs.rollout import rollout
from aerohrl.planning.planner import Candidates, Planner, leg_values

KS = torch.tensor([0.5, 1.0, 2.0])  # one length scale per critic: they disagree far away


class FakeAlgo(nn.Module):
    """act: hover; critic j: exp(-k_j |p_g - p|) (+ 0 * action so the action path is used)."""

    def __init__(self):
        super().__init__()
        self.w = nn.Parameter(torch.zeros(()))
        self.cfg = SimpleNamespace(num_critics=len(KS))
        self.normalizer = SimpleNamespace(act_center=torch.tensor([9.81, 0, 0, 0]), act_half=torch.tensor([9.0, 3, 3, 3]))

    def act(self, s, g):
        return torch.tensor([9.81, 0.0, 0.0, 0.0]).expand(len(s), 4) + 0 * self.w

    def critics(self, s, g, a):
        d = (g[:, :3] - s[:, :3]).norm(dim=1)
        return torch.exp(-KS[:, None] * d[None]) + 0 * a.sum(1)


def _cands(rng, C):
    st = hover_states(C)
    st[:, :3] = rng.uniform(-3, 3, (C, 3))
    st[:, 3:6] = rng.uniform(-1, 1, (C, 3))
    t = torch.as_tensor(st, dtype=torch.float32)
    return Candidates(t[:, :15].clone(), t.clone(), np.arange(C) + 100)


def _q(a, b):  # (m, ..) critic values between positions a (..., 3) and b (..., 3)
    d = np.linalg.norm(np.asarray(b, np.float64) - np.asarray(a, np.float64), axis=-1)
    return np.exp(-KS.double().numpy().reshape(-1, *([1] * d.ndim)) * d)


@pytest.mark.parametrize("alpha", [0.0, 1.0, 20.0])
def test_single_goal_is_eq_3_7_argmax(alpha):
    rng = np.random.default_rng(0)
    algo, cand = FakeAlgo(), _cands(rng, 40)
    s0 = hover_states(7)
    s0[3:, :3] = rng.uniform(-1, 1, (4, 3))  # some episodes share the start, some do not
    G = hover_states(7)[:, :15]
    G[:, :3] = rng.uniform(2, 3.5, (7, 3))
    plan = Planner(algo, cand, n=1, alpha=alpha).plan(s0, G)
    cp = cand.goals[:, :3].double().numpy()
    A = _q(s0[:, None, :3], cp[None])  # (m, E, C)
    B = _q(cp[None], G[:, None, :3])
    score = (A * B).mean(0) - alpha * (A.var(0) + B.var(0))
    assert np.array_equal(plan.index[:, 0], score.argmax(1))
    assert np.allclose(plan.score, score.max(1), atol=1e-5)
    assert np.allclose(plan.goals[:, 0], cand.goals.double().numpy()[score.argmax(1)])
    assert np.array_equal(plan.frame[:, 0], 100 + score.argmax(1))
    D = _q(s0[:, :3], G[:, :3])
    assert np.allclose(plan.direct_score, D.mean(0) - alpha * D.var(0), atol=1e-5)


@pytest.mark.parametrize("n", [1, 2])
def test_min_leg_excludes_candidates_at_the_start(n):
    rng = np.random.default_rng(5)
    algo, cand = FakeAlgo(), _cands(rng, 60)
    cand.goals[:5, :3] = cand.states[:5, :3] = torch.as_tensor(rng.uniform(-0.05, 0.05, (5, 3)), dtype=torch.float32)
    s0 = hover_states(6)
    s0[3:, :3] = rng.uniform(-1, 1, (3, 3))
    G = hover_states(6)[:, :15]
    G[:, :3] = rng.uniform(2, 3.5, (6, 3))
    free = Planner(algo, cand, n=n, alpha=0.0).plan(s0, G)
    cut = Planner(algo, cand, n=n, alpha=0.0, min_leg=1.0).plan(s0, G)
    d = np.linalg.norm(cand.goals[:, :3].double().numpy()[cut.index[:, 0]] - s0[:, :3], axis=1)
    assert (d >= 1.0).all()
    assert (np.linalg.norm(cand.goals[:, :3].double().numpy()[free.index[:, 0]] - s0[:, :3], axis=1) < 1.0).any()
    if n == 1:  # otherwise Eq. 3.7 over the rest
        cp = cand.goals[:, :3].double().numpy()
        A, B = _q(s0[:, None, :3], cp[None]), _q(cp[None], G[:, None, :3])
        score = np.where(np.linalg.norm(cp[None] - s0[:, None, :3], axis=-1) < 1.0, -np.inf, (A * B).mean(0))
        assert np.array_equal(cut.index[:, 0], score.argmax(1))
    with pytest.raises(Exception, match="shortest first leg"):
        Planner(algo, cand, min_leg=-1.0)


def test_variance_penalty_changes_the_choice():
    rng = np.random.default_rng(1)
    algo, cand = FakeAlgo(), _cands(rng, 60)
    s0, G = hover_states(20), hover_states(20)[:, :15]
    G[:, :3] = rng.uniform(2, 3.5, (20, 3)) * rng.choice([-1, 1], (20, 3))
    a = Planner(algo, cand, n=1, alpha=0.0).plan(s0, G).index
    b = Planner(algo, cand, n=1, alpha=50.0).plan(s0, G).index
    assert (a != b).any()


def test_two_goals_beam_is_exhaustive_eq_3_6_when_wide():
    rng = np.random.default_rng(2)
    C = 15
    algo, cand = FakeAlgo(), _cands(rng, C)
    s0, G = hover_states(4), hover_states(4)[:, :15]
    G[:, :3] = rng.uniform(2, 3.5, (4, 3))
    alpha = 0.5
    plan = Planner(algo, cand, n=2, alpha=alpha, beam=C * C).plan(s0, G)
    cp = cand.goals[:, :3].double().numpy()
    A = _q(s0[:, None, :3], cp[None])  # (m, E, C)
    P = _q(cp[:, None], cp[None])  # (m, C, C)
    B = _q(cp[None], G[:, None, :3])  # (m, E, C)
    full = (A[:, :, :, None] * P[:, None] * B[:, :, None, :]).mean(0) - alpha * (
        A.var(0)[:, :, None] + P.var(0)[None] + B.var(0)[:, None, :]
    )
    best = full.reshape(4, -1).argmax(1)
    assert np.array_equal(plan.index, np.stack([best // C, best % C], 1))
    assert np.allclose(plan.score, full.reshape(4, -1).max(1), atol=1e-5)
    narrow = Planner(algo, cand, n=2, alpha=alpha, beam=2).plan(s0, G)
    assert (narrow.score <= plan.score + 1e-6).all()


def test_leg_values_chunking():
    rng = np.random.default_rng(3)
    algo, cand = FakeAlgo(), _cands(rng, 50)
    s = cand.states
    g = cand.goals.flip(0)
    assert torch.allclose(leg_values(algo, s, g, chunk=7), leg_values(algo, s, g, chunk=1000))


def test_rollout_outcomes_and_records():
    algo = FakeAlgo()
    n = 5
    G = hover_states(n)[:, :15]
    G[1, 0], G[2, 2], G[3, 0], G[4, 0] = 0.1, 3.0, 0.3, 1.0  # reached, far, near only, far
    eps = EpisodeSet(
        "reach-desired", hover_states(n), G, np.array([50, 50, 50, 50, 30]), -np.ones(n, int), np.zeros(n, int), np.zeros(n, int)
    )
    r = rollout(algo, eps, record=True)
    assert r["success"].tolist() == [True, True, False, False, False]
    assert r["near_success"].tolist() == [True, True, False, True, False]
    assert r["first_success_step"].tolist() == [1, 1, -1, -1, -1]
    assert r["steps"].tolist() == [1, 1, 50, 50, 30]
    assert r["final_pos_err"][2] == pytest.approx(3.0, abs=0.05) and r["final_pos_err"][0] < 0.01
    assert r["positions"].shape == (5, 51, 3)


def test_rollout_flies_to_the_intermediate_goal_then_to_the_goal():
    algo = FakeAlgo()
    rng = np.random.default_rng(4)
    cand = _cands(rng, 10)
    cand.goals[3] = torch.as_tensor(hover_states(1)[0, :15], dtype=torch.float32)  # hover at the origin: reachable
    cand.states[3] = torch.as_tensor(hover_states(1)[0], dtype=torch.float32)
    G = hover_states(3)[:, :15]
    G[:, 2] = [0.05, 3.0, 3.0]
    eps = EpisodeSet(
        "ood", hover_states(3), G, np.full(3, 40), -np.ones(3, int), -np.ones(3, int), np.zeros(3, int), meta={"leg_horizon": 20}
    )
    r = rollout(algo, eps, planner=Planner(algo, cand, n=1, alpha=0.0), n_waypoints=1)
    assert r["waypoint_frame"][:, 0].tolist() == [103, 103, 103]  # the origin: Q = 1 to reach it
    # episode 0 reaches G (0.05 m away) at step 1, before its intermediate goal counts
    assert r["legs_reached"].tolist() == [0, 1, 1] and r["final_leg"].tolist() == [0, 1, 1]
    assert r["success"].tolist() == [True, False, False] and r["steps"].tolist() == [1, 40, 40]


def test_trainer_hooks_use_the_harness_rollout():
    from aerohrl.algorithms.closed_loop import make_reach_desired_evaluator
    from aerohrl.eval.harness import make_reach_intermediate_evaluator
    from aerohrl.algorithms.data import load_dataset
    from aerohrl.algorithms.synthetic import straight_columns

    data = load_dataset(straight_columns(n_eps=4, length=40))
    cfg = SimpleNamespace(seed=0, eval_episodes=3, eval_horizon=20)
    algo = FakeAlgo()
    rd = make_reach_desired_evaluator(data, cfg)(algo, 0)
    ri = make_reach_intermediate_evaluator(data, cfg)(algo, 0)
    assert set(rd) >= {"success", "near_success"} and 0 <= rd["success"] <= 1
    assert set(ri) == {"success", "near_success"} and 0 <= ri["success"] <= ri["near_success"] <= 1


def test_beam_search_in_episode_blocks_equals_one_block(monkeypatch):
    import aerohrl.planning.planner as P

    rng = np.random.default_rng(5)
    algo, cand = FakeAlgo(), _cands(rng, 12)
    s0, G = hover_states(9), hover_states(9)[:, :15]
    G[:, :3] = rng.uniform(2, 3.5, (9, 3))
    one = Planner(algo, cand, n=3, alpha=0.3, beam=4).plan(s0, G)
    monkeypatch.setattr(P, "BEAM_FLOATS", 3 * 4 * 12 * 2)  # 2 episodes per block
    blocks = Planner(algo, cand, n=3, alpha=0.3, beam=4).plan(s0, G)
    assert np.array_equal(one.index, blocks.index) and np.allclose(one.score, blocks.score)
    assert one.index.shape == (9, 3)


def test_a_planner_that_declines_flies_straight_where_its_plan_is_no_better():
    """decline_margin: episodes whose plan scores <= V(s0, G) + margin fly straight from
    take-off (and match the flight without planner); the others follow their plan."""
    algo = FakeAlgo()
    rng = np.random.default_rng(4)
    cand = _cands(rng, 10)
    G = hover_states(4)[:, :15]
    G[:, 2] = [0.05, 3.0, 0.5, 2.0]
    eps = EpisodeSet(
        "ood", hover_states(4), G, np.full(4, 40), -np.ones(4, int), -np.ones(4, int), np.zeros(4, int), meta={"leg_horizon": 20}
    )
    planner = Planner(algo, cand, n=1, alpha=0.0)
    plan = planner.plan(eps.start_states, G)
    straight = rollout(algo, eps)
    always = rollout(algo, eps, planner=planner, n_waypoints=1)
    never = rollout(algo, eps, planner=planner, n_waypoints=1, decline_margin=np.inf)
    assert never["declined"].all() and never["final_leg"].tolist() == [1, 1, 1, 1] and never["legs_reached"].sum() == 0
    for k in ("success", "steps", "final_pos_err"):
        np.testing.assert_array_equal(never[k], straight[k])
    m = float(np.median(plan.score - plan.direct_score))
    some = rollout(algo, eps, planner=planner, n_waypoints=1, decline_margin=m)
    np.testing.assert_array_equal(some["declined"], plan.score <= plan.direct_score + m)
    assert 0 < some["declined"].sum() < 4
    kept = ~some["declined"]
    for k in ("success", "steps", "legs_reached"):
        np.testing.assert_array_equal(some[k][kept], always[k][kept])
        np.testing.assert_array_equal(some[k][~kept], straight[k][~kept] if k != "legs_reached" else 0 * straight["steps"][~kept])


def test_evaluation_folders_name_the_options_that_change_results():
    from aerohrl.eval.harness import EvalOptions as E

    assert E(task="ood", planner="single", decline_margin=0.05).name() == "ood-single-decline0.05"
    assert E(task="ood", planner="none", decline_margin=0.05).name() == "ood-none"
    assert E(task="reach-novel", goal_tol=0.5).name() == "reach-novel-goaltol0.5"
    assert E(task="reach-intermediate", floor="hover").name() == "reach-intermediate-floor-hover"
    assert E(task="ood", planner="none", goal_tol=0.5).name() == "ood-none-goaltol0.5"
