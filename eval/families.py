"""Out-of-distribution goal families: goal sets that leave rho_D along one axis at a time.

The thesis's OOD set moves the goal position out of rho_D (|p_i| in [2, 3.5] m per axis).
Once the skills generalise, position alone no longer tests the hierarchy, so the reach
study (eval/rings.py and experiments/reach_study.py, eval/README.md "Reach beyond the data") steps out of rho_D along
each goal dimension in turn, the others drawn from rho_D (the dataset spec's ranges):

================  ======================================================  =========
family            rings (per axis: |x_i| ~ U(lo, hi), random sign)         horizon
================  ======================================================  =========
``position``      |p_i| in [2, 3.5], [3.5, 5], [5, 7], [7, 10], [10, 20] m  scaled
``velocity``      |v_i| in [2.5, 3.5], [3.5, 5], [5, 7] m/s                1000
``acceleration``  |a_i| in [5, 7], [7, 10] m/s^2                           1000
``combined``      |p_i| in [3.5, 5] m, |v_i| in [2.5, 3.5] m/s and          1500
                  |a_i| in [5, 7] m/s^2 at once (one ring)
================  ======================================================  =========

* **Horizons** scale with the distance to fly: ``500 * max(2, ceil(hi_p / 1.75))``
  steps, where ``hi_p`` is the ring's upper bound on |p_i| (2 m per axis for the
  families that keep rho_D's positions): 1000 steps (10 s) for today's OOD set, as the
  thesis flies it (two legs of 500), up to 6000 for [10, 20] m.
* **Today's OOD set is ring 1 of ``position``**: the same seed stream, so ``--family
  position --ring 1`` flies exactly the goals of ``--task ood``.
* **Attitudes** follow from the goal acceleration by differential flatness
  (:func:`aerohrl.datagen.goals.flat_attitude`). An acceleration whose thrust would
  fall below ``MIN_THRUST_Z`` (``g + a_z < 2`` m/s^2, i.e. a falling vehicle that must
  turn over) keeps only its positive sign on z: within the vehicle's limits (the
  hummingbird's rotors give up to ~100 m/s^2 of thrust), and a goal the expert's
  thrust model can state.
* Every ring has its own seed stream (``FAMILY_SEED_OFFSET + 1000 * family + 10 * ring
  + seed``), different from every dataset's and from Reach-Novel's.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from aerohrl.errors import UserError

G = 9.81
MIN_THRUST_Z = 2.0  # m/s^2: g + a_z below this would need the vehicle upside down
FAMILY_SEED_OFFSET = 3_000_017
LEG_STEPS = 500  # one leg of the thesis's OOD flight
METRES_PER_LEG = 1.75  # horizon scaling: 500 steps per 1.75 m of |p_i| (today's set: 2 legs for 3.5 m)
RHO_D_POS_HI = 2.0  # |p_i| upper bound of rho_D (docs/spec.md), for the families that keep it

# per family: the goal dimensions that leave rho_D, and their rings (lo, hi) per step
FAMILIES: dict[str, dict[str, tuple[tuple[float, float], ...]]] = {
    "position": {"pos": ((2.0, 3.5), (3.5, 5.0), (5.0, 7.0), (7.0, 10.0), (10.0, 20.0))},
    "velocity": {"vel": ((2.5, 3.5), (3.5, 5.0), (5.0, 7.0))},
    "acceleration": {"acc": ((5.0, 7.0), (7.0, 10.0))},
    "combined": {"pos": ((3.5, 5.0),), "vel": ((2.5, 3.5),), "acc": ((5.0, 7.0),)},
}
FAMILY_INDEX = {name: i for i, name in enumerate(FAMILIES)}
UNITS = {"pos": "m", "vel": "m/s", "acc": "m/s^2"}
SYMBOL = {"pos": "|p_i|", "vel": "|v_i|", "acc": "|a_i|"}


@dataclass(frozen=True)
class Ring:
    """One goal set of a family: the ranges that leave rho_D (``{"pos": (lo, hi), ...}``)."""

    family: str
    index: int  # 1-based step along the family (0: a custom ring)
    ranges: dict

    @property
    def label(self) -> str:
        """The ring's ranges as text (``|p| in [2, 3] m, ...``), for tables and figures."""
        return ", ".join(f"{SYMBOL[k]} in [{lo:g}, {hi:g}] {UNITS[k]}" for k, (lo, hi) in self.ranges.items())

    @property
    def slug(self) -> str:
        """Folder-safe name: ``velocity-3.5-5``."""
        return self.family + "-" + "-".join(f"{lo:g}-{hi:g}" for lo, hi in self.ranges.values())

    def horizon(self) -> int:
        """Steps of every variant (straight or planned) on this ring (module docstring)."""
        hi_p = self.ranges["pos"][1] if "pos" in self.ranges else RHO_D_POS_HI
        return LEG_STEPS * max(2, math.ceil(hi_p / METRES_PER_LEG - 1e-9))


