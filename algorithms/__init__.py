"""Offline goal-conditioned RL on torchrl (thesis §3.4.2)."""

from __future__ import annotations


def quiet_torchrl() -> None:
    """Keep torchrl's logger at WARNING (call after importing torchrl).

    torchrl's import gives its ``"torchrl"`` logger its own stdout handler at level INFO
    (``torchrl/_utils.py``), so lines such as ``Initialized TensorStorage ...`` would
    reach the user's terminal from inside the trainer. Setting ``RL_LOGGING_LEVEL``
    (torchrl's own switch) keeps whatever level the user chose."""
    import logging
    import os

    if "RL_LOGGING_LEVEL" not in os.environ:
        logging.getLogger("torchrl").setLevel(logging.WARNING)
