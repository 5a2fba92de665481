"""A run folder as one object: :class:`Run` owns its layout, its claim and lock, its
config, checkpoints, RNG states and metrics, for both training stacks.

An offline-RL run (``aerohrl train``, kind ``train``) holds::

    config.json              the resolved TrainConfig + the dataset's identity (absolute path, version)
    run.toml                 the same TrainConfig as TOML (`train --config RUN/run.toml` trains it again)
    checkpoints/step-NNNNNNNNN.pt          weights, optimiser states, step, RNG states, config,
                             dataset version/checksum/shapes (the last ``keep_checkpoints``)
    checkpoints/step-NNNNNNNNN.pt.sha256   its SHA-256 (``sha256sum -c`` format)
    .lock                    held (flock) by the process training the run
    metrics.jsonl            one JSON object per log interval / evaluation
    tb/                      TensorBoard events (when tensorboard is installed)
    learning_curve.png       written by ``aerohrl runs show``

An IPP run (``aerohrl ipp train``, kind ``ipp``) holds ``config.json`` (``train``,
``dims``, ``lattice``), one ``checkpoint.pt`` (+ ``.sha256``), ``model.pt``,
``best.pt``, ``.lock``, ``metrics.jsonl`` (one line per iteration) and
``learning_curve.png``.

Every file is written to a temporary name and renamed (:mod:`aerohrl.atomic`), so a
killed run (even ``kill -9``) loses nothing it had written; the temporaries a kill
leaves are deleted when the run starts again. Each checkpoint's SHA-256 is checked on
every load; one written before checkpoints had checksums loads with a warning. A resume
starts from the newest intact checkpoint (damaged newer ones are set aside as
``NAME.damaged``) and drops the metric lines logged after it.

A run folder belongs to one process: :meth:`Run.create` makes it with an exclusive
``mkdir`` (a taken name is an error), and training holds :meth:`Run.lock` (an
exclusive ``flock`` on ``RUN/.lock``, freed by the kernel when the process dies), so a
second trainer of the same run is refused with one line.

Only the standard library is imported here at module level: ``aerohrl.Run`` is this
class, and ``import aerohrl`` stays light.
"""

from __future__ import annotations

import fcntl
import json
import os
import random
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

from aerohrl import atomic
from aerohrl.atomic import CheckpointDamaged
from aerohrl.errors import UserError, warn

if TYPE_CHECKING:  # pragma: no cover
    import torch

    from aerohrl.algorithms.config import TrainConfig
    from aerohrl.algorithms.data import Dataset

CHECKPOINT_FORMAT = "aerohrl-checkpoint/1"
CKPT_DIR = "checkpoints"
CONFIG_NAME = "config.json"
METRICS_NAME = "metrics.jsonl"
LOCK_NAME = ".lock"


@dataclass(frozen=True)
class Layout:
    """Where a kind of run keeps its checkpoints and config, and what its checkpoints hold."""

    checkpoint: str  # relative path; ``{step}`` is filled in (a fixed name: one checkpoint)
    glob: str  # what matches every checkpoint of the run
    format: str  # the checkpoint's "format" entry
    toml: str | None  # the TOML twin of config.json, if this stack writes one
    weights_only: bool  # checkpoints hold tensors and plain containers only
    section: str  # the key of config.json holding the training config


LAYOUTS = {
    "train": Layout(f"{CKPT_DIR}/step-{{step:09d}}.pt", f"{CKPT_DIR}/step-*.pt", CHECKPOINT_FORMAT, "run.toml", False, "config"),
    "ipp": Layout("checkpoint.pt", "checkpoint.pt", "aerohrl-ipp-train-checkpoint", None, True, "train"),
}


# ----------------------------------------------------------------------------- files


def read_json(path: str | Path) -> dict:
    """A run's JSON file; a one-line UserError when it is missing or unreadable."""
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise UserError(f"{path} is missing") from None
    except json.JSONDecodeError as e:
        raise UserError(f"{path} is not a training config: {e}") from None
    except OSError as e:
        raise UserError(f"cannot read {path}: {e.strerror or e}") from None


