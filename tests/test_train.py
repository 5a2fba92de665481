"""Trainer, checkpoints, resume (also after kill -9), bad input, the CLIs."""

import json
import os
import signal
import subprocess
import sys
import time
import warnings

import pytest
import torch

from aerohrl import runs
from aerohrl.algorithms import cli
from aerohrl.algorithms.config import ENSEMBLE_ALGORITHMS, make_config
from aerohrl.algorithms.data import load_dataset
from aerohrl.algorithms.synthetic import straight_columns
from aerohrl.algorithms.run import Run, load_checkpoint, read_metrics
from aerohrl.algorithms.trainer import TrainingDiverged, resume_run, start_run
from aerohrl.errors import UserError

warnings.filterwarnings("ignore", category=UserWarning)


def checkpoint_paths(run_dir):
    return Run(run_dir).checkpoints()


TINY = dict(hidden=(16, 16), critic_hidden=(16, 16), batch_size=32, steps=40, log_every=10, checkpoint_every=20, eval_every=0)


def _same(a, b):
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


@pytest.mark.parametrize(
    "algo,extra",
    [(a, {}) for a in ENSEMBLE_ALGORITHMS]  # the OGBench agents: tests/test_agents.py
    + [(a, {"ema_decay": 0.9, "mc_lower_bound": True, "amp": "bf16"}) for a in ENSEMBLE_ALGORITHMS]
    + [(a, {"critic_random_goal_prob": 0.3}) for a in ("gcsl", "td3bc")],
)
def test_resume_gives_same_weights(algo, extra, data, tmp_path):
    """Also with the EMA policy, Monte-Carlo-bounded targets and bf16 autocast."""
    torch.set_num_threads(1)
    cfg = make_config("cpu", algo=algo, dataset=str(data.info["path"]), **TINY, **extra)
    full = start_run(cfg, tmp_path / "full", data=data, progress=False)
    full.train()
    part = start_run(cfg, tmp_path / "part", data=data, progress=False)
    part.train(until=20)
    del part
    again = resume_run(tmp_path / "part", data=data, progress=False)
    assert again.step == 20
    again.train()
    assert again.step == full.step == 40
    assert _same(full.algo, again.algo)
    for name, opt in full.algo.optimizers().items():
        s1, s2 = opt.state_dict()["state"], again.algo.optimizers()[name].state_dict()["state"]
        assert all(torch.equal(s1[i]["exp_avg"], s2[i]["exp_avg"]) for i in s1)


def test_checkpoint_contents_and_logs(data, tmp_path):
    cfg = make_config("cpu", algo="gcsl", dataset=str(data.info["path"]), keep_checkpoints=1, **TINY)
    tr = start_run(cfg, tmp_path / "r", data=data, progress=False)
    tr.train()
    ck_paths = checkpoint_paths(tmp_path / "r")
    assert [p.name for p in ck_paths] == ["step-000000040.pt"]  # keep_checkpoints=1
    ck = load_checkpoint(ck_paths[-1])
    assert ck["step"] == 40 and ck["config"]["algo"] == "gcsl"
    assert ck["dataset"]["version"] == "synthetic-1"
    assert ck["dataset"]["checksum"] == data.info["checksum"]
    assert set(ck["optimizers"]) == {"actor", "critic"}
    assert {"torch", "sampler", "numpy", "python"} <= set(ck["rng"])
    assert any(k.startswith("normalizer.") for k in ck["model"])
    recs = read_metrics(tmp_path / "r")
    assert [r["step"] for r in recs] == [10, 20, 30, 40]
    assert all("loss_actor" in r and "loss_critic" in r and "steps_per_s" in r for r in recs)
    meta = json.loads((tmp_path / "r" / "config.json").read_text())
    assert meta["dataset"]["checksum"] == data.info["checksum"] and meta["config"]["steps"] == 40


