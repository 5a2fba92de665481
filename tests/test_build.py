"""`datagen build`: the pipeline's invariants, reproducibility, versioning, atomicity."""

from pathlib import Path

import numpy as np
import pytest

from aerohrl import task
from aerohrl.errors import UserError
from aerohrl.datagen import build as build_mod
from aerohrl.datagen.build import build, generate
from aerohrl.datagen.lerobot_reader import read_columns
from aerohrl.datagen.manifest import read_manifest, validate
from aerohrl.datagen.spec import DatasetSpec, load_spec, version_name

SMALL = DatasetSpec(goals=16, seed=7)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds")
    return build(SMALL, out, progress=False), out


def test_frames_are_consistent_transitions(built):
    res, _ = built
    c = read_columns(res.path)
    ep, fi = c["episode_index"], c["frame_index"]
    s, ns = c["observation.state"], c["next.observation.state"]
    same = ep[1:] == ep[:-1]
    # within an episode the next state of frame k is the state of frame k+1
    np.testing.assert_array_equal(ns[:-1][same], s[1:][same])
    np.testing.assert_array_equal(fi[1:][same], fi[:-1][same] + 1)
    # every episode starts at rest in hover at the origin
    start = s[fi == 0]
    hover = np.r_[np.zeros(6), np.eye(3).reshape(9), np.zeros(3)]
    np.testing.assert_allclose(start, np.broadcast_to(hover, start.shape), atol=1e-7)
    # reward and success are the goal-reached test at the next state; done marks episode ends
    g = c["observation.desired_goal"]
    reached = task.goal_reached(ns[:, :15].astype(np.float64), g.astype(np.float64))
    np.testing.assert_array_equal(c["next.success"], reached)
    np.testing.assert_array_equal(c["next.reward"], reached.astype(np.float32))
    np.testing.assert_array_equal(c["next.done"], np.r_[~same, True])
    # the desired goal is constant within an episode
    assert np.all(g[1:][same] == g[:-1][same])
    assert res.episodes == SMALL.goals and res.frames == len(ep)


def test_episode_lengths_follow_reference_durations(built):
    res, _ = built
    meta = read_manifest(res.path)
    import pyarrow.parquet as pq

    eps = pq.read_table(res.path / build_mod.EPISODES_FILE).to_pydict()
    T = np.asarray(eps["reference_duration_s"])
    np.testing.assert_array_equal(np.asarray(eps["length"]), np.ceil(T * SMALL.fps - 1e-9).astype(int))
    assert np.all((T > 0) & (T <= SMALL.t_max))
    goal_abs = np.abs(np.asarray(eps["goal_pos"]))
    assert np.all((goal_abs >= 1.0) & (goal_abs <= 2.0))
    assert meta["episodes"] == SMALL.goals and meta["spec"] == SMALL.to_dict()
    assert meta["expert_success_rate"] == pytest.approx(np.mean(eps["expert_success"]))


def test_same_spec_gives_byte_identical_files(built, tmp_path):
    res, _ = built
    again = build(SMALL, tmp_path, progress=False)
    assert again.path.name == res.path.name == version_name(SMALL)
    files = sorted(p.relative_to(res.path) for p in res.path.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again.path) for p in again.path.rglob("*") if p.is_file())
    for f in files:
        assert (res.path / f).read_bytes() == (again.path / f).read_bytes(), f


def test_existing_version_is_verified_not_rebuilt(built, monkeypatch):
    res, out = built
    monkeypatch.setattr(build_mod, "generate", lambda *a, **k: pytest.fail("rebuilt an existing version"))
    again = build(SMALL, out, progress=False)
    assert not again.created and again.path == res.path and again.frames == res.frames


