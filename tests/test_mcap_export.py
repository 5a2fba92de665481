"""MCAP export of one episode: Foxglove JSON messages, read back with mcap's reader."""

import json

import numpy as np
import pytest
from mcap.reader import make_reader
from scipy.spatial.transform import Rotation

from aerohrl import task
from aerohrl.datagen.lerobot_writer import write_dataset
from aerohrl.datagen.mcap_export import TOPICS, export_mcap
from aerohrl.errors import UserError

LENGTHS = [6, 11, 4]


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    rng = np.random.default_rng(1)
    lengths = np.array(LENGTHS)
    F, E = int(lengths.sum()), len(lengths)
    ep = np.repeat(np.arange(E), lengths)

    def states(n):
        s = rng.standard_normal((n, 18)).astype(np.float32)
        s[:, task.ROT] = Rotation.random(n, random_state=rng.integers(1 << 31)).as_matrix().reshape(n, 9)
        return s

    goal = np.repeat(states(E)[:, :15], lengths, axis=0)
    cols = {
        "observation.state": states(F),
        "action": rng.standard_normal((F, 4), dtype=np.float32),
        "observation.desired_goal": goal,
        "next.observation.state": states(F),
        "next.reward": (rng.random(F) < 0.5).astype(np.float32),
        "next.done": np.r_[ep[1:] != ep[:-1], True],
        "next.success": rng.random(F) < 0.5,
    }
    root = tmp_path_factory.mktemp("mcap") / "ds"
    write_dataset(root, cols, ep)
    return root, cols, ep


def _read(path):
    out = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
            assert schema.name == TOPICS[channel.topic]
            json.loads(schema.data)
            out.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
    return out


def _quat(R_flat):
    return Rotation.from_matrix(np.asarray(R_flat, np.float64).reshape(3, 3)).as_quat(canonical=True)


def test_export_counts_and_content(ds, tmp_path):
    root, cols, ep = ds
    e = 1
    L = LENGTHS[e]
    rows = np.flatnonzero(ep == e)
    out = tmp_path / "sub" / "ep1.mcap"
    counts = export_mcap(root, e, out)
    assert counts == {
        "/tf": 2 * (L + 1),
        "/vehicle/pose": L + 1,
        "/vehicle/velocity": L + 1,
        "/goal/pose": L + 1,
        "/goal/velocity": L + 1,
        "/action": L,
        "/step": L,
    }
    msgs = _read(out)
    assert {k: len(v) for k, v in msgs.items()} == counts
    assert list(out.parent.iterdir()) == [out]  # no temporary left behind

    poses = msgs["/vehicle/pose"]
    assert [t for t, _ in poses] == [k * 10_000_000 for k in range(L + 1)]  # 100 Hz, episode-relative
    first, last = poses[0][1], poses[-1][1]
    assert first["timestamp"] == {"sec": 0, "nsec": 0} and first["frame_id"] == "world"
    s0, s_end = cols["observation.state"][rows[0]], cols["next.observation.state"][rows[-1]]
    for msg, s in ((first, s0), (last, s_end)):
        p = msg["pose"]["position"]
        assert np.array_equal(np.float32([p["x"], p["y"], p["z"]]), s[task.POS])
        q = msg["pose"]["orientation"]
        np.testing.assert_allclose([q["x"], q["y"], q["z"], q["w"]], _quat(s[task.ROT]), atol=1e-6)
    # a middle frame's pose is that frame's state
    mid = poses[3][1]["pose"]["position"]
    assert np.array_equal(np.float32([mid["x"], mid["y"], mid["z"]]), cols["observation.state"][rows[3]][task.POS])

    tf = msgs["/tf"]
    assert {m["child_frame_id"] for _, m in tf} == {"base_link", "goal"}
    t0 = [m for _, m in tf if m["child_frame_id"] == "base_link"][0]
    assert np.array_equal(np.float32([t0["translation"][k] for k in "xyz"]), s0[task.POS])

    g = cols["observation.desired_goal"][rows[0]]
    gp = msgs["/goal/pose"][0][1]["pose"]
    assert np.array_equal(np.float32([gp["position"][k] for k in "xyz"]), g[task.POS])
    np.testing.assert_allclose([gp["orientation"][k] for k in "xyzw"], _quat(g[task.ROT]), atol=1e-6)

    v = msgs["/vehicle/velocity"][2][1]
    assert np.array_equal(np.float32([v["linear"][k] for k in "xyz"]), cols["observation.state"][rows[2]][task.VEL])
    assert np.array_equal(np.float32([v["angular"][k] for k in "xyz"]), cols["observation.state"][rows[2]][task.RATE])

    acts = msgs["/action"]
    assert np.array_equal(np.float32([[m[n] for n in task.ACTION_NAMES] for _, m in acts]), cols["action"][rows])
    steps = [m for _, m in msgs["/step"]]
    assert [m["frame_index"] for m in steps] == list(range(L)) and all(m["episode_index"] == e for m in steps)
    assert [m["done"] for m in steps] == [False] * (L - 1) + [True]
    assert [m["success"] for m in steps] == cols["next.success"][rows].tolist()
    assert np.array_equal(np.float32([m["reward"] for m in steps]), cols["next.reward"][rows])


def test_export_is_deterministic(ds, tmp_path):
    root, _, _ = ds
    export_mcap(root, 2, tmp_path / "a.mcap")
    export_mcap(root, 2, tmp_path / "b.mcap")
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()


@pytest.mark.parametrize("episode", [-1, 3, 99, "0", 1.0, True])
def test_unknown_episode_is_a_user_error(ds, tmp_path, episode):
    root, _, _ = ds
    with pytest.raises(UserError, match="episode"):
        export_mcap(root, episode, tmp_path / "x.mcap")
    assert not list(tmp_path.iterdir())


def test_not_a_dataset_is_a_user_error(tmp_path):
    with pytest.raises(UserError):
        export_mcap(tmp_path, 0, tmp_path / "x.mcap")
