"""The training loop: sample -> relabel -> update, with checkpoints, logging and resume.

A run folder ``runs/<run>/`` holds::

    config.json              the resolved TrainConfig + the dataset's identity
    checkpoints/step-NNNNNNNNN.pt   weights, optimiser states, step, RNG states, config,
                             dataset version/checksum/shapes (last ``keep_checkpoints``)
    metrics.jsonl            one JSON object per log interval / evaluation
    tb/                      TensorBoard events (when tensorboard is installed)
    learning_curve.png       written by ``aerohrl runs show``

Every file is written to a temporary name and renamed, so a killed run (even
``kill -9``) loses nothing it had written; ``--resume`` restarts from the last
checkpoint, drops metrics logged after it and, because every random draw (sampling,
relabelling, TD3 noise, CQL's sampled actions) comes from RNGs saved in the
checkpoint, ends with the same weights as an uninterrupted run.
"""

from __future__ import annotations

import json
import math
import os
import random
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from aerohrl.algorithms import config as C
from aerohrl.algorithms.base import Algorithm, build_algorithm
from aerohrl.algorithms.data import Dataset, GoalBatchSampler, fit_normalizer, load_dataset
from aerohrl.algorithms.networks import Normalizer
from aerohrl.errors import UserError

CHECKPOINT_FORMAT = "aerohrl-checkpoint/1"
CKPT_DIR = "checkpoints"


class TrainingDiverged(UserError):
    """A loss became NaN/inf: the run stops, its last good checkpoint is kept."""

    exit_code = 3


# ----------------------------------------------------------------------------- files


