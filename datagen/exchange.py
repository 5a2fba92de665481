"""Hand a dataset to other offline-RL toolkits: Minari, OGBench, and the Hugging Face Hub.

* :func:`export_minari` writes a `Minari <https://minari.farama.org>`_ dataset (arrow
  format: pyarrow only, no h5py) through Minari's own ``create_dataset_from_buffers``.
  Observations are the Gymnasium goal-env dicts of ``aerohrl/QuadrotorReach-v0``
  (``observation`` (18), ``achieved_goal`` (15), ``desired_goal`` (15)), T + 1 per
  episode; actions the flown CTBR command (T); rewards ``next.reward``. An expert
  flight goes on to its reference end after the goal is first reached, so
  ``terminations`` is True only at the last step of an episode that ends at its goal,
  ``truncations`` at the last step of one that does not. The env spec is the
  registered env with the dataset's vehicle, rate and goal ranges, so
  ``minari.load_dataset(id).recover_environment()`` gives our env drawing goals from
  the same rho_D. Needs ``minari`` (``pip install 'aerohrl[exchange]'``).
* :func:`export_ogbench` writes one ``.npz`` in OGBench's layout (``ogbench.utils.load_dataset``
  reads it): per episode its T + 1 states stacked (``observations`` float32 (N, 18)),
  ``actions`` float32 (N, 4) (the last one of each episode repeats the one before: OGBench
  marks that step invalid), ``terminals`` float32 (N,) 1 at each episode's last state.
  Beside them, ignored by OGBench's loader, ``desired_goals`` (N, 15) and
  ``episode_index`` (N,). No extra package needed.
* :func:`stage_push` prepares a folder for ``LeRobotDataset.push_to_hub`` that keeps our
  card, licence and metadata (see its docstring); :func:`push` uploads it.

Every export opens the dataset with :func:`aerohrl.datagen.dataset.open_dataset` (its
checksums verified), and writes atomically (a temporary name, renamed at the end).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from aerohrl import atomic, task
from aerohrl.errors import UserError

FORMATS = ("minari", "ogbench", "mcap")
ENV_ID = "aerohrl/QuadrotorReach-v0"


def _checked_columns(root: Path) -> tuple[dict[str, np.ndarray], dict]:
    from aerohrl.datagen.dataset import open_dataset

    ds = open_dataset(root)
    return ds.columns(), ds.manifest


def _episode_bounds(ep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    starts = np.flatnonzero(np.r_[True, ep[1:] != ep[:-1]])
    return starts, np.r_[starts[1:], len(ep)]


def env_kwargs(meta: dict) -> dict:
    """Keyword arguments of ``aerohrl/QuadrotorReach-v0`` that match a dataset's spec."""
    s = meta.get("spec") or {}
    kw = {"vehicle": s.get("vehicle", "hummingbird"), "fps": int(s.get("fps", 100)), "substeps": int(s.get("substeps", 5))}
    for k in ("pos_range", "vel_range", "acc_range"):
        if k in s:
            kw[k] = [float(x) for x in s[k]]
    return kw


# ----------------------------------------------------------------------------- Minari


def minari_id(meta: dict) -> str:
    """The default Minari id: ``aerohrl/<name>/<version>-v0`` (namespace/env/dataset-version)."""
    return f"aerohrl/{meta.get('name', 'quadrotor-reach')}/{meta['version']}-v0"


