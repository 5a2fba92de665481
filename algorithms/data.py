"""Dataset -> tensors -> a torchrl replay buffer (thesis Alg. 2, line 1: the buffer B).

:func:`load_dataset` reads a ``datagen build`` folder (or takes the column dict directly,
as tests do), checks it and keeps every transition in tensors:

* ``state`` (F, 18), ``action`` (F, 4), ``goal`` (F, 15, the desired goal),
  ``next_state`` (F, 18) and ``episode_end`` (F,): the global index of the last frame of
  the frame's episode, what relabelling needs to pick a strictly later step.

:func:`make_buffer` puts them in a ``TensorDictReplayBuffer`` over a ``LazyTensorStorage``
(the whole dataset is written once; sampling is one ``randint`` and one gather with a
dedicated, checkpointed ``torch.Generator``).
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from tensordict import TensorDict

from aerohrl import task
from aerohrl.errors import UserError

if TYPE_CHECKING:
    from torchrl.data import TensorDictReplayBuffer

    from aerohrl.algorithms.networks import Normalizer
    from aerohrl.algorithms.relabel import GoalMix

REQUIRED = {
    "observation.state": (task.STATE_DIM,),
    "action": (task.ACTION_DIM,),
    "observation.desired_goal": (task.GOAL_DIM,),
    "next.observation.state": (task.STATE_DIM,),
    "episode_index": (),
}


@dataclass
class Dataset:
    state: torch.Tensor
    action: torch.Tensor
    goal: torch.Tensor
    next_state: torch.Tensor
    episode_end: torch.Tensor  # int64 (F,)
    episode_index: torch.Tensor  # int64 (F,)
    info: dict = field(default_factory=dict)  # path, version, checksum, shapes, spec
    # (F, 4) the clean expert command at each flown state (a dataset flown with action
    # noise, column "action.expert"); None when ``action`` is the expert's command itself
    action_expert: torch.Tensor | None = None
    # (F, 3) the expert's disturbance estimate at each state (a dataset flown with
    # ``--disturbance-observer``, column "observation.disturbance"); None without it
    disturbance: torch.Tensor | None = None

    def __len__(self) -> int:
        return self.state.shape[0]

    @property
    def achieved_goal(self) -> torch.Tensor:
        """(F, 15): the achieved goal of each step (its next state's [p, v, R])."""
        return task.achieved_goal(self.next_state)

    @property
    def num_episodes(self) -> int:
        """The number of episodes (distinct episode ends)."""
        return int(self.episode_end.unique().numel())

    def episode_first_frames(self) -> torch.Tensor:
        """(E,) global index of each episode's first frame, in episode order."""
        starts = torch.ones(len(self), dtype=torch.bool)
        starts[1:] = self.episode_index[1:] != self.episode_index[:-1]
        return torch.nonzero(starts).flatten()

    def desired_goals(self) -> torch.Tensor:
        """(E, 15) the desired goal of each episode, in episode order."""
        return self.goal[self.episode_first_frames()]

    def bc_actions(self, bc_target: str = "expert") -> torch.Tensor:
        """(F, 4) what the policy imitates: the clean expert command when the dataset
        has one and ``bc_target == "expert"``, else the flown action."""
        return self.action_expert if bc_target == "expert" and self.action_expert is not None else self.action

    def rest_start_episodes(self) -> torch.Tensor:
        """Indices (episode order) of one episode per desired goal of rho_D: Reach-Desired's
        goal set (docs/spec.md: from rest in hover at the origin). Every episode of a default
        dataset; of a recipe with ``rollouts_per_goal = k`` every k-th (the flights of a
        goal are contiguous); never the continuations, which a ``datagen build
        --continuations M`` dataset appends as its last M episodes (its spec records both)."""
        spec = self.info.get("spec") or {}
        m = int(spec.get("continuations", 0))
        k = int(spec.get("rollouts_per_goal", 1))
        return torch.arange(0, self.num_episodes - m, k)

    def with_disturbance(self) -> "Dataset":
        """The same frames with the disturbance estimate as state columns 18..20: ``state``
        (F, 21) ``= [s, d_hat]`` and ``next_state`` (F, 21) ``= [s', d_hat']``, ``d_hat'`` the
        estimate at the episode's next frame (at its last frame, its own: the estimate moves
        with the observer's time constant, not in one step). UserError without the column."""
        if self.disturbance is None:
            raise UserError(
                "the dataset has no 'observation.disturbance' column: build it with datagen build --disturbance-observer TAU"
            )
        d = self.disturbance
        nxt = torch.arange(len(self)) + 1
        nxt = torch.where(nxt <= self.episode_end, nxt, self.episode_end)
        return dataclasses.replace(
            self, state=torch.cat([self.state, d], -1), next_state=torch.cat([self.next_state, d[nxt]], -1)
        )

    def as_tensordict(self) -> TensorDict:
        """The per-frame tensors as one TensorDict of batch size ``(frames,)`` (no copy)."""
        return TensorDict(
            {
                "state": self.state,
                "action": self.action,
                "goal": self.goal,
                "next_state": self.next_state,
                "episode_end": self.episode_end,
                **({"action_expert": self.action_expert} if self.action_expert is not None else {}),
            },
            batch_size=[len(self)],
        )


def _columns_checksum(cols: dict) -> str:
    h = hashlib.sha256()
    for k in sorted(REQUIRED):
        a = np.ascontiguousarray(cols[k])
        h.update(k.encode())
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def load_dataset(source: str | Path | dict[str, np.ndarray]) -> Dataset:
    """A :class:`Dataset` from a dataset folder or from a column dict (same keys as
    ``read_columns``); the folder is opened with
    :func:`aerohrl.datagen.dataset.open_dataset` (checksums verified). UserError on a
    missing/damaged dataset or wrong feature shapes."""
    if isinstance(source, dict):
        cols = source
        info: dict[str, Any] = {"path": None, "version": "in-memory", "checksum": None, "spec": {}}
    else:
        from aerohrl.datagen.dataset import open_dataset

        ds = open_dataset(source)
        cols = ds.columns()
        info = {"path": str(ds.path), "version": ds.version, "checksum": ds.checksum, "spec": ds.spec}
        if ds.maze is not None:  # the layout a maze dataset was flown in (aerohrl.worlds.maze.world_maze reads it)
            info["maze"] = ds.maze
    for k, shape in REQUIRED.items():
        if k not in cols:
            raise UserError(f"dataset has no {k!r} column")
        a = np.asarray(cols[k])
        if a.ndim != 1 + len(shape) or a.shape[1:] != shape:
            raise UserError(f"dataset column {k!r} has shape {a.shape[1:]}, expected {shape}")
    F = len(cols["observation.state"])
    if F < 2:
        raise UserError("dataset holds fewer than 2 frames")
    if any(len(cols[k]) != F for k in REQUIRED):
        raise UserError("dataset columns have different lengths")
    expert = "action.expert" in cols
    dist = "observation.disturbance" in cols
    if dist and np.asarray(cols["observation.disturbance"]).shape != (F, 3):
        raise UserError(
            f"dataset column 'observation.disturbance' has shape {np.asarray(cols['observation.disturbance']).shape}, "
            f"expected ({F}, 3)"
        )
    if expert and np.asarray(cols["action.expert"]).shape != np.asarray(cols["action"]).shape:
        raise UserError(
            f"dataset column 'action.expert' has shape {np.asarray(cols['action.expert']).shape}, "
            f"expected that of 'action' {np.asarray(cols['action']).shape}"
        )
    for k in (
        ("observation.state", "action", "observation.desired_goal", "next.observation.state")
        + (("action.expert",) if expert else ())
        + (("observation.disturbance",) if dist else ())
    ):
        if not np.isfinite(cols[k]).all():
            raise UserError(f"dataset column {k!r} holds NaN or inf")
    if info["checksum"] is None:
        info["checksum"] = _columns_checksum(cols)
    ep = torch.as_tensor(np.asarray(cols["episode_index"], dtype=np.int64))
    if (ep[1:] < ep[:-1]).any():
        raise UserError("dataset episodes are not contiguous and sorted")
    # last global index of each frame's episode (episodes are contiguous)
    change = torch.nonzero(ep[1:] != ep[:-1]).flatten()
    ends = torch.cat([change, torch.tensor([F - 1])])
    lengths = torch.diff(torch.cat([torch.tensor([-1]), ends]))
    episode_end = torch.repeat_interleave(ends, lengths)
    info["shapes"] = {k: list(np.asarray(cols[k]).shape[1:]) for k in REQUIRED}
    info["frames"] = F
    info["episodes"] = int(ends.numel())

    def f32(k):
        return torch.as_tensor(np.ascontiguousarray(cols[k], dtype=np.float32))

    return Dataset(
        state=f32("observation.state"),
        action=f32("action"),
        goal=f32("observation.desired_goal"),
        next_state=f32("next.observation.state"),
        episode_end=episode_end,
        episode_index=ep,
        info=info,
        action_expert=f32("action.expert") if expert else None,
        disturbance=f32("observation.disturbance") if dist else None,
    )


def make_buffer(
    data: Dataset, batch_size: int, generator: torch.Generator, device: str | torch.device = "cpu"
) -> TensorDictReplayBuffer:
    """A torchrl ``TensorDictReplayBuffer`` over the whole dataset, sampling uniformly
    with replacement (thesis Alg. 2, line 3). Its ``TensorStorage`` wraps the dataset's
    own tensors (no copy: one copy of a multi-GB dataset in memory, not two)."""
    from torchrl.data import RandomSampler, TensorDictReplayBuffer, TensorStorage

    from aerohrl.algorithms import quiet_torchrl

    quiet_torchrl()
    td = data.as_tensordict().to(device)
    return TensorDictReplayBuffer(
        storage=TensorStorage(td, device=device),
        sampler=RandomSampler(),
        batch_size=batch_size,
        generator=generator,
    )


__all__ = ["Dataset", "load_dataset", "make_buffer", "REQUIRED"]


class GoalBatchSampler:
    """Sample -> relabel -> reward/done -> normalise: one batch in the layout torchrl's
    losses read (``observation``, ``action``, ``("next", observation|reward|done|terminated)``),
    plus ``state``/``goal``/``next_state`` in physical units and the ``relabelled`` mask.
    No Python loop over the batch; every random draw comes from ``generator``."""

    def __init__(
        self,
        data: Dataset,
        normalizer,
        batch_size: int,
        delta: float,
        generator: torch.Generator,
        device="cpu",
        future: dict | None = None,
        mc_gamma: float | None = None,
        augment: str = "none",
        critic_random_goal_prob: float = 0.0,
        bc_target: str = "expert",
        goal_mixes: dict[str, GoalMix] | None = None,
        subgoal_steps: int = 0,
        subgoal_end: str = "achieved",
        low_subgoal_offset: str = "fixed",
    ):
        from aerohrl.algorithms.relabel import first_hit_index, relabel_goals, reward_done

        self._relabel, self._reward_done = relabel_goals, reward_done
        # The buffer, the draws and the relabelling stay on the CPU with the CPU generator
        # (reproducible on any device); the finished batch moves to ``device``.
        self.device = torch.device(device)
        self.buffer = make_buffer(data, batch_size, generator)
        self.achieved_goals = data.achieved_goal
        self.normalizer = normalizer
        self.delta = float(delta)
        self.future = dict(future or {})  # sample_future_index's strategy/window/mean
        self.generator = generator
        self.batch_size = batch_size
        # mc_gamma set: each batch also carries "mc_lower_bound", the discounted return the
        # data itself achieves for the (relabelled) goal (relabel.mc_lower_bound)
        self.mc_gamma = mc_gamma
        self.first_hit = first_hit_index(data.next_state, data.goal, data.episode_end) if mc_gamma is not None else None
        # augment "mirror": each transition reflected by a random one of the vehicle's 4 mirror
        # symmetries after relabelling (the goal test is invariant; algorithms.augment)
        self.augment = augment
        # > 0: the batch also carries "critic", the same transitions with the critics' goals:
        # with this probability the achieved goal of a uniformly random frame (OGBench's
        # value_p_randomgoal), else the actor's goal. The data rarely reaches such a goal,
        # so the critics learn which legs the data supports, which the planner ranks by.
        self.critic_random_goal_prob = float(critic_random_goal_prob)
        # "expert" on a dataset with action.expert: the batch also carries "bc_action" (the
        # clean command the policy imitates, Algorithm.actor_batch); "action" stays the
        # flown one, which the critics learn from
        self.bc_expert = bc_target == "expert" and data.action_expert is not None
        # OGBench-style goal sampling (the goal-conditioned agents gciql, crl, qrl, hiql):
        # for each name, the batch also carries a sub-batch td[name] (the same transitions)
        # whose goals come from the mix's sources (relabel.GoalMix: current, trajectory,
        # random, keep), with their rewards and done flags, e.g. "value" and "actor"
        self.goal_mixes = dict(goal_mixes or {})
        # > 0 (HIQL): every mix sub-batch also carries "target_state", the state
        # min(t + subgoal_steps, a trajectory goal's step, episode end) ahead (the high
        # level's target), "target_observation" (that state's input for the mix's goal) and
        # "subgoal_observation" (the current state's input for the target's achieved goal);
        # and td["subgoal"] holds the transitions with the achieved goal of the state
        # min(t + subgoal_steps, episode end) as goal (the low level's).
        # subgoal_end "desired": where that state is cut off by the episode's end, the
        # subgoal is the episode's desired goal instead of its last achieved state (the low
        # level's goal, and the high level's target for the mix's kept desired goals): the
        # data's expert aimed at the desired goal, and its last state lies anywhere within
        # the goal test's tolerances of it
        if subgoal_end not in ("achieved", "desired"):
            raise ValueError(f"subgoal_end {subgoal_end!r}: achieved | desired")
        # low_subgoal_offset "uniform": td["subgoal"]'s goal is the state a uniform 1..k steps
        # ahead instead of exactly k (the high level's target stays k ahead), so the low
        # level also learns to arrive at a subgoal closer than k, as on an episode's last
        # steps; "fixed" is OGBench's
        if low_subgoal_offset not in ("fixed", "uniform"):
            raise ValueError(f"low_subgoal_offset {low_subgoal_offset!r}: fixed | uniform")
        self.subgoal_steps = int(subgoal_steps)
        self.subgoal_end = subgoal_end
        self.low_subgoal_offset = low_subgoal_offset
        self.next_states = data.next_state

    def sample(self) -> TensorDict:
        """One training batch: uniform frames with hindsight-relabelled goals and their
        recomputed rewards and done flags (and the critic's own goals when configured)."""
        b = self.buffer.sample()
        index = b.get("index")
        state, next_state = b.get("state"), b.get("next_state")
        goal, relabelled, k = self._relabel(
            b.get("goal"),
            index,
            b.get("episode_end"),
            self.achieved_goals,
            self.delta,
            self.generator,
            return_index=True,
            **self.future,
        )
        reward, done = self._reward_done(next_state, goal)
        extra = {}
        if self.mc_gamma is not None:
            from aerohrl.algorithms.relabel import mc_lower_bound

            extra["mc_lower_bound"] = mc_lower_bound(index, k, relabelled, self.first_hit, self.mc_gamma).unsqueeze(-1)
        critic = None
        if self.critic_random_goal_prob > 0:
            n = index.shape[0]
            coin = torch.rand(n, generator=self.generator) < self.critic_random_goal_prob
            rand = torch.randint(0, len(self.achieved_goals), (n,), generator=self.generator)
            cgoal = torch.where(coin.unsqueeze(-1), self.achieved_goals[rand], goal)
            creward, cdone = self._reward_done(next_state, cgoal)
            cextra = {}
            if "mc_lower_bound" in extra:  # the data's return for a random goal: none observed
                cextra["mc_lower_bound"] = torch.where(coin.unsqueeze(-1), creward.unsqueeze(-1), extra["mc_lower_bound"])
            critic = (cgoal, creward, cdone, cextra)
        mixed = {}  # name -> [goal, reward, done, target state or None]
        if self.goal_mixes or self.subgoal_steps > 0:
            from aerohrl.algorithms.relabel import GOAL_CUR, GOAL_KEEP, GOAL_TRAJ, sample_goal_index, subgoal_index

            ep_end = b.get("episode_end")
            sub = subgoal_index(index, ep_end, self.subgoal_steps) if self.subgoal_steps > 0 else None
            desired = b.get("goal")
            # the subgoal cut off by the episode's end becomes the desired goal (subgoal_end)
            at_end = None
            if sub is not None and self.subgoal_end == "desired":
                at_end = (index + self.subgoal_steps - 1 >= ep_end).unsqueeze(-1)
            for name, mix in self.goal_mixes.items():
                kk, src = sample_goal_index(index, ep_end, len(self.achieved_goals), mix, self.generator)
                mgoal = torch.where((src == GOAL_KEEP).unsqueeze(-1), goal, self.achieved_goals[kk])
                target, sgoal = None, None
                if sub is not None:  # k steps ahead, but not past a trajectory goal (OGBench's high_traj_target)
                    along = (src == GOAL_TRAJ) | (src == GOAL_CUR)
                    target = self.next_states[torch.where(along, torch.minimum(sub, kk), sub)]
                    sgoal = task.achieved_goal(target)
                    if at_end is not None:
                        sgoal = torch.where(at_end & (src == GOAL_KEEP).unsqueeze(-1), desired, sgoal)
                mixed[name] = [mgoal, *self._reward_done(next_state, mgoal), target, sgoal]
            if sub is not None:
                lsub, lat_end = sub, at_end
                if self.low_subgoal_offset == "uniform":
                    off = torch.randint(1, self.subgoal_steps + 1, index.shape, generator=self.generator)
                    lsub = subgoal_index(index, ep_end, off)
                    if at_end is not None:
                        lat_end = (index + off - 1 >= ep_end).unsqueeze(-1)
                lgoal = self.achieved_goals[lsub]
                if lat_end is not None:
                    lgoal = torch.where(lat_end, desired, lgoal)
                mixed["subgoal"] = [lgoal, *self._reward_done(next_state, lgoal), None, None]
        action = b.get("action")
        bc_action = b.get("action_expert") if self.bc_expert else None
        if self.augment == "mirror":
            from aerohrl.algorithms.augment import draw_reflections, mirror_action, mirror_goal, mirror_state

            m = draw_reflections(state.shape[0], self.generator)
            state, next_state, goal = mirror_state(state, m), mirror_state(next_state, m), mirror_goal(goal, m)
            action = mirror_action(action, m)
            if bc_action is not None:
                bc_action = mirror_action(bc_action, m)
            if critic is not None:
                critic = (mirror_goal(critic[0], m), *critic[1:])
            for v in mixed.values():
                v[0] = mirror_goal(v[0], m)
                v[3] = None if v[3] is None else mirror_state(v[3], m)
                v[4] = None if v[4] is None else mirror_goal(v[4], m)
        more = {"index": index, "relabelled": relabelled}
        if bc_action is not None:
            more["bc_action"] = bc_action
        td = self._batch(state, action, next_state, goal, reward, done, extra, more)
        if critic is not None:
            cgoal, creward, cdone, cextra = critic
            td.set("critic", self._batch(state, action, next_state, cgoal, creward, cdone, cextra, {}))
        for name, (mgoal, mreward, mdone, target, sgoal) in mixed.items():
            mmore = {} if bc_action is None else {"bc_action": bc_action}
            if target is not None:
                mmore["target_state"] = target
                mmore["subgoal_goal"] = sgoal
            sub_td = self._batch(state, action, next_state, mgoal, mreward, mdone, {}, mmore)
            if target is not None:
                ts = sub_td.get("target_state")
                sub_td.set("target_observation", self.normalizer.inputs(ts, sub_td.get("goal")))
                sub_td.set("subgoal_observation", self.normalizer.inputs(sub_td.get("state"), sub_td.get("subgoal_goal")))
            td.set(name, sub_td)
        return td

    def _batch(self, state, action, next_state, goal, reward, done, extra: dict, more: dict) -> TensorDict:
        """The torchrl layout for one goal per transition, on ``self.device``."""
        if self.device.type != "cpu":
            dev = self.device
            state, next_state, goal, reward, done, action = (
                t.to(dev, non_blocking=True) for t in (state, next_state, goal, reward, done, action)
            )
            extra = {key: t.to(dev, non_blocking=True) for key, t in extra.items()}
            more = {key: t.to(dev, non_blocking=True) for key, t in more.items()}
        norm = self.normalizer
        n = state.shape[0]
        if "bc_action" in more:
            more["bc_action"] = norm.action_to_unit(more["bc_action"])
        return TensorDict(
            {
                "observation": norm.inputs(state, goal),
                "action": norm.action_to_unit(action),
                **more,
                "state": state,
                "goal": goal,
                "next_state": next_state,
                **extra,
                "next": TensorDict(
                    {
                        "observation": norm.inputs(next_state, goal),
                        "reward": reward.unsqueeze(-1),
                        "done": done.unsqueeze(-1),
                        "terminated": done.unsqueeze(-1),
                    },
                    batch_size=[n],
                ),
            },
            batch_size=[n],
            device=self.device,
        )


def fit_normalizer(
    data: Dataset,
    delta: float,
    seed: int = 0,
    future: dict | None = None,
    bc_target: str = "expert",
    pos_octaves: int = 0,
) -> Normalizer:
    """Input statistics over every frame with its desired goal and with a relabelled
    (strictly later achieved, drawn as in training: ``future``) goal, action bounds over
    every frame's BC target (what the policy's [-1, 1] output must span; flown noisy
    actions beyond it stay valid critic inputs). ``pos_octaves``: the position features
    of :class:`Normalizer` (their frequencies are fixed; nothing to fit)."""
    from aerohrl.algorithms.networks import Normalizer
    from aerohrl.algorithms.relabel import relabel_goals

    g = torch.Generator().manual_seed(seed)
    idx = torch.arange(len(data))
    if len(data) > NORMALIZER_FRAMES:  # large datasets: the statistics of a seeded subset (bounded memory)
        idx = torch.randperm(len(data), generator=g)[:NORMALIZER_FRAMES].sort().values
    later, _ = relabel_goals(data.goal[idx], idx, data.episode_end[idx], data.achieved_goal, 1.0, g, **(future or {}))
    # 33-d input in a world with obstacles; + d_hat when the states carry it (Dataset.with_disturbance)
    tau = float((data.info.get("spec") or {}).get("disturbance_observer", 0.0)) if data.state.shape[-1] > task.STATE_DIM else 0.0
    norm = Normalizer.for_dataset_spec(data.info.get("spec"), pos_octaves, disturbance_tau=tau)
    state = data.state[idx]
    x = torch.cat([norm.raw_inputs(state, data.goal[idx]), norm.raw_inputs(state, later)])
    return norm.fit(x, data.bc_actions(bc_target))  # action bounds: every frame (min/max, no copy)


NORMALIZER_FRAMES = 4_000_000  # frames the input statistics are fitted on at most
