"""Chain planner over synthetic candidates (planning/planner.py ChainPlanner): Eq. 3.6 beam
search against brute force, depth, early stopping, the bias toward G, and the harness
wiring; with hand-made critics whose values are a known function of the relative goal."""

import itertools
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from torch import nn

from aerohrl.envs.episodes import EpisodeSet, hover_states
from aerohrl.planning.planner import ChainPlanner, Offsets, chain_length, synthetic_offsets

KS = torch.tensor([0.5, 1.0, 2.0])  # one scale per critic: they disagree on long legs
KV = 0.1  # value lost per m/s of velocity change


class StubAlgo(nn.Module):
    """act: hover; critic j: ``base * exp(-k_j * relu(|p_g - p| - free) - KV |v_g - v|)``:
    a function of the relative goal (and the start's velocity) only."""

    def __init__(self, free=0.0, base=1.0):
        super().__init__()
        self.w = nn.Parameter(torch.zeros(()))
        self.cfg = SimpleNamespace(num_critics=len(KS))
        self.free, self.base = free, base
        self.normalizer = SimpleNamespace(act_center=torch.tensor([9.81, 0, 0, 0]), act_half=torch.tensor([9.0, 3, 3, 3]))

    def act(self, s, g):
        return torch.tensor([9.81, 0.0, 0.0, 0.0]).expand(len(s), 4) + 0 * self.w

    def critics(self, s, g, a):
        d = (g[:, :3] - s[:, :3]).norm(dim=1)
        dv = (g[:, 3:6] - s[:, 3:6]).norm(dim=1)
        return self.base * torch.exp(-KS[:, None] * torch.relu(d - self.free)[None] - KV * dv[None]) + 0 * a.sum(1)


def _q(ps, vs, pg, vg, free=0.0, base=1.0):
    """(m,) the stub's critic values, NumPy float64."""
    d = np.linalg.norm(np.asarray(pg, float) - ps)
    dv = np.linalg.norm(np.asarray(vg, float) - vs)
    return base * np.exp(-KS.double().numpy() * max(d - free, 0.0) - KV * dv)


def _episodes(rng, E, lo=2.0, hi=5.0):
    s0 = hover_states(E)
    s0[:, :3] = rng.uniform(-1, 1, (E, 3))
    s0[:, 3:6] = rng.uniform(-1, 1, (E, 3))
    G = hover_states(E)[:, :15]
    G[:, :3] = rng.uniform(lo, hi, (E, 3)) * rng.choice([-1, 1], (E, 3))
    G[:, 3:6] = rng.uniform(-1, 1, (E, 3))
    return s0, G


def _brute(s0, G, off: Offsets, n, alpha):
    """Best chain of 1..n offsets per episode by enumeration: (score, index tuple)."""
    P, V = off.pos.double().numpy(), off.vel.double().numpy()
    out = []
    for e in range(len(s0)):
        best = (-np.inf, None)
        for d in range(1, n + 1):
            for chain in itertools.product(range(len(P)), repeat=d):
                p, v = s0[e, :3].astype(float), s0[e, 3:6].astype(float)
                prod, vs = 1.0, 0.0
                for c in chain:
                    q = _q(p, v, p + P[c], V[c])
                    prod, vs = prod * q, vs + q.var()
                    p, v = p + P[c], V[c]
                q = _q(p, v, G[e, :3], G[e, 3:6])
                s = (prod * q).mean() - alpha * (vs + q.var())
                if s > best[0] + 1e-9:
                    best = (s, chain)
        out.append(best)
    return out


@pytest.mark.parametrize("alpha", [0.0, 0.5])
def test_exhaustive_beam_finds_the_brute_force_chain(alpha):
    rng = np.random.default_rng(0)
    C, n = 5, 2
    off = synthetic_offsets(C, seed=3, toward=0.0)
    s0, G = _episodes(rng, 6)
    plan = ChainPlanner(StubAlgo(), off, n=n, alpha=alpha, beam=C * C).plan(s0, G)
    brute = _brute(s0, G, off, n, alpha)
    for e, (score, chain) in enumerate(brute):
        d = len(chain)
        assert plan.depth[e] == d
        assert plan.index[e, :d].tolist() == list(chain) and (plan.index[e, d:] == -1).all()
        assert plan.score[e] == pytest.approx(score, abs=1e-5)
        # the goals: positions add up from the start, velocity and attitude are the offset's own
        p = s0[e, :3] + np.cumsum(off.pos.double().numpy()[list(chain)], 0)
        np.testing.assert_allclose(plan.goals[e, :d, :3], p, atol=1e-5)
        np.testing.assert_allclose(plan.goals[e, :d, 3:6], off.vel.double().numpy()[list(chain)], atol=1e-6)
        np.testing.assert_allclose(plan.goals[e, :d, 6:15], off.rot.double().numpy()[list(chain)], atol=1e-6)
    q = np.stack([_q(s0[e, :3], s0[e, 3:6], G[e, :3], G[e, 3:6]) for e in range(len(s0))], 1)
    np.testing.assert_allclose(plan.direct_score, q.mean(0) - alpha * q.var(0), atol=1e-5)
    narrow = ChainPlanner(StubAlgo(), off, n=n, alpha=alpha, beam=1).plan(s0, G)  # greedy: never better
    assert (narrow.score <= plan.score + 1e-6).all()


