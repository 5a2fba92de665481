"""QRL: quasimetric reinforcement learning, as OGBench's reference agent (Wang et al.
2023; OGBench ``agents/qrl.py``).

The value is a learned *quasimetric* ``d(x, y)`` (non-negative, ``d(x, x) = 0``, triangle
inequality, not symmetric): the number of steps from x to y. ``x, y`` are encoded by one
encoder ``E`` into a latent space where the head ``q`` is a quasimetric by construction:

* IQE (interval quasimetric embedding, Wang & Isola 2022, ``qrl_quasimetric = "iqe"``):
  the latent (D) is cut into C components of D/C coordinates; component c is
  ``d_c(u, v) = | union_i [u_ci, max(u_ci, v_ci)] |`` (the total length of the union of
  the intervals from u up to v), and ``q(u, v) = alpha max_c d_c + (1 - alpha) mean_c d_c``
  with ``alpha = sigmoid(a)`` learned (the "maxmean" reduction);
* MRN (metric residual network, Liu et al. 2023, ``"mrn"``): the latent split in halves,
  ``q(u, v) = max_i relu(u_i - v_i)`` over the first + ``||u - v||_2`` over the second.

Loss (``d_neg`` on goals from the ``"value"`` mix, random dataset states by default):
``L = E[100 softplus(5 - d(s, g) / 100)] + lambda E[relu(d(s, s') - 1)^2]`` -- push the
distance to random goals up, softly saturating, while keeping every transition at most
one step long; the Lagrange multiplier ``lambda = exp(l)`` rises while the constraint
``E[relu(d(s, s') - 1)^2] <= eps`` is violated: ``L_lambda = lambda (eps - E[...])`` (the
constraint term held fixed), the penalty weight held fixed in ``L``. The largest
distances consistent with every one-step constraint are the shortest-path distances, so
the optimum is the optimal cost-to-go.

Latent dynamics (for the actor): ``z' = z + f(z, a)``, trained with
``(q(z', E(s')) + q(E(s'), z')) / 2``. Actor (goals from the ``"actor"`` mix), DDPG+BC
through the learned distance: with ``Q(s, a, g) = -q(E(s) + f(E(s), a), E(g))``,
``-Q(s, pi(s, g), g) / mean|Q| + alpha (-log N(a; pi(s, g), I))``, encoder and dynamics
held fixed.

The space of x and y: the quasimetric needs ``d(s, s')`` and ``d(s, g)`` to be one function
of two points of one space, so states enter through their achieved goal ``[p, v, R]``
(the body rates w are left out of the distance; the actor still sees them), and both
points are expressed in the frame of the transition's state as the toolkit's inputs are:
``E`` reads the goal part of ``inputs(s, y)`` (``[p_y - p_s, v_y, R_y]``, plus ``p_s`` in a
world with obstacles), ``y = `` the state's own achieved goal, the next state's, or a goal.
:class:`PointEncoder` is linear in ``p_y - p_s``, so a change of reference shifts all
latents alike and leaves ``d`` unchanged: the distance seen from s and from s' is one
quasimetric, and the one-step constraints chain into multi-step bounds.

Differences from OGBench: the constants 100 and 5 of the soft push are OGBench's, read
in steps: at 100 Hz a 500-step (5 s) flight sits where the push flattens, so distances
beyond that are only loosely ranked; latent 64 (OGBench 512) with the toolkit's network
sizes and tanh actor; the run's gamma maps distances to values (below).

``critics(state, goal, action)`` -> (1, B): ``gamma^d(s, g)`` in (0, 1], the discounted
success of a goal d steps away (the action is not used: the distance is state-to-goal).
Settings: :class:`QRLConfig` (``cfg.qrl``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import nn

from aerohrl import task
from aerohrl.algorithms.base import Algorithm
from aerohrl.algorithms.config import QRLConfig, critic_sizes, goal_mix
from aerohrl.algorithms.networks import ACT_DIM, adam, frozen, gaussian_log_prob, ln_mlp, make_actor

if TYPE_CHECKING:
    from tensordict import TensorDict

    from aerohrl.algorithms.config import TrainConfig

NEG_SCALE, NEG_OFFSET = 100.0, 5.0  # OGBench's soft push: 100 softplus(5 - d / 100)


def iqe(u: torch.Tensor, v: torch.Tensor, components: int) -> torch.Tensor:
    """The per-component IQE distances (..., C): for each component c, the length of
    ``union_i [u_ci, max(u_ci, v_ci)]``. Endpoints sorted with +1 for an interval's start,
    -1 for its end; the union's length is the sum of the gaps between consecutive sorted
    endpoints where the running count is positive. Hand-written (no quasimetric library is
    a dependency; torchqmet's IQE computes the same measure)."""
    u = u.unflatten(-1, (components, -1))
    v = v.unflatten(-1, (components, -1))
    start, end = u, torch.maximum(u, v)
    points = torch.cat([start, end], -1)
    delta = torch.cat([torch.ones_like(start), -torch.ones_like(end)], -1)
    sorted_points, order = points.sort(-1)
    coverage = delta.gather(-1, order).cumsum(-1)  # intervals open after each endpoint
    gaps = sorted_points[..., 1:] - sorted_points[..., :-1]
    return (gaps * (coverage[..., :-1] > 0.5).to(gaps.dtype)).sum(-1)


class PointEncoder(nn.Module):
    """``E(y)``: a goal-space point y seen from a reference state s -> latent (D), equivariant
    to the reference: ``E(y) = h(v_y, R_y[, p_s]) + W (p_y - p_s)`` with h an MLP and W linear.
    Moving the reference adds the same vector ``-W dp`` to every point's latent, and the
    quasimetric heads do not see such a shift (MRN: differences only; IQE: W gives every
    coordinate of a component the same shift, which moves the component's intervals
    together), so ``d`` is the same from any reference and chains across transitions: the
    triangle inequality holds between ``d(s, s')`` (seen from s) and ``d(s', g)`` (seen from s').
    An encoder of ``p_y - p_s`` through the MLP would give each reference its own geometry,
    and the one-step constraints would bound nothing beyond one step."""

    def __init__(self, goal_dim: int, latent: int, hidden, kind: str, components: int):
        super().__init__()
        self.h = ln_mlp(goal_dim - 3, latent, hidden)  # [v_y, R_y] (+ the reference's p in a world with obstacles)
        self.repeat = latent // components if kind == "iqe" else 1
        self.w = nn.Linear(3, latent // self.repeat, bias=False)  # one shift per IQE component, per coordinate for MRN

    def forward(self, point: torch.Tensor) -> torch.Tensor:
        """Latents (B, D) of points given as the goal part of the normalised input (its first
        3 columns are the standardised ``p_y - p_s``)."""
        shift = self.w(point[..., :3])
        return self.h(point[..., 3:]) + shift.repeat_interleave(self.repeat, dim=-1)


class Quasimetric(nn.Module):
    """The quasimetric head ``q(u, v)`` on latents (module docstring): IQE with the
    maxmean reduction and a learned mix ``alpha = sigmoid(a)``, or MRN."""

    def __init__(self, kind: str, components: int):
        super().__init__()
        self.kind, self.components = kind, components
        self.alpha_raw = nn.Parameter(torch.zeros(()))  # IQE's maxmean weight (sigmoid(0) = 1/2)

    def forward(self, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """``q(u, v)`` (...,) for latents u, v (..., D)."""
        if self.kind == "iqe":
            d = iqe(u, v, self.components)
            alpha = torch.sigmoid(self.alpha_raw)
            return alpha * d.max(-1).values + (1 - alpha) * d.mean(-1)
        h = u.shape[-1] // 2
        asym = F.relu(u[..., :h] - v[..., :h]).max(-1).values
        return asym + (u[..., h:] - v[..., h:]).norm(dim=-1)


def qrl_value_loss(
    d_neg: torch.Tensor, d_pos: torch.Tensor, log_lambda: torch.Tensor, eps: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(distance loss, multiplier loss, constraint term) of QRL:
    ``E[100 softplus(5 - d_neg / 100)] + sg(lambda) C`` and ``lambda (eps - sg(C))`` with
    ``C = E[relu(d_pos - 1)^2]`` and ``lambda = exp(log_lambda)``."""
    push = (NEG_SCALE * F.softplus(NEG_OFFSET - d_neg / NEG_SCALE)).mean()
    constraint = F.relu(d_pos - 1.0).pow(2).mean()
    lam = log_lambda.exp()
    return push + lam.detach() * constraint, lam * (eps - constraint.detach()), constraint


class QRL(Algorithm):
    name = "qrl"

    @classmethod
    def sampler_options(cls, cfg: TrainConfig) -> dict:
        """Distance goals and actor goals from their OGBench mixes (``qrl_value_p_*``, ``qrl_actor_p_*``)."""
        return {"goal_mixes": {"value": goal_mix(cfg, "value"), "actor": goal_mix(cfg, "actor")}}

    def __init__(self, cfg, normalizer):
        super().__init__(cfg, normalizer)
        c = cfg.qrl
        hv, latent = critic_sizes(cfg), c.qrl_latent_dim
        self.encoder = PointEncoder(normalizer.goal_dim, latent, hv, c.qrl_quasimetric, c.qrl_components)
        self.head = Quasimetric(c.qrl_quasimetric, c.qrl_components)
        self.dynamics = ln_mlp(latent + ACT_DIM, latent, hv)  # f: z' = z + f(z, a)
        self.log_lambda = nn.Parameter(torch.zeros(()))  # the Lagrange multiplier, lambda = exp(.) (OGBench: 1 at start)
        self.actor = make_actor(cfg.hidden, normalizer.in_dim)
        value_params = [*self.encoder.parameters(), *self.head.parameters(), *self.dynamics.parameters()]
        self.value_opt = adam(value_params, lr=cfg.lr_critic)
        self.lambda_opt = adam([self.log_lambda], lr=cfg.lr_critic)
        self.actor_opt = adam(self.actor.parameters(), lr=cfg.lr_actor)
        self.setup_ema()

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """The optimisers by name: the actor's, the distance's (encoder, head, dynamics) and the multiplier's."""
        return {"actor": self.actor_opt, "critic": self.value_opt, "lambda": self.lambda_opt}

    def policy_net(self) -> nn.Module:
        """The deterministic actor network."""
        return self.actor.module

    def point(self, state: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """The encoder's input for a goal-space point y (B, 15) seen from state (B, 18): the
        goal part of the normalised input (B, goal_dim)."""
        return self.normalizer.goal_part(self.normalizer.inputs(state, y))

    def distance(self, state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """``d(s, g)`` (B,): from the state's achieved goal to the goal, in steps."""
        z = self.encoder(self.point(state, task.achieved_goal(state)))
        return self.head(z, self.encoder(self.point(state, goal)))

    def losses(self, batch: TensorDict) -> dict[str, torch.Tensor]:
        """The distance, multiplier, dynamics and actor losses of one batch, with statistics."""
        c: QRLConfig = self.cfg.qrl
        vb, ab = batch.get("value"), self.actor_batch(batch.get("actor"))
        s, s_next, g = vb.get("state"), vb.get("next_state"), vb.get("goal")
        z = self.encoder(self.point(s, task.achieved_goal(s)))
        z_next = self.encoder(self.point(s, task.achieved_goal(s_next)))
        d_neg = self.head(z, self.encoder(self.point(s, g)))
        d_pos = self.head(z, z_next)
        loss_value, loss_lambda, constraint = qrl_value_loss(d_neg, d_pos, self.log_lambda, c.qrl_eps)
        # latent dynamics: z + f(z, a) should sit at distance 0 of E(s') both ways
        z_pred = z + self.dynamics(z, vb.get("action"))
        loss_dynamics = (self.head(z_pred, z_next) + self.head(z_next, z_pred)).mean() / 2
        # actor: DDPG+BC through the distance after one latent step, encoder and dynamics fixed
        sa, xa, a_data = ab.get("state"), ab.get("observation"), ab.get("action")
        pi = self.actor.module(xa)
        with torch.no_grad():
            za = self.encoder(self.point(sa, task.achieved_goal(sa)))
            zg = self.encoder(self.point(sa, ab.get("goal")))
        q = -frozen(self.head, za + frozen(self.dynamics, za, pi), zg)
        q_loss = -q.mean() / (q.abs().mean().detach() + 1e-6)
        bc_loss = -(c.qrl_alpha * gaussian_log_prob(pi, a_data)).mean()
        return {
            "loss_value": loss_value,
            "loss_lambda": loss_lambda,
            "loss_dynamics": loss_dynamics,
            "loss_actor": q_loss + bc_loss,
            "constraint": constraint.detach(),
            "lambda": self.log_lambda.detach().exp(),
            "d_neg_mean": d_neg.detach().mean(),
            "d_pos_mean": d_pos.detach().mean(),
            "q_loss": q_loss.detach(),
            "bc_loss": bc_loss.detach(),
        }

    def update(self, batch: TensorDict) -> dict[str, torch.Tensor]:
        """One joint step of distance + dynamics, multiplier and actor (disjoint parameters)."""
        out = self.losses(batch)
        for opt in (self.value_opt, self.lambda_opt, self.actor_opt):
            opt.zero_grad(set_to_none=True)
        (out["loss_value"] + out["loss_lambda"] + out["loss_dynamics"] + out["loss_actor"]).backward()
        for opt in (self.value_opt, self.lambda_opt, self.actor_opt):
            opt.step()
        self.ema_step()
        self.num_updates += 1
        return {k: v.detach() for k, v in out.items()}

    @torch.no_grad()
    def critics(self, state: torch.Tensor, goal: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """(1, B): ``gamma^d(s, g)`` in (0, 1] for states (B, 18) and goals (B, 15); the
        action is not used (module docstring)."""
        return torch.pow(self.cfg.gamma, self.distance(state, goal).float()).unsqueeze(0)


__all__ = ["QRL", "QRLConfig", "PointEncoder", "Quasimetric", "iqe", "qrl_value_loss"]
