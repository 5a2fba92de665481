"""Time to a working skill: the trainer stops at the first evaluation that reaches
``stop_success`` (with a checkpoint there), the Reach-Novel hook flies the goals of
``aerohrl eval --task reach-novel``, and bench/bench_time_to_skill.py runs end to end on
a tiny setting."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np

from aerohrl.algorithms import config as C
from aerohrl.algorithms.trainer import start_run

BENCH = Path(__file__).resolve().parent.parent / "bench" / "bench_time_to_skill.py"


def _tiny_run(tmp_path, data, evaluator, **settings):
    """A run of tiny networks in ``tmp_path/run`` whose periodic evaluation is ``evaluator`` (named "fake")."""
    cfg = C.make_config("cpu", hidden=(8,), critic_hidden=(8,), batch_size=8, **settings)
    return start_run(cfg, tmp_path / "run", data=data, progress=False, logger="none", evaluators={"fake": evaluator})


def test_training_stops_at_the_first_evaluation_that_reaches_the_target(tmp_path, data):
    scores = iter([0.2, 0.6, 0.9])
    tr = _tiny_run(tmp_path, data, lambda algo, step: {"success": next(scores)}, steps=100, eval_every=10, stop_success=0.5)
    assert tr.train() == 20 and tr.stopped_at == 20
    assert tr.run.checkpoints()[-1].name.startswith("step-") and "20" in tr.run.checkpoints()[-1].name
    evals = [json.loads(x) for x in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines() if "eval/fake/success" in x]
    assert [e["step"] for e in evals] == [10, 20]


def test_evaluations_start_at_eval_start_and_the_last_step_is_always_evaluated(tmp_path, data):
    seen = []
    tr = _tiny_run(
        tmp_path, data, lambda algo, step: seen.append(step) or {"success": 0.0}, steps=55, eval_every=10, eval_start=30
    )
    tr.train()
    assert seen == [30, 40, 50, 55]


def test_reach_novel_hook_flies_the_eval_tasks_goals(data):
    from aerohrl.algorithms import closed_loop
    from aerohrl.eval.tasks import reach_novel

    seen = {}

    def fake(goals, data, cfg):
        seen["goals"] = goals
        return lambda algo, step: {}

    cfg = C.make_config("cpu", eval_task="reach-novel", eval_episodes=7)
    orig = closed_loop._reach_evaluator
    closed_loop._reach_evaluator = fake
    try:
        closed_loop.make_reach_novel_evaluator(data, cfg)
    finally:
        closed_loop._reach_evaluator = orig
    np.testing.assert_array_equal(seen["goals"], reach_novel(data, 7, seed=0).goals)


def test_the_bench_runs_on_a_tiny_setting(dataset_dir, capsys):
    spec = importlib.util.spec_from_file_location("bench_time_to_skill", BENCH)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    argv = [
        "--seeds",
        "0",
        "--dataset",
        str(dataset_dir),
        "--steps",
        "20",
        "--eval-every",
        "10",
        "--eval-start",
        "0",
        "--episodes",
        "3",
    ]
    assert bench.main(argv) == 0
    out = capsys.readouterr().out
    assert "torch capability" in out and "target 90 % on 3 episodes" in out
    row = next(line for line in out.splitlines() if line.split()[:1] == ["0"])
    assert row.split()[1] == "no" and row.split()[5] in ("10", "20")
    assert "reached by 0 of 1 seeds" in out
