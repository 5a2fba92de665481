"""Runs and checkpoints as safe as the datasets: exclusive run folders,
checkpoint checksums with fallback, killed writes, a full disk, arguments checked before
anything is created, moved datasets, metric lines across a resume."""

import json
import shutil
import warnings

import pytest
import torch

from aerohrl import atomic, runs
from aerohrl.algorithms import cli
from aerohrl.algorithms.config import make_config
from aerohrl.algorithms.data import load_dataset
from aerohrl.algorithms.synthetic import write_synthetic_dataset
from aerohrl.algorithms.run import Run, RunLock, load_checkpoint, new_run_dir, read_metrics
from aerohrl.algorithms.trainer import resume_run, start_run
from aerohrl.cli import main as aerohrl_main
from aerohrl.errors import UserError

warnings.filterwarnings("ignore", category=UserWarning)


def checkpoint_paths(run_dir):
    return Run(run_dir).checkpoints()


TINY = dict(hidden=(16, 16), critic_hidden=(16, 16), batch_size=32, steps=40, log_every=10, checkpoint_every=20, eval_every=0)
FLAGS = [
    "--hidden",
    "16",
    "16",
    "--critic-hidden",
    "16",
    "16",
    "--batch-size",
    "32",
    "--log-every",
    "10",
    "--checkpoint-every",
    "20",
    "--eval-every",
    "0",
    "--quiet",
]


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory):
    # named by its version, as `datagen build` names its folders (datasets/<name>/<version>)
    return write_synthetic_dataset(tmp_path_factory.mktemp("proj") / "datasets" / "synthetic" / "synthetic-1")


@pytest.fixture(scope="module")
def data(dataset_dir):
    return load_dataset(dataset_dir)


@pytest.fixture(scope="module")
def trained(data, tmp_path_factory):
    """A finished 40-step run with checkpoints at 20 and 40 (copied by the tests that damage it)."""
    torch.set_num_threads(1)
    run = tmp_path_factory.mktemp("runs") / "g"
    start_run(make_config("cpu", algo="gcsl", dataset=str(data.info["path"]), **TINY), run, data=data, progress=False).train()
    return run


def _copy(run, tmp_path):
    dst = tmp_path / run.name
    shutil.copytree(run, dst)
    return dst


def _one_line(err: str) -> str:
    err = err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    return err


# ----------------------------------------------------------------------------- run folders


def test_a_taken_run_name_is_refused_and_the_other_run_untouched(dataset_dir, tmp_path, capsys):
    out = tmp_path / "runs"
    (out / "g").mkdir(parents=True)  # another `train --name g` has just claimed it
    (out / "g" / "marker").write_text("theirs")
    assert (
        cli.main(["--algo", "gcsl", "--dataset", str(dataset_dir), "--out", str(out), "--name", "g", "--steps", "20", *FLAGS])
        == 2
    )
    err = _one_line(capsys.readouterr().err)
    assert "train: error: run folder" in err and "is taken" in err and "--name" in err
    assert [p.name for p in (out / "g").iterdir()] == ["marker"]


def test_start_run_claims_its_folder_exclusively(data, tmp_path):
    cfg = make_config("cpu", algo="gcsl", dataset=str(data.info["path"]), **TINY)
    start_run(cfg, tmp_path / "r", data=data, progress=False)
    with pytest.raises(UserError, match="exists; use --resume"):
        start_run(cfg, tmp_path / "r", data=data, progress=False)


def test_default_names_started_in_one_second_differ():
    cfg = make_config("cpu", algo="gcsl", dataset="x")
    names = {new_run_dir(cfg, "runs").name for _ in range(50)}
    assert len(names) == 50 and all(n.startswith("gcsl-cpu-s0-") for n in names)


def test_a_run_being_trained_cannot_be_resumed_twice(trained, tmp_path, capsys):
    run = _copy(trained, tmp_path)
    lock = RunLock(run)
    try:
        assert cli.main(["--resume", str(run), "--steps", "60", "--quiet"]) == 2
        assert "being trained by another process" in _one_line(capsys.readouterr().err)
    finally:
        lock.release()


