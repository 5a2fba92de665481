"""The public API (aerohrl.api, re-exported by `import aerohrl`): the README's example runs,
each function does what its docstring says, and `import aerohrl` stays light."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import aerohrl
from aerohrl.errors import UserError

ROOT = Path(__file__).resolve().parents[1]
TINY = dict(hidden=(16, 16), critic_hidden=(16, 16), batch_size=32, steps=40, log_every=10, checkpoint_every=20, eval_every=0)


def _run(code: str, cwd: Path, timeout: int = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1", "MPLBACKEND": "Agg"}
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def readme_example() -> str:
    text = (ROOT / "README.md").read_text()
    m = re.search(r"<!-- api-example:begin -->\s*```python\n(.*?)```\s*<!-- api-example:end -->", text, re.S)
    assert m, "README.md has no api-example block"
    return m.group(1)


@pytest.fixture(scope="module")
def ds(tmp_path_factory) -> Path:
    return aerohrl.build_dataset(goals=12, seed=1, out=tmp_path_factory.mktemp("api") / "datasets")


@pytest.fixture(scope="module")
def run(ds, tmp_path_factory):
    return aerohrl.train({"algo": "gcsl", "dataset": ds, **TINY}, out=tmp_path_factory.mktemp("api") / "runs", name="g")


@pytest.mark.slow  # ~30 s: a subprocess that builds, trains, flies and evaluates
def test_readme_example_runs(tmp_path):
    code = readme_example()
    n_lines = len(code.strip().splitlines())
    assert 10 <= n_lines <= 20, n_lines
    small = code
    for old, new in (
        ("goals=250", "goals=12"),
        ('"steps": 3000', '"steps": 40, "hidden": (32, 32), "batch_size": 64'),
        ("episodes=250", "episodes=12"),
    ):
        assert old in small, f"the README example no longer says {old}: update this test"
        small = small.replace(old, new)
    p = _run(small, tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    out = p.stdout
    assert re.search(r"goal (reached|missed) after \d+ steps", out), out
    assert re.search(r"Reach-Desired: \d+\.\d % of 12 goals", out), out
    assert "Traceback" not in p.stderr and "torchrl" not in out + p.stderr, (out, p.stderr)  # no torchrl INFO chatter
    assert len(list((tmp_path / "datasets" / "quadrotor-reach").iterdir())) == 1
    (run_dir,) = list((tmp_path / "runs").iterdir())
    assert (run_dir / "checkpoints").is_dir() and (run_dir / "eval" / "reach-desired" / "summary.json").is_file()


def test_import_aerohrl_is_light():
    p = _run(
        "import sys, aerohrl; print(sorted(m for m in ('numpy', 'torch', 'gymnasium', 'lerobot', 'torchrl') if m in sys.modules))",
        ROOT,
    )
    assert p.returncode == 0 and p.stdout.strip() == "[]", (p.stdout, p.stderr)
    p = _run("import aerohrl; print(aerohrl.train.__module__, aerohrl.Run.__name__, 'load_policy' in dir(aerohrl))", ROOT)
    assert p.stdout.split() == ["aerohrl.api", "Run", "True"], p.stderr


@pytest.mark.parametrize(
    "code",
    [
        "import aerohrl\nimport gymnasium as gym\nenv = gym.make('aerohrl/QuadrotorReach-v0')",
        "import gymnasium as gym\nimport aerohrl\nenv = gym.make('aerohrl/QuadrotorReach-v0')",
        "import gymnasium as gym\nenv = gym.make('aerohrl:aerohrl/QuadrotorReach-v0')",
        "import gymnasium as gym\nenv = gym.make_vec('aerohrl:aerohrl/QuadrotorReach-v0', num_envs=3, vectorization_mode='vector_entry_point')",
        # torchrl asks importlib.util.find_spec("gymnasium") before anyone imports it
        "import aerohrl, importlib.util\nimportlib.util.find_spec('gymnasium')\nimport torchrl\nimport gymnasium as gym\nenv = gym.make('aerohrl/QuadrotorReach-v0')",
    ],
    ids=["aerohrl-first", "gymnasium-first", "module-prefix", "vector", "find-spec-first"],
)
def test_gymnasium_make_without_importing_the_env_module(code):
    p = _run(
        code + "\nimport sys\nobs, _ = env.reset(seed=0)\nprint(obs['desired_goal'].shape, 'aerohrl.envs.reach' in sys.modules)",
        ROOT,
    )
    assert p.returncode == 0, p.stderr[-2000:]
    assert p.stdout.split()[-1] == "True" and ("(15,)" in p.stdout or "(3, 15)" in p.stdout), p.stdout


def test_load_dataset_three_ways(ds):
    cols = aerohrl.load_dataset(ds)
    assert cols["observation.state"].shape[1:] == (18,) and cols["action"].shape[1:] == (4,)
    data = aerohrl.load_dataset(ds, as_="torch")
    assert len(data) == len(cols["action"]) and data.info["version"] == ds.name
    np.testing.assert_array_equal(data.action.numpy(), cols["action"])
    lr = aerohrl.load_dataset(ds, as_="lerobot")
    assert len(lr) == len(cols["action"]) and lr.meta.total_episodes == 12
    np.testing.assert_allclose(lr[5]["observation.state"].numpy(), cols["observation.state"][5])
    with pytest.raises(UserError, match="as_"):
        aerohrl.load_dataset(ds, as_="pandas")
    with pytest.raises(UserError, match="no dataset"):
        aerohrl.load_dataset(ds.parent / "missing")


def test_build_dataset_spec_forms(ds, tmp_path):
    from aerohrl.datagen.spec import DatasetSpec

    again = aerohrl.build_dataset(DatasetSpec(goals=12), seed=1, out=ds.parent.parent)  # verifies, does not rebuild
    assert again == ds
    spec = tmp_path / "s.toml"
    spec.write_text("goals = 3\nseed = 2\n")
    assert aerohrl.build_dataset(spec, out=tmp_path).name.startswith("n3-s2-")
    with pytest.raises(UserError):
        aerohrl.build_dataset(goals=0, out=tmp_path)


def test_train_returns_a_trained_run_and_resume_extends_it(run, ds):
    assert isinstance(run, aerohrl.Run) and run.step == 40 and run.config.algo == "gcsl"
    assert [c.name for c in run.checkpoints()] == ["step-000000020.pt", "step-000000040.pt"]
    assert run.dataset == ds.resolve() and [r["step"] for r in run.metrics() if "loss_actor" in r] == [10, 20, 30, 40]
    other = aerohrl.train({"algo": "gcsl", "dataset": ds, **TINY, "steps": 20}, out=run.path.parent, name="h")
    more = aerohrl.train(resume=other, steps=60)
    assert other.step == 20 and more.step == 60 and more.path == other.path
    with pytest.raises(UserError, match="taken|exists"):
        aerohrl.train({"dataset": ds, **TINY}, out=run.path.parent, name="g")
    with pytest.raises(UserError, match="dataset"):
        aerohrl.train({"algo": "gcsl"})
    with pytest.raises(UserError, match="algo must be one of"):
        aerohrl.train({"dataset": ds, "algo": "ppo"})


def test_load_policy_acts_on_numpy_and_torch(run, ds):
    import torch

    pol = aerohrl.load_policy(run)
    assert pol.step == run.step
    cols = aerohrl.load_dataset(ds)
    s, g = cols["observation.state"][:7], cols["observation.desired_goal"][:7]
    a = pol.act(s, g)
    assert isinstance(a, np.ndarray) and a.shape == (7, 4) and np.isfinite(a).all()
    np.testing.assert_allclose(pol.act(s[3], g[3]), a[3], rtol=1e-6)  # unbatched
    at = pol.act(torch.as_tensor(s), torch.as_tensor(g))
    assert isinstance(at, torch.Tensor) and at.shape == (7, 4)
    first = aerohrl.load_policy(run.path, step=20)
    assert first.step == 20 and not np.allclose(first.act(s, g), a)
    assert aerohrl.load_policy(run.checkpoints()[0]).step == 20  # a checkpoint file
    with pytest.raises(UserError, match="no checkpoint of step 7"):
        aerohrl.load_policy(run, step=7)
    with pytest.raises(UserError, match=r"\(\.\.\., 18\)"):
        pol.act(s[:, :15], g)


def test_evaluate_and_make_env(run, ds):
    summary = aerohrl.evaluate(run, "reach-desired", checkpoints=2, episodes=12)
    assert summary["episodes"] == 12 and len(summary["checkpoints"]) == 2 and 0 <= summary["success_mean"] <= 1
    with pytest.raises(UserError, match="unknown evaluation option"):
        aerohrl.evaluate(run, "reach-desired", epsiodes=3)
    env = aerohrl.make_env(dataset=ds)
    obs, _ = env.reset(seed=0)
    goals = aerohrl.load_dataset(ds)["observation.desired_goal"]
    assert np.isclose(goals, obs["desired_goal"], atol=1e-6).all(1).any()  # a goal of the dataset
    venv, raw = aerohrl.make_env(4, normalize_actions=True), aerohrl.make_env(4)
    assert np.all(venv.single_action_space.low == -1) and np.all(venv.single_action_space.high == 1)
    lo, hi = raw.single_action_space.low, raw.single_action_space.high
    venv.reset(seed=0), raw.reset(seed=0)
    u = np.random.default_rng(0).uniform(-1, 1, (30, 4, 4))
    u[:, 0] = -1.0  # vehicle 0: zero thrust
    for k in range(30):
        obs, *_ = venv.step(u[k])
        ref, *_ = raw.step(lo + (u[k] + 1) / 2 * (hi - lo))
        np.testing.assert_allclose(obs["observation"], ref["observation"], rtol=1e-8, atol=1e-8)
    assert obs["observation"][0, 5] < -1.0  # falling after 0.3 s without thrust
    one = aerohrl.make_env(normalize_actions=True)
    assert one.action_space.shape == (4,) and np.all(one.action_space.low == -1)


def test_torchrl_info_lines_do_not_reach_the_terminal(capfd, monkeypatch):
    import torch
    from tensordict import TensorDict

    import aerohrl.algorithms.networks  # noqa: F401  (every algorithm imports it; it quietens torchrl)
    from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer

    if "RL_LOGGING_LEVEL" in os.environ:
        pytest.skip("the user chose torchrl's logging level")
    rb = TensorDictReplayBuffer(storage=LazyTensorStorage(10))
    rb.extend(TensorDict({"a": torch.zeros(3)}, [3]))  # torchrl logs "Initialized LazyTensorStorage ..." at INFO
    out = capfd.readouterr()
    assert "Initialized" not in out.out + out.err
    import logging

    assert logging.getLogger("torchrl").getEffectiveLevel() == logging.WARNING
