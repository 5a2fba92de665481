"""Evaluation harness and goal planner (thesis §3.4.3-3.5)."""
