"""The frozen maze tasks, the maze env (aerohrl/QuadrotorMaze-v0), `aerohrl eval --task maze`
with collisions, the planner over the free cells, and loading envs and datasets by name."""

import json
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch

import aerohrl
from aerohrl import task as T
from aerohrl.datagen.expert import GeometricController
from aerohrl.envs.maze import QuadrotorMazeVectorEnv, maze_episodes, task_goal, task_horizon
from aerohrl.errors import UserError
from aerohrl.worlds import corners, load_maze

warnings.filterwarnings("ignore", category=UserWarning)
TINY = dict(
    hidden=(16, 16),
    critic_hidden=(16, 16),
    batch_size=32,
    steps=20,
    log_every=10,
    checkpoint_every=20,
    eval_every=20,
    eval_episodes=2,
    eval_horizon=20,
)


# ----------------------------------------------------------------------------- tasks and env


def test_task_episodes_frozen_and_deterministic():
    m = load_maze("medium")
    a, b = maze_episodes(m, 50, seed=3), maze_episodes("medium", 50, seed=3)
    assert len(a) == 250 and np.array_equal(a.start_states, b.start_states) and np.array_equal(a.goals, b.goals)
    assert not np.array_equal(a.start_states, maze_episodes(m, 50, seed=4).start_states)
    one = maze_episodes(m, 50, seed=3, tasks=[2])  # a task's episodes do not depend on the others flown
    assert np.array_equal(one.start_states, a.start_states[50:100])
    which = a.meta["maze_task"]
    for k, (s, g) in enumerate(m.tasks, 1):
        sel = which == k
        d = a.start_states[sel, :3] - m.cell_center(np.array(s))
        assert (np.abs(d[:, :2]) <= 0.2).all() and np.allclose(d[:, 2], 0) and d[:, :2].std() > 0.05
        assert (np.abs(a.start_states[sel, 3:6]) <= 0.1).all()
        assert np.allclose(a.goals[sel], task_goal(m, k)) and np.allclose(a.goals[sel, :3], m.cell_center(np.array(g)))
        cells = len(m.shortest_path(s, g)) - 1
        assert (a.horizons[sel] == 100 * (2 * cells + 2)).all() == (task_horizon(m, k) == 100 * (2 * cells + 2))
    assert set(a.kind()) == {f"task{k}" for k in range(1, 6)}


def test_env_steps_and_a_wall_ends_the_episode_as_failure():
    aerohrl.envs.register()
    env = gym.make("aerohrl/QuadrotorMaze-v0", maze="medium", task=1)
    obs, _ = env.reset(seed=0)
    assert set(obs) == {"observation", "achieved_goal", "desired_goal"}
    assert np.allclose(obs["desired_goal"], task_goal(load_maze("medium"), 1))
    obs, r, term, trunc, info = env.step(np.array([9.81, 0.0, 0.0, 0.0]))
    assert not term and not trunc and not info["collision"] and r == 0.0
    for _ in range(400):  # roll towards +y (north) and push sideways until a wall or the floor is hit
        obs, r, term, trunc, info = env.step(np.array([12.0, -1.5, 0.0, 0.0]))
        if term or trunc:
            break
    assert term and not trunc and info["collision"] and not info["is_success"] and r == 0.0
    assert load_maze("medium").collides(obs["observation"][:3])


def test_vector_env_autoresets_to_the_task_start():
    env = QuadrotorMazeVectorEnv(3, maze="medium", task=2)
    obs, _ = env.reset(seed=1)
    start = load_maze("medium").cell_center(np.array(load_maze("medium").tasks[1][0]))
    assert np.abs(obs["observation"][:, :2] - start[:2]).max() <= 0.2
    crashed = np.zeros(3, bool)
    for _ in range(300):  # the first crash of each vehicle; the step after it, NEXT_STEP autoreset puts it back at the start
        obs, r, term, trunc, info = env.step(np.tile([20.0, 0.0, 3.0, 0.0], (3, 1)))
        assert (term == info["collision"]).all() and not trunc.any()
        newly = info["collision"] & ~crashed
        crashed |= newly
        if newly.any():
            obs, *_ = env.step(np.tile([9.81, 0.0, 0.0, 0.0], (3, 1)))
            assert np.abs(obs["observation"][newly, :2] - start[:2]).max() <= 0.2
        if crashed.all():
            break
    assert crashed.all()


