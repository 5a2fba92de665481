"""The shared algorithm interface, for all four algorithms, on tiny networks."""

import warnings

import pytest
import torch

from aerohrl.algorithms.base import algorithm_class, build_algorithm
from aerohrl.algorithms.config import ALGORITHMS, ENSEMBLE_ALGORITHMS, make_config
from aerohrl.algorithms.data import GoalBatchSampler, fit_normalizer, load_dataset
from aerohrl.algorithms.networks import ClippedTD0Estimator, ensemble_values
from aerohrl.algorithms.synthetic import straight_columns
from aerohrl.errors import UserError

warnings.filterwarnings("ignore", category=UserWarning)


@pytest.fixture(scope="module")
def data():
    return load_dataset(straight_columns(n_eps=4, length=30))


def _build(algo, data, **kw):
    torch.manual_seed(0)
    cfg = make_config("cpu", algo=algo, hidden=(16, 16), critic_hidden=(16, 16), batch_size=32, **kw)
    norm = fit_normalizer(data, cfg.relabel_prob)
    a = build_algorithm(cfg, norm)
    s = GoalBatchSampler(
        data,
        norm,
        cfg.batch_size,
        cfg.relabel_prob,
        torch.Generator().manual_seed(0),
        **algorithm_class(algo).sampler_options(cfg),
    )
    return a, s


@pytest.mark.parametrize("algo", ENSEMBLE_ALGORITHMS)  # the 5-critic torchrl ensemble; tests/test_agents.py: the OGBench agents
def test_update_act_critics(algo, data):
    torch.set_num_threads(1)
    a, s = _build(algo, data)
    q0 = a.critic_loss.qvalue_network_params.clone()
    t0 = a.critic_loss.target_qvalue_network_params.clone()
    for _ in range(4):
        m = a.update(s.sample())
    assert m and all(torch.isfinite(v) for v in m.values())
    assert "loss_critic" in m
    # the ensemble and its targets both moved; the targets lag behind
    moved = (a.critic_loss.qvalue_network_params - q0).abs().max()
    lag = (a.critic_loss.target_qvalue_network_params - t0).abs().max()
    assert all(float(v.detach()) > 0 for v in moved.values(True, True))
    assert all(0 < float(v) for v in lag.values(True, True))
    assert a.critic_loss.qvalue_network_params.batch_size[0] == 5
    st, g = data.state[:7], data.goal[:7]
    act = a.act(st, g)
    assert act.shape == (7, 4) and torch.equal(act, a.act(st, g))  # deterministic
    # actions are in physical units, inside the data's widened bounds
    lo, hi = a.normalizer.act_center - a.normalizer.act_half, a.normalizer.act_center + a.normalizer.act_half
    assert ((act >= lo - 1e-5) & (act <= hi + 1e-5)).all()
    q = a.critics(st, g, data.action[:7])
    assert q.shape == (5, 7) and torch.isfinite(q).all()
    # translation invariance: shifting state and goal by the same offset changes nothing
    off = torch.tensor([3.0, -2.0, 1.0])
    st2, g2 = st.clone(), g.clone()
    st2[:, :3] += off
    g2[:, :3] += off
    assert torch.allclose(a.act(st2, g2), act, atol=1e-5)
    assert torch.allclose(a.critics(st2, g2, data.action[:7]), q, atol=1e-5)


def test_gcsl_policy_alone(data):
    """--no-train-critics: GCSL's policy learns as before, its critics stay where they were
    initialised, and asking the run for critic values is a one-line error."""
    torch.set_num_threads(1)
    a, s = _build("gcsl", data, train_critics=False)
    q0 = a.critic_loss.qvalue_network_params.clone()
    p0 = [p.detach().clone() for p in a.policy_net().parameters()]
    for _ in range(3):
        m = a.update(s.sample())
    assert set(m) == {"loss_actor"} and torch.isfinite(m["loss_actor"])
    assert a.num_updates == 3
    assert any(not torch.equal(p, q) for p, q in zip(p0, a.policy_net().parameters()))
    assert all(torch.equal(v, w) for v, w in zip(q0.values(True, True), a.critic_loss.qvalue_network_params.values(True, True)))
    # the same batches give the same policy with and without the critics (they never touch it)
    b, s2 = _build("gcsl", data)
    for _ in range(3):
        b.update(s2.sample())
    assert all(torch.allclose(p, q) for p, q in zip(b.policy_net().parameters(), a.policy_net().parameters()))
    with pytest.raises(UserError, match="no critics"):
        a.critics(data.state[:2], data.goal[:2], data.action[:2])