def test_damaged_existing_version_is_refused(tmp_path):
    res = build(DatasetSpec(goals=3, seed=1), tmp_path, progress=False)
    data = next((res.path / "data").rglob("*.parquet"))
    raw = bytearray(data.read_bytes())
    raw[len(raw) // 2] ^= 0x01
    data.write_bytes(bytes(raw))
    assert validate(res.path)
    with pytest.raises(UserError, match="damaged"):
        build(DatasetSpec(goals=3, seed=1), tmp_path, progress=False)


def test_interrupted_build_leaves_nothing(tmp_path, monkeypatch):
    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(build_mod, "write_manifest", boom)
    with pytest.raises(KeyboardInterrupt):
        build(DatasetSpec(goals=3, seed=2), tmp_path, progress=False)
    left = list((tmp_path / "quadrotor-reach").iterdir())
    assert left == [], left


def test_estimate_is_logged_and_a_build_that_does_not_fit_refused(tmp_path, monkeypatch):
    from aerohrl.datagen import estimate as est_mod

    said = []
    res = build(DatasetSpec(goals=40, seed=3), tmp_path, progress=False, log=said.append)
    line = next(s for s in said if s.startswith("estimate:"))
    frames = int(line.split(" episodes, ")[1].split(" frames")[0].replace(",", ""))
    assert abs(frames - res.frames) < 0.15 * res.frames and "40 episodes" in line and "on disk" in line
    monkeypatch.setattr(est_mod, "available_memory", lambda: 50e6)  # less than the 200 MB base
    monkeypatch.setattr(build_mod, "stream_dataset", lambda *a, **k: pytest.fail("started a build that cannot fit"))
    with pytest.raises(UserError, match=r"needs about 2\d\d\.\d MB of memory \(50\.0 MB available\).*--force"):
        build(DatasetSpec(goals=40, seed=4), tmp_path, progress=False, log=lambda *a: None)
    monkeypatch.undo()
    monkeypatch.setattr(est_mod, "available_disk", lambda folder: 1000.0)
    assert build(DatasetSpec(goals=3, seed=4), tmp_path, progress=False, log=lambda *a: None, force=True).created


def test_two_builds_of_one_version_at_once_both_succeed(tmp_path, monkeypatch):
    """The second to finish finds the first's result in place (rename fails: ENOTEMPTY),
    verifies it and keeps it instead of failing with 'Directory not empty'."""
    spec = DatasetSpec(goals=3, seed=5)
    real = build_mod.stream_dataset
    first = []

    def racing(s, root, progress=True, runner=None):
        data = real(s, root, progress, runner)
        monkeypatch.setattr(build_mod, "stream_dataset", real)
        first.append(build(s, tmp_path, progress=False, log=lambda *a: None))  # the other process, finishing first
        return data

    monkeypatch.setattr(build_mod, "stream_dataset", racing)
    said = []
    second = build(spec, tmp_path, progress=False, log=said.append)
    assert first[0].created and not second.created and second.path == first[0].path
    assert any("another build of" in s for s in said) and validate(second.path) == []
    assert sorted(p.name for p in (tmp_path / "quadrotor-reach").iterdir()) == [second.path.name]


def test_version_name_derives_from_spec():
    a = version_name(DatasetSpec())
    assert a == version_name(DatasetSpec())
    assert a != version_name(DatasetSpec(seed=1))
    assert a != version_name(DatasetSpec(vel_range=(-2.0, 2.0)))
    assert a.startswith("n250-s0-")


def test_spec_file_matches_defaults():
    spec = load_spec(Path(__file__).parents[1] / "datasets" / "quadrotor-reach.toml")
    assert spec == DatasetSpec()


def test_continuations_leave_earlier_versions_and_rest_episodes_unchanged():
    # published version names (README, runs) must survive the field's addition
    assert version_name(DatasetSpec()) == "n250-s0-dbb240c0"
    assert version_name(DatasetSpec(goals=10000)) == "n10000-s0-6e76448b"
    assert version_name(DatasetSpec(continuations=8)) != version_name(DatasetSpec())
    assert "continuations" not in DatasetSpec().to_dict()
    plain = generate(SMALL, progress=False)
    both = generate(DatasetSpec(goals=16, seed=7, continuations=12), progress=False)
    F = len(plain.state)
    assert np.array_equal(both.state[:F], plain.state) and np.array_equal(both.action[:F], plain.action)
    assert np.array_equal(both.goal_vec[:16], plain.goal_vec)


def test_continuations_start_where_a_rest_flight_passes_and_continue_its_commands():
    data = generate(DatasetSpec(goals=16, seed=7, continuations=12), progress=False)
    assert len(data.T) == 28 and (data.source_episode[:16] == -1).all() and (data.source_episode[16:] >= 0).all()
    first = np.r_[0, np.cumsum(data.length)[:-1]]
    for e in range(16, 28):
        src = first[data.source_episode[e]] + data.source_frame[e]
        assert data.episode_index[src] == data.source_episode[e]
        s0, s_src = data.state[first[e]], data.state[src]
        assert np.allclose(s0[task.POS], 0.0)
        assert np.allclose(s0[3:], s_src[3:], atol=1e-12)  # velocity, attitude and body rates carried over
        # the new reference starts where the old one stood (p, v, a), so the expert commands the same
        # collective thrust; the rate commands differ by the feed-forward of a new jerk
        assert np.isclose(data.action[first[e], 0], data.action[src, 0], atol=1e-6)
    assert data.episode_success[16:].mean() >= 0.9


def test_continuation_episodes_are_not_reach_desired_goals(tmp_path):
    from aerohrl.algorithms.data import load_dataset
    from aerohrl.eval.tasks import reach_desired

    res = build(DatasetSpec(goals=16, seed=7, continuations=12), tmp_path, progress=False)
    data = load_dataset(res.path)
    assert data.num_episodes == 28 and data.rest_start_episodes().tolist() == list(range(16))
    eps = reach_desired(data, n=40)
    assert eps.source_episode.max() < 16 and set(eps.source_episode) == set(range(16))
    table = __import__("pyarrow.parquet", fromlist=["x"]).read_table(res.path / build_mod.EPISODES_FILE)
    assert table.column("start_source_episode").to_pylist()[:16] == [-1] * 16
    assert read_manifest(res.path)["continuations"]["episodes"] == 12


@pytest.mark.parametrize(
    "kw,msg",
    [
        ({"continuations": -1}, "continuations must be >= 0"),
        ({"seed": -1}, "seed must be >= 0"),
        ({"goals": 0}, "goals must be >= 1"),
        ({"goals": -4}, "goals must be >= 1"),
        ({"goals": 2.5}, "goals must be an integer"),
        ({"pos_range": (2.0, 1.0)}, "inverted"),
        ({"vel_range": (1.0, 1.0)}, "empty"),
        ({"solver": "cvx"}, "solver"),
        ({"degree": 7}, "closed-form"),
    ],
)
def test_bad_specs_are_one_line_errors(kw, msg):
    with pytest.raises(UserError, match=msg) as e:
        DatasetSpec(**kw)
    assert "\n" not in str(e.value)


@pytest.mark.slow
def test_expert_succeeds_on_default_250_goals(tmp_path):
    data = generate(DatasetSpec(), progress=False)
    rate = data.episode_success.mean()
    assert rate >= 0.98, f"expert success {rate:.3f} < 0.98: a controller or gain bug"
