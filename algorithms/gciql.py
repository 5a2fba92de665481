"""GCIQL: goal-conditioned implicit Q-learning, as OGBench's reference agent (Park et al.
2024, ``agents/gciql.py``; IQL: Kostrikov et al. 2022).

Internally in OGBench's units: reward ``r = -1`` per step and 0 on the transition that
reaches the goal, which ends the episode (``mask = 1 - done``), so ``V(s, g) =
-(1 - gamma^d) / (1 - gamma)`` for a goal ``d`` steps away and OGBench's hyperparameters
(expectile, AWR temperature, the ``-Q / mean|Q|`` scaling) mean what they mean there.

One step, all three losses on the same batch, one backward (OGBench's joint update):

* value (goals from the ``"value"`` mix):
  ``L_V = E[ |tau - 1(Q' - V < 0)| (Q' - V)^2 ]``, ``Q' = min_j Q'_j(s, a, g)`` (target critics),
  the expectile regression of torchrl's ``IQLLoss.loss_value_diff``;
* critics (the same goals): ``L_Q = sum_j E[(Q_j(s, a, g) - (r + gamma mask V(s', g)))^2]``;
* actor (goals from the ``"actor"`` mix), ``gciql_actor_loss``:
  ``ddpgbc`` (OGBench's default): ``-min_j Q_j(s, pi(s, g), g) / mean|Q| + alpha * (-log N(a; pi(s, g), I))``;
  ``awr``: ``-E[min(exp(alpha (min_j Q'_j(s, a, g) - V(s, g))), 100) log N(a; pi(s, g), I)]``
  (the advantage from the target critics, as IQL and torchrl's ``IQLLoss`` take it);
* target critics: Polyak averaging with ``tau``.

Why not torchrl's ``IQLLoss`` as a whole: it is IQL with an AWR actor only (no DDPG+BC,
OGBench's default for GCIQL), it expects a stochastic ``ProbabilisticActor`` and its value
estimator reads torchrl's reward/done keys in the toolkit's [0, 1] units, not OGBench's;
its expectile loss (``IQLLoss.loss_value_diff``) is used as is.

Differences from OGBench, and why:

* the actor is the toolkit's deterministic ``tanh`` MLP (actions in [-1, 1], like every
  actor here and what ``act`` returns); OGBench's const-std Gaussian has an unsquashed
  mean, clipped to [-1, 1]. The BC term is the same unit-std Gaussian log-likelihood;
* networks: the toolkit's sizes (``hidden`` for the actor, ``critic_hidden`` for V and
  Q; OGBench 4 x 512) and learning rates (``lr_actor``, ``lr_critic``; OGBench 3e-4);
* gamma is the run's ``gamma`` (0.99 as OGBench). At 100 Hz control that is a 1 s
  horizon; OGBench's environments step at 10-50 Hz, so the same gamma sees 2-10x fewer
  seconds ahead. Raise gamma (e.g. 0.995-0.999) for long flights;
* goals are this toolkit's achieved goals ``[p, v, R]`` (relabel.GoalMix has the index
  shift against OGBench's current/trajectory goals).

``critics(state, goal, action)`` -> (2, B): ``1 + (1 - gamma) Q_j(s, a, g)``, i.e.
``gamma^d`` for a goal d steps away, clipped to [0, 1] (the toolkit's discounted success).
Settings: :class:`GCIQLConfig` (``cfg.gciql``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import nn
from torchrl.objectives.iql import IQLLoss

from aerohrl.algorithms.base import Algorithm
from aerohrl.algorithms.config import GCIQLConfig, critic_sizes, goal_mix
from aerohrl.algorithms.networks import (
    ACT_DIM,
    adam,
    Twin,
    frozen,
    gaussian_log_prob,
    ln_mlp,
    make_actor,
    make_target,
    success_value,
)

if TYPE_CHECKING:
    from tensordict import TensorDict

    from aerohrl.algorithms.config import TrainConfig

AWR_MAX_WEIGHT = 100.0  # OGBench's clip of exp(alpha A)


def expectile_value_loss(q: torch.Tensor, v: torch.Tensor, expectile: float) -> torch.Tensor:
    """IQL's value loss ``E[|tau - 1(q - v < 0)| (q - v)^2]`` (torchrl's ``IQLLoss.loss_value_diff``)."""
    return IQLLoss.loss_value_diff(q - v, expectile).mean()


def ogbench_reward_mask(td: TensorDict) -> tuple[torch.Tensor, torch.Tensor]:
    """OGBench's ``(reward, mask)`` from the toolkit's sparse batch: ``r = success - 1``
    (0 on the transition that reaches the goal, -1 otherwise), ``mask = 1 - done``. (B,) each."""
    r = td.get(("next", "reward")).squeeze(-1)
    done = td.get(("next", "done")).squeeze(-1).to(r.dtype)
    return r - 1.0, 1.0 - done


class GCIQL(Algorithm):
    name = "gciql"

    @classmethod
    def sampler_options(cls, cfg: TrainConfig) -> dict:
        """Value goals and actor goals from their OGBench mixes (``gciql_value_p_*``, ``gciql_actor_p_*``)."""
        return {"goal_mixes": {"value": goal_mix(cfg, "value"), "actor": goal_mix(cfg, "actor")}}

    def __init__(self, cfg, normalizer):
        super().__init__(cfg, normalizer)
        n_in, hv = normalizer.in_dim, critic_sizes(cfg)
        self.value = ln_mlp(n_in, 1, hv)  # V(s, g)
        self.critic = Twin(lambda: ln_mlp(n_in + ACT_DIM, 1, hv))  # Q_1, Q_2 (s, a, g)
        self.target_critic = make_target(self.critic, cfg.tau)
        self.actor = make_actor(cfg.hidden, n_in)
        self.critic_opt = adam([*self.value.parameters(), *self.critic.parameters()], lr=cfg.lr_critic)
        self.actor_opt = adam(self.actor.parameters(), lr=cfg.lr_actor)
        self.setup_ema()

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """The optimisers by name: the actor's and the value + critics'."""
        return {"actor": self.actor_opt, "critic": self.critic_opt}

    def policy_net(self) -> nn.Module:
        """The deterministic actor network."""
        return self.actor.module

    def losses(self, batch: TensorDict) -> dict[str, torch.Tensor]:
        """The value, critic and actor losses of one batch (module docstring), with statistics."""
        c: GCIQLConfig = self.cfg.gciql
        gamma = self.cfg.gamma
        vb, ab = batch.get("value"), self.actor_batch(batch.get("actor"))
        x, x_next, a = vb.get("observation"), vb.get(("next", "observation")), vb.get("action")
        r, mask = ogbench_reward_mask(vb)
        # value: expectile regression towards the target critics' minimum
        with torch.no_grad():
            q_target = self.target_critic(x, a).squeeze(-1).min(0).values
        v = self.value(x).squeeze(-1)
        loss_value = expectile_value_loss(q_target, v, c.gciql_expectile)
        # critics: one-step TD towards r + gamma mask V(s', g)
        with torch.no_grad():
            y = r + gamma * mask * self.value(x_next).squeeze(-1)
        q = self.critic(x, a).squeeze(-1)  # (2, B)
        loss_critic = (q - y).pow(2).sum(0).mean()
        # actor
        xa, a_data = ab.get("observation"), ab.get("action")
        pi = self.actor.module(xa)
        if c.gciql_actor_loss == "ddpgbc":
            q_pi = frozen(self.critic, xa, pi).squeeze(-1).min(0).values
            q_loss = -q_pi.mean() / (q_pi.abs().mean().detach() + 1e-6)
            bc_loss = -(c.gciql_alpha * gaussian_log_prob(pi, a_data)).mean()
            loss_actor = q_loss + bc_loss
            extra = {"q_loss": q_loss.detach(), "bc_loss": bc_loss.detach()}
        else:
            with torch.no_grad():
                adv = self.target_critic(xa, a_data).squeeze(-1).min(0).values - self.value(xa).squeeze(-1)
                w = (c.gciql_alpha * adv).exp().clamp_max(AWR_MAX_WEIGHT)
            loss_actor = -(w * gaussian_log_prob(pi, a_data)).mean()
            extra = {"adv_mean": adv.mean(), "awr_weight": w.mean()}
        return {
            "loss_value": loss_value,
            "loss_critic": loss_critic,
            "loss_actor": loss_actor,
            "v_mean": v.detach().mean(),
            "q_mean": q.detach().mean(),
            **extra,
        }

    def update(self, batch: TensorDict) -> dict[str, torch.Tensor]:
        """One joint step of value, critics and actor (their parameters are disjoint; the
        actor's loss reads the critics with their parameters detached), then the targets."""
        out = self.losses(batch)
        self.critic_opt.zero_grad(set_to_none=True)
        self.actor_opt.zero_grad(set_to_none=True)
        (out["loss_value"] + out["loss_critic"] + out["loss_actor"]).backward()
        self.critic_opt.step()
        self.actor_opt.step()
        self.ema_step()
        self.target_critic.update_parameters(self.critic)
        self.num_updates += 1
        return {k: v.detach() for k, v in out.items()}

    @torch.no_grad()
    def critics(self, state: torch.Tensor, goal: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """(2, B): ``1 + (1 - gamma) Q_j(s, a, g)`` in [0, 1] (``gamma^d`` for a goal d steps
        away), for states (B, 18), goals (B, 15) and physical actions (B, 4)."""
        x = self.normalizer.inputs(state, goal)
        q = self.critic(x, self.normalizer.action_to_unit(action)).squeeze(-1)
        return success_value(q, self.cfg.gamma)


__all__ = ["GCIQL", "GCIQLConfig", "expectile_value_loss", "ogbench_reward_mask"]
