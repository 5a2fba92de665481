"""CRL: contrastive reinforcement learning, as OGBench's reference agent (Eysenbach et
al. 2022; OGBench ``agents/crl.py``).

The critic is a bilinear score ``f(s, a, g) = phi(s, a) . psi(g) / sqrt(D)``, learned as a
classifier of "g is a future state of (s, a)": in a batch of B transitions with goals
drawn from their own trajectories (the ``"value"`` mix: OGBench's geometric future,
mean ``1 / (1 - gamma)``), ``logits[i, j] = f(s_i, a_i, g_j)``; the diagonal holds the
positives, the other ``B - 1`` entries of row i are negatives (another transition's future,
a sample of the goal marginal). With the goal marginal ``p(g)`` and the discounted future
occupancy ``p^pi(g | s, a)``, the optimum is ``f = log(p^pi(g | s, a) / p(g)) + const``.

* critic loss (``crl_contrastive``), for each of the two (phi, psi) pairs:
  ``binary`` (OGBench's default): ``mean_ij BCE(sigmoid(logits[i, j]), I[i, j])``;
  ``symmetric``: InfoNCE both ways, ``(CE(logits, diag) + CE(logits^T, diag)) / 2``
  (the softmax over a row picks the right goal, over a column the right state-action);
* actor (goals from the ``"actor"`` mix), DDPG+BC as OGBench:
  ``-min_j f_j(s, pi(s, g), g) / mean|f| + alpha (-log N(a; pi(s, g), I))``, the critic's
  parameters held fixed. OGBench's AWR variant needs a second, action-free contrastive
  value network; it is not offered here.

Translation invariance: ``psi`` reads the goal relative to its own transition's state
(``[p_g - p, v_g, R_g]``, the goal part of the toolkit's input), ``phi`` the state part and
the action. A negative ``(s_i, a_i, g_j)`` therefore pairs state i with goal j's offset
from state j: a sample of the dataset's goal offsets, which for a translation-invariant
problem is the goal marginal. In a world with obstacles (33-d inputs) both parts also
carry the state's absolute position, and a negative pairs state i with an offset taken at
another place: still "some other goal", no longer an exact one.

Differences from OGBench: the toolkit's tanh actor and network sizes, ``crl_latent_dim``
64 (OGBench 512, with 4 x 512 networks), the run's gamma (see gciql.py for the 100 Hz
horizon note), the toolkit's goal-index convention (relabel.GoalMix).

``critics(state, goal, action)`` -> (2, B): ``sigmoid(f_j(s, a, g))`` in (0, 1), each
pair's classifier probability that g is reached from (s, a) rather than drawn at random.
It is monotone in the score and so in ``p^pi(g | s, a) / p(g)``, but it is not a
discounted success probability: compare CRL's values with each other, not with another
agent's. Settings: :class:`CRLConfig` (``cfg.crl``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import nn

from aerohrl.algorithms.base import Algorithm
from aerohrl.algorithms.config import CRLConfig, critic_sizes, goal_mix
from aerohrl.algorithms.networks import ACT_DIM, adam, frozen, gaussian_log_prob, ln_mlp, make_actor

if TYPE_CHECKING:
    from tensordict import TensorDict

    from aerohrl.algorithms.config import TrainConfig

    from aerohrl.algorithms.networks import Normalizer


class BilinearCritic(nn.Module):
    """Two pairs of encoders ``phi_j(s, a)``, ``psi_j(g)`` (OGBench's ``GCBilinearValue``,
    ``ensemble=True``) on the normalised input's state part and goal part."""

    def __init__(self, normalizer: Normalizer, hidden, latent: int):
        super().__init__()
        self.state_index, self.goal_index = normalizer.state_index, normalizer.goal_index  # column lists, not a submodule
        self.latent = latent
        self.phi = nn.ModuleList([ln_mlp(normalizer.state_dim + ACT_DIM, latent, hidden) for _ in range(2)])
        self.psi = nn.ModuleList([ln_mlp(normalizer.goal_dim, latent, hidden) for _ in range(2)])

    def embed(self, x: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(phi, psi), each (2, B, D), from normalised inputs (B, in_dim) and actions in [-1, 1] (B, 4)."""
        s, g = x[..., self.state_index], x[..., self.goal_index]
        phi = torch.stack([net(s, action) for net in self.phi])
        psi = torch.stack([net(g) for net in self.psi])
        return phi, psi

    def forward(self, x: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """The scores ``f_j(s, a, g) = phi_j . psi_j / sqrt(D)`` of each row's own goal: (2, B)."""
        phi, psi = self.embed(x, action)
        return (phi * psi).sum(-1) / math.sqrt(self.latent)


def contrastive_loss(phi: torch.Tensor, psi: torch.Tensor, kind: str = "binary") -> tuple[torch.Tensor, torch.Tensor]:
    """(loss, logits) of the contrastive critic for embeddings phi, psi (E, B, D):
    ``logits[e, i, j] = phi[e, i] . psi[e, j] / sqrt(D)``; ``binary``: the mean over
    e, i, j of the sigmoid cross-entropy against the identity (positives on the diagonal);
    ``symmetric``: ``(CE(logits, diag) + CE(logits^T, diag)) / 2`` averaged over e."""
    logits = torch.einsum("eik,ejk->eij", phi, psi) / math.sqrt(phi.shape[-1])
    n = logits.shape[-1]
    if kind == "binary":
        eye = torch.eye(n, device=logits.device, dtype=logits.dtype).expand_as(logits)
        loss = F.binary_cross_entropy_with_logits(logits, eye)
    else:
        labels = torch.arange(n, device=logits.device)
        rows = F.cross_entropy(logits.flatten(0, 1), labels.repeat(logits.shape[0]))
        cols = F.cross_entropy(logits.transpose(-1, -2).flatten(0, 1), labels.repeat(logits.shape[0]))
        loss = (rows + cols) / 2
    return loss, logits


class CRL(Algorithm):
    name = "crl"

    @classmethod
    def sampler_options(cls, cfg: TrainConfig) -> dict:
        """Critic goals and actor goals from their OGBench mixes (``crl_value_p_*``, ``crl_actor_p_*``)."""
        return {"goal_mixes": {"value": goal_mix(cfg, "value"), "actor": goal_mix(cfg, "actor")}}

    def __init__(self, cfg, normalizer):
        super().__init__(cfg, normalizer)
        c = cfg.crl
        self.critic = BilinearCritic(normalizer, critic_sizes(cfg), c.crl_latent_dim)
        self.actor = make_actor(cfg.hidden, normalizer.in_dim)
        self.critic_opt = adam([*self.critic.phi.parameters(), *self.critic.psi.parameters()], lr=cfg.lr_critic)
        self.actor_opt = adam(self.actor.parameters(), lr=cfg.lr_actor)
        self.setup_ema()

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """The optimisers by name: the actor's and the contrastive critic's."""
        return {"actor": self.actor_opt, "critic": self.critic_opt}

    def policy_net(self) -> nn.Module:
        """The deterministic actor network."""
        return self.actor.module

    def losses(self, batch: TensorDict) -> dict[str, torch.Tensor]:
        """The contrastive critic loss and the DDPG+BC actor loss of one batch, with statistics."""
        c: CRLConfig = self.cfg.crl
        vb, ab = batch.get("value"), self.actor_batch(batch.get("actor"))
        phi, psi = self.critic.embed(vb.get("observation"), vb.get("action"))
        loss_critic, logits = contrastive_loss(phi, psi, c.crl_contrastive)
        with torch.no_grad():
            mean_logits = logits.mean(0)
            eye = torch.eye(mean_logits.shape[-1], device=mean_logits.device, dtype=torch.bool)
            accuracy = (mean_logits.argmax(-1) == torch.arange(mean_logits.shape[-1], device=mean_logits.device)).float().mean()
            stats = {
                "logits_pos": mean_logits[eye].mean(),
                "logits_neg": mean_logits[~eye].mean(),
                "critic_accuracy": accuracy,
            }
        xa, a_data = ab.get("observation"), ab.get("action")
        pi = self.actor.module(xa)
        q_pi = frozen(self.critic, xa, pi).min(0).values
        q_loss = -q_pi.mean() / (q_pi.abs().mean().detach() + 1e-6)
        bc_loss = -(c.crl_alpha * gaussian_log_prob(pi, a_data)).mean()
        return {
            "loss_critic": loss_critic,
            "loss_actor": q_loss + bc_loss,
            "q_loss": q_loss.detach(),
            "bc_loss": bc_loss.detach(),
            **stats,
        }

    def update(self, batch: TensorDict) -> dict[str, torch.Tensor]:
        """One joint step of the contrastive critic and the actor (disjoint parameters)."""
        out = self.losses(batch)
        self.critic_opt.zero_grad(set_to_none=True)
        self.actor_opt.zero_grad(set_to_none=True)
        (out["loss_critic"] + out["loss_actor"]).backward()
        self.critic_opt.step()
        self.actor_opt.step()
        self.ema_step()
        self.num_updates += 1
        return {k: v.detach() for k, v in out.items()}

    @torch.no_grad()
    def critics(self, state: torch.Tensor, goal: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """(2, B): ``sigmoid(phi_j(s, a) . psi_j(g) / sqrt(D))`` in (0, 1) (module docstring),
        for states (B, 18), goals (B, 15) and physical actions (B, 4)."""
        x = self.normalizer.inputs(state, goal)
        return torch.sigmoid(self.critic(x, self.normalizer.action_to_unit(action)))


__all__ = ["CRL", "CRLConfig", "BilinearCritic", "contrastive_loss"]
