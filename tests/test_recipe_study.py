"""The recipe study (experiments/recipe_study.py): seeds aggregated, floors beside, end to end."""

import json
import math
import sys

import numpy as np
import pytest

from aerohrl.eval import results
from conftest import load_experiment

rs = load_experiment("recipe_study")


def _fake_run(root, row: rs.Row, rates: dict, floors: dict | None = None):
    """A run folder with evaluation summaries: rates[col] = per-checkpoint success fractions."""
    rd = root / row.name
    for col, xs in rates.items():
        d = rd / "eval" / rs.EVAL_DIR.get(col, col)
        d.mkdir(parents=True)
        (d / "summary.json").write_text(json.dumps({"checkpoints": [{"success": x} for x in xs]}))
    for fl, v in (floors or {}).items():
        for col, x in v.items():
            d = rd / "eval" / f"{rs.EVAL_DIR.get(col, col)}-floor-{fl}"
            d.mkdir(parents=True)
            (d / "summary.json").write_text(json.dumps({"checkpoints": [{"success": x}]}))
    return rd


def test_bootstrap_interval_brackets_the_mean_and_needs_two_seeds():
    assert all(math.isnan(x) for x in results.bootstrap_ci([90.0]))
    lo, hi = results.bootstrap_ci([97.0, 99.0, 98.0])
    assert 97.0 <= lo <= 98.0 <= hi <= 99.0
    assert results.bootstrap_ci([95.0, 95.0, 95.0]) == (95.0, 95.0)


def test_seeds_are_aggregated_with_their_values_and_floors(tmp_path, monkeypatch):
    monkeypatch.setattr(rs, "critics_auc", lambda rd: 0.75)
    rows = [rs.Row("noise", 2500, s, 15000) for s in (0, 1, 2)]
    for s, base in zip((0, 1, 2), (0.90, 0.94, 0.98)):
        _fake_run(
            tmp_path,
            rows[s],
            {"reach-novel": [base - 0.01, base + 0.01], "reach-desired": [base, base]},
            floors={"hover": {"reach-novel": 0.0, "reach-intermediate": 0.3}} if s == 0 else None,
        )
    (rec,) = rs.aggregate(rows, tmp_path)
    rn = rec["cols"]["reach-novel"]
    np.testing.assert_allclose(rn["values"], [90.0, 94.0, 98.0])
    assert rn["mean"] == pytest.approx(94.0) and rn["std"] == pytest.approx(4.0) and rn["ckpts"] == 2
    assert rec["floors"]["hover"] == {"reach-novel": 0.0, "reach-intermediate": pytest.approx(30.0)}
    md = rs.table([rec])
    lo, hi = results.bootstrap_ci([90.0, 94.0, 98.0])
    assert f"94.0 ± 4.0 [{lo:.1f}, {hi:.1f}] (90.0/94.0/98.0)" in md and "*floor, hover" in md and "| 0.750 ± 0.000" in md


def test_rows_name_their_runs_and_repeats_count_flights():
    assert rs.Row("noise + 4 flights per goal", 2500, 1, 15000).name == "noise+4-flights-per-goal-n2500-s1-15k"
    assert rs.flights_per_goal("noise + 4 flights per goal") == 4 and rs.flights_per_goal("clean") == 1
    assert rs._flights("noise + 4 flights per goal", 2500) == "625 x 4"
    assert set(r.recipe for p in rs.PLANS.values() for r in p) <= set(rs.RECIPES)


@pytest.mark.slow
def test_a_row_end_to_end(tmp_path, monkeypatch):
    """Build a small noisy dataset, train GCSL briefly, evaluate two columns and a floor
    through the real command lines; a second call finds everything done."""
    monkeypatch.setattr(
        rs,
        "EVALS",
        [("reach-novel", ["--task", "reach-novel"]), ("reach-novel-goaltol0.5", ["--task", "reach-novel", "--goal-tol", "0.5"])],
    )
    monkeypatch.setattr(rs, "FLOORS", ("hover",))
    monkeypatch.setattr(rs, "FLOOR_COLS", ("reach-novel",))
    monkeypatch.setattr(rs, "EPISODES", 20)
    log = open(tmp_path / "log.txt", "w")
    ds = rs.dataset_for(sys.executable, "noise", 8, str(tmp_path / "ds"), log)
    row = rs.Row("noise", 8, 0, 60)
    rd = rs.run_row(sys.executable, row, ds, tmp_path / "runs", 2, log)
    for name in ("reach-novel", "reach-novel-goaltol0.5", "reach-novel-floor-hover"):
        s = json.loads((rd / "eval" / name / "summary.json").read_text())
        assert s["episodes"] == 20 and len(s["checkpoints"]) == (1 if "floor" in name else 2)
    before = (tmp_path / "log.txt").stat().st_size
    rs.run_row(sys.executable, row, ds, tmp_path / "runs", 2, log)
    log.flush()
    assert "aerohrl.eval.cli" not in (tmp_path / "log.txt").read_text()[before:]  # up to date: nothing re-evaluated
    (rec,) = rs.aggregate([row], tmp_path / "runs")
    assert set(rec["cols"]) >= {"reach-novel", "reach-novel-goaltol0.5", "auc"} and "hover" in rec["floors"]


def test_the_report_goes_to_a_dated_page(tmp_path, monkeypatch):
    """``--report-only`` tabulates what is there into OUT/recipes.md and the dated results
    page (the command first, the figure beside it); no README is touched."""
    monkeypatch.setattr(rs, "critics_auc", lambda rd: 0.75)
    rows = rs.PLANS["size"]
    for r, base in zip(rows, (0.2, 0.5, 0.8, 0.9)):
        _fake_run(tmp_path / "runs", r, {"reach-novel": [base, base], "ood": [0.0, 0.0]})
    pages = tmp_path / "pages"
    assert (
        rs.main(
            [
                "--plan",
                "size",
                "--report-only",
                "--runs",
                str(tmp_path / "runs"),
                "--out",
                str(tmp_path / "out"),
                "--results-dir",
                str(pages),
            ]
        )
        == 0
    )
    (page,) = pages.glob("*-recipes.md")
    text = page.read_text()
    assert text.index("```\npython experiments/recipe_study.py --plan size --report-only") < text.index("**size**")
    assert "| noise | 250 | 15k | 1 | — | 20.0 | — | 0.0 | 0.750 |" in text and "reach_novel_vs_size.png)" in text
    assert (pages / "figures" / page.name.replace(".md", "-reach_novel_vs_size.png")).stat().st_size > 0
    assert "**size**" in (tmp_path / "out" / "recipes.md").read_text()
