"""What more than one study script needs: running a command line the way every study does.

Imported by the scripts of this folder as ``from study_tools import ...`` (a script's own
folder is on ``sys.path`` when it runs as ``python experiments/NAME.py``).
"""

from __future__ import annotations

import os
import subprocess
from typing import TextIO

from aerohrl.errors import UserError


def run_logged(cmd: list[str], log: TextIO) -> str:
    """Run a command line with one thread, its output appended to ``log``; its output, or a
    one-line UserError when it fails."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    print("+ " + " ".join(cmd), flush=True)
    p = subprocess.run(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    log.write("+ " + " ".join(cmd) + "\n" + p.stdout + "\n")
    log.flush()
    if p.returncode != 0:
        tail = p.stdout.strip().splitlines()[-1:] or ["(no output)"]
        raise UserError(f"`{' '.join(cmd[:4])} ...` failed (exit {p.returncode}): {tail[0]}")
    return p.stdout


__all__ = ["run_logged"]
