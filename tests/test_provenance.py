"""Tracked runs: provenance in config.json, TensorBoard by default, wandb offline or a
one-line error, progress lines without a terminal."""

import importlib.util
import json
import os
import re
import subprocess
import sys
from importlib import metadata

import pytest

from aerohrl.algorithms import cli
from aerohrl.algorithms.config import make_config
from aerohrl.algorithms.provenance import git_state
from aerohrl.algorithms.trainer import ProgressLines, resume_run, start_run

TINY = dict(hidden=(16, 16), critic_hidden=(16, 16), batch_size=32, steps=40, log_every=10, checkpoint_every=20, eval_every=0)


def test_config_json_records_code_packages_and_machine(data, tmp_path):
    cfg = make_config("cpu", algo="gcsl", dataset=str(data.info["path"]), **TINY)
    tr = start_run(cfg, tmp_path / "r", data=data, progress=False)
    tr.train(until=20)
    meta = json.loads((tmp_path / "r" / "config.json").read_text())
    prov = meta["provenance"]
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    head = subprocess.run(["git", "-C", repo, "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode == 0:  # a checkout (CI's is a clone): the commit and a real dirty flag
        assert prov["git"]["commit"] == head.stdout.strip()
        assert isinstance(prov["git"]["dirty"], bool)
    v = prov["versions"]
    assert v["python"] == f"{sys.version_info.major}.{sys.version_info.minor}.{sys.version_info.micro}"
    for pkg in ("torch", "torchrl", "lerobot", "numpy"):
        assert v[pkg] == metadata.version(pkg), pkg
    m = prov["machine"]
    assert m["cpu"] and m["cpu_count"] == os.cpu_count() and m["torch_threads"] >= 1 and m["device"] == "cpu"
    assert m["gpu"] is None
    assert meta["logger"] == "tensorboard"
    assert list((tmp_path / "r" / "tb").glob("events.out.tfevents.*"))  # TensorBoard by default (a dependency)
    # a resume records its own provenance and the step it resumed at
    resume_run(tmp_path / "r", data=data, progress=False).train()
    meta = json.loads((tmp_path / "r" / "config.json").read_text())
    assert meta["provenance"] == prov and [r["step"] for r in meta["resumes"]] == [20]
    assert meta["resumes"][0]["versions"] == v


def test_git_state_outside_a_checkout(tmp_path):
    assert git_state(tmp_path) == {"commit": None, "dirty": None}


def test_git_state_sees_a_dirty_tree(tmp_path):
    env = dict(os.environ, GIT_AUTHOR_NAME="t", GIT_AUTHOR_EMAIL="t@t", GIT_COMMITTER_NAME="t", GIT_COMMITTER_EMAIL="t@t")
    run = lambda *a: subprocess.run(["git", "-C", str(tmp_path), *a], check=True, capture_output=True, env=env)  # noqa: E731
    run("init", "-q")
    (tmp_path / "f").write_text("1")
    run("add", "f")
    run("commit", "-qm", "x")
    st = git_state(tmp_path)
    assert re.fullmatch(r"[0-9a-f]{40}", st["commit"]) and st["dirty"] is False
    (tmp_path / "f").write_text("2")
    assert git_state(tmp_path)["dirty"] is True


def test_progress_lines_without_a_terminal(dataset_dir, tmp_path):
    """The CLI run as a job (stderr a file, no tty): one line every --progress-steps steps,
    with step, steps/s, the losses and the ETA."""
    env = dict(os.environ, PYTHONWARNINGS="ignore", OMP_NUM_THREADS="1")
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "aerohrl.algorithms.cli",
            "--algo",
            "td3bc",
            "--dataset",
            str(dataset_dir),
            "--out",
            str(tmp_path),
            "--name",
            "j",
            "--hidden",
            "8",
            "8",
            "--critic-hidden",
            "8",
            "--batch-size",
            "16",
            "--steps",
            "30",
            "--log-every",
            "10",
            "--checkpoint-every",
            "10",
            "--eval-every",
            "0",
            "--progress-steps",
            "10",
            "--progress-every",
            "0",
        ],
        capture_output=True,
        text=True,
        env=env,
        stdin=subprocess.DEVNULL,
    )
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("train td3bc j: step")]
    assert [int(re.search(r"step (\d+)/30", ln).group(1)) for ln in lines] == [10, 20, 30]
    for ln in lines:
        assert re.search(r"\d+\.\d steps/s", ln) and "loss_actor" in ln and "loss_critic" in ln and "ETA" in ln, ln
    assert "ETA 0m00s" in lines[-1]


def test_progress_lines_by_time():
    import io

    out = io.StringIO()
    pl = ProgressLines("x", 0, 100, every_s=3600.0, out=out)
    for s in range(1, 51):
        pl.update(s, {"loss": 1.0})
    assert out.getvalue() == ""  # an hour has not passed
    pl.every_s = 1e-9
    pl.update(51, {"loss": 3.0})
    text = out.getvalue()
    assert "step 51/100 (51.0%)" in text and "loss 1.039" in text  # the mean of the 51 steps since the start


def test_logger_errors(dataset_dir, tmp_path, capsys):
    args = ["--algo", "gcsl", "--dataset", str(dataset_dir), "--out", str(tmp_path), "--steps", "5", "--quiet"]
    assert cli.main(args + ["--logger", "mlflow"]) == 2
    assert "unknown logger 'mlflow'" in capsys.readouterr().err
    if importlib.util.find_spec("wandb") is None:
        assert cli.main(args + ["--logger", "wandb"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "pip install wandb" in err
        assert not any(tmp_path.iterdir())  # refused before a run folder was made


def test_logger_wandb_offline(data, tmp_path, monkeypatch):
    pytest.importorskip("wandb")
    monkeypatch.setenv("WANDB_MODE", "offline")
    cfg = make_config("cpu", algo="gcsl", dataset=str(data.info["path"]), **TINY)
    start_run(cfg, tmp_path / "w", data=data, progress=False, logger="wandb").train()
    assert list((tmp_path / "w" / "wandb").glob("offline-run-*"))


def test_no_logger(data, tmp_path):
    cfg = make_config("cpu", algo="gcsl", dataset=str(data.info["path"]), **TINY)
    start_run(cfg, tmp_path / "n", data=data, progress=False, logger="none").train()
    assert not (tmp_path / "n" / "tb").exists() and (tmp_path / "n" / "metrics.jsonl").exists()
