"""`aerohrl runs show`: an IPP run is shown (it crashed with KeyError: 'step'), and
the results of `aerohrl eval` appear in the text after an evaluation."""

from __future__ import annotations


from aerohrl.cli import main as aerohrl_main


def test_runs_show_an_ipp_run(tmp_path, capsys):
    from aerohrl.ipp.lattice import default_lattice
    from aerohrl.ipp.train import preset, train

    run = tmp_path / "ipp-run"
    train(preset("test"), default_lattice(), run)
    assert aerohrl_main(["runs", "show", str(run), "-o", str(tmp_path / "c.png")]) == 0
    out = capsys.readouterr()
    assert "informative path planning" in out.out and "iteration" in out.out and "search_efficiency" in out.out, out.out
    assert "Traceback" not in out.err and (tmp_path / "c.png").stat().st_size > 1000


def test_runs_show_lists_aerohrl_eval_results(tmp_path, capsys):
    import aerohrl

    ds = aerohrl.build_dataset(goals=8, seed=2, out=tmp_path / "ds")
    run = aerohrl.train(
        {
            "algo": "gcsl",
            "dataset": ds,
            "hidden": (16, 16),
            "critic_hidden": (16, 16),
            "batch_size": 32,
            "steps": 20,
            "log_every": 10,
            "checkpoint_every": 10,
            "eval_every": 0,
        },
        out=tmp_path / "runs",
        name="g",
    )
    assert aerohrl_main(["runs", "show", str(run.path), "--no-plot"]) == 0
    assert "eval:" not in capsys.readouterr().out
    assert aerohrl_main(["eval", "--task", "reach-desired", "--run", str(run.path), "--checkpoints", "2", "--episodes", "8"]) == 0
    capsys.readouterr()
    assert aerohrl_main(["runs", "show", str(run.path), "-o", str(tmp_path / "lc.png")]) == 0
    out = capsys.readouterr().out
    line = [ln for ln in out.splitlines() if ln.startswith("eval:")]
    assert len(line) == 1 and "reach-desired: success" in line[0] and "2 checkpoints x 8 episodes, steps 10..20" in line[0], out
