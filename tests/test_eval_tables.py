"""Tables over seeds (eval/results.py): runs that differ only in their seed are one row."""

import csv
import json

import numpy as np
import pytest

from aerohrl.eval import results


def _run(root, name, seed, rd_rates, *, algo="gcsl", lr=1e-3, ood=None, floors=None):
    rd = root / name
    (rd / "eval").mkdir(parents=True)
    (rd / "config.json").write_text(
        json.dumps(
            {
                "config": {"algo": algo, "seed": seed, "lr_actor": lr, "dataset": f"/x/{name}"},
                "dataset": {"version": "n250-s0-dbb240c0"},
            }
        )
    )

    def summary(name, rates, planner="none", far=None, beyond=None):
        d = rd / "eval" / name
        d.mkdir()
        ck = [
            {
                "success": r,
                "near_success": min(1.0, r + 0.05),
                **({"success_intermediate_far": far} if far is not None else {}),
                **({"success_beyond_hover": beyond} if beyond is not None else {}),
            }
            for r in rates
        ]
        (d / "summary.json").write_text(
            json.dumps(
                {
                    "checkpoints": ck,
                    "success_mean": float(np.mean(rates)),
                    "success_std": float(np.std(rates)),
                    "near_success_mean": float(np.mean(rates)) + 0.05,
                    "near_success_std": 0.0,
                    "episodes": 250,
                    "planner": planner,
                }
            )
        )

    summary("reach-desired", rd_rates)
    summary("reach-intermediate", [0.8, 0.8], far=0.6, beyond=0.1 + 0.1 * seed)
    for planner, per_ckpt in (ood or {}).items():
        summary(f"ood-{planner}", [np.mean(x) for x in per_ckpt], planner=planner)
        for k, ep in enumerate(per_ckpt):
            with open(rd / "eval" / f"ood-{planner}" / f"episodes-step-{k:09d}.csv", "w", newline="") as f:
                w = csv.writer(f)
                w.writerow(["episode", "success"])
                w.writerows([i, int(x)] for i, x in enumerate(ep))
    for fl, rate in (floors or {}).items():
        summary(f"reach-desired-floor-{fl}", [rate])
    return rd


def test_seeds_of_one_experiment_make_one_row(tmp_path):
    a = _run(tmp_path, "gcsl-cpu", 0, [0.90, 0.92], floors={"hover": 0.0})
    b = _run(tmp_path, "gcsl-cpu-s1", 1, [0.94, 0.96])
    c = _run(tmp_path, "gcsl-cpu-s2", 2, [0.98, 0.98])
    other = _run(tmp_path, "gcsl-lr", 0, [0.5, 0.5], lr=3e-4)
    assert results.group_runs([a, other, b, c]) == [[a, b, c], [other]]
    t = results.tables([a, b, c, other])
    head, rows = t["t31"]
    assert [r[0] for r in rows] == ["GCSL", "floor: hover", "GCSL"]
    st = results.seed_stats([91.0, 95.0, 98.0])
    row = dict(zip(head, rows[0]))
    assert row["Reach-Desired success %"] == results.seed_cell(st) and "(91.0/95.0/98.0)" in row["Reach-Desired success %"]
    rd_spread = rows[0][head.index("ckpt spread")]  # Reach-Desired's (the first of the two columns)
    assert row["seeds x ckpts x episodes"] == "3 x 2 x 250" and rd_spread == "0.7"  # mean of 1.0, 1.0, 0.0
    assert row["RI >= 10 steps ahead %"].startswith("60.0 ± 0.0") and "+2 seeds" in row["runs"]
    assert row["RI goals hover misses %"].startswith("20.0 ± 10.0") and "(10.0/20.0/30.0)" in row["RI goals hover misses %"]
    floor = dict(zip(head, rows[1]))
    assert floor["Reach-Desired success %"] == "0.0"  # the floor, flown on seed 0's data
    assert floor["runs"] == str(a)  # and named by the one run it was flown on
    lo, hi = st["ci95"]
    assert lo <= st["mean"] <= hi and st["std"] == pytest.approx(np.std([91, 95, 98], ddof=1))


