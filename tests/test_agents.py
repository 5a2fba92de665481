"""OGBench's goal-conditioned agents (gciql, crl, qrl, hiql): their losses against hand
computations, OGBench-style goal sampling, training with resume, checkpoints that load
back, the 33-d input of a dataset flown among obstacles, and one-line config errors."""

import math
import warnings

import pytest
import torch

from aerohrl.algorithms.base import algorithm_class, build_algorithm, load_policy
from aerohrl.algorithms.config import GOAL_AGENTS, ConfigError, make_config
from aerohrl.algorithms.crl import contrastive_loss
from aerohrl.algorithms.data import GoalBatchSampler, fit_normalizer, load_dataset
from aerohrl.algorithms.gciql import expectile_value_loss, ogbench_reward_mask
from aerohrl.algorithms.hiql import awr_weights, expectile_weighted_loss
from aerohrl.algorithms.networks import gaussian_log_prob
from aerohrl.algorithms.qrl import Quasimetric, iqe, qrl_value_loss
from aerohrl.algorithms.relabel import GoalMix, subgoal_index
from aerohrl.algorithms.synthetic import straight_columns, write_synthetic_dataset
from aerohrl.algorithms.trainer import resume_run, start_run
from aerohrl import task

warnings.filterwarnings("ignore", category=UserWarning)

TINY = dict(hidden=(16, 16), critic_hidden=(16, 16), batch_size=32, steps=40, log_every=10, checkpoint_every=20, eval_every=0)


@pytest.fixture(scope="module")
def small():
    return load_dataset(straight_columns(n_eps=4, length=30))


def _build(algo, data, **kw):
    torch.manual_seed(0)
    cfg = make_config("cpu", algo=algo, hidden=(16, 16), critic_hidden=(16, 16), batch_size=32, **kw)
    norm = fit_normalizer(data, cfg.relabel_prob)
    a = build_algorithm(cfg, norm)
    opts = algorithm_class(algo).sampler_options(cfg)
    return a, GoalBatchSampler(data, norm, cfg.batch_size, cfg.relabel_prob, torch.Generator().manual_seed(0), **opts)


# --- losses against hand computations ------------------------------------------------


def test_expectile_loss_and_ogbench_units():
    # diffs q - v = [2, -1]: weights 0.9 and 0.1 -> (0.9 * 4 + 0.1 * 1) / 2
    q, v = torch.tensor([2.0, 0.0]), torch.tensor([0.0, 1.0])
    assert torch.isclose(expectile_value_loss(q, v, 0.9), torch.tensor(1.85))
    # HIQL's form: the weight from the sign of adv, the square of diff
    out = expectile_weighted_loss(torch.tensor([1.0, -1.0]), torch.tensor([2.0, 3.0]), 0.7)
    assert torch.allclose(out, torch.tensor([0.7 * 4, 0.3 * 9]))
    # reward -1 per step, 0 (and mask 0) on the transition that reaches the goal
    from tensordict import TensorDict

    td = TensorDict({"next": {"reward": torch.tensor([[1.0], [0.0]]), "done": torch.tensor([[True], [False]])}}, [2])
    r, mask = ogbench_reward_mask(td)
    assert torch.equal(r, torch.tensor([0.0, -1.0])) and torch.equal(mask, torch.tensor([0.0, 1.0]))
    # the unit-std Gaussian log-likelihood of the BC/AWR terms
    lp = gaussian_log_prob(torch.zeros(1, 2), torch.tensor([[1.0, 0.0]]))
    assert torch.isclose(lp, torch.tensor([-0.5 - math.log(2 * math.pi)])).all()


