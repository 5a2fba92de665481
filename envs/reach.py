"""The reach task as a Gymnasium goal-conditioned environment: ``aerohrl/QuadrotorReach-v0``.

:class:`QuadrotorReachVectorEnv` is a native :class:`gymnasium.vector.VectorEnv`: its
``num_envs`` vehicles are one :class:`~aerohrl.sim.BatchedQuadrotor` stepped in one call
(wrapping a single-vehicle env in ``SyncVectorEnv`` would step them in a Python loop,
which is what this project avoids on hot paths). :class:`QuadrotorReachEnv` is the
single-vehicle ``gymnasium.Env`` (the same code with one vehicle).

Observation (the goal-env convention of gymnasium-robotics, which external GC-RL code
such as HER implementations expects): a dict with ``observation`` (18: the state
``[p, v, R, w]``), ``achieved_goal`` (15: its ``[p, v, R]``) and ``desired_goal`` (15).
Action: CTBR ``[c, wx, wy, wz]`` (clipped to the action space: ``0 <= c <=`` the
vehicle's maximum collective thrust, ``|w_i| <= 20`` rad/s). A NaN or infinite action
raises :class:`NonFiniteAction` (a ``ValueError``) naming the vehicles: there is no
safe value to clip it to (zero thrust would cut the motors), so the step is refused
and the simulation is left as it was; the vehicles a ``NEXT_STEP`` autoreset is
resetting ignore their action, whatever it holds. Reward (docs/spec.md): sparse,
``compute_reward(achieved_goal, desired_goal, info)`` = 1 when the goal-reached test
holds, else 0, batched over any leading dimensions (HER relabels with it). An episode
*terminates* when the goal is reached (``tolerance_scale`` scales the test's
tolerances for that; default 1) and is *truncated* at its horizon; ``info`` holds
``is_success``, ``near_success`` (tolerances x 2.5) and ``collision`` per vehicle (a
crash ends an episode as a failure; free space has nothing to hit, the maze env of
:mod:`aerohrl.envs.maze` has walls).

Resetting: ``reset(seed=..., options=...)`` draws goals from the goal pool (the
dataset's desired goals when built with ``dataset=``; otherwise rho_D sampled with
:func:`aerohrl.datagen.goals.sample_goals`) and starts at hover at the origin; options
``start_states`` (N, 18), ``goals`` (N, 15) and ``horizons`` (int or (N,)) fix them, as
the evaluation harness does. Autoreset: ``NEXT_STEP`` (Gymnasium's default: the step
after a sub-environment ended resets it and ignores its action), or ``DISABLED`` with
``autoreset=False`` (the harness: finished vehicles keep flying and are ignored).

Model error (robustness tests): ``perturbation=`` a :class:`~aerohrl.sim.perturb.Perturbation`
flies every vehicle on the perturbed plant (randomness seeded by ``perturb_seed``); then
``observation`` is the state as the policy observes it (noise and bias), while
``achieved_goal``, the reward and every test of the goal are on the true state.
:meth:`set_desired_goals` changes the goal (and the step budget) of some vehicles in
flight: how the harness hands planned intermediate goals to the policy.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import gymnasium as gym
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from aerohrl import task
from aerohrl.envs import REACH_ID
from aerohrl.envs.episodes import hover_states
from aerohrl.sim.params import GRAVITY
from aerohrl.sim.perturb import Perturbation

ENV_ID = REACH_ID  # registered by aerohrl.envs.register
RATE_LIMIT = 20.0  # rad/s, commanded body-rate bound of the action space


class NonFiniteAction(ValueError):
    """An action with NaN or inf: refused (a one-line error in the commands that fly policies)."""


def compute_reward(achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any = None) -> np.ndarray:
    """Sparse goal-reaching reward (docs/spec.md): 1.0 where the goal-reached test holds."""
    return np.asarray(
        task.goal_reached(np.asarray(achieved_goal, np.float64), np.asarray(desired_goal, np.float64)), dtype=np.float64
    )


def _goal_pool_from_dataset(path):
    """The desired goals the expert flew from hover at the origin (where this env's
    episodes start: one per goal of rho_D, never a continuation; as
    ``Dataset.rest_start_episodes``), and the dataset's spec. Torch-free."""
    from aerohrl.datagen.dataset import open_dataset

    ds = open_dataset(path)
    spec = ds.spec
    cols = ds.columns(["episode_index", "observation.desired_goal"])
    ep = np.asarray(cols["episode_index"])
    first = np.flatnonzero(np.r_[True, ep[1:] != ep[:-1]])  # first frame of each episode, in episode order
    m, k = int(spec.get("continuations", 0)), int(spec.get("rollouts_per_goal", 1))
    rest = np.arange(0, len(first) - m, k)
    return np.asarray(cols["observation.desired_goal"][first[rest]], np.float64), spec