def test_bad_maze_and_task_are_one_line_errors():
    with pytest.raises(UserError, match="unknown maze"):
        QuadrotorMazeVectorEnv(1, maze="tiny")
    with pytest.raises(UserError, match="1..5"):
        QuadrotorMazeVectorEnv(1, maze="medium", task=6)


def _min_jerk_legs(maze, starts, ks, accel=3.0):
    """Per episode: the corners of its task's shortest path (the first at its actual start)
    and rest-to-rest minimum-jerk durations with peak acceleration ``accel``."""
    plans = []
    for s0, k in zip(starts, ks):
        s, g = maze.tasks[k - 1]
        c = maze.cell_center(corners(maze.shortest_path(s, g)))
        c[0] = s0[:3]
        plans.append((c, np.sqrt(5.7735 * np.linalg.norm(np.diff(c, axis=0), axis=1) / accel)))
    return plans


def _reference(plan, t):
    c, dur = plan
    ends = np.cumsum(dur)
    if t >= ends[-1]:
        z = np.zeros(3)
        return c[-1], z, z, z
    i = int(np.searchsorted(ends, t))
    L, D = dur[i], c[i + 1] - c[i]
    u = (t - (ends[i] - L)) / L
    s = 10 * u**3 - 15 * u**4 + 6 * u**5
    ds = (30 * u**2 - 60 * u**3 + 30 * u**4) / L
    dds = (60 * u - 180 * u**2 + 120 * u**3) / L**2
    ddds = (60 - 360 * u + 360 * u**2) / L**3
    return c[i] + D * s, D * ds, D * dds, D * ddds


def test_scripted_controller_flies_every_medium_task_without_collision():
    """The geometric controller tracking minimum-jerk legs between the shortest path's
    corners (stopping at each) reaches every task's goal inside its horizon: the tasks
    are feasible and the success test fires in the maze env."""
    m = load_maze("medium")
    eps = maze_episodes(m, 1, seed=0)
    env = QuadrotorMazeVectorEnv(len(eps), maze=m, autoreset=False)
    obs, _ = env.reset(options={"start_states": eps.start_states, "goals": eps.goals, "horizons": eps.horizons})
    ctrl = GeometricController(env.sim.params)
    plans = _min_jerk_legs(m, eps.start_states, eps.meta["maze_task"])
    done = np.zeros(len(eps), bool)
    success = np.zeros(len(eps), bool)
    crash = np.zeros(len(eps), bool)
    for t in range(int(eps.horizons.max())):
        refs = [np.stack(x) for x in zip(*(_reference(p, t / env.fps) for p in plans))]
        obs, _, term, trunc, info = env.step(ctrl(obs["observation"], *refs))
        success |= info["is_success"] & ~done
        crash |= info["collision"] & ~done
        done |= term | trunc
        if done.all():
            break
    assert success.all() and not crash.any()


# ----------------------------------------------------------------------------- the closed loop and the planner


class FakeAlgo(torch.nn.Module):
    """act: a constant command; critics: exp(-|p_g - p|) for each of 3 critics."""

    def __init__(self, command=(9.81, 0.0, 0.0, 0.0)):
        super().__init__()
        self.w = torch.nn.Parameter(torch.zeros(()))
        self.command = torch.tensor(command)
        self.normalizer = type("N", (), {"act_center": torch.tensor([10.0, 0, 0, 0]), "act_half": torch.tensor([10.0, 5, 5, 5])})

    def act(self, s, g):
        return self.command.expand(len(s), 4) + 0 * self.w

    def critics(self, s, g, a):
        d = (g[:, :3] - s[:, :3]).norm(dim=1)
        return torch.exp(-torch.tensor([0.5, 1.0, 2.0])[:, None] * d[None]) + 0 * a.sum(1)


