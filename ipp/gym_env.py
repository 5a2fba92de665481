"""Gymnasium interface to the batched target search: ``aerohrl/IPPSearch-v0``.

:class:`IPPSearchVectorEnv` is a native :class:`gymnasium.vector.VectorEnv` over one
batched :class:`~aerohrl.ipp.env.SearchEnv` (``num_envs`` worlds stepped together as
arrays, no per-environment Python loop in ``step``); :class:`IPPSearchEnv` is the single
environment (``gymnasium.make("aerohrl/IPPSearch-v0")``), the vector env with one world.

* Observation: ``Dict(maps=Box(0, 1, (9, 8, 8), float32), vec=Box(0, 1, (2+A+1+V+1,),
  float32))`` — the thesis's egocentric multi-scale belief / coverage / boundary windows
  and the vector features (position / map size, one-hot last primitive, one-hot lattice
  vertex, remaining budget fraction); see :meth:`SearchEnv.observe`.
* Action: ``Discrete(A)``, a primitive slot of the current lattice vertex. The valid
  slots are ``info["action_mask"]`` (int8, 1 = valid; Gymnasium's convention, e.g.
  ``action_space.sample(mask=info["action_mask"])``). An invalid slot costs its
  primitive and −1, and the vehicle stays (thesis §2.5.2).
* Reward: the sum of the five terms (entropy, coverage, target, cost, invalid); the
  terms are ``info["terms"]``. ``terminated`` when the budget is spent; never truncated.
  At the end of an episode ``info["metrics"]`` holds Table 2.1's metrics for it.
* Worlds: ``reset(seed=s)`` draws world indices of suite ``world_seed`` (default 7,
  the training suite; the test suite 1000 is :data:`aerohrl.ipp.bench.TEST_SEED`) from
  the env's RNG, so a seed fixes the worlds; ``options={"worlds": [i, ...]}`` picks them.
* Vector autoreset: ``NEXT_STEP`` (Gymnasium's default): after a sub-environment ends,
  its next ``step`` ignores the action and starts a new world
  (:meth:`SearchEnv.reset_rows`).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from aerohrl.envs import IPP_SEARCH_ID

from .env import BUDGETS, EnvConfig, SearchEnv
from .lattice import Lattice, get_lattice
from .world import sample_worlds

ENV_ID = IPP_SEARCH_ID  # registered by aerohrl.envs.register
TRAIN_SEED = 7


def _config(budget, start, map_size) -> EnvConfig:
    from dataclasses import replace

    from .world import WorldConfig

    b = BUDGETS.get(budget, budget) if isinstance(budget, str) else budget
    try:
        b = float(b)
    except (TypeError, ValueError):
        raise ValueError(f"budget must be a number or one of {sorted(BUDGETS)}, got {budget!r}") from None
    if not np.isfinite(b) or b <= 0:
        raise ValueError(f"budget must be > 0, got {budget!r}")
    return replace(EnvConfig(), budget=b, start=start, map_size=map_size, world=WorldConfig(map_size=map_size))


class IPPSearchVectorEnv(VectorEnv):
    """``num_envs`` target-search worlds in one batched :class:`SearchEnv`."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int = 1,
        *,
        budget: float | str = "default",
        start: str = "random",
        map_size: int = 30,
        world_seed: int = TRAIN_SEED,
        lattice: Lattice | str | None = None,
        autoreset: bool = True,
        render_mode=None,
    ):
        if int(num_envs) < 1:
            raise ValueError("num_envs must be >= 1")
        self.lat = lattice if isinstance(lattice, Lattice) else get_lattice(lattice)
        self.cfg = _config(budget, start, map_size)
        self.env = SearchEnv(self.cfg, self.lat)
        self.env.lazy_obs = True
        self.env.keep_trace = False
        self.num_envs = n = int(num_envs)
        self.world_seed = int(world_seed)
        self.render_mode = render_mode
        self.autoreset = bool(autoreset)
        self.metadata = {**self.metadata, "autoreset_mode": AutoresetMode.NEXT_STEP if autoreset else AutoresetMode.DISABLED}
        R, sc = self.cfg.obs_radius, self.cfg.obs_scales
        A, V = self.lat.n_actions, self.lat.n_vertices
        self.single_observation_space = spaces.Dict(
            {
                "maps": spaces.Box(0.0, 1.0, (3 * len(sc), 2 * R, 2 * R), np.float32),
                "vec": spaces.Box(0.0, 1.0, (2 + A + 1 + V + 1,), np.float32),
            }
        )
        self.single_action_space = spaces.Discrete(A)
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self._needs_reset = np.zeros(n, bool)
        self._world_idx = np.zeros(n, np.int64)

    # ------------------------------------------------------------------ helpers
    def _draw(self, k: int) -> np.ndarray:
        return self.np_random.integers(0, 2**31 - 1, size=k)

    def _obs(self) -> dict:
        o = self.env.observe()
        return {"maps": o["maps"], "vec": o["vec"]}

    def _info(self) -> dict:
        return {"action_mask": self.env.valid_mask().astype(np.int8), "world": self._world_idx.copy()}

    def action_masks(self) -> np.ndarray:
        """(num_envs, A) bool valid primitive slots (sb3-contrib's MaskablePPO hook)."""
        return self.env.valid_mask()

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start every env on a new world (``options["worlds"]``: given world indices, else
        drawn); returns ``(obs, info)`` with the action masks."""
        super().reset(seed=seed)
        options = options or {}
        idx = options.get("worlds")
        idx = self._draw(self.num_envs) if idx is None else np.asarray(idx, np.int64).reshape(self.num_envs)
        self._world_idx[:] = idx
        self.env.reset(sample_worlds(self.cfg.world, self.world_seed, idx))
        self._needs_reset[:] = False
        return self._obs(), self._info()

    def step(self, actions: np.ndarray) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray, dict]:
        """Execute one primitive (action slot, (n,) int) per env; ``(obs, reward, terminated,
        truncated, info)`` (info: action masks, worlds, reward terms, metrics at the end)."""
        n, env = self.num_envs, self.env
        a: np.ndarray = np.asarray(actions).reshape(n)
        if not np.issubdtype(a.dtype, np.integer):
            if not np.all(np.isfinite(a)) or np.any(a != np.round(a)):
                raise ValueError("actions must be integer primitive slots")
            a = a.astype(np.int64)
        resetting = self._needs_reset.copy() if self.autoreset else np.zeros(n, bool)
        a = np.where(resetting | env.done, 0, a)  # ignored rows: any in-range slot
        if np.any((a < 0) | (a >= self.lat.n_actions)):
            raise ValueError(f"action outside 0..{self.lat.n_actions - 1}")
        was_done = env.done.copy()
        _, reward, terms, done = env.step(a)
        ended = done & ~was_done
        info = self._info()
        info["terms"] = terms
        if ended.any():
            m = env.metrics()
            info["metrics"] = {k: np.where(ended, v, np.nan) for k, v in m.items() if k not in ("kl",)}
            info["_metrics"] = ended
        terminated = ended.copy()
        truncated = np.zeros(n, bool)
        reward = np.where(ended | ~was_done, reward, 0.0)
        if resetting.any():
            rows = np.flatnonzero(resetting)
            new = self._draw(len(rows))
            self._world_idx[rows] = new
            env.reset_rows(rows, sample_worlds(self.cfg.world, self.world_seed, new))
            reward[rows] = 0.0
            terminated[rows] = False
            info["action_mask"] = env.valid_mask().astype(np.int8)
            info["world"] = self._world_idx.copy()
        if self.autoreset:
            self._needs_reset = ended.copy()
        return self._obs(), reward.astype(np.float64), terminated, truncated, info


class IPPSearchEnv(gym.Env):
    """One world (``gymnasium.make("aerohrl/IPPSearch-v0")``): the vector env with one."""

    metadata = {"render_modes": []}

    def __init__(self, **kw):
        kw.pop("num_envs", None)
        self._vec = IPPSearchVectorEnv(1, autoreset=False, **kw)
        self.observation_space = self._vec.single_observation_space
        self.action_space = self._vec.single_action_space
        self._done = True

    @staticmethod
    def _one(d: dict) -> dict:
        return {k: (v[0] if isinstance(v, np.ndarray) else v) for k, v in d.items()}

    def action_masks(self) -> np.ndarray:
        """The valid action slots (A,) bool of the current state (for maskable policies)."""
        return self._vec.action_masks()[0]

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start on a new world (``options["world"]``: a given index, else drawn); returns
        ``(obs, info)`` with the action mask."""
        super().reset(seed=seed)
        opts = dict(options or {})
        if "world" in opts:
            opts["worlds"] = [int(opts.pop("world"))]
        # the single env's RNG (seeded by ``seed``) draws the vector env's seed
        obs, info = self._vec.reset(seed=int(self.np_random.integers(0, 2**31 - 1)), options=opts)
        self._done = False
        return self._one(obs), {"action_mask": info["action_mask"][0], "world": int(info["world"][0])}

    def step(self, action: int) -> tuple[dict, float, bool, bool, dict]:
        """Execute one primitive (action slot); ``(obs, reward, terminated, truncated, info)``."""
        obs, r, te, tr, info = self._vec.step(np.asarray([int(action)]))
        out = {"action_mask": info["action_mask"][0], "world": int(info["world"][0]), "terms": info["terms"][0]}
        if "metrics" in info:
            out["metrics"] = {k: float(v[0]) for k, v in info["metrics"].items()}
        return self._one(obs), float(r[0]), bool(te[0]), bool(tr[0]), out


__all__ = ["IPPSearchVectorEnv", "IPPSearchEnv", "ENV_ID"]
