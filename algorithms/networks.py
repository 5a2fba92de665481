"""Networks shared by every algorithm: input/action normalisation, the actor, the
ensemble of goal-conditioned critics and the TD3-style clipped critic loss on it.

Key names (torchrl conventions, so torchrl's losses read the batches directly):
``"observation"`` the normalised 30-d input ``[o(15), relative goal(15)]``
(:func:`aerohrl.task.policy_inputs`; 33-d ``[o, relative goal, p]`` for a dataset flown in
a world with obstacles, :class:`Normalizer`), ``"action"`` the action scaled to ``[-1, 1]``,
``"state_action_value"`` a critic's output, ``("next", ...)`` the next step.
"""

from __future__ import annotations

import math
import warnings
from typing import TYPE_CHECKING, Any, Callable, Sequence

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.modules import MLP, ValueOperator
from torchrl.objectives import SoftUpdate, TD3BCLoss
from torchrl.objectives.value import TD0Estimator

from aerohrl import task
from aerohrl.errors import UserError
from aerohrl.algorithms import quiet_torchrl

if TYPE_CHECKING:
    from torchrl.objectives import LossModule

quiet_torchrl()  # every algorithm imports this module, right after torchrl

IN_DIM = task.OBS_DIM + task.GOAL_DIM  # 30: the free-space input
POS_DIM = 3  # the absolute position appended in a world with obstacles
DIST_DIM = 3  # the disturbance estimate appended to the state (observe_disturbance)
ACT_DIM = task.ACTION_DIM  # 4
ACTION_MARGIN = 0.1  # action bounds = data range widened by 10% on each side
STD_FLOOR = 1e-2


