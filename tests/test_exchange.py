"""Dataset exchange: `datagen export --format minari|ogbench` load back in the real
libraries, `datagen push` stages our card, licence and metadata unchanged (no network here)."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys

import numpy as np
import pytest

from aerohrl.datagen import cli
from aerohrl.datagen.build import build
from aerohrl.datagen.lerobot_reader import read_columns
from aerohrl.datagen.spec import DatasetSpec

NOISE = (1.0, 0.5, 0.5, 0.5)


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    return build(
        DatasetSpec(goals=6, seed=5, action_noise=NOISE), tmp_path_factory.mktemp("x"), progress=False, log=lambda m: None
    ).path


def _episodes(cols):
    ep = cols["episode_index"]
    starts = np.flatnonzero(np.r_[True, ep[1:] != ep[:-1]])
    return starts, np.r_[starts[1:], len(ep)]


def test_ogbench_npz_loads_with_ogbench(ds, tmp_path, capsys):
    out = tmp_path / "quadrotor-reach.npz"
    assert cli.main(["export", str(ds), "--format", "ogbench", "-o", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    cols = read_columns(ds)
    starts, ends = _episodes(cols)
    raw = np.load(out)
    E, F = len(starts), len(cols["action"])
    assert raw["observations"].shape == (F + E, 18) and raw["actions"].shape == (F + E, 4) and raw["terminals"].sum() == E
    ogbench_utils = pytest.importorskip("ogbench.utils")
    d = ogbench_utils.load_dataset(str(out))  # regular layout: next_observations, the terminal states dropped
    assert d["observations"].shape == (F, 18) and d["next_observations"].shape == (F, 18) and d["actions"].shape == (F, 4)
    np.testing.assert_array_equal(d["observations"], cols["observation.state"])
    np.testing.assert_array_equal(d["next_observations"], cols["next.observation.state"])
    np.testing.assert_array_equal(d["actions"], cols["action"])  # the flown action (the critics' transition)
    assert np.flatnonzero(d["terminals"]).tolist() == (ends - 1).tolist()
    c = ogbench_utils.load_dataset(str(out), compact_dataset=True)
    assert c["valids"].sum() == F and c["observations"].shape == (F + E, 18)


def test_minari_dataset_loads_and_recovers_our_env(ds, tmp_path, monkeypatch, capsys):
    minari = pytest.importorskip("minari")
    root = tmp_path / "minari"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    assert cli.main(["export", str(ds), "--format", "minari", "--dataset-id", "aerohrl/reach/test-v0"]) == 0
    assert "wrote" in capsys.readouterr().out and (root / "aerohrl" / "reach" / "test-v0" / "data" / "metadata.json").is_file()
    m = minari.load_dataset("aerohrl/reach/test-v0")
    cols = read_columns(ds)
    starts, ends = _episodes(cols)
    assert m.total_episodes == len(starts) and m.total_steps == len(cols["action"])
    for i in (0, len(starts) - 1):
        e = m[i]
        a, b = starts[i], ends[i]
        np.testing.assert_allclose(e.observations["observation"][:-1], cols["observation.state"][a:b])
        np.testing.assert_allclose(e.observations["observation"][-1], cols["next.observation.state"][b - 1])
        np.testing.assert_allclose(e.observations["achieved_goal"], e.observations["observation"][:, :15])
        np.testing.assert_allclose(e.observations["desired_goal"][0], cols["observation.desired_goal"][a])
        np.testing.assert_allclose(e.actions, cols["action"][a:b])
        np.testing.assert_allclose(e.rewards, cols["next.reward"][a:b])
        assert e.terminations[-1] == cols["next.success"][b - 1] and e.truncations[-1] != e.terminations[-1]
        assert not e.terminations[:-1].any() and not e.truncations[:-1].any()
    env = m.recover_environment()
    assert env.spec.id == "aerohrl/QuadrotorReach-v0" and env.spec.kwargs["vehicle"] == "hummingbird"
    obs, _ = env.reset(seed=0)
    assert m.observation_space.contains(obs) and m.action_space == env.action_space
    # the goals the recovered env draws come from the dataset's rho_D: |p_i| in the spec's range
    assert (np.abs(obs["desired_goal"][:3]) >= 1.0).all() and (np.abs(obs["desired_goal"][:3]) <= 2.0).all()
    # the same id again: Minari never overwrites; one line, exit 2
    assert cli.main(["export", str(ds), "--format", "minari", "--dataset-id", "aerohrl/reach/test-v0"]) == 2
    assert "exists" in capsys.readouterr().err


def test_export_bad_input_is_one_line(ds, tmp_path, capsys):
    for argv, msg in (
        (["--format", "ogbench", "-o", str(tmp_path / "x.txt")], ".npz"),
        (["--format", "mcap"], "--episode"),
        (["--format", "ogbench", "--episode", "1"], "mcap only"),
        (["--format", "parquet"], "invalid choice"),
    ):
        with pytest.raises(SystemExit) if msg == "invalid choice" else _nothing():
            rc = cli.main(["export", str(ds), *argv])
            assert rc == 2
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert cli.main(["export", str(tmp_path / "none"), "--format", "ogbench"]) == 2
    assert "no dataset at" in capsys.readouterr().err


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *a):
        return False


def test_export_mcap_through_export_and_the_old_command(ds, tmp_path):
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    assert cli.main(["export", str(ds), "--format", "mcap", "--episode", "2", "-o", str(a)]) == 0
    assert cli.main(["export-mcap", str(ds), "--episode", "2", "-o", str(b)]) == 0
    assert a.read_bytes() == b.read_bytes() and a.stat().st_size > 1000


def test_push_stages_card_licence_and_metadata_unchanged(ds, tmp_path, capsys):
    staging = tmp_path / "stage"
    assert cli.main(["push", str(ds), "--repo-id", "someone/quadrotor", "--staging", str(staging), "--dry-run"]) == 0
    assert "staged" in capsys.readouterr().out

    def files(root):
        return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in root.rglob("*") if p.is_file()}

    src, dst = files(ds), files(staging)
    assert set(dst) == set(src) | {"LICENSE"} and all(dst[k] == v for k, v in src.items())
    assert (staging / "LICENSE").read_text().startswith("MIT License")
    card = (staging / "README.md").read_text()
    assert card.startswith("---\nlicense: mit") and "action noise" in card and "| `action.expert` | float32 | (4,) |" in card
    # the staged copy is a LeRobot dataset our reader opens
    np.testing.assert_array_equal(read_columns(staging)["action"], read_columns(ds)["action"])
    # a non-empty staging folder, a bad repo id, --dry-run without --staging: one line, exit 2, nothing uploaded
    for argv in (
        ["--repo-id", "someone/q", "--staging", str(staging), "--dry-run"],
        ["--repo-id", "noslash", "--dry-run"],
        ["--repo-id", "someone/q", "--dry-run"],
    ):
        assert cli.main(["push", str(ds), *argv]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err, err


def test_push_without_network_is_one_line(ds, tmp_path):
    """No network here: the upload fails in one line (exit 2) after staging."""
    pytest.importorskip("huggingface_hub")
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_TOKEN": "hf_invalid"}
    p = subprocess.run(
        [sys.executable, "-m", "aerohrl.datagen.cli", "push", str(ds), "--repo-id", "someone/quadrotor"],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert p.returncode == 2 and "staged" in p.stdout, (p.stdout, p.stderr)
    assert p.stderr.startswith("datagen: error: upload to someone/quadrotor failed") and "Traceback" not in p.stderr, p.stderr
