"""The maze dataset families (navigate, stitch, explore) and free-space explore: tiny builds
that validate and load, the maze expert's guarantees, stitch's coverage of the frozen tasks,
explore's terminal collisions, spec round-trips and one-line errors."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from aerohrl import task
from aerohrl.config import ConfigError
from aerohrl.datagen import maze_expert as mx
from aerohrl.datagen.build import build
from aerohrl.datagen.dataset import open_dataset
from aerohrl.datagen.manifest import read_manifest, validate
from aerohrl.datagen.spec import DatasetSpec, load_spec, version_name
from aerohrl.errors import UserError
from aerohrl.worlds import load_maze

TINY = {
    "navigate": DatasetSpec(name="m-nav", goals=4, world="maze-medium", family="navigate", action_noise=(1.0, 0.5, 0.5, 0.5)),
    "stitch": DatasetSpec(name="m-stitch", goals=12, world="maze-medium", family="stitch", action_noise=(1.0, 0.5, 0.5, 0.5)),
    "explore": DatasetSpec(name="m-explore", goals=6, world="maze-medium", family="explore", explore_duration=3.0),
    "walk": DatasetSpec(
        name="m-walk",
        goals=6,
        world="maze-medium",
        family="explore",
        explore_pilot="walk",
        explore_duration=4.0,
        action_noise=(3.0, 1.5, 1.5, 1.5),
    ),
    "free-explore": DatasetSpec(
        name="f-explore", goals=3, family="explore", explore_speed=7.0, explore_climb=2.0, explore_duration=2.0
    ),
}


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("maze")
    return {k: build(s, out, progress=False, log=lambda _: None) for k, s in TINY.items()}


@pytest.mark.parametrize("family", list(TINY))
def test_each_family_builds_validates_and_loads(built, family):
    from aerohrl.algorithms.data import load_dataset

    res = built[family]
    assert validate(res.path) == []
    ds = open_dataset(res.path)
    c = ds.columns()
    assert c["observation.state"].shape == (res.frames, task.STATE_DIM)
    assert c["observation.desired_goal"].shape == (res.frames, task.GOAL_DIM)
    assert ("action.expert" in c) == (family in ("navigate", "stitch"))
    assert ds.world == TINY[family].world == ds.spec.get("world", "free")
    assert (ds.maze is not None) == (TINY[family].maze is not None)
    data = load_dataset(res.path)
    assert len(data) == res.frames and data.info["spec"].get("world", "free") == TINY[family].world
    assert (data.action_expert is not None) == (family in ("navigate", "stitch"))
    # transitions chain within episodes; every episode starts in hover
    ep, s, ns = c["episode_index"], c["observation.state"], c["next.observation.state"]
    same = ep[1:] == ep[:-1]
    np.testing.assert_array_equal(ns[:-1][same], s[1:][same])
    first = s[c["frame_index"] == 0]
    np.testing.assert_allclose(first[:, 3:6], 0.0, atol=1e-7)
    np.testing.assert_allclose(first[:, task.ROT], np.broadcast_to(np.eye(3).reshape(9), (len(first), 9)), atol=1e-7)


@pytest.mark.parametrize("family", ["navigate", "stitch"])
def test_expert_flights_are_collision_free_and_reach_hover_at_the_goal(built, family):
    meta = read_manifest(built[family].path)
    maze = load_maze("medium")
    assert meta["collisions"] == 0 and meta["maze"] == maze.to_dict()
    assert meta["expert"]["success_rate"] == 1.0
    c = open_dataset(built[family].path).columns()
    assert not maze.collides(c["next.observation.state"][:, :3].astype(np.float64)).any()
    g = c["observation.desired_goal"]
    # the goal is hover at a cell centre: zero velocity, R = I, the centre at flight altitude
    np.testing.assert_allclose(g[:, 3:6], 0.0)
    np.testing.assert_allclose(g[:, 2], maze.altitude)
    np.testing.assert_allclose((g[:, :2] / maze.cell) % 1.0, 0.5, atol=1e-6)


def test_stitch_covers_no_frozen_task(built):
    meta = read_manifest(built["stitch"].path)
    assert meta["task_coverage"]["fraction"] == 0.0
    # the test itself: a flight through a task's start and then its goal counts
    maze = load_maze("medium")
    (s, g) = maze.tasks[0]
    path = maze.cell_center(maze.shortest_path(s, g))
    passes = mx.passes_tasks(maze, path, np.zeros(len(path), np.int64), 1)
    assert passes[0, 0] and not mx.passes_tasks(maze, path[::-1], np.zeros(len(path), np.int64), 1)[0, 0]


def test_explore_episodes_end_at_their_first_collision(built):
    maze = load_maze("medium")
    c = open_dataset(built["explore"].path).columns()
    meta = read_manifest(built["explore"].path)
    ep = c["episode_index"]
    hit = maze.collides(c["next.observation.state"][:, :3].astype(np.float64))
    last = np.r_[ep[1:] != ep[:-1], True]
    assert not hit[~last].any()  # no colliding step before an episode's last
    assert hit[last].sum() == meta["explore"]["episodes_ended_by_collision"] == meta["collisions"]
    full = int(round(TINY["explore"].explore_duration * TINY["explore"].fps))
    lengths = np.bincount(ep)
    assert ((lengths == full) | hit[last]).all()
    # the desired goal is each episode's last achieved goal
    np.testing.assert_array_equal(c["observation.desired_goal"][last], c["next.observation.state"][last][:, :15])


def test_free_space_explore_flies_fast_and_stays_upright(built):
    c = open_dataset(built["free-explore"].path).columns()
    s = c["observation.state"]
    assert np.linalg.norm(s[:, 3:5], axis=1).max() > 3.0
    assert np.degrees(np.arccos(s[:, 14].min())) < 60.0


def test_explore_stop_pauses_the_commands_and_keeps_earlier_bytes():
    args = dict(speed=1.5, climb=0.0, hold=(0.5, 1.0))
    plain = mx.explore_commands(np.random.default_rng(3), 64, 800, 0.01, **args)
    same = mx.explore_commands(np.random.default_rng(3), 64, 800, 0.01, stop=0.0, **args)
    np.testing.assert_array_equal(plain, same)  # stop 0: the commands of specs without the field
    paused = mx.explore_commands(np.random.default_rng(3), 64, 800, 0.01, stop=0.4, **args)
    zero = ~paused.any(axis=-1)
    assert 0.3 < zero.mean() < 0.5  # about 40 % of the time at a hover command
    moving = ~zero
    np.testing.assert_array_equal(paused[moving], plain[moving])  # the other segments are unchanged
    # the field enters a spec's identity only when it is set, and only for explore
    base = DatasetSpec(world="maze-large", family="explore")
    assert version_name(DatasetSpec(world="maze-large", family="explore", explore_stop=0.0)) == version_name(base)
    assert version_name(DatasetSpec(world="maze-large", family="explore", explore_stop=0.3)) != version_name(base)
    assert version_name(DatasetSpec(world="maze-large", explore_stop=0.3)) == version_name(DatasetSpec(world="maze-large"))


def test_reflect_off_walls_reverses_only_a_command_into_a_wall():
    """Next to a wall, a command toward it is reversed on that axis, one away from it or
    along the wall is not, and a reversed sign is not flipped back while it pulls away."""
    maze = load_maze("large")
    r, c = (int(x) for x in maze.free_cells[0])
    centre = maze.cell_center(np.array([[r, c]]))[0]
    p = np.repeat(centre[None], 4, 0)
    # a neighbour across a wall (the first free cell lies on the maze's border)
    dc = next(d for d in (1, -1) if maze.cell_index(np.array([r, c + d])) < 0)
    side = maze.cell_center(np.array([[r, c + dc]]))[0] - centre
    j = int(np.argmax(np.abs(side[:2])))
    toward = np.sign(side[j])
    p[:, j] += toward * 0.5  # half a metre from the centre, 0.5 m from the wall face
    v = np.zeros((4, 3))
    v[:, j] = toward * 1.5  # moving toward the wall: stopping distance 0.225 m at 5 m/s^2
    cmd = np.zeros((4, 3))
    cmd[0, j] = toward * 2.0  # into the wall
    cmd[1, j] = -toward * 2.0  # away from it
    cmd[2, 1 - j] = 1.0  # along it
    cmd[3, j] = toward * 2.0
    flip = np.ones((4, 2))
    flip[3, j] = -1.0  # already reversed: pulls away
    out = mx.reflect_off_walls(maze, p, v, cmd, flip, a_max=5.0, margin=0.3)
    assert out[0, j] == -1.0 and out[1, j] == 1.0 and (out[2] == 1.0).all() and out[3, j] == -1.0


def test_explore_wall_margin_keeps_flights_going_and_earlier_bytes(tmp_path):
    """With the margin most maze explore flights last their duration (the default ends a
    flight at its first collision); the field enters the version only when set, in a maze."""
    base = DatasetSpec(name="m-explore", goals=16, world="maze-medium", family="explore", explore_duration=6.0)
    bounce = DatasetSpec(
        name="m-explore", goals=16, world="maze-medium", family="explore", explore_duration=6.0, explore_wall_margin=0.3
    )
    assert version_name(DatasetSpec(world="maze-large", family="explore", explore_wall_margin=0.0)) == version_name(
        DatasetSpec(world="maze-large", family="explore")
    )
    assert version_name(bounce) != version_name(base)
    assert version_name(DatasetSpec(family="explore", explore_wall_margin=0.3)) == version_name(DatasetSpec(family="explore"))
    hits = []
    for spec in (base, bounce):
        res = build(spec, tmp_path, progress=False, log=lambda _: None)
        hits.append(read_manifest(res.path)["collisions"])
    assert hits[1] <= 2 and hits[1] < hits[0]


def test_random_walks_run_down_corridors_and_turn_back_only_at_dead_ends():
    maze = load_maze("large")
    start = maze.free_cells[np.random.default_rng(0).integers(0, len(maze.free_cells), 64)]
    w = mx.random_walks(maze, np.random.default_rng(1), start, 40)
    assert w.shape == (64, 41, 2)
    np.testing.assert_array_equal(w[:, 0], start)
    step = np.diff(w, axis=1)
    assert (np.abs(step).sum(axis=-1) == 1).all()  # one 4-neighbour move at a time
    assert not maze.is_wall(w).any()
    back = (step[:, 1:] == -step[:, :-1]).all(axis=-1)  # move k+1 undoes move k
    here = w[:, 1:-1]  # the cell it turned back at
    exits = (~maze.is_wall(here[..., None, :] + mx.STEPS)).sum(axis=-1)
    assert back.any() and (exits[back] == 1).all()  # only at dead ends
    again = mx.random_walks(maze, np.random.default_rng(1), start, 40)
    np.testing.assert_array_equal(w, again)  # a function of the generator's seed


def test_walk_pauses_hover_at_a_legs_end_for_the_drawn_time():
    maze = load_maze("large")
    start = maze.free_cells[:6]
    legs = mx.legs_along(maze, list(mx.random_walks(maze, np.random.default_rng(2), start, 12)))
    T, coeffs = mx.leg_references(legs.a, legs.b, a_max=5.0, solver="closed-form", degree=5, tol=0.02)
    ep, T2, c2 = mx.with_pauses(np.random.default_rng(3), legs, T, coeffs, 0.5, (0.5, 1.5))
    pauses = len(T2) - len(T)
    assert 0 < pauses < len(T) and (np.diff(ep) >= 0).all()  # episodes stay consecutive
    moving = np.isin(T2, T)
    np.testing.assert_array_equal(T2[moving], T)  # the legs keep their order
    held = T2[~moving]
    assert ((held >= 0.5) & (held <= 1.5)).all()
    ref = mx.PiecewiseReference(ep, T2, c2, len(start))
    # during each pause the reference is at rest at the end of the leg before it
    starts = ref.start[ref.T > 0]
    still = ~np.isin(ref.T[ref.T > 0], T)
    rows = np.repeat(np.arange(len(start)), (ref.T > 0).sum(axis=1))
    for row, t0, dur in zip(rows[still], starts[still], ref.T[ref.T > 0][still]):
        out = mx.PiecewiseReference(ep, T2, c2, len(start))(np.full(len(start), t0 + dur / 2))
        np.testing.assert_allclose(out[1][row], 0.0, atol=1e-12)
        before = mx.PiecewiseReference(ep, T2, c2, len(start))(np.full(len(start), t0 - 1e-9))
        np.testing.assert_allclose(out[0][row], before[0][row], atol=1e-6)


def test_walk_pilot_flies_the_expert_legs_records_what_was_flown_and_keeps_earlier_bytes(built, tmp_path):
    """The walk pilot: no expert label, a flight ends at its first collision or lasts its
    duration, the legs run along corridor centre lines (no noise: no collision), and the
    field enters a spec's identity only when it is walk."""
    velocity = DatasetSpec(world="maze-large", family="explore")
    assert version_name(DatasetSpec(world="maze-large", family="explore", explore_pilot="velocity")) == version_name(velocity)
    d = DatasetSpec(world="maze-large", family="explore", explore_pilot="walk", action_noise=(3.0, 1.5)).to_dict()
    assert d["explore_pilot"] == "walk" and d["action_noise"] == [3.0, 1.5, 1.5, 1.5]
    assert not {"explore_speed", "explore_hold", "explore_stop", "explore_wall_margin"} & set(d)
    res = built["walk"]
    meta = read_manifest(res.path)
    assert meta["explore"]["legs_per_episode"]["min"] >= 1 and "task_coverage" in meta
    c = open_dataset(res.path).columns()
    ep = c["episode_index"]
    maze = load_maze("medium")
    hit = maze.collides(c["next.observation.state"][:, :3].astype(np.float64))
    last = np.r_[ep[1:] != ep[:-1], True]
    assert not hit[~last].any() and hit[last].sum() == meta["collisions"]
    assert ((np.bincount(ep) == 400) | hit[last]).all()
    speed = np.linalg.norm(c["observation.state"][:, 3:6], axis=1)
    assert speed.max() > 1.0  # it flies the maze, not a hover
    assert "explore (pilot walk)" in (res.path / "README.md").read_text()
    clean = DatasetSpec(
        name="m-walk0", goals=8, world="maze-medium", family="explore", explore_pilot="walk", explore_duration=6.0
    )
    res0 = build(clean, tmp_path, progress=False, log=lambda _: None)
    m0 = read_manifest(res0.path)
    assert m0["collisions"] == 0 and m0["frames"] == 8 * 600


