"""Offline goal-conditioned RL on torchrl (thesis §3.4.2)."""
