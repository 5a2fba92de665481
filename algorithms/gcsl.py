"""GCSL: goal-conditioned behaviour cloning on relabelled goals (thesis Eq. 3.1, Alg. 2),
plus the 5-critic ensemble the planner needs (Eq. 3.2).

Per step (Alg. 2 lines 5-7):
1. policy: ``min E[(pi(s, g) - a)^2]`` on relabelled goals -- torchrl's ``BCLoss`` (MSE);
2. critics: ``y = clip(r + gamma (1 - done) min_j Q'_j(s', pi(s', g), g), 0, 1)``, the next
   action from the *learned* policy without noise (``TD3BCLoss.qvalue_loss`` with
   ``delay_actor=False, policy_noise=0``: its "target actor" is then the actor itself);
3. targets: ``SoftUpdate`` (phi' <- (1 - tau) phi' + tau phi).

Steps 2-3 serve the planner only: with ``train_critics`` off the run learns the policy alone,
at about half the cost of a step, and cannot plan.
"""

from __future__ import annotations

import warnings

from typing import TYPE_CHECKING

import torch
from torch import nn
from torchrl.objectives import BCLoss

from aerohrl.algorithms.config import critic_sizes
from aerohrl.algorithms.base import Algorithm
from aerohrl.algorithms.networks import adam, EnsembleSoftUpdate, make_actor, make_critic_loss

if TYPE_CHECKING:
    from tensordict import TensorDict


class GCSL(Algorithm):
    name = "gcsl"

    def __init__(self, cfg, normalizer):
        super().__init__(cfg, normalizer)
        self.actor = make_actor(cfg.hidden, normalizer.in_dim)
        with warnings.catch_warnings():  # torchrl: "target_actor_network_params wasn't part of the annotations"
            warnings.filterwarnings("ignore", message=".*target_actor_network_params.*")
            self.bc_loss = BCLoss(self.actor, loss_function="l2")
        self.critic_loss = make_critic_loss(
            self.actor,
            critic_sizes(cfg),
            num_critics=cfg.num_critics,
            gamma=cfg.gamma,
            delay_actor=False,
            policy_noise=0.0,
            noise_clip=0.0,
            in_dim=normalizer.in_dim,
        )
        self.target_updater = EnsembleSoftUpdate(self.critic_loss, tau=cfg.tau)
        self.actor_opt = adam(self.actor.parameters(), lr=cfg.lr_actor)
        self.critic_opt = adam(self.critic_loss.qvalue_network_params.values(True, True), lr=cfg.lr_critic)
        self.setup_ema()

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """The optimisers by name: the actor's and the critic ensemble's."""
        return {"actor": self.actor_opt, "critic": self.critic_opt}

    def policy_net(self) -> nn.Module:
        """The deterministic actor network."""
        return self.actor.module

    def update(self, batch: TensorDict) -> dict[str, torch.Tensor]:
        """One behaviour-cloning step on the relabelled goals (Eq. 3.1) and one step of the
        evaluation critic ensemble (unless ``train_critics`` is off); the losses by name."""
        # 1. behaviour cloning on the (relabelled) goals, Eq. 3.1
        loss_bc = self.bc_loss(self.actor_batch(batch))["loss_bc"]
        self.actor_opt.zero_grad(set_to_none=True)
        loss_bc.backward()
        self.actor_opt.step()
        self.ema_step()
        self.num_updates += 1
        if not self.cfg.train_critics:  # a policy-only run (--no-train-critics)
            return {"loss_actor": loss_bc.detach()}
        # 2. the critic ensemble, Eq. 3.2 (next action from the updated policy, no grad)
        loss_q, meta = self.critic_loss.qvalue_loss(self.critic_batch(batch))
        self.critic_opt.zero_grad(set_to_none=True)
        loss_q.backward()
        self.critic_opt.step()
        # 3. target critics
        self.target_updater.step()
        return {
            "loss_actor": loss_bc.detach(),
            "loss_critic": loss_q.detach(),
            "q_mean": meta["pred_value"].mean(),
            "target_mean": meta["target_value"].mean(),
        }
