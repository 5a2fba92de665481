"""CQL (Kumar et al. 2020) made goal-conditioned, on torchrl's ``CQLLoss``.

* CQL proper: a SAC-style ``TanhNormal`` actor and torchrl's ``CQLLoss`` (critic TD loss +
  the conservative penalty ``logsumexp_a Q(s, a) - Q(s, a_data)`` over random,
  current-policy and next-policy actions in the [-1, 1] action box, automatic entropy
  temperature), its targets clipped to [0, 1] like every critic here. One summed loss,
  one optimiser per parameter group (actor, CQL critics, alpha), as torchrl's sota CQL.
* The 5-critic ensemble (Eq. 3.2) beside it: ``CQLLoss`` hard-codes 2 critics and its
  penalty code is written for exactly ``q1``/``q2``, so it cannot hold the planner's
  ensemble. The ensemble is therefore trained by the same clipped TD loss as GCSL's
  (``TD3BCLoss.qvalue_loss`` on 5 critics), the next action being the CQL policy's
  deterministic action ``tanh(loc)`` (Alg. 2: the next action comes from the learned
  policy). ``critics()`` returns that ensemble, as for every algorithm.
* Targets of both critic sets: ``SoftUpdate``.

Its settings: :class:`CQLConfig` (``cfg.cql``).
"""

from __future__ import annotations

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.data import Bounded
from torchrl.modules import ProbabilisticActor, TanhNormal
from torchrl.objectives import CQLLoss

from typing import TYPE_CHECKING

from aerohrl.algorithms.config import CQLConfig, critic_sizes
from aerohrl.algorithms.base import Algorithm
from aerohrl.algorithms.networks import ACT_DIM, adam, EnsembleSoftUpdate, make_critic, make_critic_loss, mlp, use_clipped_td0

if TYPE_CHECKING:
    from tensordict import TensorDict


class _TanhLoc(nn.Module):
    """The CQL policy's deterministic action: tanh of the TanhNormal's location."""

    def __init__(self, net):
        super().__init__()
        self.net = net

    def forward(self, observation):
        loc, _ = self.net(observation)
        return torch.tanh(loc)


