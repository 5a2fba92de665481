"""The benchmark suite end to end (slow): a tiny maze dataset built from its spec, a flat
agent and the same runs under the planner, trained and evaluated through Ray, the
leaderboard written; a rerun trains and evaluates nothing again."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_ci_sized_suite_writes_the_leaderboard_and_resumes(tmp_path):
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONWARNINGS="ignore")
    out = tmp_path / "suite"
    cmd = [
        sys.executable,
        "-m",
        "aerohrl.cli",
        "bench",
        "suite",
        "--size",
        "ci",
        "--datasets",
        "maze-medium-stitch@8",
        "--agents",
        "gcsl",
        "gcsl+planner",
        "--seeds",
        "0",
        "--steps",
        "40",
        "--eval-episodes",
        "5",
        "--num-cpus",
        "1",
        "--specs",
        str(ROOT / "datasets"),
        "--data",
        str(tmp_path / "ds"),
        "-o",
        str(out),
    ]
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    board = (out / "leaderboard.md").read_text()
    assert "| maze-medium-stitch@8 | maze | gcsl |" in board and "| maze-medium-stitch@8 | maze | gcsl+planner |" in board
    csv = (out / "leaderboard.csv").read_text().splitlines()
    assert len(csv) == 3 and (out / "leaderboard.png").stat().st_size > 1000
    run = out / "runs" / "gcsl-maze-medium-stitch-n8-s0"
    names = sorted(p.parent.name for p in run.glob("eval/*/summary.json"))
    assert names == ["maze", "maze-graph-corridor-edge8.5-minleg1"]
    assert json.loads((out / "suite.json").read_text())["seeds"] == [0]

    summaries = {f: f.stat().st_mtime for f in out.glob("runs/*/eval/*/summary.json")}
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    report = json.loads((out / "suite-report.json").read_text())
    assert {v["status"] for v in report["runs"].values()} == {"finished before"}
    assert {f: f.stat().st_mtime for f in out.glob("runs/*/eval/*/summary.json")} == summaries
    assert (out / "leaderboard.md").read_text() == board
