"""The algorithm options: TD3-BC's alpha schedule, TD3-AWBC's advantage
normalisation with its logged weight statistics, CQL's Lagrange variant."""

import json
import warnings

import pytest
import torch

from aerohrl.algorithms.config import make_config
from aerohrl.algorithms.synthetic import write_synthetic_dataset
from aerohrl.algorithms.trainer import start_run
from aerohrl.errors import UserError

warnings.filterwarnings("ignore", category=UserWarning)
TINY = dict(hidden=(16, 16), critic_hidden=(16, 16), batch_size=64, steps=40, log_every=10, checkpoint_every=40, eval_every=0)


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    torch.set_num_threads(1)
    return write_synthetic_dataset(tmp_path_factory.mktemp("opts") / "ds")


def _metrics(run):
    return [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if '"step"' in line]


def test_awbc_std_normalisation_spreads_the_weights(ds, tmp_path):
    stats = {}
    for norm in ("none", "std"):
        cfg = make_config("cpu", algo="td3awbc", dataset=str(ds), awr_normalize=norm, awr_max_weight=3.0, **TINY)
        tr = start_run(cfg, tmp_path / norm, progress=False)
        tr.train()
        m = [r for r in _metrics(tmp_path / norm) if "awr_weight_std" in r]
        assert m and all(0.0 <= r["awr_clipped"] <= 1.0 for r in m)
        stats[norm] = max(r["awr_weight_std"] for r in m)
    assert stats["none"] < 0.05 < stats["std"]  # Q in [0, 1]: raw exp(A) ~ 1; normalised, the weights differ


def test_alpha_schedule_linear_fades_the_q_term(ds, tmp_path):
    cfg = make_config("cpu", algo="td3bc", dataset=str(ds), alpha=1.0, alpha_schedule="linear", policy_delay=1, **TINY)
    tr = start_run(cfg, tmp_path / "lin", progress=False)
    tr.train()
    assert tr.algo.critic_loss.alpha == pytest.approx(1.0 / 40, abs=1e-9)  # alpha (1 - 39/40) at the last update
    lam = [r["lambda"] for r in _metrics(tmp_path / "lin") if "lambda" in r]
    assert lam[-1] < lam[0]


def test_cql_lagrange_trains_its_multiplier(ds, tmp_path):
    cfg = make_config("cpu", algo="cql", dataset=str(ds), cql_lagrange_thresh=5.0, **TINY)
    tr = start_run(cfg, tmp_path / "cql", progress=False)
    before = tr.algo.cql_loss.log_alpha_prime.detach().clone()
    tr.train()
    assert "alpha_prime" in tr.algo.optimizers()
    assert not torch.equal(before, tr.algo.cql_loss.log_alpha_prime.detach())
    assert any("loss_alpha_prime" in r and "alpha_prime" in r and "cql_gap" in r for r in _metrics(tmp_path / "cql"))


def test_cql_lagrange_scales_the_penalty_and_ascends_on_it():
    """Kumar et al.'s form: the critics get α' ∇P (a penalty at any α'), α' grows while the
    gap exceeds τ and shrinks below it; no gradient crosses between the two."""
    from aerohrl.algorithms.cql import lagrange_terms

    for gap, grows in ((8.0, True), (2.0, False)):
        loss_cql = torch.tensor(2 * gap, requires_grad=True)  # mean(P1 + P2)
        log_ap = torch.tensor(float(torch.log(torch.tensor(3.0))), requires_grad=True)  # α' = 3 > 2
        critics, dual, ap, mean_gap = lagrange_terms(loss_cql, log_ap, thresh=5.0)
        critics.backward()
        assert loss_cql.grad.item() == pytest.approx(3.0) and log_ap.grad is None
        assert mean_gap.item() == pytest.approx(gap) and ap.item() == pytest.approx(3.0)
        dual.backward()
        assert loss_cql.grad.item() == pytest.approx(3.0)  # unchanged by the dual loss
        assert (log_ap.grad.item() < 0) == grows  # gradient descent on -α'(P̄ - τ)


@pytest.mark.parametrize(
    "kw, msg",
    [
        ({"alpha_schedule": "cosine"}, "alpha_schedule must be one of constant, linear"),
        ({"awr_normalize": "max"}, "awr_normalize must be one of std, none"),
        ({"cql_lagrange_thresh": -1.0}, "cql_lagrange_thresh must be >= 0"),
    ],
)
def test_bad_options_are_one_line_errors(ds, kw, msg):
    with pytest.raises(UserError, match=msg):
        make_config("cpu", algo="td3bc", dataset=str(ds), **kw)
