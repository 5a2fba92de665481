"""The public API: the whole pipeline from Python, one call per step.

Each function is also reachable from the top-level package (``aerohrl.train`` is
:func:`aerohrl.api.train`); ``import aerohrl`` stays light (numpy-free) and imports the
heavy parts (torch, torchrl, lerobot) only when a function that needs them is called.

```python
import aerohrl

ds = aerohrl.build_dataset(goals=250)                        # -> datasets/quadrotor-reach/n250-s0-<hash>
run = aerohrl.train({"algo": "gcsl", "dataset": ds, "steps": 3000})
policy = aerohrl.load_policy(run)
summary = aerohrl.evaluate(run, "reach-desired", checkpoints=1)
env = aerohrl.make_env(dataset=ds)                           # the Gymnasium goal env

env = aerohrl.make_env("quadrotor-maze-large-stitch-v0", task=1)   # by name: the maze env of that maze, task 1
ds = aerohrl.load_dataset("quadrotor-maze-large-stitch-v0", root="datasets")   # its newest built dataset
```

Errors the caller can fix (a missing dataset, a bad config value, a damaged checkpoint)
raise :class:`aerohrl.errors.UserError` with a one-line message.

Which extra each function needs: :func:`build_dataset`, ``load_dataset(as_="numpy")`` and
:func:`make_env` run on the core install; :func:`train`, :func:`load_policy`,
:func:`evaluate` and ``load_dataset(as_="torch")`` need ``aerohrl[train]``;
``load_dataset(as_="lerobot")`` needs ``aerohrl[lerobot]``.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Mapping

from aerohrl.algorithms.run import Run  # the run folder handle (standard library only at import)
from aerohrl.errors import UserError

if TYPE_CHECKING:  # pragma: no cover - names for the annotations only
    import numpy as np
    import torch

    from aerohrl.algorithms.config import TrainConfig
    from aerohrl.datagen.spec import DatasetSpec

log = logging.getLogger("aerohrl")

PathLike = str | Path


# ----------------------------------------------------------------------------- datasets


def build_dataset(
    spec: "DatasetSpec | PathLike | None" = None,
    *,
    out: PathLike = "datasets",
    progress: bool = False,
    force: bool = False,
    **overrides: Any,
) -> Path:
    """Build the expert dataset of ``spec`` (or verify it, when that version exists) and return its folder.

    Args:
        spec: a :class:`~aerohrl.datagen.spec.DatasetSpec`, the path of a spec TOML file
            (``datasets/quadrotor-reach-dart.toml``), or None for the defaults (the
            thesis's 250 goals).
        out: root folder; the dataset goes to ``out/<name>/<version>/``.
        progress: show a progress bar while flying the expert.
        force: build even when the size estimate exceeds the free memory or disk.
        **overrides: spec fields that replace the spec's (``goals=1000``,
            ``action_noise=(1.0, 0.5)``, ``seed=3``); the same names as ``datagen build``'s flags.

    Returns:
        The dataset folder, ``out/<name>/n<goals>-s<seed>-<hash8>``. The same spec and
        seed always give the same version name and byte-identical files.
    """
    from dataclasses import asdict

    from aerohrl.datagen.build import build
    from aerohrl.datagen.spec import DatasetSpec, load_spec

    if isinstance(spec, DatasetSpec):
        try:
            spec = DatasetSpec(**{**asdict(spec), **{k: v for k, v in overrides.items() if v is not None}})
        except (TypeError, ValueError) as e:
            raise UserError(f"invalid spec: {e}") from None
    else:
        spec = load_spec(spec, **overrides)
    return build(spec, out, progress=progress, log=log.info, force=force).path


# ----------------------------------------------------------------------------- names

FAMILIES = ("navigate", "stitch", "explore")  # maze dataset families (datagen spec `family`)
_NAME = re.compile(r"^quadrotor-(?P<body>[a-z0-9][a-z0-9-]*?)-v(?P<version>[0-9]+)$")
_NAME_HELP = "quadrotor-reach[-<recipe>]-v0 or quadrotor-maze-<medium|large|giant>-<navigate|stitch|explore>-v0"


def parse_name(name: str) -> dict:
    """An environment/dataset name (the OGBench naming) -> its parts: ``dataset`` (the
    dataset's name, the folder under ``datasets/``), ``world`` (``free`` or
    ``maze-<maze>``), ``maze`` (None in free space) and ``family`` (None in free space).

    ``quadrotor-reach-v0`` (and ``quadrotor-reach-<recipe>-v0``) is free space;
    ``quadrotor-maze-<maze>-<family>-v0`` a maze (``medium`` | ``large`` | ``giant``) and a
    dataset family (``navigate`` | ``stitch`` | ``explore``). UserError (one line) for
    anything else."""
    from aerohrl.worlds.maze import MAZES

    m = _NAME.match(str(name))
    if not m:
        raise UserError(f"unknown name {name!r} (names look like {_NAME_HELP})")
    if m["version"] != "0":
        raise UserError(f"unknown version v{m['version']} of {name!r} (only v0 exists)")
    body = m["body"]
    if body == "reach" or body.startswith("reach-"):
        return {"name": str(name), "dataset": f"quadrotor-{body}", "world": "free", "maze": None, "family": None}
    parts = body.split("-")
    if parts[0] != "maze":
        raise UserError(f"unknown name {name!r} (names look like {_NAME_HELP})")
    if len(parts) != 3:
        raise UserError(f"maze names are quadrotor-maze-<maze>-<family>-v0, got {name!r}")
    _, maze, family = parts
    if maze not in MAZES:
        raise UserError(f"unknown maze {maze!r} in {name!r} (choose from {', '.join(MAZES)})")
    if family not in FAMILIES:
        raise UserError(f"unknown dataset family {family!r} in {name!r} (choose from {', '.join(FAMILIES)})")
    return {"name": str(name), "dataset": f"quadrotor-{body}", "world": f"maze-{maze}", "maze": maze, "family": family}


def dataset_path(name: str, root: PathLike = "datasets") -> Path:
    """The newest built version (by the time its manifest was written, the last file of a
    build) of the dataset ``name`` (``quadrotor-maze-large-stitch-v0``) under ``root``;
    UserError naming the ``datagen build`` command when none is built."""
    from aerohrl.datagen.manifest import MANIFEST_PATH

    parts = parse_name(name)
    folder = Path(root) / parts["dataset"]
    built = [p for p in folder.glob("*") if (p / MANIFEST_PATH).is_file()] if folder.is_dir() else []
    if not built:
        raise UserError(
            f"dataset {name} is not built under {folder}: build it with "
            f"`datagen build --spec {Path(root) / (parts['dataset'] + '.toml')}`"
        )
    return max(built, key=lambda p: ((p / MANIFEST_PATH).stat().st_mtime_ns, p.name))


def load_dataset(
    path: PathLike,
    as_: Literal["numpy", "torch", "lerobot"] = "numpy",
    *,
    validate: bool = True,
    root: PathLike = "datasets",
) -> Any:
    """Open a dataset folder written by :func:`build_dataset` (or ``datagen build``), or a
    built dataset by name (the OGBench ``make_env_and_datasets`` analogue).

    Args:
        path: the dataset folder (``datasets/quadrotor-reach/n250-s0-<hash>``), or a
            dataset name (``quadrotor-maze-large-stitch-v0``, ``quadrotor-reach-v0``;
            :func:`parse_name`): the newest built version under ``root/<name without
            -v0>/`` (UserError naming the ``datagen build --spec`` command when it is not
            built; unknown names are one-line errors too).
        as_: what to return:

            * ``"numpy"``: a dict of every column as NumPy arrays
              (``observation.state`` (F, 18), ``action`` (F, 4), ``observation.desired_goal``
              (F, 15), ``next.observation.state`` (F, 18), ``episode_index`` (F,), ...);
              no torch needed.
            * ``"torch"``: an :class:`aerohrl.algorithms.data.Dataset` (float32 tensors
              ``state``, ``action``, ``goal``, ``next_state``, episode bookkeeping): what
              the trainer learns from.
            * ``"lerobot"``: a ``lerobot.datasets.lerobot_dataset.LeRobotDataset`` (items
              are dicts of tensors), opened without probing a video decoder (our datasets
              hold no video).
        validate: check every file's SHA-256 against the manifest first (about a second
            per 2 M frames). ``as_="torch"`` always validates.

    Returns:
        The dataset in the requested form.

    Raises:
        aerohrl.datagen.dataset.DatasetError: (a :class:`~aerohrl.errors.UserError`) when
            the folder is missing, not an aerohrl dataset, damaged or of an unsupported
            format version: :func:`aerohrl.datagen.dataset.open_dataset` opens it.
    """
    from aerohrl.datagen.dataset import open_dataset

    if as_ not in ("numpy", "torch", "lerobot"):
        raise UserError(f"unknown as_={as_!r} (choose from numpy, torch, lerobot)")
    folder = Path(path)
    if isinstance(path, str) and not folder.exists() and _NAME.match(path):  # a name, not a folder
        folder = dataset_path(path, root)
    if as_ == "torch":
        from aerohrl.algorithms.data import load_dataset as load_torch

        return load_torch(folder)
    ds = open_dataset(folder, verify=validate)
    if as_ == "numpy":
        return ds.columns()
    return _lerobot_dataset(ds.path, ds.manifest)


def open_lerobot(root: PathLike) -> Any:
    """``LeRobotDataset`` over a local dataset folder, with the repo id of its card.

    ``video_backend="pyav"`` is passed so that lerobot does not probe torchcodec (it
    does so in every ``LeRobotDataset(...)`` whose backend is not given, video or not;
    without FFmpeg that probe logs a long traceback). Nothing is decoded with it: the
    datasets hold no video features."""
    from aerohrl.datagen.dataset import open_dataset

    ds = open_dataset(root, verify=False)
    return _lerobot_dataset(ds.path, ds.manifest)


def _lerobot_dataset(root: Path, manifest: dict) -> Any:
    try:
        from lerobot.datasets.lerobot_dataset import LeRobotDataset
    except ImportError as e:
        raise UserError(f"load_dataset(as_='lerobot') needs lerobot: pip install 'aerohrl[lerobot]' ({e})") from None
    repo_id = manifest.get("repo_id") or f"aerohrl/{root.parent.name}"
    return LeRobotDataset(repo_id, root=root, video_backend="pyav")


# ----------------------------------------------------------------------------- training


def train(
    config: "TrainConfig | Mapping[str, Any] | None" = None,
    *,
    out: PathLike = "runs",
    name: str | None = None,
    resume: "PathLike | Run | None" = None,
    progress: bool = False,
    **overrides: Any,
) -> Run:
    """Train a goal-conditioned policy to the end of its steps and return the run.

    Args:
        config: a :class:`~aerohrl.algorithms.config.TrainConfig`, or a mapping of its
            fields (``{"algo": "gcsl", "dataset": path, "steps": 3000}``; ``"preset"``
            picks ``cpu`` (default) or ``thesis`` first). ``dataset`` is required.
        out: the folder runs go to (``out/<name>``).
        name: the run's folder name (default ``<algo>-<preset>-s<seed>-<time>-<random>``).
            A taken name raises :class:`~aerohrl.errors.UserError`.
        resume: continue this existing run instead (from its newest intact checkpoint;
            ``overrides`` may raise ``steps``); ``config`` must then be None.
        progress: show a progress bar.
        **overrides: config fields that replace ``config``'s.

    Returns:
        The :class:`Run`, trained to ``config.steps``, with its checkpoints written.
    """
    from aerohrl.algorithms import config as C
    from aerohrl.algorithms.run import new_run_dir
    from aerohrl.algorithms.trainer import resume_run, start_run

    if resume is not None:
        if config is not None:
            raise UserError("train(resume=RUN) continues RUN with its own config; pass no config")
        tr = resume_run(Path(resume), progress=progress, overrides=overrides or None)
    else:
        if isinstance(config, C.TrainConfig):
            values = C.to_dict(config)
        else:
            values = dict(config or {})
        values.update(overrides)
        preset = values.pop("preset", None) or "cpu"
        if isinstance(values.get("dataset"), Path):
            values["dataset"] = str(values["dataset"])
        cfg = C.make_config(preset, **values)
        if not cfg.dataset:
            raise UserError("train() needs a dataset: train({'dataset': path, ...})")
        tr = start_run(cfg, new_run_dir(cfg, out, name), progress=progress)
    tr.train()
    return Run.open(tr.run_dir)


# ----------------------------------------------------------------------------- policies


class Policy:
    """A trained goal-conditioned policy: ``act(state, goal) -> action``.

    ``state`` is the vehicle state ``[p(3), v(3), R(9) row-major, w(3)]`` (18, world
    frame, absolute), ``goal`` the goal ``[p, v, R]`` (15, absolute); the action is CTBR
    ``[c, wx, wy, wz]`` (mass-normalised collective thrust in m/s², body rates in rad/s).
    Both take a leading batch dimension or none, as NumPy arrays (returns NumPy) or
    torch tensors (returns a tensor).

    Attributes:
        algo: the underlying :class:`aerohrl.algorithms.base.Algorithm` (critics, networks).
        step: the training step of the checkpoint.
        checkpoint: the checkpoint file it was loaded from.
    """

    def __init__(self, algo: Any, step: int, checkpoint: Path, device: str = "cpu") -> None:
        self.algo = algo
        self.step = step
        self.checkpoint = checkpoint
        self.device = device

    def act(self, state: "np.ndarray | torch.Tensor", goal: "np.ndarray | torch.Tensor") -> "np.ndarray | torch.Tensor":
        """The action for ``state`` (..., 18) towards ``goal`` (..., 15): (..., 4). A policy
        trained with ``observe_disturbance`` also takes ``state`` (..., 21) ``= [s, d_hat]``,
        ``d_hat`` its disturbance observer's estimate (18 wide: ``d_hat = 0``)."""
        import numpy as np
        import torch

        is_torch = isinstance(state, torch.Tensor)
        s = torch.as_tensor(np.asarray(state, np.float32) if not is_torch else state, dtype=torch.float32, device=self.device)
        g = torch.as_tensor(
            np.asarray(goal, np.float32) if not isinstance(goal, torch.Tensor) else goal, dtype=torch.float32, device=self.device
        )
        widths = sorted({18, self.algo.normalizer.state_width})
        if s.shape[-1] not in widths or g.shape[-1] != 15:
            raise UserError(
                f"act(state, goal) takes states (..., {' or '.join(map(str, widths))}) and goals (..., 15), "
                f"got {tuple(s.shape)} and {tuple(g.shape)}"
            )
        one = s.ndim == 1
        a = self.algo.act(s.reshape(-1, s.shape[-1]), g.reshape(-1, 15))
        a = a[0] if one else a.reshape(*s.shape[:-1], 4)
        return a if is_torch else a.double().cpu().numpy()

    __call__ = act

    def __repr__(self) -> str:
        return f"Policy({self.algo.__class__.__name__}, step {self.step}, {self.checkpoint})"


