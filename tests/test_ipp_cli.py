"""`aerohrl ipp` command line: outputs and one-line errors."""

import numpy as np
import pytest

from aerohrl.ipp.cli import main


def test_lattice_build(tmp_path, capsys):
    out = tmp_path / "lat.npz"
    assert main(["lattice", "build", "-o", str(out), "--vertices", "5", "--reach", "5", "--max-edges", "8"]) == 0
    assert out.is_file() and out.with_suffix(".png").is_file()
    assert "5 vertices" in capsys.readouterr().out
    assert not list(tmp_path.glob(".*"))  # no temp files left


def test_bench_and_show(tmp_path, capsys):
    d = tmp_path / "b"
    assert main(["bench", "--planner", "greedy", "--envs", "3", "--budget", "1500", "--out", str(d), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "Greedy-IPP" in out and "54.4" in out  # thesis column beside ours
    for f in ("ipp_bench.md", "ipp_bench.csv", "ipp_bench_envs.csv", "ipp_kl.png"):
        assert (d / f).is_file()
    rows = (d / "ipp_bench_envs.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + 3
    png = tmp_path / "path.png"
    assert main(["show", "--env", "7", "--planner", "coverage", "--budget", "1500", "-o", str(png)]) == 0
    assert png.is_file() and png.stat().st_size > 1000


@pytest.mark.parametrize(
    "argv,msg",
    [
        (["bench", "--planner", "astar"], "unknown planner"),
        (["show", "--planner", "astar", "-o", "x.png"], "unknown planner"),
        (["bench", "--budget", "10"], "budget"),
        (["bench", "--budget", "nan"], "budget"),
        (["bench", "--map-size", "4"], "too small"),
        (["bench", "--map-size", "0"], "--map-size: must be >= 1"),
        (["bench", "--seed", "-1"], "--seed: must be >= 0"),
        (["bench", "--envs", "0"], "--envs"),
        (["bench", "--depth", "7", "--envs", "1"], "depth"),
        (["bench", "--lattice", "MISSING.npz"], "not found"),
        (["frobnicate"], "invalid choice"),
        (["bench", "--planner", "rl", "--envs", "1"], "needs --run"),
        (["bench", "--planner", "rl", "--run", "nowhere"], "no trained policy"),
        (["train", "--preset", "gpu-cluster"], "invalid choice: 'gpu-cluster'"),
        (["train", "--preset", "test", "--iterations", "-1"], "--iterations"),
        (["lattice", "build"], "required"),
        (["lattice", "build", "-o", "x.npz", "--vertices", "0"], "--vertices: must be >= 1"),
    ],
)
def test_bad_input_one_line_error(argv, msg, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("aerohrl ipp: error:") and msg in err
    assert "\n" not in err


def test_malformed_lattice_file(tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    np.savez(bad, x=np.zeros(3))
    assert main(["bench", "--lattice", str(bad), "--envs", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "not a lattice file" in err or "meta" in err


def test_train_then_bench_rl(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["train", "--preset", "test", "--out", str(run.parent), "--name", run.name, "--quiet"]) == 0
    assert (run / "model.pt").is_file() and (run / "config.json").is_file()
    assert (
        main(
            [
                "bench",
                "--planner",
                "rl",
                "--run",
                str(run),
                "--envs",
                "2",
                "--budget",
                "1500",
                "--out",
                str(tmp_path / "b"),
                "--quiet",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if "(run)" in line)
    # the truthful name: preset test = 2 DAgger iterations from detect + 1 PPO
    assert row.startswith("| Imitation of detect planner + PPO 1 it. (DAgger; its features, GRU) (run)")
    assert "88.5" in row and "Ours" not in row  # the thesis's RL-LSTM number beside it
    model = run / "model.pt"
    raw = bytearray(model.read_bytes())
    raw[len(raw) // 2] ^= 0x01  # a weight: torch alone would load it
    model.write_bytes(bytes(raw))
    assert (
        main(
            [
                "bench",
                "--planner",
                "rl",
                "--run",
                str(run),
                "--envs",
                "2",
                "--budget",
                "1500",
                "--out",
                str(tmp_path / "b"),
                "--quiet",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err.strip()
    assert err == f"aerohrl ipp: error: checkpoint {model} is damaged: its SHA-256 differs from model.pt.sha256"


def test_show_writes_figure_and_animated_gif(tmp_path, capsys):
    """IPP figures: the episode figure and a GIF with one frame per primitive."""
    png, gif = tmp_path / "ep.png", tmp_path / "ep.gif"
    assert main(["show", "--env", "2", "--planner", "greedy", "--budget", "1500", "-o", str(png), "--gif", str(gif)]) == 0
    from PIL import Image

    im = Image.open(gif)
    assert im.format == "GIF" and im.n_frames >= 3
    assert png.stat().st_size > 10_000
    assert main(["show", "--planner", "greedy", "-o", str(png), "--gif", str(tmp_path / "x.mp4")]) == 2
    assert "--gif must end in .gif" in capsys.readouterr().err


def test_budget_sweep_and_named_budgets(tmp_path, capsys):
    assert (
        main(["bench", "--planner", "greedy", "--envs", "2", "--budgets", "1500,tight", "--out", str(tmp_path), "--quiet"]) == 0
    )
    out = capsys.readouterr().out
    assert "| Greedy-IPP | 1500 |" in out and "| Greedy-IPP | 5000 |" in out
    for f in ("ipp_budgets.md", "ipp_budgets.csv", "ipp_budgets.png"):
        assert (tmp_path / f).is_file()
    import csv

    rows = list(csv.DictReader(open(tmp_path / "ipp_budgets.csv")))
    assert [r["budget"] for r in rows] == ["1500", "5000"]
    # a bigger budget flies further
    assert float(rows[1]["path_cells_mean"]) > 2 * float(rows[0]["path_cells_mean"])
    for bad in ("0", "-3", "nan", "lots", ""):
        assert main(["bench", "--budgets", bad]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("aerohrl ipp: error: argument --budgets") and "\n" not in err


def test_table_has_both_denominators_and_thesis_beside_padded(tmp_path, capsys):
    assert main(["bench", "--planner", "dp", "--envs", "2", "--budget", "1500", "--out", str(tmp_path), "--quiet"]) == 0
    lines = capsys.readouterr().out.splitlines()
    head = [c.strip() for c in lines[0].split("|")]
    row = [c.strip() for c in lines[2].split("|")]
    assert head.index("thesis cov (1600)") == head.index("coverage % (1600)") + 1
    assert head.index("thesis ent (1600)") == head.index("entropy red. % (1600)") + 1
    assert row[head.index("thesis cov (1600)")].startswith("57.8")  # DP-IPP, Table 2.1
    inner = float(row[head.index("coverage % (900)")].split()[0])
    padded = float(row[head.index("coverage % (1600)")].split()[0])
    assert padded < inner and padded >= inner * 900 / 1600 - 0.05


def test_compare_pairs_two_benches_over_their_worlds(tmp_path, capsys):
    def bench(name, planner, values, kl="0.1"):
        d = tmp_path / name
        d.mkdir()
        rows = ["planner,env,kl,search_efficiency,steps"] + [f"{planner},{i},{kl},{v},30" for i, v in enumerate(values)]
        (d / "ipp_bench_envs.csv").write_text("\n".join(rows) + "\n")
        return str(d)

    a = bench("a", "detect", [90, 80, 70, 60])
    b = bench("b", "dp", [88, 81, 66, 60])  # differences +2, -1, +4, 0
    assert main(["compare", a, b]) == 0
    out = capsys.readouterr().out
    assert "detect" in out and "dp" in out and "+1.25 ± 1.11" in out and "over 4 worlds" in out
    assert "better on 2, worse on 1" in out
    two = tmp_path / "two"
    two.mkdir()
    (two / "ipp_bench_envs.csv").write_text("planner,env,search_efficiency\ndp,0,1\ngreedy,0,2\n")
    for argv, msg in (
        (["compare", a, str(two)], "holds 2 planners"),
        (["compare", a, str(tmp_path / "none")], "no bench results"),
        (["compare", a, b, "--metric", "nope"], "no column 'nope'"),
        (["compare", a, bench("other-seed", "dp", [1, 2, 3, 4], kl="0.2")], "different worlds"),
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert msg in err and len(err.splitlines()) == 1