def test_same_spec_same_bytes(built, tmp_path):
    res = build(TINY["stitch"], tmp_path, progress=False, log=lambda _: None)
    assert read_manifest(res.path)["checksums"] == read_manifest(built["stitch"].path)["checksums"]


def test_spec_round_trips_through_toml_and_free_space_names_hold(tmp_path):
    from aerohrl.config import to_toml

    spec = TINY["stitch"]
    p = tmp_path / "s.toml"
    p.write_text(to_toml(spec))
    assert load_spec(p) == spec and version_name(load_spec(p)) == version_name(spec)
    assert load_spec("datasets/quadrotor-maze-large-stitch.toml").name == "quadrotor-maze-large-stitch"
    # free-space specs keep their version names (and so their bytes' identity)
    assert version_name(DatasetSpec()) == "n250-s0-dbb240c0"
    assert version_name(load_spec(None, goals=25000, action_noise=[1.0, 0.5])) == "n25000-s0-81b96355"
    assert "world" not in DatasetSpec().to_dict() and "hop_cells" not in DatasetSpec().to_dict()
    # a family's sub-settings enter the identity only where they apply
    assert version_name(DatasetSpec(world="maze-large", hop_cells=(2, 3))) == version_name(DatasetSpec(world="maze-large"))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"world": "maze-tiny"}, "world must be one of"),
        ({"family": "wander"}, "family must be one of"),
        ({"family": "stitch"}, "stitch needs a maze world"),
        ({"world": "maze-medium", "continuations": 5}, "--continuations is a free-space reach recipe"),
        ({"world": "maze-medium", "expert": "replan"}, "--expert is a free-space reach recipe"),
        ({"world": "maze-large", "family": "stitch", "hop_cells": (4, 2)}, "hop_cells is inverted"),
        ({"family": "explore", "action_noise": (1.0, 0.5)}, "--action-noise is a free-space reach recipe"),
        ({"family": "explore", "explore_pilot": "walk"}, "walk is a maze explore recipe"),
        ({"world": "maze-large", "explore_pilot": "walk"}, "walk is a maze explore recipe"),
        ({"world": "maze-large", "family": "explore", "explore_pilot": "drift"}, "explore_pilot must be one of"),
    ],
)
def test_bad_inputs_are_one_line_errors(kwargs, message):
    with pytest.raises((UserError, ConfigError), match=message) as e:
        DatasetSpec(**kwargs)
    assert "\n" not in str(e.value)