def export_minari(root: str | Path, dataset_id: str | None = None, out: str | Path | None = None) -> Path:
    """Write dataset ``root`` as the Minari dataset ``dataset_id`` and return its folder.

    ``out`` is the Minari datasets root (default: ``$MINARI_DATASETS_PATH``, else
    ``~/.minari/datasets``); the dataset goes to ``out/<dataset_id>/``. An existing id
    is an error (Minari never overwrites)."""
    try:
        import gymnasium as gym
        import minari
        from minari.data_collector import EpisodeBuffer
        from minari.dataset.minari_dataset import parse_dataset_id
    except ImportError as e:
        raise UserError(f"--format minari needs minari: pip install 'aerohrl[exchange]' ({e})") from None
    import aerohrl

    root = Path(root)
    cols, meta = _checked_columns(root)
    dataset_id = dataset_id or minari_id(meta)
    try:
        parse_dataset_id(dataset_id)
    except Exception as e:  # minari raises ValueError / its own errors on a malformed id
        raise UserError(f"bad Minari dataset id {dataset_id!r}: {e}") from None
    old = os.environ.get("MINARI_DATASETS_PATH")
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        os.environ["MINARI_DATASETS_PATH"] = str(Path(out).resolve())
    try:
        from minari.storage import get_dataset_path

        target = Path(get_dataset_path(dataset_id))
        if target.exists():
            raise UserError(f"Minari dataset {dataset_id} exists at {target}; choose another --dataset-id or delete it")
        spec = gym.spec(ENV_ID)  # registered by `import aerohrl` once gymnasium is imported (aerohrl/__init__.py)
        env_spec = gym.envs.registration.EnvSpec(
            id=spec.id, entry_point=spec.entry_point, kwargs=env_kwargs(meta), max_episode_steps=None
        )
        buffers = _minari_buffers(cols, EpisodeBuffer)
        s = meta.get("spec") or {}
        try:
            ds = minari.create_dataset_from_buffers(
                dataset_id,
                buffers,
                env=env_spec,
                eval_env=env_spec,
                algorithm_name="aerohrl.datagen expert (Lee/Mellinger geometric controller, "
                "minimum-time minimum-jerk references)",
                author="aerohrl",
                author_email="aerohrl@users.noreply.github.com",
                code_permalink="https://github.com/aerohrl/aerohrl",
                description=f"aerohrl {meta.get('name')} {meta['version']}: {meta['episodes']} expert quadrotor flights "
                f"({meta['frames']} steps, seed {meta.get('seed')}, {s.get('goals')} goals) from hover at the origin "
                "to goals [p, v, R]; CTBR actions; reward 1 when the goal-reached test holds "
                "(0.15 m, 0.35 m/s, 0.15 rad). Exported from the LeRobot v3.0 dataset by `datagen export`.",
                data_format="arrow",
                requirements=[f"aerohrl>={aerohrl.__version__}"],
            )
        except ValueError as e:
            raise UserError(f"Minari refused the dataset: {e}") from None
        return Path(ds.storage.data_path).parent
    finally:
        if out is not None:
            if old is None:
                os.environ.pop("MINARI_DATASETS_PATH", None)
            else:
                os.environ["MINARI_DATASETS_PATH"] = old


def _minari_buffers(cols: dict, EpisodeBuffer) -> list:
    s, ns = cols["observation.state"].astype(np.float64), cols["next.observation.state"].astype(np.float64)
    g = cols["observation.desired_goal"].astype(np.float64)
    a = cols["action"].astype(np.float64)
    r = cols["next.reward"].astype(np.float64).reshape(-1)
    succ = cols["next.success"].astype(bool).reshape(-1)
    starts, ends = _episode_bounds(np.asarray(cols["episode_index"]))
    out = []
    for i, (a0, b) in enumerate(zip(starts, ends)):
        states = np.concatenate([s[a0:b], ns[b - 1 : b]])  # T + 1
        T = b - a0
        term = np.zeros(T, bool)
        trunc = np.zeros(T, bool)
        term[-1] = succ[b - 1]
        trunc[-1] = not succ[b - 1]
        out.append(
            EpisodeBuffer(
                id=i,
                observations={
                    "observation": states,
                    "achieved_goal": task.achieved_goal(states),
                    "desired_goal": np.repeat(g[a0 : a0 + 1], T + 1, axis=0),
                },
                actions=a[a0:b],
                rewards=list(r[a0:b]),
                terminations=list(term),
                truncations=list(trunc),
                infos={},
            )
        )
    return out


# ----------------------------------------------------------------------------- OGBench