@pytest.mark.parametrize("algo", ["td3bc", "cql", "gciql"])
def test_policy_alone_is_gcsl_only(algo):
    with pytest.raises(UserError, match="GCSL's"):
        make_config("cpu", algo=algo, train_critics=False)


def test_targets_clipped_to_unit_interval(data):
    a, s = _build("td3bc", data, gamma=1.0)
    est = a.critic_loss.value_estimator
    assert isinstance(est, ClippedTD0Estimator)
    b = s.sample()
    b["next", "reward"] = torch.ones_like(b["next", "reward"])
    b["next", "done"] = torch.zeros_like(b["next", "done"])
    b["next", "terminated"] = torch.zeros_like(b["next", "terminated"])
    b.set(("next", "state_action_value"), torch.full_like(b["next", "reward"], 5.0))
    assert torch.all(est.value_estimate(b) == 1.0)
    b.set(("next", "state_action_value"), torch.full_like(b["next", "reward"], -9.0))
    b["next", "reward"] = torch.zeros_like(b["next", "reward"])
    assert torch.all(est.value_estimate(b) == 0.0)
    _, meta = a.critic_loss.qvalue_loss(s.sample())
    assert meta["target_value"].min() >= 0 and meta["target_value"].max() <= 1


def test_target_is_min_over_all_five_critics(data):
    """TD3BCLoss's target: r + gamma (1 - done) min_j Q'_j(s', a') -- checked by hand (GCSL:
    a' = pi(s'), no noise)."""
    a, s = _build("gcsl", data)
    b = s.sample()
    _, meta = a.critic_loss.qvalue_loss(b)
    with torch.no_grad():
        a_next = a.actor.module(b["next", "observation"])
        qn = ensemble_values(a.critic_loss, b["next", "observation"], a_next, params=a.critic_loss.target_qvalue_network_params)
        y = (b["next", "reward"].squeeze(-1) + 0.99 * (~b["next", "done"].squeeze(-1)).float() * qn.min(0).values).clamp(0, 1)
    assert qn.shape[0] == 5
    assert torch.allclose(meta["target_value"], y, atol=1e-5)


def test_gcsl_policy_fits_the_data(data):
    """Eq. 3.1: a few hundred BC steps reduce the normalised action error."""
    torch.set_num_threads(1)
    a, s = _build("gcsl", data, lr_actor=3e-3)
    first = float(a.update(s.sample())["loss_actor"])
    for _ in range(150):
        m = a.update(s.sample())
    assert float(m["loss_actor"]) < 0.5 * first


def test_unknown_algorithm_and_preset():
    with pytest.raises(UserError, match="algo must be one of gcsl, td3bc, td3awbc, cql, gciql, crl, qrl, hiql, got 'ppo'"):
        make_config("cpu", algo="ppo")
    with pytest.raises(UserError, match="unknown preset"):
        make_config("gpu")


def test_presets():
    t = make_config("thesis")
    assert t.hidden == (512, 2048, 2048, 512) and t.batch_size == 1048 and t.steps == 2_000_000
    c = make_config("cpu", steps=123, batch_size=7)
    assert c.steps == 123 and c.batch_size == 7 and c.num_critics == 5
    # per-algorithm values of the cpu preset (GCSL's relabelling probability), under the flags
    assert make_config("cpu", algo="gcsl").relabel_prob == 0.01
    assert {make_config("cpu", algo=a).relabel_prob for a in ("td3bc", "td3awbc", "cql")} == {0.05}
    assert make_config("cpu", algo="gcsl", relabel_prob=0.2).relabel_prob == 0.2
    assert make_config("thesis", algo="gcsl").relabel_prob == 0.5  # the thesis preset has none


