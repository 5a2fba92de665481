"""Learned planner: recurrent actor-critic over motion primitives (thesis §2.5.3).

Network (thesis Fig. 2.2 in spirit): a small CNN over the egocentric multi-scale maps
and an MLP over the vector features, a GRU core (``recurrent=False`` gives the
"no-LSTM" variant: an MLP core), and three heads:

* policy logits over the action slots, ``pi(.|o_t)``;
* one value per reward term (entropy, coverage, target, cost, invalid), ``V_delta``;
  the state value is their sum;
* valid-primitive logits ``phi(o_t)`` trained with the asymmetric binary cross entropy
  of Eq. 2.7 against the environment's valid mask.

With ``n_feat > 0`` the policy also reads per-primitive look-ahead features
(:mod:`.features`): each action slot's feature vector is embedded by a shared MLP; the
mean and max of the embeddings join the trunk (so the core and the value heads see
them) and a per-slot scoring head adds ``w . relu(emb_a + ctx(h))`` to the slot's logit
(a pointer-style head, one set of weights for every slot).
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from aerohrl import atomic
from aerohrl.errors import UserError, warn

from .baselines import Planner
from .env import TERMS
from .train_config import PolicyConfig  # noqa: F401  (declared torch-free for the flags)


class ActorCritic(nn.Module):
    # set after construction: load_policy (env_kind, train_info) and ipp.cli (run_label, checkpoint_name)
    env_kind: str
    train_info: dict
    run_label: str
    checkpoint_name: str
    # the learned belief the policy observes in place of the posterior plane (train's
    # belief_input; saved with the policy), None: the hand-written posterior
    obs_belief: Any = None

    def __init__(
        self, map_ch: int, map_hw: int, vec_dim: int, n_actions: int, cfg: PolicyConfig = PolicyConfig(), n_feat: int = 0
    ):
        super().__init__()
        self.cfg = cfg
        self.n_feat = n_feat
        h = cfg.hidden
        self.conv = nn.Sequential(
            nn.Conv2d(map_ch, 32, 3, padding=1), nn.ReLU(), nn.Conv2d(32, 64, 3, stride=2, padding=1), nn.ReLU(), nn.Flatten()
        )
        conv_out = 64 * ((map_hw + 1) // 2) ** 2
        self.vec = nn.Sequential(nn.Linear(vec_dim, 64), nn.ReLU())
        fe = 0
        if n_feat:
            fe = 64
            self.feat = nn.Sequential(nn.Linear(n_feat, fe), nn.ReLU(), nn.Linear(fe, fe), nn.ReLU())
            self.ctx = nn.Linear(h, fe)
            self.score = nn.Linear(fe, 1)
        self.fuse = nn.Sequential(nn.Linear(conv_out + 64 + 2 * fe, 2 * h), nn.ReLU(), nn.Linear(2 * h, h), nn.ReLU())
        self.core = nn.GRU(h, h, batch_first=False) if cfg.recurrent else nn.Sequential(nn.Linear(h, h), nn.ReLU())
        self.pi = nn.Linear(h, n_actions)
        self.v = nn.Linear(h, len(TERMS))
        self.valid = nn.Linear(h, n_actions)
        nn.init.orthogonal_(self.pi.weight, 0.01)
        nn.init.zeros_(self.pi.bias)

    def initial_state(self, n: int) -> torch.Tensor:
        """The zero recurrent state (1, n, hidden) of ``n`` new episodes."""
        return torch.zeros(1, n, self.cfg.hidden)

    def forward(
        self, maps: torch.Tensor, vec: torch.Tensor, h: torch.Tensor, feat: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """maps (T, N, C, H, W), vec (T, N, D), h (1, N, hidden), feat (T, N, A, F)
        -> (policy logits, per-term values, valid logits, h) over (T, N)."""
        T, N = maps.shape[:2]
        parts = [self.conv(maps.reshape(T * N, *maps.shape[2:])), self.vec(vec.reshape(T * N, -1))]
        if self.n_feat:
            if feat is None:
                raise UserError("this policy needs per-primitive features (feat)")
            e = self.feat(feat.reshape(T * N, feat.shape[2], -1))  # (TN, A, fe)
            parts += [e.mean(1), e.max(1).values]
        x = self.fuse(torch.cat(parts, -1)).reshape(T, N, -1)
        if self.cfg.recurrent:
            x, h = self.core(x, h)
        else:
            x = self.core(x)
        logits = self.pi(x)
        if self.n_feat:
            c = self.ctx(x).reshape(T * N, 1, -1)
            logits = logits + self.score(torch.relu(e + c)).reshape(T, N, -1)
        return logits, self.v(x), self.valid(x), h


def valid_loss(phi_logits: torch.Tensor, valid: torch.Tensor, beta1: float = 1.0, beta2: float = 0.2) -> torch.Tensor:
    """Eq. 2.7: ``-[beta1 (1-y) log(1-phi) + beta2 y log phi]`` (invalid weighted heavily)."""
    y = valid.float()
    ls = nn.functional.logsigmoid
    return -(beta1 * (1 - y) * ls(-phi_logits) + beta2 * y * ls(phi_logits)).mean()


def save_policy(model: ActorCritic, dims: dict, path: str | Path, env_kind: str = "targets") -> None:
    """Atomically, with a SHA-256 sidecar (``model.pt.sha256``) checked by :func:`load_policy`;
    the learned belief it observes (``model.obs_belief``) goes with it, so the file alone acts."""
    ck = {"state_dict": model.state_dict(), "dims": dims, "config": asdict(model.cfg), "env_kind": env_kind}
    if model.obs_belief is not None:
        from .belief import belief_state

        ck["obs_belief"] = belief_state(model.obs_belief)
    atomic.torch_save(path, ck)


def load_policy(path: str | Path) -> ActorCritic:
    """A policy saved by :func:`save_policy` (``path`` or ``path/model.pt``), its SHA-256
    verified, in eval mode; a one-line UserError when missing or damaged."""
    path = Path(path)
    if path.is_dir():
        path = path / "model.pt"
    if not path.is_file():
        raise UserError(f"no trained policy at {path} (run 'aerohrl ipp train' first)")
    ck = atomic.torch_load(path, weights_only=True, warn=warn)  # CheckpointDamaged names the file
    try:
        model = ActorCritic(**ck["dims"], cfg=PolicyConfig(**ck["config"]))
        model.env_kind = ck.get("env_kind", "targets")
        model.load_state_dict(ck["state_dict"])
    except Exception as e:
        raise UserError(f"{path}: not a policy checkpoint ({type(e).__name__})") from None
    from .features import N_FEAT

    if model.n_feat not in (0, N_FEAT):
        raise UserError(f"{path}: policy reads {model.n_feat} primitive features, this version computes {N_FEAT} (retrain it)")
    if "obs_belief" in ck:
        from .belief import belief_from_state

        model.obs_belief = belief_from_state(ck["obs_belief"], str(path))
    model.train_info = _train_info(path.parent)
    model.eval()
    return model


def _train_info(run: Path) -> dict:
    """What trained the policy, from ``RUN/config.json`` (written by ``ipp train``):
    DAgger iterations, teacher, PPO iterations, training seed. Empty if the file is absent or unreadable."""
    from aerohrl.algorithms.run import Run

    try:
        cfg = Run.open(run).meta
    except UserError:
        return {}
    tc = cfg.get("train", cfg)
    keys = ("bc_iterations", "teacher", "teacher_depth", "teacher_belief", "iterations", "seed")
    return {k: tc[k] for k in keys if isinstance(tc, dict) and k in tc}


def describe_policy(model: ActorCritic) -> str:
    """The truthful row name of a trained policy: what it learned from and what it reads.

    * DAgger from a teacher, no PPO: ``Imitation of detect (DAgger; its features, GRU)``
      (``detect over the learned belief`` when the teacher planned over it);
    * DAgger then PPO: ``Imitation of detect + PPO (...)``;
    * no warm start: ``Actor-critic RL (map-only, GRU)`` (the thesis's setting);
      ``(map-only, the learned belief's map, GRU)`` when it observes the learned belief.
    ``features`` = the per-primitive look-ahead features (:mod:`.features`), whose
    feature 14 is the ``detect`` planner's own score."""
    info = getattr(model, "train_info", {}) or {}
    core = "GRU" if model.cfg.recurrent else "MLP core"
    obs = "its features" if model.cfg.features else "map-only"
    belief = ", the learned belief's map" if model.obs_belief is not None else ""
    bc, it = int(info.get("bc_iterations", 0) or 0), int(info.get("iterations", 0) or 0)
    if bc > 0:
        t = info.get("teacher", "detect")
        depth = info.get("teacher_depth")
        t = f"{t}{'' if depth in (None, 2) else f' depth {depth}'}"
        t += " over the learned belief" if info.get("teacher_belief") else ""
        ppo = f" + PPO {it} it." if it > 0 else ""
        feats = "its features" if model.cfg.features and t.startswith("detect") else obs
        return f"Imitation of {t} planner{ppo} (DAgger; {feats}{belief}, {core})"
    if info:
        return f"Actor-critic RL ({obs}{belief}, {core})"
    return f"Learned policy ({obs}{belief}, {core}; training unknown)"


class RLPlanner(Planner):
    """Acts with a trained :class:`ActorCritic` (argmax over valid primitives)."""

    name = "rl"

    def __init__(self, env, model: ActorCritic, greedy: bool = True):
        super().__init__(env)
        self.model, self.greedy = model, greedy
        self.h: torch.Tensor | None = None
        if model.obs_belief is not None:  # observe what it was trained on
            model.obs_belief.check_env(env)
            env.obs_belief = model.obs_belief

    def reset(self) -> None:
        """Forget the recurrent state (a new episode starts)."""
        self.h = None

    @torch.no_grad()
    def act(self) -> np.ndarray:
        """One action slot per environment (N,) int: a valid primitive of the policy (its argmax
        when ``greedy``, else sampled); the recurrent state advances for live envs."""
        env = self.env
        if self.h is None or self.h.shape[1] != env.n:
            self.h = self.model.initial_state(env.n)
        obs = env.observe()
        feat = None
        if self.model.n_feat:
            feat = torch.from_numpy(env.action_features())[None]
        logits, _, _, h = self.model(torch.from_numpy(obs["maps"])[None], torch.from_numpy(obs["vec"])[None], self.h, feat)
        live = torch.from_numpy(~env.done)
        self.h = torch.where(live[None, :, None], h, self.h)
        logits = logits[0]
        valid = torch.from_numpy(obs["valid"])
        logits = logits.masked_fill(~valid, -1e9)
        if self.greedy:
            a = logits.argmax(-1)
        else:
            a = torch.distributions.Categorical(logits=logits).sample()
        return a.numpy().astype(np.int64)
