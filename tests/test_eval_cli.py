"""`aerohrl eval` end to end on a tiny synthetic run: files, numbers traceable to
episodes, tables, plots, one-line errors."""

import csv
import json
import warnings

import numpy as np
import pytest
import torch

from aerohrl.algorithms.config import make_config
from aerohrl.algorithms.synthetic import straight_columns, write_synthetic_dataset
from aerohrl.algorithms.trainer import start_run
from aerohrl.atomic import torch_save
from aerohrl.cli import main
from aerohrl.errors import UserError

warnings.filterwarnings("ignore", category=UserWarning)
TINY = dict(
    hidden=(16, 16),
    critic_hidden=(16, 16),
    batch_size=32,
    steps=40,
    log_every=10,
    checkpoint_every=20,
    eval_every=20,
    eval_episodes=2,
    eval_horizon=20,
)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("evalcli")
    ds = write_synthetic_dataset(root / "ds" / "a")
    other = write_synthetic_dataset(root / "ds" / "b", straight_columns(seed=5), version="synthetic-2")
    cfg = make_config("cpu", algo="gcsl", dataset=str(ds), **TINY)
    tr = start_run(cfg, root / "runs" / "gcsl", progress=False)
    tr.train()
    empty = root / "runs" / "empty"
    start_run(make_config("cpu", algo="td3bc", dataset=str(ds), **TINY), empty, progress=False)
    return {"root": root, "ds": ds, "other": other, "run": root / "runs" / "gcsl", "empty": empty}


def _err(capsys, argv):
    try:
        code = main(argv)
    except SystemExit as e:  # a usage error found while parsing (aerohrl.cli_types): one line, exit 2
        code = e.code
    err = capsys.readouterr().err.strip()
    return code, err


def test_reach_desired_files_trace_to_episodes(setup, capsys):
    run = setup["run"]
    assert main(["eval", "--task", "reach-desired", "--run", str(run), "--episodes", "4", "--quiet"]) == 0
    assert "reach-desired: gcsl" in capsys.readouterr().out
    d = run / "eval" / "reach-desired"
    s = json.loads((d / "summary.json").read_text())
    assert [c["step"] for c in s["checkpoints"]] == [20, 40] and s["episodes"] == 4
    rates = []
    for c in s["checkpoints"]:
        rows = list(csv.DictReader(open(d / f"episodes-step-{c['step']:09d}.csv")))
        assert len(rows) == 4 and {"goal_px", "start_px", "first_success_step", "final_pos_err"} <= set(rows[0])
        rates.append(np.mean([int(r["success"]) for r in rows]))
        assert c["success"] == rates[-1]
    assert s["success_mean"] == pytest.approx(np.mean(rates)) and s["success_std"] == pytest.approx(np.std(rates))
    assert (d / "trajectories-step-000000040.npz").exists()
    assert not list(d.glob(".*tmp*"))


