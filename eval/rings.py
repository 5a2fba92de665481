"""Planners on the rings of OOD goal families: flown straight, planned, and declining.

The library half of the reach study (``experiments/reach_study.py``, eval/README.md
"Reach beyond the data"). For runs (one per training seed) and every ring of the
families of eval/families.py, a *variant* is one way to fly the ring's goals:

* ``straight``: the policy flies to G (no planner);
* ``single``: the thesis's planner (Eq. 3.7 over the dataset's achieved goals), which
  always inserts its waypoint;
* ``single-decline``: the same planner, but flying straight stays a candidate: it
  inserts the waypoint only where the critics' composed value beats ``V(s0, G)`` by
  the margin ``M`` (``decline_margin``). Its test rows are composed from the straight
  and planned flights of the same goals (exact: a declining episode flies what the
  straight flight flew, and the flights of a batch are independent; a test checks it
  against flying ``--decline-margin M``); ``fly_declines`` flies them instead;
* ``chain`` / ``chain-decline``: Eq. 3.6 with synthetic candidates (any state within
  rho_D relative to the current waypoint, planning/planner.py), ``n`` waypoints scaled to
  the distance, re-planned at every reached waypoint.

:func:`fly_group` flies one variant on several rings of one horizon in one batched
closed loop and writes each ring's evaluation as ``aerohrl eval`` would;
:func:`study` flies everything (resumable).

**The margin is chosen on held-out goals** (episode-set seed 1, ``heldout_n`` goals per
ring), never on the test goals: each planner's straight and planned flights of the
held-out goals give, for any margin ``M``, the success of declining exactly (an episode
that declines flies what the straight flight flew: the same start, goal and horizon, and
every flight of the batch is independent). ``M`` maximises the mean paired gain over
straight (pooled over seeds) among the margins whose worst ring loses at most 1 point
(:func:`choose_margin`), then prefers the larger ``M`` (declining more).

:func:`collect` turns the evaluations into per-ring records (success per seed, on all
and on expert-feasible goals, :func:`aerohrl.eval.feasibility.ring_feasibility`; paired
gain over straight), :func:`tables` into Markdown, :func:`plot_curves` and
:func:`plot_paths` into figures. Per run the evaluations sit in ``RUN/eval/reach/``
(``reach-nN/`` for other test sizes; the held-out ones in ``heldout/`` below it).
"""

from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from aerohrl.errors import UserError

if TYPE_CHECKING:
    from aerohrl.algorithms.data import Dataset
    from aerohrl.eval.families import Ring
    from aerohrl.eval.harness import EvalOptions

HELDOUT_SEED = 1  # episode-set seed of the goals the margins are chosen on (the test goals: seed 0)
MARGIN_GRID = (-0.05, -0.02, -0.01, 0.0, 0.005, 0.01, 0.02, 0.03, 0.05, 0.075, 0.1, 0.15, 0.2, 0.3, 0.5, math.inf)
BASE_VARIANTS = ("straight", "single")
PLANNED = {"single": "single", "chain": "chain"}  # planner variants that get a declining twin


CHAIN_CANDIDATES, CHAIN_BEAM = 64, 4  # synthetic offsets per extension and beam width (planning cost ~ E k C n^2)


def chain_waypoints(ring: Ring) -> int:
    """At most this many waypoints in a chain to a ring's goals: one per 2 m of the ring's
    largest |p_i| less one (planning/planner.py chain_length), >= 2; the beam search may stop earlier."""
    hi = ring.ranges["pos"][1] if "pos" in ring.ranges else 2.0
    return max(2, math.ceil(hi / 2.0 - 1e-9) - 1)


def eval_root(run: Path, episodes: int) -> Path:
    """Where a study's evaluations go: RUN/eval/reach (250 goals per ring), RUN/eval/reach-nN otherwise."""
    return run / "eval" / ("reach" if episodes == 250 else f"reach-n{episodes}")