def checkpoint_step(path: str | Path) -> int:
    """The training step in a checkpoint's name (``step-000001000.pt`` -> 1000)."""
    return int(Path(path).stem.split("-")[1])


_unverified_folders: set[Path] = set()


def _warn_unverified(folder: Path) -> None:
    """Once per folder: a run from before checkpoints had checksums has ten of them."""
    if folder not in _unverified_folders:
        _unverified_folders.add(folder)
        warn(f"the checkpoints in {folder} have no .sha256 files (written before checkpoints had checksums); loaded unverified")


def load_checkpoint(
    path: str | Path, map_location: Any = "cpu", *, format: str = CHECKPOINT_FORMAT, weights_only: bool = False
) -> dict:
    """A checkpoint file, its SHA-256 verified; CheckpointDamaged (one line naming the file)
    when it differs, is unreadable or is not a ``format`` checkpoint. One written before
    checkpoints had checksums loads with a warning."""
    path = Path(path)
    if not path.exists():
        raise UserError(f"no checkpoint at {path}")
    ck = atomic.torch_load(
        path, map_location=map_location, weights_only=weights_only, warn=lambda _: _warn_unverified(path.parent)
    )
    if not isinstance(ck, dict) or ck.get("format") != format:
        raise CheckpointDamaged(f"{path} is not an aerohrl checkpoint")
    return ck


def checkpoint_problem(path: str | Path) -> str | None:
    """Why the checkpoint at ``path`` cannot be trusted, or None. Without loading it: its
    SHA-256 against the sidecar, or for an old checkpoint without one, the CRC-32 of
    every member of its zip container (what torch.save writes)."""
    import zipfile

    try:
        if atomic.verify(path):
            return None
        with zipfile.ZipFile(path) as z:
            bad = z.testzip()
        return None if bad is None else f"{path} is damaged: zip member {bad} fails its CRC"
    except CheckpointDamaged as e:
        return str(e)
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        return f"{path} is damaged: {e}"


def read_metrics(run_dir: str | Path) -> list[dict]:
    """The records of ``RUN/metrics.jsonl`` in order (a line cut by a kill is skipped)."""
    path = Path(run_dir) / METRICS_NAME
    out = []
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                pass  # a line cut by a kill
    return out


# ----------------------------------------------------------------------------- config


# ----------------------------------------------------------------------------- the lock


class RunLock:
    """An exclusive lock on ``RUN/.lock`` while a process trains the run (released by the
    kernel when the process dies, even by kill -9). The file holds the owner's pid. A
    context manager; :meth:`release` frees it early."""

    def __init__(self, run_dir: str | Path):
        run_dir = Path(run_dir)
        self.path = run_dir / LOCK_NAME
        try:
            self.fd: int | None = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            raise atomic.write_error(self.path, e) from None
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pid = os.pread(self.fd, 32, 0).decode(errors="replace").strip() or "?"
            os.close(self.fd)
            raise UserError(f"run {run_dir} is being trained by another process (pid {pid}); wait for it to end") from None
        try:  # who holds it, for that message; the lock itself needs no disk space
            os.ftruncate(self.fd, 0)
            os.pwrite(self.fd, f"{os.getpid()}\n".encode(), 0)
        except OSError:
            pass

    def release(self) -> None:
        """Release the run's lock (close its file descriptor); a second call does nothing."""
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None

    def __enter__(self) -> "RunLock":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.release()


# ----------------------------------------------------------------------------- RNG


def rng_state(generators: Mapping[str, "torch.Generator"] | None = None, *, tensors: bool = False) -> dict:
    """The state of every random generator a run draws from: torch, NumPy, Python, CUDA
    when present, and each of ``generators`` under its name. ``tensors``: NumPy's state as
    a dict of tensors and numbers (a checkpoint loaded with ``weights_only=True``)."""
    import numpy as np
    import torch

    st: dict[str, Any] = {"torch": torch.get_rng_state()}
    for name, gen in (generators or {}).items():
        st[name] = gen.get_state()
    st["numpy"] = _np_state_tensors() if tensors else np.random.get_state()
    st["python"] = random.getstate()
    if torch.cuda.is_available():
        st["cuda"] = torch.cuda.get_rng_state_all()
    return st