def test_rollout_in_a_maze_reports_collisions():
    from aerohrl.envs.rollout import rollout

    m = load_maze("medium")
    eps = maze_episodes(m, 2, seed=0)
    short = maze_episodes(m, 2, seed=0)
    short.horizons[:] = 100  # open-loop hover drifts with the start velocity: 1 s stays clear of the walls
    hover = rollout(FakeAlgo(), short, maze=m)
    assert not hover["collision"].any() and not hover["success"].any() and (hover["steps"] == 100).all()
    crash = rollout(FakeAlgo((14.0, 0.0, 2.0, 0.0)), eps, maze=m, record=True)  # pitch over and accelerate: into a wall
    assert crash["collision"].all() and not crash["success"].any() and not crash["near_success"].any()
    assert (crash["steps"] == crash["collision_step"]).all() and (crash["collision_step"] < eps.horizons).all()
    last = crash["positions"][np.arange(len(eps)), crash["steps"]]
    assert m.collides(last.astype(np.float64)).all()


def test_planner_candidates_are_the_free_cells():
    from aerohrl.planning.planner import Planner, candidates_from_maze

    m = load_maze("medium")
    c = candidates_from_maze(m)
    free = m.free_cells
    assert len(c) == len(free) and np.array_equal(c.frame, np.arange(len(free)))
    assert np.allclose(c.goals[:, :3].numpy(), m.cell_center(free))
    assert np.allclose(c.goals[:, 3:6].numpy(), 0) and np.allclose(c.goals[:, T.ROT].numpy(), np.eye(3).ravel())
    assert np.allclose(c.states[:, :15].numpy(), c.goals.numpy()) and np.allclose(c.states[:, 15:].numpy(), 0)
    eps = maze_episodes(m, 1, seed=0)
    plan = Planner(FakeAlgo(), c, n=1, alpha=0.0).plan(eps.start_states, eps.goals)
    picked = m.free_cells[plan.index[:, 0]]
    assert not m.is_wall(picked).any() and np.allclose(plan.goals[:, 0, :3], m.cell_center(picked))


def test_world_errors_are_one_line():
    from aerohrl.worlds import maze_from_dict, world_maze

    assert world_maze({}) is None and world_maze({"world": "free"}) is None
    assert world_maze({"world": "maze-large"}).name == "large"
    with pytest.raises(UserError, match="unknown maze 'tiny'"):
        world_maze({"world": "maze-tiny"})
    with pytest.raises(UserError, match="unknown world"):
        world_maze({"world": "forest"})
    d = load_maze("medium").to_dict()
    assert np.array_equal(world_maze({"world": "maze-medium", "maze": d}).walls, load_maze("medium").walls)
    d["tasks"][0]["start"] = [0, 0]  # a start inside a wall
    with pytest.raises(UserError, match=r"task cell \(0, 0\) is a wall"):
        maze_from_dict(d)


# ----------------------------------------------------------------------------- aerohrl eval --task maze / fast


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    from aerohrl.algorithms.config import make_config
    from aerohrl.algorithms.synthetic import straight_columns, write_synthetic_dataset
    from aerohrl.algorithms.trainer import start_run

    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("mazeeval")
    free = write_synthetic_dataset(root / "ds" / "free")
    maze = write_synthetic_dataset(
        root / "ds" / "maze", straight_columns(seed=2), version="synthetic-maze", spec={"world": "maze-medium"}
    )
    out = {"root": root, "free_ds": free, "maze_ds": maze}
    for name, ds in (("free", free), ("maze", maze)):
        start_run(make_config("cpu", algo="gcsl", dataset=str(ds), **TINY), root / "runs" / name, progress=False).train()
        out[name] = root / "runs" / name
    return out


def _err(capsys, argv):
    from aerohrl.cli import main

    try:
        code = main(argv)
    except SystemExit as e:
        code = e.code
    return code, capsys.readouterr().err.strip()


def test_eval_maze_writes_results_table_and_plot(runs, capsys):
    from aerohrl.cli import main

    run = runs["maze"]
    assert main(["eval", "--task", "maze", "--run", str(run), "--episodes", "5", "--checkpoints", "1", "--quiet"]) == 0
    assert "collision" in capsys.readouterr().out
    d = run / "eval" / "maze"
    s = json.loads((d / "summary.json").read_text())
    assert s["maze"]["name"] == "medium" and s["episodes"] == 5 and 0 <= s["collision_mean"] <= 1
    ck = s["checkpoints"][0]
    assert {f"success_task{k}" for k in range(1, 6)} <= set(ck) and {f"collision_task{k}" for k in range(1, 6)} <= set(ck)
    assert s["task_horizons"] == {str(k): task_horizon(load_maze("medium"), k) for k in range(1, 6)}
    table = (d / "tasks.md").read_text()
    assert table.count("\n| ") == 7 and "collision %" in table  # header, 5 tasks, all
    assert (d / "maze.png").stat().st_size > 0
    rows = (d / "episodes-step-000000020.csv").read_text().splitlines()
    assert "maze_task" in rows[0] and "collision_step" in rows[0] and len(rows) == 6


