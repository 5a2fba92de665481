"""The learned target belief: disjoint world suites, the loss, checkpoints and resume,
one-line errors, and planning over it in ``ipp bench``."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from aerohrl.errors import UserError
from aerohrl.ipp.baselines import make_planner
from aerohrl.ipp.belief import (
    BeliefModel,
    BeliefNetConfig,
    belief_loss,
    check_temperature,
    collect_states,
    expected_calibration_error,
    fit_temperature,
    load_belief,
    load_data,
    preset,
    save_belief,
    train_belief,
    training_indices,
    validation_indices,
)
from aerohrl.ipp.cli import main
from aerohrl.ipp.factory import make_env
from aerohrl.ipp.lattice import default_lattice
from aerohrl.ipp.world import TEST_SEED


class _Interrupt(Exception):
    """Raised by :class:`_StopAfter` to cut a training run short."""


class _StopAfter:
    """tqdm stand-in that interrupts training after ``k`` epochs (like Ctrl-C)."""

    def __init__(self, k):
        self.k, self.n = k, 0

    def update(self, m):
        self.n += m
        if self.n >= self.k:
            raise _Interrupt

    def set_postfix(self, **kw):
        """Nothing to show (tqdm's postfix)."""


@pytest.fixture(scope="module")
def belief_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("belief") / "run"
    train_belief(preset("test"), default_lattice(), run)
    return run


def test_train_validation_and_test_worlds_never_overlap(belief_run):
    cfg = preset("test")
    train, val = load_data(belief_run / "data.npz")
    assert set(train.seeds[:, 0]) == {cfg.seed} and set(val.seeds[:, 0]) == {cfg.val_seed}
    assert len({cfg.seed, cfg.val_seed, TEST_SEED}) == 3
    tr = {tuple(s) for s in train.seeds}
    va = {tuple(s) for s in val.seeds}
    assert not tr & va and all(s[0] != TEST_SEED for s in tr | va)
    # no world of one suite is a world of another (the generator is keyed by (seed, index))
    assert not any((train.targets[i] == val.targets[j]).all() for i in range(len(tr)) for j in range(len(va)))
    # planners fly disjoint worlds of the training suite
    idx = training_indices(replace(cfg, planners=("detect", "dp", "coverage"), n_worlds=5))
    assert len(set(sum(idx, []))) == 15
    assert len(set(sum(validation_indices(cfg), []))) == cfg.val_worlds * len(cfg.planners)
    for bad in ({"seed": TEST_SEED}, {"val_seed": TEST_SEED}, {"val_seed": cfg.seed}):
        with pytest.raises(UserError, match="never overlap"):
            replace(cfg, **bad).validate()


def test_loss_equals_a_hand_computation():
    z = torch.tensor([[[2.0, -1.0], [0.0, -3.0]]])
    y = torch.tensor([[[1, 0], [1, 0]]], dtype=torch.bool)
    q = 1 / (1 + np.exp(-np.array([2.0, -1.0, 0.0, -3.0])))
    yy = np.array([1, 0, 1, 0])
    hand = -np.mean(yy * np.log(q) + (1 - yy) * np.log(1 - q))
    assert belief_loss(z, y).item() == pytest.approx(hand, rel=1e-6)


def test_untrained_belief_is_the_posterior_and_plans_like_detect():
    lat = default_lattice()
    env, _ = make_env(preset("test").env, lat, 3, range(4))
    env.lazy_obs = True
    env.step(make_planner("coverage", env).act())
    model = BeliefModel(BeliefNetConfig(width=4, dilations=(1,)), env.S)
    np.testing.assert_allclose(model.predict(env), env.belief(), rtol=0, atol=1e-12)
    a = make_planner("detect", env).act()
    b = make_planner("detect", model.view(env)).act()
    np.testing.assert_array_equal(a, b)


def test_context_branch_starts_at_the_posterior_reads_the_whole_map_and_round_trips(tmp_path):
    lat = default_lattice()
    env, _ = make_env(preset("test").env, lat, 3, range(2))
    env.lazy_obs = True
    env.step(make_planner("coverage", env).act())
    model = BeliefModel(BeliefNetConfig(width=4, dilations=(1,), context=True), env.S)
    np.testing.assert_allclose(model.predict(env), env.belief(), rtol=0, atol=1e-12)
    # one 3 x 3 convolution sees 1 cell around; the pooled branch carries a far cell's input
    torch.manual_seed(0)
    for p in model.net.parameters():
        torch.nn.init.normal_(p, std=0.3)
    x = torch.zeros(1, 8, 12, 12)
    y = torch.zeros(1, 8, 12, 12)
    y[0, :, 11, 11] = 5.0
    with torch.no_grad():
        assert model.net(x)[0, 0, 0] != model.net(y)[0, 0, 0]
        flat = BeliefModel(BeliefNetConfig(width=4, dilations=(1,)), 12).net
        assert flat(x)[0, 0, 0] == flat(y)[0, 0, 0]
    save_belief(model, tmp_path / "belief.pt")
    back = load_belief(tmp_path / "belief.pt")
    assert back.cfg.context
    with torch.no_grad():
        np.testing.assert_array_equal(back.net(y).numpy(), model.net(y).numpy())


def test_a_belief_saved_before_the_context_setting_loads_without_it(tmp_path):
    from aerohrl.ipp.belief import _weights, _from_weights

    ck = _weights(BeliefModel(BeliefNetConfig(width=4, dilations=(1,)), 20))
    del ck["net"]["context"]
    model = _from_weights(ck, 1.0, "old", "old.pt", "damaged")
    assert not model.cfg.context


def test_belief_for_another_grid_size_is_a_one_line_error(tmp_path):
    save_belief(BeliefModel(BeliefNetConfig(width=4, dilations=(1,)), 20), tmp_path / "belief.pt")
    model = load_belief(tmp_path / "belief.pt")
    env, _ = make_env(preset("test").env, default_lattice(), 3, range(1))
    with pytest.raises(UserError, match="trained on 20 x 20 maps") as e:
        model.view(env)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("T", [0.0, -1.0, float("nan"), float("inf")])
def test_temperature_must_be_positive(T, tmp_path, capsys):
    with pytest.raises(UserError, match="> 0"):
        check_temperature(T)
    with pytest.raises(UserError, match="> 0"):
        BeliefModel(BeliefNetConfig(width=4, dilations=(1,)), 30, temperature=T)
    rc = main(["bench", "--planner", "detect", "--envs", "2", "--belief", str(tmp_path), "--belief-temperature", str(T)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err and "temperature" in err


def test_temperature_fit_recovers_a_known_scale():
    rng = np.random.default_rng(0)
    z = rng.normal(0, 3, 20000)
    y = rng.random(20000) < 1 / (1 + np.exp(-z / 2.0))  # true logits z / 2: fit T = 2
    assert fit_temperature(z, y) == pytest.approx(2.0, rel=0.1)
    p = 1 / (1 + np.exp(-z / 2.0))
    assert expected_calibration_error(p, y) < 0.02 < expected_calibration_error(1 / (1 + np.exp(-z)), y)


def test_resume_gives_the_uninterrupted_weights(belief_run, tmp_path):
    cfg, lat = preset("test"), default_lattice()
    run = tmp_path / "run"
    with pytest.raises(_Interrupt):
        train_belief(cfg, lat, run, progress=_StopAfter(1))
    assert not (run / "calibration.json").exists()
    train_belief(cfg, lat, run, resume=True)
    a = torch.load(run / "checkpoint.pt", weights_only=True)["model"]
    b = torch.load(belief_run / "checkpoint.pt", weights_only=True)["model"]
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert (run / "calibration.json").is_file() and (run / "reliability.png").is_file()


def test_damaged_belief_is_a_one_line_error(belief_run, tmp_path):
    import shutil

    bad = tmp_path / "r"
    shutil.copytree(belief_run, bad)
    with open(bad / "belief.pt", "r+b") as f:
        f.seek(40)
        f.write(b"\x00\x01\x02")
    with pytest.raises(UserError, match="damaged"):
        load_belief(bad)


def test_bench_with_belief_runs_end_to_end(belief_run, tmp_path, capsys):
    out = tmp_path / "bench"
    rc = main(
        ["bench", "--planner", "detect", "--envs", "2", "--budget", "800", "--belief", str(belief_run), "-o", str(out), "--quiet"]
    )
    text = capsys.readouterr().out
    assert rc == 0 and "over the learned belief" in text
    assert (out / "ipp_bench_envs.csv").is_file()
    rc = main(["bench", "--planner", "coverage", "--envs", "2", "--belief", str(belief_run), "-o", str(out)])
    assert rc == 2


def test_budget_sweep_over_the_belief_matches_the_single_budget_bench(belief_run, tmp_path, capsys):
    """``--budgets`` with ``--belief``: each budget's per-world results equal the
    single-budget bench's over the same belief (ipp_budgets_envs.csv pairs the worlds)."""
    import csv

    sweep, one = tmp_path / "sweep", tmp_path / "one"
    common = ["bench", "--planner", "detect", "--envs", "2", "--belief", str(belief_run), "--quiet"]
    assert main([*common, "--budgets", "600,800", "-o", str(sweep)]) == 0
    assert main([*common, "--budget", "800", "-o", str(one)]) == 0
    capsys.readouterr()
    rows = list(csv.DictReader((sweep / "ipp_budgets_envs.csv").open()))
    assert {r["budget"] for r in rows} == {"600", "800"} and all("learned belief" in r["label"] for r in rows)
    single = {r["env"]: r["search_efficiency"] for r in csv.DictReader((one / "ipp_bench_envs.csv").open())}
    at800 = {r["env"]: r["search_efficiency"] for r in rows if r["budget"] == "800"}
    assert at800 == single and len(single) == 2


def test_observation_belief_plane_is_the_learned_beliefs():
    """``env.obs_belief``: the belief plane of observe() is the learned belief's prediction;
    an untrained belief (the posterior exactly) observes as without it."""
    env, _ = make_env(preset("test").env, default_lattice(), 3, range(2))
    env.step(np.zeros(env.n, np.int64))
    plain = env.observe()["maps"]
    model = BeliefModel(BeliefNetConfig(width=4, dilations=(1,)), env.S)
    env.obs_belief = model
    np.testing.assert_allclose(env.observe()["maps"], plain, rtol=0, atol=1e-6)
    env.obs_belief = BeliefModel(BeliefNetConfig(width=4, dilations=(1,)), env.S, temperature=3.0)
    hot = env.observe()["maps"]
    C = env.planes.shape[1]
    belief_ch = np.arange(hot.shape[1]) % C == 0
    assert not np.allclose(hot[:, belief_ch], plain[:, belief_ch], atol=1e-3)  # the belief planes moved
    np.testing.assert_array_equal(hot[:, ~belief_ch], plain[:, ~belief_ch])  # coverage and boundary did not


def test_actor_critic_with_the_belief_as_input(belief_run, tmp_path, capsys):
    """``ipp train --belief-input``: the policy carries its belief, observes it in training,
    in bench and after loading; a warm start across the two is a one-line error."""
    from aerohrl.ipp.policy import describe_policy, load_policy

    run = tmp_path / "ac"
    argv = ["train", "--preset", "test", "--quiet", "--out", str(tmp_path), "--name", "ac"]
    assert main([*argv, "--belief-input", str(belief_run)]) == 0
    m = load_policy(run)
    assert m.obs_belief is not None and m.obs_belief.label == belief_run.name
    assert "the learned belief's map" in describe_policy(m)
    out = tmp_path / "b"
    assert (
        main(["bench", "--planner", "rl", "--run", str(run), "--envs", "2", "--budget", "1500", "-o", str(out), "--quiet"]) == 0
    )
    assert "the learned belief's map" in capsys.readouterr().out
    rc = main(["train", "--preset", "test", "--quiet", "--out", str(tmp_path), "--name", "ft", "--init", str(run)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "learned belief" in err and "\n" not in err
    rc = main(
        ["train", "--preset", "test", "--quiet", "--out", str(tmp_path), "--name", "x", "--belief-input", str(tmp_path / "none")]
    )
    assert rc == 2 and "no learned belief" in capsys.readouterr().err


def test_student_of_the_teacher_over_the_learned_belief(belief_run, tmp_path, capsys, monkeypatch):
    """``ipp train --teacher-belief``: the DAgger teacher plans over the learned belief (its
    planner reads the belief's view), the row name says so; without a DAgger teacher, or
    with a missing belief, one-line errors before any run is written."""
    from aerohrl.ipp import baselines
    from aerohrl.ipp.belief import BeliefView
    from aerohrl.ipp.policy import describe_policy, load_policy

    seen = []
    make = baselines.make_planner

    def spy(name, env, cfg=None):
        seen.append(env)
        return make(name, env, cfg)

    monkeypatch.setattr(baselines, "make_planner", spy)  # ipp.train imports it when it trains
    argv = ["train", "--preset", "test", "--quiet", "--out", str(tmp_path), "--bc-iterations", "1"]
    assert main([*argv, "--name", "st", "--teacher-belief", str(belief_run)]) == 0
    assert seen and isinstance(seen[-1], BeliefView)
    assert "detect over the learned belief" in describe_policy(load_policy(tmp_path / "st"))
    capsys.readouterr()
    rc = main([*argv[:-1], "0", "--name", "nob", "--teacher-belief", str(belief_run)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "bc_iterations" in err and "\n" not in err and not (tmp_path / "nob").exists()
    rc = main([*argv, "--name", "bad", "--teacher-belief", str(tmp_path / "none")])
    assert rc == 2 and "no learned belief" in capsys.readouterr().err and not (tmp_path / "bad").exists()


def test_collect_records_live_states_only():
    cfg = preset("test")
    d = collect_states(cfg.env, default_lattice(), ("coverage",), cfg.seed, [[0, 1]], 1)
    assert len(d) > 0 and d.L.shape[1:] == (30, 30) and set(d.world) <= {0, 1}
    assert (d.rem > 0).all()


def test_ranking_study_scores_every_belief_and_the_generators_marginal(belief_run, tmp_path, capsys):
    """experiments/ipp_belief_ranking.py: one row per learned belief, the posterior, the
    prior and the oracle; the oracle's AUC is a probability and the untrained rows agree
    where they must (the posterior's and the prior's never-sensed cells are the same)."""
    from conftest import load_experiment

    m = load_experiment("ipp_belief_ranking")
    out = tmp_path / "t.md"
    assert m.main([str(belief_run), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert out.read_text() == text
    rows = {
        r.split(" | ")[0].lstrip("| "): r.split(" | ")[1:] for r in text.splitlines() if r.startswith("| ") and "---" not in r
    }
    assert set(rows) - {"belief"} == {
        f"learned: {belief_run.name} (T = {load_belief(belief_run / 'belief.pt').temperature:.3f})",
        "hand-written posterior",
        "prior",
        "generator's marginal (oracle)",
    }
    auc = {k: float(v[2]) for k, v in rows.items() if k != "belief"}
    assert all(0.0 <= a <= 1.0 for a in auc.values())
    assert rows["hand-written posterior"][1:] == rows["prior"][1:]  # never sensed: no measurement moved it
    assert m.main([str(tmp_path / "nothing")]) == 2
    assert "not a learned-belief run" in capsys.readouterr().err