def load_policy(source: "Run | PathLike", *, step: int | None = None, device: str = "cpu") -> Policy:
    """Load a trained policy from a run (its newest checkpoint, or that of ``step``) or a checkpoint file.

    Args:
        source: a :class:`Run`, a run folder, or a ``checkpoints/step-N.pt`` file.
        step: with a run, the checkpoint of this step instead of the newest.
        device: ``cpu`` or ``cuda``.

    Returns:
        A :class:`Policy` in eval mode; the checkpoint's checksum has been verified.
    """
    from aerohrl.algorithms.base import load_policy as load_algo

    p = Path(source)
    run = None
    if p.is_dir():
        run = Run.open(p, kind="train")
        ckpts = run.checkpoints()
        if not ckpts:
            raise UserError(f"run {p} has no checkpoints ({run.layout.glob})")
        if step is not None:
            match = [c for c in ckpts if c == run.checkpoint_path(step)]
            if not match:
                raise UserError(f"run {p} has no checkpoint of step {step} (it keeps {', '.join(c.name for c in ckpts)})")
            p = match[0]
        else:
            p = ckpts[-1]
    elif not p.is_file():
        raise UserError(f"no run or checkpoint at {p}")
    algo, ck = load_algo(p, device, run)
    return Policy(algo, int(ck["step"]), p, device)


