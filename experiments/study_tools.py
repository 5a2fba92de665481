"""What more than one study script needs: running a command line the way every study does.

Imported by the scripts of this folder as ``from study_tools import ...`` (a script's own
folder is on ``sys.path`` when it runs as ``python experiments/NAME.py``).
"""

from __future__ import annotations

import contextlib
import importlib
import io
import os
import subprocess
import sys
import traceback
from typing import TextIO

from aerohrl.errors import UserError

THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")


def run_logged(cmd: list[str], log: TextIO, in_process: bool = False) -> str:
    """Run a command line with one thread, its output appended to ``log``; its output, or a
    one-line UserError when it fails.

    ``in_process``: a ``PYTHON -m MODULE ARGS...`` command line runs as ``MODULE.main(ARGS)``
    in this interpreter instead (the same output, stdout and stderr together, and the same
    exit status), which saves a new interpreter's start-up (imports, torch) per command; any
    other command line still runs as a subprocess."""
    print("+ " + " ".join(cmd), flush=True)
    if in_process and len(cmd) > 2 and cmd[1] == "-m":
        code, out = _call_main(cmd[2], cmd[3:])
    else:
        env = {**os.environ, **dict.fromkeys(THREAD_VARS, "1")}
        p = subprocess.run(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        code, out = p.returncode, p.stdout
    log.write("+ " + " ".join(cmd) + "\n" + out + "\n")
    log.flush()
    if code != 0:
        tail = out.strip().splitlines()[-1:] or ["(no output)"]
        raise UserError(f"`{' '.join(cmd[:4])} ...` failed (exit {code}): {tail[0]}")
    return out


def _call_main(module: str, argv: list[str]) -> tuple[int, str]:
    """``MODULE.main(argv)`` with one thread (the environment's thread counts and torch's
    intra-op threads, restored afterwards) and its stdout and stderr captured; (exit status,
    output), an uncaught exception's traceback in the output and status 1 as the interpreter
    would have it."""
    try:
        import torch
    except ModuleNotFoundError:  # a core install: the command imports no torch either
        torch = None  # type: ignore[assignment]
    saved_env = {k: os.environ.get(k) for k in THREAD_VARS}
    saved_threads = torch.get_num_threads() if torch is not None else None
    os.environ.update(dict.fromkeys(THREAD_VARS, "1"))
    if torch is not None:
        torch.set_num_threads(1)
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            try:
                code = importlib.import_module(module).main(argv)
            except SystemExit as e:  # argparse's usage errors, sys.exit(...)
                code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
            except Exception:
                traceback.print_exc(file=sys.stderr)
                code = 1
    finally:
        for k, v in saved_env.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        if torch is not None and saved_threads is not None:
            torch.set_num_threads(saved_threads)
    return int(code or 0), buf.getvalue()


__all__ = ["run_logged"]
