"""experiments/ipp_learned_targets.py: train over seeds (resumable), bench, the dated page.

The presets are swapped for the tiny ``test`` preset and the bench runs on 2 worlds."""

import os

import pytest

from conftest import load_experiment


@pytest.fixture
def study(monkeypatch):
    m = load_experiment("ipp_learned_targets")
    real, calls = m.ipp, []

    def tiny(argv):
        calls.append(list(argv))
        return real(["test" if x in m.PRESETS else x for x in argv])

    monkeypatch.setattr(m, "ipp", tiny)
    return m, calls


def test_runs_are_named_by_preset_and_seed():
    m = load_experiment("ipp_learned_targets")
    assert m.run_name("cpu", 7) == "ipp-cpu-b9250" and m.run_name("thesis", 9) == "ipp-thesis-b9250-s9"


def test_train_resume_and_bench_over_seeds(study, tmp_path):
    m, calls = study
    argv = [
        "--runs",
        str(tmp_path / "runs"),
        "--out",
        str(tmp_path / "bench"),
        "--presets",
        "cpu",
        "--seeds",
        "7",
        "8",
        "--envs",
        "2",
        "--results-dir",
        str(tmp_path / "pages"),
    ]
    assert m.main(argv) == 0
    assert [c[:2] for c in calls] == [["train", "--preset"], ["train", "--preset"], ["bench", "--all"]]
    runs = [str(tmp_path / "runs" / n) for n in ("ipp-cpu-b9250", "ipp-cpu-b9250-s8")]
    assert calls[-1][calls[-1].index("-o") + 2 :] == [
        "--run",
        runs[0],
        "--run",
        runs[1],
        "--run",
        runs[0] + "/best.pt",
        "--run",
        runs[1] + "/best.pt",
        "--quiet",
    ]
    (page,) = (tmp_path / "pages").glob("*-ipp-learned-targets.md")
    text = page.read_text()
    assert text.index("```\npython experiments/ipp_learned_targets.py --runs") < text.index("| planner |")
    assert "seeds 7, 8" in text and "DP-IPP" in text
    # a second pass trains nothing; a run whose last checkpoint is older than its log is resumed
    calls.clear()
    assert m.main(argv) == 0 and [c[0] for c in calls] == ["bench"]
    log = tmp_path / "runs" / "ipp-cpu-b9250-s8" / "metrics.jsonl"
    ck = log.parent / "checkpoint.pt"
    os.utime(log, (ck.stat().st_mtime + 10,) * 2)
    calls.clear()
    assert m.main(argv) == 0 and calls[0] == ["train", "--resume", runs[1], "--quiet"]
    # --bench-only refuses a run that is not there
    assert m.main([*argv, "--seeds", "9", "--bench-only"]) == 2
