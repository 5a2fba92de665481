"""Run planners on the seeded test suite (thesis Table 2.1, Fig. 2.3, Fig. 2.4 analogues).

The test suite is worlds ``0..n-1`` of suite seed :data:`TEST_SEED` (thesis: 100 test
environments, fixed start). Planners run on batches of environments; planning time
per decision is the planner's wall time divided by the number of (environment,
decision) pairs it served.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from aerohrl.config import param, section, validate
from aerohrl.errors import UserError

from aerohrl.atomic import atomic_path
from .baselines import PLANNERS, TEACHERS, THESIS_NAMES, Planner, PlannerConfig, make_planner
from .env import EnvConfig, SearchEnv
from .flown import EXECUTIONS
from .factory import create_env, sample_for
from .lattice import Lattice
from .world import TEST_SEED

if TYPE_CHECKING:
    from aerohrl.envs.rollout import PolicyFn

    from .belief import BeliefModel
    from .policy import ActorCritic


@dataclass
class BenchConfig:
    """``ipp bench`` flags."""

    planners: tuple[str, ...] = param(("dp",), "planners to run: baselines, teachers, rl")
    envs: int = param(100, "test worlds", ge=1)
    seed: int = param(TEST_SEED, "test-suite seed", ge=0)
    batch: int = param(100, "environments stepped together", ge=1)
    env: EnvConfig = section(EnvConfig, "the test environment")
    planner: PlannerConfig = section(PlannerConfig, "the planners' knobs")
    execution: str = param(
        "ideal",
        "the lattice's sensing (ideal), the simulator flying each primitive (flown) "
        "or the chapter-3 policy flying it (skill); see aerohrl.ipp.flown",
        choices=EXECUTIONS,
    )

    def validate(self) -> None:
        """UserError (one line) for a setting out of its declared range
        (:func:`aerohrl.config.validate`) or an unknown planner."""
        validate(self)
        for p in self.planners:
            if p not in PLANNERS + TEACHERS + ("rl",):
                raise UserError(f"unknown planner {p!r} (choose from {', '.join(PLANNERS + TEACHERS)}, rl)")


def run_episodes(
    name: str,
    lattice: Lattice,
    cfg: BenchConfig,
    env_ids: Sequence[int] | np.ndarray | None = None,
    progress: Any = None,
    keep_env: bool = False,
    model: ActorCritic | None = None,
    skill: PolicyFn | None = None,
    belief: BeliefModel | None = None,
) -> dict:
    """Run ``name`` on the suite; returns per-env metrics, summary inputs and timing.
    With ``belief`` the planner plans over that learned belief
    (:class:`~aerohrl.ipp.belief.BeliefView`; its forward pass counts as planning time);
    the environment, and so every metric, is unchanged."""
    ids = np.arange(cfg.envs) if env_ids is None else np.asarray(env_ids)
    per_env: dict[str, list] = {}
    plan_time, decisions = 0.0, 0
    env = None
    tracking: list[np.ndarray] = []
    legs: list[np.ndarray] = []
    for s in range(0, len(ids), cfg.batch):
        chunk = ids[s : s + cfg.batch]
        if cfg.execution == "ideal":
            env = create_env(cfg.env, lattice)
        else:
            from .flown import create_flown_env

            env = create_flown_env(cfg.env, lattice, cfg.execution, skill)
            env.keep_trace = keep_env
        env.reset(sample_for(cfg.env, cfg.seed, chunk))
        env.lazy_obs = True  # baselines read the maps directly, RLPlanner observes itself
        if s == 0:  # per-lattice tables of the semantic fast path: built once, not timed
            from .features import fast_path_applies

            fast_path_applies(env)
        pl: Planner
        if model is not None:
            from .policy import RLPlanner

            pl = RLPlanner(env, model)
        else:
            pl = make_planner(name, env if belief is None else belief.view(env), cfg.planner)
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
        if hasattr(env, "tracking_table"):
            tt = env.tracking_table()
            tt[:, 0] = chunk[tt[:, 0].astype(int)]  # batch row -> world index
            tracking.append(tt)
        if hasattr(env, "leg_table"):
            legs.append(env.leg_table())
    out = {
        "per_env": {k: np.concatenate(v) for k, v in per_env.items()},
        "ms_per_decision": 1000.0 * plan_time / max(decisions, 1),
        "n": len(ids),
        "env_ids": ids,
        "execution": cfg.execution,
    }
    if tracking:  # per flown primitive: world, max error (m), RMS error (m), duration (s)
        out["tracking"] = np.concatenate(tracking, 0)
    if legs:  # per skill leg: strict success, near success, duration (s)
        out["legs"] = np.concatenate(legs, 0)
    if keep_env:
        out["env"] = env
    return out


def render_episode(env: SearchEnv, n: int, path: str | Path, title: str = "") -> Path:
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
        from .semantic import CLASSES, PALETTE, class_rgb
        from matplotlib.patches import Patch

        fig.legend(
            handles=[Patch(color=PALETTE[i] / 255.0, label=c) for i, c in enumerate(CLASSES[: w.prior.shape[-1]])],
            loc="lower center",
            ncol=len(CLASSES),
            fontsize=8,
            frameon=False,
        )
        axes[0].imshow(class_rgb(w.classes[n]), origin="lower", extent=ext)
        axes[0].set_title(f"truth ({int(env.n_targets[n])} feature cells)")
        prior_img = np.clip((w.prior[n] @ PALETTE[: w.prior.shape[-1]].astype(float)) / 255.0, 0, 1)
        axes[1].imshow(prior_img, origin="lower", extent=ext)
        axes[1].set_title(f"prior (CE {w.kl[n]:.2f} nats/cell)")
        final_img = np.clip((env.probs()[n] @ PALETTE[: w.prior.shape[-1]].astype(float)) / 255.0, 0, 1)
        alpha = 1.0
    else:
        im = axes[0].imshow(w.density[n], origin="lower", extent=ext, cmap="Greys")
        fig.colorbar(im, ax=axes[0], fraction=0.046, pad=0.02, label="true target density")
        ty, tx = np.nonzero(w.targets[n])
        p0 = env.pad
        found = env.found[n, p0 : p0 + S, p0 : p0 + S][ty, tx]
        axes[0].scatter(tx[found], ty[found], c="limegreen", s=10, edgecolors="k", linewidths=0.3, label="found")
        axes[0].scatter(tx[~found], ty[~found], c="r", marker="x", s=12, label="missed")
        axes[0].legend(fontsize=6, loc="upper right")
        axes[0].set_title(f"truth ({len(tx)} targets, {int(found.sum())} found)")
        im = axes[1].imshow(w.prior[n], origin="lower", extent=ext, cmap="Blues", vmin=0, vmax=1)
        fig.colorbar(im, ax=axes[1], fraction=0.046, pad=0.02, label="P(target)")
        axes[1].set_title(f"prior (KL {w.kl[n]:.2f})")
        prior_img, final_img, alpha = w.prior[n], env.belief()[n], 0.6
    for ax, frac in zip(axes[2:], (0.7, 0.3, 0.0)):
        k = int(np.searchsorted(-budget, -frac, side="right"))  # steps taken at >= frac left
        k = min(k, len(env.trace_prim))
        im = ax.imshow(
            final_img if frac == 0.0 else prior_img,
            origin="lower",
            extent=ext,
            cmap=None if semantic else "Blues",
            vmin=0,
            vmax=1,
            alpha=alpha,
        )
        if not semantic:
            fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02, label="belief P(target)" if frac == 0.0 else "prior P(target)")
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
    unit = "cells (4 m)" if semantic else "cells (1 m)"
    for ax in axes:
        ax.set_xlim(-0.5, S - 0.5)
        ax.set_ylim(-0.5, S - 0.5)
        ax.set_aspect("equal")
        ax.set_xlabel(f"x, {unit}", fontsize=8)
        ax.set_ylabel(f"y, {unit}", fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format=(path.suffix.lstrip(".") or "png"))
    plt.close(fig)
    return path


def animate_episode(
    name: str,
    lattice: Lattice,
    cfg: BenchConfig,
    env_id: int,
    path: str | Path,
    model: ActorCritic | None = None,
    title: str = "",
    fps: int = 4,
    skill: PolicyFn | None = None,
) -> Path:
    """Animated episode (GIF) on test world ``env_id`` (target search): one frame per
    primitive, showing the belief (colour bar), the path so far (flown path too with
    ``cfg.execution == "flown"``), the true targets found (green) and not yet found (red
    x), and the budget left. Written with matplotlib's PillowWriter, atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter

    if cfg.env.kind != "targets":
        raise UserError("--gif is for target search (--world targets)")
    if cfg.execution == "ideal":
        env = create_env(cfg.env, lattice)
    else:
        from .flown import create_flown_env

        env = create_flown_env(cfg.env, lattice, cfg.execution, skill)
    env.reset(sample_for(cfg.env, cfg.seed, [env_id]))
    pl: Planner
    if model is not None:
        from .policy import RLPlanner

        pl = RLPlanner(env, model)
    else:
        pl = make_planner(name, env, cfg.planner)
    pl.reset()
    S, p = env.S, env.pad
    frames = []
    while True:
        frames.append(
            (
                env.belief()[0].copy(),
                env.found[0, p : p + S, p : p + S].copy(),
                len(env.trace_prim),
                float(env.remaining[0]),
                int(env.n_found[0]),
            )
        )
        if env.done.all():
            break
        env.step(pl.act())
    ty, tx = np.nonzero(env.worlds.targets[0])
    segs = []
    for j, prims in enumerate(env.trace_prim):
        pr = int(prims[0])
        segs.append(lattice.positions(pr, env.trace[j][0]) if pr >= 0 else np.zeros((0, 2)))
    flown = getattr(env, "flown_trace", None)
    fig, ax = plt.subplots(figsize=(5.6, 5))
    ext = (-0.5, S - 0.5, -0.5, S - 0.5)
    im = ax.imshow(frames[0][0], origin="lower", extent=ext, cmap="Blues", vmin=0, vmax=1)
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02, label="belief P(target)")
    (line,) = ax.plot([], [], "k-", lw=1.2, label="planned path")
    (fline,) = ax.plot([], [], "m-", lw=0.8, label="flown path") if flown else (None,)
    (agent,) = ax.plot([], [], "o", color="orange", ms=7, label="vehicle")
    fsc = ax.scatter([], [], c="limegreen", s=18, edgecolors="k", linewidths=0.4, label="found")
    msc = ax.scatter([], [], c="r", marker="x", s=18, label="not yet found")
    ax.legend(fontsize=7, loc="upper right")
    ax.set_xlim(-0.5, S - 0.5)
    ax.set_ylim(-0.5, S - 0.5)
    ax.set_xlabel("x, cells (1 m)")
    ax.set_ylabel("y, cells (1 m)")

    def draw(i):
        b, fnd, k, rem, nf = frames[i]
        im.set_data(b)
        xy = np.concatenate([segs[j] for j in range(k)], 0) if k else np.zeros((0, 2))
        line.set_data(xy[:, 0], xy[:, 1])
        if fline is not None:
            fx = np.concatenate(flown[0][: k + 1], 0)
            fline.set_data(fx[:, 0], fx[:, 1])
        pos = env.trace[k][0]
        agent.set_data([pos[0]], [pos[1]])
        hit = fnd[ty, tx]
        fsc.set_offsets(np.c_[tx[hit], ty[hit]] if hit.any() else np.zeros((0, 2)))
        msc.set_offsets(np.c_[tx[~hit], ty[~hit]] if (~hit).any() else np.zeros((0, 2)))
        ax.set_title(
            f"{title}\nprimitive {k}, budget left {100 * max(rem, 0.0) / cfg.env.budget:.0f} %, found {nf}/{len(tx)}", fontsize=9
        )
        return im, line, agent, fsc, msc

    anim = FuncAnimation(fig, draw, frames=len(frames), blit=False)
    import tempfile

    from aerohrl.atomic import write_bytes

    with tempfile.TemporaryDirectory() as d:  # Pillow picks the format from the suffix
        f = Path(d) / "episode.gif"
        anim.save(str(f), writer=PillowWriter(fps=fps))
        plt.close(fig)
        return write_bytes(path, f.read_bytes())


__all__ = ["BenchConfig", "run_episodes", "render_episode", "animate_episode", "TEST_SEED", "THESIS_NAMES"]