def test_intermediate_ood_planners_table_and_plots(setup, capsys, tmp_path):
    run = setup["run"]
    common = ["--run", str(run), "--checkpoints", "1", "--quiet"]
    assert main(["eval", "--task", "reach-intermediate", "--episodes", "6", *common]) == 0
    s = json.loads((run / "eval" / "reach-intermediate" / "summary.json").read_text())
    assert set(s["checkpoints"][0]) >= {"success_desired", "success_intermediate"}
    ood = ["--task", "ood", "--episodes", "3", "--horizon", "90", "--candidates", "40", *common]
    assert main(["eval", *ood, "--planner", "none"]) == 0
    assert main(["eval", *ood, "--planner", "single", "--alpha", "0.5"]) == 0
    assert main(["eval", *ood, "--planner", "multi", "--waypoints", "2", "--beam", "3", "--replan-every", "10"]) == 0
    names = sorted(p.name for p in (run / "eval").glob("ood-*"))
    assert names == ["ood-multi2-replan10", "ood-none", "ood-single-a0.5"]
    rows = list(csv.DictReader(open(next((run / "eval" / "ood-multi2-replan10").glob("episodes-*.csv")))))
    assert {"wp0_frame", "wp1_frame", "plan_score", "legs_reached"} <= set(rows[0])
    for name in names:  # every variant flies the same goals for the same time
        r = list(csv.DictReader(open(next((run / "eval" / name).glob("episodes-*.csv")))))
        assert [x["goal_px"] for x in r] == [x["goal_px"] for x in rows] and {x["horizon"] for x in r} == {"90"}
    capsys.readouterr()
    assert main(["eval", "table", str(run), "-o", str(tmp_path / "t")]) == 0
    out = capsys.readouterr().out
    assert "Table 3.1" in out and "GCSL" in out and "93.2 ± 3.78" in out and "Table 3.2" in out
    assert (tmp_path / "t.md").exists() and (tmp_path / "t-t31.csv").exists() and (tmp_path / "t-t32.csv").exists()
    assert main(["eval", "plot", "--task", "ood", "--run", str(run), "-o", str(tmp_path / "ood.png")]) == 0
    assert main(["eval", "plot", "--task", "reach-desired", "--run", str(run), "-o", str(tmp_path / "rd.png")]) == 0
    assert main(["eval", "plot", "--curves", str(run), "-o", str(tmp_path / "c.png")]) == 0
    assert all((tmp_path / f).stat().st_size > 1000 for f in ("ood.png", "rd.png", "c.png"))


def test_beyond_hover_rate_is_success_on_the_episodes_the_hover_floor_misses(setup):
    run = setup["run"]
    common = ["--task", "reach-intermediate", "--run", str(run), "--episodes", "12", "--checkpoints", "1", "--quiet"]
    assert main(["eval", *common, "-o", str(run / "eval" / "ri12")]) == 0
    assert main(["eval", *common, "--floor", "hover"]) == 0

    def outcomes(name):
        d = run / "eval" / name
        rows = list(csv.DictReader(open(next(d.glob("episodes-*.csv")))))
        return np.array([int(r["success"]) for r in rows], bool), json.loads((d / "summary.json").read_text())["checkpoints"][0]

    policy, ck = outcomes("ri12")
    hover, ck_hover = outcomes("reach-intermediate-floor-hover")
    if hover.all():
        assert "success_beyond_hover" not in ck
    else:
        assert ck["success_beyond_hover"] == pytest.approx(policy[~hover].mean())
        assert ck_hover["success_beyond_hover"] == 0.0  # hover misses them all, by construction


@pytest.mark.parametrize(
    "case", ["task", "no-ckpt", "no-run", "mismatch", "empty-goals", "planner-task", "no-evals", "more-than-goals", "bad-seed"]
)
def test_bad_input_is_one_line(setup, capsys, case):
    run, empty = str(setup["run"]), str(setup["empty"])
    argv, match = {
        "task": (["eval", "--task", "reach-far", "--run", run], "invalid choice: 'reach-far'"),
        "no-ckpt": (["eval", "--task", "reach-desired", "--run", empty], "has no checkpoints"),
        "no-run": (["eval", "--task", "reach-desired", "--run", run + "-missing"], "no run at"),
        "mismatch": (["eval", "--task", "reach-desired", "--run", run, "--dataset", str(setup["other"])], "does not belong"),
        "empty-goals": (["eval", "--task", "reach-desired", "--run", run, "--episodes", "0"], "--episodes: must be >= 1"),
        "planner-task": (["eval", "--task", "reach-desired", "--run", run, "--planner", "single"], "ood only"),
        "no-evals": (["eval", "table", empty], "none of the runs has evaluation results"),
        "more-than-goals": (
            ["eval", "--task", "reach-desired", "--run", run, "--episodes", "5"],
            "--episodes 5 exceeds the 4 desired goals of dataset",
        ),
        "bad-seed": (["eval", "--task", "ood", "--run", run, "--seed", "-1"], "--seed: must be >= 0"),
    }[case]
    code, err = _err(capsys, argv)
    assert code == 2 and err.startswith("aerohrl eval: error: ") and match in err and "\n" not in err


