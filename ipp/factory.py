"""Environment factory: a :class:`~aerohrl.ipp.env.SearchEnv` or a
:class:`~aerohrl.ipp.semantic_env.SemanticEnv` by ``EnvConfig.kind``, and their worlds.

It lives apart from :mod:`.env` so that the environment module never imports its
subclass (no import cycle: ``env`` <- ``semantic_env`` <- ``factory``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

import numpy as np

from .env import EnvConfig, SearchEnv
from .lattice import Lattice
from .semantic import sample_semantic_worlds
from .semantic_env import SemanticEnv
from .world import sample_worlds

if TYPE_CHECKING:
    from .semantic import SemanticWorlds
    from .world import Worlds


def create_env(cfg: EnvConfig, lattice: Lattice) -> SearchEnv:
    """A :class:`SearchEnv` or (``cfg.kind == "semantic"``) a :class:`SemanticEnv`."""
    if cfg.kind == "semantic":
        return SemanticEnv(cfg, lattice)
    return SearchEnv(cfg, lattice)


def sample_for(cfg: EnvConfig, seed: int, indices: Sequence[int] | np.ndarray) -> Worlds | SemanticWorlds:
    """Worlds ``indices`` of suite ``seed`` of the config's kind."""
    if cfg.kind == "semantic":
        return sample_semantic_worlds(cfg.semantic, seed, indices)
    return sample_worlds(cfg.world, seed, indices)


def make_env(cfg: EnvConfig, lattice: Lattice, seed: int, indices: Sequence[int] | np.ndarray) -> tuple[SearchEnv, dict]:
    """Convenience: an env reset on worlds ``indices`` of suite ``seed``."""
    env = create_env(cfg, lattice)
    obs = env.reset(sample_for(cfg, seed, indices))
    return env, obs


__all__ = ["create_env", "sample_for", "make_env"]
