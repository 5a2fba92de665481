"""Hindsight relabelling (thesis Alg. 2, line 4), vectorised over the batch.

With probability ``delta`` the goal of transition ``j`` becomes the achieved goal of a
strictly later step ``k`` (``j < k <= last step of the episode``) of the same trajectory,
``k`` uniform (the "future" strategy of HER/WGCSL: ``k = j + 1 + floor(u (end - j))``).
The last step of an episode has no later step and keeps its goal. Rewards and done
flags are then recomputed for the (new) goal with the task's goal-reached test:
``r = goal_reached(achieved goal of j, g)``, ``done = r`` (a goal-reaching episode ends
at success; running out of expert data is a truncation, not a termination).

Why not ``torchrl.data.HERReplayBuffer``: its "future" offset starts at 0 (the goal can
be the transition's own achieved goal, not a strictly later one), it relabels a fixed
leading fraction of each batch instead of a Bernoulli(delta) choice per transition, and
it recomputes only the reward; Alg. 2 and docs/spec.md ask for the strictly-later,
per-transition version, which is three tensor ops here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

from aerohrl import task


FUTURE_STRATEGIES = ("uniform", "geometric")


def sample_future_index(
    index: torch.Tensor,
    episode_end: torch.Tensor,
    generator: torch.Generator | None = None,
    *,
    strategy: str = "uniform",
    window: int = 0,
    mean: float = 30.0,
) -> torch.Tensor:
    """A strictly later step ``k in (j, end]`` of the same episode for each ``j``
    (``k = j`` where ``j`` is the last step of its episode). The offset ``k - j >= 1`` is

    * ``uniform``: uniform over ``1 .. span`` with ``span = end - j``, or over
      ``1 .. min(window, span)`` when ``window > 0``;
    * ``geometric``: ``Geometric(1 / mean)`` on ``1, 2, ...`` (mean ``mean``; OGBench's
      ``geom_sample`` with ``p = 1 - gamma``), capped at ``window`` when ``window > 0``
      and at the episode's last step (the cap puts the overflow on that step).
    """
    span = (episode_end - index).clamp_min(0)
    if window > 0:
        span = span.clamp_max(int(window))
    u = torch.rand(index.shape, generator=generator, device=index.device)
    if strategy == "uniform":
        offset = 1 + (u * span).long()
    elif strategy == "geometric":
        p = 1.0 / max(float(mean), 1.0)
        if p >= 1.0:
            offset = torch.ones_like(index)
        else:  # inverse CDF: P(offset > n) = (1 - p)^n
            offset = 1 + torch.floor(torch.log1p(-u) / math.log1p(-p)).clamp(0, 2**40).long()
    else:
        raise ValueError(f"unknown future strategy {strategy!r}")
    offset = torch.minimum(offset, span.clamp_min(1))
    return torch.where(span > 0, index + offset, index)


def relabel_goals(
    goal: torch.Tensor,
    index: torch.Tensor,
    episode_end: torch.Tensor,
    achieved_goals: torch.Tensor,
    delta: float,
    generator: torch.Generator | None = None,
    return_index: bool = False,
    **future: Any,
) -> tuple[torch.Tensor, torch.Tensor] | tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(new goals (B, 15), relabelled mask (B,)) -- and, with ``return_index``, the
    drawn later step ``k`` (B,) whose achieved goal a relabelled transition got.

    ``index`` are the transitions' global dataset indices, ``episode_end`` the global
    index of their episode's last step, ``achieved_goals`` the (F, 15) achieved goal of
    every step of the dataset; ``future`` = ``strategy``/``window``/``mean`` of
    :func:`sample_future_index`.
    """
    coin = torch.rand(index.shape, generator=generator, device=index.device) < delta
    k = sample_future_index(index, episode_end, generator, **future)
    mask = coin & (k > index)
    new = torch.where(mask.unsqueeze(-1), achieved_goals[k], goal)
    return (new, mask, k) if return_index else (new, mask)


@dataclass(frozen=True)
class GoalMix:
    """Where a batch's goals come from, OGBench's way (``GCDataset.sample_goals``): with
    probability ``p_cur`` the transition's own achieved goal (the goal its action reaches:
    reward 1, done), ``p_traj`` a later achieved goal of the same trajectory
    (:func:`sample_future_index`: ``geometric`` with mean ``mean`` or uniform over the rest
    of the episode), ``p_rand`` the achieved goal of a uniformly random dataset frame; the
    rest of the probability (``1 - p_cur - p_traj - p_rand``, 0 in OGBench's settings)
    keeps the transition's own goal (its desired goal, or the goal ``relabel_prob``
    relabelled it with).

    Index convention: OGBench's goal ``obs[idx + m]`` (``m >= 0``; ``m = 0`` its "current
    goal") is here the achieved goal of step ``j + m - 1``, i.e. the state after step
    ``j + m - 1``. OGBench's rewards count a goal as reached at the state itself; here,
    as everywhere in this toolkit, at the transition into it (reward 1 when the next state
    reaches the goal). So OGBench's current goal (value 0, reached) is this toolkit's
    achieved goal of step ``j`` (value 1 reached by this action) and its trajectory goals
    are strictly later steps, the offsets shifted by one."""

    p_cur: float = 0.0
    p_traj: float = 1.0
    p_rand: float = 0.0
    geometric: bool = True
    mean: float = 100.0  # geometric mean offset: OGBench's 1 / (1 - discount)