def set_rng_state(st: Mapping[str, Any], generators: Mapping[str, "torch.Generator"] | None = None) -> None:
    """Restore the generators in :func:`rng_state`'s ``st`` (those it holds; ``generators``:
    the named ones, restored in place)."""
    import numpy as np
    import torch

    if "torch" in st:
        torch.set_rng_state(st["torch"])
    for name, gen in (generators or {}).items():
        gen.set_state(st[name])
    if "numpy" in st:
        n = st["numpy"]
        np.random.set_state(
            n
            if not isinstance(n, dict)
            else (n["name"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached"])
        )
    if "python" in st:
        random.setstate(_python_state(st["python"]))
    if "cuda" in st and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(st["cuda"])


def _np_state_tensors() -> dict:
    import numpy as np
    import torch

    state: Any = np.random.get_state()  # the legacy tuple
    name, keys, pos, has_gauss, cached = state
    return {
        "name": name,
        "keys": torch.from_numpy(keys.astype(np.int64)),
        "pos": int(pos),
        "has_gauss": int(has_gauss),
        "cached": float(cached),
    }


def _python_state(st: Any) -> tuple:
    version, internal, gauss = st  # lists after a weights_only load: random.setstate wants tuples
    return version, tuple(internal), gauss


def seed_everything(seed: int) -> "torch.Generator":
    """Seed torch, NumPy and Python with ``seed``; returns a torch generator seeded ``seed + 1``
    (the offline trainer's sampler draws from it)."""
    import numpy as np
    import torch

    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)
    random.seed(seed)
    return torch.Generator().manual_seed(seed + 1)


# ----------------------------------------------------------------------------- metrics


LOGGERS = ("tensorboard", "wandb", "none")


def check_logger(name: str) -> None:
    """One-line errors for an unknown ``--logger`` or a missing wandb (not a dependency)."""
    import importlib.util

    if name not in LOGGERS:
        raise UserError(f"unknown logger {name!r} (choose from {', '.join(LOGGERS)})")
    if name == "wandb" and importlib.util.find_spec("wandb") is None:
        raise UserError("--logger wandb needs the wandb package: pip install wandb (runs log offline; `wandb sync` uploads)")


def _after_newest_event_file(tb_dir: Path) -> None:
    """Wait until the clock's second is past the newest event file's in ``tb_dir``.

    TensorBoard reads a log directory's files in name order, and a file's name is
    ``events.out.tfevents.<second>.<host>.<pid>.<counter>``: two files opened in the same
    second by one process sort by the counter as text ("10" before "9"), which can put a
    resumed run's file, and its purge, before the file it purges."""
    stamps = [int(f.name.split(".")[3]) for f in tb_dir.glob("events.out.tfevents.*") if f.name.split(".")[3].isdigit()]
    if stamps:
        while int(time.time()) <= max(stamps):
            time.sleep(0.05)


class MetricsLog:
    """metrics.jsonl (append-only, flushed per line), plus TensorBoard events in ``RUN/tb``
    (``logger="tensorboard"``) or a wandb run in offline mode in ``RUN/wandb``
    (``logger="wandb"``, torchrl's WandbLogger; upload it later with
    ``wandb sync RUN/wandb/offline-run-*``).

    ``keep_until``: a resume: the lines whose ``key`` (``step``, or an IPP run's
    ``iteration``) is past the checkpoint's are dropped; None: a new run, an empty file.
    TensorBoard is written with torch's SummaryWriter directly rather than torchrl's
    TensorboardLogger (a thin wrapper of it) for ``purge_step``: on resume, the events
    logged after the checkpoint are dropped, as metrics.jsonl's lines are."""

    def __init__(self, run_dir: str | Path, keep_until: int | None, logger: str = "tensorboard", key: str = "step"):
        run_dir = Path(run_dir)
        self.path, self.key = run_dir / METRICS_NAME, key
        check_logger(logger)
        try:
            if keep_until is not None and self.path.exists():  # resume: drop what came after the checkpoint
                kept = [r for r in read_metrics(run_dir) if r.get(key, 0) <= keep_until]
                atomic.write_text(self.path, "".join(json.dumps(r) + "\n" for r in kept))
            elif keep_until is None and self.path.exists():
                self.path.unlink()
            self._f = open(self.path, "a")
        except OSError as e:
            raise atomic.write_error(self.path, e) from None
        self.tb = None
        self.wandb = None
        if logger == "tensorboard":
            from torch.utils.tensorboard import SummaryWriter  # tensorboard is a dependency

            purge = None if keep_until is None else keep_until + 1
            if purge is not None:
                _after_newest_event_file(run_dir / "tb")
            self.tb = SummaryWriter(str(run_dir / "tb"), purge_step=purge)
        elif logger == "wandb":
            from torchrl.record.loggers.wandb import WandbLogger

            os.environ.setdefault("WANDB_MODE", "offline")
            os.environ.setdefault("WANDB_SILENT", "true")
            self.wandb = WandbLogger(
                exp_name=run_dir.name, offline=True, save_dir=str(run_dir), project="aerohrl", id=run_dir.name, resume="allow"
            )

    def write(self, record: dict) -> None:
        """Append ``record`` to ``metrics.jsonl`` (flushed) and its numeric values to
        TensorBoard or W&B at ``record[key]``."""
        try:
            self._f.write(json.dumps(record) + "\n")
            self._f.flush()
        except OSError as e:
            raise atomic.write_error(self.path, e) from None
        if self.tb is None and self.wandb is None:
            return
        step = record.get(self.key, 0)
        scalars = {k: v for k, v in record.items() if k != self.key and isinstance(v, (int, float)) and not isinstance(v, bool)}
        for k, v in scalars.items():
            if self.tb is not None:
                self.tb.add_scalar(k, v, step)
            if self.wandb is not None:
                self.wandb.log_scalar(k, v, step=step)

    def close(self) -> None:
        """Close ``metrics.jsonl`` and the TensorBoard / W&B writers."""
        try:
            self._f.close()
        except OSError:
            pass  # a full disk: the error that stopped the run has been raised already
        if self.tb is not None:
            self.tb.close()
        if self.wandb is not None:
            self.wandb.experiment.finish()

    def __enter__(self) -> "MetricsLog":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


# ----------------------------------------------------------------------------- the dataset a run trained on


def dataset_identity(data: "Dataset") -> dict:
    """What a run records of its dataset: the absolute path (so that eval and resume work
    from any folder), the version (to find it again when it moved) and its checksum."""
    i = data.info
    path = str(Path(i["path"]).resolve()) if i.get("path") else None
    return {
        "path": path,
        "version": i.get("version"),
        "checksum": i.get("checksum"),
        "shapes": i.get("shapes"),
        "frames": i.get("frames"),
        "episodes": i.get("episodes"),
    }


def locate_dataset(identity: dict, run_dir: str | Path, override: str | Path | None = None) -> Path:
    """The folder of a run's dataset: ``override`` (``--dataset``), else the recorded path,
    else a folder ``datasets/*/<version>`` (under the current folder or the run's
    project, RUN/../../datasets) when the data moved. UserError saying ``--dataset``
    when none exists."""
    if override:
        return Path(override)
    recorded = identity.get("path")
    if recorded and Path(recorded).is_dir():
        return Path(recorded)
    version = identity.get("version")
    roots = dict.fromkeys([Path("datasets"), Path(run_dir).resolve().parent.parent / "datasets"])
    for root in roots if version else ():
        found = sorted(p for p in root.glob(f"*/{version}") if p.is_dir())
        if found:
            warn(f"the run's dataset {recorded} is gone; using {found[0]} (same version {version}; its checksum is checked)")
            return found[0]
    raise UserError(
        f"the run's dataset {recorded or '(none recorded)'} (version {version}) is missing and no "
        f"datasets/*/{version} was found; pass --dataset PATH"
    )


def check_same_dataset(expected: dict, data: "Dataset") -> None:
    """UserError (one line) when ``data``'s feature shapes or version differ from the run's
    recorded dataset identity."""
    got = dataset_identity(data)
    if got["shapes"] != expected.get("shapes"):
        raise UserError(f"dataset feature shapes {got['shapes']} differ from the run's {expected.get('shapes')}")
    if got["version"] != expected.get("version"):
        raise UserError(f"dataset version {got['version']!r} differs from the run's {expected.get('version')!r}")
    if got["checksum"] != expected.get("checksum"):
        raise UserError(f"dataset checksum differs from the run's (version {got['version']!r}): the data changed")


# ----------------------------------------------------------------------------- naming


def new_run_dir(cfg: "TrainConfig", runs_root: str | Path = "runs", name: str | None = None) -> Path:
    """The folder of a new run: ``--name``, or ``ALGO-PRESET-sSEED-TIMESTAMP-XXXXXX`` whose
    random suffix keeps runs started in the same second apart. Not created here:
    :meth:`Run.create` does that, exclusively."""
    if name is None:
        from aerohrl.cli_common import run_name

        name = run_name(cfg.algo, cfg.preset, seed=cfg.seed)  # the shape of every command's run names
    d = Path(runs_root) / name
    if (d / CONFIG_NAME).exists():
        raise UserError(f"run {d} exists; use --resume {d} to continue it")
    return d


# ----------------------------------------------------------------------------- the handle


class Run:
    """A run folder: :meth:`create` a new one or :meth:`open` an existing one, then read
    and write everything in it through this object.

    Attributes:
        path: the run folder.
        kind: ``train`` (offline RL, ``aerohrl train``) or ``ipp`` (``aerohrl ipp train``).
        step: the step of the newest checkpoint when the run was opened (an IPP run: its
            iteration count is in the checkpoint, 0 here).
    """

    def __init__(self, path: str | Path, kind: str = "train"):
        if kind not in LAYOUTS:
            raise ValueError(f"unknown run kind {kind!r} (choose from {', '.join(LAYOUTS)})")
        self.path = Path(path)
        self.kind = kind
        self.layout = LAYOUTS[kind]
        self.step = 0
        self._meta: dict | None = None
        self._config: Any = None

    # --- opening ------------------------------------------------------------------
    @classmethod
    def create(cls, path: str | Path, kind: str = "train") -> "Run":
        """Claim a new run folder with an exclusive mkdir: of two runs given one folder,
        the second gets a one-line UserError instead of writing into the first's."""
        path = Path(path)
        if not atomic.new_folder(path):
            if (path / CONFIG_NAME).exists():
                raise UserError(f"run {path} exists; use --resume {path} to continue it")
            raise UserError(
                f"run folder {path} is taken (another run is starting there, or it is a leftover); choose another --name"
            )
        return cls(path, kind)

    @classmethod
    def open(cls, path: "str | Path | Run", kind: str | None = None) -> "Run":
        """The existing run at ``path`` (its config.json read; ``kind`` detected from it
        unless given). One-line UserError when there is no run there."""
        if isinstance(path, Run):
            path = path.path
        path = Path(path)
        if not (path / CONFIG_NAME).is_file():
            raise UserError(f"no run at {path} (no {CONFIG_NAME})")
        meta = read_json(path / CONFIG_NAME)
        if not isinstance(meta, dict):
            raise UserError(f"{path / CONFIG_NAME} is not a training config")
        if kind is None:
            kind = "ipp" if "lattice" in meta and "train" in meta and "config" not in meta else "train"
        run = cls(path, kind)
        run._meta = meta
        ckpts = run.checkpoints()
        run.step = checkpoint_step(ckpts[-1]) if ckpts and kind == "train" else 0
        return run

    @property
    def name(self) -> str:
        """The folder's name."""
        return self.path.name

    @property
    def is_ipp(self) -> bool:
        """An ``aerohrl ipp train`` run."""
        return self.kind == "ipp"

    def __fspath__(self) -> str:
        return str(self.path)

    def __repr__(self) -> str:
        return f"Run({str(self.path)!r}, kind={self.kind!r}, step={self.step})"

    def lock(self) -> RunLock:
        """Hold the run's lock (a context manager, or ``release()`` it); UserError (one line)
        when another process holds it."""
        return RunLock(self.path)

    def remove_stale_temporaries(self) -> None:
        """Delete the temporaries a killed write left in the run and its checkpoint folder."""
        for d in (self.path, self.path / CKPT_DIR):
            atomic.remove_stale_temporaries(d)

    # --- config -------------------------------------------------------------------
    @property
    def meta(self) -> dict:
        """config.json as written (the config, the dataset's identity, provenance, resumes)."""
        if self._meta is None:
            self._meta = read_json(self.path / CONFIG_NAME)
        return self._meta

    @property
    def config(self) -> "TrainConfig":
        """The offline-RL :class:`~aerohrl.algorithms.config.TrainConfig` of config.json
        (an IPP run's is read by :func:`aerohrl.ipp.train.load_run_config`)."""
        if self._config is None:
            if self.is_ipp:
                raise UserError(f"{self.path} is an ipp train run: its config is read_config(aerohrl.ipp.train.TrainConfig)")
            from aerohrl.algorithms import config as C

            try:
                self._config = C.from_dict(self.meta["config"])
            except (KeyError, TypeError) as e:
                raise UserError(f"{self.path / CONFIG_NAME} is damaged: {e}") from None
        return self._config

    def read_config(self, cls: type, read: Any = None) -> Any:
        """The config section of config.json (``config``, an IPP run's ``train``) as the
        dataclass ``cls``, read by ``read(cls, mapping, where=..., check=False)`` (default
        :func:`aerohrl.config.from_mapping`; the IPP trainer's nested config passes
        :func:`aerohrl.config.from_nested`). Missing keys keep their defaults, so
        runs written before a setting existed stay readable; unknown keys and malformed
        values are a one-line UserError naming the file."""
        from aerohrl import config as K

        p = self.path / CONFIG_NAME
        try:
            return (read or K.from_mapping)(cls, self.meta[self.layout.section], where=str(p), check=False)
        except UserError as e:
            raise UserError(str(e) if str(e).startswith(str(p)) else f"{p}: {e}") from None
        except (ValueError, KeyError, TypeError, AttributeError) as e:
            raise UserError(f"{p}: not a training config ({type(e).__name__})") from None

    def write_config(self, meta: dict, toml: str | None = None) -> None:
        """Write config.json (atomically) and, where this kind of run has one, its TOML twin."""
        atomic.write_json(self.path / CONFIG_NAME, meta)
        if toml is not None and self.layout.toml:
            atomic.write_text(self.path / self.layout.toml, toml)
        self._meta, self._config = meta, None

    @property
    def dataset(self) -> Path | None:
        """The dataset folder the run trained on (as recorded; it may have moved since)."""
        p = (self.meta.get("dataset") or {}).get("path") or (self.meta.get(self.layout.section) or {}).get("dataset")
        return Path(p) if p else None

    def locate_dataset(self, override: str | Path | None = None) -> Path:
        """The folder of the run's dataset now (see :func:`locate_dataset`)."""
        identity = self.meta.get("dataset") or {"path": (self.meta.get(self.layout.section) or {}).get("dataset")}
        return locate_dataset(identity, self.path, override)

    # --- checkpoints --------------------------------------------------------------
    def checkpoint_path(self, step: int = 0) -> Path:
        """Where the checkpoint of ``step`` goes."""
        return self.path / self.layout.checkpoint.format(step=step)

    def checkpoints(self) -> list[Path]:
        """The run's checkpoints, oldest first."""
        return sorted(p for p in self.path.glob(self.layout.glob) if p.is_file())

    def save_checkpoint(self, obj: dict, step: int = 0, keep: int | None = None) -> Path:
        """Save ``obj`` (its ``format`` entry set to this kind's) as the checkpoint of
        ``step``, atomically with a SHA-256 sidecar; then delete all but the newest ``keep``.
        Returns the path."""
        path = self.checkpoint_path(step)
        atomic.torch_save(path, {"format": self.layout.format, **obj})
        if keep is not None:
            for old in self.checkpoints()[:-keep]:
                atomic.remove(old)
        return path

    def load_checkpoint(self, path: str | Path | None = None, map_location: Any = "cpu") -> dict:
        """The checkpoint at ``path`` (default: the newest), its SHA-256 verified
        (CheckpointDamaged, one line, otherwise; a checkpoint from before checksums loads
        with a warning)."""
        if path is None:
            ckpts = self.checkpoints()
            if not ckpts:
                raise UserError(f"run {self.path} has no checkpoints ({self.layout.glob})")
            path = ckpts[-1]
        return load_checkpoint(path, map_location, format=self.layout.format, weights_only=self.layout.weights_only)

    def newest_intact(self, map_location: Any = "cpu") -> tuple[Path, dict, list[tuple[Path, str]]]:
        """The newest checkpoint that loads and matches its SHA-256: (path, checkpoint, the
        damaged newer ones set aside as ``NAME.damaged`` with why). CheckpointDamaged
        (one line, with a hint) when none is intact."""
        damaged = []
        for path in reversed(self.checkpoints()):
            try:
                ck = self.load_checkpoint(path, map_location)
            except CheckpointDamaged as e:
                damaged.append((path, str(e)))
                continue
            aside = []
            for bad, why in damaged:  # kept, out of the way of eval and the next resume
                to = bad.with_name(bad.name + ".damaged")
                os.replace(bad, to)
                atomic.checksum_path(bad).unlink(missing_ok=True)
                aside.append((to, why))
            return path, ck, aside
        if not damaged:
            raise UserError(f"{self.path}: no {self.layout.glob} to resume from")
        if self.layout.glob == self.layout.checkpoint:  # one checkpoint, no older one to fall back to
            raise CheckpointDamaged(damaged[0][1])
        raise CheckpointDamaged(
            f"no intact checkpoint to resume from: {damaged[0][1]}"
            + (f" (and the {len(damaged) - 1} older ones)" if len(damaged) > 1 else "")
            + f"; delete {self.path / CKPT_DIR} to start the run over"
        )

    def set_aside(self) -> list[str]:
        """The names of the checkpoints an earlier resume set aside as damaged."""
        return sorted(p.name for p in self.checkpoint_path().parent.glob("*.damaged"))

    # --- metrics ------------------------------------------------------------------
    @property
    def metrics_path(self) -> Path:
        """``RUN/metrics.jsonl``."""
        return self.path / METRICS_NAME

    def metrics(self) -> list[dict]:
        """Every line of ``metrics.jsonl`` (a line cut by a kill is skipped)."""
        return read_metrics(self.path)

    def metrics_log(self, keep_until: int | None = None, logger: str = "tensorboard", key: str = "step") -> MetricsLog:
        """Open ``metrics.jsonl`` for appending (see :class:`MetricsLog`)."""
        return MetricsLog(self.path, keep_until, logger=logger, key=key)


__all__ = [
    "Run",
    "RunLock",
    "MetricsLog",
    "Layout",
    "LAYOUTS",
    "CHECKPOINT_FORMAT",
    "CKPT_DIR",
    "LOGGERS",
    "check_logger",
    "new_run_dir",
    "read_json",
    "read_metrics",
    "checkpoint_step",
    "load_checkpoint",
    "checkpoint_problem",
    "rng_state",
    "set_rng_state",
    "seed_everything",
    "dataset_identity",
    "locate_dataset",
    "check_same_dataset",
]
