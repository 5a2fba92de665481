"""Export one episode of a dataset as an MCAP file for Foxglove (JSON-schema messages).

Topics (log time = the frame's timestamp, episode-relative, rounded to the microsecond,
on the fixed epoch 0, so the same episode always gives the same bytes):

* ``/tf`` — ``foxglove.FrameTransform`` ``world -> base_link`` (vehicle) and
  ``world -> goal`` (desired goal), for the 3D panel;
* ``/vehicle/pose`` — ``foxglove.PoseInFrame`` (position, attitude from R);
* ``/vehicle/velocity`` — ``aerohrl.Velocity``: world-frame ``linear`` {x,y,z}, body rates
  ``angular`` {x,y,z} and ``speed`` (plot e.g. ``/vehicle/velocity.linear.x``);
* ``/goal/pose`` — ``foxglove.PoseInFrame`` of the desired goal; ``/goal/velocity`` —
  ``aerohrl.Velocity`` (``linear`` only);
* ``/action`` — ``aerohrl.Action``: ``c`` (collective thrust, m/s^2) and the body-rate
  commands ``wx_cmd``, ``wy_cmd``, ``wz_cmd`` (rad/s);
* ``/step`` — ``aerohrl.Step``: ``frame_index``, ``reward``, ``done``, ``success``.

The vehicle and goal topics carry one message per frame plus one for the final state
(``next.observation.state`` of the last frame, one period later), so an episode of ``L``
frames has ``L + 1`` poses and ``L`` actions. Quaternions come from R via
``scipy.spatial.transform.Rotation`` (canonical: w >= 0).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from aerohrl import task
from aerohrl.atomic import atomic_path
from aerohrl.errors import UserError

EPOCH_NS = 0
WORLD_FRAME = "world"
VEHICLE_FRAME = "base_link"
GOAL_FRAME = "goal"
LIBRARY = "aerohrl.datagen.mcap_export"

_TIME = {
    "type": "object",
    "title": "time",
    "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}},
}
_VEC3 = {
    "type": "object",
    "title": "foxglove.Vector3",
    "properties": {k: {"type": "number"} for k in "xyz"},
}
_QUAT = {
    "type": "object",
    "title": "foxglove.Quaternion",
    "properties": {k: {"type": "number"} for k in "xyzw"},
}
SCHEMAS = {
    "foxglove.FrameTransform": {
        "title": "foxglove.FrameTransform",
        "description": "A transform between two reference frames in 3D space",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "parent_frame_id": {"type": "string"},
            "child_frame_id": {"type": "string"},
            "translation": _VEC3,
            "rotation": _QUAT,
        },
    },
    "foxglove.PoseInFrame": {
        "title": "foxglove.PoseInFrame",
        "description": "A timestamped pose for an object or reference frame in 3D space",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "frame_id": {"type": "string"},
            "pose": {
                "type": "object",
                "title": "foxglove.Pose",
                "properties": {"position": _VEC3, "orientation": _QUAT},
            },
        },
    },
    "aerohrl.Velocity": {
        "title": "aerohrl.Velocity",
        "description": "Linear velocity (world frame, m/s), body rates (rad/s) and speed (m/s)",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "frame_id": {"type": "string"},
            "linear": _VEC3,
            "angular": _VEC3,
            "speed": {"type": "number"},
        },
    },
    "aerohrl.Action": {
        "title": "aerohrl.Action",
        "description": "CTBR action: collective thrust (m/s^2) and body-rate commands (rad/s)",
        "type": "object",
        "properties": {"timestamp": _TIME, **{n: {"type": "number"} for n in task.ACTION_NAMES}},
    },
    "aerohrl.Step": {
        "title": "aerohrl.Step",
        "description": "Per-step reward and flags of the episode",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "episode_index": {"type": "integer"},
            "frame_index": {"type": "integer"},
            "reward": {"type": "number"},
            "done": {"type": "boolean"},
            "success": {"type": "boolean"},
        },
    },
}
TOPICS = {
    "/tf": "foxglove.FrameTransform",
    "/vehicle/pose": "foxglove.PoseInFrame",
    "/vehicle/velocity": "aerohrl.Velocity",
    "/goal/pose": "foxglove.PoseInFrame",
    "/goal/velocity": "aerohrl.Velocity",
    "/action": "aerohrl.Action",
    "/step": "aerohrl.Step",
}
_COLUMNS = [
    "observation.state",
    "next.observation.state",
    "observation.desired_goal",
    "action",
    "next.reward",
    "next.done",
    "next.success",
    "timestamp",
    "frame_index",
    "episode_index",
]


def _episode_rows(root: Path, episode: int) -> tuple[dict[str, np.ndarray], dict]:
    """The frames of one episode (numpy) located through the episodes parquet, and info.json."""
    from aerohrl.datagen.lerobot_layout import DatasetLayout
    from aerohrl.datagen.lerobot_reader import read_info

    info = read_info(root)
    n = info.get("total_episodes")
    if isinstance(episode, bool) or not isinstance(episode, (int, np.integer)) or not isinstance(n, int) or not 0 <= episode < n:
        raise UserError(f"no episode {episode!r} in {root} (it has {n} episodes: 0..{n - 1 if isinstance(n, int) else '?'})")
    episode = int(episode)
    missing = [c for c in _COLUMNS if c not in info["features"]]
    if missing:
        raise UserError(f"{root}: features {missing} missing; not an aerohrl reach dataset")
    layout = DatasetLayout(root)
    meta_paths = layout.episodes_files()
    row = None
    for p in meta_paths:
        try:
            t = pq.read_table(
                p,
                columns=["episode_index", "data/chunk_index", "data/file_index", "length"],
                filters=[("episode_index", "=", episode)],
            )
        except (OSError, pa.ArrowException, ValueError) as e:
            raise UserError(f"cannot read {p}: {e}") from None
        if t.num_rows:
            row = {c: t.column(c)[0].as_py() for c in t.column_names}
            break
    if row is None:
        raise UserError(f"no episode {episode} in the episodes metadata of {root}")
    path = layout.data_file(row["data/chunk_index"], row["data/file_index"])
    try:
        t = pq.read_table(path, columns=_COLUMNS, filters=[("episode_index", "=", episode)])
    except FileNotFoundError:
        raise UserError(f"missing file {path}") from None
    except (OSError, pa.ArrowException, ValueError) as e:
        raise UserError(f"cannot read {path}: {e}") from None
    if t.num_rows != row["length"] or t.num_rows == 0:
        raise UserError(f"{path}: episode {episode} has {t.num_rows} frames, the metadata says {row['length']}")
    out = {}
    for c in _COLUMNS:
        a = t.column(c).combine_chunks()
        if pa.types.is_fixed_size_list(a.type):
            out[c] = a.flatten().to_numpy(zero_copy_only=False).reshape(len(a), a.type.list_size)
        else:
            out[c] = a.to_numpy(zero_copy_only=False)
    order = np.argsort(out["frame_index"], kind="stable")
    return {k: v[order] for k, v in out.items()}, info


def _quats(R_flat: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    R = np.asarray(R_flat, dtype=np.float64).reshape(-1, 3, 3)
    return Rotation.from_matrix(R).as_quat(canonical=True)  # (x, y, z, w)


def _stamp(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _v3(v) -> dict:
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


def _q(q) -> dict:
    return {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}


def export_mcap(root: str | Path, episode: int, out_path: str | Path) -> dict[str, int]:
    """Write episode ``episode`` of the dataset at ``root`` to ``out_path`` (MCAP, zstd
    chunks, JSON messages); return the number of messages per topic."""
    root, out_path = Path(root), Path(out_path)
    d, info = _episode_rows(root, episode)
    fps = info["fps"]
    # vehicle states: every frame's state, then the final next state
    states = np.concatenate([d["observation.state"], d["next.observation.state"][-1:]])
    goal = d["observation.desired_goal"]
    t_us = np.round(d["timestamp"].astype(np.float64) * 1e6).astype(np.int64)
    t_final = int(round((int(d["frame_index"][-1]) + 1) / fps * 1e6))
    return write_flight_mcap(
        out_path,
        states,
        np.concatenate([goal, goal[-1:]]),
        d["action"],
        np.append(t_us, t_final) * 1000 + EPOCH_NS,
        episode_index=d["episode_index"],
        frame_index=d["frame_index"],
        reward=d["next.reward"],
        done=d["next.done"],
        success=d["next.success"],
    )


def write_flight_mcap(
    out_path: str | Path,
    states: np.ndarray,
    goals: np.ndarray,
    actions: np.ndarray,
    t_ns: np.ndarray,
    *,
    episode_index: np.ndarray,
    frame_index: np.ndarray,
    reward: np.ndarray,
    done: np.ndarray,
    success: np.ndarray,
) -> dict[str, int]:
    """Write one flight to ``out_path`` (MCAP, the topics of :data:`TOPICS`): ``states``
    (L + 1, 18) and the goals flown to ``goals`` (L + 1, 15) at the times ``t_ns`` (L + 1,),
    ``actions`` (L, 4) and the per-step ``episode_index``, ``frame_index``, ``reward``,
    ``done``, ``success`` (L,). A dataset episode (:func:`export_mcap`) and a policy's
    flight (``aerohrl eval --mcap-episode``) are written alike; returns the messages per topic."""
    from mcap.writer import CompressionType, Writer

    out_path = Path(out_path)
    states, goal = np.asarray(states, np.float64), np.asarray(goals, np.float64)
    L = len(actions)
    if states.shape != (L + 1, task.STATE_DIM) or goal.shape != (L + 1, task.GOAL_DIM) or len(t_ns) != L + 1:
        raise ValueError(f"a flight of {L} actions needs {L + 1} states, goals and times")
    q_vehicle = _quats(states[:, task.ROT])
    q_goal = _quats(goal[:, task.ROT])

    counts = {t: 0 for t in TOPICS}
    with atomic_path(out_path) as tmp:
        with open(tmp, "wb") as f:
            w = Writer(f, compression=CompressionType.ZSTD)
            w.start(profile="", library=LIBRARY)
            schema_ids = {
                name: w.register_schema(name=name, encoding="jsonschema", data=json.dumps(s, sort_keys=True).encode())
                for name, s in SCHEMAS.items()
            }
            channels = {
                topic: w.register_channel(topic=topic, message_encoding="json", schema_id=schema_ids[s])
                for topic, s in TOPICS.items()
            }

            def emit(topic: str, ns: int, msg: dict) -> None:
                data = json.dumps(msg, separators=(",", ":")).encode()
                w.add_message(channels[topic], log_time=ns, data=data, publish_time=ns, sequence=counts[topic])
                counts[topic] += 1

            for i in range(L + 1):
                ns = int(t_ns[i])
                ts = _stamp(ns)
                s, g = states[i], goal[i]
                emit(
                    "/tf",
                    ns,
                    {
                        "timestamp": ts,
                        "parent_frame_id": WORLD_FRAME,
                        "child_frame_id": VEHICLE_FRAME,
                        "translation": _v3(s[task.POS]),
                        "rotation": _q(q_vehicle[i]),
                    },
                )
                emit(
                    "/tf",
                    ns,
                    {
                        "timestamp": ts,
                        "parent_frame_id": WORLD_FRAME,
                        "child_frame_id": GOAL_FRAME,
                        "translation": _v3(g[task.POS]),
                        "rotation": _q(q_goal[i]),
                    },
                )
                emit(
                    "/vehicle/pose",
                    ns,
                    {
                        "timestamp": ts,
                        "frame_id": WORLD_FRAME,
                        "pose": {"position": _v3(s[task.POS]), "orientation": _q(q_vehicle[i])},
                    },
                )
                emit(
                    "/vehicle/velocity",
                    ns,
                    {
                        "timestamp": ts,
                        "frame_id": WORLD_FRAME,
                        "linear": _v3(s[task.VEL]),
                        "angular": _v3(s[task.RATE]),
                        "speed": float(np.linalg.norm(s[task.VEL])),
                    },
                )
                emit(
                    "/goal/pose",
                    ns,
                    {
                        "timestamp": ts,
                        "frame_id": WORLD_FRAME,
                        "pose": {"position": _v3(g[task.POS]), "orientation": _q(q_goal[i])},
                    },
                )
                emit(
                    "/goal/velocity",
                    ns,
                    {
                        "timestamp": ts,
                        "frame_id": WORLD_FRAME,
                        "linear": _v3(g[task.VEL]),
                        "speed": float(np.linalg.norm(g[task.VEL])),
                    },
                )
                if i < L:
                    a = actions[i]
                    emit("/action", ns, {"timestamp": ts, **{n: float(a[j]) for j, n in enumerate(task.ACTION_NAMES)}})
                    emit(
                        "/step",
                        ns,
                        {
                            "timestamp": ts,
                            "episode_index": int(episode_index[i]),
                            "frame_index": int(frame_index[i]),
                            "reward": float(reward[i]),
                            "done": bool(done[i]),
                            "success": bool(success[i]),
                        },
                    )
            w.finish()
    return counts


__all__ = ["export_mcap", "write_flight_mcap", "TOPICS", "SCHEMAS"]