class QuadrotorReachVectorEnv(VectorEnv):
    """``num_envs`` quadrotors, one batched simulator; see the module docstring."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}
    single_action_space: spaces.Box  # set in __init__

    def __init__(
        self,
        num_envs: int = 1,
        *,
        dataset=None,
        goals=None,
        vehicle: str | None = None,
        fps: int | None = None,
        substeps: int | None = None,
        horizon: int = 500,
        autoreset: bool = True,
        pos_range=(1.0, 2.0),
        vel_range=(-2.5, 2.5),
        acc_range=(-5.0, 5.0),
        tolerance_scale: float = 1.0,
        render_mode=None,
        perturbation: Perturbation | None = None,
        perturb_seed: int = 0,
    ):
        from aerohrl.sim import BatchedQuadrotor, get_preset

        spec = {}
        if dataset is not None and goals is None:
            goals, spec = _goal_pool_from_dataset(dataset)
        self.goal_pool = None if goals is None else np.asarray(goals, np.float64).reshape(-1, task.GOAL_DIM)
        if self.goal_pool is not None and len(self.goal_pool) == 0:
            raise ValueError("the goal pool is empty")
        self.goal_ranges = {
            "pos_range": tuple(spec.get("pos_range", pos_range)),
            "vel_range": tuple(spec.get("vel_range", vel_range)),
            "acc_range": tuple(spec.get("acc_range", acc_range)),
        }
        self.vehicle = vehicle or spec.get("vehicle", "hummingbird")
        self.fps = int(fps or spec.get("fps", 100))
        self.substeps = int(substeps or spec.get("substeps", 5))
        self.num_envs = n = int(num_envs)
        self.render_mode = render_mode
        self._perturb_seed = int(perturb_seed)
        self.sim = BatchedQuadrotor(
            get_preset(self.vehicle), n, dt=1.0 / self.fps, substeps=self.substeps, perturbation=perturbation, seed=perturb_seed
        )
        self.metadata = {**self.metadata, "autoreset_mode": AutoresetMode.NEXT_STEP if autoreset else AutoresetMode.DISABLED}
        self.autoreset = bool(autoreset)
        self.tolerance = task.TOLERANCE.scaled(float(tolerance_scale))  # of `terminated` (1: the SPEC's goal-reached test)
        inf = np.inf
        self.single_observation_space = spaces.Dict(
            {
                "observation": spaces.Box(-inf, inf, (task.STATE_DIM,), np.float64),
                "achieved_goal": spaces.Box(-inf, inf, (task.GOAL_DIM,), np.float64),
                "desired_goal": spaces.Box(-inf, inf, (task.GOAL_DIM,), np.float64),
            }
        )
        cmax = float(self.sim.params.max_collective)
        self.single_action_space = spaces.Box(
            np.array([0.0, -RATE_LIMIT, -RATE_LIMIT, -RATE_LIMIT]),
            np.array([cmax, RATE_LIMIT, RATE_LIMIT, RATE_LIMIT]),
            dtype=np.float64,
        )
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self.default_horizon = int(horizon)
        self.state = self.sim.state
        self.goals = np.zeros((n, task.GOAL_DIM))
        self.start_states = self.state.copy()
        self.horizons = np.full(n, self.default_horizon, np.int64)
        self.elapsed = np.zeros(n, np.int64)
        self.done = np.zeros(n, bool)
        self._needs_reset = np.zeros(n, bool)

    # ------------------------------------------------------------------ goals
    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any = None) -> np.ndarray:
        """The sparse reward (1.0 where the goal-reached test holds) of achieved vs desired goals (..., 15)."""
        return compute_reward(achieved_goal, desired_goal, info)

    def _sample_goals(self, k: int) -> np.ndarray:
        if self.goal_pool is not None:
            return self.goal_pool[self.np_random.integers(0, len(self.goal_pool), size=k)]
        from aerohrl.datagen.goals import goal_vectors, sample_goals

        return goal_vectors(sample_goals(self.np_random, k, **self.goal_ranges))

    def _new_episodes(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Start states (k, 18), goals (k, 15) and horizons (k,) of ``k`` fresh episodes (reset
        without options, and autoreset): hover at the origin, goals from the pool. A world
        with its own tasks (:mod:`aerohrl.envs.maze`) overrides it."""
        return hover_states(k), self._sample_goals(k), np.full(k, self.default_horizon, np.int64)

    def _crashed(self, state: np.ndarray) -> np.ndarray:
        """(n,) bool: the vehicles whose state is a crash, which ends their episode as a
        failure (``info["collision"]``). Free space has nothing to hit."""
        return np.zeros(len(state), bool)

    def _obs(self) -> dict:
        s = self.state
        seen = s.copy() if self.sim.plant is None else self.sim.observe()
        return {"observation": seen, "achieved_goal": task.achieved_goal(s).copy(), "desired_goal": self.goals.copy()}

    def _reset_rows(self, rows: np.ndarray, starts: np.ndarray, goals: np.ndarray, horizons: np.ndarray) -> None:
        full = self.state.copy()
        full[rows] = starts
        om = self.sim.rotor_speeds
        om[rows] = self.sim.params.hover_rotor_speed
        self.state = self.sim.reset(full, om, rows=rows)
        self.start_states[rows] = self.state[rows]
        self.goals[rows] = goals
        self.horizons[rows] = horizons
        self.elapsed[rows] = 0
        self.done[rows] = False
        self._needs_reset[rows] = False

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start every vehicle at hover at the origin (or ``options["start_states"]`` (n, 18))
        with new goals (``options["goals"]`` (n, 15), else drawn); returns ``(obs, info)``."""
        super().reset(seed=seed)
        if seed is not None and self.sim.plant is not None:  # a seeded reset replays the gusts and noise too
            self.sim.plant.reseed([self._perturb_seed, int(seed)])
        options = options or {}
        n = self.num_envs
        given = [options.get(k) for k in ("start_states", "goals", "horizons")]
        # fresh episodes only for what the options leave open (drawing none when they fix all keeps the seeded stream)
        fresh = self._new_episodes(n) if any(x is None for x in given) else (None, None, None)
        starts, goals, hz = (f if x is None else x for x, f in zip(given, fresh))
        starts = np.asarray(starts, np.float64).reshape(n, task.STATE_DIM)
        goals = np.asarray(goals, np.float64).reshape(n, task.GOAL_DIM)
        hz = np.broadcast_to(np.asarray(hz, np.int64), (n,))
        self._reset_rows(np.arange(n), starts, goals, hz)
        return self._obs(), {}

    def set_desired_goals(
        self, goals: np.ndarray, mask: np.ndarray | None = None, horizons: np.ndarray | int | None = None
    ) -> dict:
        """New goals (and step budgets) for the vehicles in ``mask`` mid-flight; their
        step counters and done flags restart. Returns the observation."""
        mask = np.ones(self.num_envs, bool) if mask is None else np.asarray(mask, bool)
        goals = np.asarray(goals, np.float64).reshape(-1, task.GOAL_DIM)
        self.goals[mask] = goals[mask] if len(goals) == self.num_envs else goals  # full (N, 15) or one row per masked vehicle
        if horizons is not None:
            self.horizons[mask] = np.broadcast_to(np.asarray(horizons, np.int64), (self.num_envs,))[mask]
        self.elapsed[mask] = 0
        self.done[mask] = False
        return self._obs()

    def step(self, actions: np.ndarray) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray, dict]:
        """Apply CTBR actions (n, 4), clipped to the action box, for one control period; ``(obs, reward, terminated,
        truncated, info)`` per vehicle (a non-finite action raises :class:`NonFiniteAction`)."""
        n = self.num_envs
        a: np.ndarray = np.asarray(actions, np.float64).reshape(n, 4).copy()
        resetting = self._needs_reset.copy() if self.autoreset else np.zeros(n, bool)
        bad_action = ~np.isfinite(a).all(1) & ~resetting
        if bad_action.any():
            rows = np.flatnonzero(bad_action)
            raise NonFiniteAction(
                f"non-finite action (NaN or inf) for vehicle(s) {rows[:8].tolist()}"
                + (f" and {len(rows) - 8} more" if len(rows) > 8 else "")
                + ": step refused"
            )
        a = np.clip(a, self.single_action_space.low, self.single_action_space.high)
        if resetting.any():  # NEXT_STEP autoreset: these ignore their action
            a[resetting] = [GRAVITY, 0.0, 0.0, 0.0]  # hover command
        self.state = self.sim.step(a)
        self.elapsed += 1
        bad = ~np.isfinite(self.state).all(1)
        if bad.any():  # a diverged vehicle: back to its start, episode truncated
            self._reset_rows(np.flatnonzero(bad), self.start_states[bad], self.goals[bad], self.horizons[bad])
        ag = task.achieved_goal(self.state)
        crash = self._crashed(self.state) & ~bad  # a crash ends the episode as a failure, whatever the goal test says
        reached = task.goal_reached(ag, self.goals, self.tolerance) & ~crash
        near = task.near_success(ag, self.goals) & ~crash
        active = ~self.done & ~resetting
        terminated = (reached | crash) & active
        truncated = active & ~terminated & ((self.elapsed >= self.horizons) | bad)
        reward = compute_reward(ag, self.goals) * (active & ~crash)
        self.done |= terminated | truncated
        if resetting.any():
            rows = np.flatnonzero(resetting)
            self._reset_rows(rows, *self._new_episodes(len(rows)))
        if self.autoreset:
            self._needs_reset |= terminated | truncated
        info = {
            "is_success": task.goal_reached(ag, self.goals) & ~crash,
            "near_success": near,
            "collision": crash & active,
            "elapsed": self.elapsed.copy(),
            "diverged": bad,
        }
        return self._obs(), reward, terminated, truncated, info


class QuadrotorReachEnv(gym.Env):
    """One quadrotor (``gymnasium.make("aerohrl/QuadrotorReach-v0")``); the vector env with one vehicle."""

    metadata = {"render_modes": []}

    def __init__(self, **kw):
        kw.pop("num_envs", None)
        self._vec = QuadrotorReachVectorEnv(1, autoreset=False, **kw)
        self.observation_space = self._vec.single_observation_space
        self.action_space = self._vec.single_action_space

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any = None) -> np.ndarray:
        """The sparse reward (1.0 where the goal-reached test holds) of achieved vs desired goals (..., 15)."""
        return compute_reward(achieved_goal, desired_goal, info)

    @staticmethod
    def _one(d):
        return {k: v[0] for k, v in d.items()}

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start at hover at the origin (or ``options["start_states"]`` (18,)) with a new goal
        (``options["goals"]`` (15,), else drawn); returns ``(obs, info)``."""
        super().reset(seed=seed)
        opts = dict(options or {})
        for k, shape in (("start_states", task.STATE_DIM), ("goals", task.GOAL_DIM)):
            if k in opts:
                opts[k] = np.asarray(opts[k], np.float64).reshape(1, shape)
        obs, _ = self._vec.reset(seed=seed, options=opts)
        return self._one(obs), {}

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        """Apply one CTBR action (4,); ``(obs, reward, terminated, truncated, info)``."""
        obs, r, te, tr, info = self._vec.step(np.asarray(action, np.float64).reshape(1, 4))
        return self._one(obs), float(r[0]), bool(te[0]), bool(tr[0]), {k: v[0] for k, v in info.items()}


def normalize_actions(env: gym.Env | VectorEnv) -> gym.Env | VectorEnv:
    """``env`` with actions in [-1, 1]^4, mapped affinely onto the CTBR box (-1: zero
    thrust and -20 rad/s, +1: full thrust and +20 rad/s): Gymnasium's ``RescaleAction``
    (``gymnasium.wrappers.vector.RescaleAction`` for a vector env)."""
    if isinstance(env, VectorEnv):
        from gymnasium.wrappers.vector import RescaleAction as VecRescale

        return VecRescale(env, -1.0, 1.0)  # type: ignore[arg-type]  # gymnasium annotates numpy scalars or arrays; floats work
    return gym.wrappers.RescaleAction(env, -1.0, 1.0)  # type: ignore[arg-type]  # as above


__all__ = ["QuadrotorReachVectorEnv", "QuadrotorReachEnv", "NonFiniteAction", "compute_reward", "normalize_actions", "ENV_ID"]
