"""Which tolerance of the goal test binds the expert on a perturbed vehicle.

For each perturbation (``aerohrl eval --perturb`` text), the geometric expert that flew a
run's dataset (its disturbance observer included) flies the robustness study's episodes
(``eval/robustness.py`` ``expert_success``: min-time references from hover, Reach-Novel's
horizon) and is scored under the goal test as it is, then with one tolerance at a time
(position, velocity, attitude) multiplied by ``--scale``. A tolerance whose relaxation
lifts the success most is the one the expert's flights miss.

    python experiments/robust_bounds.py --run runs/drow-s0 \\
        --perturb drag=0.5,wind=3,gust=1 --perturb mass=1.2,thrust=0.85 [--scale 2] [--episodes 100] \\
        [--expert-set expert=replan --expert-set terminal_disturbance=true]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from aerohrl.errors import UserError

HORIZON = 500  # Reach-Novel's (and the robustness study's) steps per episode


def bounds(
    run: Path, perturbations: list[str], scale: float, episodes: int, seed: int, expert_set: dict | None = None
) -> list[dict]:
    """One row per perturbation: the expert's success under the task's test and with each
    tolerance x ``scale``. ``expert_set``: spec fields of the expert replaced (another
    expert recipe on the same goals, e.g. ``{"expert": "replan"}``)."""
    from aerohrl import task
    from aerohrl.eval.harness import open_run_dataset
    from aerohrl.eval.robustness import expert_flights, expert_spec
    from aerohrl.sim.perturb import Perturbation

    spec = expert_spec(open_run_dataset(run).spec)  # the expert flies; no frame is read
    if expert_set:
        from dataclasses import fields

        names = {f.name for f in fields(spec)}
        unknown = sorted(set(expert_set) - names)
        if unknown:
            raise UserError(f"--expert-set {unknown[0]}: not a dataset spec field")
        spec = replace(spec, **expert_set)
    tol = task.TOLERANCE
    tests = {
        "as is": tol,
        "position": replace(tol, pos=tol.pos * scale),
        "velocity": replace(tol, vel=tol.vel * scale),
        "attitude": replace(tol, rot=tol.rot * scale),
    }
    rows = []
    for text in perturbations:
        Perturbation.parse(text).check()  # a one-line error before any flight
        achieved, goals = expert_flights(spec, episodes, seed, HORIZON, text)  # one flight, scored under each test
        hits = {k: np.asarray(task.goal_reached(achieved, goals[None], t)).any(axis=0) for k, t in tests.items()}
        rows.append({"perturb": text} | {k: float(h.mean()) for k, h in hits.items()})
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", type=Path, required=True, help="a training run; its dataset's expert (and observer) flies")
    p.add_argument("--perturb", action="append", required=True, help="NAME=VALUE[,...] as aerohrl eval --perturb (repeatable)")
    p.add_argument("--scale", type=float, default=2.0, help="factor on the one relaxed tolerance [2]")
    p.add_argument("--episodes", type=int, default=100, help="episodes per perturbation [100]")
    p.add_argument("--seed", type=int, default=0, help="episode and perturbation seed, as aerohrl eval robustness [0]")
    p.add_argument(
        "--expert-set",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="replace a spec field of the expert (expert=replan, terminal_disturbance=true; repeatable)",
    )
    a = p.parse_args(argv)
    try:
        if a.scale <= 0 or a.episodes < 1 or a.seed < 0:
            raise UserError("--scale must be > 0, --episodes >= 1 and --seed >= 0")
        from aerohrl.sweep import key_values

        rows = bounds(a.run, a.perturb, a.scale, a.episodes, a.seed, key_values(a.expert_set, "--expert-set", many=False))
    except (UserError, ValueError) as e:
        print(f"robust_bounds: error: {e}", file=sys.stderr)
        return 2
    print(f"expert success %, {a.episodes} episodes; one tolerance x {a.scale:g} at a time\n")
    print("| perturbation | goal test | position | velocity | attitude |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(
            f"| `{r['perturb']}` | "
            + " | ".join(f"{100 * r[k]:.0f}" for k in ("as is", "position", "velocity", "attitude"))
            + " |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
