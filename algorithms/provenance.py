"""What a run records about where it came from (``config.json`` -> ``provenance``).

The code version (git commit, and whether the work tree had uncommitted changes), the
versions of the packages that decide the numbers (python, torch, torchrl, tensordict,
lerobot, numpy), the machine (CPU model, GPU model when training on CUDA, host) and the
thread count torch uses. Nothing here can fail a run: what cannot be found is recorded
as ``None``.
"""

from __future__ import annotations

import os
import platform
import socket
import subprocess
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

PACKAGES = ("torch", "torchrl", "tensordict", "lerobot", "numpy")


def git_state(where: Path | None = None) -> dict:
    """``{"commit", "dirty"}`` of the git work tree holding this package (None, None when
    the package is not installed from a checkout, or git is missing)."""
    where = Path(where or Path(__file__).resolve().parent)

    def git(*args):
        return subprocess.run(["git", "-C", str(where), *args], capture_output=True, text=True, timeout=20)

    try:
        head = git("rev-parse", "HEAD")
        if head.returncode != 0:
            return {"commit": None, "dirty": None}
        status = git("status", "--porcelain", "--untracked-files=no")
        dirty = bool(status.stdout.strip()) if status.returncode == 0 else None
        return {"commit": head.stdout.strip(), "dirty": dirty}
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}


def package_versions() -> dict:
    """Python's and every package of ``PACKAGES``'s installed version (None when absent)."""
    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def cpu_model() -> str | None:
    """The CPU's model name (``/proc/cpuinfo``, else ``platform.processor()``); None if unknown."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def device_info(device: str = "cpu") -> dict:
    """The training device, CPU model and count, torch and OpenMP threads, and the GPU's name
    when ``device`` is CUDA: what a run records for its timings."""
    import torch

    info = {
        "device": str(device),
        "cpu": cpu_model(),
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "gpu": None,
    }
    if str(device).startswith("cuda") and torch.cuda.is_available():
        dev = torch.device(device)
        info["gpu"] = torch.cuda.get_device_name(dev.index if dev.index is not None else torch.cuda.current_device())
        info["cuda"] = torch.version.cuda
    return info


def provenance(device: str = "cpu") -> dict:
    """Everything above, with the host and the time it was taken."""
    return {
        "git": git_state(),
        "versions": package_versions(),
        "machine": {**device_info(device), "host": socket.gethostname(), "platform": platform.platform()},
        "time": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