def test_checkpoint_from_another_dataset_is_refused(setup, tmp_path, capsys):
    import shutil

    run = tmp_path / "mixed"
    shutil.copytree(setup["run"], run)
    ck = torch.load(run / "checkpoints" / "step-000000040.pt", weights_only=False)
    ck["dataset"]["checksum"] = "0" * 64
    torch_save(run / "checkpoints" / "step-000000040.pt", ck)  # a checkpoint written so, its SHA-256 beside it
    code, err = _err(capsys, ["eval", "--task", "reach-desired", "--run", str(run), "--episodes", "2"])
    assert code == 2 and "do not belong together" in err and "step-000000040.pt" in err


def test_results_page_is_dated_and_opens_with_its_command(tmp_path):
    from aerohrl.eval.results import write_results_page

    fig = tmp_path / "curves.png"
    fig.write_bytes(b"png")
    p = write_results_page(tmp_path / "pages", "chapter3-tables", "make results", "new table\n", figures=[fig], date="2026-12-02")
    assert p == tmp_path / "pages" / "2026-12-02-chapter3-tables.md"
    text = p.read_text()
    assert text.index("```\nmake results\n```") < text.index("new table")
    assert "](figures/2026-12-02-chapter3-tables-curves.png)" in text
    assert (tmp_path / "pages" / "figures" / "2026-12-02-chapter3-tables-curves.png").read_bytes() == b"png"
    p2 = write_results_page(tmp_path / "pages", "chapter3-tables", "make results", "newer\n", date="2026-12-02")
    assert p2 == p and "newer" in p.read_text()  # a second run on one day replaces its page
    for bad in ("Chapter 3", "../x", ""):
        with pytest.raises(UserError, match="lower-case"):
            write_results_page(tmp_path, bad, "c", "b")
    with pytest.raises(UserError, match="YYYY-MM-DD"):
        write_results_page(tmp_path, "x", "c", "b", date="yesterday")


@pytest.mark.slow
def test_make_results_pipeline_end_to_end(tmp_path):
    """`make results` in miniature: build, train two algorithms, evaluate, tables into a dated page."""
    import subprocess
    import sys
    from pathlib import Path

    pages = tmp_path / "pages"
    p = subprocess.run(
        [
            sys.executable,
            "experiments/reproduce.py",
            "--steps",
            "30",
            "--episodes",
            "6",
            "--checkpoints",
            "2",
            "--algos",
            "gcsl",
            "td3bc",
            "--seeds",
            "0",
            "1",
            "--continuations",
            "20",
            "--oracle-goals",
            "3",
            "--oracle-candidates",
            "8",
            "--datasets",
            str(tmp_path / "ds"),
            "--runs",
            str(tmp_path / "runs"),
            "--out",
            str(tmp_path / "res"),
            "--results-dir",
            str(pages),
            "--in-process",
        ],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parent.parent,
        timeout=1800,
    )  # generous: a loaded 2-core machine runs it several times slower (Ray start-up included)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    (page,) = pages.glob("*-chapter3-tables.md")
    text = page.read_text()
    assert text.index("```\npython experiments/reproduce.py --steps 30") < text.index("Reproduced by `make results`")
    assert (tmp_path / "res" / "results.md").read_text() in text
    assert "Table 3.1 analogue" in text and "Table 3.2 analogue" in text and "wall time" in text and "TD3-BC" in text
    assert "Oracle of the single-goal planner for gcsl" in text and "Reach-Novel" in text
    assert "(+1 seed: gcsl-cpu-s1)" in text and "floor: hover" in text  # rows over seeds, floors beside GCSL
    assert (tmp_path / "res" / "tables-t31.csv").exists() and (tmp_path / "res" / "ood-gcsl.png").exists()
    assert "Oracle of the single-goal planner for gcsl-cont" in text and "runs/gcsl-cpu-cont" in text
    assert (tmp_path / "res" / "ood-gcsl-cont.png").exists()


