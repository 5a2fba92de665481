"""Training bookkeeping: checkpoints, resume equality, DAgger warm start, the learning
curve, the detection teacher and its feature, paired differences, bad input."""

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from aerohrl.errors import UserError
from aerohrl.ipp.baselines import make_planner
from aerohrl.ipp.cli import main
from aerohrl.ipp.env import EnvConfig
from aerohrl.ipp.factory import make_env
from aerohrl.ipp.lattice import default_lattice
from aerohrl.ipp.metrics import paired_differences
from aerohrl.ipp.policy import load_policy
from aerohrl.ipp.curve import plot_learning_curve
from aerohrl.ipp.train import load_run_config, preset, train
from aerohrl.config import from_nested
from test_ipp_policy import random_walk  # tests/ helpers (pytest puts tests/ on sys.path)


class _Interrupt(Exception):
    """Raised by :class:`_StopAfter` to cut a training run short."""


class _StopAfter:
    """tqdm stand-in that interrupts training after ``k`` iterations (like Ctrl-C)."""

    def __init__(self, k):
        self.k, self.n = k, 0

    def update(self, m):
        self.n += m
        if self.n >= self.k:
            raise _Interrupt

    def set_postfix(self, **kw):
        """Nothing to show (tqdm's postfix)."""


def _weights(run):
    return torch.load(run / "model.pt", weights_only=True)["state_dict"]


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("full") / "run"
    train(preset("test"), default_lattice(), run)
    return run


@pytest.mark.parametrize("stop", [1, 2])  # 1: inside the DAgger phase, 2: at its end
def test_resume_gives_the_uninterrupted_weights(full_run, tmp_path, stop):
    lat, cfg = default_lattice(), preset("test")
    run = tmp_path / "run"
    with pytest.raises(_Interrupt):
        train(cfg, lat, run, progress=_StopAfter(stop))
    ck = torch.load(run / "checkpoint.pt", weights_only=True)
    assert ck["iteration"] == stop
    assert {"model", "opt", "torch_rng", "numpy_rng", "buffer"} <= set(ck)
    assert len(ck["buffer"]) == (1 if stop == 1 else 0)  # DAgger data only while needed
    assert load_run_config(run) == cfg
    train(load_run_config(run), lat, run, resume=True)
    a, b = _weights(full_run), _weights(run)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    lines = (run / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(x)["iteration"] for x in lines] == [1, 2, 3]
    assert (run / "learning_curve.png").stat().st_size > 5000


def test_resumed_weights_differ_from_a_fresh_start(full_run, tmp_path):
    """The equality above is not trivial: another seed gives other weights."""
    run = tmp_path / "other"
    train(preset("test", seed=8), default_lattice(), run)
    a, b = _weights(full_run), _weights(run)
    assert not all(torch.equal(a[k], b[k]) for k in a)


def test_dagger_warm_start_imitates_the_teacher(tmp_path):
    lat = default_lattice()
    cfg = preset("test", n_envs=8, bc_iterations=4, iterations=0, bc_epochs=8, eval_every=0, bc_beta_decay=0.5, bc_lr=3e-3)
    train(cfg, lat, tmp_path / "bc")
    rows = [json.loads(x) for x in (tmp_path / "bc" / "metrics.jsonl").read_text().splitlines()]
    assert [r["phase"] for r in rows] == ["bc"] * 4
    assert rows[-1]["beta"] == pytest.approx(0.5**3)
    assert rows[-1]["bc_accuracy"] > 0.4

    def agreement(model):  # on unseen worlds, along the teacher's own path
        from aerohrl.ipp.policy import RLPlanner

        env, _ = make_env(EnvConfig(budget=1500.0), lat, 500, range(6))
        teacher, pl = make_planner("detect", env), RLPlanner(env, model)
        agree = tot = 0
        while not env.done.all():
            a, t = pl.act(), teacher.act()
            live = ~env.done
            agree += int((a[live] == t[live]).sum())
            tot += int(live.sum())
            env.step(t)
        return agree / tot

    train(replace(cfg, bc_iterations=0, iterations=1, lr=1e-12), lat, tmp_path / "none")
    cloned, untrained = agreement(load_policy(tmp_path / "bc")), agreement(load_policy(tmp_path / "none"))
    print(cloned, untrained)
    assert cloned > 0.3 and cloned > untrained + 0.15


