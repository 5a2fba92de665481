"""What a build will need, before it starts: frames, disk and memory.

``datagen build`` prints :func:`estimate`'s figures and refuses (one line, unless
``--force``) a build that would not fit in the memory or on the disk free now, instead
of growing until the machine gives out. The episode length comes from minimum-time
references solved for a sample of the spec's own goals (milliseconds); the bytes per
frame were measured on this project's builds (README "Speed"):

* disk: 190 bytes per frame (zstd parquet + metadata; 250 to 10,000 goals);
* memory: ``datagen build`` streams (``build.stream_dataset``): each rollout block's
  frames are written as the block lands, so the peak is one block's working set
  (``build.ROLLOUT_BLOCK`` episodes: the rollout buffers, episodes x the longest episode x
  26 float64, plus the block's recorded frames at :data:`STREAM_BYTES_PER_FRAME`, measured),
  per worker with ``--workers``; plus :data:`EPISODE_BYTES` per episode (goals, references
  and per-episode results, measured on 50,000 and 200,000 goals), 4 bytes per frame for
  the dataset statistics (one feature dimension sorted at a time) and the interpreter's
  ~200 MB. Measured with noise (README "Speed", `bench/bench_datagen.py`): peak RSS
  0.99 / 1.40 / 1.56 GB at 10,000 / 25,000 / 50,000 goals (blocks of 5,000 / 6,250 /
  7,143 episodes; the estimate says 1.2 / 1.5 / 1.7 GB). A spec with
  continuations keeps every frame of its rest-start flights (their starts are drawn from
  them): :data:`MEMORY_BYTES_PER_FRAME` per frame, as before streaming (100,000 goals with
  noise: 20.66 M frames, peak RSS 13.98 GB);
* scratch disk: the statistics spill, one feature at a time read back from the data
  files (the widest, 18 dimensions x 4 bytes per frame), deleted as used (on the same
  file system as the output). A spec whose statistics are the streamed sketch
  (``spec.stats_mode == "sketch"``) has no spill and sorts nothing at the end; it holds
  the merged histograms instead (:data:`SKETCH_BYTES`).
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from aerohrl.datagen.spec import DatasetSpec

DISK_BYTES_PER_FRAME = 195
MEMORY_BYTES_PER_FRAME = 650
MEMORY_BASE = 200e6
BLOCK_BYTES_PER_EPISODE_STEP = 26 * 8  # states (18) + actions (4) + expert actions (4), float64
STREAM_BYTES_PER_FRAME = (
    550  # a block's recorded frames in flight (float64 gathers, float32 columns, stats temporaries; 350-500 measured)
)
EPISODE_BYTES = 800  # per episode for the whole build (goals, coefficients, per-episode results)
STATS_BYTES_PER_FRAME = 4  # one float32 feature dimension sorted at a time
SPILL_DIMS = 18  # the widest feature (observation.state): the statistics spill holds one feature at a time
SAMPLE_GOALS = 128
# the merged quantile histograms of the streamed statistics: 2**20 int32 counts per
# feature dimension (62 dimensions with action noise)
SKETCH_BYTES = 62 * (1 << 20) * 4


@dataclass(frozen=True)
class Estimate:
    episodes: int
    frames: int
    disk: float  # bytes
    memory: float  # bytes
    scratch: float = 0.0  # temporary disk bytes during the build (the statistics spill)


def estimate(spec: DatasetSpec, workers: int = 1) -> Estimate:
    """Expected frames, disk and peak memory of building ``spec`` (from a sample of its
    goals) with ``workers`` processes flying the blocks."""
    from aerohrl.datagen.build import ROLLOUT_BLOCK, block_bounds, plan_references

    if not spec.reach:
        return _estimate_maze(spec)
    n = min(spec.goals, SAMPLE_GOALS)
    _, T, _, _, _ = plan_references(spec, np.random.default_rng([spec.seed, 99]), n)
    steps = np.ceil(T * spec.fps - 1e-9)
    episodes = spec.goals * spec.rollouts_per_goal + spec.continuations
    frames = int(round(episodes * float(steps.mean())))
    block_eps = min(episodes, ROLLOUT_BLOCK)
    if episodes > ROLLOUT_BLOCK:
        block_eps = int(np.diff(block_bounds(episodes)).max())
    block = block_eps * (spec.t_max * spec.fps + 1) * BLOCK_BYTES_PER_EPISODE_STEP
    sketch = spec.stats_mode == "sketch"
    spill = 0 if sketch else frames * 4 * SPILL_DIMS
    stats_memory = SKETCH_BYTES if sketch else frames * STATS_BYTES_PER_FRAME
    if spec.continuations:  # the rest-start flights' frames stay in memory
        memory = MEMORY_BASE + block + frames * MEMORY_BYTES_PER_FRAME
    else:
        in_flight = max(1, int(workers))
        memory = (
            MEMORY_BASE
            + in_flight * (block + block_eps * float(steps.mean()) * STREAM_BYTES_PER_FRAME)
            + episodes * EPISODE_BYTES
            + stats_memory
        )
    return Estimate(episodes, frames, frames * DISK_BYTES_PER_FRAME, memory, spill)


def _estimate_maze(spec: DatasetSpec) -> Estimate:
    """The maze families and exploration (datagen/maze_build.py): the episode lengths of a
    sample of the spec's own episodes (explore: the full flight length, an upper bound);
    memory is one block of :data:`aerohrl.datagen.maze_build.BLOCK_STEPS` episode-steps."""
    from aerohrl.datagen import maze_build

    steps = maze_build.plan(spec, min(spec.goals, SAMPLE_GOALS)).length
    frames = int(round(spec.goals * float(steps.mean())))
    block = min(maze_build.BLOCK_STEPS, spec.goals * int(steps.max())) * BLOCK_BYTES_PER_EPISODE_STEP
    sketch = spec.stats_mode == "sketch"
    stats_memory = SKETCH_BYTES if sketch else frames * STATS_BYTES_PER_FRAME
    memory = MEMORY_BASE + block + spec.goals * EPISODE_BYTES + stats_memory
    return Estimate(spec.goals, frames, frames * DISK_BYTES_PER_FRAME, memory, 0 if sketch else frames * 4 * SPILL_DIMS)


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


def available_disk(folder: str | Path) -> float:
    """Free bytes on the file system of ``folder`` (its nearest existing ancestor)."""
    p = Path(folder).absolute()
    while not p.exists():
        p = p.parent
    return float(shutil.disk_usage(p).free)


def human(n: float) -> str:
    """``n`` bytes as a short decimal size (``12.3 MB``)."""
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if abs(n) < 1000 or unit == "PB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} PB"


def shortfall(est: Estimate, memory: float, disk: float) -> str | None:
    """Why ``est`` does not fit in ``memory`` and ``disk`` bytes, or None."""
    short = [
        f"{human(need)} of {what} ({human(free)} {verb})"
        for what, need, free, verb in (
            ("memory", est.memory, memory, "available"),
            ("disk", est.disk + est.scratch, disk, "free"),
        )
        if need > free
    ]
    return " and ".join(short) or None


__all__ = ["Estimate", "estimate", "available_memory", "available_disk", "shortfall", "human"]