@pytest.mark.parametrize(
    "flags,msg",
    [
        (["--seed", "-1"], "--seed: must be >= 0"),
        (["--lr-actor", "-1"], "--lr-actor: must be > 0"),
        (["--lr-critic", "0"], "--lr-critic: must be > 0"),
        (["--batch-size", "0"], "--batch-size: must be >= 1"),
        (["--steps", "0"], "--steps: must be >= 1"),
        (["--hidden", "16", "0"], "--hidden: must be >= 1"),
        (["--gamma", "nan"], "--gamma: must be a finite number"),
        (["--tau", "2"], "tau"),
        (["--relabel-prob", "1.5"], "--relabel-prob: must be <= 1"),
        (["--device", "tpu"], "unknown device"),
    ]
    + ([] if torch.cuda.is_available() else [(["--device", "cuda"], "no CUDA device")]),
)
def test_bad_arguments_fail_before_the_run_folder_exists(flags, msg, dataset_dir, tmp_path, capsys):
    out = tmp_path / "runs"
    try:
        code = cli.main(["--algo", "gcsl", "--dataset", str(dataset_dir), "--out", str(out), *flags])
    except SystemExit as e:  # argparse: a parse-time check (aerohrl.cli_types)
        code = e.code
    assert code == 2
    err = _one_line(capsys.readouterr().err)
    assert err.startswith("train: error:") and msg in err
    assert not out.exists()


def test_a_full_disk_at_the_start_is_one_line_and_leaves_no_run_folder(dataset_dir, small_disk, capsys):
    small_disk.fill()
    out = small_disk.path / "runs"
    assert (
        cli.main(["--algo", "gcsl", "--dataset", str(dataset_dir), "--out", str(out), "--name", "g", "--steps", "20", *FLAGS])
        == 2
    )
    err = _one_line(capsys.readouterr().err)
    assert err.startswith("train: error: cannot write") and "No space left on device" in err
    assert not (out / "g").exists()


# ----------------------------------------------------------------------------- checkpoints


