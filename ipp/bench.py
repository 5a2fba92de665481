"""Run planners on the seeded test suite (thesis Table 2.1, Fig. 2.3, Fig. 2.4 analogues).

The test suite is worlds ``0..n-1`` of suite seed :data:`TEST_SEED` (thesis: 100 test
environments, fixed start). Planners run on batches of environments; planning time
per decision is the planner's wall time divided by the number of (environment,
decision) pairs it served.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aerohrl.errors import UserError

from aerohrl.atomic import atomic_path
from .baselines import PLANNERS, TEACHERS, THESIS_NAMES, PlannerConfig, make_planner
from .env import EnvConfig, SearchEnv
from .factory import create_env, sample_for
from .lattice import Lattice

TEST_SEED = 1000


@dataclass
class BenchConfig:
    """``ipp bench`` flags."""

    planners: tuple[str, ...] = ("dp",)
    envs: int = 100
    seed: int = TEST_SEED
    batch: int = 100
    env: EnvConfig = field(default_factory=EnvConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)

    def validate(self) -> None:
        if self.envs < 1 or self.batch < 1:
            raise UserError("--envs and --batch must be >= 1")
        for p in self.planners:
            if p not in PLANNERS + TEACHERS + ("rl",):
                raise UserError(f"unknown planner {p!r} (choose from "
                                f"{', '.join(PLANNERS + TEACHERS)}, rl)")


def run_episodes(name: str, lattice: Lattice, cfg: BenchConfig, env_ids=None, progress=None,
                 keep_env: bool = False, model=None) -> dict:
    """Run ``name`` on the suite; returns per-env metrics, summary inputs and timing."""
    ids = np.arange(cfg.envs) if env_ids is None else np.asarray(env_ids)
    per_env: dict[str, list] = {}
    plan_time, decisions = 0.0, 0
    env = None
    for s in range(0, len(ids), cfg.batch):
        chunk = ids[s:s + cfg.batch]
        env = create_env(cfg.env, lattice)
        env.reset(sample_for(cfg.env, cfg.seed, chunk))
        env.lazy_obs = True  # baselines read the maps directly, RLPlanner observes itself
        if s == 0:  # per-lattice tables of the semantic fast path: built once, not timed
            from .features import fast_path_applies
            fast_path_applies(env)
        if model is not None:
            from .policy import RLPlanner
            pl = RLPlanner(env, model)
        else:
            pl = make_planner(name, env, cfg.planner)
        pl.reset()
        prev_done = 0
        while not env.done.all():
            live = int((~env.done).sum())
            t = time.perf_counter()
            a = pl.act()
            plan_time += time.perf_counter() - t
            decisions += live
            env.step(a)
            nd = int(env.done.sum())
            if progress is not None:
                progress.update(nd - prev_done)
            prev_done = nd
        for k, v in env.metrics().items():
            per_env.setdefault(k, []).append(v)
    out = {"per_env": {k: np.concatenate(v) for k, v in per_env.items()},
           "ms_per_decision": 1000.0 * plan_time / max(decisions, 1),
           "n": len(ids), "env_ids": ids}
    if keep_env:
        out["env"] = env
    return out


def render_episode(env: SearchEnv, n: int, path, title: str = "") -> Path:
    """Fig. 2.3 analogue for env ``n`` of a finished run: truth, prior, path at 70/30/0 %."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lat, S = env.lat, env.S
    w = env.worlds
    semantic = env.cfg.kind == "semantic"
    budget = np.array([b[n] for b in env.trace_budget]) / env.cfg.budget
    fig, axes = plt.subplots(1, 5, figsize=(17, 3.8))
    ext = (-0.5, S - 0.5, -0.5, S - 0.5)
    if semantic:  # Fig. 2.5 analogue: classes, prior (expected colour), final belief
        from .semantic import PALETTE, class_rgb
        axes[0].imshow(class_rgb(w.classes[n]), origin="lower", extent=ext)
        axes[0].set_title(f"truth ({int(env.n_targets[n])} feature cells)")
        prior_img = np.clip((w.prior[n] @ PALETTE[:w.prior.shape[-1]].astype(float)) / 255.0, 0, 1)
        axes[1].imshow(prior_img, origin="lower", extent=ext)
        axes[1].set_title(f"prior (CE {w.kl[n]:.2f} nats/cell)")
        final_img = np.clip((env.probs()[n] @ PALETTE[:w.prior.shape[-1]].astype(float)) / 255.0, 0, 1)
        alpha = 1.0
    else:
        axes[0].imshow(w.density[n], origin="lower", extent=ext, cmap="Greys")
        ty, tx = np.nonzero(w.targets[n])
        axes[0].scatter(tx, ty, c="r", s=8)
        axes[0].set_title(f"truth ({len(tx)} targets)")
        axes[1].imshow(w.prior[n], origin="lower", extent=ext, cmap="Blues", vmin=0, vmax=1)
        axes[1].set_title(f"prior (KL {w.kl[n]:.2f})")
        prior_img, final_img, alpha = w.prior[n], env.belief()[n], 0.6
    for ax, frac in zip(axes[2:], (0.7, 0.3, 0.0)):
        k = int(np.searchsorted(-budget, -frac, side="right"))  # steps taken at >= frac left
        k = min(k, len(env.trace_prim))
        ax.imshow(final_img if frac == 0.0 else prior_img, origin="lower", extent=ext,
                  cmap=None if semantic else "Blues", vmin=0, vmax=1, alpha=alpha)
        for j in range(k):
            pr = int(env.trace_prim[j][n])
            if pr < 0:
                continue
            xy = lat.positions(pr, env.trace[j][n])
            ax.plot(xy[:, 0], xy[:, 1], "k-", lw=1)
        start, end = env.trace[0][n], env.trace[k][n]
        ax.plot(*start, "go", ms=6)
        ax.plot(*end, "ro", ms=6)
        ax.set_title(f"{int(round(100 * frac))}% budget left ({k} primitives)")
    for ax in axes:
        ax.set_xlim(-0.5, S - 0.5)
        ax.set_ylim(-0.5, S - 0.5)
        ax.set_aspect("equal")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format=(path.suffix.lstrip(".") or "png"))
    plt.close(fig)
    return path


__all__ = ["BenchConfig", "run_episodes", "render_episode", "TEST_SEED", "THESIS_NAMES"]