@pytest.mark.parametrize("planner", ["single", "graph"])
def test_eval_maze_with_planner_over_free_cells(runs, capsys, planner):
    from aerohrl.cli import main

    run = runs["maze"]
    argv = ["eval", "--task", "maze", "--planner", planner, "--run", str(run), "--episodes", "5", "--checkpoints", "1"]
    assert main([*argv, "--quiet"]) == 0
    d = run / "eval" / f"maze-{planner}"
    rows = (d / "episodes-step-000000020.csv").read_text().splitlines()
    head = rows[0].split(",")
    m = load_maze("medium")
    for line in rows[1:]:
        r = dict(zip(head, line.split(",")))
        cell = m.free_cells[int(r["wp0_frame"])]
        assert np.allclose([float(r["wp0_px"]), float(r["wp0_py"])], m.cell_center(cell)[:2])


def test_eval_maze_with_graph_over_the_datasets_states(runs, capsys):
    """--waypoints-from data plans over the dataset's achieved goals. The synthetic data's
    states lie outside the maze, so no clear leg joins them: every plan is the straight leg
    (waypoints = the task goal, frame -1). Planning through them is tests/test_graph_planner.py's."""
    from aerohrl.cli import main

    run = runs["maze"]
    argv = ["eval", "--task", "maze", "--planner", "graph", "--waypoints-from", "data", "--candidates", "64"]
    assert main([*argv, "--max-edge", "3", "--run", str(run), "--episodes", "5", "--checkpoints", "1", "--quiet"]) == 0
    d = run / "eval" / "maze-graph-data64-edge3"
    rows = (d / "episodes-step-000000020.csv").read_text().splitlines()
    head = rows[0].split(",")
    for line in rows[1:]:
        r = dict(zip(head, line.split(",")))
        assert int(r["wp0_frame"]) == -1
        assert [float(r[f"wp0_p{a}"]) for a in "xyz"] == [float(r[f"goal_p{a}"]) for a in "xyz"]
    code, err = _err(capsys, [*argv, "--legs", "corridor", "--run", str(run), "--episodes", "5", "--quiet"])
    assert code == 2 and len(err.splitlines()) == 1 and "no --legs corridor" in err


def test_eval_task_must_fit_the_world(runs, capsys):
    code, err = _err(capsys, ["eval", "--task", "maze", "--run", str(runs["free"]), "--episodes", "5", "--quiet"])
    assert code == 2 and len(err.splitlines()) == 1 and "maze dataset" in err
    code, err = _err(capsys, ["eval", "--task", "reach-desired", "--run", str(runs["maze"]), "--episodes", "2", "--quiet"])
    assert code == 2 and len(err.splitlines()) == 1 and "use --task maze" in err
    code, err = _err(capsys, ["eval", "--task", "maze", "--run", str(runs["maze"]), "--episodes", "7", "--quiet"])
    assert code == 2 and len(err.splitlines()) == 1 and "multiple of 5" in err


def test_eval_fast_on_free_space(runs, capsys):
    from aerohrl.cli import main
    from aerohrl.eval.tasks import fast

    eps = fast(None, 40, 0)
    speed = np.abs(eps.goals[:, 3:6])
    assert (speed >= 3.5).all() and (speed <= 7.0).all() and (eps.horizons == 1000).all()
    assert np.array_equal(eps.goals, fast(None, 40, 0).goals)
    run = runs["free"]
    assert main(["eval", "--task", "fast", "--run", str(run), "--episodes", "3", "--checkpoints", "1", "--quiet"]) == 0
    s = json.loads((run / "eval" / "fast" / "summary.json").read_text())
    assert s["task"] == "fast" and s["episodes"] == 3 and s["horizon"] == 1000


# ----------------------------------------------------------------------------- loading by name