GOAL_KEEP, GOAL_CUR, GOAL_TRAJ, GOAL_RAND = 0, 1, 2, 3  # the sources of sample_goal_index


def sample_goal_index(
    index: torch.Tensor,
    episode_end: torch.Tensor,
    num_frames: int,
    mix: GoalMix,
    generator: torch.Generator | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(k, source): per transition ``j`` the frame ``k`` whose achieved goal becomes its
    goal and the source it came from (``GOAL_CUR``: ``k = j``; ``GOAL_TRAJ``: a later step
    of the episode, ``j`` itself for an episode's last step; ``GOAL_RAND``: a uniform frame;
    ``GOAL_KEEP``: ``k = j`` and the goal stays the transition's own). Three draws from
    ``generator`` (the future offset, the random frame, the source), always in this order."""
    strategy = "geometric" if mix.geometric else "uniform"
    traj = sample_future_index(index, episode_end, generator, strategy=strategy, mean=mix.mean)
    rand = torch.randint(0, num_frames, index.shape, generator=generator, device=index.device)
    u = torch.rand(index.shape, generator=generator, device=index.device)
    # u in [0, p_cur): current, [p_cur, p_cur + p_traj): trajectory, then random, then keep
    c1, c2, c3 = mix.p_cur, mix.p_cur + mix.p_traj, mix.p_cur + mix.p_traj + mix.p_rand
    source = torch.full_like(index, GOAL_KEEP)
    source = torch.where(u < c3, torch.full_like(index, GOAL_RAND), source)
    source = torch.where(u < c2, torch.full_like(index, GOAL_TRAJ), source)
    source = torch.where(u < c1, torch.full_like(index, GOAL_CUR), source)
    k = torch.where(source == GOAL_TRAJ, traj, index)
    k = torch.where(source == GOAL_RAND, rand, k)
    return k, source


def subgoal_index(index: torch.Tensor, episode_end: torch.Tensor, steps: int | torch.Tensor) -> torch.Tensor:
    """The frame whose next state is the state ``steps`` steps after step ``j``'s state:
    ``min(j + steps - 1, end)`` (HIQL's ``min(idx + subgoal_steps, final_state_idx)`` in
    this toolkit's convention, where frame ``k`` holds the state after it as ``next_state``).
    ``steps`` is one int or one per transition (>= 1)."""
    if isinstance(steps, torch.Tensor):
        return torch.minimum(index + steps.clamp_min(1) - 1, episode_end)
    return torch.minimum(index + max(int(steps), 1) - 1, episode_end)


def first_hit_index(next_state: torch.Tensor, goal: torch.Tensor, episode_end: torch.Tensor) -> torch.Tensor:
    """For every frame ``j``: the first step ``t >= j`` of its episode whose achieved goal
    reaches the frame's own goal (the episode's desired goal), or -1 when none does.
    (F,) int64, one searchsorted over the frames that reach their goal."""
    hits = torch.nonzero(task.goal_reached(task.achieved_goal(next_state), goal)).flatten()
    j = torch.arange(len(goal))
    if hits.numel() == 0:
        return torch.full_like(j, -1)
    pos = torch.searchsorted(hits, j).clamp_max(hits.numel() - 1)
    t = hits[pos]
    return torch.where((t >= j) & (t <= episode_end), t, torch.full_like(t, -1))


def mc_lower_bound(
    index: torch.Tensor, k: torch.Tensor, relabelled: torch.Tensor, first_hit: torch.Tensor, gamma: float
) -> torch.Tensor:
    """A lower bound on the discounted return of the data's own continuation (MCAC,
    Wilcox et al. 2022), per transition ``j`` with sparse reward and termination at the
    first success: ``gamma^(k - j)`` for a goal relabelled with the achieved goal of step
    ``k`` (that step reaches it, maybe an earlier one already), ``gamma^(t - j)`` for the
    desired goal first reached at step ``t`` (:func:`first_hit_index`), 0 when the data
    never reaches it. (B,) float."""
    t = torch.where(relabelled, k, first_hit[index])
    lb = torch.pow(torch.full(t.shape, float(gamma)), (t - index).clamp_min(0).float())
    return torch.where(t >= index, lb, torch.zeros_like(lb))


def reward_done(next_state: torch.Tensor, goal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Sparse reward (float, 1 when the next state reaches ``goal``) and done (bool)."""
    reached = task.goal_reached(task.achieved_goal(next_state), goal)
    return reached.to(next_state.dtype), reached


__all__ = [
    "GoalMix",
    "sample_goal_index",
    "subgoal_index",
    "GOAL_KEEP",
    "GOAL_CUR",
    "GOAL_TRAJ",
    "GOAL_RAND",
    "FUTURE_STRATEGIES",
    "sample_future_index",
    "relabel_goals",
    "first_hit_index",
    "mc_lower_bound",
    "reward_done",
]
