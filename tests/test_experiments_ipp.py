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


def _sweep(folder, rows):
    """An ipp_budgets_envs.csv of (planner, label, budget, {env: search efficiency})."""
    folder.mkdir(parents=True)
    lines = ["planner,label,budget,env,kl,search_efficiency,steps"]
    for planner, label, budget, vals in rows:
        lines += [f"{planner},{label},{budget},{e},0.{e}0000,{v:.3f},10" for e, v in vals.items()]
    (folder / "ipp_budgets_envs.csv").write_text("\n".join(lines) + "\n")


def test_budget_curve_pairs_the_seed_mean_with_dp(tmp_path):
    m = load_experiment("ipp_budget_curve")
    dp = {0: 50.0, 1: 60.0, 2: 70.0}
    pc = {0: 55.0, 1: 65.0, 2: 90.0}  # the best baseline (mean 70)
    _sweep(tmp_path / "all", [("dp", "DP", b, dp) for b in (1000, 2000)] + [("prio_coverage", "PC", b, pc) for b in (1000, 2000)])
    # two seeds: per world +2 / +4 / +6 and +4 / +6 / +8 over DP -> seed mean +3 / +5 / +7
    _sweep(tmp_path / "s1", [("detect", "x", b, {e: v + 2 + 2 * e for e, v in dp.items()}) for b in (1000, 2000)])
    _sweep(tmp_path / "s2", [("detect", "x", b, {e: v + 4 + 2 * e for e, v in dp.items()}) for b in (1000, 2000)])
    md, curves = m.build([str(tmp_path / "all")], [["belief", f"{tmp_path}/s1:detect", f"{tmp_path}/s2:detect"]])
    # differences 3, 5, 7: mean 5, s.e. 2 / sqrt(3) = 1.15; every world better
    assert "| belief | 2 | 64.0 / 66.0 | 65.0 ± 1.4 | +5.00 ± 1.15 (3/0," in md
    assert curves["belief"][1000.0] == pytest.approx((65.0, 2**0.5))
    # seed mean 53 / 65 / 77 against 55 / 65 / 90: -2, 0, -13 (s.e. 7 / sqrt(3))
    assert "best baseline (Prioritised Coverage)" in md and "| -5.00 ± 4.04 (0/2," in md
    _sweep(tmp_path / "s3", [("detect", "x", 1000, {0: 1.0, 1: 2.0})])
    with pytest.raises(m.UserError, match="other worlds"):
        m.build([str(tmp_path / "all")], [["belief", f"{tmp_path}/s3:detect"]])
    assert m.main(["--baselines", str(tmp_path / "nowhere")]) == 2