def options(base: EvalOptions, ring: Ring, variant: str, margin: float | None = None) -> EvalOptions:
    """EvalOptions of one variant on one ring."""
    kw = dict(task="ood", family=ring.family, ring=str(ring.index) if ring.index else None, decline_margin=None)
    if variant == "straight":
        kw.update(planner="none")
    elif variant.startswith("single"):
        kw.update(planner="single")
    elif variant.startswith("chain"):
        kw.update(
            planner="multi",
            waypoints=chain_waypoints(ring),
            candidate_source="synthetic",
            candidates=CHAIN_CANDIDATES,
            beam=CHAIN_BEAM,
        )
    else:
        raise UserError(f"unknown variant {variant!r}")
    if variant.endswith("-decline"):
        kw.update(decline_margin=margin)
    return replace(base, **kw)


def episode_outcomes(summary_dir: Path) -> dict[int, dict]:
    """Per evaluated checkpoint step: success (E,), and plan_score/direct_score when planned."""
    out = {}
    for f in sorted(summary_dir.glob("episodes-step-*.csv")):
        with open(f, newline="") as fh:
            rows = list(csv.DictReader(fh))
        rec = {
            "success": np.array([r["success"] == "1" for r in rows], bool),
            "near": np.array([r["near_success"] == "1" for r in rows], bool),
        }
        if rows and "plan_score" in rows[0]:
            rec["diff"] = np.array([float(r["plan_score"]) - float(r["direct_score"]) for r in rows])
        out[int(f.stem.rsplit("-", 1)[1])] = rec
    return out


def _done(out_dir: Path, opt) -> bool:
    """Is the evaluation there with these options and episodes (resume: skip it)?"""
    f = out_dir / "summary.json"
    if not f.exists():
        return False
    try:
        s = json.loads(f.read_text())
    except (OSError, ValueError):
        return False
    return s.get("episodes") == opt.episodes and len(s.get("checkpoints", [])) == opt.checkpoints


def _subset(eps, idx: np.ndarray):
    from aerohrl.envs.episodes import EpisodeSet

    return EpisodeSet(
        eps.task,
        eps.start_states[idx],
        eps.goals[idx],
        eps.horizons[idx],
        eps.source_episode[idx],
        eps.start_frame[idx],
        eps.steps_ahead[idx],
        eps.seed,
        dict(eps.meta),
    )


def _slice(r: dict, idx: np.ndarray, E: int) -> dict:
    return {k: (v[idx] if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == E else v) for k, v in r.items()}