def _damage(path, how: str) -> None:
    raw = path.read_bytes()
    if how == "flip":
        b = bytearray(raw)
        b[len(b) // 2] ^= 0x01  # a weight's bytes: torch alone would load it
        path.write_bytes(bytes(b))
    elif how == "truncate":
        path.write_bytes(raw[: len(raw) // 2])
    else:
        path.write_bytes(b"")


@pytest.mark.parametrize("how", ["flip", "truncate", "empty"])
def test_damaged_newest_checkpoint(how, trained, data, tmp_path, capsys):
    """eval and runs show name it; --resume falls back to the previous one, says so, and
    ends with the uninterrupted run's weights."""
    run = _copy(trained, tmp_path)
    newest = run / "checkpoints" / "step-000000040.pt"
    _damage(newest, how)
    assert aerohrl_main(["eval", "--task", "reach-desired", "--run", str(run), "--episodes", "2", "--quiet"]) == 2
    err = _one_line(capsys.readouterr().err)
    assert err.startswith("aerohrl eval: error: checkpoint") and str(newest) in err and "damaged" in err

    assert runs.main(["show", str(run), "--no-plot"]) == 0
    shown = capsys.readouterr().out
    assert "checkpoint at step 20 / 40" in shown and "DAMAGED:   step-000000040.pt" in shown

    assert cli.main(["--resume", str(run), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert f"train: warning: checkpoint {newest} is damaged" in err and "set aside as step-000000040.pt.damaged" in err
    assert "at step 20 from" in err and "step-000000020.pt (the newest intact checkpoint)" in err
    a, b = load_checkpoint(trained / "checkpoints" / "step-000000040.pt"), load_checkpoint(newest)
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])
    assert (run / "checkpoints" / "step-000000040.pt.damaged").exists()
    assert runs.main(["show", str(run), "--no-plot"]) == 0
    assert "set aside: step-000000040.pt.damaged" in capsys.readouterr().out


def test_checkpoints_from_before_checksums_load_with_one_warning(trained, tmp_path, capsys):
    run = _copy(trained, tmp_path)
    for side in (run / "checkpoints").glob("*.sha256"):
        side.unlink()
    assert aerohrl_main(["eval", "--task", "reach-desired", "--run", str(run), "--episodes", "2", "--quiet"]) == 0
    err = capsys.readouterr().err.strip()
    assert (
        err == f"aerohrl eval: warning: the checkpoints in {run / 'checkpoints'} have no .sha256 files "
        "(written before checkpoints had checksums); loaded unverified"
    )  # once for both checkpoints
    assert runs.main(["show", str(run), "--no-plot"]) == 0
    assert "DAMAGED" not in capsys.readouterr().out  # their zip CRCs hold
    _damage(run / "checkpoints" / "step-000000040.pt", "flip")
    assert runs.main(["show", str(run), "--no-plot"]) == 0
    shown = capsys.readouterr().out
    assert "DAMAGED:   step-000000040.pt" in shown and "fails its CRC" in shown


def test_no_intact_checkpoint_is_one_line_with_a_hint(trained, tmp_path, capsys):
    run = _copy(trained, tmp_path)
    for p in checkpoint_paths(run):
        _damage(p, "flip")
    assert cli.main(["--resume", str(run), "--quiet"]) == 2
    err = _one_line(capsys.readouterr().err)
    assert "no intact checkpoint to resume from" in err and "step-000000040.pt is damaged" in err and "start the run over" in err


def test_a_killed_checkpoint_write_leaves_nothing_after_the_next_start(trained, data, tmp_path, dead_pid):
    run = _copy(trained, tmp_path)
    partial = run / "checkpoints" / f".step-000000060.pt.tmp-{dead_pid}.pt"  # what kill -9 mid-write leaves
    partial.write_bytes(b"\0" * 1000)
    resume_run(run, data=data, progress=False, overrides={"steps": 60})
    assert not partial.exists()


def test_full_disk_during_a_checkpoint_keeps_the_last_good_one(data, small_disk):
    run = small_disk.path / "r"
    cfg = make_config("cpu", algo="gcsl", dataset=str(data.info["path"]), **TINY)
    tr = start_run(cfg, run, data=data, progress=False)
    tr.train(until=20)
    small_disk.fill(leave=16_000)  # metric lines still fit, a 126 kB checkpoint does not
    with pytest.raises(UserError) as e:
        tr.train()
    assert "step-000000040.pt: No space left on device" in str(e.value) and "\n" not in str(e.value)
    assert [p.name for p in checkpoint_paths(run)] == ["step-000000020.pt"] and atomic.verify(checkpoint_paths(run)[0])
    assert not [p for p in run.rglob("*") if ".tmp-" in p.name]
    small_disk.free()
    again = resume_run(run, data=data, progress=False)
    assert again.step == 20 and again.train() == 40


# ----------------------------------------------------------------------------- datasets and metrics


def test_runs_find_a_moved_dataset_by_version_or_say_dataset(dataset_dir, tmp_path, monkeypatch, capsys):
    proj = tmp_path / "proj"
    shutil.copytree(dataset_dir.parents[2], proj)  # proj/datasets/synthetic/synthetic-1
    monkeypatch.chdir(proj)
    args = ["--algo", "gcsl", "--dataset", "datasets/synthetic/synthetic-1", "--name", "g", "--steps", "20", *FLAGS]
    assert cli.main(args) == 0
    meta = json.loads((proj / "runs" / "g" / "config.json").read_text())
    absolute = str((proj / "datasets" / "synthetic" / "synthetic-1").resolve())
    assert meta["dataset"]["path"] == meta["config"]["dataset"] == absolute and meta["dataset"]["version"] == "synthetic-1"
    moved = tmp_path / "moved"
    proj.rename(moved)  # the whole project elsewhere: the recorded path is gone
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    assert (
        aerohrl_main(["eval", "--task", "reach-desired", "--run", str(moved / "runs" / "g"), "--episodes", "2", "--quiet"]) == 0
    )
    assert "using " + str(moved / "datasets" / "synthetic" / "synthetic-1") in capsys.readouterr().err
    shutil.rmtree(moved / "datasets")
    assert cli.main(["--resume", str(moved / "runs" / "g"), "--steps", "30", "--quiet"]) == 2
    err = _one_line(capsys.readouterr().err)
    assert "is missing" in err and "pass --dataset PATH" in err


def test_the_first_metric_line_after_a_resume_is_the_uninterrupted_one(data, tmp_path):
    cfg = make_config("cpu", algo="td3bc", dataset=str(data.info["path"]), **dict(TINY, checkpoint_every=15))
    start_run(cfg, tmp_path / "full", data=data, progress=False).train()
    part = start_run(cfg, tmp_path / "part", data=data, progress=False)
    part.train(until=15)  # stopped after the checkpoint at 15, halfway through the line of 20
    resume_run(tmp_path / "part", data=data, progress=False).train()

    def lines(run):
        return {r["step"]: {k: v for k, v in r.items() if k != "steps_per_s"} for r in read_metrics(run)}

    full, again = lines(tmp_path / "full"), lines(tmp_path / "part")
    assert sorted(again) == [10, 20, 30, 40] and again == full
    # a checkpoint from before the partial sums were saved: the line is marked, not silently shorter
    ck_path = tmp_path / "part" / "checkpoints" / "step-000000015.pt"
    ck = load_checkpoint(ck_path)
    del ck["metrics_acc"]
    atomic.torch_save(ck_path, ck)
    for p in checkpoint_paths(tmp_path / "part")[1:]:
        atomic.remove(p)
    resume_run(tmp_path / "part", data=data, progress=False).train()
    first = read_metrics(tmp_path / "part")[1]
    assert first["step"] == 20 and first["partial"] is True and "partial" not in read_metrics(tmp_path / "part")[2]