def test_gciql_losses_match_hand_computation(small):
    a, s = _build("gciql", small)
    b = s.sample()
    out = a.losses(b)
    vb, ab = b["value"], a.actor_batch(b["actor"])
    x, a_, x2 = vb["observation"], vb["action"], vb["next", "observation"]
    r = vb["next", "reward"].squeeze(-1) - 1
    mask = 1 - vb["next", "done"].squeeze(-1).float()
    with torch.no_grad():
        q1, q2 = (net(x, a_).squeeze(-1) for net in a.target_critic.module.nets)
        v = a.value(x).squeeze(-1)
        u = torch.minimum(q1, q2) - v
        value = (torch.where(u > 0, 0.9, 0.1) * u**2).mean()
        y = r + a.cfg.gamma * mask * a.value(x2).squeeze(-1)
        critic = sum(((net(x, a_).squeeze(-1) - y) ** 2).mean() for net in a.critic.nets)
        pi = a.actor.module(ab["observation"])
        qp = torch.minimum(*(net(ab["observation"], pi).squeeze(-1) for net in a.critic.nets))
        actor = (
            -qp.mean() / (qp.abs().mean() + 1e-6)
            + a.cfg.gciql.gciql_alpha * (0.5 * ((ab["action"] - pi) ** 2).sum(-1) + 2 * math.log(2 * math.pi)).mean()
        )
    assert torch.isclose(out["loss_value"], value, rtol=1e-5)
    assert torch.isclose(out["loss_critic"], critic, rtol=1e-5)
    assert torch.isclose(out["loss_actor"], actor, rtol=1e-5)


def test_gciql_awr_weights():
    cfg_awr = make_config("cpu", algo="gciql", gciql_actor_loss="awr", gciql_alpha=3.0, hidden=(16, 16), critic_hidden=(16, 16))
    data = load_dataset(straight_columns(n_eps=4, length=30))
    norm = fit_normalizer(data, cfg_awr.relabel_prob)
    torch.manual_seed(0)
    a = build_algorithm(cfg_awr, norm)
    s = GoalBatchSampler(data, norm, 32, 0.05, torch.Generator().manual_seed(0), **a.sampler_options(cfg_awr))
    b = s.sample()
    ab = b["actor"]
    with torch.no_grad():
        x, act = ab["observation"], ab["action"]
        adv = torch.minimum(*(n(x, act).squeeze(-1) for n in a.target_critic.module.nets)) - a.value(x).squeeze(-1)
        w = torch.exp(3.0 * adv).clamp_max(100)
        want = -(w * gaussian_log_prob(a.actor.module(x), act)).mean()
    assert torch.isclose(a.losses(b)["loss_actor"], want, rtol=1e-5)


def test_contrastive_losses_by_hand():
    phi = torch.tensor([[[1.0], [2.0]]])  # (E=1, B=2, D=1)
    psi = torch.tensor([[[1.0], [-1.0]]])  # logits [[1, -1], [2, -2]]
    sp = torch.nn.functional.softplus
    loss, logits = contrastive_loss(phi, psi, "binary")
    assert torch.allclose(logits[0], torch.tensor([[1.0, -1.0], [2.0, -2.0]]))
    # positives (diagonal) 1 and -2: -log sigmoid = softplus(-l); negatives -1 and 2: softplus(l)
    want = (sp(torch.tensor(-1.0)) + sp(torch.tensor(2.0)) + sp(torch.tensor(-1.0)) + sp(torch.tensor(2.0))) / 4
    assert torch.isclose(loss, want)
    loss, _ = contrastive_loss(phi, psi, "symmetric")
    rows = (math.log(1 + math.exp(-2)) + math.log(1 + math.exp(4))) / 2  # softmax over goals
    cols = (math.log(1 + math.exp(1)) + math.log(1 + math.exp(1))) / 2  # over state-actions
    assert math.isclose(float(loss), (rows + cols) / 2, rel_tol=1e-6)


def test_crl_critic_is_sigmoid_of_the_bilinear_score(small):
    a, s = _build("crl", small)
    for _ in range(3):
        a.update(s.sample())
    st, g, act = small.state[:6], small.goal[:6], small.action[:6]
    x = a.normalizer.inputs(st, g)
    phi, psi = a.critic.embed(x, a.normalizer.action_to_unit(act))
    want = torch.sigmoid((phi * psi).sum(-1) / math.sqrt(phi.shape[-1]))
    assert torch.allclose(a.critics(st, g, act), want, atol=1e-6)


