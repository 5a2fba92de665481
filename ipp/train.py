"""Train the learned planner: synchronous PPO on batched environments (thesis §2.5.3),
optionally warm-started by behaviour cloning from a teacher planner (DAgger).

The thesis trained with A3C (asynchronous workers, one episode each). Here ``n_envs``
environments run in one batch, every iteration collects one full episode per
environment (the budget bounds its length), and the recurrent policy is updated by
back-propagation through the whole episode with the clipped PPO objective, which is a
"sound parallel actor-critic on batched environments" (docs/spec.md). Losses:

* critic: ``sum_delta (G^lambda_delta - V_delta)^2`` per reward term (Eq. 2.6 per head);
* actor: clipped surrogate on GAE(lambda) advantages; the advantage is the sum of the
  per-term GAEs weighted by ``adv_weights`` (thesis: all 1, i.e. the GAE of the summed
  reward; the per-term heads make any other weighting free);
* entropy bonus ``alpha_1 L_ent`` and the valid-primitive loss ``L_val`` (Eq. 2.7),
  combined as Eq. 2.8.

Deviation: primitives are sampled only among valid ones (``mask_invalid``); the thesis
found masking brittle with asynchronous updates, which do not occur here. The valid
head is still trained (Eq. 2.7) and reported.

**Warm start (deviation, off in the ``thesis`` preset).** With ``bc_iterations > 0``
the first iterations are DAgger (Ross et al. 2011) from a teacher tree planner
(``teacher``, default ``detect``: depth-2 search for expected new detections, see
:mod:`.baselines`): each iteration rolls out one episode per environment in which the
teacher acts with probability ``beta_i = bc_beta0 * bc_beta_decay**i`` per step and the
(sampled) student otherwise, labels every visited state with the teacher's choice,
adds the batch to a buffer of the last ``bc_buffer`` iterations and fits the whole
network on it: cross entropy of the (valid-masked) policy against the teacher's
primitive, the per-term critics against the discounted returns of the rollouts, and
the valid loss. PPO then continues from these weights (iterations
``bc_iterations .. bc_iterations + iterations - 1``).

Training worlds come from suite seed ``seed`` (never the test seed) with random starts
(iteration ``i`` uses worlds ``i*N .. (i+1)*N - 1``). With ``eval_every > 0`` the greedy
policy is also scored on a fixed validation suite (seed ``eval_seed``, centre start, not
the test seed) and the best one so far is kept as ``best.pt``.

**Bookkeeping.** ``checkpoint.pt`` (every ``log_every`` iterations and at the end) holds
the weights, the optimiser state, the iteration, the RNG states (torch and numpy), the
DAgger buffer and the best validation score; ``train(..., resume=True)`` continues from
it and gives the same weights as an uninterrupted run (CPU, same thread count).
``metrics.jsonl`` has one line per iteration; ``learning_curve.png`` is drawn at the end
(:func:`.curve.plot_learning_curve`, ``aerohrl ipp curve RUN``). The folder (claimed
exclusively, locked while training), config.json, the checkpoint and its SHA-256, the
RNG states and the metrics log are a :class:`~aerohrl.algorithms.run.Run` of kind ``ipp``.
"""

from __future__ import annotations

import shutil
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from aerohrl import config as K
from aerohrl.algorithms.run import Run, rng_state, seed_everything, set_rng_state
from aerohrl.errors import UserError
from .curve import plot_learning_curve, read_metrics
from .env import TERMS, EnvConfig
from .factory import create_env, sample_for
from .features import N_FEAT
from .lattice import Lattice
from .policy import ActorCritic, save_policy, valid_loss
from .train_config import (
    TrainConfig,
    preset,
    preset_names,
)

CHECKPOINT_VERSION = 1  # the format is the Run layout's (aerohrl.algorithms.run.LAYOUTS["ipp"])
# every shipped preset, resolved (ipp/presets/NAME.toml over the TrainConfig defaults)
PRESETS = {name: preset(name) for name in preset_names()}


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