def atomic_write_bytes(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def atomic_write_json(path: Path, obj) -> None:
    atomic_write_bytes(path, (json.dumps(obj, indent=2, sort_keys=True) + "\n").encode())


def atomic_torch_save(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        torch.save(obj, tmp)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def checkpoint_paths(run_dir) -> list[Path]:
    """Checkpoints of a run, oldest first."""
    d = Path(run_dir) / CKPT_DIR
    return sorted(d.glob("step-*.pt")) if d.is_dir() else []


def read_json(path: Path) -> dict:
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise UserError(f"{path} is missing") from None
    except (OSError, json.JSONDecodeError) as e:
        raise UserError(f"cannot read {path}: {e}") from None


def load_checkpoint(path, map_location="cpu") -> dict:
    try:
        ck = torch.load(path, map_location=map_location, weights_only=False)
    except FileNotFoundError:
        raise UserError(f"no checkpoint at {path}") from None
    except Exception as e:  # torch raises many types on a truncated/damaged file
        raise UserError(f"checkpoint {path} is damaged: {type(e).__name__}: {e}") from None
    if not isinstance(ck, dict) or ck.get("format") != CHECKPOINT_FORMAT:
        raise UserError(f"{path} is not an aerohrl checkpoint")
    return ck


def read_metrics(run_dir) -> list[dict]:
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
    i = data.info
    return {"path": i.get("path"), "version": i.get("version"), "checksum": i.get("checksum"),
            "shapes": i.get("shapes"), "frames": i.get("frames"), "episodes": i.get("episodes")}


def check_same_dataset(expected: dict, data: Dataset) -> None:
    got = dataset_identity(data)
    if got["shapes"] != expected.get("shapes"):
        raise UserError(f"dataset feature shapes {got['shapes']} differ from the run's {expected.get('shapes')}")
    if got["version"] != expected.get("version"):
        raise UserError(f"dataset version {got['version']!r} differs from the run's {expected.get('version')!r}")
    if got["checksum"] != expected.get("checksum"):
        raise UserError(f"dataset checksum differs from the run's (version {got['version']!r}): the data changed")


def new_run_dir(cfg: C.TrainConfig, runs_root="runs", name: str | None = None) -> Path:
    if name is None:
        stamp = datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")
        name = f"{cfg.algo}-{cfg.preset}-s{cfg.seed}-{stamp}"
    d = Path(runs_root) / name
    if (d / "config.json").exists():
        raise UserError(f"run {d} exists; use --resume {d} to continue it")
    return d


# ----------------------------------------------------------------------------- RNG


def rng_state(gen: torch.Generator) -> dict:
    st = {"torch": torch.get_rng_state(), "sampler": gen.get_state(), "numpy": np.random.get_state(), "python": random.getstate()}
    if torch.cuda.is_available():
        st["cuda"] = torch.cuda.get_rng_state_all()
    return st


def set_rng_state(st: dict, gen: torch.Generator) -> None:
    torch.set_rng_state(st["torch"])
    gen.set_state(st["sampler"])
    np.random.set_state(st["numpy"])
    random.setstate(st["python"])
    if "cuda" in st and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(st["cuda"])


def seed_everything(seed: int) -> torch.Generator:
    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)
    random.seed(seed)
    return torch.Generator().manual_seed(seed + 1)


def resolve_device(name: str) -> torch.device:
    try:
        dev = torch.device(name)
    except RuntimeError:
        raise UserError(f"unknown device {name!r}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise UserError("--device cuda asked for, but no CUDA device is available")
    return dev


# ----------------------------------------------------------------------------- logging


class MetricsLog:
    """metrics.jsonl (+ TensorBoard when installed)."""

    def __init__(self, run_dir: Path, keep_until_step: int | None):
        self.path = run_dir / "metrics.jsonl"
        if keep_until_step is not None and self.path.exists():  # resume: drop what came after the checkpoint
            kept = [r for r in read_metrics(run_dir) if r.get("step", 0) <= keep_until_step]
            atomic_write_bytes(self.path, "".join(json.dumps(r) + "\n" for r in kept).encode())
        elif keep_until_step is None and self.path.exists():
            self.path.unlink()
        self._f = open(self.path, "a")
        self.tb = None
        try:
            from torch.utils.tensorboard import SummaryWriter
        except Exception:  # tensorboard is optional
            SummaryWriter = None
        if SummaryWriter is not None:
            # on resume, TensorBoard drops the events logged after the checkpoint (purge_step)
            purge = None if keep_until_step is None else keep_until_step + 1
            self.tb = SummaryWriter(str(run_dir / "tb"), purge_step=purge)

    def write(self, record: dict) -> None:
        self._f.write(json.dumps(record) + "\n")
        self._f.flush()
        if self.tb is not None:
            step = record.get("step", 0)
            for k, v in record.items():
                if k != "step" and isinstance(v, (int, float)):
                    self.tb.add_scalar(k, v, step)

    def close(self) -> None:
        self._f.close()
        if self.tb is not None:
            self.tb.close()


# ----------------------------------------------------------------------------- trainer


Evaluator = Callable[[Algorithm, int], dict]


class Trainer:
    """Owns a run: the algorithm, the batch sampler, the checkpoints and the logs."""

    def __init__(self, run_dir, cfg: C.TrainConfig, data: Dataset, *, progress: bool = True,
                 evaluators: dict[str, Evaluator] | None = None):
        self.run_dir = Path(run_dir)
        self.cfg = cfg
        self.data = data
        self.progress = progress
        self.device = resolve_device(cfg.device)
        self.evaluators = evaluators
        self.step = 0
        ckpts = checkpoint_paths(self.run_dir)
        if ckpts:
            self._resume(ckpts[-1])
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
        atomic_write_json(self.run_dir / "config.json", {"config": C.to_dict(cfg), "dataset": self.dataset,
                                                           "created": datetime.now(timezone.utc).isoformat(timespec="seconds")})
        self.resumed_from = None

    def _resume(self, path: Path):
        ck = load_checkpoint(path, map_location=self.device)
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
        self.resumed_from = path

    def checkpoint(self) -> Path:
        path = self.run_dir / CKPT_DIR / f"step-{self.step:09d}.pt"
        atomic_torch_save(path, {
            "format": CHECKPOINT_FORMAT,
            "step": self.step,
            "algo": self.cfg.algo,
            "config": C.to_dict(self.cfg),
            "dataset": self.dataset,
            "model": self.algo.state_dict(),
            "optimizers": {k: o.state_dict() for k, o in self.algo.optimizers().items()},
            "extra": self.algo.extra_state(),
            "rng": rng_state(self.generator),
            "time": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        })
        for old in checkpoint_paths(self.run_dir)[: -self.cfg.keep_checkpoints]:
            old.unlink(missing_ok=True)
        return path

    # --- the loop -----------------------------------------------------------------
    def _default_evaluators(self) -> dict[str, Evaluator]:
        if self.cfg.eval_every <= 0:
            return {}
        from aerohrl.algorithms.closed_loop import make_reach_desired_evaluator

        return {"reach_desired": make_reach_desired_evaluator(self.data, self.cfg)}

    def evaluate(self) -> dict:
        evals = self._default_evaluators() if self.evaluators is None else self.evaluators
        out = {}
        for name, fn in evals.items():
            for k, v in fn(self.algo, self.step).items():
                out[f"eval/{name}/{k}"] = v
        return out

    def train(self, until: int | None = None) -> int:
        """Train up to ``cfg.steps`` (or ``until``); returns the step reached."""
        from tqdm import tqdm

        cfg = self.cfg
        end = cfg.steps if until is None else min(until, cfg.steps)
        log = MetricsLog(self.run_dir, keep_until_step=self.step if self.resumed_from else None)
        if self.evaluators is None:
            self.evaluators = self._default_evaluators()
        bar = tqdm(total=cfg.steps, initial=self.step, disable=not self.progress, desc=f"{cfg.algo}", unit="step", dynamic_ncols=True)
        sums: dict[str, float] = {}
        count, t0 = 0, time.perf_counter()
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
                # bf16 autocast (--amp bf16): ~2x faster matrix products on CPUs with AVX512-BF16 and on
                # GPUs; parameters, optimiser states and the EMA stay float32
                with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=cfg.amp == "bf16"):
                    metrics = self.algo.update(batch)
                vals = torch.stack([v.float() for v in metrics.values()])
                if not bool(torch.isfinite(vals).all()):
                    bad = [k for k, v in metrics.items() if not math.isfinite(float(v))]
                    last = checkpoint_paths(self.run_dir)
                    kept = f"last good checkpoint kept: {last[-1]}" if last else "no checkpoint was written yet"
                    raise TrainingDiverged(f"{', '.join(bad)} became NaN/inf at step {self.step + 1}; training stopped; {kept}")
                self.step += 1
                for k, v in zip(metrics, vals.tolist()):
                    sums[k] = sums.get(k, 0.0) + v
                count += 1
                bar.update(1)
                if self.step % cfg.log_every == 0 or self.step == end:
                    dt = time.perf_counter() - t0
                    rec = {"step": self.step, **{k: v / count for k, v in sums.items()}, "steps_per_s": count / max(dt, 1e-9)}
                    log.write(rec)
                    bar.set_postfix({k: f"{rec[k]:.3g}" for k in list(sums)[:2]})
                    sums, count, t0 = {}, 0, time.perf_counter()
                if self.evaluators and cfg.eval_every > 0 and (self.step % cfg.eval_every == 0 or self.step == cfg.steps):
                    ev = self.evaluate()
                    if ev:
                        log.write({"step": self.step, **ev})
                    t0 = time.perf_counter()
                if self.step % cfg.checkpoint_every == 0 or self.step == cfg.steps:
                    self.checkpoint()
        finally:
            bar.close()
            log.close()
        return self.step


# ----------------------------------------------------------------------------- entry points


def start_run(cfg: C.TrainConfig, run_dir, *, data: Dataset | None = None, progress: bool = True,
              evaluators=None) -> Trainer:
    """A new run in ``run_dir`` (config.json written, no step taken yet)."""
    run_dir = Path(run_dir)
    if (run_dir / "config.json").exists():
        raise UserError(f"run {run_dir} exists; use --resume {run_dir} to continue it")
    if data is None:
        if not cfg.dataset:
            raise UserError("no dataset given (--dataset PATH)")
        data = load_dataset(cfg.dataset)
    run_dir.mkdir(parents=True, exist_ok=True)
    return Trainer(run_dir, cfg, data, progress=progress, evaluators=evaluators)


def resume_run(run_dir, *, data: Dataset | None = None, progress: bool = True, evaluators=None,
               overrides: dict | None = None) -> Trainer:
    """Continue ``run_dir`` from its last checkpoint (or from scratch when it has none)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise UserError(f"no run at {run_dir}")
    meta = read_json(run_dir / "config.json")
    try:
        cfg = C.from_dict(meta["config"])
    except (KeyError, TypeError) as e:
        raise UserError(f"{run_dir / 'config.json'} is damaged: {e}") from None
    changed = False
    for k, v in (overrides or {}).items():
        if v is not None and k != "dataset" and getattr(cfg, k) != v:
            setattr(cfg, k, v)
            changed = True
    C.check(cfg)
    if changed:  # e.g. more --steps: the run's config says so from now on
        atomic_write_json(run_dir / "config.json", {**meta, "config": C.to_dict(cfg)})
    if data is None:  # --dataset on resume: the same data moved elsewhere (identity is checked)
        data = load_dataset((overrides or {}).get("dataset") or cfg.dataset)
    if not checkpoint_paths(run_dir):
        check_same_dataset(meta["dataset"], data)
    return Trainer(run_dir, cfg, data, progress=progress, evaluators=evaluators)


__all__ = ["Trainer", "TrainingDiverged", "start_run", "resume_run", "new_run_dir", "checkpoint_paths", "load_checkpoint", "read_metrics"]