def test_quasimetric_heads_by_hand():
    u, v = torch.tensor([[0.0, 2.0, 5.0, 5.0]]), torch.tensor([[1.0, 3.0, 4.0, 6.0]])
    # component 1: [0, 1] u [2, 3] = 2; component 2: [5, 5] u [5, 6] = 1; and the other way 0 and [4, 5] u [6, 6] = 1
    assert torch.equal(iqe(u, v, 2), torch.tensor([[2.0, 1.0]]))
    assert torch.equal(iqe(v, u, 2), torch.tensor([[0.0, 1.0]]))
    assert torch.equal(
        iqe(torch.tensor([[0.0, 0.5]]), torch.tensor([[1.0, 2.0]]), 1), torch.tensor([[2.0]])
    )  # overlap counted once
    head = Quasimetric("iqe", 2)
    assert torch.isclose(head(u, v), torch.tensor([0.5 * 2 + 0.5 * 1.5]))  # sigmoid(0) max + (1 - sigmoid(0)) mean
    mrn = Quasimetric("mrn", 1)
    assert torch.isclose(mrn(torch.tensor([1.0, 0.0, 0.0, 0.0]), torch.tensor([0.0, 0.0, 3.0, 4.0])), torch.tensor(1.0 + 5.0))
    # a quasimetric: d(x, x) = 0, d >= 0, triangle inequality
    g = torch.Generator().manual_seed(0)
    x, y, z = (torch.randn(256, 16, generator=g) for _ in range(3))
    for h in (head, mrn):
        h2 = Quasimetric(h.kind, 4)
        assert torch.allclose(h2(x, x), torch.zeros(256))
        assert (h2(x, y) >= 0).all() and (h2(x, z) <= h2(x, y) + h2(y, z) + 1e-5).all()


@pytest.mark.parametrize("kind", ["iqe", "mrn"])
def test_qrl_distance_does_not_depend_on_the_reference(kind):
    """Moving the reference state (the first 3 input columns, p_y - p_s, of every point
    alike) leaves d unchanged, so d(s, s') and d(s', g) chain through the triangle inequality."""
    from aerohrl.algorithms.qrl import PointEncoder

    torch.manual_seed(0)
    enc, head = PointEncoder(15, 16, (8,), kind, 4), Quasimetric(kind, 4)
    y1, y2 = torch.randn(64, 15), torch.randn(64, 15)
    shift = torch.zeros(64, 15)
    shift[:, :3] = torch.randn(64, 3)
    with torch.no_grad():
        assert torch.allclose(head(enc(y1 + shift), enc(y2 + shift)), head(enc(y1), enc(y2)), atol=1e-5)
        assert not torch.allclose(head(enc(y1 + shift), enc(y2)), head(enc(y1), enc(y2)), atol=1e-3)


def test_qrl_objective_by_hand():
    d_neg, d_pos = torch.tensor([0.0, 1000.0]), torch.tensor([0.5, 2.0])
    log_lam = torch.tensor(math.log(2.0), requires_grad=True)
    loss, loss_lam, constraint = qrl_value_loss(d_neg, d_pos, log_lam, 0.05)
    push = (100 * math.log1p(math.exp(5.0)) + 100 * math.log1p(math.exp(-5.0))) / 2
    assert math.isclose(float(constraint), 0.5)  # relu(0.5 - 1)^2 = 0, relu(2 - 1)^2 = 1
    assert math.isclose(float(loss), push + 2.0 * 0.5, rel_tol=1e-6)
    assert math.isclose(float(loss_lam.detach()), 2.0 * (0.05 - 0.5), rel_tol=1e-6)
    loss_lam.backward()
    assert log_lam.grad < 0  # a violated constraint: descent raises lambda
    # the distance loss does not move lambda, the multiplier loss does not move the distances
    d = torch.tensor([2.0], requires_grad=True)
    ll = torch.tensor(0.0, requires_grad=True)
    _, lam_only, _ = qrl_value_loss(torch.tensor([0.0]), d, ll, 0.05)
    lam_only.backward()
    assert d.grad is None or float(d.grad.abs().sum()) == 0.0


def _hiql_losses(data, **kw):
    """A HIQL agent (5-step subgoals) after 3 updates, a fresh batch, its losses, and the
    batch's low-level (subgoal) and high-level (actor) parts."""
    a, s = _build("hiql", data, hiql_subgoal_steps=5, **kw)
    for _ in range(3):
        a.update(s.sample())
    b = s.sample()
    return a, b, a.losses(b), a.actor_batch(b["subgoal"]), b["actor"]