def test_planner_comparison_is_pooled_over_seeds(tmp_path):
    # per run one checkpoint of 4 episodes; the planner wins 2 episodes in each run and loses 1 in one
    a = _run(tmp_path, "a", 0, [0.9], ood={"none": [[1, 0, 0, 0]], "single": [[1, 1, 1, 0]]})
    b = _run(tmp_path, "b", 1, [0.9], ood={"none": [[0, 1, 0, 0]], "single": [[1, 0, 0, 1]]})
    pv = results.paired_vs_none([a, b], "ood-single")
    assert (pv["only_planner"], pv["only_none"], pv["checkpoints"]) == (4, 1, 2)
    assert pv["diff"] == pytest.approx(np.mean([0.5, 0.25]))
    head, rows = results.tables([a, b])["t32"]
    single = [dict(zip(head, r)) for r in rows if r[2] == "single"][0]
    assert single["seeds x ckpts x episodes"] == "2 x 1 x 250" and "episodes 4 : 1" in single[head[-1]]


def test_ood_floors_and_tolerance_variants_are_labelled_not_compared_as_planners(tmp_path):
    a = _run(
        tmp_path,
        "a",
        0,
        [0.9],
        ood={
            "none": [[1, 1, 0, 0]],
            "none-goaltol0.5": [[1, 0, 0, 0]],
            "none-floor-hover": [[0, 0, 0, 0]],
            "single": [[1, 1, 1, 0]],
        },
    )
    b = _run(tmp_path, "b", 1, [0.9], ood={"none": [[1, 0, 0, 0]], "single": [[1, 0, 0, 0]]})
    head, rows = results.tables([a, b])["t32"]
    by = {(r[0], r[2]): dict(zip(head, r)) for r in rows}
    assert set(by) == {("GCSL", "none"), ("GCSL", "none (goal tolerance x 0.5)"), ("floor: hover", "none"), ("GCSL", "single")}
    paired = head[-1]
    assert by[("GCSL", "single")][paired].startswith("+12.5")  # the one planner: compared with flying straight
    assert all(by[k][paired] == "—" for k in by if k[1] != "single")  # floors and tolerances: no comparison
    assert by[("floor: hover", "none")]["runs"] == str(a)  # named by the run it was flown on
    assert by[("GCSL", "none")]["thesis success %"] == "0.0" and by[("floor: hover", "none")]["thesis success %"] == "—"
    assert results._ood_variant("ood-multi2-replan10-goaltol0.5-floor-no-goal") == ("multi2-replan10", "0.5", "no-goal")


def test_kind_rates_split_intermediate_goals_by_steps_ahead_and_by_what_hover_misses():
    from aerohrl.envs.episodes import EpisodeSet

    n = 6
    steps_ahead = np.array([0, 0, 2, 12, 30, 40])
    eps = EpisodeSet(
        "reach-intermediate",
        np.zeros((n, 18)),
        np.zeros((n, 15)),
        np.full(n, 100),
        np.zeros(n, np.int64),
        np.zeros(n, np.int64),
        steps_ahead,
        0,
    )
    r = {"success": np.array([1, 0, 1, 1, 0, 1], bool)}
    hover = np.array([0, 0, 1, 1, 0, 0], bool)  # hover meets the goals 2 and 12 steps ahead
    out = results.kind_rates(eps, r, hover)
    assert out["success_desired"] == 0.5 and out["success_intermediate"] == 0.75
    assert out["success_intermediate_far"] == pytest.approx(2 / 3)  # 12, 30, 40 steps ahead
    assert out["success_beyond_hover"] == 0.5  # episodes 0, 1, 4, 5: two of four reached
    assert "success_beyond_hover" not in results.kind_rates(eps, r)  # no hover outcomes given
    assert "success_beyond_hover" not in results.kind_rates(eps, r, np.ones(n, bool))  # hover meets every goal