def rings(family: str) -> list[Ring]:
    """Every ring of ``family``, in order."""
    if family not in FAMILIES:
        raise UserError(f"unknown goal family {family!r} (choose from {', '.join(FAMILIES)})")
    dims = FAMILIES[family]
    n = len(next(iter(dims.values())))
    return [Ring(family, i + 1, {k: v[i] for k, v in dims.items()}) for i in range(n)]


_RANGE = re.compile(r"^\s*([0-9.eE+]+)\s*[:,]\s*([0-9.eE+]+)\s*$")


def parse_ring(family: str, ring: str | int) -> Ring:
    """``--ring``: a 1-based step of the family (``2``) or a custom range ``LO:HI`` on the
    family's one dimension (not for ``combined``). One-line errors for anything else."""
    all_rings = rings(family)
    text = str(ring).strip()
    if text.isdigit():
        k = int(text)
        if not 1 <= k <= len(all_rings):
            raise UserError(
                f"--ring {k}: family {family!r} has rings 1..{len(all_rings)} ({'; '.join(r.label for r in all_rings)})"
            )
        return all_rings[k - 1]
    m = _RANGE.match(text)
    if not m:
        raise UserError(f"--ring must be a step 1..{len(all_rings)} or a range LO:HI, got {ring!r}")
    dims = FAMILIES[family]
    if len(dims) != 1:
        raise UserError(f"family {family!r} has fixed rings only (--ring 1..{len(all_rings)})")
    try:
        lo, hi = float(m.group(1)), float(m.group(2))
    except ValueError:
        raise UserError(f"--ring range must be two numbers LO:HI, got {ring!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo < hi):
        raise UserError(f"--ring range needs 0 <= LO < HI (magnitudes per axis), got {lo:g}:{hi:g}")
    (dim,) = dims
    limit = {"pos": 100.0, "vel": 20.0, "acc": 30.0}[dim]
    if hi > limit:
        raise UserError(f"--ring {lo:g}:{hi:g}: |{dim}_i| above {limit:g} {UNITS[dim]} is beyond what the vehicle can fly")
    return Ring(family, 0, {dim: (lo, hi)})


def _ring_magnitudes(rng: np.random.Generator, n: int, lo: float, hi: float) -> np.ndarray:
    mag = rng.uniform(lo, hi, size=(n, 3))
    sign = np.where(rng.integers(0, 2, size=(n, 3)) == 1, 1.0, -1.0)
    return mag * sign


def sample_ring(
    ring: Ring,
    n: int,
    seed: int = 0,
    *,
    pos_range: tuple[float, float] = (1.0, 2.0),
    vel_range: tuple[float, float] = (-2.5, 2.5),
    acc_range: tuple[float, float] = (-5.0, 5.0),
) -> dict[str, np.ndarray]:
    """``n`` goals of ``ring`` (``{"pos", "vel", "acc"}`` (n, 3), ``"R"`` (n, 3, 3)); the
    dimensions the ring does not move are drawn from rho_D (the given ranges)."""
    from aerohrl.datagen.goals import flat_attitude, sample_goals
    from aerohrl.eval.tasks import OOD_SEED_OFFSET, _check_n

    n = _check_n(n)
    if ring.family == "position" and ring.index == 1:  # the thesis's OOD set, same stream (eval/tasks.py)
        return sample_goals(
            np.random.default_rng(OOD_SEED_OFFSET + int(seed)),
            n,
            pos_range=ring.ranges["pos"],
            vel_range=vel_range,
            acc_range=acc_range,
        )
    stream = FAMILY_SEED_OFFSET + 1000 * FAMILY_INDEX[ring.family] + 10 * ring.index + int(seed)
    if ring.index == 0:  # custom ring: its own stream, from its bounds
        lo, hi = next(iter(ring.ranges.values()))
        stream += 7919 * (1 + int(round(lo * 100)) + 10_007 * int(round(hi * 100)))
    rng = np.random.default_rng(stream)
    g = sample_goals(rng, n, pos_range=ring.ranges.get("pos", pos_range), vel_range=vel_range, acc_range=acc_range)
    if "vel" in ring.ranges:
        g["vel"] = _ring_magnitudes(rng, n, *ring.ranges["vel"])
    if "acc" in ring.ranges:
        acc = _ring_magnitudes(rng, n, *ring.ranges["acc"])
        falling = G + acc[:, 2] < MIN_THRUST_Z
        acc[falling, 2] = np.abs(acc[falling, 2])
        g["acc"] = acc
        g["R"] = flat_attitude(acc)
    return g


__all__ = ["FAMILIES", "Ring", "rings", "parse_ring", "sample_ring", "MIN_THRUST_Z"]
