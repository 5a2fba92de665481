"""The training loop: sample -> relabel -> update, with checkpoints, logging and resume.

A run folder ``runs/<run>/`` holds::

    config.json              the resolved TrainConfig + the dataset's identity (absolute path, version)
    run.toml                 the same TrainConfig as TOML (`train --config RUN/run.toml` trains it again)
    checkpoints/step-NNNNNNNNN.pt   weights, optimiser states, step, RNG states, config,
                             dataset version/checksum/shapes (last ``keep_checkpoints``)
    checkpoints/step-NNNNNNNNN.pt.sha256   its SHA-256 (``sha256sum -c`` format)
    .lock                    held (flock) by the process training the run
    metrics.jsonl            one JSON object per log interval / evaluation
    tb/                      TensorBoard events (when tensorboard is installed)
    learning_curve.png       written by ``aerohrl runs show``

Every file is written to a temporary name and renamed (:mod:`aerohrl.atomic`), so a
killed run (even ``kill -9``) loses nothing it had written, and the temporaries a kill
leaves are deleted when the run starts again; a full disk is a one-line error. Each
checkpoint has a ``step-N.pt.sha256`` beside it, checked on every load (resume,
``aerohrl eval``, ``runs show``). ``--resume`` restarts from the newest intact
checkpoint (a damaged newer one is set aside as ``step-N.pt.damaged``), drops metrics
logged after it and, because every random draw (sampling, relabelling, TD3 noise,
CQL's sampled actions) comes from RNGs saved in the checkpoint, ends with the same
weights as an uninterrupted run; the checkpoint also holds the partial sums of the
metric line in progress, so the first line after a resume is the uninterrupted one.

A run folder belongs to one process: a new run creates it with an exclusive ``mkdir``
(a taken name is an error; default names end in a random suffix), and training holds
an exclusive lock on ``RUN/.lock`` (a second ``--resume`` of a running run is refused).
"""

from __future__ import annotations

import dataclasses
import fcntl
import json
import math
import os
import random
import shutil
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from aerohrl.algorithms import config as C
from aerohrl.algorithms.base import Algorithm, build_algorithm
from aerohrl.algorithms.data import Dataset, GoalBatchSampler, fit_normalizer, load_dataset
from aerohrl.algorithms.networks import Normalizer
from aerohrl import atomic
from aerohrl.atomic import CheckpointDamaged
from aerohrl.errors import UserError, warn
from aerohrl.hardware import resolve_amp

CHECKPOINT_FORMAT = "aerohrl-checkpoint/1"
CKPT_DIR = "checkpoints"


class TrainingDiverged(UserError):
    """A loss became NaN/inf: the run stops, its last good checkpoint is kept."""

    exit_code = 3


# ----------------------------------------------------------------------------- files


def checkpoint_paths(run_dir: str | Path) -> list[Path]:
    """Checkpoints of a run, oldest first."""
    d = Path(run_dir) / CKPT_DIR
    return sorted(d.glob("step-*.pt")) if d.is_dir() else []


def checkpoint_step(path: str | Path) -> int:
    """The training step in a checkpoint's name (``step-000001000.pt`` -> 1000)."""
    return int(Path(path).stem.split("-")[1])


def read_json(path: Path) -> dict:
    """A run's JSON file; a one-line UserError when it is missing or unreadable."""
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise UserError(f"{path} is missing") from None
    except (OSError, json.JSONDecodeError) as e:
        raise UserError(f"cannot read {path}: {e}") from None


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict:
    """A checkpoint, its SHA-256 verified; CheckpointDamaged (one line naming the file)
    when it differs, is unreadable or is no aerohrl checkpoint. One written before
    checkpoints had checksums loads with a warning."""
    if not Path(path).exists():
        raise UserError(f"no checkpoint at {path}")
    ck = atomic.torch_load(path, map_location=map_location, warn=lambda _: _warn_unverified(Path(path).parent))
    if not isinstance(ck, dict) or ck.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointDamaged(f"{path} is not an aerohrl checkpoint")
    return ck


_unverified_folders: set[Path] = set()