def test_cli_refuses_an_unknown_world_in_one_line():
    r = subprocess.run(
        [sys.executable, "-m", "aerohrl.datagen.cli", "build", "--world", "maze-tiny"], capture_output=True, text=True
    )
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) <= 2 and "maze-tiny" in r.stderr


def test_maze_legs_run_along_corridor_centre_lines():
    maze = load_maze("large")
    rng = np.random.default_rng(3)
    s, g = mx.sample_pairs(maze, rng, 20, min_path=0.5)
    d = maze.distances()[maze.cell_index(s), maze.cell_index(g)]
    assert (d >= np.ceil(0.5 * maze.distances().max())).all()
    legs = mx.plan_legs(maze, s, g)
    T, coeffs = mx.leg_references(legs.a, legs.b, a_max=5.0, solver="closed-form", degree=5, tol=0.02)
    ref = mx.PiecewiseReference(legs.ep, T, coeffs, len(s))
    for t in np.linspace(0.0, ref.duration.max() + 1.0, 400):
        p = ref(t)[0]
        assert not maze.collides(p).any()
    end = ref(ref.duration.max() + 1.0)
    np.testing.assert_allclose(end[0], maze.cell_center(g), atol=1e-9)
    for x in end[1:]:
        np.testing.assert_allclose(x, 0.0, atol=1e-9)
    sh, gh = mx.sample_pairs(maze, rng, 50, hops=(1, 4))
    hop = maze.distances()[maze.cell_index(sh), maze.cell_index(gh)]
    assert ((hop >= 1) & (hop <= 4)).all()


def test_cli_builds_validates_describes_and_exports_a_maze_dataset(tmp_path):
    def run(*args):
        r = subprocess.run([sys.executable, "-m", "aerohrl.datagen.cli", *args], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        return r.stdout

    out = run("build", "--quiet", "--out", str(tmp_path), "--name", "mz", "--goals", "3", "--world", "maze-medium")
    path = out.strip().splitlines()[-1]
    assert run("validate", path).strip().endswith("OK")
    assert "world        maze-medium, family navigate" in run("info", path)
    run("export", path, "--format", "ogbench", "--out", str(tmp_path / "mz.npz"))
    assert (tmp_path / "mz.npz").is_file()