def test_plan_shapes_depth_and_padding():
    rng = np.random.default_rng(1)
    off = synthetic_offsets(16, seed=1)
    s0, G = _episodes(rng, 7, 4.0, 9.0)
    for n in (1, 3):
        plan = ChainPlanner(StubAlgo(free=2.0, base=0.95), off, n=n, beam=4).plan(s0, G)
        assert plan.goals.shape == (7, n, 15) and plan.index.shape == (7, n) and plan.frame.shape == (7, n)
        assert plan.score.shape == plan.direct_score.shape == plan.depth.shape == (7,)
        assert (plan.frame == -1).all() and ((1 <= plan.depth) & (plan.depth <= n)).all()
        for e in range(7):
            d = plan.depth[e]
            assert (plan.index[e, :d] >= 0).all() and (plan.index[e, d:] == -1).all()
            assert np.allclose(plan.goals[e, d:], plan.goals[e, d - 1])  # repeats of the last goal
    with pytest.raises(Exception, match=">= 1"):
        ChainPlanner(StubAlgo(), off, n=2).plan(s0, G, n=0)


def _line_offsets():
    """+1.5 m or -1.5 m along x, at rest; one useless step along z."""
    pos = torch.tensor([[1.5, 0, 0], [-1.5, 0, 0], [0, 0, 1.5]])
    rot = torch.eye(3).reshape(1, 9).repeat(3, 1)
    return Offsets(pos, torch.zeros(3, 3), rot, torch.zeros(3, dtype=torch.bool), torch.ones(3, 3))


def test_chains_stop_early_and_grow_with_the_distance():
    """Legs up to 2 m are worth 0.9 (every critic), longer ones decay: the best chain has
    the fewest legs of <= 2 m, whatever the depth allowed."""
    algo, off = StubAlgo(free=2.0, base=0.9), _line_offsets()
    s0 = hover_states(3)
    G = hover_states(3)[:, :15]
    G[:, 0] = [1.0, 4.4, 5.9]  # 1, 2 and 3 goals of +1.5 m before the last leg of <= 2 m
    plan = ChainPlanner(algo, off, n=6, alpha=1.0, beam=3).plan(s0, G)
    assert plan.depth.tolist() == [1, 2, 3]
    np.testing.assert_allclose(plan.score, [0.9**2, 0.9**3, 0.9**4], atol=1e-5)
    assert plan.index[2].tolist() == [0, 0, 0, -1, -1, -1]
    np.testing.assert_allclose(plan.goals[2, :, 0], [1.5, 3.0, 4.5, 4.5, 4.5, 4.5], atol=1e-6)
    short = ChainPlanner(algo, off, n=1, alpha=1.0, beam=3).plan(s0, G)  # too few legs for the far goals
    assert short.score[0] == pytest.approx(plan.score[0], abs=1e-6) and (short.score[1:] < plan.score[1:] - 1e-3).all()
    assert chain_length(s0, G, step=1.5).tolist() == [1, 2, 3]  # the helper's n for legs of 1.5 m agrees


def test_chain_length_helper():
    s0 = hover_states(4)
    G = hover_states(4)[:, :15]
    G[:, 1] = [0.5, 3.5, -20.0, 100.0]
    assert chain_length(s0, G).tolist() == [1, 1, 9, 12]
    assert chain_length(s0, G, step=1.0, max_n=30).tolist() == [1, 3, 19, 30]


