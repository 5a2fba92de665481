"""``aerohrl sweep``: the grid, its file, bad inputs (fast); on local Ray, a sweep whose
worker is killed mid-run ends with the weights and the tables of an uninterrupted one,
and a rerun does nothing twice (slow)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from aerohrl import sweep
from aerohrl.algorithms.synthetic import write_synthetic_dataset


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory):
    return write_synthetic_dataset(tmp_path_factory.mktemp("ds") / "synthetic" / "v1")


def _main(args, capsys):
    code = sweep.main(args)
    return code, capsys.readouterr().err.strip()


def test_grid_points_and_names(dataset_dir):
    a = sweep.parser().parse_args(
        [
            "--out",
            "x",
            "--algos",
            "gcsl",
            "td3bc",
            "--seeds",
            "0",
            "1",
            "--datasets",
            str(dataset_dir),
            "--set",
            "steps=100",
            "--grid",
            "batch_size=32,64",
            "--grid",
            "hidden=[16,16],[32]",
        ]
    )
    sp = sweep.load_spec(None, a)
    pts = sweep.points(sp)
    assert len(pts) == 2 * 2 * 2 * 2 and len({p.name() for p in pts}) == 16
    assert "gcsl-v1-batch_size32-hidden16x16-s0" in {p.name() for p in pts}
    cfg = sweep._config(sp, pts[0])
    assert cfg.steps == 100 and cfg.hidden in ((16, 16), (32,)) and cfg.dataset == str(Path(dataset_dir).resolve())
    # the saved grid reads back as the same sweep
    f = Path(a.out).with_suffix(".toml")
    try:
        f.write_text(sp.to_toml())
        b = sweep.parser().parse_args(["--out", "x", "--config", str(f)])
        assert sweep.load_spec(f, b) == sp
    finally:
        f.unlink(missing_ok=True)


def test_yaml_grid_equals_toml(dataset_dir, tmp_path):
    y = tmp_path / "g.yaml"
    y.write_text(
        f"algos: [gcsl]\nseeds: [0, 1]\ndatasets: ['{dataset_dir}']\nset: {{steps: 100}}\ngrid: {{batch_size: [32, 64]}}\n"
        "eval: {episodes: 5}\n"
    )
    t = tmp_path / "g.toml"
    t.write_text(
        f"algos = ['gcsl']\nseeds = [0, 1]\ndatasets = ['{dataset_dir}']\n[set]\nsteps = 100\n[grid]\n"
        "batch_size = [32, 64]\n[eval]\nepisodes = 5\n"
    )
    a = sweep.parser().parse_args(["--out", "x"])
    assert sweep.load_spec(y, a) == sweep.load_spec(t, a)
    assert sweep.load_spec(y, a).episodes == 5 and len(sweep.points(sweep.load_spec(y, a))) == 4


def test_bad_inputs_are_one_line_errors(dataset_dir, tmp_path, capsys):
    base = ["--out", str(tmp_path / "s"), "--algos", "gcsl", "--datasets", str(dataset_dir)]
    cases = [
        (["--grid", "batch_sz=32,64"], "unknown grid key 'batch_sz'"),
        (["--set", "learning=3"], "unknown grid key 'learning'"),
        (["--grid", "seed=1,2"], "the seed is an axis of the sweep"),
        (["--algos", "ppo"], "algos must be one of gcsl, td3bc, td3awbc, cql, gciql, crl, qrl, hiql, got 'ppo'"),
        (["--datasets", str(tmp_path / "none")], "no dataset at"),
        (["--set", "steps=0"], "steps"),
        (["--tasks", "fly"], "unknown evaluation task 'fly'"),
        (["--address", "127.0.0.1:9"], "cannot reach a Ray cluster at 127.0.0.1:9"),
        (["--config", str(tmp_path / "nope.toml")], "no sweep file at"),
    ]
    import torch

    if not torch.cuda.is_available():
        cases.append((["--device", "cuda"], "GPU(s) (--device cuda), this machine has 0"))
    for extra, msg in cases:
        code, err = _main(base + extra, capsys)
        assert code == 2 and msg in err and err.count("\n") == 0, (extra, err)
    for text, msg in (
        ('algos = ["gcsl"]\nseeds = [-1]\n', "seeds must be >= 0, got -1"),
        ('algos = ["gcsl"]\n[eval]\nepisodes = 0\n', "episodes must be >= 1, got 0"),
        ('algos = "gcsl"\n', "algos must be a list"),
    ):
        (tmp_path / "v.toml").write_text(text)
        code, err = _main(
            ["--out", str(tmp_path / "s"), "--config", str(tmp_path / "v.toml"), "--datasets", str(dataset_dir)], capsys
        )
        assert code == 2 and msg in err and err.count("\n") == 0, err
    bad = tmp_path / "bad.toml"
    bad.write_text('algos = ["gcsl"]\nlearning_rate = 3\n')
    code, err = _main(["--out", str(tmp_path / "s"), "--config", str(bad)], capsys)
    assert code == 2 and "unknown key(s)" in err and "learning_rate" in err
    for name, text in (("broken.toml", "algos = [gcsl\n"), ("broken.yaml", "algos: [gcsl\n"), ("list.yaml", "- gcsl\n")):
        (tmp_path / name).write_text(text)
        code, err = _main(["--out", str(tmp_path / "s"), "--config", str(tmp_path / name)], capsys)
        assert code == 2 and err.count("\n") == 0 and str(tmp_path / name) in err, err
    assert not (tmp_path / "s").exists()  # nothing was created


def test_another_grid_in_the_same_folder_is_refused(dataset_dir, tmp_path):
    from aerohrl.errors import UserError

    a = sweep.parser().parse_args(["--out", "x", "--algos", "gcsl", "--datasets", str(dataset_dir)])
    sp = sweep.load_spec(None, a)
    sweep._check_saved(tmp_path, sp)
    sweep._check_saved(tmp_path, sp)  # the same grid: resumed
    sp.seeds = [0, 1]
    with pytest.raises(UserError, match="holds another sweep"):
        sweep._check_saved(tmp_path, sp)


def _sweep_cmd(ds, out):
    return [
        sys.executable,
        "-m",
        "aerohrl.sweep",
        "--out",
        str(out),
        "--algos",
        "gcsl",
        "td3bc",
        "--seeds",
        "0",
        "1",
        "--datasets",
        str(ds),
        "--set",
        "steps=160",
        "--set",
        "checkpoint_every=40",
        "--set",
        "log_every=40",
        "--set",
        "hidden=[32,32]",
        "--set",
        "critic_hidden=[32,32]",
        "--set",
        "batch_size=64",
        "--set",
        "eval_every=0",
        "--tasks",
        "reach-desired",
        "--episodes",
        "8",
        "--checkpoints",
        "2",
        "--num-cpus",
        "2",
    ]


def _weights(run):
    import torch

    from aerohrl.algorithms.run import Run

    return torch.load(Run(run).checkpoints()[-1], weights_only=False)["model"]


def test_a_reused_run_with_another_config_says_so(dataset_dir, tmp_path):
    """A run is reused or resumed with its own config; when a preset or a flag changed since,
    the status names the fields instead of hiding it (steps and dataset path are not compared)."""
    from aerohrl.algorithms import config as C

    cfg = C.make_config("cpu", algo="gcsl", dataset=str(dataset_dir), steps=40)
    rd = tmp_path / "run"
    rd.mkdir()
    (rd / "config.json").write_text(json.dumps({"config": C.to_dict(cfg)}))
    assert sweep.config_differences(rd, C.make_config("cpu", algo="gcsl", dataset="/elsewhere", steps=80)) == ""
    msg = sweep.config_differences(
        rd, C.make_config("cpu", algo="gcsl", dataset=str(dataset_dir), steps=40, relabel_prob=0.3, hidden=(64, 64))
    )
    assert msg.startswith(" (kept its own config: ") and f"relabel_prob {cfg.relabel_prob} -> 0.3" in msg
    assert "hidden [512, 512, 512] -> [64, 64]" in msg and "steps" not in msg
    assert sweep.config_differences(tmp_path / "no-run", cfg) == ""


@pytest.mark.slow
def test_sweep_survives_a_killed_worker(tmp_path):
    """2 algorithms x 2 seeds on a 250-goal dataset: the process training a run is killed
    (SIGKILL) after its first checkpoint; Ray retries the task, the run resumes, and the
    weights and the seed-aggregated table equal an uninterrupted sweep's. Rerunning the
    finished sweep trains and evaluates nothing again."""
    import torch

    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONWARNINGS="ignore")
    r = subprocess.run(
        [sys.executable, "-m", "aerohrl.datagen.cli", "build", "--goals", "250", "--out", str(tmp_path / "ds"), "--quiet"],
        capture_output=True,
        text=True,
        env=env,
    )
    assert r.returncode == 0, r.stderr
    ds = r.stdout.strip().splitlines()[-1]

    # the interrupted sweep: kill the first run that has written a checkpoint
    killed = tmp_path / "killed"
    p = subprocess.Popen(_sweep_cmd(ds, killed), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    victim = None
    deadline = time.time() + 600  # Ray start-up and the first checkpoint on a loaded machine
    while victim is None and time.time() < deadline and p.poll() is None:
        for ck in sorted(killed.glob("runs/*/checkpoints/step-000000040.pt")):
            run = ck.parent.parent
            if not (run / "checkpoints" / "step-000000160.pt").exists():
                pid = int((run / ".lock").read_text().split()[0])
                os.kill(pid, signal.SIGKILL)
                victim = run
                break
        time.sleep(0.05)
    out, err = p.communicate(timeout=600)
    assert victim is not None, err
    assert p.returncode == 0, err
    report = json.loads((killed / "sweep-report.json").read_text())
    assert report["runs"][victim.name]["status"].startswith("resumed at step"), report

    # the uninterrupted sweep
    clean = tmp_path / "clean"
    r = subprocess.run(_sweep_cmd(ds, clean), capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    tables = (clean / "tables.md").read_text()
    assert (killed / "tables.md").read_text() == tables and tables in out  # stdout: the tables (Ray may add lines)
    assert "GCSL" in out and "TD3-BC" in out and "2 x 2 x 8" in out  # both algorithms over 2 seeds
    assert (killed / "sweep.toml").read_text() == (clean / "sweep.toml").read_text()
    for run in sorted((clean / "runs").iterdir()):
        a, b = _weights(run), _weights(killed / "runs" / run.name)
        assert all(torch.equal(a[k], b[k]) for k in a), run.name

    # a rerun: nothing trained or evaluated again, the same tables
    summaries = {f: f.stat().st_mtime for f in clean.glob("runs/*/eval/*/summary.json")}
    r = subprocess.run(_sweep_cmd(ds, clean), capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    rep = json.loads((clean / "sweep-report.json").read_text())
    assert {v["status"] for v in rep["runs"].values()} == {"finished before"}
    assert {f: f.stat().st_mtime for f in clean.glob("runs/*/eval/*/summary.json")} == summaries
    assert tables in r.stdout and (clean / "tables.md").read_text() == tables


@pytest.mark.slow
def test_local_ray_workers_run_at_the_callers_priority():
    """Ray's default worker niceness (15) starves sweep tasks beside any ordinary process;
    the local Ray of ray_connect starts its workers at the caller's niceness."""
    code = (
        "import os\nfrom aerohrl.cluster import ray_connect\n"
        "def niceness():\n    return os.nice(0)\n"
        "r = ray_connect(num_cpus=1)\nprint('NICE', r.get(r.remote(niceness).remote()), os.nice(0))\nr.shutdown()\n"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    line = [x for x in p.stdout.splitlines() if x.startswith("NICE")]
    assert p.returncode == 0 and line, p.stderr[-2000:]
    worker, caller = map(int, line[0].split()[1:])
    assert worker == caller