def fly_group(run: Path, opts: list, loaded: tuple[Dataset, dict], heldout: bool, base_episodes: int) -> list[Path]:
    """Fly one variant on several rings of equal horizon in one batched closed loop per
    checkpoint (the rings' episodes side by side: one policy call per step for all of
    them), and write each ring's evaluation as ``aerohrl eval`` would (episodes CSV,
    trajectories, summary.json). Rings already evaluated with these options are skipped."""
    from aerohrl.eval import results
    from aerohrl.algorithms.base import load_policy
    from aerohrl.eval.harness import build_episodes, check_checkpoint_dataset, check_options, fly, run_checkpoints

    outs = [
        eval_root(run, opts[0].episodes if not heldout else base_episodes) / ("heldout" if heldout else "") / o.name()
        for o in opts
    ]
    todo = [(o, d) for o, d in zip(opts, outs) if not _done(d, o)]
    if not todo:
        return outs
    for o, _ in todo:
        check_options(o)
    data, meta = loaded
    sets = [build_episodes(data, o) for o, _ in todo]
    horizons = {int(e.horizons.max()) for e in sets}
    if len(horizons) != 1:
        raise UserError(f"fly_group needs rings of one horizon, got {sorted(horizons)}")
    bounds = np.cumsum([0] + [len(e) for e in sets])
    from aerohrl.envs.episodes import EpisodeSet

    allset = EpisodeSet(
        "ood",
        *(
            np.concatenate([getattr(e, f) for e in sets])
            for f in ("start_states", "goals", "horizons", "source_episode", "start_frame", "steps_ahead")
        ),
        seed=sets[0].seed,
        meta={"leg_horizon": horizons.pop()},
    )
    o0 = todo[0][0]
    per_ckpt: list[list[dict]] = [[] for _ in todo]
    t_all = time.perf_counter()
    ckpts = run_checkpoints(run, o0.checkpoints)
    for i, path in enumerate(ckpts):
        algo, ck = load_policy(path, o0.device)
        check_checkpoint_dataset(ck, data, path)
        record = o0.record and i == len(ckpts) - 1
        t0 = time.perf_counter()
        # the rings of one variant fly as one episode set (one batched closed loop)
        r = fly(algo, allset, data, replace(o0, progress=False), record=record)
        wall = (time.perf_counter() - t0) / len(todo)
        for j, ((_o, d), eps) in enumerate(zip(todo, sets)):
            idx = np.arange(bounds[j], bounds[j + 1])
            rj = _slice(r, idx, len(allset))
            results.write_episodes(d, int(ck["step"]), eps, rj)
            per_ckpt[j].append(
                {
                    "checkpoint": path.name,
                    "step": int(ck["step"]),
                    "success": float(rj["success"].mean()),
                    "near_success": float(rj["near_success"].mean()),
                    "seconds": wall,
                    **({"declined": float(rj["declined"].mean())} if "declined" in rj else {}),
                }
            )
            if record:
                results.write_trajectories(d, int(ck["step"]), eps, rj)
    for j, ((o, d), eps) in enumerate(zip(todo, sets)):
        s = results.summarize(
            per_ckpt[j],
            run_dir=run,
            meta=meta,
            options=replace(o, out=str(d)),
            episodes=eps,
            seconds=(time.perf_counter() - t_all) / len(todo),
        )
        s["batched_with"] = [x.name() for x, _ in todo]  # flown side by side in one closed loop
        results.write_summary(d, s)
    return outs


def decline_success(straight: np.ndarray, planned: np.ndarray, diff: np.ndarray, margin: float) -> np.ndarray:
    """Per episode, what the declining planner reaches: planned where ``diff > margin``, else straight."""
    return np.where(diff > margin, planned, straight)


MAX_LOSS = 0.01  # the bar: on every set the planner stays within 1 point of flying straight


def choose_margin(pairs: dict, max_loss: float = MAX_LOSS) -> tuple[float, dict]:
    """The margin of one planner from its held-out flights.

    ``pairs[ring] = [(straight (E,), planned (E,), diff (E,)) per run/checkpoint]``.
    Per margin: the paired gain over straight per ring (pooled over runs), its worst ring
    and mean. The chosen margin maximises the mean gain among the margins whose worst ring
    loses at most ``max_loss`` (declining everywhere, M = inf, always qualifies), then
    prefers the larger margin (declining more)."""
    table: dict[float, dict[str, Any]] = {}
    for m in MARGIN_GRID:
        gains = {
            ring: float(np.mean([decline_success(s, p, d, m).mean() - s.mean() for s, p, d in v])) for ring, v in pairs.items()
        }
        table[m] = {"worst": min(gains.values()), "mean": float(np.mean(list(gains.values()))), "gains": gains}
    ok = [m for m in MARGIN_GRID if table[m]["worst"] >= -max_loss - 1e-12]
    best = max(ok, key=lambda m: (round(table[m]["mean"], 9), m))
    return best, table


