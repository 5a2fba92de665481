"""Informative path planning on motion primitives (thesis chapter 2).

Modules: :mod:`.lattice` (dispersion-minimising primitive lattice, file format),
:mod:`.world` (ground truth, prior, KL), :mod:`.sensor` (Eq. 2.2), :mod:`.env`
(batched target-search environment), :mod:`.baselines` (Table 2.1 heuristics),
:mod:`.policy` / :mod:`.train` (learned recurrent planner), :mod:`.features`,
:mod:`.semantic` / :mod:`.semantic_env` (semantic feature detection), :mod:`.metrics`,
:mod:`.bench`, :mod:`.cli`. See ipp/README.md.
"""

from .baselines import PLANNERS, PlannerConfig, make_planner
from .env import TERMS, EnvConfig, SearchEnv, semantic_config
from .factory import create_env, make_env
from .lattice import (Lattice, LatticeConfig, build_lattice, default_lattice, load_lattice,
                      save_lattice)
from .semantic import CLASSES, SemanticConfig, load_class_raster
from .sensor import SensorConfig
from .world import WorldConfig, Worlds, sample_worlds

try:  # gymnasium is a dependency; registration must never break `import aerohrl.ipp`
    from .gym_env import register as _register

    _register()  # aerohrl/IPPSearch-v0
except ImportError:  # pragma: no cover
    pass

__all__ = ["PLANNERS", "PlannerConfig", "make_planner", "TERMS", "EnvConfig", "SearchEnv",
           "make_env", "create_env", "semantic_config", "CLASSES", "SemanticConfig",
           "load_class_raster", "Lattice", "LatticeConfig", "build_lattice", "default_lattice",
           "load_lattice", "save_lattice", "SensorConfig", "WorldConfig", "Worlds",
           "sample_worlds"]