def test_refuses_a_different_dataset(data, tmp_path):
    cfg = make_config("cpu", algo="gcsl", dataset=str(data.info["path"]), **TINY)
    start_run(cfg, tmp_path / "r", data=data, progress=False).train(until=20)
    other = load_dataset(straight_columns(n_eps=3, length=11, seed=7))
    with pytest.raises(UserError, match="version|checksum"):
        resume_run(tmp_path / "r", data=other, progress=False)
    cols = straight_columns()
    cols["observation.desired_goal"] = cols["observation.desired_goal"][:, :12]
    with pytest.raises(UserError, match="shape"):
        load_dataset(cols)


def test_nan_loss_stops_and_keeps_last_checkpoint(data, tmp_path):
    cfg = make_config("cpu", algo="td3bc", dataset=str(data.info["path"]), **TINY)
    tr = start_run(cfg, tmp_path / "r", data=data, progress=False)
    real = tr.algo.update

    def poisoned(batch):
        m = real(batch)
        if tr.step >= 25:
            m["loss_critic"] = torch.tensor(float("nan"))
        return m

    tr.algo.update = poisoned
    with pytest.raises(TrainingDiverged, match=r"loss_critic became NaN/inf at step 26.*step-000000020\.pt"):
        tr.train()
    assert [p.name for p in checkpoint_paths(tmp_path / "r")] == ["step-000000020.pt"]


def _cli(args, cwd=None):
    env = dict(os.environ, PYTHONWARNINGS="ignore", OMP_NUM_THREADS="1")
    return subprocess.run(
        [sys.executable, "-m", "aerohrl.algorithms.cli", *args], capture_output=True, text=True, env=env, cwd=cwd
    )


def test_cli_bad_input(dataset_dir, tmp_path):
    for args, _msg in [
        (["--algo", "ppo", "--dataset", str(dataset_dir)], "invalid choice: 'ppo'"),
        (["--algo", "gcsl", "--dataset", str(dataset_dir), "--preset", "huge"], "invalid choice: 'huge'"),
        (["--algo", "gcsl", "--dataset", str(tmp_path / "nothing")], "no dataset at"),
        (["--algo", "gcsl"], "--dataset is required"),
        (["--resume", str(tmp_path / "norun")], "no run at"),
    ] + ([] if torch.cuda.is_available() else [(["--algo", "gcsl", "--dataset", str(dataset_dir), "--device", "cuda"], "CUDA")]):
        try:
            code = cli.main(args + ["--out", str(tmp_path / "runs")])
        except SystemExit as e:  # a usage error found while parsing (a choice, a number): one line, exit 2
            code = e.code
        assert code == 2, args
    r = _cli(["--algo", "ppo", "--dataset", str(dataset_dir)])
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "train: error:" in r.stderr


