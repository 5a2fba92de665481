"""Evaluation harness and goal planner (thesis §3.4.3-3.5).

The Gymnasium environment ``aerohrl/QuadrotorReach-v0`` (:mod:`aerohrl.eval.gym_env`) is
registered by ``import aerohrl`` itself (by name: this package is imported only when
the env is made), so ``import aerohrl.eval`` stays quick for the command line."""