def test_offsets_toward_the_goal_never_overshoot():
    off = synthetic_offsets(40, seed=2, toward=0.5, toward_range=(1.0, 2.0))
    assert off.toward.sum() == 20 and len(off) == 40
    d = torch.tensor([[5.0, -0.4, 0.0], [-3.0, 10.0, -1.5]])
    st = off.steps(d)  # (2, 40, 3)
    tw = st[:, off.toward]
    assert (tw * d[:, None].sign() >= 0).all() and (tw.abs() <= d[:, None].abs() + 1e-6).all()
    assert (tw[0, :, 0] >= 1.0).all() and torch.allclose(tw[0, :, 1], torch.tensor(-0.4)) and (tw[0, :, 2] == 0).all()
    assert torch.equal(st[:, ~off.toward], off.pos[~off.toward].expand(2, 20, 3))
    assert (off.pos.abs() <= 2.0).all() and torch.allclose(off.rot.reshape(-1, 3, 3).det(), torch.ones(40))
    again = synthetic_offsets(40, seed=2, toward=0.5)
    assert torch.equal(off.pos, again.pos) and not torch.equal(off.pos, synthetic_offsets(40, seed=3).pos)
    # a planner with only biased offsets walks toward a far goal
    s0 = hover_states(1)
    G = hover_states(1)[:, :15]
    G[0, :3] = [12.0, -7.0, 3.0]
    plan = ChainPlanner(StubAlgo(free=2.0, base=0.95), synthetic_offsets(32, toward=1.0), n=6, beam=4).plan(s0, G)
    x = plan.goals[0, : plan.depth[0], :3]
    assert plan.depth[0] >= 5 and (np.diff(np.abs(G[0, :3] - np.vstack([s0[0, :3], x])), axis=0) <= 1e-6).all()
    assert plan.score[0] > 10 * plan.direct_score[0] > 0


def test_episode_blocks_equal_one_block(monkeypatch):
    import aerohrl.planning.planner as P

    rng = np.random.default_rng(5)
    off = synthetic_offsets(12, seed=5)
    s0, G = _episodes(rng, 9, 3.0, 8.0)
    one = ChainPlanner(StubAlgo(free=2.0, base=0.95), off, n=3, alpha=0.3, beam=4).plan(s0, G)
    monkeypatch.setattr(P, "BEAM_FLOATS", 2 * 4 * 12 * (4 * 3 + 66))  # 2 episodes per block
    blocks = ChainPlanner(StubAlgo(free=2.0, base=0.95), off, n=3, alpha=0.3, beam=4).plan(s0, G)
    assert np.array_equal(one.index, blocks.index) and np.allclose(one.score, blocks.score)
    assert np.array_equal(one.depth, blocks.depth)


def test_harness_and_cli_reach_the_chain_planner():
    from aerohrl.eval.cli import _eval_parser
    from aerohrl.eval.harness import EvalOptions, check_options, make_planner

    algo = StubAlgo()
    spec = {"pos_range": [1.0, 1.5], "vel_range": [-1.0, 1.0], "acc_range": [-2.0, 2.0]}
    data = SimpleNamespace(info={"spec": spec})
    opt = EvalOptions(task="ood", planner="multi", waypoints=4, candidates=64, candidate_source="synthetic")
    check_options(opt)
    planner, n = make_planner(algo, data, opt)
    assert isinstance(planner, ChainPlanner) and n == 4 and planner.n == 4 and len(planner.off) == 64
    free = ~planner.off.toward
    assert planner.off.pos[free].abs().max() <= 1.5 and planner.off.vel.abs().max() <= 1.0
    assert opt.name() == "ood-multi4-synth"
    assert EvalOptions(task="ood", planner="multi", waypoints=4).name() == "ood-multi4"
    assert EvalOptions(task="ood", planner="none", candidate_source="synthetic").name() == "ood-none"
    with pytest.raises(Exception, match="candidate.source"):
        check_options(EvalOptions(task="ood", planner="single", candidate_source="grid"))
    a = _eval_parser().parse_args(["--task", "ood", "--run", "x", "--candidate-source", "synthetic"])
    assert a.candidate_source == "synthetic"
    assert _eval_parser().parse_args(["--task", "ood", "--run", "x"]).candidate_source == "dataset"


def test_rollout_flies_a_chain_with_replanning():
    from aerohrl.envs.rollout import rollout

    algo = StubAlgo(free=2.0, base=0.9)
    G = hover_states(2)[:, :15]
    G[:, 0] = [4.4, 7.4]
    eps = EpisodeSet(
        "ood", hover_states(2), G, np.full(2, 30), -np.ones(2, int), -np.ones(2, int), np.zeros(2, int), meta={"leg_horizon": 10}
    )
    planner = ChainPlanner(algo, _line_offsets(), n=3, beam=3)
    r = rollout(algo, eps, planner=planner, n_waypoints=3)
    assert r["planned_waypoints"].shape == (2, 3, 15) and (r["planned_frame"] == -1).all()
    np.testing.assert_allclose(r["planned_waypoints"][1, :, 0], [1.5, 3.0, 4.5], atol=1e-6)
    assert not r["success"].any() and r["steps"].tolist() == [30, 30]  # the stub hovers
