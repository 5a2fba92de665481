"""TD3-AWBC: TD3-BC whose behaviour-cloning term also gets an advantage-weighted
regression term (thesis §3.5.1, "inspired from" Yang et al. 2022, WGCSL):

    loss_actor = -lambda Q_0(s, pi(s)) + (pi(s) - a)^2 + mean_b[ w_b (pi(s_b) - a_b)^2 ],
    w = min(exp(A / temperature), awr_max_weight),
    A = mean_j Q_j(s, a, g) - mean_j Q_j(s, pi(s), g)      (no gradient through A or w)

With ``awr_normalize = "std"`` (the cpu preset) A is divided by its batch standard
deviation first, as AWAC/IQL-style implementations scale advantages: the critics' values
lie in [0, 1], so raw advantages are ~1e-3 and exp(A / 1) is 1 +- 0.003 (the
weighting then does nothing). The logged ``awr_weight_std`` and ``awr_clipped`` (share of
weights at the clip) show whether it does something.

Critics, targets and the update schedule are TD3-BC's (see td3bc.py). Its settings:
:class:`TD3AWBCConfig` (``cfg.td3awbc``) beside TD3-BC's (``cfg.td3bc``).

``TD3BCLoss`` has no hook for a weighted BC term, so :class:`TD3AWBCLoss` extends it and
overrides ``actor_loss`` only; the critic loss, the ensemble, the target networks and
the vmapped critic calls are torchrl's.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torchrl.objectives import TD3BCLoss

from aerohrl.algorithms.config import TD3AWBCConfig, critic_sizes
from aerohrl.algorithms.networks import make_critic_loss
from aerohrl.algorithms.td3bc import TD3BC

if TYPE_CHECKING:
    from tensordict import TensorDict


class TD3AWBCLoss(TD3BCLoss):
    awr_temperature: float = 1.0
    awr_max_weight: float = 100.0
    awr_normalize: str = "none"

    def actor_loss(self, tensordict: TensorDict) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The TD3-AWBC actor loss ``-lambda Q_0(s, pi(s)) + (pi(s) - a)^2 + mean_b[w_b (pi(s_b) - a_b)^2]``
        (module docstring; batch B, actions (B, 4)), ``lambda = alpha / mean|Q_0|``; returns
        ``(loss, meta)`` with the BC and AWR terms and the weight statistics."""
        td = tensordict.select(*self.actor_network.in_keys, strict=False)
        with self.actor_network_params.to_module(self.actor_network, preserve_module_state=False):
            td = self.actor_network(td)
        pi = td.get(self.tensor_keys.action)
        a = tensordict.get(self.tensor_keys.action)
        n, batch = self.num_qvalue_nets, tensordict.batch_size
        params = self._cached_detach_qvalue_network_params
        q_pi = (
            self._vmap_qvalue_network00(td.select(*self.qvalue_network.in_keys, strict=False).expand(n, *batch), params)
            .get(self.tensor_keys.state_action_value)
            .squeeze(-1)
        )  # (n, B), grad to pi only
        with torch.no_grad():
            q_data = (
                self._vmap_qvalue_network00(
                    tensordict.select(*self.qvalue_network.in_keys, strict=False).expand(n, *batch), params
                )
                .get(self.tensor_keys.state_action_value)
                .squeeze(-1)
            )
            adv = q_data.mean(0) - q_pi.detach().mean(0)
            if self.awr_normalize == "std":
                adv = adv / (adv.std() + 1e-6)
            raw = (adv / self.awr_temperature).exp()
            w = raw.clamp_max(self.awr_max_weight)
        sq = (pi - a).pow(2).mean(-1)  # (B,)
        bc_loss = sq.mean()
        awr_loss = (w * sq).mean()
        lmbd = self.alpha / q_pi[0].abs().mean().detach()
        loss = -lmbd * q_pi[0].mean() + bc_loss + awr_loss
        meta = {
            "bc_loss": bc_loss.detach(),
            "awr_loss": awr_loss.detach(),
            "lmbd": lmbd,
            "awr_weight": w.mean(),
            "awr_weight_std": w.std(),
            "awr_clipped": (raw >= self.awr_max_weight).float().mean(),
        }
        return loss, meta


class TD3AWBC(TD3BC):
    name = "td3awbc"

    def _make_loss(self, cfg, actor):
        loss = make_critic_loss(
            actor,
            critic_sizes(cfg),
            num_critics=cfg.num_critics,
            gamma=cfg.gamma,
            delay_actor=True,
            policy_noise=cfg.td3bc.policy_noise,
            noise_clip=cfg.td3bc.noise_clip,
            alpha=cfg.td3bc.alpha,
            loss_cls=TD3AWBCLoss,
            in_dim=self.normalizer.in_dim,
        )
        loss.awr_temperature = cfg.td3awbc.awr_temperature
        loss.awr_max_weight = cfg.td3awbc.awr_max_weight
        loss.awr_normalize = cfg.td3awbc.awr_normalize
        return loss

    def _actor_extras(self, meta):
        return {
            "lambda": meta["lmbd"].detach(),
            "awr_loss": meta["awr_loss"],
            "awr_weight": meta["awr_weight"],
            "awr_weight_std": meta["awr_weight_std"],
            "awr_clipped": meta["awr_clipped"],
        }


__all__ = ["TD3AWBC", "TD3AWBCLoss", "TD3AWBCConfig"]