def test_hiql_awr_weights_and_advantages(small):
    assert torch.allclose(awr_weights(torch.tensor([0.0, 1.0, 100.0]), 3.0), torch.tensor([1.0, math.exp(3.0), 100.0]))
    a, b, out, lb, hb = _hiql_losses(small)
    with torch.no_grad():
        xl = lb["observation"]
        adv = a.value(lb["next", "observation"]).mean(0) - a.value(xl).mean(0)  # V(s', w) - V(s, w)
        w = torch.exp(3.0 * adv).clamp_max(100)
        pi = a.policy.low(torch.cat([a.normalizer.state_part(xl), a.value.phi(xl)], -1))
        low = -(w * gaussian_log_prob(pi, lb["action"])).mean()
        xh = hb["observation"]
        adv_h = a.value(hb["target_observation"]).mean(0) - a.value(xh).mean(0)  # V(s_{t+k}, g) - V(s, g)
        wh = torch.exp(3.0 * adv_h).clamp_max(100)
        high = -(wh * gaussian_log_prob(a.policy.high(xh), a.value.phi(hb["subgoal_observation"]))).mean()
    assert torch.isclose(out["loss_actor_low"], low, rtol=1e-5)
    assert torch.isclose(out["loss_actor_high"], high, rtol=1e-5)
    assert torch.isclose(out["adv_low"], adv.mean(), rtol=1e-4, atol=1e-7)


def test_hiql_goal_subgoal_space(small):
    """hiql_subgoal_space goal: the high level regresses the subgoal's goal-only input
    columns, the low level reads the input with those columns, and acts on the high
    level's proposal in their place (the goal's own columns under the goal switch)."""
    a, b, out, lb, hb = _hiql_losses(small, hiql_subgoal_space="goal")
    idx, norm = a.subgoal_index, a.normalizer
    assert not set(idx) & set(norm.state_index) and len(idx) == norm.in_dim - len(norm.state_index)
    with torch.no_grad():
        xl = lb["observation"]
        w = torch.exp(3.0 * (a.value(lb["next", "observation"]).mean(0) - a.value(xl).mean(0))).clamp_max(100)
        low = -(w * gaussian_log_prob(a.policy.low(xl), lb["action"])).mean()
        xh = hb["observation"]
        wh = torch.exp(3.0 * (a.value(hb["target_observation"]).mean(0) - a.value(xh).mean(0))).clamp_max(100)
        high = -(wh * gaussian_log_prob(a.policy.high(xh), hb["subgoal_observation"][:, idx])).mean()
    assert torch.isclose(out["loss_actor_low"], low, rtol=1e-5)
    assert torch.isclose(out["loss_actor_high"], high, rtol=1e-5)
    state, goal = b["state"][:8], b["goal"][:8]
    x = norm.inputs(state, goal)
    net = a._net()
    with torch.no_grad():
        proposed = x.clone()
        proposed[:, idx] = net.high(x)
        assert torch.allclose(a.act(state, goal), norm.action_from_unit(net.low(proposed)), atol=1e-6)
        a.cfg.hiql.hiql_subgoal_steps = 10**9  # every goal within the horizon: the goal itself
        a.cfg.hiql.hiql_goal_switch = True
        assert torch.allclose(a.act(state, goal), norm.action_from_unit(net.low(x)), atol=1e-6)
    assert a.goal_representation(state, goal).shape == (8, len(idx))


# --- goal sampling ---------------------------------------------------------------------