def test_cli_damaged_dataset(dataset_dir, tmp_path, capsys):
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(dataset_dir, bad)
    f = next((bad / "data").rglob("*.parquet"))
    raw = bytearray(f.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    f.write_bytes(bytes(raw))
    assert cli.main(["--algo", "gcsl", "--dataset", str(bad), "--out", str(tmp_path / "runs"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "is damaged" in err and "checksum mismatch" in err and err.count("\n") == 0


def test_cli_train_show_and_resume_args(dataset_dir, tmp_path, capsys):
    out = tmp_path / "runs"
    args = [
        "--algo",
        "gcsl",
        "--dataset",
        str(dataset_dir),
        "--out",
        str(out),
        "--name",
        "g",
        "--quiet",
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
        "15",
        "--eval-episodes",
        "2",
        "--eval-horizon",
        "10",
    ]
    assert cli.main(args) == 0
    assert cli.main(args) == 2  # the run exists
    assert "use --resume" in capsys.readouterr().err
    assert cli.main(["--resume", str(out / "g"), "--batch-size", "8"]) == 2
    assert cli.main(["--resume", str(out / "g"), "--steps", "40", "--quiet"]) == 0
    recs = read_metrics(out / "g")
    assert any("eval/reach_desired/success" in r for r in recs)
    assert max(r["step"] for r in recs) == 40
    capsys.readouterr()
    assert runs.main(["show", str(out / "g")]) == 0
    text = capsys.readouterr().out
    assert "gcsl" in text and "version synthetic-1" in text and "40 / 40" in text
    assert (out / "g" / "learning_curve.png").stat().st_size > 1000
    assert runs.main(["show", str(tmp_path / "nope")]) == 2


@pytest.mark.slow
def test_kill9_then_resume_matches_uninterrupted(dataset_dir, tmp_path):
    """A run killed with SIGKILL resumes from its last checkpoint and ends with the same
    weights as a run that was never interrupted."""
    common = [
        "--algo",
        "td3bc",
        "--dataset",
        str(dataset_dir),
        "--out",
        str(tmp_path),
        "--quiet",
        "--hidden",
        "16",
        "16",
        "--critic-hidden",
        "16",
        "16",
        "--batch-size",
        "32",
        "--steps",
        "800",
        "--checkpoint-every",
        "50",
        "--log-every",
        "50",
        "--eval-every",
        "0",
        "--keep-checkpoints",
        "50",
    ]
    assert _cli(common + ["--name", "full"]).returncode == 0
    env = dict(os.environ, PYTHONWARNINGS="ignore", OMP_NUM_THREADS="1")
    p = subprocess.Popen(
        [sys.executable, "-m", "aerohrl.algorithms.cli", *common, "--name", "killed"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    ck_dir = tmp_path / "killed" / "checkpoints"
    t0 = time.time()
    while time.time() - t0 < 60 and len(list(ck_dir.glob("step-*.pt"))) < 3:
        time.sleep(0.02)
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    done = checkpoint_paths(tmp_path / "killed")
    assert done and int(done[-1].stem.split("-")[1]) < 800, "the run finished before it could be killed"
    for c in done:
        load_checkpoint(c)  # no checkpoint is half-written
    r = _cli(["--resume", str(tmp_path / "killed"), "--quiet"])
    assert r.returncode == 0, r.stderr
    a = load_checkpoint(checkpoint_paths(tmp_path / "full")[-1])
    b = load_checkpoint(checkpoint_paths(tmp_path / "killed")[-1])
    assert a["step"] == b["step"] == 800
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])
    steps = [r["step"] for r in read_metrics(tmp_path / "killed")]
    assert steps == sorted(steps) and len(steps) == len(set(steps)) == 16


def test_real_dataset_from_datagen_build(tmp_path):
    """A small dataset made by `datagen build` loads, relabels and trains; the closed-loop
    hook runs in the simulator with the dataset's vehicle."""
    build = pytest.importorskip("aerohrl.datagen.build")
    from aerohrl.datagen.spec import load_spec

    res = build.build(load_spec(None, goals=3), tmp_path / "datasets", progress=False, log=lambda *a, **k: None)
    data = load_dataset(res.path)
    assert data.info["version"] == res.path.name and data.num_episodes == 3
    assert torch.equal(
        data.achieved_goal[:-1][data.episode_end[:-1] > torch.arange(len(data) - 1)],
        data.state[1:, :15][data.episode_end[:-1] > torch.arange(len(data) - 1)],
    )  # contiguous episodes
    cfg = make_config("cpu", algo="gcsl", dataset=str(res.path), **dict(TINY, eval_every=20, eval_episodes=2, eval_horizon=15))
    tr = start_run(cfg, tmp_path / "run", data=data, progress=False)
    tr.train()
    evals = [r for r in read_metrics(tmp_path / "run") if "eval/reach_desired/success" in r]
    assert [r["step"] for r in evals] == [20, 40]


@pytest.mark.slow
def test_end_to_end_cpu_preset(tmp_path, capsys):
    """datagen build -> train (cpu preset networks, short) -> runs show, through the CLIs."""
    from aerohrl.datagen.cli import main as datagen_main

    assert datagen_main(["build", "--goals", "10", "--out", str(tmp_path / "datasets"), "--quiet"]) == 0
    ds = next((tmp_path / "datasets" / "quadrotor-reach").iterdir())
    assert (
        cli.main(
            [
                "--algo",
                "gcsl",
                "--dataset",
                str(ds),
                "--preset",
                "cpu",
                "--steps",
                "200",
                "--eval-every",
                "100",
                "--eval-episodes",
                "5",
                "--checkpoint-every",
                "100",
                "--log-every",
                "50",
                "--out",
                str(tmp_path / "runs"),
                "--name",
                "e2e",
                "--quiet",
            ]
        )
        == 0
    )
    assert runs.main(["show", str(tmp_path / "runs" / "e2e")]) == 0
    out = capsys.readouterr().out
    assert "200 / 200" in out and "eval @ 200" in out


def test_cosine_schedule_resumes_exactly(data, tmp_path):
    cfg = make_config("cpu", algo="td3awbc", dataset=str(data.info["path"]), lr_schedule="cosine", **TINY)
    full = start_run(cfg, tmp_path / "full", data=data, progress=False)
    full.train()
    lr_end = full.algo.optimizers()["actor"].param_groups[0]["lr"]
    assert lr_end < 0.1 * cfg.lr_actor
    part = start_run(cfg, tmp_path / "part", data=data, progress=False)
    part.train(until=20)
    again = resume_run(tmp_path / "part", data=data, progress=False)
    again.train()
    assert _same(full.algo, again.algo)
    with pytest.raises(UserError, match="lr_schedule must be one of constant, cosine"):
        make_config("cpu", lr_schedule="step")


def test_tensorboard_events_match_metrics_and_resume_purges(data, tmp_path, monkeypatch):
    """tb/ holds the metrics.jsonl scalars; a resumed run's events after its checkpoint are dropped,
    also when the resumed file's counter in its name sorts before the first's ("10" < "9")."""
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    from tensorboard.summary.writer import event_file_writer

    monkeypatch.setattr(event_file_writer, "_global_uid", event_file_writer.AtomicCounter(9))

    cfg = make_config("cpu", algo="gcsl", dataset=str(data.info["path"]), **TINY)
    evals = {"fake": lambda algo, step: {"success": step / 100}}
    tr = start_run(cfg, tmp_path / "r", data=data, progress=False, evaluators=evals)
    tr.cfg.eval_every = 20
    tr.train(until=30)  # logs 10, 20, 30; checkpoint at 20; events at 30 are then stale
    again = resume_run(tmp_path / "r", data=data, progress=False, evaluators=evals)
    again.cfg.eval_every = 20
    again.train()
    ea = EventAccumulator(str(tmp_path / "r" / "tb"))
    ea.Reload()
    recs = read_metrics(tmp_path / "r")
    for tag in ("loss_actor", "loss_critic", "steps_per_s", "eval/fake/success"):
        got = [(e.step, e.value) for e in ea.Scalars(tag)]
        want = [(r["step"], r[tag]) for r in recs if tag in r]
        assert [s for s, _ in got] == [s for s, _ in want], tag  # no step twice after the resume
        assert all(abs(a - b) <= 1e-6 * max(1.0, abs(b)) for (_, a), (_, b) in zip(got, want)), tag
    assert [e.step for e in ea.Scalars("loss_actor")] == [10, 20, 30, 40]
    assert [e.step for e in ea.Scalars("eval/fake/success")] == [20, 40]


def test_relabel_offset_flags_reach_the_sampler(data, tmp_path):
    a = cli.parser().parse_args(["--relabel-offset", "geometric", "--relabel-mean-offset", "12.5", "--relabel-window", "60"])
    ov = cli._overrides(a)
    assert ov == {"relabel_offset": "geometric", "relabel_mean_offset": 12.5, "relabel_window": 60}
    cfg = make_config("cpu", algo="gcsl", dataset=str(data.info["path"]), **TINY, **ov)
    tr = start_run(cfg, tmp_path / "r", data=data, progress=False)
    assert tr.sampler.future == {"strategy": "geometric", "mean": 12.5, "window": 60}
    assert json.loads((tmp_path / "r" / "config.json").read_text())["config"]["relabel_offset"] == "geometric"
    for bad, msg in [
        ({"relabel_offset": "final"}, "relabel_offset must be one of uniform, geometric, got 'final'"),
        ({"relabel_window": -1}, "relabel_window must be >= 0"),
        ({"relabel_mean_offset": 0.5}, "relabel_mean_offset must be >= 1"),
    ]:
        with pytest.raises(UserError, match=msg):
            make_config("cpu", **bad)
    with pytest.raises(SystemExit) as e:  # a choice: refused when the command line is parsed
        cli.main(["--algo", "gcsl", "--dataset", str(data.info["path"]), "--relabel-offset", "final"])
    assert e.value.code == 2


def test_learning_curve_reads_harness_results(tmp_path):
    """`runs show` plots every checkpoint `aerohrl eval` evaluated (RUN/eval/<task>/summary.json)."""
    d = tmp_path / "eval" / "reach-desired"
    d.mkdir(parents=True)
    rows = [{"step": 2000, "success": 0.5, "near_success": 0.8}, {"step": 1000, "success": 0.25, "near_success": 0.5}]
    (d / "summary.json").write_text(json.dumps({"checkpoints": rows}))
    (tmp_path / "eval" / "broken").mkdir()
    (tmp_path / "eval" / "broken" / "summary.json").write_text("{not json")
    from aerohrl.algorithms.runs import _harness_curves

    assert _harness_curves(tmp_path) == {"reach-desired": [(1000, 25.0, 50.0), (2000, 50.0, 80.0)]}


def test_auto_precision_follows_the_hardware_and_is_recorded(data, tmp_path, monkeypatch):
    """amp "auto" trains in bf16 only where the device multiplies bf16 natively; the run's
    config records the precision chosen, so its resume trains the same way on any machine."""
    from aerohrl import hardware
    from aerohrl.algorithms import trainer

    for native, want in ((True, "bf16"), (False, "none")):
        monkeypatch.setattr(hardware, "native_bf16", lambda device, native=native: native)
        cfg = make_config("cpu", **{**TINY, "steps": 20}, amp="auto")
        tr = trainer.start_run(cfg, tmp_path / want, data=data, progress=False)
        assert tr.cfg.amp == want and tr.precision.startswith(want)
        tr.train()
        saved = json.loads((tmp_path / want / "config.json").read_text())["config"]
        assert saved["amp"] == want
        monkeypatch.setattr(hardware, "native_bf16", lambda device, native=not native: native)
        assert resume_run(tmp_path / want, progress=False, overrides={"steps": 30}).cfg.amp == want
    assert make_config("cpu").amp == "auto" and make_config("thesis").amp == "none"
    with pytest.raises(ValueError, match="unknown amp mode"):
        hardware.resolve_amp("fp8")


def test_native_bf16_honours_the_isa_cap():
    """A CPU capped at AVX2 (ONEDNN_MAX_CPU_ISA, ATEN_CPU_CAPABILITY: what an AVX2-only CPU
    reports) has no native bf16; the describe line names the CPU's extensions."""
    code = "from aerohrl.hardware import native_bf16, describe_cpu; print(native_bf16('cpu')); print(describe_cpu())"
    env = {**os.environ, "ONEDNN_MAX_CPU_ISA": "AVX2", "ATEN_CPU_CAPABILITY": "avx2"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    native, line = r.stdout.splitlines()
    assert native == "False" and "cores" in line and "bf16" in line
