"""Informative path planning on motion primitives (thesis chapter 2).

Modules: :mod:`.lattice` (dispersion-minimising primitive lattice, file format),
:mod:`.world` (ground truth, prior, KL), :mod:`.sensor` (Eq. 2.2), :mod:`.env`
(batched target-search environment), :mod:`.baselines` (Table 2.1 heuristics),
:mod:`.policy` / :mod:`.train` (learned recurrent planner), :mod:`.features`,
:mod:`.semantic` / :mod:`.semantic_env` (semantic feature detection), :mod:`.metrics`,
:mod:`.bench`, :mod:`.cli`. See ipp/README.md.
"""

import importlib

# the package's names, loaded on first use (PEP 562): `aerohrl ipp ... --help` and
# `import aerohrl.ipp` stay light (scipy.ndimage and torch load with the modules that need them)
_EXPORTS = {
    "PLANNERS": "baselines",
    "PlannerConfig": "baselines",
    "make_planner": "baselines",
    "TERMS": "env",
    "EnvConfig": "env",
    "SearchEnv": "env",
    "semantic_config": "env",
    "create_env": "factory",
    "make_env": "factory",
    "Lattice": "lattice",
    "LatticeConfig": "lattice",
    "build_lattice": "lattice",
    "default_lattice": "lattice",
    "load_lattice": "lattice",
    "save_lattice": "lattice",
    "CLASSES": "semantic",
    "SemanticConfig": "semantic",
    "load_class_raster": "semantic",
    "SensorConfig": "sensor",
    "WorldConfig": "world",
    "Worlds": "world",
    "sample_worlds": "world",
}
ENV_ID = "aerohrl/IPPSearch-v0"  # = aerohrl.envs.IPP_SEARCH_ID = gym_env.ENV_ID


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
        globals()[name] = value
        return value
    try:  # a submodule not imported yet (aerohrl.ipp.bench after `import aerohrl.ipp`)
        return importlib.import_module(f".{name}", __name__)
    except ModuleNotFoundError as e:
        if e.name != f"{__name__}.{name}":
            raise
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


try:  # gymnasium is a dependency; registration (by name, of every id) must never break `import aerohrl.ipp`
    from aerohrl.envs import register as _register_envs

    _register_envs()
except ImportError:  # pragma: no cover
    pass

__all__ = [
    "PLANNERS",
    "PlannerConfig",
    "make_planner",
    "TERMS",
    "EnvConfig",
    "SearchEnv",
    "make_env",
    "create_env",
    "semantic_config",
    "CLASSES",
    "SemanticConfig",
    "load_class_raster",
    "Lattice",
    "LatticeConfig",
    "build_lattice",
    "default_lattice",
    "load_lattice",
    "save_lattice",
    "SensorConfig",
    "WorldConfig",
    "Worlds",
    "sample_worlds",
]