def test_subgoal_and_target_indices(small):
    i = torch.tensor([0, 10, 27, 29, 30])
    end = small.episode_end[i]
    assert torch.equal(subgoal_index(i, end, 5), torch.tensor([4, 14, 29, 29, 34]))
    cfg = make_config("cpu", algo="hiql", hiql_subgoal_steps=5)
    norm = fit_normalizer(small, 0.05)
    s = GoalBatchSampler(small, norm, 512, 0.05, torch.Generator().manual_seed(0), **algorithm_class("hiql").sampler_options(cfg))
    b = s.sample()
    idx, ep_end = b["index"], small.episode_end[b["index"]]
    sub = torch.minimum(idx + 4, ep_end)
    # the low level's goal: the achieved goal of the state 5 steps after s_t (frame t + 4's next state)
    assert torch.equal(b["subgoal", "goal"], small.achieved_goal[sub])
    # the high level's target: at most 5 steps ahead and never past the actor goal's own step
    ts = b["actor", "target_state"]
    k = [
        torch.nonzero((small.achieved_goal[lo : hi + 1] == g).all(-1))[0].item() + lo
        for g, lo, hi in zip(b["actor", "goal"], idx, ep_end)
    ]
    want = small.next_state[torch.minimum(sub, torch.tensor(k))]
    assert torch.equal(ts, want)
    assert torch.allclose(b["actor", "subgoal_observation"], norm.inputs(b["state"], task.achieved_goal(ts)))


def test_subgoal_end_desired():
    """hiql_subgoal_end desired: a subgoal cut off by the episode's end is the episode's desired
    goal, for the low level and for the high level's kept desired goals; elsewhere unchanged."""
    cols = straight_columns(n_eps=4, length=30)
    cols["observation.desired_goal"][:, :3] += 0.1  # the flights end 10 cm short of their goals per axis
    small = load_dataset(cols)
    norm = fit_normalizer(small, 0.0)
    opts = {}
    for end in ("achieved", "desired"):
        cfg = make_config("cpu", algo="hiql", hiql_subgoal_steps=5, hiql_actor_p_trajgoal=0.0, hiql_subgoal_end=end)
        opts[end] = GoalBatchSampler(
            small, norm, 512, 0.0, torch.Generator().manual_seed(0), **algorithm_class("hiql").sampler_options(cfg)
        ).sample()
    a, d = opts["achieved"], opts["desired"]
    assert torch.equal(a["index"], d["index"])
    idx, ep_end = d["index"], small.episode_end[d["index"]]
    at_end = idx + 4 >= ep_end
    assert 0 < at_end.sum() < len(idx)
    assert torch.equal(d["subgoal", "goal"][at_end], d["goal"][at_end])  # the desired goal
    assert torch.equal(d["subgoal", "goal"][~at_end], a["subgoal", "goal"][~at_end])
    assert not torch.equal(a["subgoal", "goal"][at_end], a["goal"][at_end])  # the last state is not the goal here
    # the high level's actor goals are the desired goals (p_trajgoal 0): its target at the end is the goal too
    want = norm.inputs(d["state"][at_end], d["goal"][at_end])
    assert torch.allclose(d["actor", "subgoal_observation"][at_end], want)
    assert torch.allclose(d["actor", "subgoal_observation"][~at_end], a["actor", "subgoal_observation"][~at_end])
    with pytest.raises(ConfigError, match="hiql_subgoal_end"):
        make_config("cpu", algo="hiql", hiql_subgoal_end="goal")


def test_low_subgoal_offset_uniform(small):
    """hiql_low_subgoal_offset uniform: the low level's subgoal is the state 1..k steps ahead
    (every offset drawn, clipped at the episode's end); the high level's target is unchanged."""
    norm = fit_normalizer(small, 0.05)
    batches = {}
    for off in ("fixed", "uniform"):
        cfg = make_config("cpu", algo="hiql", hiql_subgoal_steps=5, hiql_low_subgoal_offset=off)
        opts = algorithm_class("hiql").sampler_options(cfg)
        batches[off] = GoalBatchSampler(small, norm, 2048, 0.05, torch.Generator().manual_seed(0), **opts).sample()
    f, u = batches["fixed"], batches["uniform"]
    assert torch.equal(f["index"], u["index"])
    assert torch.equal(f["actor", "target_state"], u["actor", "target_state"])
    idx, ep_end = u["index"], small.episode_end[u["index"]]
    # the frame of each low-level subgoal: its achieved goal matches a frame idx .. min(idx + 4, end)
    ag = small.achieved_goal
    offsets = []
    for g, lo, hi in zip(u["subgoal", "goal"], idx.tolist(), torch.minimum(idx + 4, ep_end).tolist()):
        hit = torch.nonzero((ag[lo : hi + 1] == g).all(-1))
        assert len(hit) > 0
        offsets.append(hit[0].item())
    seen = set(offsets)
    assert seen == {0, 1, 2, 3, 4}  # 1..5 steps ahead, every one drawn
    far = idx + 4 <= ep_end  # not clipped: the uniform draw puts the fixed subgoal's offset at 1/5
    share = sum(o == 4 for o, ok in zip(offsets, far.tolist()) if ok) / max(int(far.sum()), 1)
    assert 0.12 < share < 0.28
    with pytest.raises(ConfigError, match="hiql_low_subgoal_offset"):
        make_config("cpu", algo="hiql", hiql_low_subgoal_offset="geometric")


