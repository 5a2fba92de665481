"""The training loop: sample -> relabel -> update, with checkpoints, logging and resume.

The run folder (its files, claim, lock, checkpoints, RNG states and metrics) is a
:class:`~aerohrl.algorithms.run.Run`; this module is the loop that fills it.
``--resume`` restarts from the newest intact checkpoint, drops the metrics logged after
it and, because every random draw (sampling, relabelling, TD3 noise, CQL's sampled
actions) comes from RNGs saved in the checkpoint, ends with the same weights as an
uninterrupted run; the checkpoint also holds the partial sums of the metric line in
progress, so the first line after a resume is the uninterrupted one.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

import torch

from aerohrl.algorithms import config as C
from aerohrl.algorithms.base import Algorithm, algorithm_class, build_algorithm
from aerohrl.algorithms.data import Dataset, GoalBatchSampler, fit_normalizer, load_dataset
from aerohrl.algorithms.networks import Normalizer
from aerohrl.algorithms.run import (
    Run,
    RunLock,
    check_logger,
    check_same_dataset,
    dataset_identity,
    rng_state,
    seed_everything,
    set_rng_state,
)
from aerohrl.errors import UserError
from aerohrl.hardware import resolve_amp


class TrainingDiverged(UserError):
    """A loss became NaN/inf: the run stops, its last good checkpoint is kept."""

    exit_code = 3


def resolve_device(name: str) -> torch.device:
    """``name`` as a torch device; UserError for an unknown one or CUDA without a GPU."""
    try:
        dev = torch.device(name)
    except RuntimeError:
        raise UserError(f"unknown device {name!r}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise UserError("--device cuda asked for, but no CUDA device is available")
    return dev


# ----------------------------------------------------------------------------- trainer


Evaluator = Callable[[Algorithm, int], dict]


class Trainer:
    """Owns a run: the algorithm, the batch sampler, the checkpoints and the logs."""

    def __init__(
        self,
        run_dir: str | Path | Run,
        cfg: C.TrainConfig,
        data: Dataset,
        *,
        progress: bool = True,
        evaluators: dict[str, Evaluator] | None = None,
        lock: RunLock | None = None,
        logger: str = "tensorboard",
        progress_every_s: float = 0.0,
        progress_every_steps: int = 0,
    ):
        self.run = run_dir if isinstance(run_dir, Run) else Run(run_dir)
        self.run_dir = self.run.path
        self.cfg = cfg
        # with observe_disturbance the states carry the expert's estimate d_hat (columns 18..20)
        self.data = data = data.with_disturbance() if cfg.observe_disturbance else data
        self.progress = progress
        self.logger = logger
        # without the bar: a progress line every progress_every_s seconds / progress_every_steps steps (0: never)
        self.progress_every = (progress_every_s, progress_every_steps)
        self.device = resolve_device(cfg.device)
        if cfg.amp not in ("none", "bf16"):  # start_run resolves "auto"; a Trainer trains in one precision
            cfg = self.cfg = dataclasses.replace(cfg, amp=resolve_amp(cfg.amp, self.device)[0])
        self.precision = f"{cfg.amp} (the run's own)"
        self._lock = lock or self.run.lock()  # held until train() returns
        self.evaluators = evaluators
        self.step = 0
        self.stopped_at: int | None = None  # the step whose evaluation reached cfg.stop_success
        self.set_aside: list[tuple[Path, str]] = []  # damaged checkpoints skipped on resume, and why
        # what the metric line in progress has summed so far (restored on resume)
        self._acc: dict[str, Any] = {"sums": {}, "count": 0, "seconds": 0.0}  # loss sums, step count, seconds
        self._acc_restored = True
        self._t0 = time.perf_counter()
        self.run.remove_stale_temporaries()
        ckpts = self.run.checkpoints()
        if ckpts:
            self._resume()
        else:
            self._fresh()
        self.sampler = GoalBatchSampler(
            data,
            self.algo.normalizer,
            cfg.batch_size,
            cfg.relabel_prob,
            self.generator,
            device=self.device,
            future=C.relabel_future(cfg),
            mc_gamma=cfg.gamma if cfg.mc_lower_bound else None,
            augment=cfg.augment,
            critic_random_goal_prob=cfg.critic_random_goal_prob,
            bc_target=cfg.bc_target,
            **algorithm_class(cfg.algo).sampler_options(cfg),
        )
        if ckpts:
            set_rng_state(self._pending_rng, {"sampler": self.generator})

    # --- construction -------------------------------------------------------------
    def _fresh(self):
        cfg = self.cfg
        self.generator = seed_everything(cfg.seed)
        norm = fit_normalizer(
            self.data,
            cfg.relabel_prob,
            seed=cfg.seed,
            future=C.relabel_future(cfg),
            bc_target=cfg.bc_target,
            pos_octaves=cfg.pos_octaves,
        )
        self.algo = build_algorithm(cfg, norm).to(self.device)
        self.dataset = dataset_identity(self.data)
        from aerohrl.algorithms.provenance import provenance

        self.run.write_config(
            {
                "config": C.to_dict(cfg),
                "dataset": self.dataset,
                "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                "logger": self.logger,
                "provenance": provenance(cfg.device),
            },
            toml=C.to_toml(cfg),
        )  # the same config, for `train --config RUN/run.toml`
        self.resumed_from = None

    def _resume(self):
        # damaged newer checkpoints are set aside as *.damaged (kept, out of the way of eval and the next resume)
        path, ck, self.set_aside = self.run.newest_intact(map_location=self.device)
        check_same_dataset(ck["dataset"], self.data)
        self.dataset = ck["dataset"]
        self.generator = torch.Generator()
        self.algo = build_algorithm(self.cfg, Normalizer.for_state_dict(ck["model"])).to(self.device)
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
        return self.run.save_checkpoint(
            {
                "step": self.step,
                "algo": self.cfg.algo,
                "config": C.to_dict(self.cfg),
                "dataset": self.dataset,
                "model": self.algo.state_dict(),
                "optimizers": {k: o.state_dict() for k, o in self.algo.optimizers().items()},
                "extra": self.algo.extra_state(),
                "rng": rng_state({"sampler": self.generator}),
                "metrics_acc": {**self._acc, "seconds": self._acc["seconds"] + time.perf_counter() - self._t0},
                "time": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            },
            self.step,
            keep=self.cfg.keep_checkpoints,
        )

    # --- the loop -----------------------------------------------------------------
    def _evaluates(self, step: int) -> bool:
        """Whether the periodic evaluation runs after ``step``: every ``eval_every`` steps from
        ``eval_start`` on, and at the last step."""
        cfg = self.cfg
        return step == cfg.steps or (step % cfg.eval_every == 0 and step >= cfg.eval_start)

    def _default_evaluators(self) -> dict[str, Evaluator]:
        if self.cfg.eval_every <= 0:
            return {}
        from aerohrl.algorithms.closed_loop import make_maze_evaluator, make_reach_desired_evaluator, make_reach_novel_evaluator

        maze = make_maze_evaluator(self.data, self.cfg)
        if maze is not None:
            return {"maze": maze}
        if self.cfg.eval_task == "reach-novel":
            return {"reach_novel": make_reach_novel_evaluator(self.data, self.cfg)}
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
        rec = {
            "step": self.step,
            **{k: v / acc["count"] for k, v in acc["sums"].items()},
            "steps_per_s": acc["count"] / max(acc["seconds"], 1e-9),
        }
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
            self._lock = self.run.lock()
        try:
            log = self.run.metrics_log(keep_until=self.step if self.resumed_from else None, logger=self.logger)
        except BaseException:
            self.release()
            raise
        if self.evaluators is None:
            self.evaluators = self._default_evaluators()
        bar = tqdm(
            total=cfg.steps, initial=self.step, disable=not self.progress, desc=f"{cfg.algo}", unit="step", dynamic_ncols=True
        )
        lines = (
            ProgressLines(f"train {cfg.algo} {self.run_dir.name}", self.step, cfg.steps, *self.progress_every)
            if not self.progress and any(self.progress_every)
            else None
        )
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
                    last = self.run.checkpoints()
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
                reached = False
                if self.evaluators and cfg.eval_every > 0 and self._evaluates(self.step):
                    self._acc["seconds"] += time.perf_counter() - self._t0
                    ev = self.evaluate()
                    if ev:
                        log.write({"step": self.step, **ev})
                    reached = cfg.stop_success > 0 and any(v >= cfg.stop_success for k, v in ev.items() if k.endswith("/success"))
                    self._t0 = time.perf_counter()
                if reached:  # the policy that reached it is the run's last checkpoint
                    if self._acc["count"]:
                        log.write(self._metrics_line())
                    self.checkpoint()
                    self.stopped_at = self.step
                    break
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


def start_run(
    cfg: C.TrainConfig,
    run_dir: str | Path,
    *,
    data: Dataset | None = None,
    progress: bool = True,
    evaluators: dict[str, Evaluator] | None = None,
    **trainer_kw: Any,
) -> Trainer:
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
    run = Run.create(run_dir)
    lock = run.lock()
    try:
        tr = Trainer(run, cfg, data, progress=progress, evaluators=evaluators, lock=lock, **trainer_kw)
        tr.precision = f"{amp} ({why})"
        return tr
    except BaseException:
        lock.release()
        shutil.rmtree(run.path, ignore_errors=True)  # ours alone (claimed above), and nothing trained yet
        raise


def resume_run(
    run_dir: str | Path | Run,
    *,
    data: Dataset | None = None,
    progress: bool = True,
    evaluators: dict[str, Evaluator] | None = None,
    overrides: dict | None = None,
    logger: str | None = None,
    **trainer_kw: Any,
) -> Trainer:
    """Continue ``run_dir`` from its newest intact checkpoint (or from scratch when it has none)."""
    run = Run.open(run_dir, kind="train")
    meta, cfg = run.meta, run.config
    cfg = C.update(cfg, **{k: v for k, v in (overrides or {}).items() if v is not None and k != "dataset"})
    C.check(cfg)
    resolve_device(cfg.device)
    logger = logger or meta.get("logger", "tensorboard")  # the run's own, unless asked otherwise
    check_logger(logger)
    if data is None:  # --dataset on resume: the same data moved elsewhere (identity is checked)
        data = load_dataset(run.locate_dataset((overrides or {}).get("dataset")))
    if not run.checkpoints():
        check_same_dataset(meta["dataset"], data)
    lock = run.lock()  # before anything in the run changes
    try:
        from aerohrl.algorithms.provenance import provenance

        # e.g. more --steps: the run's config says so from now on; each resume records its own code and machine
        resumes = [*meta.get("resumes", []), {**provenance(cfg.device), "step": run.step}]
        run.write_config({**meta, "config": C.to_dict(cfg), "logger": logger, "resumes": resumes}, toml=C.to_toml(cfg))
        return Trainer(run, cfg, data, progress=progress, evaluators=evaluators, lock=lock, logger=logger, **trainer_kw)
    except BaseException:
        lock.release()
        raise


# ----------------------------------------------------------------------------- progress


class ProgressLines:
    """The progress of a run without a terminal (a cluster job's log): one line on stderr
    every ``every_s`` seconds and, when ``every_steps`` > 0, every that many steps:
    step, steps/s (since the previous line), the mean losses since it, and the ETA."""

    sums: dict[str, float]  # the losses summed since the last line, set by _reset

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
        text = (
            f"{self.name}: step {step:,}/{self.total:,} ({100 * step / max(self.total, 1):.1f}%)  {rate:.1f} steps/s"
            + (f"  {losses}" if losses else "")
            + f"  ETA {_duration(eta)}"
        )
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


__all__ = ["Trainer", "TrainingDiverged", "ProgressLines", "start_run", "resume_run", "resolve_device"]