def test_make_env_by_name():
    from aerohrl.envs.maze import QuadrotorMazeEnv
    from aerohrl.envs.reach import QuadrotorReachEnv, QuadrotorReachVectorEnv

    env = aerohrl.make_env("quadrotor-maze-large-stitch-v0", task=3)
    assert isinstance(env, QuadrotorMazeEnv) and env.maze.name == "large"
    obs, _ = env.reset(seed=0)
    assert np.allclose(obs["desired_goal"], task_goal(load_maze("large"), 3))
    venv = aerohrl.make_env("quadrotor-maze-medium-navigate-v0", 4, task=2)
    assert venv.num_envs == 4 and venv.task == 2 and venv.maze.name == "medium"
    assert isinstance(aerohrl.make_env("quadrotor-reach-v0"), QuadrotorReachEnv)
    assert isinstance(aerohrl.make_env(3), QuadrotorReachVectorEnv)  # a number is still the number of vehicles
    for bad, why in [
        ("quadrotor-maze-tiny-stitch-v0", "unknown maze 'tiny'"),
        ("quadrotor-maze-large-wander-v0", "unknown dataset family 'wander'"),
        ("quadrotor-maze-large-stitch-v1", "unknown version v1"),
        ("quadrotor-forest-v0", "unknown name"),
        ("antmaze-large-stitch-v0", "unknown name"),
    ]:
        with pytest.raises(UserError, match=why) as e:
            aerohrl.make_env(bad)
        assert "\n" not in str(e.value)
    with pytest.raises(UserError, match="1..5"):
        aerohrl.make_env("quadrotor-maze-large-stitch-v0", task=9)
    with pytest.raises(UserError, match="free space"):
        aerohrl.make_env("quadrotor-reach-v0", task=1)


def test_load_dataset_by_name(tmp_path):
    import os

    from aerohrl.algorithms.synthetic import straight_columns, write_synthetic_dataset

    name = "quadrotor-maze-medium-stitch-v0"
    with pytest.raises(UserError, match=r"datagen build --spec .*quadrotor-maze-medium-stitch\.toml") as e:
        aerohrl.load_dataset(name, root=tmp_path)
    assert "\n" not in str(e.value)
    folder = tmp_path / "quadrotor-maze-medium-stitch"
    old = write_synthetic_dataset(folder / "v-old", spec={"world": "maze-medium"})
    new = write_synthetic_dataset(
        folder / "v-new", straight_columns(seed=3), version="synthetic-3", spec={"world": "maze-medium"}
    )
    os.utime(old / "meta" / "aerohrl.json", ns=(1, 1))  # the older build
    cols = aerohrl.load_dataset(name, root=tmp_path)
    ref = aerohrl.load_dataset(new)
    assert np.array_equal(cols["observation.state"], ref["observation.state"])
    assert aerohrl.load_dataset(name, "torch", root=tmp_path).info["version"] == "synthetic-3"
    with pytest.raises(UserError, match="unknown dataset family"):
        aerohrl.load_dataset("quadrotor-maze-medium-sprint-v0", root=tmp_path)


def test_maze_env_passes_gymnasium_checks_and_seeds_its_starts():
    from gymnasium.utils.env_checker import check_env

    aerohrl.envs.register()
    check_env(gym.make("aerohrl/QuadrotorMaze-v0", maze="giant", task=5).unwrapped, skip_render_check=True)
    venv = gym.make_vec("aerohrl/QuadrotorMaze-v0", num_envs=4, vectorization_mode="vector_entry_point", maze="medium", task=1)
    a, _ = venv.reset(seed=7)
    b, _ = venv.reset(seed=7)
    assert a["observation"].shape == (4, 18) and np.array_equal(a["observation"], b["observation"])


def test_training_on_a_maze_dataset_evaluates_the_maze_tasks(runs, tmp_path):
    from aerohrl.algorithms.config import make_config
    from aerohrl.algorithms.trainer import start_run

    cfg = make_config("cpu", algo="gcsl", dataset=str(runs["maze_ds"]), **{**TINY, "eval_every": 10, "eval_episodes": 5})
    tr = start_run(cfg, tmp_path / "run", progress=False)
    tr.train()
    keys = set().union(*(json.loads(x) for x in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()))
    assert {"eval/maze/success", "eval/maze/collision"} <= keys and not any("reach_desired" in k for k in keys)
