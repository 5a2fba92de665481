"""`aerohrl export-policy`: the exported policy equals the PyTorch one on 10,000 states, carries its metadata."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from aerohrl.cli import main


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from aerohrl.algorithms.config import make_config
    from aerohrl.algorithms.synthetic import write_synthetic_dataset
    from aerohrl.algorithms.trainer import start_run

    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("export")
    ds = write_synthetic_dataset(root / "ds")
    tiny = dict(hidden=(16, 16), critic_hidden=(16, 16), batch_size=32, steps=20, log_every=10, checkpoint_every=20)
    cfg = make_config("cpu", algo="td3bc", dataset=str(ds), eval_every=20, eval_episodes=2, eval_horizon=20, **tiny)
    tr = start_run(cfg, root / "runs" / "td3bc", progress=False)
    tr.train()
    return root / "runs" / "td3bc"


def _states(n: int = 10_000) -> tuple[np.ndarray, np.ndarray]:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    R = Rotation.random(n, random_state=1).as_matrix().reshape(n, 9)
    Rg = Rotation.random(n, random_state=2).as_matrix().reshape(n, 9)
    s = np.column_stack([rng.uniform(-3, 3, (n, 3)), rng.uniform(-3, 3, (n, 3)), R, rng.uniform(-2, 2, (n, 3))])
    g = np.column_stack([rng.uniform(-3, 3, (n, 3)), rng.uniform(-3, 3, (n, 3)), Rg])
    return s.astype(np.float32), g.astype(np.float32)


def _reference(run, s, g) -> np.ndarray:
    from aerohrl.algorithms.base import load_policy
    from aerohrl.algorithms.run import Run
    from aerohrl.envs.rollout import PolicyFn

    r = Run.open(run, kind="train")
    algo, _ = load_policy(r.checkpoints()[-1], "cpu", r)
    return PolicyFn(algo)(s, g)


@pytest.mark.parametrize("fmt, suffix", [("torchscript", "pt"), ("onnx", "onnx")])
def test_export_matches_pytorch(run, tmp_path, fmt, suffix, capsys):
    if fmt == "onnx":
        pytest.importorskip("onnxruntime")
        pytest.importorskip("onnx")
    from aerohrl.algorithms.export import load_exported

    out = tmp_path / f"policy.{suffix}"
    assert main(["export-policy", "--run", str(run), "--format", fmt, "-o", str(out), "--latency"]) == 0
    assert "us (median)" in capsys.readouterr().out
    predict, meta = load_exported(out)
    s, g = _states()
    np.testing.assert_allclose(predict(s, g), _reference(run, s, g), rtol=0, atol=1e-5)
    assert meta["inputs"]["state"]["names"][:3] == ["px", "py", "pz"] and len(meta["normalisation"]["in_mean"]) == 30
    assert meta["algorithm"] == "TD3BC" and meta["checkpoint_step"] == 20
    json.dumps(meta)


def test_export_errors_are_one_line(run, tmp_path, capsys):
    code = main(["export-policy", "--run", str(tmp_path / "none"), "--format", "torchscript", "-o", str(tmp_path / "p.pt")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err