class Normalizer(nn.Module):
    """Dataset statistics (saved in every checkpoint through the state dict).

    Inputs: ``(x - mean) / std`` on the translation-invariant 30-d input
    ``x = [o(15), rel(15)] = [v, R, w, p_g - p, v_g, R_g]``. In a world with obstacles (a
    dataset whose spec names a ``world`` other than ``"free"``) the same place is not the
    same situation everywhere, so the absolute position ``p`` (3) is appended:
    ``x = [o, rel, p]`` (33-d, ``absolute_position=True``). The layout is recorded by the
    length of the ``in_mean``/``in_std`` buffers in the state dict (30 or 33), which is how
    :meth:`for_state_dict` rebuilds the right size from a checkpoint; a free-space
    normaliser's state dict is exactly what it was before the layout existed.

    Position features (``pos_octaves`` K > 0, world with obstacles only): the standardised
    input is followed by the Fourier features of the state's and the goal's standardised
    positions, ``x = [o, rel, p, F(p), F(p_g)]`` (33 + 12 K, :func:`position_features`);
    the frequencies are the ``pos_freq`` buffer, whose presence and length record K.

    Disturbance estimate (``disturbance_tau`` > 0): the state carries the expert's
    estimate ``d_hat`` (3, m/s^2) of an unmodelled acceleration as columns 18..20, from a
    :class:`~aerohrl.datagen.expert.DisturbanceObserver` with time constant ``tau``; it is
    appended last, ``x = [o, rel, (p), d_hat]``, and belongs to the state's columns. The
    ``dob_tau`` buffer records it (present only then), so evaluation runs the same observer.
    A state without the columns (18 wide: a planner's imagined state) is read as
    undisturbed, ``d_hat = 0``.

    Actions: an affine map of the data range (widened by :data:`ACTION_MARGIN`) onto
    ``[-1, 1]``, so thrust (~10 m/s^2) and rates (~1 rad/s) weigh alike and TD3's/CQL's
    ``[-1, 1]`` bounds, noise and random actions are meaningful.
    """

    # buffers, registered in __init__ (declared: nn.Module's __getattr__ types them Tensor | Module)
    in_mean: torch.Tensor
    in_std: torch.Tensor
    act_center: torch.Tensor
    act_half: torch.Tensor

    def __init__(self, absolute_position: bool = False, pos_octaves: int = 0, disturbance_tau: float = 0.0):
        super().__init__()
        if pos_octaves and not absolute_position:
            raise UserError("position features (--pos-octaves) need a dataset flown in a world with obstacles")
        self.absolute_position = bool(absolute_position)
        self.pos_octaves = int(pos_octaves)
        self.disturbance_tau = float(disturbance_tau)
        self.dist_dim = DIST_DIM if self.disturbance_tau > 0 else 0
        raw = IN_DIM + (POS_DIM if absolute_position else 0) + self.dist_dim
        self.in_dim = raw + 4 * POS_DIM * self.pos_octaves
        self.register_buffer("in_mean", torch.zeros(raw))
        self.register_buffer("in_std", torch.ones(raw))
        self.register_buffer("act_center", torch.zeros(ACT_DIM))
        self.register_buffer("act_half", torch.ones(ACT_DIM))
        if self.pos_octaves:  # registered only when used: other state dicts keep their keys
            self.register_buffer("pos_freq", position_frequencies(self.pos_octaves))
        if self.dist_dim:  # likewise
            self.register_buffer("dob_tau", torch.tensor(self.disturbance_tau, dtype=torch.float64))
        # column indices of the normalised input: what describes the state alone ([o] and,
        # with absolute position, [p] and its features) and what describes the goal relative
        # to it ([rel], [p] and its features, the goal position's features)
        pos = list(range(IN_DIM, raw - self.dist_dim))
        dist = list(range(raw - self.dist_dim, raw))
        f = 2 * POS_DIM * self.pos_octaves
        p_feat, g_feat = list(range(raw, raw + f)), list(range(raw + f, raw + 2 * f))
        self.state_index = [*range(task.OBS_DIM), *pos, *dist, *p_feat]
        self.goal_index = [*range(task.OBS_DIM, IN_DIM), *pos, *p_feat, *g_feat]

    @staticmethod
    def for_dataset_spec(spec: dict | None, pos_octaves: int = 0, disturbance_tau: float = 0.0) -> "Normalizer":
        """An unfitted normaliser with the input layout of a dataset with this spec: the
        absolute position appended when ``spec["world"]`` names a world other than ``"free"``
        (and its Fourier features at ``pos_octaves`` octaves); the disturbance estimate of an
        observer with time constant ``disturbance_tau`` appended when it is > 0."""
        return Normalizer(
            absolute_position=(spec or {}).get("world", "free") != "free",
            pos_octaves=pos_octaves,
            disturbance_tau=disturbance_tau,
        )

    @staticmethod
    def for_state_dict(state: dict, prefix: str = "normalizer.") -> "Normalizer":
        """An unfitted normaliser with the input layout of a saved model state dict (the
        length of its ``in_mean``), to load that state into."""
        mean, freq, tau = state.get(prefix + "in_mean"), state.get(prefix + "pos_freq"), state.get(prefix + "dob_tau")
        dist = 0 if tau is None else DIST_DIM
        return Normalizer(
            absolute_position=mean is not None and mean.shape[-1] - dist == IN_DIM + POS_DIM,
            pos_octaves=0 if freq is None else freq.shape[-1],
            disturbance_tau=0.0 if tau is None else float(tau),
        )

    @property
    def state_width(self) -> int:
        """Columns of the state this normaliser reads: 18, or 21 with the disturbance estimate."""
        return task.STATE_DIM + self.dist_dim

    @property
    def state_dim(self) -> int:
        """Width of :meth:`state_part` (15, or 18 with the absolute position; + 3 with the disturbance estimate)."""
        return len(self.state_index)

    @property
    def goal_dim(self) -> int:
        """Width of :meth:`goal_part` (15, or 18 with the absolute position)."""
        return len(self.goal_index)

    def state_part(self, x: torch.Tensor) -> torch.Tensor:
        """The columns of a normalised input that describe the state alone (``[o]``, plus ``p``)."""
        return x[..., self.state_index]

    def goal_part(self, x: torch.Tensor) -> torch.Tensor:
        """The columns of a normalised input that describe the goal relative to the state (``[rel]``, plus ``p``)."""
        return x[..., self.goal_index]

    @torch.no_grad()
    def fit(self, inputs: torch.Tensor, actions: torch.Tensor) -> "Normalizer":
        """Fit the input mean/std over ``inputs`` (F, in_dim) and the action bounds over
        ``actions`` (F, 4); returns ``self``."""
        self.in_mean.copy_(inputs.mean(0))
        self.in_std.copy_(inputs.std(0).clamp_min(STD_FLOOR))
        lo, hi = actions.min(0).values, actions.max(0).values
        span = (hi - lo).clamp_min(1e-3)
        lo, hi = lo - ACTION_MARGIN * span, hi + ACTION_MARGIN * span
        self.act_center.copy_((hi + lo) / 2)
        self.act_half.copy_((hi - lo) / 2)
        return self

    def raw_inputs(self, state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Unnormalised inputs ``[v, R, w, p_g - p, v_g, R_g]`` (B, 30), ``+ [p]`` (B, 33)
        with the absolute position, from states (B, 18) and goals (B, 15); ``+ [d_hat]``
        with the disturbance estimate, from states (B, 21) (18 wide: ``d_hat = 0``)."""
        o, rel = task.policy_inputs(state, goal)
        parts = [o, rel, state[..., task.POS]] if self.absolute_position else [o, rel]
        if self.dist_dim:
            d = state[..., task.STATE_DIM : task.STATE_DIM + DIST_DIM]
            parts.append(d if d.shape[-1] == DIST_DIM else torch.zeros_like(o[..., :DIST_DIM]))
        return torch.cat(parts, -1)

    def inputs(self, state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Standardised network inputs (B, in_dim) from states (B, 18) and goals (B, 15):
        :meth:`raw_inputs` minus the dataset mean, over the dataset std; then, with
        ``pos_octaves``, the Fourier features of the state's and the goal's standardised
        positions (:func:`position_features`)."""
        raw = self.raw_inputs(state, goal)
        x = (raw - self.in_mean) / self.in_std
        if not self.pos_octaves:
            return x
        freq = self.get_buffer("pos_freq")
        return torch.cat([x, fourier_inputs(raw, self.in_mean, self.in_std, freq)], -1)

    def action_to_unit(self, a: torch.Tensor) -> torch.Tensor:
        """Physical actions (B, 4) -> [-1, 1] (affine map of the fitted bounds)."""
        return (a - self.act_center) / self.act_half

    def action_from_unit(self, u: torch.Tensor) -> torch.Tensor:
        """[-1, 1] actions (B, 4) -> physical units (inverse of :meth:`action_to_unit`)."""
        return self.act_center + self.act_half * u


def position_frequencies(octaves: int) -> torch.Tensor:
    """Angular frequencies ``pi/2 * 2^k``, k = 0 .. octaves - 1, per unit of standardised
    position: the lowest has a period of 4 standard deviations (a maze's whole extent, which
    a uniform spread covers in about 3.5), each next one half of it."""
    return (math.pi / 2) * 2.0 ** torch.arange(octaves, dtype=torch.float32)


def position_features(p: torch.Tensor, freq: torch.Tensor) -> torch.Tensor:
    """Fourier features of standardised positions p (B, 3) over the frequencies ``f`` (K):
    ``[sin(f_k p_i)]`` then ``[cos(f_k p_i)]`` (B, 6 K), each axis-major (i outer, k inner). In a maze the expert's choice at rest is a
    function of (cell, goal cell) with jumps at the walls; a ReLU network of raw coordinates
    fits such a function slowly (spectral bias), one of these features in a few steps
    (Tancik et al. 2020, "Fourier features let networks learn high frequency functions")."""
    a = (p.unsqueeze(-1) * freq).flatten(-2)  # (B, 3 K)
    return torch.cat([torch.sin(a), torch.cos(a)], -1)


def fourier_inputs(raw: torch.Tensor, in_mean: torch.Tensor, in_std: torch.Tensor, freq: torch.Tensor) -> torch.Tensor:
    """The features (B, 12 K) of an unstandardised 33-d input's state position ``p`` and goal
    position ``p_g = p + (p_g - p)``, both standardised by the position's statistics."""
    pos, rel = slice(IN_DIM, IN_DIM + POS_DIM), slice(task.OBS_DIM, task.OBS_DIM + POS_DIM)
    p = raw[..., pos]
    return torch.cat([position_features((q - in_mean[pos]) / in_std[pos], freq) for q in (p, p + raw[..., rel])], -1)


def adam(params: Any, lr: float) -> torch.optim.Adam:
    """torch's Adam with its fused kernel: one pass over each parameter tensor instead of a
    dozen element-wise operations, the same update up to rounding (fused Adam runs on CPU
    and CUDA alike). On a small network the optimiser step is a large share of a gradient
    step, and under bf16 autocast every separate operation also pays the autocast dispatch."""
    return torch.optim.Adam(params, lr=lr, fused=True)


def mlp(in_features: int, out_features: int, hidden: Sequence[int]) -> MLP:
    """A ReLU MLP ``in_features -> hidden... -> out_features``."""
    return MLP(in_features=in_features, out_features=out_features, num_cells=list(hidden), activation_class=nn.ReLU)


def make_actor(hidden: Sequence[int], in_dim: int = IN_DIM) -> TensorDictModule:
    """Deterministic actor: observation (``in_dim``: the normaliser's) -> tanh(MLP) = action in [-1, 1]."""
    return TensorDictModule(nn.Sequential(mlp(in_dim, ACT_DIM, hidden), nn.Tanh()), in_keys=["observation"], out_keys=["action"])


def make_critic(hidden: Sequence[int], in_dim: int = IN_DIM) -> ValueOperator:
    """One goal-conditioned critic Q(o, g, a) (the MLP concatenates its inputs)."""
    return ValueOperator(mlp(in_dim + ACT_DIM, 1, hidden), in_keys=["observation", "action"])


# --- pieces of OGBench's goal-conditioned agents (gciql, crl, qrl, hiql) ---------------


def ln_mlp(in_features: int, out_features: int, hidden: Sequence[int]) -> MLP:
    """A ReLU MLP with a LayerNorm on every hidden layer (OGBench's value networks use
    ``layer_norm=True``; torchrl's MLP puts the norm before the activation, OGBench after)."""
    return MLP(
        in_features=in_features,
        out_features=out_features,
        num_cells=list(hidden),
        activation_class=nn.ReLU,
        norm_class=nn.LayerNorm,
        norm_kwargs=[{"normalized_shape": h} for h in hidden],
    )


class Twin(nn.Module):
    """Two independently initialised copies of a network, called together: ``(2, B, ...)``
    (OGBench's ``ensemble=True`` value and critic heads, whose minimum or mean is taken)."""

    def __init__(self, make: Callable[[], nn.Module]):
        super().__init__()
        self.nets = nn.ModuleList([make(), make()])

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        """Both networks' outputs on the same inputs, stacked on a leading dimension of 2."""
        return torch.stack([net(*inputs) for net in self.nets])


def frozen(module: nn.Module, *inputs: torch.Tensor) -> torch.Tensor:
    """``module(*inputs)`` with its parameters detached: gradients reach the inputs only
    (an actor loss through a critic, which in OGBench's one joint step never moves the
    critic: the critic's loss owns its parameters)."""
    params = {k: v.detach() for k, v in module.named_parameters()}
    return torch.func.functional_call(module, params, inputs)


def make_target(module: nn.Module, tau: float) -> nn.Module:
    """A target network: torch's ``AveragedModel`` of ``module`` with the EMA update
    ``phi' <- (1 - tau) phi' + tau phi`` (``update_parameters(module)`` after each step;
    in the state dict). torchrl's ``SoftUpdate`` does the same on a torchrl ``LossModule``'s
    functional target parameters; these agents' losses are not torchrl losses, so torch's
    EMA holds their targets, as it holds the policy's EMA."""
    from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

    target = AveragedModel(module, multi_avg_fn=get_ema_multi_avg_fn(1.0 - tau))
    target.requires_grad_(False)
    return target


def gaussian_log_prob(mean: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``log N(x; mean, I)`` summed over the last dimension: the log-likelihood of OGBench's
    actors with a constant unit std (``const_std=True``), whose BC and AWR terms weigh it."""
    return torch.distributions.Normal(mean, torch.ones_like(mean)).log_prob(x).sum(-1)


def success_value(v: torch.Tensor, gamma: float) -> torch.Tensor:
    """OGBench-unit value (reward -1 per step, 0 on reaching the goal: ``V = -(1 - gamma^d) / (1 - gamma)``
    for a goal ``d`` steps away) -> this toolkit's discounted success ``1 + (1 - gamma) V = gamma^d``, clipped to [0, 1]."""
    return (1.0 + (1.0 - gamma) * v).clamp(0.0, 1.0)


class ClippedTD0Estimator(TD0Estimator):
    """TD(0) target clipped to [0, 1] (thesis Eq. 3.2: with a sparse 0/1 reward no return
    lies outside it; clipping stops over-estimation). torchrl's TD0 has no clipping, so the
    estimator is extended rather than the loss rewritten.

    When the batch carries ``"mc_lower_bound"`` (``--mc-lower-bound``), the target is
    ``max(clip(TD target), bound)``: the discounted return that the data's own
    continuation achieves for the goal (Monte-Carlo augmented actor-critic, Wilcox et al.
    2022). TD(0) with soft target updates moves a sparse reward back about one step per
    ``1 / tau`` updates, so in a 15k-step CPU run the critics know only the last ~50 steps
    before a goal; the bound gives every step of an expert trajectory its value at once,
    and on expert data it is close to the value itself. Off in the ``thesis`` preset."""

    def value_estimate(
        self,
        tensordict: TensorDict,
        target_params: TensorDict | None = None,
        next_value: torch.Tensor | None = None,
        **kwargs: Any,
    ) -> torch.Tensor:
        """The TD(0) target ``r + gamma (1 - done) V'`` clipped to [0, 1], raised to the
        Monte-Carlo lower bound ``mc_lower_bound`` where the batch has one."""
        v = super().value_estimate(tensordict, target_params=target_params, next_value=next_value, **kwargs).clamp(0.0, 1.0)
        lb = tensordict.get("mc_lower_bound", None)
        return v if lb is None else torch.maximum(v, lb.to(v.dtype))


def make_critic_loss(
    actor: TensorDictModule,
    hidden: Sequence[int],
    *,
    num_critics: int,
    gamma: float,
    delay_actor: bool,
    policy_noise: float,
    noise_clip: float,
    alpha: float = 2.5,
    loss_cls: type[TD3BCLoss] = TD3BCLoss,
    in_dim: int = IN_DIM,
) -> TD3BCLoss:
    """torchrl's ``TD3BCLoss`` over an ensemble of ``num_critics`` critics, each with its
    own initialisation and target network, targets ``clip(r + gamma (1 - done)
    min_j Q'_j(s', a', g), 0, 1)`` (docs/spec.md; the minimum over *all* critics is exactly
    what TD3BCLoss computes), squared error.

    The next action ``a'`` is the target actor's action plus clipped noise (TD3-BC) or,
    with ``delay_actor=False, policy_noise=0``, the learned policy's own action (Alg. 2,
    used by GCSL and CQL).
    """
    critics = [make_critic(hidden, in_dim) for _ in range(num_critics)]
    with warnings.catch_warnings():  # torchrl warns that target_actor_network_params is unannotated when delay_actor=False
        warnings.filterwarnings("ignore", message=".*target_actor_network_params.*")
        loss = _make_td3bc(loss_cls, actor, critics, num_critics, policy_noise, noise_clip, alpha, delay_actor)
    return use_clipped_td0(loss, gamma, loss.tensor_keys.state_action_value)


def _make_td3bc(loss_cls, actor, critics, num_critics, policy_noise, noise_clip, alpha, delay_actor):
    return loss_cls(
        actor,
        critics,
        bounds=(-torch.ones(ACT_DIM), torch.ones(ACT_DIM)),
        num_qvalue_nets=num_critics,
        policy_noise=policy_noise,
        noise_clip=noise_clip,
        alpha=alpha,
        loss_function="l2",
        delay_actor=delay_actor,
        delay_qvalue=True,
    )


def use_clipped_td0(loss: LossModule, gamma: float, value_key: Any) -> LossModule:
    """Give a torchrl loss the [0, 1]-clipped TD(0) target (keys: ("next", reward|done|terminated))."""
    est = ClippedTD0Estimator(gamma=gamma, value_network=None)
    est.set_keys(value=value_key, reward="reward", done="done", terminated="terminated")
    loss.make_value_estimator(est)
    return loss


class EnsembleSoftUpdate(SoftUpdate):
    """torchrl's ``SoftUpdate`` (``phi' <- (1 - tau) phi' + tau phi``, its ``step``/``_step``)
    for losses whose critic ensemble is a *list* of modules.

    torchrl 0.13.3 + tensordict 0.13.0: ``TargetNetUpdater.init_`` ends with a ``select``
    on the nested, locked ``TensorDictParams`` that ``TensorDict.from_modules`` builds
    for a list of critics, which raises "Cannot modify locked TensorDict" (also for
    plain ``TD3BCLoss`` with ``delay_actor=True``). This ``init_`` keeps the same
    semantics -- every target group whose tensors are distinct copies is synchronised
    to its source and updated; groups that share the source's storage (an actor with
    ``delay_actor=False``, as GCSL's and CQL's ensemble losses) are skipped -- without
    that ``select``.
    """

    # set by torchrl's TargetNetUpdater.__init__, whose untyped code mypy cannot infer them from
    _target_names: list[str]
    _source_names: list[str]

    def init_(self) -> None:
        """Copy each source's weights to its target group (the start of the Polyak averaging);
        target groups that share the source's storage are skipped (class docstring)."""
        keep = []
        for t, s in zip(self._target_names, self._source_names):
            src, tgt = getattr(self.loss_module, s), getattr(self.loss_module, t)
            if tgt.requires_grad:
                raise RuntimeError("the target parameter is part of a graph.")
            distinct = all(v.data_ptr() != src.get(k).data.data_ptr() for k, v in tgt.items(True, True))
            if distinct:
                tgt.data.copy_(src.data)
                keep.append((t, s))
        if not keep:
            raise RuntimeError("no distinct target parameters to update")
        self._target_names = [t for t, _ in keep]
        self._source_names = [s for _, s in keep]
        self.initialized = True


def ensemble_values(
    loss: LossModule, observation: torch.Tensor, action: torch.Tensor, params: TensorDict | None = None
) -> torch.Tensor:
    """(num_critics, B) values of every critic of a torchrl loss's vmapped ensemble."""
    params = loss.qvalue_network_params if params is None else params
    n = params.batch_size[0]
    td = TensorDict({"observation": observation, "action": action}, batch_size=observation.shape[:-1])
    td = td.expand(n, *td.batch_size)
    return loss._vmap_qvalue_network00(td, params).get("state_action_value").squeeze(-1)


__all__ = [
    "adam",
    "Normalizer",
    "position_features",
    "position_frequencies",
    "fourier_inputs",
    "make_actor",
    "make_critic",
    "make_critic_loss",
    "ClippedTD0Estimator",
    "use_clipped_td0",
    "ensemble_values",
    "EnsembleSoftUpdate",
    "mlp",
    "ln_mlp",
    "Twin",
    "frozen",
    "make_target",
    "gaussian_log_prob",
    "success_value",
    "IN_DIM",
    "POS_DIM",
    "ACT_DIM",
    "TensorDictSequential",
]
