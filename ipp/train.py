"""Train the learned planner: synchronous PPO on batched environments (thesis §2.5.3).

The thesis trained with A3C (asynchronous workers, one episode each). Here ``n_envs``
environments run in one batch, every iteration collects one full episode per
environment (the budget bounds its length), and the recurrent policy is updated by
back-propagation through the whole episode with the clipped PPO objective, which is a
"sound parallel actor-critic on batched environments" (SPEC.md). Losses:

* critic: ``sum_delta (G^lambda_delta - V_delta)^2`` per reward term (Eq. 2.6 per head);
* actor: clipped surrogate on GAE(lambda) advantages of the summed reward;
* entropy bonus ``alpha_1 L_ent`` and the valid-primitive loss ``L_val`` (Eq. 2.7),
  combined as Eq. 2.8.

Deviation: primitives are sampled only among valid ones (``mask_invalid``); the thesis
found masking brittle with asynchronous updates, which do not occur here. The valid
head is still trained (Eq. 2.7) and reported.

Training worlds come from suite seed ``seed`` (never the test seed) with random starts.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from aerohrl.errors import UserError

from ._io import atomic_path
from .env import TERMS, EnvConfig, create_env, sample_for
from .lattice import Lattice
from .features import N_FEAT
from .policy import ActorCritic, PolicyConfig, save_policy, valid_loss


@dataclass(frozen=True)
class TrainConfig:
    n_envs: int = 64
    iterations: int = 600
    lr: float = 3e-4
    gamma: float = 0.98
    lam: float = 0.8              # thesis: lambda = 0.8
    clip: float = 0.2
    epochs: int = 4
    minibatches: int = 4
    value_coef: float = 0.5
    entropy_coef: float = 0.01
    valid_coef: float = 0.1
    valid_beta: tuple[float, float] = (1.0, 0.2)   # Eq. 2.7 beta1 (invalid), beta2 (valid)
    reward_scale: float = 0.05    # rewards / 20: one target = 1
    grad_clip: float = 5.0
    seed: int = 7
    threads: int = 1
    log_every: int = 10
    init: str | None = None       # warm start: a run directory / model.pt (fine-tuning)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    env: EnvConfig = field(default_factory=lambda: EnvConfig(start="random"))


PRESETS = {
    "cpu": TrainConfig(),
    "quick": TrainConfig(n_envs=32, iterations=60),
    "test": TrainConfig(n_envs=4, iterations=2, epochs=1, minibatches=1,
                        policy=PolicyConfig(hidden=32)),
}


def _gae(rew, val, alive, gamma, lam):
    """GAE(lambda) per term. rew, val (T, N, K); alive (T, N). Returns adv, returns."""
    T = rew.shape[0]
    adv = torch.zeros_like(rew)
    last = torch.zeros_like(rew[0])
    for t in reversed(range(T)):
        nxt = val[t + 1] * alive[t + 1, :, None] if t + 1 < T else torch.zeros_like(val[t])
        delta = rew[t] + gamma * nxt - val[t]
        cont = alive[t + 1, :, None] if t + 1 < T else torch.zeros_like(alive[t, :, None])
        last = delta + gamma * lam * cont * last
        adv[t] = last * alive[t, :, None]
    return adv, adv + val


def train(cfg: TrainConfig, lattice: Lattice, run_dir: Path, progress=None) -> dict:
    if cfg.n_envs < 1 or cfg.iterations < 1:
        raise UserError("--envs and --iterations must be >= 1")
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    env = create_env(cfg.env, lattice)
    obs = env.reset(sample_for(cfg.env, cfg.seed, range(cfg.n_envs)))
    dims = {"map_ch": obs["maps"].shape[1], "map_hw": obs["maps"].shape[2],
            "vec_dim": obs["vec"].shape[1], "n_actions": lattice.n_actions,
            "n_feat": N_FEAT if cfg.policy.features else 0}
    model = ActorCritic(**dims, cfg=cfg.policy)
    if cfg.init is not None:
        from .policy import load_policy
        src = load_policy(cfg.init)
        if src.n_feat != dims["n_feat"] or src.cfg != cfg.policy or \
                src.pi.out_features != dims["n_actions"]:
            raise UserError(f"{cfg.init}: policy does not match this configuration")
        try:
            model.load_state_dict(src.state_dict())
        except RuntimeError:
            raise UserError(f"{cfg.init}: policy shapes do not match this environment") from None
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    with atomic_path(run_dir / "config.json") as tmp:
        Path(tmp).write_text(json.dumps({"train": asdict(cfg), "dims": dims,
                                         "lattice": asdict(lattice.config)}, indent=1))
    log_path = run_dir / "metrics.jsonl"
    log_path.write_text("")
    N = cfg.n_envs
    last = {}
    t0 = time.time()
    for it in range(cfg.iterations):
        ids = range(it * N, (it + 1) * N)
        obs = env.reset(sample_for(cfg.env, cfg.seed, ids))
        h = model.initial_state(N)
        M, Vv, Vd, A, LP, R, AL, F = [], [], [], [], [], [], [], []
        with torch.no_grad():
            while not env.done.all():
                alive = torch.from_numpy(~env.done)
                maps = torch.from_numpy(obs["maps"])
                vec = torch.from_numpy(obs["vec"])
                valid = torch.from_numpy(obs["valid"])
                feat = torch.from_numpy(env.action_features()) if dims["n_feat"] else None
                logits, _, _, h = model(maps[None], vec[None], h,
                                        None if feat is None else feat[None])
                logits = logits[0]
                if cfg.policy.mask_invalid:
                    logits = logits.masked_fill(~valid, -1e9)
                dist = torch.distributions.Categorical(logits=logits)
                a = dist.sample()
                M.append(maps), Vv.append(vec), Vd.append(valid), A.append(a)
                LP.append(dist.log_prob(a)), AL.append(alive), F.append(feat)
                obs, _, terms, _ = env.step(a.numpy())
                R.append(torch.from_numpy(terms).float() * cfg.reward_scale)
        maps, vec, valid = torch.stack(M), torch.stack(Vv), torch.stack(Vd)
        act, oldlp, rew = torch.stack(A), torch.stack(LP), torch.stack(R)
        alive = torch.stack(AL).float()
        feats = torch.stack(F) if dims["n_feat"] else None
        with torch.no_grad():
            _, v_old, _, _ = model(maps, vec, model.initial_state(N), feats)
        adv_k, ret = _gae(rew, v_old, alive, cfg.gamma, cfg.lam)
        adv = adv_k.sum(-1)
        am = alive.bool()
        adv = (adv - adv[am].mean()) / (adv[am].std() + 1e-8)
        stats = []
        for _ in range(cfg.epochs):
            perm = torch.randperm(N)
            for mb in perm.chunk(cfg.minibatches):
                logits, v, phi, _ = model(maps[:, mb], vec[:, mb], model.initial_state(len(mb)),
                                          None if feats is None else feats[:, mb])
                if cfg.policy.mask_invalid:
                    logits = logits.masked_fill(~valid[:, mb], -1e9)
                dist = torch.distributions.Categorical(logits=logits)
                lp = dist.log_prob(act[:, mb])
                w = alive[:, mb]
                nw = w.sum().clamp(min=1)
                ratio = torch.exp(lp - oldlp[:, mb])
                a_mb = adv[:, mb]
                pg = -torch.min(ratio * a_mb, ratio.clamp(1 - cfg.clip, 1 + cfg.clip) * a_mb)
                l_actor = (pg * w).sum() / nw
                l_critic = (((ret[:, mb] - v) ** 2).sum(-1) * w).sum() / nw
                l_ent = (dist.entropy() * w).sum() / nw
                l_val = valid_loss(phi[w.bool()], valid[:, mb][w.bool()], *cfg.valid_beta)
                loss = l_actor + cfg.value_coef * l_critic - cfg.entropy_coef * l_ent \
                    + cfg.valid_coef * l_val  # Eq. 2.8 (+ critic)
                opt.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
                opt.step()
                stats.append([l_actor.item(), l_critic.item(), l_ent.item(), l_val.item()])
        m = env.metrics()
        tot = (rew.sum(0) / cfg.reward_scale).mean(0).tolist()
        last = {"iteration": it + 1, "time_s": round(time.time() - t0, 1),
                "return": float(sum(tot)), **{f"r_{k}": v for k, v in zip(TERMS, tot)},
                **{k: float(m[k].mean()) for k in ("coverage", "entropy_reduction",
                                                    "search_efficiency")},
                **dict(zip(("loss_actor", "loss_critic", "entropy", "loss_valid"),
                           np.mean(stats, 0).tolist()))}
        with open(log_path, "a") as f:
            f.write(json.dumps(last) + "\n")
        if progress is not None:
            progress.update(1)
            progress.set_postfix(ret=f"{last['return']:.1f}", eff=f"{last['search_efficiency']:.0f}")
        if (it + 1) % cfg.log_every == 0 or it + 1 == cfg.iterations:
            save_policy(model, dims, run_dir / "model.pt", cfg.env.kind)
    return last


def preset(name: str, **overrides) -> TrainConfig:
    if name not in PRESETS:
        raise UserError(f"unknown preset {name!r} (choose from {', '.join(PRESETS)})")
    cfg = PRESETS[name]
    over = {k: v for k, v in overrides.items() if v is not None}
    pol = over.pop("recurrent", None)
    if pol is not None:
        cfg = replace(cfg, policy=replace(cfg.policy, recurrent=pol))
    return replace(cfg, **over)