def _warn_unverified(folder: Path) -> None:
    """Once per folder: a run from before checkpoints had checksums has ten of them."""
    if folder not in _unverified_folders:
        _unverified_folders.add(folder)
        warn(f"the checkpoints in {folder} have no .sha256 files (written before checkpoints had checksums); loaded unverified")


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
    path = Path(run_dir) / "metrics.jsonl"
    out = []
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                pass  # a line cut by a kill
    return out


# ----------------------------------------------------------------------------- identity


def dataset_identity(data: Dataset) -> dict:
    """What a run records of its dataset: the absolute path (so that eval and resume work
    from any folder), the version (to find it again when it moved) and its checksum."""
    i = data.info
    path = str(Path(i["path"]).resolve()) if i.get("path") else None
    return {"path": path, "version": i.get("version"), "checksum": i.get("checksum"),
            "shapes": i.get("shapes"), "frames": i.get("frames"), "episodes": i.get("episodes")}


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
    raise UserError(f"the run's dataset {recorded or '(none recorded)'} (version {version}) is missing and no "
                    f"datasets/*/{version} was found; pass --dataset PATH")


def check_same_dataset(expected: dict, data: Dataset) -> None:
    """UserError (one line) when ``data``'s feature shapes or version differ from the run's
    recorded dataset identity."""
    got = dataset_identity(data)
    if got["shapes"] != expected.get("shapes"):
        raise UserError(f"dataset feature shapes {got['shapes']} differ from the run's {expected.get('shapes')}")
    if got["version"] != expected.get("version"):
        raise UserError(f"dataset version {got['version']!r} differs from the run's {expected.get('version')!r}")
    if got["checksum"] != expected.get("checksum"):
        raise UserError(f"dataset checksum differs from the run's (version {got['version']!r}): the data changed")


def new_run_dir(cfg: C.TrainConfig, runs_root: str | Path = "runs", name: str | None = None) -> Path:
    """The folder of a new run: ``--name``, or ``ALGO-PRESET-sSEED-TIMESTAMP-XXXXXX`` whose
    random suffix keeps runs started in the same second apart. Not created here:
    :func:`claim_run_dir` does that, exclusively."""
    if name is None:
        from aerohrl.cli_common import run_name

        name = run_name(cfg.algo, cfg.preset, seed=cfg.seed)  # the shape of every command's run names
    d = Path(runs_root) / name
    if (d / "config.json").exists():
        raise UserError(f"run {d} exists; use --resume {d} to continue it")
    return d


def claim_run_dir(run_dir: Path) -> None:
    """Create ``run_dir`` with an exclusive mkdir: of two runs given one folder, the
    second gets a one-line error instead of writing into the first's."""
    if not atomic.new_folder(run_dir):
        if (run_dir / "config.json").exists():
            raise UserError(f"run {run_dir} exists; use --resume {run_dir} to continue it")
        raise UserError(f"run folder {run_dir} is taken (another run is starting there, or it is a leftover); "
                        "choose another --name")


class RunLock:
    """An exclusive lock on ``RUN/.lock`` while a process trains the run (released by the
    kernel when the process dies, even by kill -9). The file holds the owner's pid."""

    def __init__(self, run_dir: Path):
        self.path = run_dir / ".lock"
        try:
            self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
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
        """Release the run's lock (close its file descriptor)."""
        os.close(self.fd)


# ----------------------------------------------------------------------------- RNG


def rng_state(gen: torch.Generator) -> dict:
    """The state of every random generator a run draws from (torch, the sampler's ``gen``,
    NumPy, Python, CUDA when present), for a checkpoint."""
    st = {"torch": torch.get_rng_state(), "sampler": gen.get_state(), "numpy": np.random.get_state(), "python": random.getstate()}
    if torch.cuda.is_available():
        st["cuda"] = torch.cuda.get_rng_state_all()
    return st


def set_rng_state(st: dict, gen: torch.Generator) -> None:
    """Restore :func:`rng_state`'s generators (``gen``: the sampler's)."""
    torch.set_rng_state(st["torch"])
    gen.set_state(st["sampler"])
    np.random.set_state(st["numpy"])
    random.setstate(st["python"])
    if "cuda" in st and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(st["cuda"])


def seed_everything(seed: int) -> torch.Generator:
    """Seed torch, NumPy and Python with ``seed``; returns the sampler's generator (seeded
    ``seed + 1``)."""
    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)
    random.seed(seed)
    return torch.Generator().manual_seed(seed + 1)


