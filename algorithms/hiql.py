"""HIQL: hierarchical implicit Q-learning, as OGBench's reference agent (Park et al.
2023; OGBench ``agents/hiql.py``).

One goal-conditioned value and two policies that read it:

* goal representation ``phi(s, g)``: an MLP of the normalised input (which already holds
  the goal relative to the state) with ``rep_dim`` outputs, length-normalised to norm
  ``sqrt(rep_dim)`` (OGBench's ``LengthNormalize``);
* value ``V_j(s, g) = MLP_j([s, phi(s, g)])``, j = 1, 2 (the state part of the input and the
  representation: the goal reaches the value only through phi), target copies ``V'``;
  learned in OGBench's units (reward -1 per step, 0 when the goal is reached, see
  gciql.py) by expectile regression on goals from the ``"value"`` mix (IQL without Q):
  ``q_j = r + gamma mask V'_j(s', g)``, ``A = r + gamma mask min_j V'_j(s', g) - mean_j V'_j(s, g)``,
  ``L_V = sum_j E[|tau - 1(A < 0)| (q_j - V_j(s, g))^2]`` -- the expectile weight is chosen by
  the sign of the target value's advantage A, not by ``q_j - V_j`` (OGBench's form, which
  is why torchrl's ``IQLLoss.loss_value_diff``, weighting by the difference itself, is not
  used here);
* high-level policy ``pi_h(s, g) -> z`` (goals from the ``"actor"`` mix): AWR towards the
  representation of the state ``w`` that the data reached k = ``subgoal_steps`` steps later
  (not past the goal's own step, the episode's end), ``z_w = phi(s, w)`` (held fixed),
  ``L_h = -E[min(exp(alpha_h A_h), 100) log N(z_w; pi_h(s, g), I)]``,
  ``A_h = mean_j V_j(w, g) - mean_j V_j(s, g)``;
* low-level policy ``pi_l(s, z) -> a`` (goal: the state ``w`` k steps ahead,
  ``min(t + k, episode end)``, as the achieved goal ``[p, v, R]`` relative to s):
  ``L_l = -E[min(exp(alpha_l A_l), 100) log N(a; pi_l(s, phi(s, w)), I)]``,
  ``A_l = mean_j V_j(s', w) - mean_j V_j(s, w)``; ``phi(s, w)`` held fixed unless
  ``hiql_low_actor_rep_grad``.

One joint step of the three losses (OGBench's), then the target value's Polyak step.

``act(state, goal) = pi_l(s, normalise(pi_h(s, g)))`` (OGBench's deterministic
``sample_actions``; the high level's output is length-normalised like phi).

**Goal switch** (``hiql_goal_switch``, off by default): once the value puts the goal within
the subgoal horizon, ``d(s, g) = log(gamma^d) / log(gamma) <= k`` with
``gamma^d = 1 + (1 - gamma) mean_j V_j(s, g)``, the low level is handed ``phi(s, g)``, the
goal itself, in place of ``pi_h(s, g)``: the state k steps ahead of a goal closer than k
steps is the goal (the low level's training targets, ``min(t + k, episode end)``, include
it), and the high level's Gaussian mean regression lands near, not on, that
representation, which the low level then tracks to within its error rather than to the
goal's tolerances. Only ``act`` switches; ``policy_net`` (the EMA, exports) stays the two
levels alone.

**Subgoal at the episode's end** (``hiql_subgoal_end``): OGBench's subgoal is the state
``min(t + k, episode end)``, so the last k steps of an episode aim at its last state. With
``desired`` those steps aim at the episode's desired goal instead (the low level's subgoal,
and the high level's target where its goal is that desired goal): on expert data the clean
expert aimed at the desired goal, and the last state lies anywhere within the goal test's
tolerances of it. Data whose desired goal is its last state (explore) is unchanged.

**Subgoal space** (``hiql_subgoal_space``): ``rep`` is OGBench's, above. ``goal`` is the
HIQL paper's variant without a representation (Park et al. 2023, where raw-state subgoals
did about as well on state inputs): the high level regresses the goal-only columns of the
normalised input ``x(s, w)`` (the subgoal's position, velocity and attitude relative to
the state, and its position features) with the same AWR weights, and the low level is a
flat goal-conditioned policy ``pi_l(x(s, w))``, the same input as GCSL's actor. The value
and phi are unchanged (the advantages still come from ``V(s, w)``); only what the two
policies exchange changes, so the low level no longer sees its subgoal through the
10 numbers of phi.

**Subgoals for a planner**: :meth:`HIQL.subgoals` returns ``z = pi_h(s, g)``, normalised,
(B, rep_dim): the representation ``phi(s, w)`` of the state w the high level proposes to
be at k steps from now on the way to g. It is a representation, not a state: to use it
as a candidate source, score candidate goals ``w_i`` (e.g. dataset achieved goals) by the
closeness of :meth:`HIQL.goal_representation(s, w_i) <HIQL.goal_representation>` to z
(e.g. the dot product, both of norm ``sqrt(rep_dim)``), or hand z to the low level.

Differences from OGBench: subgoal_steps 25 is OGBench's (10-50 Hz environments, where 25
steps are 0.5-2.5 s); at this toolkit's 100 Hz, 25 steps are 0.25 s, so longer flights may
want 50-100; gamma is the run's (see gciql.py). The toolkit's network sizes (``hidden`` for
both policies, ``critic_hidden`` for phi and the value; OGBench 4 x 512), tanh low-level
actor (actions in [-1, 1]), unsquashed high level as OGBench.

``critics(state, goal, action)`` -> (2, B): ``1 + (1 - gamma) V_j(s, g)`` in [0, 1]
(``gamma^d`` for a goal d steps away); the action is not used (a state value).
Settings: :class:`HIQLConfig` (``cfg.hiql``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import torch
from torch import nn

from aerohrl.algorithms.base import Algorithm
from aerohrl.algorithms.config import HIQLConfig, critic_sizes, goal_mix
from aerohrl.algorithms.gciql import ogbench_reward_mask
from aerohrl.algorithms.networks import ACT_DIM, adam, gaussian_log_prob, ln_mlp, make_target, mlp, success_value

if TYPE_CHECKING:
    from tensordict import TensorDict

    from aerohrl.algorithms.config import TrainConfig

AWR_MAX_WEIGHT = 100.0  # OGBench's clip of exp(alpha A)


def length_normalize(z: torch.Tensor) -> torch.Tensor:
    """``z / ||z|| * sqrt(dim)`` (OGBench's ``LengthNormalize``)."""
    return z / z.norm(dim=-1, keepdim=True).clamp_min(1e-6) * math.sqrt(z.shape[-1])


def expectile_weighted_loss(adv: torch.Tensor, diff: torch.Tensor, expectile: float) -> torch.Tensor:
    """``|tau - 1(adv < 0)| diff^2`` elementwise (OGBench's ``expectile_loss(adv, diff, tau)``:
    the weight from the sign of ``adv``, the square of ``diff``)."""
    weight = torch.where(adv >= 0, expectile, 1.0 - expectile)
    return weight * diff.pow(2)


def awr_weights(adv: torch.Tensor, alpha: float) -> torch.Tensor:
    """AWR weights ``min(exp(alpha A), 100)``."""
    return (alpha * adv).exp().clamp_max(AWR_MAX_WEIGHT)


class HIQLValue(nn.Module):
    """``V_j(s, g) = MLP_j([s, phi(s, g)])``, j = 1, 2, with the goal representation phi."""

    def __init__(self, in_dim: int, state_index: list[int], hidden, rep_dim: int):
        super().__init__()
        self.state_index = state_index  # columns of the input describing the state alone
        self.rep = ln_mlp(in_dim, rep_dim, hidden)
        self.heads = nn.ModuleList([ln_mlp(len(state_index) + rep_dim, 1, hidden) for _ in range(2)])

    def phi(self, x: torch.Tensor) -> torch.Tensor:
        """The goal representation ``phi(s, g)`` (B, rep_dim), of norm ``sqrt(rep_dim)``."""
        return length_normalize(self.rep(x))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(V_1, V_2)(s, g)`` (2, B) from normalised inputs (B, in_dim)."""
        h = torch.cat([x[..., self.state_index], self.phi(x)], -1)
        return torch.stack([head(h).squeeze(-1) for head in self.heads])


class HIQLPolicy(nn.Module):
    """The two levels as one deterministic policy (what ``act``, the EMA and the trainer use):
    normalised input -> ``pi_l(s, normalise(pi_h(s, g)))`` in [-1, 1].

    With ``subgoal_index`` (``hiql_subgoal_space = "goal"``) the subgoal is no
    representation but the goal-only columns of the normalised input ``x(s, w)`` (the
    subgoal relative to the state and its position features): the high level regresses
    them, and the low level is a flat goal-conditioned policy ``pi_l(x(s, w))`` that reads
    ``x`` with those columns replaced by the subgoal."""

    sub_index: torch.Tensor | None

    def __init__(self, in_dim: int, state_index: list[int], hidden, rep_dim: int, subgoal_index: list[int] | None = None):
        super().__init__()
        self.state_index = state_index
        if subgoal_index is None:
            self.register_buffer("sub_index", None)
            self.high = mlp(in_dim, rep_dim, hidden)  # pi_h(s, g): the subgoal representation's mean
            self.low = nn.Sequential(mlp(len(state_index) + rep_dim, ACT_DIM, hidden), nn.Tanh())  # pi_l(s, z)
        else:  # not persistent: the index follows the device and the state dict keeps the weights alone
            self.register_buffer("sub_index", torch.tensor(subgoal_index, dtype=torch.long), persistent=False)
            self.high = mlp(in_dim, len(subgoal_index), hidden)  # pi_h(s, g): the subgoal's goal columns
            self.low = nn.Sequential(mlp(in_dim, ACT_DIM, hidden), nn.Tanh())  # pi_l(x(s, w))

    def subgoal(self, x: torch.Tensor) -> torch.Tensor:
        """The high level's subgoal: a representation normalised like phi (B, rep_dim), or
        the subgoal's goal columns (B, len(subgoal_index))."""
        return length_normalize(self.high(x)) if self.sub_index is None else self.high(x)

    def low_action(self, x: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """The low level's action in [-1, 1] for inputs x (B, in_dim) and a subgoal z (:meth:`subgoal`'s space)."""
        if self.sub_index is None:
            return self.low(torch.cat([x[..., self.state_index], z], -1))
        return self.low(x.index_copy(-1, self.sub_index, z.to(x.dtype)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """The action in [-1, 1]: the low level towards the high level's subgoal."""
        return self.low_action(x, self.subgoal(x))


class HIQL(Algorithm):
    name = "hiql"

    @classmethod
    def sampler_options(cls, cfg: TrainConfig) -> dict:
        """Value goals and high-level goals from their OGBench mixes (``hiql_value_p_*``,
        ``hiql_actor_p_*``), the subgoals ``hiql_subgoal_steps`` ahead (the sampler's
        ``"subgoal"`` batch and the actor batch's ``target_*`` keys)."""
        return {
            "goal_mixes": {"value": goal_mix(cfg, "value"), "actor": goal_mix(cfg, "actor")},
            "subgoal_steps": cfg.hiql.hiql_subgoal_steps,
            "subgoal_end": cfg.hiql.hiql_subgoal_end,
            "low_subgoal_offset": cfg.hiql.hiql_low_subgoal_offset,
        }

    def __init__(self, cfg, normalizer):
        super().__init__(cfg, normalizer)
        c = cfg.hiql
        n_in, rep = normalizer.in_dim, c.hiql_rep_dim
        self.value = HIQLValue(n_in, normalizer.state_index, critic_sizes(cfg), rep)
        self.target_value = make_target(self.value, cfg.tau)
        # the goal-only columns of the input (the subgoal space of hiql_subgoal_space "goal")
        state_cols = set(normalizer.state_index)
        self.subgoal_index = [i for i in normalizer.goal_index if i not in state_cols]
        goal_space = c.hiql_subgoal_space == "goal"
        self.policy = HIQLPolicy(n_in, normalizer.state_index, cfg.hidden, rep, self.subgoal_index if goal_space else None)
        self.value_opt = adam(self.value.parameters(), lr=cfg.lr_critic)
        self.high_opt = adam(self.policy.high.parameters(), lr=cfg.lr_actor)
        self.low_opt = adam(self.policy.low.parameters(), lr=cfg.lr_actor)
        self.setup_ema()

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """The optimisers by name: the value's (with phi), the high and the low level's."""
        return {"critic": self.value_opt, "actor_high": self.high_opt, "actor_low": self.low_opt}

    def policy_net(self) -> nn.Module:
        """Both levels as one module: normalised input -> action in [-1, 1]."""
        return self.policy

    def _net(self) -> HIQLPolicy:
        net = self.policy_ema.module if self.policy_ema is not None else self.policy
        assert isinstance(net, HIQLPolicy)
        return net

    def losses(self, batch: TensorDict) -> dict[str, torch.Tensor]:
        """The value, high-level and low-level losses of one batch (module docstring), with statistics."""
        c: HIQLConfig = self.cfg.hiql
        gamma = self.cfg.gamma
        # value: expectile regression on the value goals, weighted by the target's advantage
        vb = batch.get("value")
        x, x_next = vb.get("observation"), vb.get(("next", "observation"))
        r, mask = ogbench_reward_mask(vb)
        with torch.no_grad():
            next_vt = self.target_value(x_next)  # (2, B)
            vt = self.target_value(x).mean(0)
            adv = r + gamma * mask * next_vt.min(0).values - vt
            q = r + gamma * mask * next_vt
        v = self.value(x)
        loss_value = expectile_weighted_loss(adv, q - v, c.hiql_expectile).mean(-1).sum(0)
        # low level: towards the state k steps ahead
        lb = self.actor_batch(batch.get("subgoal"))
        xl = lb.get("observation")
        with torch.no_grad():
            adv_low = self.value(lb.get(("next", "observation"))).mean(0) - self.value(xl).mean(0)
            w_low = awr_weights(adv_low, c.hiql_low_alpha)
        z_low = self.subgoal_target(xl)
        if not c.hiql_low_actor_rep_grad:
            z_low = z_low.detach()
        loss_low = -(w_low * gaussian_log_prob(self.policy.low_action(xl, z_low), lb.get("action"))).mean()
        # high level: the representation of the state the data reached k steps ahead
        hb = batch.get("actor")
        xh = hb.get("observation")
        with torch.no_grad():
            adv_high = self.value(hb.get("target_observation")).mean(0) - self.value(xh).mean(0)
            w_high = awr_weights(adv_high, c.hiql_high_alpha)
            z_target = self.subgoal_target(hb.get("subgoal_observation"))
        loss_high = -(w_high * gaussian_log_prob(self.policy.high(xh), z_target)).mean()
        return {
            "loss_value": loss_value,
            "loss_actor_low": loss_low,
            "loss_actor_high": loss_high,
            "v_mean": v.detach().mean(),
            "adv_low": adv_low.mean(),
            "adv_high": adv_high.mean(),
            "awr_weight_low": w_low.mean(),
            "awr_weight_high": w_high.mean(),
        }

    def update(self, batch: TensorDict) -> dict[str, torch.Tensor]:
        """One joint step of value (with phi), high and low level, then the target value."""
        out = self.losses(batch)
        opts = (self.value_opt, self.high_opt, self.low_opt)
        for opt in opts:
            opt.zero_grad(set_to_none=True)
        (out["loss_value"] + out["loss_actor_low"] + out["loss_actor_high"]).backward()
        for opt in opts:
            opt.step()
        self.ema_step()
        self.target_value.update_parameters(self.value)
        self.num_updates += 1
        return {k: v.detach() for k, v in out.items()}

    def subgoal_target(self, x: torch.Tensor) -> torch.Tensor:
        """The subgoal ``w`` of normalised inputs ``x(s, w)`` in the high level's space:
        ``phi(s, w)``, or (``hiql_subgoal_space`` "goal") the goal-only columns of x."""
        return self.value.phi(x) if self.policy.sub_index is None else x[..., self.subgoal_index]

    @torch.no_grad()
    def act(self, state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """The action (B, 4), in physical units, for states (B, 18) and goals (B, 15): the low
        level towards the high level's subgoal, or with ``hiql_goal_switch`` towards the goal
        itself where the value puts it within the subgoal horizon (module docstring)."""
        x = self.normalizer.inputs(state, goal)
        net = self._net()
        z = net.subgoal(x)
        if self.cfg.hiql.hiql_goal_switch:
            near = self.steps_to_goal(state, goal) <= self.cfg.hiql.hiql_subgoal_steps
            z = torch.where(near[:, None], self.subgoal_target(x), z)
        return self.normalizer.action_from_unit(net.low_action(x, z))

    @torch.no_grad()
    def steps_to_goal(self, state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """The value's distance to the goal in steps, ``d = log(gamma^d) / log(gamma)`` with
        ``gamma^d = 1 + (1 - gamma) mean_j V_j(s, g)`` (B,); inf where the value is at its floor."""
        v = self.value(self.normalizer.inputs(state, goal)).mean(0)
        return torch.log(success_value(v, self.cfg.gamma)) / math.log(self.cfg.gamma)

    @torch.no_grad()
    def subgoals(self, state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """The high level's proposed subgoal for states (B, 18) and goals (B, 15): the
        representation (B, rep_dim), norm ``sqrt(rep_dim)``, of the state it proposes to
        reach ``hiql_subgoal_steps`` steps from now (module docstring: how a planner reads it)."""
        return self._net().subgoal(self.normalizer.inputs(state, goal))

    @torch.no_grad()
    def goal_representation(self, state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Goals (B, 15) seen from states (B, 18) in the space :meth:`subgoals` proposes in
        (a candidate goal's representation to compare): ``phi(s, g)`` (B, rep_dim), or the
        goal columns of the input (``hiql_subgoal_space`` "goal")."""
        return self.subgoal_target(self.normalizer.inputs(state, goal))

    @torch.no_grad()
    def critics(self, state: torch.Tensor, goal: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """(2, B): ``1 + (1 - gamma) V_j(s, g)`` in [0, 1] for states (B, 18) and goals
        (B, 15); the action is not used (a state value)."""
        return success_value(self.value(self.normalizer.inputs(state, goal)), self.cfg.gamma)


__all__ = ["HIQL", "HIQLConfig", "HIQLValue", "HIQLPolicy", "expectile_weighted_loss", "awr_weights", "length_normalize"]