def lagrange_terms(
    loss_cql: torch.Tensor, log_alpha_prime: torch.Tensor, thresh: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """CQL's Lagrange form (Kumar et al. 2020, CQL(H) with an automatically tuned
    penalty weight; their code's ``with_lagrange``): the critics minimise ``α' (P1 + P2 - 2τ)`` with α' held fixed, and α'
    maximises ``α' (P̄ - τ)`` with the penalties held fixed, where ``P_i = min_q_weight ·
    (logsumexp_a Q_i(s, a) - Q_i(s, a_data))`` and ``P̄`` their mean over the two critics.

    ``loss_cql`` is torchrl's ``CQLLoss`` output ``mean(P1 + P2)``. Written here because
    torchrl's own pieces do not give this: its ``loss_cql`` is never scaled by α', and its
    ``loss_alpha_prime = -α' (P̄ - τ)`` keeps the critics' graph, so adding it to the
    critics' loss (as torchrl's sota script does) gives them ``-α'/2 ∇P``: the penalty turns
    into a bonus once α' exceeds 2. Returns (critics' term, α' loss, α', P̄)."""
    alpha_prime = log_alpha_prime.exp().clamp(max=1e6)
    gap = loss_cql.detach() / 2
    return alpha_prime.detach() * (loss_cql - 2 * thresh), -alpha_prime * (gap - thresh), alpha_prime.detach(), gap


class CQL(Algorithm):
    name = "cql"

    def __init__(self, cfg, normalizer):
        super().__init__(cfg, normalizer)
        net = nn.Sequential(mlp(normalizer.in_dim, 2 * ACT_DIM, cfg.hidden), NormalParamExtractor())
        params = TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"])
        spec = Bounded(-torch.ones(ACT_DIM), torch.ones(ACT_DIM), (ACT_DIM,))
        self.actor = ProbabilisticActor(
            params,
            in_keys=["loc", "scale"],
            spec=spec,
            distribution_class=TanhNormal,
            distribution_kwargs={"low": -1.0, "high": 1.0},
            return_log_prob=False,
        )
        # the deterministic policy: tanh of the location (shares the actor's weights)
        self.det_actor = TensorDictSequential(
            params, TensorDictModule(torch.tanh, in_keys=["loc"], out_keys=["action"]), selected_out_keys=["action"]
        )
        self.cql_loss = CQLLoss(
            self.actor,
            [make_critic(critic_sizes(cfg), normalizer.in_dim) for _ in range(2)],
            loss_function="l2",
            action_spec=spec,
            min_q_weight=cfg.cql.cql_min_q_weight,
            num_random=cfg.cql.cql_num_random,
            deterministic_backup=False,
            with_lagrange=cfg.cql.cql_lagrange_thresh > 0,
            lagrange_thresh=cfg.cql.cql_lagrange_thresh,
        )
        use_clipped_td0(self.cql_loss, cfg.gamma, self.cql_loss.tensor_keys.value)
        self.critic_loss = make_critic_loss(
            self.det_actor,
            critic_sizes(cfg),
            num_critics=cfg.num_critics,
            gamma=cfg.gamma,
            delay_actor=False,
            policy_noise=0.0,
            noise_clip=0.0,
            in_dim=normalizer.in_dim,
        )
        self.cql_updater = EnsembleSoftUpdate(self.cql_loss, tau=cfg.tau)
        self.target_updater = EnsembleSoftUpdate(self.critic_loss, tau=cfg.tau)
        self.actor_opt = adam(self.cql_loss.actor_network_params.values(True, True), lr=cfg.lr_actor)
        self.cql_critic_opt = adam(self.cql_loss.qvalue_network_params.values(True, True), lr=cfg.lr_critic)
        self.alpha_opt = adam([self.cql_loss.log_alpha], lr=cfg.lr_actor)
        # the Lagrange variant's multiplier (its own optimiser: gradient ascent on the gap)
        self.alpha_prime_opt = (
            adam([self.cql_loss.log_alpha_prime], lr=cfg.lr_critic) if cfg.cql.cql_lagrange_thresh > 0 else None
        )
        self.critic_opt = adam(self.critic_loss.qvalue_network_params.values(True, True), lr=cfg.lr_critic)
        # tanh(loc) as a module sharing the actor's weights; kept out of the module tree
        # (its weights are the actor's, already in the state dict)
        object.__setattr__(self, "_det_net", _TanhLoc(net))
        self.setup_ema()

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """The optimisers by name: actor, conservative critics, temperature (and its Lagrange
        multiplier when tuned), and the TD3BC-style critic ensemble."""
        opts = {"actor": self.actor_opt, "cql_critic": self.cql_critic_opt, "alpha": self.alpha_opt, "critic": self.critic_opt}
        if self.alpha_prime_opt is not None:
            opts["alpha_prime"] = self.alpha_prime_opt
        return opts

    def policy_net(self) -> nn.Module:
        """The deterministic policy: the mean of the tanh-Gaussian actor."""
        return self._det_net

    def update(self, batch: TensorDict) -> dict[str, torch.Tensor]:
        """One CQL step (actor, conservative critics, temperature) and one step of the evaluation
        critic ensemble; the losses by name."""
        # 1. CQL: actor, conservative critics, entropy temperature (disjoint gradients)
        out = self.cql_loss(batch.clone(False))
        penalty, lagrange = out["loss_cql"], {}
        opts = [self.actor_opt, self.cql_critic_opt, self.alpha_opt]
        if self.alpha_prime_opt is not None:  # Lagrange form: α' scales the penalty, and ascends on it
            penalty, loss_alpha_prime, alpha_prime, gap = lagrange_terms(
                out["loss_cql"], self.cql_loss.log_alpha_prime, self.cfg.cql.cql_lagrange_thresh
            )
            penalty = penalty + loss_alpha_prime  # disjoint gradients: critics | log α'
            lagrange = {"loss_alpha_prime": loss_alpha_prime.detach(), "alpha_prime": alpha_prime, "cql_gap": gap}
            opts.append(self.alpha_prime_opt)
        loss = out["loss_actor"] + out["loss_qvalue"] + penalty + out["loss_alpha"]
        for opt in opts:
            opt.zero_grad(set_to_none=True)
        loss.backward()
        for opt in opts:
            opt.step()
        self.ema_step()
        # 2. the planner's 5-critic ensemble, Eq. 3.2, next action from the CQL policy
        loss_q, meta = self.critic_loss.qvalue_loss(self.critic_batch(batch))
        self.critic_opt.zero_grad(set_to_none=True)
        loss_q.backward()
        self.critic_opt.step()
        self.cql_updater.step()
        self.target_updater.step()
        self.num_updates += 1
        return {
            "loss_actor": out["loss_actor"].detach(),
            "loss_cql_qvalue": out["loss_qvalue"].detach(),
            "loss_cql": out["loss_cql"].detach(),
            "alpha": out["alpha"].detach(),
            **lagrange,
            "loss_critic": loss_q.detach(),
            "q_mean": meta["pred_value"].mean(),
            "target_mean": meta["target_value"].mean(),
        }


__all__ = ["CQL", "CQLConfig"]
