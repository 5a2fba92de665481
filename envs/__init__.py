"""The Gymnasium environments and the batched closed loop that flies policies in them.

Modules: :mod:`.reach` (``aerohrl/QuadrotorReach-v0``: :class:`~aerohrl.envs.reach.QuadrotorReachEnv`
and the native vector env :class:`~aerohrl.envs.reach.QuadrotorReachVectorEnv`),
:mod:`.maze` (``aerohrl/QuadrotorMaze-v0``: the reach env in a maze of
:mod:`aerohrl.worlds`, ``maze=`` and ``task=`` 1-5, collisions end episodes as failures;
the frozen maze tasks, :func:`~aerohrl.envs.maze.maze_episodes`),
:mod:`.episodes` (:class:`~aerohrl.envs.episodes.EpisodeSet`, hover start states) and
:mod:`.rollout` (the batched closed loop; a planner enters it through its ``plan``
method only). The IPP search environment's classes live with the search they wrap
(:mod:`aerohrl.ipp.gym_env`); its id is registered here with the others.

:func:`register` registers every Gymnasium id of the project, by name: the entry points
are strings, so registering imports no environment module (``gymnasium.make`` loads it).
``import aerohrl`` calls it once Gymnasium is imported; calling it again does nothing.
"""

from __future__ import annotations

REACH_ID = "aerohrl/QuadrotorReach-v0"
MAZE_ID = "aerohrl/QuadrotorMaze-v0"
IPP_SEARCH_ID = "aerohrl/IPPSearch-v0"

# id -> (single-env entry point, vector entry point)
ENTRY_POINTS = {
    REACH_ID: ("aerohrl.envs.reach:QuadrotorReachEnv", "aerohrl.envs.reach:QuadrotorReachVectorEnv"),
    MAZE_ID: ("aerohrl.envs.maze:QuadrotorMazeEnv", "aerohrl.envs.maze:QuadrotorMazeVectorEnv"),
    IPP_SEARCH_ID: ("aerohrl.ipp.gym_env:IPPSearchEnv", "aerohrl.ipp.gym_env:IPPSearchVectorEnv"),
}


def register() -> None:
    """Register every id of :data:`ENTRY_POINTS` not registered yet (idempotent)."""
    import gymnasium as gym

    for env_id, (entry, vector_entry) in ENTRY_POINTS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry, vector_entry_point=vector_entry, max_episode_steps=None)


__all__ = ["REACH_ID", "MAZE_ID", "IPP_SEARCH_ID", "ENTRY_POINTS", "register"]
