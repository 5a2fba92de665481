"""The common command-line vocabulary, added to every parser by one helper.

Every command takes, where it means something, the same five flags with the same
meaning (README "Command-line conventions")::

    --out PATH       where results go (-o is its short form)
    --quiet          no progress bars (they are drawn on terminals only anyway)
    --threads N      torch / OpenMP threads of this process
    --seed N         random seed (>= 0)
    --device DEV     cpu | cuda | cuda:N

:func:`add_common` adds them (only those asked for, each with the command's default
and help) and the old spellings each command had before (``--no-progress``,
``--run-dir``, ``--out-dir``, ``--output``), hidden from ``--help``; an old spelling
still works for one release and prints one line on stderr,
``train: --no-progress is deprecated, use --quiet``.

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


class _Deprecated(argparse.Action):
    """An old spelling of a flag: stores like the new one and says so on stderr, once per use."""

    def __init__(self, option_strings, dest, new: str = "", const=None, nargs=None, **kw):
        self.new = new
        super().__init__(option_strings, dest, nargs=nargs, const=const, **kw)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog}: {option_string} is deprecated, use {self.new}", file=sys.stderr)
        setattr(namespace, self.dest, self.const if self.nargs == 0 else values)


def deprecated(p: argparse.ArgumentParser, old: str, new: str, dest: str, *, flag: bool = False,
               type: Callable[[str], Any] | None = None) -> None:
    """``old`` as a hidden alias of ``new`` (same ``dest``): it works and prints a deprecation note.
    ``flag``: a switch (no value; stores True)."""
    kw: dict[str, Any] = {"nargs": 0, "const": True} if flag else {"type": type}
    p.add_argument(old, dest=dest, action=_Deprecated, new=new, help=argparse.SUPPRESS, default=argparse.SUPPRESS, **kw)


def add_common(p: argparse.ArgumentParser, *, out: dict | None = None, quiet: bool = False, threads: dict | None = None,
               seed: dict | None = None, device: dict | None = None, old_out: tuple[str, ...] = (),
               old_quiet: tuple[str, ...] = ()) -> argparse.ArgumentParser:
    """Add the common flags to ``p``: each given dict holds the command's argparse keywords
    for that flag (``default``, ``help``, ``type``, ``required``...), on top of these defaults:

    - ``out``: ``-o/--out PATH`` (type Path); ``old_out`` lists old spellings (``--run-dir``).
    - ``quiet``: ``--quiet`` (dest ``quiet``); ``old_quiet`` lists old spellings (``--no-progress``).
    - ``threads``: ``--threads N`` (>= 1) [default None: torch's and OpenMP's own].
    - ``seed``: ``--seed N`` (>= 0) [0].
    - ``device``: ``--device DEV`` [cpu].
    """
    if out is not None:
        kw = {"type": Path, "default": None, "metavar": "PATH", **out}
        short = ("-o",) if kw.pop("short", True) else ()
        if kw.get("required") and old_out:  # argparse would not count the old spelling: errors.ArgumentParser checks it
            kw["required"] = False
            kw["help"] = kw.get("help", "") + " (required)"
            p.required_dests = [*getattr(p, "required_dests", ()), ("out", "-o/--out")]  # type: ignore[attr-defined]
        p.add_argument(*short, "--out", dest="out", **kw)
        for o in old_out:
            deprecated(p, o, "--out", "out", type=kw["type"])
    if quiet:
        p.add_argument("--quiet", dest="quiet", action="store_true", default=False,
                       help="no progress bars (drawn on terminals only anyway)")
        for o in old_quiet:
            deprecated(p, o, "--quiet", "quiet", flag=True)
    if threads is not None:
        kw = {"type": T.positive_int, "default": None, "metavar": "N", **threads}
        kw.setdefault("help", "torch and OpenMP threads of this process" +
                      (f" [{kw['default']}]" if kw["default"] is not None else " [their own default: all cores]"))
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


__all__ = ["COMMON", "add_common", "add_run", "deprecated", "set_threads", "progress", "run_name", "toml_value", "to_toml"]