def _discounted(rew, alive, gamma):
    """Discounted reward-to-go per term (T, N, K), zero after an episode ends."""
    out = torch.zeros_like(rew)
    acc = torch.zeros_like(rew[0])
    for t in reversed(range(rew.shape[0])):
        acc = (rew[t] + gamma * acc) * alive[t, :, None]
        out[t] = acc
    return out


# ------------------------------------------------------------------------ the run folder
def load_run_config(run_dir: str | Path | Run) -> TrainConfig:
    """The :class:`TrainConfig` of an ``ipp train`` run (``RUN/config.json``); a one-line
    UserError when it is missing or malformed."""
    return Run.open(run_dir, kind="ipp").read_config(TrainConfig, read=K.from_nested)


# --------------------------------------------------------------------------- rollouts
def _step_inputs(env, obs, use_feat):
    maps = torch.from_numpy(obs["maps"])
    vec = torch.from_numpy(obs["vec"])
    valid = torch.from_numpy(obs["valid"])
    feat = torch.from_numpy(env.action_features()) if use_feat else None
    return maps, vec, valid, feat


def _rollout(model, env, obs, cfg, use_feat, teacher=None, beta=0.0):
    """One episode per environment with the sampled policy; with a ``teacher`` each step
    is taken by the teacher with probability ``beta`` and every step is labelled with
    the teacher's primitive. Returns the stacked (T, N, ...) tensors."""
    N = env.n
    h = model.initial_state(N)
    keys = ("maps", "vec", "valid", "feat", "act", "logp", "rew", "alive", "label")
    buf = {k: [] for k in keys}
    with torch.no_grad():
        while not env.done.all():
            alive = torch.from_numpy(~env.done)
            maps, vec, valid, feat = _step_inputs(env, obs, use_feat)
            logits, _, _, h = model(maps[None], vec[None], h, None if feat is None else feat[None])
            logits = logits[0]
            if cfg.policy.mask_invalid:
                logits = logits.masked_fill(~valid, -1e9)
            dist = torch.distributions.Categorical(logits=logits)
            a = dist.sample()
            if teacher is not None:
                lab = torch.from_numpy(teacher.act())
                use = torch.rand(N) < beta
                a = torch.where(use, lab, a)
                buf["label"].append(lab)
            buf["maps"].append(maps), buf["vec"].append(vec), buf["valid"].append(valid)
            buf["feat"].append(feat), buf["act"].append(a), buf["alive"].append(alive)
            buf["logp"].append(dist.log_prob(a))
            obs, _, terms, _ = env.step(a.numpy())
            buf["rew"].append(torch.from_numpy(terms).float() * cfg.reward_scale)
    out = {k: torch.stack(v) for k, v in buf.items() if v and v[0] is not None}
    out["alive"] = out["alive"].float()
    return out


def _masked(logits, valid, cfg):
    return logits.masked_fill(~valid, -1e9) if cfg.policy.mask_invalid else logits


def _bc_update(model, opt, buffer, cfg, use_feat):
    """Fit policy (cross entropy to the teacher), critics (discounted returns) and the
    valid head on every stored DAgger batch; returns mean losses."""
    stats = []
    order = torch.randperm(len(buffer))
    for _ in range(cfg.bc_epochs):
        for bi in order.tolist():
            b = buffer[bi]
            N = b["maps"].shape[1]
            for mb in torch.randperm(N).chunk(cfg.minibatches):
                logits, v, phi, _ = model(
                    b["maps"][:, mb].float(),
                    b["vec"][:, mb],
                    model.initial_state(len(mb)),
                    b["feat"][:, mb] if use_feat else None,
                )
                valid = b["valid"][:, mb]
                w = b["alive"][:, mb]
                nw = w.sum().clamp(min=1)
                lp = torch.log_softmax(_masked(logits, valid, cfg), -1)
                ce = -(lp.gather(-1, b["label"][:, mb, None]).squeeze(-1) * w).sum() / nw
                l_critic = (((b["ret"][:, mb] - v) ** 2).sum(-1) * w).sum() / nw
                l_val = valid_loss(phi[w.bool()], valid[w.bool()], *cfg.valid_beta)
                loss = ce + cfg.value_coef * l_critic + cfg.valid_coef * l_val
                opt.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
                opt.step()
                acc = ((lp.argmax(-1) == b["label"][:, mb]).float() * w).sum() / nw
                stats.append([ce.item(), l_critic.item(), l_val.item(), acc.item()])
        order = torch.randperm(len(buffer))
    return dict(zip(("loss_bc", "loss_critic", "loss_valid", "bc_accuracy"), np.mean(stats, 0).tolist()))


