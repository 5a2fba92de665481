"""The benchmark suite's names, grid and leaderboard (aerohrl/benchmark.py); the end-to-end
CI-sized suite is in tests/test_benchmark_e2e.py."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from aerohrl import benchmark as B
from aerohrl.errors import UserError


def test_dataset_names_resolve_to_spec_files():
    assert B.spec_path("reach-dart").name == "quadrotor-reach-dart.toml"
    assert B.spec_path("quadrotor-reach-dart-v0").name == "quadrotor-reach-dart.toml"
    with pytest.raises(UserError, match="unknown dataset 'maze-huge-stitch'"):
        B.spec_path("maze-huge-stitch")
    assert B.split_dataset("reach-dart@250") == ("reach-dart", 250) and B.split_dataset("reach-dart") == ("reach-dart", 0)
    with pytest.raises(UserError, match="positive integer"):
        B.split_dataset("reach-dart@x")


def test_agents_and_their_evaluations():
    assert B.split_agent("gcsl") == ("gcsl", "")
    assert B.split_agent("td3bc+planner") == ("td3bc", "planner")
    assert B.split_agent("hiql+subgoals") == ("hiql", "subgoals")
    with pytest.raises(UserError, match=r"\+subgoals needs a hierarchical agent \(hiql\)"):
        B.split_agent("gcsl+subgoals")
    with pytest.raises(UserError, match="unknown agent 'hql'"):
        B.split_agent("hql")
    assert B.eval_entries("free", "") == [("--task", "reach-novel"), ("--task", "fast")]
    assert B.eval_entries("maze-large", "planner") == [("--task", "maze", *B.MAZE_PLANNER_ARGS)]
    assert B.eval_entries("maze-large", "subgoals") == [("--task", "maze", *B.MAZE_SUBGOALS_ARGS)]


def test_runs_are_shared_by_an_agent_and_its_planner():
    sp = B.with_size_defaults(B.SuiteSpec(agents=("gcsl", "gcsl+planner", "td3bc"), datasets=("a", "b"), seeds=(0, 1)))
    runs = B.suite_runs(sp, {"a": ("/d/a", "free", "navigate"), "b": ("/d/b", "maze-large", "stitch")})
    assert len(runs) == 2 * 2 * 2  # algorithms x datasets x seeds
    assert {r.name() for r in runs} >= {"gcsl-a-s0", "td3bc-b-s1"}
    assert B.SuiteRun("gcsl", "a@100", "/d", "free", 3).name() == "gcsl-a-n100-s3"
    assert B.with_size_defaults(B.SuiteSpec(size="ci")).seeds == B.SIZES["ci"].seeds


def test_maze_runs_get_position_features_unless_set():
    sp = B.with_size_defaults(B.SuiteSpec(agents=("gcsl",), datasets=("a",), seeds=(0,), steps=100))
    maze, free = B.SuiteRun("gcsl", "a", "/d/a", "maze-large", 0), B.SuiteRun("gcsl", "a", "/d/a", "free", 0)
    assert B.run_config(sp, maze)["pos_octaves"] == B.MAZE_TRAIN_SETTINGS["pos_octaves"] > 0
    assert B.run_config(sp, free)["pos_octaves"] == 0
    sp0 = B.SuiteSpec(agents=("gcsl",), datasets=("a",), seeds=(0,), steps=100, set={"pos_octaves": 0})
    assert B.run_config(sp0, maze)["pos_octaves"] == 0


def test_explore_runs_learn_from_later_states_only():
    """An explore dataset's desired goals are its flights' last states: every goal is relabelled."""
    sp = B.with_size_defaults(B.SuiteSpec(agents=("gcsl",), datasets=("a",), seeds=(0,), steps=100))
    runs = B.suite_runs(sp, {"a": ("/d/a", "maze-large", "explore")})
    assert runs[0].family == "explore"
    cfg = B.run_config(sp, runs[0])
    assert cfg["relabel_prob"] == 1.0 and cfg["relabel_offset"] == "uniform" and cfg["pos_octaves"] > 0
    gciql = B.run_config(sp, B.SuiteRun("gciql", "a", "/d/a", "maze-large", 0, "explore"))
    assert gciql["gciql_actor_p_trajgoal"] == 1.0  # the cpu preset's 0 is for expert data
    stitch = B.run_config(sp, B.SuiteRun("gciql", "a", "/d/a", "maze-large", 0, "stitch"))
    assert stitch["gciql_actor_p_trajgoal"] == 0.0 and stitch["relabel_prob"] == 0.05
    mine = B.SuiteSpec(agents=("gcsl",), datasets=("a",), seeds=(0,), steps=100, set={"relabel_prob": 0.5})
    assert B.run_config(mine, runs[0])["relabel_prob"] == 0.5  # --set still has the last word


def _summary(run: Path, task: str, planner: str, success: float, folder: str = "", **options) -> None:
    d = run / "eval" / (folder or (task if planner == "none" else f"{task}-{planner}"))
    d.mkdir(parents=True)
    s = {"task": task, "planner": planner, "options": options, "checkpoints": [{"success": success}]}
    (d / "summary.json").write_text(json.dumps(s))


def test_leaderboard_aggregates_seeds_at_the_final_checkpoint(tmp_path):
    sp = B.SuiteSpec(agents=("gcsl", "gcsl+planner"), datasets=("m",), seeds=(0, 1, 2))
    runs = B.suite_runs(sp, {"m": ("/d/m", "maze-large", "stitch")})
    suite_planner = {"legs": "corridor", "max_edge": 8.5, "min_leg": 1.0}
    for r, (flat, planned) in zip(runs, [(0.1, 0.7), (0.2, 0.8), (0.3, 0.9)]):
        _summary(tmp_path / "runs" / r.name(), "maze", "none", flat)
        _summary(tmp_path / "runs" / r.name(), "maze", "graph", planned, **suite_planner)
        # another planner variant flown on the same run (a study's) is not the agent's row
        _summary(tmp_path / "runs" / r.name(), "maze", "graph", 0.0, "maze-adjacent-study", max_edge=2.5, min_leg=1.0)
    rows = B.leaderboard(tmp_path, sp, runs)
    by = {r["agent"]: r for r in rows}
    assert by["gcsl"]["stats"]["values"] == pytest.approx([10, 20, 30])
    assert by["gcsl+planner"]["stats"]["mean"] == pytest.approx(80)
    assert by["gcsl"]["seeds"] == [0, 1, 2]
    B.write_leaderboard(tmp_path, rows)
    md = (tmp_path / "leaderboard.md").read_text()
    assert "80.0 ± 10.0" in md and "gcsl+planner" in md
    csv = (tmp_path / "leaderboard.csv").read_text().splitlines()
    assert csv[0].startswith("dataset,task,agent,mean") and len(csv) == 3
    assert (tmp_path / "leaderboard.png").stat().st_size > 1000


def test_command_line_errors_are_one_line(capsys):
    assert B.main(["suite", "--agents", "nope", "-o", "/tmp/unused"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown agent" in err[0]
    assert B.main(["suite", "--datasets", "maze-nowhere", "-o", "/tmp/unused"]) == 2
    assert "unknown dataset" in capsys.readouterr().err