def export_ogbench(root: str | Path, out: str | Path) -> Path:
    """Write dataset ``root`` as an OGBench ``.npz`` at ``out`` (see the module docstring)."""
    root, out = Path(root), Path(out)
    if out.suffix != ".npz":
        raise UserError(f"the OGBench file must end in .npz (OGBench's loader reads name.npz), got {out}")
    cols, _ = _checked_columns(root)
    s, ns = cols["observation.state"], cols["next.observation.state"]
    a, g = cols["action"], cols["observation.desired_goal"]
    ep = np.asarray(cols["episode_index"])
    starts, ends = _episode_bounds(ep)
    E, F = len(starts), len(ep)
    N = F + E
    # frame f of episode e goes to row f + e; episode e's final state to row ends[e] + e
    rows = np.arange(F) + np.repeat(np.arange(E), ends - starts)
    last = ends - 1 + np.arange(E) + 1
    obs = np.empty((N, task.STATE_DIM), np.float32)
    obs[rows] = s
    obs[last] = ns[ends - 1]
    act = np.empty((N, task.ACTION_DIM), np.float32)
    act[rows] = a
    act[last] = a[ends - 1]  # not a real action: OGBench drops it (terminal state)
    term = np.zeros(N, np.float32)
    term[last] = 1.0
    goals = np.empty((N, task.GOAL_DIM), np.float32)
    goals[rows] = g
    goals[last] = g[ends - 1]
    epi = np.empty(N, np.int64)
    epi[rows] = ep
    epi[last] = ep[ends - 1]
    with atomic.atomic_path(out) as tmp:
        with open(tmp, "wb") as f:  # a file object: np.savez would append .npz to a name
            np.savez(f, observations=obs, actions=act, terminals=term, desired_goals=goals, episode_index=epi)
    return out


# ----------------------------------------------------------------------------- the Hub


def stage_push(root: str | Path, staging: str | Path, license_file: str | Path | None = None) -> Path:
    """Copy dataset ``root`` to ``staging`` as it will be uploaded and return the folder.

    lerobot 0.6's ``LeRobotDataset.push_to_hub`` uploads the folder, then always pushes
    a card of its own template over ``README.md`` (licence ``apache-2.0`` unless told)
    and knows nothing of our metadata. The staged folder is the dataset byte for byte
    (our card, whose front matter says ``license: mit``; ``meta/aerohrl.json`` with the
    spec and every checksum; ``meta/aerohrl_episodes.parquet``) plus the project's
    ``LICENSE``; :func:`push` uploads it with the same Hub calls as ``push_to_hub``
    except the card's."""
    from aerohrl.datagen.dataset import open_dataset

    root, staging = Path(root), Path(staging)
    open_dataset(root)
    if staging.exists() and (not staging.is_dir() or any(staging.iterdir())):
        raise UserError(f"staging folder {staging} exists and is not empty")
    lic = Path(license_file) if license_file else _project_license()
    if not lic.is_file():
        raise UserError(f"no licence file at {lic}")
    tmp = atomic.temp_path(staging)
    try:
        shutil.copytree(root, tmp)
        shutil.copyfile(lic, tmp / "LICENSE")
        if staging.exists():
            staging.rmdir()
        os.rename(tmp, staging)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return staging


def _project_license() -> Path:
    """The project's LICENSE: in the source tree, else the installed distribution's copy."""
    here = Path(__file__).resolve().parents[1] / "LICENSE"
    if here.is_file():
        return here
    import importlib.metadata

    try:
        for f in importlib.metadata.distribution("aerohrl").files or []:
            if f.name == "LICENSE":
                return Path(f.locate())
    except importlib.metadata.PackageNotFoundError:
        pass
    raise UserError("the project's LICENSE file was not found")


def push(staging: str | Path, repo_id: str, private: bool = False) -> str:  # pragma: no cover - needs the network
    """Upload a folder made by :func:`stage_push` to the Hub dataset repo ``repo_id``:
    the calls of lerobot's ``push_to_hub`` (create the repo, upload the folder, tag the
    revision with lerobot's ``CODEBASE_VERSION``, which its loader asks for) without
    the one that replaces the card."""
    try:
        from huggingface_hub import HfApi
        from lerobot.datasets.dataset_metadata import CODEBASE_VERSION
    except ImportError as e:
        raise UserError(f"datagen push needs lerobot: pip install 'aerohrl[lerobot]' ({e})") from None
    api = HfApi()
    api.create_repo(repo_id, repo_type="dataset", private=private, exist_ok=True)
    api.upload_folder(repo_id=repo_id, folder_path=str(staging), repo_type="dataset", ignore_patterns=["images/"])
    try:
        api.delete_tag(repo_id, tag=CODEBASE_VERSION, repo_type="dataset")
    except Exception:  # RevisionNotFoundError: no tag yet
        pass
    api.create_tag(repo_id, tag=CODEBASE_VERSION, repo_type="dataset")
    return f"https://huggingface.co/datasets/{repo_id}"


__all__ = ["FORMATS", "export_minari", "export_ogbench", "stage_push", "push", "minari_id", "env_kwargs"]
