"""The high level over skills (thesis §3.4.3-3.4.4): intermediate goals for a trained policy.

Modules: :mod:`.planner` (Eq. 3.7 / 3.6 over the dataset's achieved goals, chains of
synthetic waypoints, declining) and :mod:`.oracle` (what any single-intermediate-goal
planner could reach with a policy, found by flying). The closed loop that flies a plan
is :func:`aerohrl.envs.rollout.rollout`; ``aerohrl eval`` puts the two together."""