def test_in_process_command_lines_answer_as_subprocesses_do(tmp_path):
    """`experiments/reproduce.py --in-process` runs `python -m MODULE ARGS` as MODULE.main(ARGS):
    the same output and failure as the subprocess, one thread while it runs, the settings restored."""
    import io
    import os
    import sys

    from study_tools import run_logged

    bad = [sys.executable, "-m", "aerohrl.eval.cli", "table", str(tmp_path / "no-run")]
    errors = []
    for in_process in (False, True):
        log = io.StringIO()
        with pytest.raises(UserError) as e:
            run_logged(bad, log, in_process=in_process)
        errors.append((str(e.value), log.getvalue()))
    assert errors[0] == errors[1] and "(exit 2): aerohrl eval: error: no run at" in errors[0][0]
    threads, omp = torch.get_num_threads(), os.environ.get("OMP_NUM_THREADS")
    usage = run_logged([sys.executable, "-m", "aerohrl.eval.cli", "--help"], io.StringIO(), in_process=True)
    assert usage.startswith("usage: aerohrl eval")  # argparse's exit(0) is a success
    assert torch.get_num_threads() == threads and os.environ.get("OMP_NUM_THREADS") == omp


def test_make_results_keeps_evaluations_that_cover_the_newest_checkpoints(tmp_path):
    import json
    import os

    from aerohrl.eval.results import evaluation_is_current as _evaluated

    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    for step in (10, 20, 30):
        (run / "checkpoints" / f"step-{step:09d}.pt").write_bytes(b"x")
    f = run / "eval" / "reach-desired" / "summary.json"
    f.parent.mkdir(parents=True)
    f.write_text(json.dumps({"episodes": 6, "checkpoints": [{"checkpoint": f"step-{s:09d}.pt"} for s in (20, 30)]}))
    assert _evaluated(run, "reach-desired", 6, 2)
    assert not _evaluated(run, "reach-desired", 250, 2)  # other episodes
    assert not _evaluated(run, "reach-desired", 6, 3)  # other checkpoints
    assert not _evaluated(run, "reach-novel", 6, 2)  # never evaluated
    (run / "checkpoints" / "step-000000040.pt").write_bytes(b"x")  # trained on since
    assert not _evaluated(run, "reach-desired", 6, 2)
    os.utime(f, (1, 1))
    assert not _evaluated(run, "reach-desired", 6, 2)


def test_planner_is_compared_with_flying_straight_pairwise(tmp_path):
    from aerohrl.eval.results import paired_vs_none

    run = tmp_path / "run"
    rng = np.random.default_rng(0)
    won = {"planner": 0, "none": 0}
    diffs = []
    for step in (10, 20, 30):
        a, b = rng.random(200) < 0.3, rng.random(200) < 0.1
        won["planner"] += int((a & ~b).sum())
        won["none"] += int((b & ~a).sum())
        diffs.append(a.mean() - b.mean())
        for name, s in (("ood-single", a), ("ood-none", b)):
            d = run / "eval" / name
            d.mkdir(parents=True, exist_ok=True)
            (d / f"episodes-step-{step:09d}.csv").write_text(
                "episode,success,near_success\n" + "".join(f"{i},{int(x)},1\n" for i, x in enumerate(s))
            )
    (run / "eval" / "ood-single" / "episodes-step-000000040.csv").write_text("episode,success\n0,1\n")  # no partner
    pv = paired_vs_none(run, "ood-single")
    assert pv["checkpoints"] == 3 and pv["only_planner"] == won["planner"] and pv["only_none"] == won["none"]
    assert np.isclose(pv["diff"], np.mean(diffs)) and np.isclose(pv["se"], np.std(diffs, ddof=1) / np.sqrt(3))
    assert pv["p"] < 1e-6  # 30% against 10% on 600 paired episodes
    assert paired_vs_none(run, "ood-multi2") is None
