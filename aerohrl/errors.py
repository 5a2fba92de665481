"""How errors reach a user: one line, never a traceback.

Library code raises ``ValueError`` or ``TypeError`` (or subclasses) for anything the
caller can fix: bad values, missing or damaged files, inconsistent inputs. Code that
reads the user's files and flags raises :class:`UserError`, a ``ValueError`` whose
message is written for the command line; planners, environments and the simulator raise
plain ``ValueError``. Every command-line entry point runs through :func:`run_cli`, which
turns both (and a few standard failures: interrupts, broken pipes, any ``OSError`` such
as a full disk) into ``<prog>: error: <message>`` on one line with a non-zero exit;
``AEROHRL_TRACEBACK=1`` shows the traceback of a ``ValueError``/``TypeError`` instead.
:func:`warn` prints ``<prog>: warning: <message>`` and goes on.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any, Callable, NoReturn, Sequence


class UserError(ValueError):
    """Bad input or a damaged file: reported in one line, exit status 2."""

    exit_code = 2


_prog = "aerohrl"  # the running command, for warnings (set by run_cli)

# top-level modules of the optional extras (pyproject.toml) -> the extra that installs them
EXTRAS = {
    "torch": "train",
    "torchrl": "train",
    "tensordict": "train",
    "cmaes": "train",
    "ray": "train",
    "tensorboard": "train",
    "lerobot": "lerobot",
    "datasets": "lerobot",
    "minari": "exchange",
    "onnx": "export",
    "onnxruntime": "export",
    "ogbench": "exchange",
}


def warn(message: str) -> None:
    """One line ``<prog>: warning: <message>`` on stderr: something is off, the command goes on."""
    print(f"{_prog}: warning: {message}", file=sys.stderr)


def run_cli(prog: str, fn: Callable[[], int | None]) -> int:
    """Run ``fn`` and turn expected failures into one-line errors and exit codes."""
    global _prog
    _prog = prog
    try:
        return int(fn() or 0)
    except UserError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return e.exit_code
    except (ValueError, TypeError) as e:  # a library's refusal of a value (planners, environments, the simulator)
        if os.environ.get("AEROHRL_TRACEBACK"):
            raise
        print(f"{prog}: error: {str(e).splitlines()[0] if str(e) else type(e).__name__}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as e:  # an optional dependency of a core-only install (pyproject extras)
        extra = EXTRAS.get((e.name or "").split(".")[0])
        if extra is None:
            raise
        print(f"{prog}: error: this needs {e.name}, which is not installed: pip install 'aerohrl[{extra}]'", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; nothing partial was kept", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except OSError as e:  # a write the atomic helpers did not make (a log line on a full disk), a vanished file
        where = f"{e.filename}: " if e.filename else ""
        print(f"{prog}: error: {where}{e.strerror or e}", file=sys.stderr)
        return 2


class ArgumentParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (``prog: error: ...``) and exit status 2."""

    def error(self, message: str) -> NoReturn:  # noqa: D401 - argparse API
        """Print ``PROG: error: MESSAGE (see --help)`` and exit with status 2."""
        print(f"{self.prog}: error: {message} (see --help)", file=sys.stderr)
        sys.exit(2)

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: Any = None
    ) -> tuple[Any, list[str]]:
        """``argparse``'s parse, then the run given as ``RUN`` or ``--run RUN`` merged into
        ``namespace.run`` (two different runs -> error)."""
        namespace, extras = super().parse_known_args(args, namespace)
        if getattr(self, "run_positional", False):  # RUN or --run RUN (aerohrl.cli_common.add_run)
            flag = namespace.__dict__.pop("run_flag", None)
            if flag is not None and namespace.run is not None and flag != namespace.run:
                self.error(f"two runs given: {namespace.run} and --run {flag}")
            namespace.run = namespace.run if flag is None else flag
            if namespace.run is None:
                self.error("the following arguments are required: RUN (or --run RUN)")
        return namespace, extras
