"""End-to-end `datagen build` wall time, and how it scales with the number of goals.

    python bench/bench_datagen.py                 # 250, 1000, 2500, 10000 goals
    python bench/bench_datagen.py --goals 250 1000
    python bench/bench_datagen.py --goals 10000 100000 --recipe --action-noise 1 0.5   # a recipe at scale

Each size runs the real command (`python -m aerohrl.datagen.cli build`) in a fresh
output directory, so interpreter start-up, imports and writing are all counted; the
peak resident memory is the children's (``resource.getrusage(RUSAGE_CHILDREN)``: the
maximum over the builds so far, rows smallest first; now that a build's peak no longer
grows with the goals, run one size per invocation to see each size's own); ``cpu s`` is
the child's user + system time, steadier than the wall time on a loaded machine.

Targets: 250 goals <= 10 s; 10,000 goals <= 3 min, cost linear in goals.

    python bench/bench_datagen.py --goals 1500                                   # free space, then
    python bench/bench_datagen.py --goals 250 --recipe --world maze-large --family navigate --action-noise 1 0.5

A maze dataset (``goals`` = episodes, each several times longer than a reach flight) is
compared with a free-space build of a similar frame count by the ``frames/s`` column;
target: a maze build at no less than half the free-space frames per second.

    python bench/bench_datagen.py --goals 20000 --workers 1 2     # sharded builds

``--workers`` runs every size with each worker count (``datagen build --workers N``:
rollout blocks of 8,192 episodes flown in N processes); the peak RSS is then also the
process tree's (parent + workers, summed from /proc every 0.1 s), and the speed-up is
against 1 worker, and ``cpu s`` is the user + system time of the build and its workers.
"""

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time


def _tree_rss(root: int) -> int:
    """Resident bytes of ``root`` and all its descendants (from /proc)."""
    kids: dict[int, list[int]] = {}
    rss: dict[int, int] = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{d}/statm") as f:
                rss[int(d)] = int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
        except (OSError, ValueError, IndexError):
            continue
        kids.setdefault(ppid, []).append(int(d))
    total, todo = 0, [root]
    while todo:
        p = todo.pop()
        total += rss.get(p, 0)
        todo += kids.get(p, [])
    return total


def run_build(args: list[str]) -> tuple[float, float, str, str]:
    """(wall s, peak tree RSS GB, stdout, stderr) of one build."""
    t0 = time.perf_counter()
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    peak = 0
    import threading

    out: dict = {}
    th = threading.Thread(target=lambda: out.update(zip(("o", "e"), p.communicate())))
    th.start()
    while th.is_alive():
        peak = max(peak, _tree_rss(p.pid))
        th.join(0.1)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        sys.exit(f"build failed: {out['e'].strip()}")
    return wall, peak / 1e9, out["o"], out["e"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--goals", type=int, nargs="+", default=[250, 1000, 2500, 10000])
    ap.add_argument("--workers", type=int, nargs="+", default=None, help="worker counts to compare (datagen build --workers)")
    ap.add_argument("--recipe", nargs=argparse.REMAINDER, default=[], help="datagen build flags of a recipe (last)")
    a = ap.parse_args()
    if a.workers:
        return sharded(a)
    from aerohrl.hardware import describe_cpu

    print(f"cpu: {describe_cpu()}   python: {sys.version.split()[0]}   recipe: {' '.join(a.recipe) or 'default'}")
    print(f"{'goals':>7} {'wall s':>8} {'ms/goal':>8} {'cpu s':>8} {'peak RSS GB':>12} {'frames/s':>9}  frames")
    rows = []
    for n in sorted(a.goals):
        with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_TMP")) as d:
            ru = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu0 = ru.ru_utime + ru.ru_stime
            t0 = time.perf_counter()
            p = subprocess.run(
                [sys.executable, "-m", "aerohrl.datagen.cli", "build", "--goals", str(n), "--out", d, "--quiet", *a.recipe],
                capture_output=True,
                text=True,
            )
            wall = time.perf_counter() - t0
            if p.returncode != 0:
                sys.exit(f"build failed: {p.stderr.strip()}")
            # the "built ...: N episodes, F frames" line (the estimate line before it is a guess)
            built = next((ln for ln in p.stdout.splitlines() if ln.startswith("built ")), p.stdout)
            frames = built.split(" frames")[0].rsplit(" ", 1)[-1]
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
        rss = ru.ru_maxrss / 1e6  # KB -> GB, max over children so far
        cpu = ru.ru_utime + ru.ru_stime - cpu0  # user + system seconds of this build (less sensitive to load than wall)
        rows.append((n, wall))
        rate = int(frames) / wall if frames.isdigit() else float("nan")
        print(f"{n:>7} {wall:>8.2f} {1000 * wall / n:>8.2f} {cpu:>8.1f} {rss:>12.2f} {rate:>9.0f}  {frames}", flush=True)
    if len(rows) >= 2:
        (n0, w0), (n1, w1) = rows[0], rows[-1]
        print(f"marginal cost {1000 * (w1 - w0) / (n1 - n0):.2f} ms/goal between {n0} and {n1} goals")


def sharded(a):
    from aerohrl.hardware import describe_cpu

    print(
        f"cpu: {describe_cpu()}   python: {sys.version.split()[0]}   recipe: {' '.join(a.recipe) or 'default'}   "
        f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}   load average at start: {os.getloadavg()[0]:.2f}"
    )
    print(
        f"{'goals':>7} {'workers':>7} {'wall s':>8} {'ms/goal':>8} {'cpu s':>8} {'speed-up':>8} {'peak RSS GB (tree)':>19}  frames"
    )
    for n in sorted(a.goals):
        base = None
        for w in a.workers:
            ru = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu0 = ru.ru_utime + ru.ru_stime
            with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_TMP")) as d:
                wall, rss, out, _ = run_build(
                    [
                        sys.executable,
                        "-m",
                        "aerohrl.datagen.cli",
                        "build",
                        "--goals",
                        str(n),
                        "--out",
                        d,
                        "--quiet",
                        "--workers",
                        str(w),
                        *a.recipe,
                    ]
                )
            ru = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = ru.ru_utime + ru.ru_stime - cpu0  # the build and its workers (waited for), user + system
            base = base or wall
            frames = out.split(" frames")[0].rsplit(" ", 1)[-1]
            print(
                f"{n:>7} {w:>7} {wall:>8.1f} {1000 * wall / n:>8.2f} {cpu:>8.1f} {base / wall:>8.2f} {rss:>19.2f}  {frames}",
                flush=True,
            )


if __name__ == "__main__":
    main()