def _ppo_update(model, opt, ro, cfg, use_feat):
    N = ro["maps"].shape[1]
    feats = ro.get("feat")
    alive = ro["alive"]
    with torch.no_grad():
        _, v_old, _, _ = model(ro["maps"], ro["vec"], model.initial_state(N), feats)
    adv_k, ret = _gae(ro["rew"], v_old, alive, cfg.gamma, cfg.lam)
    adv = (adv_k * torch.tensor(cfg.adv_weights, dtype=adv_k.dtype)).sum(-1)
    am = alive.bool()
    adv = (adv - adv[am].mean()) / (adv[am].std() + 1e-8)
    stats = []
    for _ in range(cfg.epochs):
        perm = torch.randperm(N)
        for mb in perm.chunk(cfg.minibatches):
            logits, v, phi, _ = model(
                ro["maps"][:, mb], ro["vec"][:, mb], model.initial_state(len(mb)), None if feats is None else feats[:, mb]
            )
            valid = ro["valid"][:, mb]
            dist = torch.distributions.Categorical(logits=_masked(logits, valid, cfg))
            lp = dist.log_prob(ro["act"][:, mb])
            w = alive[:, mb]
            nw = w.sum().clamp(min=1)
            ratio = torch.exp(lp - ro["logp"][:, mb])
            a_mb = adv[:, mb]
            pg = -torch.min(ratio * a_mb, ratio.clamp(1 - cfg.clip, 1 + cfg.clip) * a_mb)
            l_actor = (pg * w).sum() / nw
            l_critic = (((ret[:, mb] - v) ** 2).sum(-1) * w).sum() / nw
            l_ent = (dist.entropy() * w).sum() / nw
            l_val = valid_loss(phi[w.bool()], valid[w.bool()], *cfg.valid_beta)
            loss = l_actor + cfg.value_coef * l_critic - cfg.entropy_coef * l_ent + cfg.valid_coef * l_val  # Eq. 2.8 (+ critic)
            if cfg.bc_anchor > 0:  # stay close to the teacher where PPO has no signal
                lab = ro["label"][:, mb]
                ce = -(dist.log_prob(lab) * w).sum() / nw
                loss = loss + cfg.bc_anchor * ce
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
            opt.step()
            stats.append([l_actor.item(), l_critic.item(), l_ent.item(), l_val.item()])
    return dict(zip(("loss_actor", "loss_critic", "entropy", "loss_valid"), np.mean(stats, 0).tolist()))


def evaluate(model: ActorCritic, lattice: Lattice, env_cfg: EnvConfig, seed: int, n: int) -> dict:
    """Greedy policy on worlds ``0..n-1`` of suite ``seed`` from the centre start: mean
    Table 2.1 metrics (used for validation; never pass the test seed while training)."""
    from .policy import RLPlanner

    env = create_env(replace(env_cfg, start="center"), lattice)
    env.reset(sample_for(env_cfg, seed, range(n)))
    was = model.training
    model.eval()
    pl = RLPlanner(env, model)
    while not env.done.all():
        env.step(pl.act())
    model.train(was)
    m = env.metrics()
    return {k: float(m[k].mean()) for k in ("coverage", "entropy_reduction", "search_efficiency")}


# ------------------------------------------------------------------------ training
def _dims(env, obs, cfg):
    return {
        "map_ch": obs["maps"].shape[1],
        "map_hw": obs["maps"].shape[2],
        "vec_dim": obs["vec"].shape[1],
        "n_actions": env.lat.n_actions,
        "n_feat": N_FEAT if cfg.policy.features else 0,
    }