# ----------------------------------------------------------------------------- evaluation


def evaluate(run: "Run | PathLike", task: str = "reach-desired", **opts: Any) -> dict:
    """Fly a run's last checkpoints on one task in the simulator (``aerohrl eval``) and return the summary.

    Args:
        run: a :class:`Run` or a run folder.
        task: ``reach-desired``, ``reach-intermediate``, ``ood``, ``reach-novel`` or
            ``fast`` (free-space runs), ``maze`` (runs on a maze dataset: the five frozen
            tasks of its maze; the summary adds ``collision_mean`` / ``collision_std``).
        **opts: fields of :class:`aerohrl.eval.harness.EvalOptions`: ``checkpoints``
            (last K, default 10), ``episodes`` (default 250), ``planner`` (ood: ``none``,
            ``single`` = thesis Eq. 3.7, ``multi`` = Eq. 3.6), ``seed``, ``device``,
            ``progress`` (default False), ``out``, ...

    Returns:
        The summary written to ``RUN/eval/<task>[...]/summary.json``: ``success_mean``,
        ``success_std``, ``near_success_mean``, ``near_success_std`` (fractions, over the
        checkpoints), one entry per checkpoint under ``checkpoints`` (step, success,
        near_success, seconds), ``episodes``, ``horizon`` and the ``options`` used.
    """
    from dataclasses import fields

    from aerohrl.eval.harness import EvalOptions, evaluate_run

    names = {f.name for f in fields(EvalOptions)}
    unknown = sorted(set(opts) - names)
    if unknown:
        raise UserError(f"unknown evaluation option(s): {', '.join(unknown)} (see aerohrl.eval.harness.EvalOptions)")
    opts.setdefault("progress", False)
    return evaluate_run(Path(run), EvalOptions(task=task, **opts))


