"""aerohrl: hierarchical reinforcement learning for aerial vehicles.

The pipeline from Python (:mod:`aerohrl.api`, re-exported here)::

    import aerohrl

    ds = aerohrl.build_dataset(goals=250)                  # expert data, LeRobot v3.0
    run = aerohrl.train({"algo": "gcsl", "dataset": ds})   # offline goal-conditioned RL
    policy = aerohrl.load_policy(run)                      # policy.act(state, goal) -> CTBR action
    summary = aerohrl.evaluate(run, "reach-desired")       # closed loop in the simulator
    env = aerohrl.make_env()                               # the Gymnasium goal env

One import namespace over the repository's folders:
``aerohrl.sim`` (sim/), ``aerohrl.datagen`` (datagen/), ``aerohrl.envs`` (envs/),
``aerohrl.algorithms`` (algorithms/), ``aerohrl.planning`` (planning/), ``aerohrl.eval``
(eval/), ``aerohrl.ipp`` (ipp/). This package itself holds what every stage shares: the
user-facing error type (:mod:`aerohrl.errors`) and the reach-task vocabulary
(:mod:`aerohrl.task`).

``import aerohrl`` is light: the API's functions load numpy, torch or lerobot when
called. It also registers the Gymnasium environments (``aerohrl/QuadrotorReach-v0``,
``aerohrl/IPPSearch-v0``; :func:`aerohrl.envs.register`) without importing Gymnasium
itself: right away when Gymnasium is already imported, else the moment it is, so ``gymnasium.make("aerohrl/QuadrotorReach-v0")`` works after
``import aerohrl`` in either order, and ``gymnasium.make("aerohrl:aerohrl/QuadrotorReach-v0")``
works with no import at all (Gymnasium 1.x imports the module named before the colon;
it has no entry-point plugins any more).
"""

from __future__ import annotations

import importlib.util
import sys
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

_API = ("build_dataset", "load_dataset", "train", "Run", "load_policy", "Policy", "evaluate", "make_env")

if TYPE_CHECKING:  # pragma: no cover
    from aerohrl.api import Policy, Run, build_dataset, evaluate, load_dataset, load_policy, make_env, train


def __getattr__(name: str) -> Any:  # PEP 562: the API is imported on first use
    if name in _API:
        from aerohrl import api

        return getattr(api, name)
    raise AttributeError(f"module 'aerohrl' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(list(globals()) + list(_API))


# ----------------------------------------------------------------------------- Gymnasium

ENV_ID = "aerohrl/QuadrotorReach-v0"  # = aerohrl.envs.REACH_ID


def _register_env() -> None:
    """Register the project's Gymnasium ids by name (:func:`aerohrl.envs.register`; an env
    module loads on ``make``)."""
    from aerohrl.envs import register

    register()


class _AfterGymnasiumImport:  # a MetaPathFinder and Loader (duck-typed: importlib.abc costs 35 ms)
    """A post-import hook: once ``gymnasium`` has been imported (by anyone), register the envs.

    It stays in ``sys.meta_path`` until that import has run: a mere
    ``importlib.util.find_spec("gymnasium")`` (torchrl makes one) also asks it."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname != "gymnasium":
            return None
        from importlib.machinery import PathFinder

        spec = PathFinder.find_spec(fullname, path)
        if spec is None or spec.loader is None:
            return None  # let the other finders try (and fail) as usual
        self._loader = spec.loader
        spec.loader = self
        return spec

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        module.__loader__ = module.__spec__.loader = self._loader  # gymnasium sees its own loader
        self._loader.exec_module(module)
        if self in sys.meta_path:
            sys.meta_path.remove(self)
        try:
            _register_env()
        except Exception:  # pragma: no cover - never break the user's `import gymnasium`
            pass


if "gymnasium" in sys.modules:
    _register_env()
elif importlib.util.find_spec("gymnasium") is not None:
    sys.meta_path.insert(0, _AfterGymnasiumImport())

__all__ = ["__version__", "ENV_ID", *_API]