def train(cfg: TrainConfig, lattice: Lattice, run_dir: str | Path | Run, progress: Any = None, resume: bool = False) -> dict:
    """Train in the new folder ``run_dir`` (claimed exclusively), or with ``resume``
    continue the run there; returns the last iteration's log entry. The run is locked
    while it trains (a second trainer of it gets a one-line UserError). ``progress``: a
    tqdm-like object (``update``/``set_postfix``)."""
    cfg.validate()
    run = Run.open(run_dir, kind="ipp") if resume else Run.create(run_dir, kind="ipp")
    try:
        with run.lock():
            run.remove_stale_temporaries()  # a kill during a write leaves its temporary
            return _train(cfg, lattice, run, progress, resume)
    except BaseException:
        if not resume and not (run.path / "config.json").exists():  # refused before it began: ours alone, empty
            shutil.rmtree(run.path, ignore_errors=True)
        raise


def _train(cfg: TrainConfig, lattice: Lattice, run: Run, progress: Any, resume: bool) -> dict:
    from .baselines import PlannerConfig, make_planner

    seed_everything(cfg.seed)
    torch.set_num_threads(cfg.threads)
    run_dir = run.path
    env = create_env(cfg.env, lattice)
    belief = None
    if cfg.belief_input is not None:  # the observation's belief plane is the learned belief's
        from .belief import load_belief

        belief = load_belief(cfg.belief_input)
        belief.check_env(env)
        env.obs_belief = belief
    teacher_belief = None
    if cfg.teacher_belief is not None:  # checked before the run is written
        from .belief import load_belief

        # the observed belief itself when they are the same: one forward pass per state
        teacher_belief = belief if cfg.teacher_belief == cfg.belief_input else load_belief(cfg.teacher_belief)
        assert teacher_belief is not None
        teacher_belief.check_env(env)
    obs = env.reset(sample_for(cfg.env, cfg.seed, range(cfg.n_envs)))
    dims = _dims(env, obs, cfg)
    use_feat = bool(dims["n_feat"])
    model = ActorCritic(**dims, cfg=cfg.policy)
    model.obs_belief = belief  # saved with the policy; evaluate's RLPlanner observes it
    if cfg.init is not None and not resume:
        from .policy import load_policy

        src = load_policy(cfg.init)
        if src.n_feat != dims["n_feat"] or src.cfg != cfg.policy or src.pi.out_features != dims["n_actions"]:
            raise UserError(f"{cfg.init}: policy does not match this configuration")
        if (src.obs_belief is None) != (belief is None):
            raise UserError(
                f"{cfg.init}: the policy observes {'no' if src.obs_belief is None else 'a'} learned belief, this run "
                f"{'does not' if belief is None else 'does'} (--belief-input)"
            )
        try:
            model.load_state_dict(src.state_dict())
        except RuntimeError:
            raise UserError(f"{cfg.init}: policy shapes do not match this environment") from None
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    last: dict[str, Any]  # the latest iteration's log entry
    start, buffer, best, elapsed0, last = 0, [], -np.inf, 0.0, {}
    if resume:
        _, ck, _ = run.newest_intact()  # CheckpointDamaged names the file
        if ck.get("version") != CHECKPOINT_VERSION:
            raise UserError(f"{run.checkpoint_path()}: checkpoint version {ck.get('version')} is not supported")
        if ck["dims"] != dims:
            raise UserError(f"{run_dir}: checkpoint does not match this environment")
        try:
            model.load_state_dict(ck["model"])
            opt.load_state_dict(ck["opt"])
        except (RuntimeError, ValueError, KeyError):
            raise UserError(f"{run_dir}: checkpoint does not match its config.json") from None
        start, buffer, best, elapsed0 = ck["iteration"], ck["buffer"], ck["best"], ck["elapsed"]
        if start > cfg.total_iterations:
            raise UserError(f"{run_dir}: already has {start} iterations, more than the {cfg.total_iterations} asked for")
        set_rng_state({"torch": ck["torch_rng"], "numpy": ck["numpy_rng"]})
        if run.metrics_path.is_file() and run.metrics_path.read_text().strip():  # a damaged line: one-line error
            kept = [r for r in read_metrics(run_dir) if r["iteration"] <= start]
            last = kept[-1] if kept else last
        if progress is not None:
            progress.update(start)
    run.write_config({"train": asdict(cfg), "dims": dims, "lattice": asdict(lattice.config)})
    # a resume drops the lines after the checkpoint's iteration
    with run.metrics_log(keep_until=start if resume else None, logger="none", key="iteration") as log:
        teacher = None
        if cfg.bc_iterations > start or cfg.bc_anchor > 0:
            # what the teacher plans over: the posterior, or the learned belief
            seen = env if teacher_belief is None else teacher_belief.view(env)
            teacher = make_planner(cfg.teacher, seen, PlannerConfig(depth=cfg.teacher_depth))
        N, T_all = cfg.n_envs, cfg.total_iterations
        t0 = time.time()
        for it in range(start, T_all):
            bc = it < cfg.bc_iterations
            obs = env.reset(sample_for(cfg.env, cfg.seed, range(it * N, (it + 1) * N)))
            for g in opt.param_groups:
                g["lr"] = cfg.bc_lr if bc else cfg.lr
            if bc:
                beta = cfg.bc_beta0 * cfg.bc_beta_decay**it
                ro = _rollout(model, env, obs, cfg, use_feat, teacher, beta)
                ro["ret"] = _discounted(ro["rew"], ro["alive"], cfg.gamma)
                keep = {k: ro[k] for k in ("maps", "vec", "valid", "label", "alive", "ret") + (("feat",) if use_feat else ())}
                if cfg.env.kind == "semantic":  # half the buffer's memory (maps in [0, 1])
                    keep["maps"] = keep["maps"].half()
                buffer = (buffer + [keep])[-cfg.bc_buffer :]
                stats = {"beta": beta, **_bc_update(model, opt, buffer, cfg, use_feat)}
                if it + 1 == cfg.bc_iterations:
                    buffer = []  # the warm start is over: keep checkpoints small
            else:
                buffer = []  # not needed any more (and not stored in PPO checkpoints)
                ro = _rollout(model, env, obs, cfg, use_feat, teacher if cfg.bc_anchor > 0 else None, 0.0)
                stats = _ppo_update(model, opt, ro, cfg, use_feat)
            m = env.metrics()
            tot = (ro["rew"].sum(0) / cfg.reward_scale).mean(0).tolist()
            last = {
                "iteration": it + 1,
                "phase": "bc" if bc else "ppo",
                "time_s": round(elapsed0 + time.time() - t0, 1),
                "return": float(sum(tot)),
                **{f"r_{k}": v for k, v in zip(TERMS, tot)},
                **{k: float(m[k].mean()) for k in ("coverage", "entropy_reduction", "search_efficiency")},
                **stats,
            }
            if cfg.eval_every and ((it + 1) % cfg.eval_every == 0 or it + 1 == T_all):
                ev = evaluate(model, lattice, cfg.env, cfg.eval_seed, cfg.eval_envs)
                last.update({f"val_{k}": v for k, v in ev.items()})
                if ev["search_efficiency"] > best:
                    best = ev["search_efficiency"]
                    save_policy(model, dims, run_dir / "best.pt", cfg.env.kind)
            log.write(last)
            if (it + 1) % cfg.log_every == 0 or it + 1 == T_all:
                save_policy(model, dims, run_dir / "model.pt", cfg.env.kind)
                rng = rng_state(tensors=True)  # loads with weights_only=True
                run.save_checkpoint(
                    {
                        "version": CHECKPOINT_VERSION,
                        "iteration": it + 1,
                        "model": model.state_dict(),
                        "opt": opt.state_dict(),
                        "torch_rng": rng["torch"],
                        "numpy_rng": rng["numpy"],
                        "buffer": buffer,
                        "best": best,
                        "elapsed": elapsed0 + time.time() - t0,
                        "dims": dims,
                        "env_kind": cfg.env.kind,
                    }
                )
            if progress is not None:
                progress.update(1)
                progress.set_postfix(ret=f"{last['return']:.1f}", eff=f"{last['search_efficiency']:.0f}")
    plot_learning_curve(run_dir)
    return last