def test_detect_feature_is_the_teacher_score():
    lat = default_lattice()
    env, _ = make_env(EnvConfig(budget=2000.0), lat, 500, range(6))  # to the budget's end
    pl = make_planner("detect", env)
    while not env.done.all():
        f = env.action_features()
        valid = env.valid_mask()
        a = pl.act()
        live = ~env.done & (f[..., 14].max(1) > 1e-6)  # else: frontier fallback
        assert np.array_equal(np.where(valid, f[..., 14], -1).argmax(1)[live], a[live])
        assert np.allclose(f[live, :, 15].max(1), 1.0)
        env.step(a)


def test_features_do_not_read_the_truth():
    lat = default_lattice()
    env, _ = make_env(EnvConfig(), lat, 5, range(3))
    pl = make_planner("detect", env)
    for _ in range(6):
        env.step(pl.act())
    assert env.found.any()
    f = env.action_features()
    env.truth[:] = np.random.default_rng(0).random(env.truth.shape) < 0.5
    env.found[:] = ~env.found
    np.testing.assert_array_equal(env.action_features(), f)


def test_budget_aware_endgame_maximises_detections_by_hand():
    """With less budget left than any primitive costs, the last primitive is free beyond
    the remainder: the detect planner (and feature 14) rank by expected detections."""
    lat = default_lattice()
    env, _ = make_env(EnvConfig(), lat, 11, range(3))
    pl = make_planner("detect", env)
    for _ in range(5):
        env.step(pl.act())
    env.remaining[:] = 1.0
    a, f = pl.act(), env.action_features()
    cmean = lat.prim_cost.mean()
    for n in range(env.n):
        valid = np.flatnonzero(env.valid_mask()[n])
        d1 = []
        for slot in valid:
            cells, lev = lat.sensed_cells(int(lat.edges[env.vert[n], slot]), env.pos[n])
            ok = (cells >= 0).all(1) & (cells < env.S).all(1)
            uc, inv = np.unique(cells[ok], axis=0, return_inverse=True)
            lam = np.bincount(inv.ravel(), weights=env.lam_levels[lev[ok]])
            b = env.belief()[n][uc[:, 1], uc[:, 0]]
            d1.append(env.plan_detect_gain(b, np.zeros_like(lam), lam).sum())
        d1 = np.array(d1)
        assert d1[list(valid).index(a[n])] == pytest.approx(d1.max())
        np.testing.assert_allclose(f[n, valid, 14] * 25 * (1.0 / cmean), d1, rtol=1e-6, atol=1e-12)


