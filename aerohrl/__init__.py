"""aerohrl: hierarchical reinforcement learning for aerial vehicles.

One import namespace over the repository's folders:
``aerohrl.sim`` (sim/), ``aerohrl.datagen`` (datagen/), ``aerohrl.algorithms``
(algorithms/), ``aerohrl.eval`` (eval/), ``aerohrl.ipp`` (ipp/). This package itself
holds what every stage shares: the user-facing error type and the reach-task
vocabulary (:mod:`aerohrl.task`).
"""

__version__ = "0.1.0"
