"""The `datagen` and `aerohrl` commands: outputs, and bad input as one line + non-zero exit."""

import os
import subprocess
import sys

import pytest


def run(*args, cwd=None):
    env = dict(os.environ, HF_HUB_OFFLINE="1")
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=300)


def assert_one_line_error(p):
    assert p.returncode != 0, p.stdout
    assert "Traceback" not in p.stderr, p.stderr
    lines = [l for l in p.stderr.splitlines() if l.strip()]
    assert len(lines) == 1 and "error" in lines[0], p.stderr


@pytest.mark.parametrize(
    "flags",
    [
        ["--goals", "0"],
        ["--goals", "-3"],
        ["--goals", "many"],
        ["--pos-range", "2", "1"],
        ["--vel-range", "1", "1"],
        ["--acc-range", "5", "-5"],
        ["--solver", "magic"],
        ["--vehicle", "blimp"],
        ["--spec", "/nonexistent.toml"],
        ["--seed", "-1"],
        ["--fps", "0"],
        ["--a-max", "-1"],
        ["--t-max", "nan"],
        ["--continuations", "-2"],
    ],
)
def test_build_bad_input(flags, tmp_path):
    assert_one_line_error(run("aerohrl.datagen.cli", "build", "--out", str(tmp_path), *flags))


def test_build_unwritable_output(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    target = "/proc/aerohrl-cannot-write" if os.geteuid() == 0 else str(ro)
    p = run("aerohrl.datagen.cli", "build", "--goals", "2", "--out", target)
    assert_one_line_error(p)


@pytest.mark.parametrize(
    "cmd", [["validate"], ["info"], ["plot", "-o", "x.png"], ["export-mcap", "--episode", "0", "-o", "x.mcap"]]
)
def test_missing_dataset(cmd, tmp_path):
    assert_one_line_error(run("aerohrl.datagen.cli", cmd[0], str(tmp_path / "nope"), *cmd[1:], cwd=tmp_path))


def test_cli_round_trip_and_damage(tmp_path):
    p = run("aerohrl.cli", "datagen", "build", "--goals", "4", "--seed", "3", "--out", str(tmp_path))
    assert p.returncode == 0, p.stderr
    assert "expert success rate" in p.stdout
    path = p.stdout.strip().splitlines()[-1]
    assert os.path.isdir(path)
    info = run("aerohrl.datagen.cli", "info", path)
    assert info.returncode == 0 and "all match" in info.stdout, info.stdout + info.stderr
    assert run("aerohrl.datagen.cli", "validate", path).returncode == 0
    assert_one_line_error(run("aerohrl.datagen.cli", "export-mcap", path, "--episode", "99", "-o", str(tmp_path / "e.mcap")))
    # flip one byte of the dataset card: validate must fail
    card = os.path.join(path, "README.md")
    raw = bytearray(open(card, "rb").read())
    raw[10] ^= 0x20
    open(card, "wb").write(bytes(raw))
    v = run("aerohrl.datagen.cli", "validate", path)
    assert v.returncode != 0 and "README.md" in v.stderr and "Traceback" not in v.stderr


def test_build_that_cannot_fit_is_refused_before_it_starts(tmp_path):
    """The probe `--goals 100000000`: an estimate, then a one-line refusal (about 21 TB of memory)."""
    p = run("aerohrl.datagen.cli", "build", "--goals", "100000000", "--out", str(tmp_path))
    assert_one_line_error(p)
    assert "needs about" in p.stderr and "memory" in p.stderr and "--force" in p.stderr
    assert "estimate: 100,000,000 episodes" in p.stdout
    assert not list((tmp_path / "quadrotor-reach").iterdir())


def test_reading_commands_warn_on_a_damaged_dataset(tmp_path, capsys):
    from aerohrl.datagen.build import build
    from aerohrl.datagen.cli import main
    from aerohrl.datagen.spec import DatasetSpec

    path = build(DatasetSpec(goals=3, seed=4), tmp_path, progress=False, log=lambda *a: None).path
    for cmd in (
        ["info"],
        ["plot", "-o", str(tmp_path / "g.png")],
        ["export-mcap", "--episode", "0", "-o", str(tmp_path / "e.mcap")],
    ):
        assert main([cmd[0], str(path), *cmd[1:]]) == 0
        assert "warning" not in capsys.readouterr().err
    card = path / "README.md"
    card.write_bytes(card.read_bytes().replace(b"Expert", b"expert", 1))
    for cmd in (
        ["info"],
        ["plot", "-o", str(tmp_path / "g.png")],
        ["export-mcap", "--episode", "0", "-o", str(tmp_path / "e.mcap")],
    ):
        assert main([cmd[0], str(path), *cmd[1:]]) == 0, cmd
        err = capsys.readouterr().err.strip()
        assert (
            err == f"datagen: warning: dataset {path} is damaged: checksum mismatch: README.md; "
            f"`datagen validate {path}` lists every problem; what follows may be wrong"
        ), cmd


def test_umbrella_unknown_command():
    assert_one_line_error(run("aerohrl.cli", "fly"))


@pytest.mark.slow
def test_demo_pipeline_end_to_end(tmp_path):
    """README command 1's steps on the default spec: build 250 goals, validate, info, plot, MCAP."""
    p = run("aerohrl.datagen.cli", "build", "--goals", "250", "--out", str(tmp_path))
    assert p.returncode == 0, p.stderr
    rate = float(p.stdout.split("expert success rate:")[1].split("%")[0])
    assert rate >= 98.0, p.stdout
    path = p.stdout.strip().splitlines()[-1]
    for args in (
        ["validate", path],
        ["info", path],
        ["plot", path, "-o", str(tmp_path / "g.png")],
        ["export-mcap", path, "--episode", "3", "-o", str(tmp_path / "ep3.mcap")],
    ):
        q = run("aerohrl.datagen.cli", *args)
        assert q.returncode == 0, (args, q.stderr)
    assert (tmp_path / "g.png").stat().st_size > 10_000 and (tmp_path / "ep3.mcap").stat().st_size > 1_000
    # an external project loads it with lerobot's own class
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("aerohrl/quadrotor-reach", root=path)
    assert ds.num_episodes == 250