def make_env(
    name: str | int | None = None,
    num_envs: int | None = None,
    *,
    task: int | None = None,
    dataset: PathLike | None = None,
    normalize_actions: bool = False,
    **kwargs: Any,
) -> Any:
    """A Gymnasium goal env: the reach task (``aerohrl/QuadrotorReach-v0``), or by name the
    env of a dataset (``make_env("quadrotor-maze-large-stitch-v0", task=1)``: the maze env
    ``aerohrl/QuadrotorMaze-v0`` of that maze and task).

    Args:
        name: None (the reach env), or an env/dataset name (:func:`parse_name`):
            ``quadrotor-reach-v0`` -> the reach env; ``quadrotor-maze-<maze>-<family>-v0``
            -> the maze env of ``<maze>`` (the family selects nothing for the env but
            must be a known one). An integer here is ``num_envs`` (``make_env(4)``).
        num_envs: None for one vehicle (a ``gymnasium.Env``); N for a native
            ``gymnasium.vector.VectorEnv`` of N vehicles stepped in one batched call.
        task: a maze env's task, 1-5 (default 1); the frozen tasks of docs/spec.md.
        dataset: draw goals from this dataset's desired goals (default: fresh goals from
            the spec's distribution rho_D).
        normalize_actions: rescale the action space to [-1, 1]^4 (Gymnasium's
            ``RescaleAction`` wrapper, its vector twin for ``num_envs``), what most RL
            libraries expect; -1 is zero thrust, +1 full thrust and +20 rad/s.
        **kwargs: passed to the env (``vehicle``, ``horizon``, ``tolerance_scale``, ...).

    Returns:
        The environment; observations are dicts ``observation`` (18), ``achieved_goal``
        (15), ``desired_goal`` (15); reward 1 when the goal is reached.
    """
    from aerohrl.envs import reach

    if isinstance(name, int) and not isinstance(name, bool):  # make_env(4): the number of vehicles
        if num_envs is not None:
            raise UserError("make_env(N) takes the number of vehicles once")
        name, num_envs = None, name
    world = parse_name(str(name)) if name is not None else {"maze": None}
    if world["maze"] is not None:
        from aerohrl.envs import maze as maze_env

        if dataset is not None:
            raise UserError("a maze env draws its goals from its task; it takes no dataset=")
        kw = {"maze": world["maze"], "task": 1 if task is None else task, **kwargs}
        env = maze_env.QuadrotorMazeEnv(**kw) if num_envs is None else maze_env.QuadrotorMazeVectorEnv(num_envs, **kw)
        return reach.normalize_actions(env) if normalize_actions else env
    if task is not None:
        raise UserError(f"task= selects a maze task; {name or 'the reach env'} is free space")
    if dataset is not None:
        kwargs["dataset"] = str(dataset)
    if num_envs is None:
        env = reach.QuadrotorReachEnv(**kwargs)
    else:
        env = reach.QuadrotorReachVectorEnv(num_envs, **kwargs)
    return reach.normalize_actions(env) if normalize_actions else env


__all__ = [
    "build_dataset",
    "load_dataset",
    "parse_name",
    "dataset_path",
    "open_lerobot",
    "train",
    "Run",
    "load_policy",
    "Policy",
    "evaluate",
    "make_env",
]