def test_loader_rejects_bad_columns():
    cols = straight_columns(n_eps=2, length=5)
    bad = dict(cols, action=cols["action"][:, :3])
    with pytest.raises(UserError, match="shape"):
        load_dataset(bad)
    nan = dict(cols)
    nan["observation.state"] = cols["observation.state"].copy()
    nan["observation.state"][3, 2] = float("nan")
    with pytest.raises(UserError, match="NaN"):
        load_dataset(nan)
    with pytest.raises(UserError, match="no 'action'"):
        load_dataset({k: v for k, v in cols.items() if k != "action"})


@pytest.mark.parametrize("algo", ALGORITHMS)
def test_ema_policy_acts_and_round_trips(algo, data):
    """--ema-decay: act() uses the averaged weights, which trail the trained ones and are
    part of the state dict (a checkpoint restores the same actions)."""
    torch.set_num_threads(1)
    a, s = _build(algo, data, ema_decay=0.9)
    for _ in range(6):
        a.update(s.sample())
    st, g = data.state[:5], data.goal[:5]
    x = a.normalizer.inputs(st, g)
    with torch.no_grad():
        raw = a.policy_net()(x)
        ema = a.policy_ema.module(x)
    assert not torch.allclose(raw, ema)
    assert torch.allclose(a.normalizer.action_to_unit(a.act(st, g)), ema, atol=1e-5)
    b, _ = _build(algo, data, ema_decay=0.9)
    b.load_state_dict(a.state_dict())
    assert torch.allclose(b.act(st, g), a.act(st, g))


def test_mc_lower_bound_raises_targets_to_the_data_return(data):
    """--mc-lower-bound: each target is at least gamma^(steps until the data reaches the
    goal), and exactly the clipped TD target where that is larger."""
    cfg = make_config("cpu", hidden=(16, 16), critic_hidden=(16, 16), batch_size=256, relabel_prob=0.5, mc_lower_bound=True)
    norm = fit_normalizer(data, cfg.relabel_prob)
    torch.manual_seed(0)
    a = build_algorithm(cfg, norm)
    s = GoalBatchSampler(data, norm, cfg.batch_size, cfg.relabel_prob, torch.Generator().manual_seed(0), mc_gamma=cfg.gamma)
    b = s.sample()
    lb = b.get("mc_lower_bound").squeeze(-1)
    assert (lb > 0).all() and (lb <= 1).all()  # every straight-line episode reaches its goal
    r = b.get(("next", "reward")).squeeze(-1) > 0
    desired = ~b.get("relabelled")
    assert (r & desired).any() and torch.allclose(lb[r & desired], torch.tensor(1.0))
    _, meta = a.critic_loss.qvalue_loss(b)
    tgt = meta["target_value"]
    assert torch.allclose(tgt[r], torch.tensor(1.0))
    assert (tgt >= lb - 1e-6).all()
    b2 = b.exclude("mc_lower_bound")
    _, meta2 = a.critic_loss.qvalue_loss(b2)
    assert torch.allclose(tgt, torch.maximum(meta2["target_value"], lb))
    assert (tgt > meta2["target_value"] + 1e-3).any()  # fresh critics: the bound is what lifts them


def test_first_hit_index_by_hand():
    from aerohrl.algorithms.relabel import first_hit_index, mc_lower_bound

    # two episodes of 4 frames; the goal is the origin state; frame 2 and frame 5 reach it
    F = 8
    goal = torch.zeros(F, 15)
    goal[:, 6:15] = torch.eye(3).flatten()
    nxt = torch.zeros(F, 18)
    nxt[:, 6:15] = torch.eye(3).flatten()
    nxt[:, 0] = 5.0
    nxt[2, 0] = 0.0
    nxt[5, 0] = 0.0
    end = torch.tensor([3, 3, 3, 3, 7, 7, 7, 7])
    hit = first_hit_index(nxt, goal, end)
    assert hit.tolist() == [2, 2, 2, -1, 5, 5, -1, -1]
    idx = torch.arange(F)
    k = torch.tensor([3, 3, 3, 3, 7, 6, 7, 7])
    relab = torch.tensor([False, True, False, False, False, False, True, False])
    lb = mc_lower_bound(idx, k, relab, hit, 0.5)
    assert lb.tolist() == [0.25, 0.25, 1.0, 0.0, 0.5, 1.0, 0.5, 0.0]
