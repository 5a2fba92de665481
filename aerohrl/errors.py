"""The one error type a user sees.

Every command-line entry point catches :class:`UserError` (and a few standard ones,
see :func:`run_cli`) and prints ``<prog>: error: <message>`` on one line with a
non-zero exit instead of a traceback. Code raises it for anything the user can fix:
bad flags, missing or damaged files, inconsistent inputs.
"""

from __future__ import annotations

import argparse
import sys
from typing import Callable


class UserError(Exception):
    """Bad input or a damaged file: reported in one line, exit status 2."""

    exit_code = 2


def run_cli(prog: str, fn: Callable[[], int | None]) -> int:
    """Run ``fn`` and turn expected failures into one-line errors and exit codes."""
    try:
        return int(fn() or 0)
    except UserError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; nothing partial was kept", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0


class ArgumentParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (``prog: error: ...``) and exit status 2."""

    def error(self, message: str):  # noqa: D401 - argparse API
        print(f"{self.prog}: error: {message} (see --help)", file=sys.stderr)
        sys.exit(2)
