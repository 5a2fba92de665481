"""Policies that observe the expert's disturbance estimate: the recorded column, the state
layout, training, closed-loop evaluation with the same observer, and the exported file."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from aerohrl.errors import UserError


@pytest.fixture(scope="module")
def dob_dataset(tmp_path_factory):
    """A small dataset flown by the expert with its disturbance observer, on a heavier vehicle."""
    from aerohrl.datagen.build import build
    from aerohrl.datagen.spec import DatasetSpec

    root = tmp_path_factory.mktemp("dob")
    spec = DatasetSpec(goals=12, seed=0, disturbance_observer=0.25, randomize="mass=1.15:1.25")
    return build(spec, root, progress=False, log=lambda *a: None).path


def test_the_estimate_is_recorded_as_the_command_used_it(dob_dataset):
    """``observation.disturbance`` is d_hat before each command: 0 at every episode's first
    frame, then the observer's estimate, which on a vehicle ~20 % heavier tends to the
    missing lift ``g (1/s - 1)`` along z (about -1.6 m/s^2)."""
    from aerohrl.datagen.dataset import open_dataset

    cols = open_dataset(dob_dataset).columns()
    d, ep, k = cols["observation.disturbance"], cols["episode_index"], cols["frame_index"]
    assert d.shape == (len(ep), 3) and d.dtype == np.float32
    assert np.all(d[k == 0] == 0)
    late = k >= 100  # 1 s = 4 tau into each flight
    assert -2.2 < np.median(d[late, 2]) < -1.0
    assert np.abs(np.median(d[late, :2], 0)).max() < 0.3


def test_no_column_without_the_observer(tmp_path):
    from aerohrl.datagen.build import build
    from aerohrl.datagen.dataset import open_dataset
    from aerohrl.datagen.spec import DatasetSpec

    path = build(DatasetSpec(goals=4, seed=1), tmp_path, progress=False, log=lambda *a: None).path
    assert "observation.disturbance" not in open_dataset(path).columns()


def test_with_disturbance_appends_the_estimate_and_its_next_value(dob_dataset):
    from aerohrl.algorithms.data import load_dataset

    data = load_dataset(dob_dataset)
    aug = data.with_disturbance()
    assert aug.state.shape == (len(data), 21) and aug.next_state.shape == (len(data), 21)
    torch.testing.assert_close(aug.state[:, :18], data.state)
    torch.testing.assert_close(aug.state[:, 18:], data.disturbance)
    inner = torch.nonzero(torch.arange(len(data)) < data.episode_end).flatten()
    torch.testing.assert_close(aug.next_state[inner, 18:], data.disturbance[inner + 1])
    last = torch.unique(data.episode_end)
    torch.testing.assert_close(aug.next_state[last, 18:], data.disturbance[last])
    plain = load_dataset({k: v for k, v in _columns(dob_dataset).items() if k != "observation.disturbance"})
    with pytest.raises(UserError, match="disturbance-observer"):
        plain.with_disturbance()


def _columns(path):
    from aerohrl.datagen.dataset import open_dataset

    return open_dataset(path).columns()


def test_normaliser_layout_round_trips_and_reads_narrow_states_as_undisturbed():
    from aerohrl.algorithms.networks import IN_DIM, Normalizer

    for absolute in (False, True):
        n = Normalizer(absolute_position=absolute, disturbance_tau=0.25)
        assert n.state_width == 21 and len(n.in_mean) == IN_DIM + 3 * absolute + 3
        back = Normalizer.for_state_dict(n.state_dict(), prefix="")
        assert (back.absolute_position, back.disturbance_tau, back.state_width) == (absolute, 0.25, 21)
        s = torch.randn(5, 21)
        g = torch.randn(5, 15)
        x = n.raw_inputs(s, g)
        assert torch.equal(x[:, -3:], s[:, 18:])
        assert torch.equal(n.raw_inputs(s[:, :18], g)[:, -3:], torch.zeros(5, 3))
        assert n.state_part(x).shape[-1] == n.state_dim == 15 + 3 * absolute + 3
    plain = Normalizer()
    assert "dob_tau" not in plain.state_dict() and Normalizer.for_state_dict(plain.state_dict(), prefix="").state_width == 18


def test_observe_disturbance_rejects_the_mirror_augmentation():
    from aerohrl.algorithms.config import check, make_config
    from aerohrl.config import ConfigError

    with pytest.raises(ConfigError, match="augment"):
        check(make_config("cpu", observe_disturbance=True, augment="mirror"))


@pytest.fixture(scope="module")
def dob_run(dob_dataset, tmp_path_factory):
    from aerohrl.algorithms.config import make_config
    from aerohrl.algorithms.trainer import start_run

    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("dobrun")
    tiny = dict(hidden=(32, 32), critic_hidden=(16, 16), batch_size=64, steps=40, log_every=20, checkpoint_every=40)
    cfg = make_config("cpu", algo="gcsl", dataset=str(dob_dataset), observe_disturbance=True, eval_every=0, **tiny)
    start_run(cfg, root / "run", progress=False).train()
    return root / "run"


def test_training_without_the_column_is_refused(tmp_path):
    from aerohrl.algorithms.config import make_config
    from aerohrl.algorithms.synthetic import write_synthetic_dataset
    from aerohrl.algorithms.trainer import start_run

    ds = write_synthetic_dataset(tmp_path / "ds")
    cfg = make_config("cpu", algo="gcsl", dataset=str(ds), observe_disturbance=True, steps=2, eval_every=0)
    with pytest.raises(UserError, match="observation.disturbance"):
        start_run(cfg, tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


def test_the_policy_acts_on_the_estimate_and_the_rollout_runs_the_observer(dob_run, monkeypatch):
    """The trained policy's action depends on d_hat; the closed loop feeds it the observer's
    estimate (21 columns), starting from 0, and resuming the run keeps the layout."""
    from aerohrl.algorithms.base import load_policy
    from aerohrl.algorithms.run import Run
    from aerohrl.envs import rollout as R

    run = Run.open(dob_run, kind="train")
    algo, _ = load_policy(run.checkpoints()[-1], "cpu", run)
    assert algo.normalizer.disturbance_tau == 0.25
    s = torch.zeros(1, 21)
    s[0, 6] = s[0, 10] = s[0, 14] = 1.0
    g = torch.zeros(1, 15)
    g[0, 0], g[0, 6], g[0, 10], g[0, 14] = 1.0, 1.0, 1.0, 1.0
    s2 = s.clone()
    s2[0, 20] = -3.0
    with torch.no_grad():
        assert not torch.allclose(algo.act(s, g), algo.act(s2, g))

    seen: list[np.ndarray] = []
    call = R.PolicyFn.__call__

    def spy(self, states, goals):
        seen.append(np.array(states))
        return call(self, states, goals)

    monkeypatch.setattr(R.PolicyFn, "__call__", spy)
    out = R.rollout_reach(algo, np.tile(g[0].numpy().astype(np.float64), (3, 1)), horizon=30)
    assert out
    assert seen[0].shape == (3, 21) and np.all(seen[0][:, 18:] == 0)
    assert np.abs(seen[-1][:, 18:]).max() > 0  # the observer has moved


@pytest.mark.parametrize("fmt", ["torchscript", "onnx"])
def test_export_takes_the_estimate_as_state_columns(dob_run, tmp_path, fmt):
    if fmt == "onnx":
        pytest.importorskip("onnxruntime")
        pytest.importorskip("onnx")
    from aerohrl.algorithms.base import load_policy
    from aerohrl.algorithms.export import export_policy, load_exported
    from aerohrl.algorithms.run import Run
    from aerohrl.envs.rollout import PolicyFn

    out, meta = export_policy(dob_run, fmt, tmp_path / f"p.{fmt}")
    assert meta["inputs"]["state"]["shape"] == ["B", 21] and meta["inputs"]["state"]["names"][-3:] == ["d_x", "d_y", "d_z"]
    assert meta["disturbance_observer"]["tau_s"] == 0.25
    predict, _ = load_exported(out)
    rng = np.random.default_rng(0)
    s = rng.normal(size=(256, 21)).astype(np.float32)
    g = rng.normal(size=(256, 15)).astype(np.float32)
    r = Run.open(dob_run, kind="train")
    algo, _ = load_policy(r.checkpoints()[-1], "cpu", r)
    np.testing.assert_allclose(predict(s, g), PolicyFn(algo)(s, g), rtol=0, atol=1e-5)