def test_goal_mix_shares_and_current_goal_rewards(small):
    norm = fit_normalizer(small, 0.0)
    mixes = {"cur": GoalMix(p_cur=1.0, p_traj=0.0), "mix": GoalMix(p_cur=0.2, p_traj=0.5, p_rand=0.3), "keep": GoalMix(0, 0, 0)}
    s = GoalBatchSampler(small, norm, 4096, 0.0, torch.Generator().manual_seed(0), goal_mixes=mixes)
    b = s.sample()
    idx = b["index"]
    # the current goal is this transition's achieved goal: reached by this very step
    assert torch.equal(b["cur", "goal"], small.achieved_goal[idx]) and b["cur", "next", "reward"].all()
    assert torch.equal(b["keep", "goal"], b["goal"])  # the rest of the probability keeps the batch's goal
    cur = (b["mix", "goal"] == small.achieved_goal[idx]).all(-1)
    assert 0.17 < cur.float().mean() < 0.25  # 0.2, plus trajectory goals of an episode's last step (its own)
    frame = (b["mix", "goal"].unsqueeze(1) == small.achieved_goal.unsqueeze(0)).all(-1).float().argmax(1)
    other_episode = small.episode_index[frame] != small.episode_index[idx]
    assert 0.19 < other_episode.float().mean() < 0.26  # random goals (0.3) from the 3 other episodes of 4
    later = (frame > idx) & ~other_episode
    assert 0.45 < later.float().mean() < 0.55  # trajectory goals (0.5), strictly later in the episode


def test_mixes_draw_after_the_thesis_batch(small):
    """A sampler with goal mixes gives the same main batch as one without: its draws come after."""
    norm = fit_normalizer(small, 0.5)
    plain = GoalBatchSampler(small, norm, 64, 0.5, torch.Generator().manual_seed(3)).sample()
    mixed = GoalBatchSampler(
        small, norm, 64, 0.5, torch.Generator().manual_seed(3), goal_mixes={"value": GoalMix()}, subgoal_steps=3
    ).sample()
    for k in ("index", "goal", "observation", "action", ("next", "reward")):
        assert torch.equal(plain[k], mixed[k])


# --- training, checkpoints, loading -----------------------------------------------------


def _same(a, b):
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