def study(
    runs: list[Path],
    rings: list[Ring],
    variants: list[str],
    base: EvalOptions,
    heldout_n: int,
    log: Callable[[str], Any],
    fly_declines: bool = False,
) -> dict:
    """Fly everything (resumable); returns {"margins": {planner: M}, "margin_tables": ...}."""
    from aerohrl.eval.harness import load_run_dataset

    margins, margin_tables = {}, {}
    loaded: dict[Path, Any] = {}

    def data_of(run):
        if run not in loaded:
            loaded.clear()  # one large dataset in memory at a time
            loaded[run] = load_run_dataset(run, base.dataset)
        return loaded[run]

    planners = [v for v in variants if v in PLANNED]
    groups: dict[int, list] = {}
    for ring in rings:  # rings of one horizon fly side by side
        groups.setdefault(ring.horizon(), []).append(ring)

    def fly(run, variant, heldout, margin=None):
        for h, rs in groups.items():
            opts = [options(base, r, variant, margin) for r in rs]
            if heldout:
                opts = [replace(o, episodes=heldout_n, seed=HELDOUT_SEED) for o in opts]
            t0 = time.perf_counter()
            fly_group(run, opts, data_of(run), heldout, base.episodes)
            log(
                f"{run.name} {'held-out' if heldout else 'test'} {variant} horizon {h} "
                f"({', '.join(r.slug for r in rs)}): {time.perf_counter() - t0:.0f} s"
            )

    # 1. held-out goals: straight and every planner, for the margins
    for run in runs:
        for v in ["straight", *planners]:
            fly(run, v, True)
    for p in planners:
        pairs: dict[str, list] = {}
        for ring in rings:
            for run in runs:
                h = eval_root(run, base.episodes) / "heldout"
                s = episode_outcomes(h / replace(options(base, ring, "straight"), seed=HELDOUT_SEED).name())
                q = episode_outcomes(h / replace(options(base, ring, p), seed=HELDOUT_SEED).name())
                pairs.setdefault(ring.slug, []).extend((s[k]["success"], q[k]["success"], q[k]["diff"]) for k in q if k in s)
        margins[p], margin_tables[p] = choose_margin(pairs)
        log(
            f"margin of {p}: {margins[p]} (held-out worst ring {100 * margin_tables[p][margins[p]]['worst']:+.1f}, "
            f"mean {100 * margin_tables[p][margins[p]]['mean']:+.1f} points)"
        )
    # 2. test goals: every variant; a declining one is flown for real only with fly_declines
    #    (otherwise composed exactly from its straight and planned flights: collect())
    for run in runs:
        for v in variants:
            m = margins.get(v.removesuffix("-decline")) if v.endswith("-decline") else None
            if v.endswith("-decline") and (not fly_declines or (m is not None and math.isinf(m))):
                continue
            fly(run, v, False, m)
    return {"margins": margins, "margin_tables": {p: {str(k): v for k, v in t.items()} for p, t in margin_tables.items()}}


def collect(runs: list[Path], rings: list[Ring], variants: list[str], base: EvalOptions, margins: dict, feas: dict) -> list[dict]:
    """Per ring: per variant the success per seed (mean over checkpoints), on all and on
    feasible goals, and the paired gain over straight pooled over seeds."""
    from aerohrl.eval.results import seed_stats

    out = []
    for ring in rings:
        rec = {"ring": ring, "variants": {}, "feasible": None}
        fz = feas.get(ring.slug)
        if fz is not None:
            rec["feasible"] = {k: 100 * float(np.mean(v)) for k, v in fz.items()}
        straight = {run: episode_outcomes(eval_root(run, base.episodes) / options(base, ring, "straight").name()) for run in runs}
        for v in variants:
            m = margins.get(v.removesuffix("-decline")) if v.endswith("-decline") else None
            if v.endswith("-decline") and m is None:
                continue
            per_seed, per_seed_f, near, diffs, only = [], [], [], [], [0, 0]
            for run in runs:
                root = eval_root(run, base.episodes)
                if v.endswith("-decline"):
                    assert m is not None  # a declining variant without a margin was skipped above
                    flown = root / options(base, ring, v, m).name()
                    if math.isinf(m):  # declines everywhere: the straight flight
                        ep = straight[run]
                    elif (flown / "summary.json").exists():
                        ep = episode_outcomes(flown)
                    else:  # composed exactly: declining episodes fly what the straight flight flew
                        planned = episode_outcomes(root / options(base, ring, v.removesuffix("-decline")).name())
                        ep = {
                            k: {
                                "success": decline_success(straight[run][k]["success"], q["success"], q["diff"], m),
                                "near": decline_success(straight[run][k]["near"], q["near"], q["diff"], m),
                            }
                            for k, q in planned.items()
                            if k in straight[run]
                        }
                else:
                    ep = episode_outcomes(root / options(base, ring, v, m).name())
                if not ep:
                    continue
                per_seed.append(100 * np.mean([e["success"].mean() for e in ep.values()]))
                near.append(100 * np.mean([e["near"].mean() for e in ep.values()]))
                if fz is not None and fz["feasible"].any():
                    per_seed_f.append(
                        100
                        * np.mean(
                            [e["success"][fz["feasible"]].mean() for e in ep.values() if len(e["success"]) == len(fz["feasible"])]
                        )
                    )
                for k, e in ep.items():
                    s = straight[run].get(k)
                    if s is not None and len(s["success"]) == len(e["success"]):
                        diffs.append(100 * (e["success"].mean() - s["success"].mean()))
                        only[0] += int((e["success"] & ~s["success"]).sum())
                        only[1] += int((s["success"] & ~e["success"]).sum())
            if per_seed:
                rec["variants"][v] = {
                    "success": seed_stats(per_seed),
                    "near": seed_stats(near),
                    "feasible": seed_stats(per_seed_f) if per_seed_f else None,
                    "paired": {
                        "diff": float(np.mean(diffs)) if diffs else float("nan"),
                        "only_variant": only[0],
                        "only_straight": only[1],
                    },
                    "margin": m,
                }
        out.append(rec)
    return out


