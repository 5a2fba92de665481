"""The common command-line vocabulary, added to every parser by one helper.

Every command takes, where it means something, the same five flags with the same
meaning (README "Command-line conventions")::

    --out PATH       where results go (-o is its short form)
    --quiet          no progress bars (they are drawn on terminals only anyway)
    --threads N      torch / OpenMP threads of this process
    --seed N         random seed (>= 0)
    --device DEV     cpu | cuda | cuda:N

:func:`add_common` adds them (only those asked for, each with the command's default
and help).

This module imports nothing heavy: ``--help`` of every command stays under a second
(bench/bench_cli_help.py). argparse stays (rather than tyro or draccus): the flags are
already generated from the config dataclasses, the one-line errors and parse-time
number checks (:mod:`aerohrl.cli_types`) hook into it, and draccus comes only with the
``[lerobot]`` extra, which ``datagen`` and ``train`` do not need.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any, Callable

from aerohrl import cli_types as T

COMMON = ("out", "quiet", "threads", "seed", "device")
DEVICE_HELP = "torch device: cpu | cuda | cuda:N"


def add_common(
    p: argparse.ArgumentParser,
    *,
    out: dict | None = None,
    quiet: bool = False,
    threads: dict | None = None,
    seed: dict | None = None,
    device: dict | None = None,
) -> argparse.ArgumentParser:
    """Add the common flags to ``p``: each given dict holds the command's argparse keywords
    for that flag (``default``, ``help``, ``type``, ``required``...), on top of these defaults:

    - ``out``: ``-o/--out PATH`` (type Path).
    - ``quiet``: ``--quiet`` (dest ``quiet``).
    - ``threads``: ``--threads N`` (>= 1) [default None: torch's and OpenMP's own].
    - ``seed``: ``--seed N`` (>= 0) [0].
    - ``device``: ``--device DEV`` [cpu].
    """
    if out is not None:
        kw = {"type": Path, "default": None, "metavar": "PATH", **out}
        short = ("-o",) if kw.pop("short", True) else ()
        p.add_argument(*short, "--out", dest="out", **kw)
    if quiet:
        p.add_argument(
            "--quiet", dest="quiet", action="store_true", default=False, help="no progress bars (drawn on terminals only anyway)"
        )
    if threads is not None:
        kw = {"type": T.positive_int, "default": None, "metavar": "N", **threads}
        kw.setdefault(
            "help",
            "torch and OpenMP threads of this process"
            + (f" [{kw['default']}]" if kw["default"] is not None else " [their own default: all cores]"),
        )
        p.add_argument("--threads", dest="threads", **kw)
    if seed is not None:
        kw = {"type": T.nonneg_int, "default": 0, "metavar": "N", **seed}
        kw.setdefault("help", f"random seed (>= 0) [{kw['default']}]")
        p.add_argument("--seed", dest="seed", **kw)
    if device is not None:
        kw = {"default": "cpu", "metavar": "DEV", **device}
        kw.setdefault("help", f"{DEVICE_HELP} [{kw['default']}]")
        p.add_argument("--device", dest="device", **kw)
    return p


def add_run(p: argparse.ArgumentParser, *, help: str, type: Callable[[str], Any] = Path) -> None:
    """The run a command reads, as ``RUN`` or ``--run RUN`` (``aerohrl eval``'s spelling), either one;
    checked by :class:`aerohrl.errors.ArgumentParser` (``p`` must be one)."""
    p.add_argument("run", nargs="?", type=type, default=None, metavar="RUN", help=f"{help} (or --run RUN)")
    p.add_argument("--run", dest="run_flag", type=type, default=None, metavar="RUN", help="the same, as a flag")
    p.run_positional = True  # type: ignore[attr-defined]


def set_threads(n: int | None, *, torch: bool = True) -> None:
    """``--threads N``: the OpenMP/BLAS threads of the processes started from here on (and
    of this one, when called before numpy is imported) and, with ``torch``, torch's
    intra-op threads (importing torch if needed). None: leave the defaults."""
    if n is None:
        return
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = str(n)
    if not torch:
        return
    _set_torch_threads(n)


def _set_torch_threads(n: int) -> None:
    try:
        import torch  # the commands that take --threads use it anyway; a core install lacks it
    except ModuleNotFoundError:
        return
    torch.set_num_threads(n)


def progress(quiet: bool) -> bool:
    """Progress bars: on a terminal, unless ``--quiet``."""
    return not quiet and sys.stderr.isatty()


# ----------------------------------------------------------------------------- run names


def run_name(*parts: Any, seed: int | None = None) -> str:
    """The default name of a new run, the same shape in every command:
    ``PART-PART-sSEED-YYYYMMDD-HHMMSS-XXXXXX`` (UTC; the random suffix keeps runs started
    in one second apart)."""
    import secrets
    from datetime import datetime, timezone

    stamp = datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")
    head = [str(x) for x in parts if x not in (None, "")] + ([f"s{seed}"] if seed is not None else [])
    return "-".join(head + [stamp, secrets.token_hex(3)])


# ----------------------------------------------------------------------------- TOML


def toml_value(v: Any) -> str:
    """A TOML value for the flat configs we write (bool, int, float, str, lists of them).
    tomllib reads TOML since Python 3.11 but nothing in the standard library writes it;
    these few lines spare a dependency (tomli_w) for the flat tables we save."""
    import math

    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return repr(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("nan" if v != v else ("inf" if v > 0 else "-inf"))
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string is a TOML basic string
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as TOML")


def to_toml(values: dict, header: str = "") -> str:
    """A flat TOML document of ``values`` (top-level keys only), with ``header`` comment lines."""
    lines = [f"# {h}" for h in header.splitlines()]
    lines += [f"{k} = {toml_value(v)}" for k, v in values.items()]
    return "\n".join(lines) + "\n"


__all__ = ["COMMON", "add_common", "add_run", "set_threads", "progress", "run_name", "toml_value", "to_toml"]