@pytest.mark.parametrize("algo", GOAL_AGENTS)
@pytest.mark.parametrize("extra", [{}, {"amp": "bf16", "augment": "mirror", "ema_decay": 0.9}])
def test_train_resume_load(algo, extra, data, tmp_path):
    torch.set_num_threads(1)
    cfg = make_config("cpu", algo=algo, dataset=str(data.info["path"]), **TINY, **extra)
    full = start_run(cfg, tmp_path / "full", data=data, progress=False)
    full.train()
    part = start_run(cfg, tmp_path / "part", data=data, progress=False)
    part.train(until=20)
    del part
    again = resume_run(tmp_path / "part", data=data, progress=False)
    assert again.step == 20
    again.train()
    assert again.step == full.step == 40 and _same(full.algo, again.algo)
    m = full.algo.update(full.sampler.sample())
    assert all(torch.isfinite(v) for v in m.values())
    # the checkpoint loads back as a policy (checksum verified), acting and scoring as the trained one
    from aerohrl import load_policy as api_load

    pol = api_load(tmp_path / "part")
    algo_l, _ = load_policy(full.run.checkpoints()[-1])
    st, g, act = data.state[:9], data.goal[:9], data.action[:9]
    out = pol.algo.act(st, g)
    assert out.shape == (9, 4) and torch.equal(out, again.algo.act(st, g))
    q = algo_l.critics(st, g, act)
    n = {"gciql": 2, "crl": 2, "qrl": 1, "hiql": 2}[algo]
    assert q.shape == (n, 9) and (q >= 0).all() and (q <= 1).all()
    lo, hi = algo_l.normalizer.act_center - algo_l.normalizer.act_half, algo_l.normalizer.act_center + algo_l.normalizer.act_half
    assert ((out >= lo - 1e-5) & (out <= hi + 1e-5)).all()
    # translation invariance of the free-space input
    st2, g2 = st.clone(), g.clone()
    st2[:, :3] += 2.0
    g2[:, :3] += 2.0
    assert torch.allclose(pol.algo.critics(st2, g2, act), pol.algo.critics(st, g, act), atol=1e-5)
    if algo == "hiql":
        z = pol.algo.subgoals(st, g)
        assert z.shape == (9, cfg.hiql.hiql_rep_dim)
        assert torch.allclose(z.norm(dim=-1), torch.full((9,), math.sqrt(cfg.hiql.hiql_rep_dim)), atol=1e-4)
        assert pol.algo.goal_representation(st, g).shape == z.shape
        # the goal switch: rows the value puts within the horizon act towards phi(s, g), the rest as before
        h = pol.algo
        d = h.steps_to_goal(st, g)
        assert d.shape == (9,) and (d >= 0).all()
        v = h.value(h.normalizer.inputs(st, g)).mean(0)
        assert torch.allclose(cfg.gamma**d, (1 + (1 - cfg.gamma) * v).clamp(0, 1), atol=1e-5)
        h.steps_to_goal = lambda s, g: torch.arange(9.0)  # rows 0-4 within a horizon of 4 steps
        h.cfg.hiql.hiql_goal_switch, h.cfg.hiql.hiql_subgoal_steps = True, 4
        x = h.normalizer.inputs(st, g)
        towards_goal = h.normalizer.action_from_unit(h._net().low_action(x, h.value.phi(x)))
        near = torch.arange(9) <= 4
        switched = h.act(st, g)
        assert torch.allclose(switched[near], towards_goal[near]) and torch.equal(switched[~near], out[~near])
        h.cfg.hiql.hiql_goal_switch = False
        assert torch.equal(h.act(st, g), out)


def test_maze_dataset_gives_33d_inputs_and_checkpoints_load(tmp_path):
    torch.set_num_threads(1)
    root = write_synthetic_dataset(tmp_path / "maze" / "v1", spec={"world": "maze-medium"})
    data = load_dataset(root)
    for algo in ("hiql", "gcsl"):
        cfg = make_config("cpu", algo=algo, dataset=str(root), **dict(TINY, steps=20))
        tr = start_run(cfg, tmp_path / algo, data=data, progress=False)
        tr.train()
        assert tr.algo.normalizer.in_dim == 33 and tr.sampler.sample()["observation"].shape[-1] == 33
        algo_l, _ = load_policy(tr.run.checkpoints()[-1])
        assert algo_l.normalizer.in_dim == 33 and algo_l.normalizer.absolute_position
        st, g = data.state[:5], data.goal[:5]
        assert torch.equal(algo_l.act(st, g), tr.algo.act(st, g))
        # the absolute position counts: the same relative situation elsewhere is another input
        st2, g2 = st.clone(), g.clone()
        st2[:, :3] += 2.0
        g2[:, :3] += 2.0
        assert not torch.allclose(algo_l.normalizer.inputs(st2, g2), algo_l.normalizer.inputs(st, g))
    # a free-space dataset keeps the 30-d input and state dict
    free = fit_normalizer(load_dataset(straight_columns()), 0.05)
    assert free.in_dim == 30 and free.state_dict()["in_mean"].shape == (30,)


