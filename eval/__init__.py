"""Evaluation of training runs (thesis §3.4.3-3.5): task episode sets, the harness over a
run's checkpoints, robustness families, tables and plots.

The batched closed loop and the Gymnasium environment are :mod:`aerohrl.envs`, the
intermediate-goal planner is :mod:`aerohrl.planning`; this package imports them, never
the reverse. This file imports nothing, so ``import aerohrl.eval`` stays quick for the
command line."""