def resolve_device(name: str) -> torch.device:
    """``name`` as a torch device; UserError for an unknown one or CUDA without a GPU."""
    try:
        dev = torch.device(name)
    except RuntimeError:
        raise UserError(f"unknown device {name!r}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise UserError("--device cuda asked for, but no CUDA device is available")
    return dev


# ----------------------------------------------------------------------------- logging


LOGGERS = ("tensorboard", "wandb", "none")


def check_logger(name: str) -> None:
    """One-line errors for an unknown ``--logger`` or a missing wandb (not a dependency)."""
    import importlib.util

    if name not in LOGGERS:
        raise UserError(f"unknown logger {name!r} (choose from {', '.join(LOGGERS)})")
    if name == "wandb" and importlib.util.find_spec("wandb") is None:
        raise UserError("--logger wandb needs the wandb package: pip install wandb (runs log offline; `wandb sync` uploads)")


class MetricsLog:
    """metrics.jsonl, plus TensorBoard events in ``RUN/tb`` (default) or a wandb run in
    offline mode in ``RUN/wandb`` (``logger="wandb"``, torchrl's WandbLogger; upload it
    later with ``wandb sync RUN/wandb/offline-run-*``).

    TensorBoard is written with torch's SummaryWriter directly rather than torchrl's
    TensorboardLogger (a thin wrapper of it) for ``purge_step``: on resume, the events
    logged after the checkpoint are dropped, as metrics.jsonl's lines are."""

    def __init__(self, run_dir: Path, keep_until_step: int | None, logger: str = "tensorboard"):
        self.path = run_dir / "metrics.jsonl"
        try:
            if keep_until_step is not None and self.path.exists():  # resume: drop what came after the checkpoint
                kept = [r for r in read_metrics(run_dir) if r.get("step", 0) <= keep_until_step]
                atomic.write_text(self.path, "".join(json.dumps(r) + "\n" for r in kept))
            elif keep_until_step is None and self.path.exists():
                self.path.unlink()
            self._f = open(self.path, "a")
        except OSError as e:
            raise atomic.write_error(self.path, e) from None
        self.tb = None
        self.wandb = None
        check_logger(logger)
        if logger == "tensorboard":
            from torch.utils.tensorboard import SummaryWriter  # tensorboard is a dependency

            # on resume, TensorBoard drops the events logged after the checkpoint (purge_step)
            purge = None if keep_until_step is None else keep_until_step + 1
            self.tb = SummaryWriter(str(run_dir / "tb"), purge_step=purge)
        elif logger == "wandb":
            from torchrl.record.loggers.wandb import WandbLogger

            os.environ.setdefault("WANDB_MODE", "offline")
            os.environ.setdefault("WANDB_SILENT", "true")
            self.wandb = WandbLogger(exp_name=run_dir.name, offline=True, save_dir=str(run_dir), project="aerohrl",
                                     id=run_dir.name, resume="allow")

    def write(self, record: dict) -> None:
        """Append ``record`` to ``metrics.jsonl`` (flushed) and its numeric values to
        TensorBoard or W&B at ``record["step"]``."""
        try:
            self._f.write(json.dumps(record) + "\n")
            self._f.flush()
        except OSError as e:
            raise atomic.write_error(self.path, e) from None
        step = record.get("step", 0)
        scalars = {k: v for k, v in record.items() if k != "step" and isinstance(v, (int, float)) and not isinstance(v, bool)}
        if self.tb is not None:
            for k, v in scalars.items():
                self.tb.add_scalar(k, v, step)
        if self.wandb is not None:
            for k, v in scalars.items():
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


class ProgressLines:
    """The progress of a run without a terminal (a cluster job's log): one line on stderr
    every ``every_s`` seconds and, when ``every_steps`` > 0, every that many steps:
    step, steps/s (since the previous line), the mean losses since it, and the ETA."""

    def __init__(self, name: str, step: int, total: int, every_s: float = 60.0, every_steps: int = 0, out=None):
        import sys

        self.name, self.total, self.every_s, self.every_steps = name, total, every_s, every_steps
        self.out = out or sys.stderr
        self._reset(step)

    def _reset(self, step: int) -> None:
        self.last_step, self.last_t, self.sums, self.count = step, time.monotonic(), {}, 0

    def update(self, step: int, metrics: dict[str, float]) -> None:
        """Add one step's losses to the running means; print a line when one is due (every
        ``every_s`` seconds, every ``every_steps`` steps, and at the last step)."""
        for k, v in metrics.items():
            self.sums[k] = self.sums.get(k, 0.0) + v
        self.count += 1
        now = time.monotonic()
        due = (self.every_s > 0 and now - self.last_t >= self.every_s) or (self.every_steps > 0 and step % self.every_steps == 0)
        if due or step == self.total:
            self.line(step, now)

    def line(self, step: int, now: float | None = None) -> str:
        """Print (and return) the progress line at ``step``, then start new means."""
        now = time.monotonic() if now is None else now
        rate = (step - self.last_step) / max(now - self.last_t, 1e-9)
        eta = (self.total - step) / rate if rate > 0 else float("inf")
        losses = "  ".join(f"{k} {v / self.count:.4g}" for k, v in self.sums.items()) if self.count else ""
        text = (f"{self.name}: step {step:,}/{self.total:,} ({100 * step / max(self.total, 1):.1f}%)  {rate:.1f} steps/s"
                + (f"  {losses}" if losses else "") + f"  ETA {_duration(eta)}")
        print(text, file=self.out, flush=True)
        self._reset(step)
        return text


def _duration(s: float) -> str:
    if not math.isfinite(s):
        return "?"
    s = int(round(s))
    h, m = divmod(s, 3600)
    m, sec = divmod(m, 60)
    return f"{h}h{m:02d}m" if h else f"{m}m{sec:02d}s"


# ----------------------------------------------------------------------------- trainer


Evaluator = Callable[[Algorithm, int], dict]


class Trainer:
    """Owns a run: the algorithm, the batch sampler, the checkpoints and the logs."""

    def __init__(self, run_dir, cfg: C.TrainConfig, data: Dataset, *, progress: bool = True,
                 evaluators: dict[str, Evaluator] | None = None, lock: "RunLock | None" = None,
                 logger: str = "tensorboard", progress_every_s: float = 0.0, progress_every_steps: int = 0):
        self.run_dir = Path(run_dir)
        self.cfg = cfg
        self.data = data
        self.progress = progress
        self.logger = logger
        # without the bar: a progress line every progress_every_s seconds / progress_every_steps steps (0: never)
        self.progress_every = (progress_every_s, progress_every_steps)
        self.device = resolve_device(cfg.device)
        if cfg.amp not in ("none", "bf16"):  # start_run resolves "auto"; a Trainer trains in one precision
            cfg = self.cfg = dataclasses.replace(cfg, amp=resolve_amp(cfg.amp, self.device)[0])
        self.precision = f"{cfg.amp} (the run's own)"
        self._lock = lock or RunLock(self.run_dir)  # held until train() returns
        self.evaluators = evaluators
        self.step = 0
        self.set_aside: list[tuple[Path, str]] = []  # damaged checkpoints skipped on resume, and why
        # what the metric line in progress has summed so far (restored on resume)
        self._acc = {"sums": {}, "count": 0, "seconds": 0.0}
        self._acc_restored = True
        self._t0 = time.perf_counter()
        for d in (self.run_dir, self.run_dir / CKPT_DIR):  # temporaries of a killed write
            atomic.remove_stale_temporaries(d)
        ckpts = checkpoint_paths(self.run_dir)
        if ckpts:
            self._resume(ckpts)
        else:
            self._fresh()
        self.sampler = GoalBatchSampler(data, self.algo.normalizer, cfg.batch_size, cfg.relabel_prob, self.generator, device=self.device,
                                        future=C.relabel_future(cfg), mc_gamma=cfg.gamma if cfg.mc_lower_bound else None,
                                        augment=cfg.augment, critic_random_goal_prob=cfg.critic_random_goal_prob,
                                        bc_target=cfg.bc_target)
        if ckpts:
            set_rng_state(self._pending_rng, self.generator)

    # --- construction -------------------------------------------------------------
    def _fresh(self):
        cfg = self.cfg
        self.generator = seed_everything(cfg.seed)
        norm = fit_normalizer(self.data, cfg.relabel_prob, seed=cfg.seed, future=C.relabel_future(cfg), bc_target=cfg.bc_target)
        self.algo = build_algorithm(cfg, norm).to(self.device)
        self.dataset = dataset_identity(self.data)
        from aerohrl.algorithms.provenance import provenance

        atomic.write_json(self.run_dir / "config.json", {"config": C.to_dict(cfg), "dataset": self.dataset,
                                                         "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                                                         "logger": self.logger, "provenance": provenance(cfg.device)})
        atomic.write_text(self.run_dir / C.TOML_NAME, C.to_toml(cfg))  # the same config, for `train --config`
        self.resumed_from = None

    def _newest_intact(self, ckpts: list[Path]) -> tuple[Path, dict]:
        """The newest checkpoint that loads and matches its SHA-256; the damaged ones after
        it are renamed ``*.damaged`` (kept, out of the way of eval and the next resume)."""
        damaged = []
        for path in reversed(ckpts):
            try:
                ck = load_checkpoint(path, map_location=self.device)
            except CheckpointDamaged as e:
                damaged.append((path, str(e)))
                continue
            for bad, why in damaged:
                aside = bad.with_name(bad.name + ".damaged")
                os.replace(bad, aside)
                atomic.checksum_path(bad).unlink(missing_ok=True)
                self.set_aside.append((aside, why))
            return path, ck
        raise CheckpointDamaged(f"no intact checkpoint to resume from: {damaged[0][1]}"
                                + (f" (and the {len(damaged) - 1} older ones)" if len(damaged) > 1 else "")
                                + f"; delete {self.run_dir / CKPT_DIR} to start the run over")

    def _resume(self, ckpts: list[Path]):
        path, ck = self._newest_intact(ckpts)
        check_same_dataset(ck["dataset"], self.data)
        self.dataset = ck["dataset"]
        self.generator = torch.Generator()
        self.algo = build_algorithm(self.cfg, Normalizer()).to(self.device)
        try:
            self.algo.load_state_dict(ck["model"])
            for name, opt in self.algo.optimizers().items():
                opt.load_state_dict(ck["optimizers"][name])
        except (RuntimeError, KeyError, ValueError) as e:
            raise UserError(f"checkpoint {path} does not match the {self.cfg.algo} model of this config: {e}") from None
        self.algo.load_extra_state(ck.get("extra", {}))
        self.step = int(ck["step"])
        self._pending_rng = ck["rng"]
        if "metrics_acc" in ck:
            self._acc = ck["metrics_acc"]
        else:  # a checkpoint from before the partial sums were saved: the next line covers fewer steps
            self._acc_restored = self.step % self.cfg.log_every == 0
        self.resumed_from = path

    def checkpoint(self) -> Path:
        """Save weights, optimisers, RNG states and metric sums as
        ``RUN/checkpoints/step-N.pt`` (atomic, with a SHA-256 sidecar), keep the newest
        ``keep_checkpoints``; returns the path."""
        path = self.run_dir / CKPT_DIR / f"step-{self.step:09d}.pt"
        atomic.torch_save(path, {
            "format": CHECKPOINT_FORMAT,
            "step": self.step,
            "algo": self.cfg.algo,
            "config": C.to_dict(self.cfg),
            "dataset": self.dataset,
            "model": self.algo.state_dict(),
            "optimizers": {k: o.state_dict() for k, o in self.algo.optimizers().items()},
            "extra": self.algo.extra_state(),
            "rng": rng_state(self.generator),
            "metrics_acc": {**self._acc, "seconds": self._acc["seconds"] + time.perf_counter() - self._t0},
            "time": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        })
        for old in checkpoint_paths(self.run_dir)[: -self.cfg.keep_checkpoints]:
            atomic.remove(old)
        return path

    # --- the loop -----------------------------------------------------------------
    def _default_evaluators(self) -> dict[str, Evaluator]:
        if self.cfg.eval_every <= 0:
            return {}
        from aerohrl.algorithms.closed_loop import make_reach_desired_evaluator

        return {"reach_desired": make_reach_desired_evaluator(self.data, self.cfg)}

    def evaluate(self) -> dict:
        """Run every evaluator on the current policy; ``{"eval/NAME/METRIC": value}``."""
        evals = self._default_evaluators() if self.evaluators is None else self.evaluators
        out = {}
        for name, fn in evals.items():
            for k, v in fn(self.algo, self.step).items():
                out[f"eval/{name}/{k}"] = v
        return out

    def _metrics_line(self) -> dict:
        """The line for the steps summed since the last one (their mean losses, the step
        rate); marked partial when a resume lost the sums of its first steps."""
        acc = self._acc
        acc["seconds"] += time.perf_counter() - self._t0
        rec = {"step": self.step, **{k: v / acc["count"] for k, v in acc["sums"].items()},
               "steps_per_s": acc["count"] / max(acc["seconds"], 1e-9)}
        if not self._acc_restored:
            rec["partial"] = True  # averages acc["count"] steps, fewer than an uninterrupted run's line
            self._acc_restored = True
        self._acc = {"sums": {}, "count": 0, "seconds": 0.0}
        self._t0 = time.perf_counter()
        return rec

    def train(self, until: int | None = None) -> int:
        """Train up to ``cfg.steps`` (or ``until``); returns the step reached."""
        from tqdm import tqdm

        cfg = self.cfg
        end = cfg.steps if until is None else min(until, cfg.steps)
        if self._lock is None:  # a second train() call of this Trainer
            self._lock = RunLock(self.run_dir)
        try:
            log = MetricsLog(self.run_dir, keep_until_step=self.step if self.resumed_from else None, logger=self.logger)
        except BaseException:
            self.release()
            raise
        if self.evaluators is None:
            self.evaluators = self._default_evaluators()
        bar = tqdm(total=cfg.steps, initial=self.step, disable=not self.progress, desc=f"{cfg.algo}", unit="step", dynamic_ncols=True)
        lines = (ProgressLines(f"train {cfg.algo} {self.run_dir.name}", self.step, cfg.steps, *self.progress_every)
                 if not self.progress and any(self.progress_every) else None)
        self._t0 = time.perf_counter()
        try:
            self.algo.train()
            opts = list(self.algo.optimizers().values())
            base_lrs = [[g.setdefault("initial_lr", g["lr"]) for g in o.param_groups] for o in opts]
            while self.step < end:
                if cfg.lr_schedule != "constant":
                    f = C.lr_factor(cfg, self.step)
                    for o, lrs in zip(opts, base_lrs):
                        for g, lr in zip(o.param_groups, lrs):
                            g["lr"] = lr * f
                batch = self.sampler.sample()
                # bf16 autocast (--amp bf16, or auto on a device with native bf16): faster matrix
                # products; parameters, optimiser states and the EMA stay float32
                with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=cfg.amp == "bf16"):
                    metrics = self.algo.update(batch)
                vals = torch.stack([v.float() for v in metrics.values()])
                if not bool(torch.isfinite(vals).all()):
                    bad = [k for k, v in metrics.items() if not math.isfinite(float(v))]
                    last = checkpoint_paths(self.run_dir)
                    kept = f"last good checkpoint kept: {last[-1]}" if last else "no checkpoint was written yet"
                    raise TrainingDiverged(f"{', '.join(bad)} became NaN/inf at step {self.step + 1}; training stopped; {kept}")
                self.step += 1
                sums = self._acc["sums"]
                for k, v in zip(metrics, vals.tolist()):
                    sums[k] = sums.get(k, 0.0) + v
                self._acc["count"] += 1
                bar.update(1)
                if lines is not None:
                    lines.update(self.step, dict(zip(metrics, vals.tolist())))
                # the lines fall where an uninterrupted run's do (a stop at `until` leaves the sums to the checkpoint)
                if self.step % cfg.log_every == 0 or self.step == cfg.steps:
                    rec = self._metrics_line()
                    log.write(rec)
                    bar.set_postfix({k: f"{rec[k]:.3g}" for k in list(metrics)[:2]})
                if self.evaluators and cfg.eval_every > 0 and (self.step % cfg.eval_every == 0 or self.step == cfg.steps):
                    self._acc["seconds"] += time.perf_counter() - self._t0
                    ev = self.evaluate()
                    if ev:
                        log.write({"step": self.step, **ev})
                    self._t0 = time.perf_counter()
                if self.step % cfg.checkpoint_every == 0 or self.step == cfg.steps:
                    self.checkpoint()
        finally:
            bar.close()
            log.close()
            self.release()
        return self.step

    def release(self) -> None:
        """Let another process train this run (train() does it when it returns)."""
        if self._lock is not None:
            self._lock.release()
            self._lock = None


# ----------------------------------------------------------------------------- entry points


def start_run(cfg: C.TrainConfig, run_dir: str | Path, *, data: Dataset | None = None, progress: bool = True,
              evaluators: dict[str, Evaluator] | None = None, **trainer_kw: Any) -> Trainer:
    """A new run in ``run_dir`` (config.json written, no step taken yet). Everything that
    can be refused (config values, the device, the dataset) is checked before the folder
    is created, exclusively; a failure after that removes it again."""
    run_dir = Path(run_dir)
    C.check(cfg)
    resolve_device(cfg.device)
    check_logger(trainer_kw.get("logger", "tensorboard"))
    if data is None:
        if not cfg.dataset:
            raise UserError("no dataset given (--dataset PATH)")
        data = load_dataset(cfg.dataset)
    if cfg.dataset:  # config.json and the checkpoints name it absolutely: eval and resume work from any folder
        cfg = dataclasses.replace(cfg, dataset=str(Path(cfg.dataset).resolve()))
    # "auto" precision becomes what this device runs fastest; the run records the choice, so
    # that its resume (and `train --config run.toml`) trains the same way
    amp, why = resolve_amp(cfg.amp, resolve_device(cfg.device))
    cfg = dataclasses.replace(cfg, amp=amp)
    claim_run_dir(run_dir)
    lock = RunLock(run_dir)
    try:
        tr = Trainer(run_dir, cfg, data, progress=progress, evaluators=evaluators, lock=lock, **trainer_kw)
        tr.precision = f"{amp} ({why})"
        return tr
    except BaseException:
        lock.release()
        shutil.rmtree(run_dir, ignore_errors=True)  # ours alone (claimed above), and nothing trained yet
        raise


def resume_run(run_dir: str | Path, *, data: Dataset | None = None, progress: bool = True,
               evaluators: dict[str, Evaluator] | None = None, overrides: dict | None = None, logger: str | None = None,
               **trainer_kw: Any) -> Trainer:
    """Continue ``run_dir`` from its newest intact checkpoint (or from scratch when it has none)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise UserError(f"no run at {run_dir}")
    meta = read_json(run_dir / "config.json")
    try:
        cfg = C.from_dict(meta["config"])
    except (KeyError, TypeError) as e:
        raise UserError(f"{run_dir / 'config.json'} is damaged: {e}") from None
    for k, v in (overrides or {}).items():
        if v is not None and k != "dataset" and getattr(cfg, k) != v:
            setattr(cfg, k, v)
    C.check(cfg)
    resolve_device(cfg.device)
    logger = logger or meta.get("logger", "tensorboard")  # the run's own, unless asked otherwise
    check_logger(logger)
    if data is None:  # --dataset on resume: the same data moved elsewhere (identity is checked)
        data = load_dataset(locate_dataset(meta.get("dataset") or {"path": cfg.dataset}, run_dir, (overrides or {}).get("dataset")))
    if not checkpoint_paths(run_dir):
        check_same_dataset(meta["dataset"], data)
    lock = RunLock(run_dir)  # before anything in the run changes
    try:
        from aerohrl.algorithms.provenance import provenance

        # e.g. more --steps: the run's config says so from now on; each resume records its own code and machine
        resumes = [*meta.get("resumes", []), {**provenance(cfg.device), "step": _newest_step(run_dir)}]
        atomic.write_json(run_dir / "config.json", {**meta, "config": C.to_dict(cfg), "logger": logger, "resumes": resumes})
        atomic.write_text(run_dir / C.TOML_NAME, C.to_toml(cfg))
        return Trainer(run_dir, cfg, data, progress=progress, evaluators=evaluators, lock=lock, logger=logger, **trainer_kw)
    except BaseException:
        lock.release()
        raise


def _newest_step(run_dir) -> int:
    ckpts = checkpoint_paths(run_dir)
    return checkpoint_step(ckpts[-1]) if ckpts else 0


__all__ = ["Trainer", "TrainingDiverged", "start_run", "resume_run", "new_run_dir", "claim_run_dir", "checkpoint_paths",
           "load_checkpoint", "checkpoint_problem", "locate_dataset", "read_metrics"]