def test_detect_gain_flat_matches_the_generic_hook():
    lat = default_lattice()
    env, _ = make_env(EnvConfig(), lat, 3, range(2))
    rng = np.random.default_rng(1)
    random_walk(env, rng, 4)
    flat = rng.integers(0, env.L.size, 500)
    lp = rng.choice([0.0, 1.3, 2.1, 4.6], 500)
    lam = rng.choice([1.3, 2.1, 4.6, 6.7], 500)
    HH = env.Hp * env.Hp
    b = env.plan_cells(flat // HH, flat % HH)
    np.testing.assert_allclose(env.plan_detect_gain_flat(flat, lp, lam), env.plan_detect_gain(b, lp, lam), atol=1e-12)
    g = env.plan_detect_gain(np.array([0.3, 0.3, 0.97]), np.array([0.0, 0.0, 0.0]), np.array([4.6, 1.3, 4.6]))
    # one centre look at b=0.3 finds it with P(target) * P(label 1) = 0.3 * 0.99; an
    # edge look (posterior logit -0.85 + 1.3 < logit 0.95) finds nothing; b >= 0.95: done
    np.testing.assert_allclose(g, [0.3 * (1 - 1 / (1 + np.exp(4.6))), 0.0, 0.0])


def test_paired_differences_by_hand():
    ids = np.arange(3)
    res = {
        "dp": {"per_env": {"search_efficiency": np.array([50.0, 60.0, 70.0])}, "env_ids": ids},
        "prio_coverage": {"per_env": {"search_efficiency": np.array([55.0, 60.0, 71.0])}, "env_ids": ids},
        "rl": {"per_env": {"search_efficiency": np.array([56.0, 62.0, 71.0])}, "env_ids": ids},
    }
    d, best = paired_differences(res, ("dp", "prio_coverage"))
    assert best == "prio_coverage"
    m, se, n = d["rl"]["prio_coverage"]
    diff = np.array([1.0, 2.0, 0.0])
    assert n == 3 and m == pytest.approx(1.0)
    assert se == pytest.approx(diff.std(ddof=1) / np.sqrt(3))


def test_config_round_trip_and_curve(full_run, tmp_path):
    cfg = load_run_config(full_run)
    assert cfg == preset("test") and isinstance(cfg.env.world.n_targets, tuple)
    with pytest.raises(UserError, match="unknown key"):
        from_nested(type(cfg), {"n_envs": 3, "colour": "red"})
    out = plot_learning_curve(full_run, tmp_path / "c.png")
    assert out.stat().st_size > 5000


def test_cli_train_resume_and_curve(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["train", "--preset", "test", "--iterations", "1", "--out", str(run.parent), "--name", run.name, "--quiet"]) == 0
    assert "learning_curve.png" in capsys.readouterr().out
    first = json.loads((run / "metrics.jsonl").read_text().splitlines()[-1])
    assert first["iteration"] == 3 and first["phase"] == "ppo"
    # extend the finished run by one PPO iteration
    assert main(["train", "--resume", str(run), "--iterations", "2", "--threads", "1", "--quiet"]) == 0
    assert json.loads((run / "config.json").read_text())["train"]["threads"] == 1  # where it runs may change
    rows = (run / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(x)["iteration"] for x in rows] == [1, 2, 3, 4]
    (run / "learning_curve.png").unlink()
    assert main(["curve", str(run)]) == 0
    assert (run / "learning_curve.png").is_file()
    assert [p.name for p in run.glob(".*")] == [".lock"]  # the run's lock; atomic writes leave no temp files


@pytest.mark.parametrize(
    "argv,msg",
    [
        (["train", "--resume", "nowhere"], "no config.json"),
        (["train", "--preset", "test", "--adv-weights", "1,2"], "--adv-weights"),
        (["train", "--preset", "test", "--adv-weights", "1,x,1,1,1"], "comma-separated"),
        (["train", "--preset", "test", "--teacher", "astar"], "invalid choice: 'astar'"),
        (["train", "--preset", "test", "--teacher", "cmaes"], "invalid choice: 'cmaes'"),
        (["train", "--preset", "test", "--teacher-depth", "9"], "teacher-depth"),
        (["train", "--preset", "test", "--seed", "1000"], "test suite"),
        (["train", "--preset", "test", "--lr", "-1"], "--lr"),
        (["train", "--preset", "test", "--bc-iterations", "-1"], "--bc-iterations"),
        (["train", "--preset", "test", "--iterations", "0", "--bc-iterations", "0"], "must be >= 1"),
        (["train", "--preset", "test", "--eval-every", "-2"], "--eval-every"),
        (["train", "--preset", "test", "--threads", "0"], "--threads"),
        (["curve", "nowhere"], "no metrics.jsonl"),
        (["bench", "--planner", "detect", "--depth", "9", "--envs", "1"], "depth"),
        (["bench", "--planner", "dp", "--depth", "0", "--envs", "1"], "depth"),
    ],
)
def test_train_bad_input_one_line(argv, msg, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("aerohrl ipp: error:") and msg in err and "\n" not in err


def test_resume_rejects_damaged_runs(full_run, tmp_path, capsys):
    import shutil

    run = tmp_path / "r"
    shutil.copytree(full_run, run)
    assert main(["train", "--resume", str(run), "--envs", "9"]) == 2
    assert "only --iterations" in capsys.readouterr().err
    good = (run / "metrics.jsonl").read_text()
    (run / "metrics.jsonl").write_text(good + "garbage\n")
    assert main(["train", "--resume", str(run), "--quiet"]) == 2
    assert "not a metrics line" in capsys.readouterr().err
    (run / "metrics.jsonl").write_text(good)
    assert main(["train", "--resume", str(run), "--iterations", "0", "--bc-iterations", "1"]) == 2
    assert main(["train", "--resume", str(run), "--iterations", "0", "--quiet"]) == 2
    assert "already has 3 iterations" in capsys.readouterr().err
    (run / "checkpoint.pt").write_bytes(b"junk")
    assert main(["train", "--resume", str(run), "--quiet"]) == 2
    assert "checkpoint.pt is damaged: its SHA-256 differs" in capsys.readouterr().err  # the sidecar catches it
    (run / "checkpoint.pt.sha256").unlink()  # as written before checkpoints had checksums: torch cannot read it
    assert main(["train", "--resume", str(run), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "checkpoint.pt is damaged" in err and "no .sha256 file" in err
    (run / "config.json").write_text("{not json")
    assert main(["train", "--resume", str(run)]) == 2
    assert "not a training config" in capsys.readouterr().err
    (run / "config.json").write_text(json.dumps({"train": {"n_envs": "many"}}))
    assert main(["train", "--resume", str(run)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("aerohrl ipp: error:") and "\n" not in err
    (run / "metrics.jsonl").write_text('{"iteration": 1}\n')
    assert main(["curve", str(run)]) == 2
    assert "not a metrics line" in capsys.readouterr().err


def test_an_ipp_run_being_trained_cannot_be_resumed_twice(full_run, tmp_path, capsys):
    """`ipp train --resume RUN` while another process trains RUN exits 2 with train's line
    and changes nothing; once the lock is free, a checkpoint from before checksums
    resumes with a warning."""
    import os
    import shutil

    from aerohrl.algorithms.run import RunLock

    run = tmp_path / "r"
    shutil.copytree(full_run, run)
    before = (run / "metrics.jsonl").read_text()
    with RunLock(run):
        assert main(["train", "--resume", str(run), "--iterations", "2", "--quiet"]) == 2
        err = capsys.readouterr().err.strip()
    assert err == f"aerohrl ipp: error: run {run} is being trained by another process (pid {os.getpid()}); wait for it to end"
    assert (run / "metrics.jsonl").read_text() == before
    (run / "checkpoint.pt.sha256").unlink()  # as written before checkpoints had checksums
    assert main(["train", "--resume", str(run), "--iterations", "2", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "no .sha256 file" in err and "loaded unverified" in err
    assert [json.loads(x)["iteration"] for x in (run / "metrics.jsonl").read_text().splitlines()] == [1, 2, 3, 4]
    assert (run / "checkpoint.pt.sha256").is_file()  # the new checkpoint has one


def test_seeds_markdown_by_hand():
    """A recipe over seeds: per-seed means, mean ± std over seeds, and the seed-averaged
    policy paired with every baseline (t-test p from scipy)."""
    from scipy import stats

    from aerohrl.ipp.metrics import seeds_markdown

    ids = np.arange(4)
    dp = np.array([50.0, 60.0, 70.0, 80.0])
    s1, s2 = dp + [1.0, 3.0, 2.0, 2.0], dp + [3.0, 1.0, 2.0, 0.0]
    res = {
        "dp": {"per_env": {"search_efficiency": dp}, "env_ids": ids},
        "rl": {"per_env": {"search_efficiency": s1}, "env_ids": ids},
        "rl_2": {"per_env": {"search_efficiency": s2}, "env_ids": ids},
    }
    names = {"dp": "DP-IPP"}
    md = seeds_markdown(res, names, {"recipe, seeds 7, 8": ["rl", "rl_2"]}, ("dp",))
    row = next(line for line in md.splitlines() if line.startswith("| recipe, seeds"))
    p = stats.ttest_rel((s1 + s2) / 2, dp).pvalue
    assert f"| 2 | {s1.mean():.1f} / {s2.mean():.1f} | " in row
    assert f"{np.std([s1.mean(), s2.mean()], ddof=1):.1f} |" in row
    assert row.endswith(f"+1.75 ± 0.25 (4/0, p = {p:.3g}) |")  # seed mean: +2, +2, +2, +1
    assert "per seed − best baseline (DP-IPP)" in md
    assert seeds_markdown(res, names, {"one seed": ["rl"]}, ("dp",)) == ""


def test_bench_groups_a_recipe_over_seeds(full_run, tmp_path, capsys):
    """bench --run A --run B of one recipe trained with two seeds prints the over-seeds
    table; the same seed twice (a re-run) is not a seed spread and prints none."""
    s8 = tmp_path / "s8"
    train(preset("test", seed=8), default_lattice(), s8)
    argv = ["bench", "--envs", "2", "--budget", "1500", "--quiet", "--out", str(tmp_path / "b")]
    assert main(argv + ["--planner", "rl", "--run", str(full_run), "--run", str(s8)]) == 0
    assert "Over seeds" not in capsys.readouterr().out  # no baseline to pair with
    assert main(argv + ["--all", "--run", str(full_run), "--run", str(s8)]) == 0
    out = capsys.readouterr().out
    assert "Over seeds" in out
    assert "| Imitation of detect planner + PPO 1 it. (DAgger; its features, GRU), model.pt, seeds 7, 8 | 2 |" in out
    assert main(argv + ["--all", "--run", str(full_run), "--run", str(full_run)]) == 0
    assert "Over seeds" not in capsys.readouterr().out
