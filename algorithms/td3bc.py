"""TD3-BC (Fujimoto & Gu 2021) made goal-conditioned, on torchrl's ``TD3BCLoss``.

* critics (every step): the ensemble of ``num_critics`` (5) goal-conditioned critics,
  ``y = clip(r + gamma (1 - done) min_j Q'_j(s', pi'(s') + eps, g), 0, 1)``, with TD3's
  target policy smoothing. ``TD3BCLoss`` takes the minimum over *all* its critics, which
  is thesis Eq. 3.2 as written; the [0, 1] clip comes from
  :class:`~aerohrl.algorithms.networks.ClippedTD0Estimator` plugged into the loss.
* actor (every ``policy_delay`` steps): ``-lambda Q_0(s, pi(s)) + (pi(s) - a)^2``,
  ``lambda = alpha / mean|Q_0|``; ``alpha_schedule = "linear"`` anneals alpha to 0 over
  the run (an option of the TD3-BC sweep: the Q-term shapes the start, BC the end). ``TD3BCLoss``'s actor reads only the first critic, as
  the original TD3-BC reads Q1; kept as is (the 5 critics share targets, so Q_0 is one
  member of the same ensemble).
* targets (actor and critics): ``SoftUpdate`` on the delayed steps, as in TD3.

Its settings: :class:`TD3BCConfig` (``cfg.td3bc``; declared in algorithms/config.py, which
``train --help`` imports without torch).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import nn

from aerohrl.algorithms.config import TD3BCConfig, critic_sizes
from aerohrl.algorithms.base import Algorithm
from aerohrl.algorithms.networks import adam, EnsembleSoftUpdate, make_actor, make_critic_loss

if TYPE_CHECKING:
    from tensordict import TensorDict


class TD3BC(Algorithm):
    name = "td3bc"

    def _make_loss(self, cfg, actor):
        return make_critic_loss(
            actor,
            critic_sizes(cfg),
            num_critics=cfg.num_critics,
            gamma=cfg.gamma,
            delay_actor=True,
            policy_noise=cfg.td3bc.policy_noise,
            noise_clip=cfg.td3bc.noise_clip,
            alpha=cfg.td3bc.alpha,
            in_dim=self.normalizer.in_dim,
        )

    def __init__(self, cfg, normalizer):
        super().__init__(cfg, normalizer)
        self.actor = make_actor(cfg.hidden, normalizer.in_dim)
        self.critic_loss = self._make_loss(cfg, self.actor)
        self.target_updater = EnsembleSoftUpdate(self.critic_loss, tau=cfg.tau)
        self.actor_opt = adam(self.critic_loss.actor_network_params.values(True, True), lr=cfg.lr_actor)
        self.critic_opt = adam(self.critic_loss.qvalue_network_params.values(True, True), lr=cfg.lr_critic)
        self._last_actor = {}
        self.setup_ema()

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """The optimisers by name: the actor's and the critic ensemble's."""
        return {"actor": self.actor_opt, "critic": self.critic_opt}

    def policy_net(self) -> nn.Module:
        """The deterministic actor network."""
        return self.actor.module

    def update(self, batch: TensorDict) -> dict[str, torch.Tensor]:
        """One critic step (clipped TD(0) targets over the ensemble) and, every ``policy_delay``
        updates, one actor step on ``-lambda Q + BC``; the losses by name."""
        loss_q, meta = self.critic_loss.qvalue_loss(self.critic_batch(batch))
        self.critic_opt.zero_grad(set_to_none=True)
        loss_q.backward()
        self.critic_opt.step()
        self.num_updates += 1
        if self.num_updates % self.cfg.td3bc.policy_delay == 0:
            if self.cfg.td3bc.alpha_schedule == "linear":  # the Q-term fades to 0 at the last step; BC stays
                self.critic_loss.alpha = self.cfg.td3bc.alpha * max(0.0, 1.0 - (self.num_updates - 1) / self.cfg.steps)
            loss_pi, ameta = self.critic_loss.actor_loss(self.actor_batch(batch))
            self.actor_opt.zero_grad(set_to_none=True)
            loss_pi.backward()
            self.actor_opt.step()
            self.ema_step()
            self.target_updater.step()
            self._last_actor = {"loss_actor": loss_pi.detach(), "bc_loss": ameta["bc_loss"], **self._actor_extras(ameta)}
        return {
            "loss_critic": loss_q.detach(),
            "q_mean": meta["pred_value"].mean(),
            "target_mean": meta["target_value"].mean(),
            **self._last_actor,
        }

    def _actor_extras(self, meta):
        return {"lambda": meta["lmbd"].detach()}


__all__ = ["TD3BC", "TD3BCConfig"]