def test_position_features_layout_values_checkpoint_and_export(tmp_path):
    import numpy as np

    from aerohrl.algorithms.export import ExportedPolicy
    from aerohrl.algorithms.networks import Normalizer
    from aerohrl.errors import UserError

    torch.set_num_threads(1)
    root = write_synthetic_dataset(tmp_path / "maze" / "v1", spec={"world": "maze-medium"})
    data = load_dataset(root)
    cfg = make_config("cpu", algo="gcsl", dataset=str(root), pos_octaves=3, **dict(TINY, steps=20))
    tr = start_run(cfg, tmp_path / "pf", data=data, progress=False)
    tr.train()
    n = tr.algo.normalizer
    assert n.in_dim == 33 + 12 * 3 and tr.sampler.sample()["observation"].shape[-1] == 69
    assert n.state_dict()["in_mean"].shape == (33,) and len(n.goal_index) == 15 + 3 + 36
    # by hand: the features of the standardised state and goal positions, pi/2 * 2^k
    st, g = data.state[:7], data.goal[:7]
    x = n.inputs(st, g)
    m, sd = n.in_mean[30:33], n.in_std[30:33]
    for q, col in ((st[:, :3], 33), (g[:, :3], 33 + 18)):
        qn = (q - m) / sd
        for i in range(3):  # axis-major: axis i's three frequencies side by side
            f = math.pi / 2 * 2.0 ** torch.arange(3)
            assert torch.allclose(x[:, col + 3 * i : col + 3 * i + 3], torch.sin(f * qn[:, i : i + 1]), atol=1e-5)
            assert torch.allclose(x[:, col + 9 + 3 * i : col + 12 + 3 * i], torch.cos(f * qn[:, i : i + 1]), atol=1e-5)
    # the checkpoint records the layout; the loaded policy and the exported graph act alike
    algo_l, _ = load_policy(tr.run.checkpoints()[-1])
    assert algo_l.normalizer.pos_octaves == 3 and torch.equal(algo_l.act(st, g), tr.algo.act(st, g))
    exported = ExportedPolicy(algo_l).eval()
    with torch.no_grad():
        np.testing.assert_allclose(exported(st.float(), g.float()).numpy(), algo_l.act(st, g).numpy(), atol=1e-5)
    # free space has no absolute position to take features of
    with pytest.raises(UserError, match="pos-octaves"):
        Normalizer(absolute_position=False, pos_octaves=2)


def test_bad_hyperparameters_are_one_line_errors():
    for kw, msg in [
        ({"algo": "gciql", "gciql_expectile": 1.5}, "gciql_expectile"),
        ({"algo": "hiql", "hiql_expectile": 0.0}, "hiql_expectile"),
        ({"algo": "hiql", "hiql_subgoal_steps": 0}, "hiql_subgoal_steps"),
        ({"algo": "crl", "crl_contrastive": "triplet"}, "crl_contrastive"),
        ({"algo": "qrl", "qrl_latent_dim": 30, "qrl_components": 8}, "multiple of qrl_components"),
        ({"algo": "gciql", "gciql_value_p_trajgoal": 0.9}, "at most 1"),
        ({"algo": "qrl", "gamma": 1.0}, "gamma"),
    ]:
        with pytest.raises(ConfigError, match=msg) as e:
            make_config("cpu", **kw)
        assert "\n" not in str(e.value)


@pytest.mark.parametrize("algo", ["hiql", "qrl"])
def test_eval_and_planner_read_an_agent_run(algo, dataset_dir, tmp_path):
    """The trainer's closed-loop evaluation, `aerohrl eval` and the planner take these agents'
    runs as any other (QRL's critics have one row, HIQL's two)."""
    from aerohrl.cli import main

    torch.set_num_threads(1)
    cfg = make_config("cpu", algo=algo, dataset=str(dataset_dir), **dict(TINY, eval_every=20, eval_episodes=2, eval_horizon=20))
    start_run(cfg, tmp_path / "run", progress=False).train()
    common = ["--run", str(tmp_path / "run"), "--checkpoints", "1", "--quiet"]
    assert main(["eval", "--task", "reach-desired", "--episodes", "2", *common]) == 0
    ood = ["--task", "ood", "--episodes", "2", "--horizon", "40", "--candidates", "20", *common]
    assert main(["eval", *ood, "--planner", "single", "--alpha", "0.5"]) == 0