def _paired(p: dict) -> str:
    from scipy.stats import binomtest

    n = p["only_variant"] + p["only_straight"]
    pv = binomtest(p["only_variant"], n).pvalue if n else 1.0
    return f"{p['diff']:+.1f} ({p['only_variant']}:{p['only_straight']}, p={pv:.2f})"


VARIANT_LABEL = {
    "straight": "straight",
    "single": "single (Eq. 3.7, thesis)",
    "single-decline": "single, declining",
    "chain": "chain (synthetic)",
    "chain-decline": "chain, declining",
}


def tables(recs: list[dict], variants: list[str], margins: dict) -> str:
    """The reach tables as Markdown: per family and ring, each variant's success (mean and
    seed spread, on all and on expert-feasible goals) and the paired gain over straight."""
    from aerohrl.eval.results import seed_cell

    fams: dict[str, list[dict]] = {}
    for r in recs:
        fams.setdefault(r["ring"].family, []).append(r)
    shown = [v for v in variants if any(v in r["variants"] for r in recs)]
    parts = []
    for fam, rs in fams.items():
        head = (
            "| ring | horizon | expert reaches: directly / only by run-up / either (%) | "
            + " | ".join(VARIANT_LABEL[v] for v in shown)
            + " |\n"
        )
        head += "|---" * (3 + len(shown)) + "|\n"
        lines = []
        for r in rs:
            fz = r["feasible"]
            fcell = f"{fz['direct']:.0f} / {fz['runup']:.0f} / {fz['feasible']:.0f}" if fz else "—"
            cells = []
            for v in shown:
                x = r["variants"].get(v)
                if not x:
                    cells.append("—")
                    continue
                c = seed_cell(x["success"]) + f"; near {x['near']['mean']:.1f}"
                if v != "straight":
                    c += f"; vs straight {_paired(x['paired'])}"
                if x["feasible"]:
                    c += f"; feasible goals {x['feasible']['mean']:.1f}"
                cells.append(c)
            lines.append(
                f"| {r['ring'].label.replace('|', chr(92) + '|')} | {r['ring'].horizon()} | {fcell} | " + " | ".join(cells) + " |"
            )
        parts.append(f"**{fam}**\n\n" + head + "\n".join(lines) + "\n")
    ms = ", ".join(f"{p}: {m:g}" for p, m in margins.items())
    return "\n".join(parts) + (f"\nDecline margins chosen on held-out goals: {ms}.\n" if ms else "")


