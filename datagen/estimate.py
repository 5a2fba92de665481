"""What a build will need, before it starts: frames, disk and memory.

``datagen build`` prints :func:`estimate`'s figures and refuses (one line, unless
``--force``) a build that would not fit in the memory or on the disk free now, instead
of growing until the machine gives out. The episode length comes from minimum-time
references solved for a sample of the spec's own goals (milliseconds); the bytes per
frame were measured on this project's builds (README "Speed"):

* disk: 190 bytes per frame (zstd parquet + metadata; 250 to 10,000 goals);
* memory: the recorded frames (float64 while flown, then the float32 columns and
  pyarrow's buffers), 650 bytes per frame with the action-noise column (measured
  100,000 goals with noise: 20.66 M frames, peak RSS 13.98 GB, `bench/bench_datagen.py`),
  plus one rollout block's buffers (``build.ROLLOUT_BLOCK`` episodes x the longest
  episode x 26 float64) and the interpreter's ~200 MB.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DISK_BYTES_PER_FRAME = 195
MEMORY_BYTES_PER_FRAME = 650
MEMORY_BASE = 200e6
BLOCK_BYTES_PER_EPISODE_STEP = 26 * 8  # states (18) + actions (4) + expert actions (4), float64
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
    from aerohrl.datagen.build import ROLLOUT_BLOCK

    steps = np.ceil(T * spec.fps - 1e-9)
    episodes = spec.goals * spec.rollouts_per_goal + spec.continuations
    frames = int(round(episodes * float(steps.mean())))
    block = min(episodes, ROLLOUT_BLOCK) * (spec.t_max * spec.fps + 1) * BLOCK_BYTES_PER_EPISODE_STEP
    return Estimate(episodes, frames, frames * DISK_BYTES_PER_FRAME, MEMORY_BASE + block + frames * MEMORY_BYTES_PER_FRAME)


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
