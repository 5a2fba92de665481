"""What a build will need, before it starts: frames, disk and memory.

``datagen build`` prints :func:`estimate`'s figures and refuses (one line, unless
``--force``) a build that would not fit in the memory or on the disk free now, instead
of growing until the machine gives out. The episode length comes from minimum-time
references solved for a sample of the spec's own goals (milliseconds); the bytes per
frame were measured on this project's builds (README "Speed"):

* disk: 190 bytes per frame (zstd parquet + metadata; 250 to 10,000 goals);
* memory: 810 bytes per frame above the interpreter's ~150 MB at peak (rollout arrays,
  recorded frames, the float32 columns and pyarrow's buffers); 1,000 bytes per frame
  and 200 MB are used, which also covers continuation episodes (measured 2,500 + 2,500:
  1.26 GB, estimated 1.28 GB).
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DISK_BYTES_PER_FRAME = 195
MEMORY_BYTES_PER_FRAME = 1000
MEMORY_BASE = 200e6
SAMPLE_GOALS = 128


@dataclass(frozen=True)
class Estimate:
    episodes: int
    frames: int
    disk: float  # bytes
    memory: float  # bytes


def estimate(spec) -> Estimate:
    """Expected frames, disk and peak memory of building ``spec`` (from a sample of its goals)."""
    from aerohrl.datagen.build import plan_references

    n = min(spec.goals, SAMPLE_GOALS)
    _, T, _, _, _ = plan_references(spec, np.random.default_rng([spec.seed, 99]), n)
    per_episode = float(np.ceil(T * spec.fps - 1e-9).mean())
    episodes = spec.goals + spec.continuations
    frames = int(round(episodes * per_episode))
    return Estimate(episodes, frames, frames * DISK_BYTES_PER_FRAME, MEMORY_BASE + frames * MEMORY_BYTES_PER_FRAME)


def available_memory() -> float:
    """Bytes this process can still allocate: MemAvailable, capped by a cgroup v2 limit."""
    avail = float("inf")
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail = int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        used = int(Path("/sys/fs/cgroup/memory.current").read_text())
        if limit != "max":
            avail = min(avail, int(limit) - used)
    except (OSError, ValueError):
        pass
    return float(avail)


def available_disk(folder) -> float:
    """Free bytes on the file system of ``folder`` (its nearest existing ancestor)."""
    p = Path(folder).absolute()
    while not p.exists():
        p = p.parent
    return float(shutil.disk_usage(p).free)


def human(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if abs(n) < 1000 or unit == "PB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} PB"


def shortfall(est: Estimate, memory: float, disk: float) -> str | None:
    """Why ``est`` does not fit in ``memory`` and ``disk`` bytes, or None."""
    short = [f"{human(need)} of {what} ({human(free)} {verb})" for what, need, free, verb in
             (("memory", est.memory, memory, "available"), ("disk", est.disk, disk, "free")) if need > free]
    return " and ".join(short) or None


__all__ = ["Estimate", "estimate", "available_memory", "available_disk", "shortfall", "human"]