def plot_curves(recs: list[dict], variants: list[str], path: Path) -> Path:
    """Success against each family's step, one panel per family, seed band (min-max) per variant."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fams: dict[str, list[dict]] = {}
    for r in recs:
        fams.setdefault(r["ring"].family, []).append(r)
    fig, axes = plt.subplots(1, len(fams), figsize=(4.2 * len(fams), 3.8), squeeze=False)
    colours = {
        "straight": "black",
        "single": "tab:blue",
        "single-decline": "tab:cyan",
        "chain": "tab:red",
        "chain-decline": "tab:orange",
    }
    for ax, (fam, rs) in zip(axes[0], fams.items()):
        x = np.arange(len(rs))
        for v in variants:
            ys = [r["variants"].get(v) for r in rs]
            if not any(ys):
                continue
            mean = [y["success"]["mean"] if y else np.nan for y in ys]
            lo = [min(y["success"]["values"]) if y else np.nan for y in ys]
            hi = [max(y["success"]["values"]) if y else np.nan for y in ys]
            ax.plot(
                x,
                mean,
                "--o" if v.endswith("-decline") else "-o",
                ms=3,
                color=colours.get(v),
                label=VARIANT_LABEL[v],
                lw=1.2 if v.endswith("-decline") else 1.6,
            )
            ax.fill_between(x, lo, hi, color=colours.get(v), alpha=0.15)
        fz = [r["feasible"]["feasible"] if r["feasible"] else np.nan for r in rs]
        if not np.all(np.isnan(fz)):
            ax.plot(x, fz, ":", color="grey", label="expert feasible")
        ax.set_xticks(
            x,
            [r["ring"].label.split(" in ")[1] if len(r["ring"].ranges) == 1 else "p, v and a\nout at once" for r in rs],
            rotation=20,
            fontsize=7,
        )
        unit = rs[0]["ring"].label.split(" in ")[0] if len(rs[0]["ring"].ranges) == 1 else "rings"
        ax.set_xlabel(f"{fam}: {unit}")
        ax.set_ylabel("success % (mean; band: min-max over seeds)")
        ax.set_ylim(-2, 102)
        ax.grid(alpha=0.3)
        ax.set_title(f"{fam} family")
    axes[0][0].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_paths(run: Path, rings: list[Ring], base: EvalOptions, variant: str, path: Path, per_ring: int = 3) -> Path | None:
    """3-D paths of far goals (the last ring of each family), planned waypoints marked
    (thesis Fig. 3.6 analogue): flown path per episode, start, goal and its waypoints."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    last = {}
    for r in rings:
        last[r.family] = r
    panels = []
    for ring in last.values():
        d = eval_root(run, base.episodes) / options(base, ring, variant).name()
        files = sorted(d.glob("trajectories-step-*.npz"))
        if files:
            panels.append((ring, np.load(files[-1])))
    if not panels:
        return None
    fig = plt.figure(figsize=(4.4 * len(panels), 4.4))
    cmap = plt.get_cmap("tab10")
    for k, (ring, z) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), k + 1, projection="3d")
        succ = z["success"]
        idx = list(np.flatnonzero(succ)[: per_ring - 1]) + list(np.flatnonzero(~succ)[:1])
        idx = idx or list(range(min(per_ring, len(succ))))
        for j, i in enumerate(idx):
            c = cmap(j % 10)
            p = z["positions"][i, : int(z["steps"][i]) + 1]
            ax.plot(p[:, 0], p[:, 1], p[:, 2], color=c, lw=1.0, ls="-" if succ[i] else "--")
            ax.scatter(*z["goals"][i, :3], color=c, marker="*", s=60, depthshade=False)
            if "waypoints" in z.files:
                w = z["waypoints"][i, :, :3]
                ax.scatter(w[:, 0], w[:, 1], w[:, 2], color=c, marker="^", s=18, depthshade=False)
        ax.scatter(0, 0, 0, color="black", s=15)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")
        ax.set_title(f"{ring.label}\n{VARIANT_LABEL[variant]}: ★ goal, ▲ waypoints, -- failed", fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
