"""Ray for the commands that fan work out (``aerohrl sweep``, ``datagen build --ray-address``):
join a cluster or start a local Ray, with the settings both need."""

from __future__ import annotations

import contextlib
import os
import socket
import sys
from typing import Any

from aerohrl.errors import UserError


def ray_connect(address: str | None = None, num_cpus: int | None = None, num_gpus: int | None = None) -> Any:
    """``ray`` initialised: joined to the cluster at ``address`` (``host:port`` or
    ``auto``; unreachable -> UserError), or a local Ray of ``num_cpus`` cores, no
    dashboard, a 500 MB object store."""
    import ray  # [train]; missing: run_cli's one line "this needs ray ... pip install 'aerohrl[train]'"

    if ray.is_initialized():
        return ray
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    os.environ.setdefault("RAY_DEDUP_LOGS", "0")
    # Ray starts its workers at niceness 15 (its raylet's worker_niceness), to keep a driver
    # responsive; here the tasks are the work itself, and beside any ordinary process at
    # niceness 0 they starve (a sweep's runs train several times slower beside other jobs).
    # Workers of a local Ray (whose raylet inherits this environment) run at the caller's
    # priority; on a cluster, start the nodes with RAY_worker_niceness=0 (docs/cluster.md).
    os.environ.setdefault("RAY_worker_niceness", "0")
    if address:
        if address != "auto":
            host, _, port = address.removeprefix("ray://").rpartition(":")
            try:
                with socket.create_connection((host or "127.0.0.1", int(port)), timeout=5):
                    pass
            except (OSError, ValueError) as e:
                raise UserError(f"cannot reach a Ray cluster at {address}: {getattr(e, 'strerror', None) or e}") from None
        try:
            with _quiet_stderr():  # Ray's C++ client logs each failed attempt to fd 2: one error line instead
                ray.init(address=address, log_to_driver=True, logging_level="ERROR")  # type: ignore[arg-type]  # ray annotates int; logging takes level names too
        except (ConnectionError, RuntimeError, ValueError) as e:
            raise UserError(f"cannot join the Ray cluster at {address}: {str(e).splitlines()[0]}") from None
    else:
        ray.init(
            num_cpus=num_cpus,
            num_gpus=num_gpus,
            include_dashboard=False,
            object_store_memory=500 * 2**20,
            logging_level="ERROR",  # type: ignore[arg-type]  # ray annotates int; logging takes level names too
            log_to_driver=True,
        )
    return ray


@contextlib.contextmanager
def _quiet_stderr():
    """File descriptor 2 to /dev/null for the duration (also what C++ code writes)."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)


__all__ = ["ray_connect"]
