"""The shared algorithm interface, for all four algorithms, on tiny networks."""

import warnings

import pytest
import torch

from aerohrl.algorithms.base import build_algorithm
from aerohrl.algorithms.config import ALGORITHMS, make_config
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
    s = GoalBatchSampler(data, norm, cfg.batch_size, cfg.relabel_prob, torch.Generator().manual_seed(0))
    return a, s


@pytest.mark.parametrize("algo", ALGORITHMS)
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
    with pytest.raises(UserError, match="unknown algorithm"):
        make_config("cpu", algo="ppo")
    with pytest.raises(UserError, match="unknown preset"):
        make_config("gpu")


def test_presets():
    t = make_config("thesis")
    assert t.hidden == (512, 2048, 2048, 512) and t.batch_size == 1048 and t.steps == 2_000_000
    c = make_config("cpu", steps=123, batch_size=7)
    assert c.steps == 123 and c.batch_size == 7 and c.num_critics == 5


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
