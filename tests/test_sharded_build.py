"""``datagen build --workers N``: blocks flown in worker processes (or Ray tasks) give a
dataset byte-identical to the single-process build of the same spec.

The unit of sharding is the rollout block (build.ROLLOUT_BLOCK, 8,192 episodes); the
tests shrink it (in the parent, which cuts the blocks) so that a few hundred goals make
several blocks, and build the same spec with 1 and with 3 workers."""

import os
import subprocess
import sys

import pytest

from aerohrl.datagen import build as B
from aerohrl.datagen.cli import main as datagen_main
from aerohrl.datagen.manifest import validate
from aerohrl.datagen.spec import DatasetSpec


def _files(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _same_bytes(spec, tmp_path, block, workers=3, ray_address=None):
    B.ROLLOUT_BLOCK = block
    one = B.build(spec, tmp_path / "one", progress=False, log=lambda m: None)
    many = B.build(spec, tmp_path / "many", progress=False, log=lambda m: None, workers=workers, ray_address=ray_address)
    assert len(B.block_bounds(one.episodes)) - 1 >= 3  # several blocks were shared out
    a, b = _files(one.path), _files(many.path)
    assert sorted(a) == sorted(b)
    for name in a:
        assert a[name] == b[name], name
    assert validate(many.path) == []
    return many


@pytest.fixture(autouse=True)
def _restore_block():
    block = B.ROLLOUT_BLOCK
    yield
    B.ROLLOUT_BLOCK = block


def test_three_workers_give_the_single_process_bytes(tmp_path):
    _same_bytes(DatasetSpec(goals=120, seed=4), tmp_path, block=40)


def test_three_workers_stream_a_noisy_recipe_byte_identically(tmp_path):
    """Action noise (per-block noise streams), no continuations: the streamed path, each
    block written as it comes back from its worker."""
    _same_bytes(DatasetSpec(goals=90, seed=3, action_noise=(1.0, 0.5)), tmp_path, block=30)


@pytest.mark.slow
def test_sharded_recipe_with_continuations_is_byte_identical_and_validates(tmp_path):
    """Action noise (per-block noise streams) and continuation episodes (a second part
    whose starts come from the first part's frames), 1,000 goals in 4 blocks + 1."""
    res = _same_bytes(DatasetSpec(goals=1000, seed=2, action_noise=(1.0, 0.5), continuations=250), tmp_path, block=250)
    env = dict(os.environ, OMP_NUM_THREADS="1")
    r = subprocess.run(
        [sys.executable, "-m", "aerohrl.datagen.cli", "validate", str(res.path)], capture_output=True, text=True, env=env
    )
    assert r.returncode == 0 and r.stdout.strip().endswith("OK")


@pytest.mark.slow
def test_ray_tasks_give_the_single_process_bytes(tmp_path):
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, object_store_memory=200 * 2**20, logging_level="ERROR")
    try:
        _same_bytes(DatasetSpec(goals=120, seed=4), tmp_path, block=40, workers=2, ray_address="auto")
    finally:
        ray.shutdown()


def test_cli_flags(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        datagen_main(["build", "--goals", "10", "--workers", "0", "--out", str(tmp_path)])
    assert e.value.code == 2 and "--workers" in capsys.readouterr().err
    assert datagen_main(["build", "--goals", "10", "--out", str(tmp_path), "--ray-address", "127.0.0.1:9", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "cannot reach a Ray cluster at 127.0.0.1:9" in err
    assert not list(tmp_path.rglob("*.parquet"))
