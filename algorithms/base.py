"""The interface every algorithm implements, so the trainer, the evaluator and the
planner never branch on the algorithm's name:

* ``build_algorithm(cfg, normalizer)``;
* ``update(batch) -> metrics`` (a dict of detached scalar tensors);
* ``act(state, goal)`` -> (B, 4) CTBR actions, batched and deterministic, from absolute
  states (B, 18) and goals (B, 15) (inputs via :func:`aerohrl.task.policy_inputs`);
* ``critics(state, goal, action)`` -> (num_critics, B), the goal-conditioned ensemble the
  planner scores with (thesis Eq. 3.7);
* ``optimizers()`` -> name -> torch optimiser (checkpointed by the trainer).

The module's ``state_dict`` holds every weight, target weight, learned temperature and
the dataset normaliser.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import nn

from aerohrl.algorithms.networks import Normalizer, ensemble_values
from aerohrl.errors import UserError

if TYPE_CHECKING:
    from pathlib import Path

    from tensordict import TensorDict

    from aerohrl.algorithms.config import TrainConfig
    from aerohrl.algorithms.run import Run


class Algorithm(nn.Module):
    name = ""

    def __init__(self, cfg, normalizer: Normalizer):
        super().__init__()
        self.cfg = cfg
        self.normalizer = normalizer
        self.num_updates = 0

    # --- to implement -------------------------------------------------------------
    def update(self, batch: TensorDict) -> dict[str, torch.Tensor]:  # pragma: no cover - interface
        """One gradient step of every network on ``batch``; the losses (detached) by name."""
        raise NotImplementedError

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:  # pragma: no cover - interface
        """The optimisers by name (checkpointed with the weights)."""
        raise NotImplementedError

    def policy_net(self) -> nn.Module:  # pragma: no cover - interface
        """The deterministic policy as a module: normalised inputs -> action in [-1, 1]."""
        raise NotImplementedError

    # the TD3BCLoss holding the critic ensemble (see networks.make_critic_loss)
    critic_loss: nn.Module

    @classmethod
    def sampler_options(cls, cfg: TrainConfig) -> dict:
        """Extra keyword arguments of :class:`~aerohrl.algorithms.data.GoalBatchSampler`
        this algorithm's batches need (OGBench-style ``goal_mixes``, HIQL's
        ``subgoal_steps``); none for the thesis's four, whose batches stay as they were."""
        return {}

    # --- shared -------------------------------------------------------------------
    def setup_ema(self) -> None:
        """With ``cfg.ema_decay > 0``, keep an exponential moving average of the policy's
        weights (torch's ``AveragedModel`` with its EMA update), which ``act`` then uses:
        BC's last iterates jitter by more than the goal tolerances ask for, the average
        does not. Its weights live in the state dict (checkpointed, resumable)."""
        self.policy_ema = None
        if getattr(self.cfg, "ema_decay", 0.0) > 0:
            from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

            self.policy_ema = AveragedModel(self.policy_net(), multi_avg_fn=get_ema_multi_avg_fn(self.cfg.ema_decay))

    @staticmethod
    def critic_batch(batch: TensorDict) -> TensorDict:
        """The batch the critic ensemble learns from: its own goals when the sampler drew
        them (``--critic-random-goal-prob``, key ``"critic"``), else the actor's batch."""
        return batch.get("critic") if "critic" in batch.keys() else batch

    @staticmethod
    def actor_batch(batch: TensorDict) -> TensorDict:
        """The batch the policy imitates: the flown ``action`` replaced by the BC target
        (``"bc_action"``: the clean expert command of a noisy dataset, ``--bc-target
        expert``) when the sampler provides one. The critics keep the flown action."""
        if "bc_action" not in batch.keys():
            return batch
        return batch.clone(False).set("action", batch.get("bc_action"))

    def ema_step(self) -> None:
        """Call after every policy update."""
        if self.policy_ema is not None:
            self.policy_ema.update_parameters(self.policy_net())

    def policy_unit(self, observation: torch.Tensor) -> torch.Tensor:
        """Deterministic action in [-1, 1] from normalised inputs (the EMA weights when kept)."""
        net = self.policy_ema.module if self.policy_ema is not None else self.policy_net()
        return net(observation)

    @torch.no_grad()
    def act(self, state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """The action (B, 4), in physical units, for states (B, 18) and goals (B, 15)."""
        x = self.normalizer.inputs(state, goal)
        return self.normalizer.action_from_unit(self.policy_unit(x))

    @torch.no_grad()
    def critics(self, state: torch.Tensor, goal: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Every critic's value ``Q_j(o, g, a)`` -> (num_critics, B), for states (B, 18),
        goals (B, 15) and physical actions (B, 4). A one-line error for a run that trained no
        critics (GCSL with ``--no-train-critics``)."""
        if not getattr(self.cfg, "train_critics", True):
            raise UserError("this run trained its policy alone (--no-train-critics): it has no critics to plan or rank with")
        x = self.normalizer.inputs(state, goal)
        return ensemble_values(self.critic_loss, x, self.normalizer.action_to_unit(action))

    def extra_state(self) -> dict:
        """What a checkpoint keeps beyond the state dict (the update count)."""
        return {"num_updates": self.num_updates}

    def load_extra_state(self, d: dict) -> None:
        """Restore :meth:`extra_state` from a checkpoint."""
        self.num_updates = int(d.get("num_updates", 0))


def algorithm_class(name: str) -> type[Algorithm]:
    """The :class:`Algorithm` subclass named ``name`` (gcsl, td3bc, td3awbc, cql, gciql, crl, qrl, hiql)."""
    from aerohrl.algorithms.cql import CQL
    from aerohrl.algorithms.crl import CRL
    from aerohrl.algorithms.gciql import GCIQL
    from aerohrl.algorithms.gcsl import GCSL
    from aerohrl.algorithms.hiql import HIQL
    from aerohrl.algorithms.qrl import QRL
    from aerohrl.algorithms.td3awbc import TD3AWBC
    from aerohrl.algorithms.td3bc import TD3BC

    classes: dict[str, type[Algorithm]] = {
        "gcsl": GCSL,
        "td3bc": TD3BC,
        "td3awbc": TD3AWBC,
        "cql": CQL,
        "gciql": GCIQL,
        "crl": CRL,
        "qrl": QRL,
        "hiql": HIQL,
    }
    return classes[name]


def build_algorithm(cfg: TrainConfig, normalizer: Normalizer) -> Algorithm:
    """The algorithm ``cfg.algo`` with fresh weights (seed the RNG before calling)."""
    return algorithm_class(cfg.algo)(cfg, normalizer)


def load_policy(ckpt_path: str | Path, device: str | torch.device = "cpu", run: Run | None = None) -> tuple[Algorithm, dict]:
    """(algo, checkpoint dict) from a checkpoint file (of ``run``, when given), its SHA-256
    verified, in eval mode."""
    from aerohrl.algorithms import config as C
    from aerohrl.algorithms.run import load_checkpoint

    ck = run.load_checkpoint(ckpt_path, map_location=device) if run is not None else load_checkpoint(ckpt_path, device)
    try:
        cfg = C.from_dict(ck["config"])
        algo = build_algorithm(cfg, Normalizer.for_state_dict(ck["model"])).to(device)
        algo.load_state_dict(ck["model"])
    except (KeyError, RuntimeError, ValueError, TypeError) as e:
        raise UserError(f"checkpoint {ckpt_path} cannot be loaded as a policy: {e}") from None
    algo.eval()
    return algo, ck


__all__ = ["Algorithm", "build_algorithm", "algorithm_class", "load_policy"]
