"""Evaluation harness and goal planner (thesis §3.4.3-3.5).

Importing the package registers the Gymnasium environment ``aerohrl/QuadrotorReach-v0``
(:mod:`aerohrl.eval.gym_env`)."""

try:  # gymnasium is a dependency; registration must never break `import aerohrl.eval`
    from aerohrl.eval.gym_env import register as _register

    _register()
except ImportError:  # pragma: no cover
    pass
