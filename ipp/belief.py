"""A learned target belief: P(target) per cell from the planner's state, and search over it.

The hand-written belief is the prior plus Bayesian sensor updates (thesis Eq. 2.2,
:mod:`.sensor`); the prior is wrong by construction (shifted centres, spurious
components, :mod:`.world`). :class:`BeliefNet` is a small dilated CNN over the map that
outputs a correction ``c`` to the Bayesian log-odds ``L``::

    q = sigmoid((clip(L, -L_max, L_max) + c(x)) / T)

where ``x`` stacks the planner's state on the ``S x S`` map (:func:`belief_inputs`:
prior, posterior, measurement evidence, coverage, the vehicle's position, the budget
left, cell coordinates) and ``T > 0`` is a temperature fitted on validation worlds.
The head starts at zero, so an untrained model *is* the Bayesian posterior.

**Training** (:func:`train_belief`, ``aerohrl ipp belief train``): states are recorded
along baseline planners' trajectories (``planners``, e.g. detect, dp and coverage) on
worlds of the training suite seed ``seed`` (random starts; planner ``j`` flies worlds
``j*n_worlds .. (j+1)*n_worlds - 1``), every ``every``-th decision; the loss is the
per-cell binary cross-entropy to the true target map (:func:`belief_loss`). Validation
states come from the validation suite (``val_seed``, centre start) along the same
planners; the test suite (:data:`aerohrl.ipp.world.TEST_SEED`) is never read. The run
folder is a :class:`~aerohrl.algorithms.run.Run` of kind ``ipp``: ``config.json``,
``data.npz`` (the recorded states, with a SHA-256 sidecar), ``checkpoint.pt`` (weights,
optimiser, epoch, RNG states; SHA-256 checked), ``belief.pt`` (the weights of the best
validation log-loss), ``metrics.jsonl``; ``--resume`` continues from the checkpoint and
gives the same weights as an uninterrupted run.

**Calibration** (:func:`calibrate`): one temperature ``T`` minimising the validation
log-loss, then expected calibration error (:func:`expected_calibration_error`), log-loss
of the learned belief (before and after ``T``) against the hand-written posterior, and a
reliability diagram; ``calibration.json`` and ``reliability.png`` in the run folder.

**Search** (:class:`BeliefView`): a planner built on ``BeliefView(env, model)`` instead of
the environment reads ``q`` wherever it reads the belief (``plan_cells``); the
``detect`` utility becomes ``q * P(the Bayesian posterior crosses the found threshold |
target)`` on cells the posterior does not yet call found, because a target counts as
found by the Bayesian posterior, which the environment keeps unchanged. The metrics are
the environment's own.
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence, cast

import numpy as np

from aerohrl import atomic
from aerohrl import config as K
from aerohrl.config import param
from aerohrl.errors import UserError, warn

from .env import EnvConfig, SearchEnv
from .sensor import logit, sigmoid
from .train_config import VAL_SEED
from .world import TEST_SEED, Worlds

if TYPE_CHECKING:
    import torch

    from .lattice import Lattice

PRESET_DIR = Path(__file__).parent / "presets" / "belief"  # one TOML file per preset
BELIEF_FORMAT = "aerohrl-ipp-belief"
BELIEF_VERSION = 1
CHECKPOINT_VERSION = 1
N_IN = 8  # input channels of belief_inputs
L_MAX = 20.0  # bound on the Bayesian log-odds fed to the residual (the sensor's clip)
POS_SIGMA = 2.0  # width of the vehicle's position channel (cells)
EVIDENCE_SCALE = 8.0  # measurement evidence enters as tanh(evidence / this)
BELIEF_PLANNERS = ("detect", "dp", "coverage", "prio_coverage", "greedy")  # trajectory sources


@dataclass(frozen=True)
class BeliefNetConfig:
    """The network: dilated 3 x 3 convolutions, optionally a global-context branch, then a
    1 x 1 head (zero-initialised)."""

    width: int = param(24, "channels of every hidden convolution", unit="channels", ge=1)
    dilations: tuple[int, ...] = param((1, 2, 4, 8), "dilation of each 3 x 3 convolution (receptive field 1 + 2 * sum)", ge=1)
    context: bool = param(
        False,
        "a global-context branch: the map-wide mean and max of the features, through a linear layer, "
        "join every cell's features before a 1 x 1 convolution (world-level latents, e.g. how far the "
        "detections so far agree with the prior, are a statistic of the whole map)",
    )


@dataclass(frozen=True)
class BeliefConfig:
    """``aerohrl ipp belief train`` settings (presets: ``ipp/presets/belief/NAME.toml``)."""

    seed: int = param(7, "random seed and training suite seed (never the validation or test seed)", ge=0)
    n_worlds: int = param(64, "training worlds per trajectory planner", ge=1)
    planners: tuple[str, ...] = param(
        ("detect", "dp", "coverage"), "planners whose trajectories give the states", choices=BELIEF_PLANNERS
    )
    every: int = param(2, "record every N-th decision of an episode", ge=1)
    val_seed: int = param(VAL_SEED, "validation suite seed (calibration, model selection)", ge=0)
    val_worlds: int = param(32, "validation worlds per trajectory planner", ge=1)
    epochs: int = param(12, "passes over the recorded training states", ge=1)
    batch_size: int = param(64, "states per gradient step", ge=1)
    lr: float = param(2e-3, "learning rate (Adam)", gt=0, lt=1)
    weight_decay: float = param(1e-4, "Adam weight decay", ge=0)
    threads: int = param(1, "torch threads", ge=1)
    net: BeliefNetConfig = K.section(BeliefNetConfig, "the network")
    env: EnvConfig = param(EnvConfig(start="random"), "the environment the states are recorded in (random starts)")

    def validate(self) -> None:
        """ConfigError (one line) for a setting out of range, a planner repeated, or
        suites that overlap: the training, validation and test seeds must differ."""
        K.validate(self)
        if self.env.kind != "targets":
            raise K.ConfigError("the learned belief is for target search (env.kind targets)")
        if len(set(self.planners)) != len(self.planners) or not self.planners:
            raise K.ConfigError(f"planners must be distinct and non-empty, got {list(self.planners)}")
        if len({self.seed, self.val_seed, TEST_SEED}) < 3:
            raise K.ConfigError(
                f"seed {self.seed}, val_seed {self.val_seed} and the test seed {TEST_SEED} must all differ "
                "(training, validation and test worlds never overlap)"
            )


def preset_names() -> tuple[str, ...]:
    """The belief presets shipped in ``ipp/presets/belief`` (sorted)."""
    return K.preset_names(PRESET_DIR)


def preset(name: str, **overrides: Any) -> BeliefConfig:
    """The preset ``name`` over the :class:`BeliefConfig` defaults, non-None ``overrides``
    (settings of BeliefConfig or of its ``net`` section) applied."""
    cfg = K.from_nested(BeliefConfig, K.load_preset(PRESET_DIR, name), where=f"belief preset {name}", check=False)
    over = {k: v for k, v in overrides.items() if v is not None}
    net_names = [f.name for f in dataclasses.fields(BeliefNetConfig)]
    net = {k: over.pop(k) for k in net_names if k in over}
    if net:
        cfg = dataclasses.replace(cfg, net=dataclasses.replace(cfg.net, **net))
    K.unknown_keys(list(over), [f.name for f in dataclasses.fields(BeliefConfig)], f"belief preset {name}")
    return dataclasses.replace(cfg, **over)


# ----------------------------------------------------------------------------- the model


def belief_inputs(prior: torch.Tensor, L: torch.Tensor, cov: torch.Tensor, pos: torch.Tensor, rem: torch.Tensor) -> torch.Tensor:
    """The network's input planes (B, N_IN, S, S) from batched state (B, S, S maps; ``pos``
    (B, 2) cells (x, y); ``rem`` (B,) budget fraction left):

    0. the prior ``p0``;  1. the Bayesian posterior ``sigmoid(L)``;
    2. the measurement evidence ``tanh((L - logit(p0)) / EVIDENCE_SCALE)`` (Eq. 2.2: the
       summed label log-ratios);  3. coverage;
    4. the vehicle ``exp(-|c - pos|^2 / (2 sigma^2))``;  5. the budget left (constant);
    6, 7. cell coordinates ``2 c / (S - 1) - 1`` (x, y).
    """
    import torch

    B, S = L.shape[0], L.shape[-1]
    p0 = prior.float().clamp(1e-6, 1 - 1e-6)
    Lf = L.float()
    g = torch.arange(S, dtype=torch.float32)
    dx = g[None, None, :] - pos[:, 0, None, None].float()
    dy = g[None, :, None] - pos[:, 1, None, None].float()
    here = torch.exp(-(dx**2 + dy**2) / (2 * POS_SIGMA**2))
    cx = (2 * g / max(S - 1, 1) - 1)[None, None, :].expand(B, S, S)
    cy = (2 * g / max(S - 1, 1) - 1)[None, :, None].expand(B, S, S)
    planes = [
        p0,
        torch.sigmoid(Lf),
        torch.tanh((Lf - torch.logit(p0)) / EVIDENCE_SCALE),
        cov.float(),
        here,
        rem.float()[:, None, None].expand(B, S, S),
        cx,
        cy,
    ]
    return torch.stack(planes, 1)


def base_logits(L: torch.Tensor) -> torch.Tensor:
    """The residual's base: the Bayesian log-odds, clipped to ``[-L_MAX, L_MAX]``."""
    return L.float().clamp(-L_MAX, L_MAX)


def belief_loss(logits: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
    """Mean per-cell binary cross-entropy ``-[y log q + (1 - y) log(1 - q)]``,
    ``q = sigmoid(logits)`` (computed from the logits, stable)."""
    import torch.nn.functional as F

    return F.binary_cross_entropy_with_logits(logits, targets.float())


def check_temperature(T: float) -> float:
    """``T`` as a float; UserError (one line) unless it is finite and > 0."""
    try:
        t = float(T)
    except (TypeError, ValueError):
        raise UserError(f"belief temperature must be a number > 0, got {T!r}") from None
    if not np.isfinite(t) or t <= 0:
        raise UserError(f"belief temperature must be finite and > 0, got {t:g}")
    return t


def _net(cfg: BeliefNetConfig):
    import torch
    from torch import nn

    class BeliefNet(nn.Module):
        """Dilated CNN -> per-cell log-odds correction (zero at initialisation)."""

        def __init__(self) -> None:
            super().__init__()
            layers: list[nn.Module] = []
            c = N_IN
            for d in cfg.dilations:
                layers += [nn.Conv2d(c, cfg.width, 3, padding=d, dilation=d), nn.ReLU()]
                c = cfg.width
            self.body = nn.Sequential(*layers)
            if cfg.context:
                # the squeeze of squeeze-and-excitation (Hu et al. 2018), added rather than
                # multiplied: the pooled statistics shift every cell's features
                self.ctx = nn.Linear(2 * c, c)
                self.mix = nn.Sequential(nn.Conv2d(c, c, 1), nn.ReLU())
            self.head = nn.Conv2d(c, 1, 1)
            # a zero residual at the start: the untrained belief is the Bayesian posterior
            nn.init.zeros_(self.head.weight)
            assert self.head.bias is not None
            nn.init.zeros_(self.head.bias)

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            h = self.body(x)
            if cfg.context:
                g = self.ctx(torch.cat([h.mean((-2, -1)), h.amax((-2, -1))], -1))
                h = self.mix(h + g[:, :, None, None])
            return self.head(h)[:, 0]

    return BeliefNet()


class BeliefModel:
    """A trained belief: the network, the map size it was trained for, the temperature."""

    def __init__(self, net_cfg: BeliefNetConfig, map_size: int, temperature: float = 1.0, label: str = ""):
        self.cfg, self.map_size = net_cfg, int(map_size)
        self.net = _net(net_cfg)
        self.temperature = check_temperature(temperature)
        self.label = label
        # the last prediction, keyed on the environment and its state version: the policy's
        # observation and a planner's view of the same state share one forward pass
        self._last: tuple[Any, int, float, np.ndarray] | None = None

    def logits(
        self,
        prior: torch.Tensor,
        L: torch.Tensor,
        cov: torch.Tensor,
        pos: torch.Tensor,
        rem: torch.Tensor,
        temperature: float | None = None,
    ) -> torch.Tensor:
        """Calibrated log-odds (B, S, S): ``(base_logits(L) + c(x)) / T``."""
        T = self.temperature if temperature is None else check_temperature(temperature)
        return (base_logits(L) + self.net(belief_inputs(prior, L, cov, pos, rem))) / T

    def predict(self, env: SearchEnv) -> np.ndarray:
        """q (N, S, S) float64 for the environments' current state, as
        ``sigmoid((clip(L) + c) / T)`` with ``L`` in float64 (an untrained model returns the
        posterior exactly). Read-only: the same array is returned until the state changes."""
        import weakref

        import torch

        last = self._last
        if last is not None and last[0]() is env and last[1:3] == (env.version, self.temperature):
            return last[3]
        self.check_env(env)
        p, S = env.pad, env.S
        L = env.L[:, p : p + S, p : p + S]
        with torch.no_grad():
            c = self.net(
                belief_inputs(
                    torch.from_numpy(env.worlds.prior),
                    torch.from_numpy(L),
                    torch.from_numpy(env.cov[:, p : p + S, p : p + S]),
                    torch.from_numpy(env.pos),
                    torch.from_numpy(np.maximum(env.remaining, 0) / env.cfg.budget),
                )
            ).numpy()
        q = sigmoid((np.clip(L, -L_MAX, L_MAX) + c.astype(np.float64)) / self.temperature)
        q.flags.writeable = False
        self._last = (weakref.ref(env), env.version, self.temperature, q)
        return q

    def check_env(self, env: SearchEnv) -> None:
        """UserError (one line) unless ``env`` is target search on this model's map size."""
        if env.cfg.kind != "targets":
            raise UserError(
                f"belief {self.label or ''}: a learned belief is for target search, not {env.cfg.kind} worlds".strip()
            )
        if env.S != self.map_size:
            raise UserError(
                f"belief {self.label}: trained on {self.map_size} x {self.map_size} maps, "
                f"this environment's map is {env.S} x {env.S} (retrain with --map-size {env.S})"
            )

    def view(self, env: SearchEnv) -> SearchEnv:
        """``env`` as a planner sees it with this belief (:class:`BeliefView`)."""
        self.check_env(env)
        return cast(SearchEnv, BeliefView(env, self))


def _weights(model: BeliefModel) -> dict:
    """What a saved belief holds in every form: format, version, weights, network config, map size."""
    return {
        "format": BELIEF_FORMAT,
        "version": BELIEF_VERSION,
        "state_dict": model.net.state_dict(),
        "net": asdict(model.cfg),
        "map_size": model.map_size,
    }


def _from_weights(ck: dict, temperature: float, label: str, where: str, damaged: str) -> BeliefModel:
    """The :class:`BeliefModel` of :func:`_weights`' dict ``ck`` (its version already checked),
    in eval mode; a one-line UserError ``f"{where}: {damaged} (ErrorType)"`` when it does not load."""
    try:
        net_cfg = K.from_nested(BeliefNetConfig, ck["net"], where=where)
        model = BeliefModel(net_cfg, int(ck["map_size"]), temperature, label=label)
        model.net.load_state_dict(ck["state_dict"])
    except UserError:
        raise
    except Exception as e:
        raise UserError(f"{where}: {damaged} ({type(e).__name__})") from None
    model.net.eval()
    return model


def belief_state(model: BeliefModel) -> dict:
    """The belief as plain data (weights, network config, map size, temperature, label), to
    embed in another checkpoint (a policy that observes it: :func:`belief_from_state`)."""
    return {**_weights(model), "temperature": model.temperature, "label": model.label}


def belief_from_state(state: dict, where: str) -> BeliefModel:
    """The :class:`BeliefModel` of :func:`belief_state`'s ``state``; a one-line UserError
    naming ``where`` when it is not one."""
    if not isinstance(state, dict) or state.get("format") != BELIEF_FORMAT or state.get("version") != BELIEF_VERSION:
        raise UserError(f"{where}: the embedded learned belief is not one this version reads")
    try:
        T, label = float(state["temperature"]), str(state["label"])
    except (KeyError, TypeError, ValueError) as e:
        raise UserError(f"{where}: the embedded learned belief is damaged ({type(e).__name__})") from None
    return _from_weights(state, T, label, where, "the embedded learned belief is damaged")


def save_belief(model: BeliefModel, path: str | Path, extra: dict | None = None) -> None:
    """The weights, network config and map size, atomically with a SHA-256 sidecar."""
    atomic.torch_save(path, {**_weights(model), "env_kind": "targets", **(extra or {})})


def load_belief(path: str | Path, temperature: float | None = None) -> BeliefModel:
    """A belief saved by :func:`save_belief` (``path``, or a run folder's ``belief.pt``),
    SHA-256 verified. ``temperature``: this one, else the run's ``calibration.json``, else
    1. A one-line UserError when missing, damaged or not a belief."""
    path = Path(path)
    run = path if path.is_dir() else path.parent
    if path.is_dir():
        path = path / "belief.pt"
    if not path.is_file():
        raise UserError(f"no learned belief at {path} (run 'aerohrl ipp belief train' first)")
    if temperature is not None:
        temperature = check_temperature(temperature)
    ck = atomic.torch_load(path, weights_only=True, warn=warn)
    if not isinstance(ck, dict) or ck.get("format") != BELIEF_FORMAT:
        raise UserError(f"{path}: not a learned-belief checkpoint")
    if ck.get("version") != BELIEF_VERSION:
        raise UserError(f"{path}: belief version {ck.get('version')} is not supported")
    T = temperature if temperature is not None else _calibrated_temperature(run)
    label = run.name if path.name == "belief.pt" else str(path)
    return _from_weights(ck, T, label, str(path), "not a learned-belief checkpoint")


def _calibrated_temperature(run: Path) -> float:
    f = run / "calibration.json"
    if not f.is_file():
        return 1.0
    try:
        T = json.loads(f.read_text())["temperature"]
    except (OSError, ValueError, KeyError, TypeError):
        raise UserError(f"{f} is damaged (no temperature in it)") from None
    return check_temperature(T)


# ------------------------------------------------------------------- planning over q


class PlannerCells(np.ndarray):
    """Learned P(target) at queried cells, carrying the Bayesian log-odds ``logodds`` of
    the same cells (which decide when a target counts as found)."""

    logodds: np.ndarray


class BeliefView:
    """A :class:`SearchEnv` as a planner sees it with a learned belief: every attribute is
    the environment's, but the belief a planner reads (``plan_cells``, ``prio_map``) is
    the model's ``q``, and the expected new detections of a cell are
    ``q * [P(crossing | target, lp + lam) - P(crossing | target, lp)]`` with the crossing
    of the found threshold decided by the Bayesian log-odds ``L`` (one-measurement
    equivalent of the summed label log-ratio ``lam``, as :func:`.scoring.detect_prob`):
    ``P(crossing | target, lam) = (1 - e) [L + lam >= thr] + e [L - lam >= thr]``,
    ``e = sigmoid(-lam)``, on cells with ``L < thr``."""

    def __init__(self, env: SearchEnv, model: BeliefModel):
        self._env, self._model = env, model
        self._key: tuple | None = None
        self._q: np.ndarray = np.zeros(0)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._env, name)

    def _qmap(self) -> np.ndarray:
        """(N, Hp, Hp) learned belief (0 off the map), recomputed when the state changes."""
        env = self._env
        key = (id(env.worlds), env.version)
        if key != self._key:
            q = np.zeros((env.n, env.Hp, env.Hp))
            p, S = env.pad, env.S
            q[:, p : p + S, p : p + S] = self._model.predict(env)
            self._q, self._key = q, key
        return self._q

    def plan_cells(self, n_idx: np.ndarray, flat: np.ndarray) -> np.ndarray:
        """The learned belief at cells ``flat`` of environments ``n_idx``, carrying the
        Bayesian log-odds along as ``.logodds`` for the detection gain."""
        env = self._env
        q = self._qmap().reshape(env.n, -1)[n_idx, flat]
        out = q.view(PlannerCells)
        out.logodds = env.L.reshape(env.n, -1)[n_idx, flat]
        return out

    def prio_map(self) -> np.ndarray:
        """(N, Hp, Hp) float32 priority map for the planners: the learned belief."""
        return self._qmap().astype(np.float32)

    def plan_detect_gain(self, b: np.ndarray, lp: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """Expected detections of one more look at cells ``b`` (from ``plan_cells``): the
        chance the look moves the Bayesian log-odds over the found threshold, weighted by the
        learned probability that a target is there."""
        L = getattr(b, "logodds", None)
        q = np.asarray(b)
        if L is None or np.shape(L) != q.shape:
            raise ValueError("plan_detect_gain over a learned belief needs the cells of plan_cells")
        thr = logit(self._env.cfg.found_threshold)
        lt = lp + lam
        et, ep = sigmoid(-lt), sigmoid(-lp)
        g = (1 - et) * (L + lt >= thr) + et * (L - lt >= thr) - (1 - ep) * (L + lp >= thr) - ep * (L - lp >= thr)
        return np.where(L < thr, q * g, 0.0)


# --------------------------------------------------------------------- recorded states


@dataclass
class BeliefData:
    """States recorded along planners' episodes: per state its world (row of ``prior`` /
    ``targets``), Bayesian log-odds, coverage, position, budget fraction left, planner."""

    prior: np.ndarray  # (W, S, S) float32
    targets: np.ndarray  # (W, S, S) bool
    seeds: np.ndarray  # (W, 2) int64 (suite seed, index)
    world: np.ndarray  # (k,) int64
    L: np.ndarray  # (k, S, S) float32
    cov: np.ndarray  # (k, S, S) bool
    pos: np.ndarray  # (k, 2) int64
    rem: np.ndarray  # (k,) float32
    planner: np.ndarray  # (k,) int64 index into the config's planners

    FIELDS = ("prior", "targets", "seeds", "world", "L", "cov", "pos", "rem", "planner")

    def __len__(self) -> int:
        return len(self.world)

    def tensors(self, idx: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(inputs, base logits, targets) as torch tensors for states ``idx``."""
        import torch

        w = self.world[idx]
        L = torch.from_numpy(self.L[idx])
        x = belief_inputs(
            torch.from_numpy(self.prior[w]),
            L,
            torch.from_numpy(self.cov[idx]),
            torch.from_numpy(self.pos[idx]),
            torch.from_numpy(self.rem[idx]),
        )
        return x, base_logits(L), torch.from_numpy(self.targets[w])


def collect_states(
    env_cfg: EnvConfig,
    lattice: Lattice,
    planners: Sequence[str],
    seed: int,
    indices: Sequence[Sequence[int]],
    every: int,
    progress: Any = None,
) -> BeliefData:
    """Run planner ``planners[j]`` on worlds ``indices[j]`` of suite ``seed`` (one batch each)
    and record the state before every ``every``-th decision of each live episode."""
    from .baselines import make_planner
    from .factory import create_env, sample_for

    worlds_all: list[Worlds] = []
    rec: dict[str, list] = {k: [] for k in ("world", "L", "cov", "pos", "rem", "planner")}
    base = 0
    for j, (name, idx) in enumerate(zip(planners, indices)):
        env = create_env(env_cfg, lattice)
        env.keep_trace = False
        worlds = cast(Worlds, sample_for(env_cfg, seed, list(idx)))
        env.reset(worlds)
        env.lazy_obs = True
        pl = make_planner(name, env)
        pl.reset()
        p, S = env.pad, env.S
        t = 0
        while not env.done.all():
            if t % every == 0:
                live = np.flatnonzero(~env.done)
                rec["world"].append(base + live)
                rec["L"].append(env.L[live, p : p + S, p : p + S].astype(np.float32))
                rec["cov"].append(env.cov[live, p : p + S, p : p + S].copy())
                rec["pos"].append(env.pos[live].copy())
                rec["rem"].append((np.maximum(env.remaining[live], 0) / env_cfg.budget).astype(np.float32))
                rec["planner"].append(np.full(len(live), j, np.int64))
            env.step(pl.act())
            t += 1
        worlds_all.append(worlds)
        base += len(worlds)
        if progress is not None:
            progress.update(1)
    return BeliefData(
        prior=np.concatenate([w.prior for w in worlds_all]).astype(np.float32),
        targets=np.concatenate([w.targets for w in worlds_all]),
        seeds=np.concatenate([w.seeds for w in worlds_all]),
        world=np.concatenate(rec["world"]).astype(np.int64),
        L=np.concatenate(rec["L"]),
        cov=np.concatenate(rec["cov"]),
        pos=np.concatenate(rec["pos"]).astype(np.int64),
        rem=np.concatenate(rec["rem"]),
        planner=np.concatenate(rec["planner"]),
    )


def training_indices(cfg: BeliefConfig) -> list[list[int]]:
    """Training world indices per planner: planner ``j`` flies ``j*n .. (j+1)*n - 1``."""
    n = cfg.n_worlds
    return [list(range(j * n, (j + 1) * n)) for j in range(len(cfg.planners))]


def validation_indices(cfg: BeliefConfig) -> list[list[int]]:
    """Validation world indices per planner (the same layout on the validation suite)."""
    n = cfg.val_worlds
    return [list(range(j * n, (j + 1) * n)) for j in range(len(cfg.planners))]


def save_data(path: Path, train: BeliefData, val: BeliefData) -> None:
    """Both sets in one ``.npz`` (atomically) with a SHA-256 sidecar."""
    arrays = {f"{tag}_{f}": getattr(d, f) for tag, d in (("train", train), ("val", val)) for f in BeliefData.FIELDS}
    with atomic.atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
        digest = atomic.sha256_file(tmp)
    atomic.write_text(atomic.checksum_path(path), f"{digest}  {path.name}\n")


def load_data(path: Path) -> tuple[BeliefData, BeliefData]:
    """The sets :func:`save_data` wrote, SHA-256 verified (CheckpointDamaged otherwise)."""
    atomic.verify(path)
    try:
        with np.load(path) as z:
            return tuple(BeliefData(**{f: z[f"{tag}_{f}"] for f in BeliefData.FIELDS}) for tag in ("train", "val"))  # type: ignore[return-value]
    except (OSError, KeyError, ValueError) as e:
        raise atomic.CheckpointDamaged(f"{path} is damaged ({type(e).__name__})") from None


# ------------------------------------------------------------------------- training


def _val_loss(model: BeliefModel, data: BeliefData, batch: int = 256) -> tuple[float, float]:
    """(learned log-loss at T = 1, hand-written posterior's log-loss) over ``data``."""
    import torch

    tot = base = 0.0
    with torch.no_grad():
        for s in range(0, len(data), batch):
            idx = np.arange(s, min(s + batch, len(data)))
            x, b0, y = data.tensors(idx)
            n = len(idx) * y.shape[-1] * y.shape[-2]
            tot += belief_loss(b0 + model.net(x), y).item() * n
            base += belief_loss(b0, y).item() * n
    cells = len(data) * data.L.shape[-1] * data.L.shape[-2]
    return tot / cells, base / cells


def read_belief_config(run: Path) -> BeliefConfig:
    """The :class:`BeliefConfig` of a belief run (``RUN/config.json``), one-line errors."""
    from aerohrl.algorithms.run import Run

    opened = Run.open(run, kind="ipp")
    meta = opened.meta
    if "belief" not in meta:
        raise UserError(f"{run} is not a learned-belief run (no 'belief' section in config.json)")
    try:
        return K.from_nested(BeliefConfig, meta["belief"], where=str(run / "config.json"), check=False)
    except UserError:
        raise
    except (ValueError, KeyError, TypeError) as e:
        raise UserError(f"{run / 'config.json'}: not a belief config ({type(e).__name__})") from None


def train_belief(cfg: BeliefConfig, lattice: Lattice, run_dir: str | Path, progress: Any = None, resume: bool = False) -> dict:
    """Record the states (or read them back on resume), fit the network, then calibrate.
    Returns the last epoch's log entry with the calibration report under ``calibration``."""
    import shutil

    from aerohrl.algorithms.run import Run

    cfg.validate()
    run = Run.open(run_dir, kind="ipp") if resume else Run.create(run_dir, kind="ipp")
    try:
        with run.lock():
            run.remove_stale_temporaries()
            last = _train(cfg, lattice, run, progress, resume)
    except BaseException:
        if not resume and not (run.path / "config.json").exists():
            shutil.rmtree(run.path, ignore_errors=True)
        raise
    last["calibration"] = calibrate(run.path)
    return last


def _train(cfg: BeliefConfig, lattice: Lattice, run: Any, progress: Any, resume: bool) -> dict:
    import torch

    from aerohrl.algorithms.run import rng_state, seed_everything, set_rng_state

    seed_everything(cfg.seed)
    torch.set_num_threads(cfg.threads)
    path = run.path
    model = BeliefModel(cfg.net, cfg.env.map_size)
    opt = torch.optim.Adam(model.net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    start, best, elapsed0 = 0, np.inf, 0.0
    last: dict[str, Any] = {}
    if resume:
        _, ck, _ = run.newest_intact()
        if ck.get("version") != CHECKPOINT_VERSION or ck.get("kind") != "belief":
            raise UserError(f"{run.checkpoint_path()}: not a learned-belief checkpoint of this version")
        try:
            model.net.load_state_dict(ck["model"])
            opt.load_state_dict(ck["opt"])
        except (RuntimeError, ValueError, KeyError):
            raise UserError(f"{path}: checkpoint does not match its config.json") from None
        start, best, elapsed0 = int(ck["epoch"]), float(ck["best"]), float(ck["elapsed"])
        if start > cfg.epochs:
            raise UserError(f"{path}: already has {start} epochs, more than the {cfg.epochs} asked for")
        set_rng_state({"torch": ck["torch_rng"], "numpy": ck["numpy_rng"]})
        kept = [r for r in run.metrics() if r.get("epoch", 0) <= start]
        last = kept[-1] if kept else last
    run.write_config({"belief": asdict(cfg), "lattice": asdict(lattice.config), "kind": "ipp-belief"})
    data_path = path / "data.npz"
    if data_path.is_file():
        train, val = load_data(data_path)
    else:
        from tqdm import tqdm

        bar = tqdm(
            total=2 * len(cfg.planners), desc="record states", disable=bool(getattr(progress, "disable", True)), leave=False
        )
        train = collect_states(cfg.env, lattice, cfg.planners, cfg.seed, training_indices(cfg), cfg.every, bar)
        val_env = dataclasses.replace(cfg.env, start="center")
        val = collect_states(val_env, lattice, cfg.planners, cfg.val_seed, validation_indices(cfg), cfg.every, bar)
        bar.close()
        save_data(data_path, train, val)
    if progress is not None:
        progress.update(start)
    n = len(train)
    t0 = time.time()
    with run.metrics_log(keep_until=start if resume else None, logger="none", key="epoch") as log:
        for ep in range(start, cfg.epochs):
            model.net.train()
            order = torch.randperm(n).numpy()
            losses = []
            for s in range(0, n, cfg.batch_size):
                x, b0, y = train.tensors(np.sort(order[s : s + cfg.batch_size]))
                loss = belief_loss(b0 + model.net(x), y)
                opt.zero_grad()
                loss.backward()
                opt.step()
                losses.append(loss.item())
            model.net.eval()
            vl, vb = _val_loss(model, val)
            last = {
                "epoch": ep + 1,
                "time_s": round(elapsed0 + time.time() - t0, 1),
                "loss": float(np.mean(losses)),
                "val_logloss": vl,
                "val_logloss_posterior": vb,
            }
            if vl < best:
                best = vl
                save_belief(model, path / "belief.pt", {"epoch": ep + 1})
            log.write(last)
            rng = rng_state(tensors=True)
            run.save_checkpoint(
                {
                    "version": CHECKPOINT_VERSION,
                    "kind": "belief",
                    "epoch": ep + 1,
                    "model": model.net.state_dict(),
                    "opt": opt.state_dict(),
                    "torch_rng": rng["torch"],
                    "numpy_rng": rng["numpy"],
                    "best": best,
                    "elapsed": elapsed0 + time.time() - t0,
                    "map_size": cfg.env.map_size,
                }
            )
            if progress is not None:
                progress.update(1)
                progress.set_postfix(loss=f"{last['loss']:.4f}", val=f"{vl:.4f}", post=f"{vb:.4f}")
    return last


# ----------------------------------------------------------------------- calibration


def log_loss(p: np.ndarray, y: np.ndarray, eps: float = 1e-12) -> float:
    """Mean ``-[y log p + (1 - y) log(1 - p)]`` (nats per cell)."""
    if np.size(p) == 0:
        return float("nan")
    p = np.clip(p, eps, 1 - eps)
    return float(-np.mean(np.where(y, np.log(p), np.log1p(-p))))


def reliability(p: np.ndarray, y: np.ndarray, bins: int = 15) -> dict[str, np.ndarray]:
    """Equal-width bins of the predicted probability: per bin the count, mean prediction
    and observed frequency (NaN where empty)."""
    p, y = np.ravel(p), np.ravel(y).astype(float)
    k = np.clip((p * bins).astype(np.int64), 0, bins - 1)
    cnt = np.bincount(k, minlength=bins).astype(float)
    with np.errstate(invalid="ignore"):
        conf = np.bincount(k, weights=p, minlength=bins) / cnt
        freq = np.bincount(k, weights=y, minlength=bins) / cnt
    return {"count": cnt, "confidence": conf, "frequency": freq, "edges": np.linspace(0, 1, bins + 1)}


def expected_calibration_error(p: np.ndarray, y: np.ndarray, bins: int = 15) -> float:
    """ECE ``= sum_b (n_b / n) |freq_b - conf_b|`` over equal-width probability bins."""
    r = reliability(p, y, bins)
    ok = r["count"] > 0
    return float(np.sum(r["count"][ok] / r["count"].sum() * np.abs(r["frequency"][ok] - r["confidence"][ok])))


def fit_temperature(logits: np.ndarray, y: np.ndarray) -> float:
    """The ``T > 0`` minimising the mean log-loss of ``sigmoid(logits / T)`` (bounded
    scalar search over ``log T`` in [-3, 3])."""
    from scipy.optimize import minimize_scalar
    from scipy.special import log_expit

    z, yy = np.ravel(logits).astype(np.float64), np.ravel(y).astype(bool)

    def nll(logT: float) -> float:
        s = z / np.exp(logT)
        return float(-np.mean(np.where(yy, log_expit(s), log_expit(-s))))

    r = minimize_scalar(nll, bounds=(-3.0, 3.0), method="bounded", options={"xatol": 1e-4})
    return float(np.exp(r.x))


def logits_over(model: BeliefModel, data: BeliefData, batch: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """The model's log-odds at ``T = 1`` and the Bayesian base log-odds (float64, (k, S, S))
    over every state of ``data``."""
    import torch

    zs, bs = [], []
    with torch.no_grad():
        for s in range(0, len(data), batch):
            x, b0, _ = data.tensors(np.arange(s, min(s + batch, len(data))))
            zs.append((b0 + model.net(x)).double().numpy())
            bs.append(b0.double().numpy())
    return np.concatenate(zs), np.concatenate(bs)


def calibrate(run_dir: str | Path, bins: int = 15) -> dict:
    """Fit the temperature on the run's validation states and write ``calibration.json``
    and ``reliability.png`` to the run folder; returns the report."""
    run = Path(run_dir)
    read_belief_config(run)
    model = load_belief(run / "belief.pt", temperature=1.0)
    _, val = load_data(run / "data.npz")
    z, b = logits_over(model, val)
    y = val.targets[val.world]
    T = fit_temperature(z, y)
    q1, qT, post = sigmoid(z), sigmoid(z / T), sigmoid(b)
    sensed = val.cov
    report: dict[str, Any] = {
        "temperature": T,
        "states": int(len(val)),
        "cells": int(y.size),
        "target_rate": float(y.mean()),
        "val_seed": int(val.seeds[0, 0]),
        "val_worlds": int(len(val.seeds)),
        "bins": bins,
    }
    for name, p in (("posterior", post), ("learned", q1), ("learned_T", qT)):
        report[name] = {
            "logloss": log_loss(p, y),
            "ece": expected_calibration_error(p, y, bins),
            "brier": float(np.mean((p - y) ** 2)),
            "logloss_sensed": _finite(log_loss(p[sensed], y[sensed])),
            "logloss_unsensed": _finite(log_loss(p[~sensed], y[~sensed])),
            "reliability": {k: [None if not np.isfinite(v) else float(v) for v in a] for k, a in reliability(p, y, bins).items()},
        }
    atomic.write_json(run / "calibration.json", report)
    plot_reliability(report, run / "reliability.png")
    return report


def _finite(v: float) -> float | None:
    return v if np.isfinite(v) else None


def plot_reliability(report: dict, path: str | Path) -> Path:
    """Reliability diagram (observed frequency against mean prediction per bin) of the
    hand-written posterior and the learned belief before / after temperature, with the
    count per bin below (log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ah) = plt.subplots(2, 1, figsize=(5.5, 6.5), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax.plot([0, 1], [0, 1], ":", color="grey", lw=1, label="perfect calibration")
    names = {
        "posterior": "hand-written posterior",
        "learned": "learned, T = 1",
        "learned_T": f"learned, T = {report['temperature']:.2f}",
    }
    edges = np.asarray(report["posterior"]["reliability"]["edges"])
    centres = 0.5 * (edges[:-1] + edges[1:])
    w = (edges[1] - edges[0]) / 4
    for i, (k, lab) in enumerate(names.items()):
        r = report[k]["reliability"]
        conf = np.array([np.nan if v is None else v for v in r["confidence"]])
        freq = np.array([np.nan if v is None else v for v in r["frequency"]])
        ax.plot(conf, freq, "o-", ms=4, label=f"{lab}: ECE {report[k]['ece']:.4f}, log-loss {report[k]['logloss']:.4f}")
        ah.bar(centres + (i - 1) * w, r["count"], width=w, label=lab)
    ax.set_ylabel("observed target frequency")
    ax.set_title(f"Validation worlds ({report['val_worlds']}, seed {report['val_seed']}), {report['states']} states")
    ax.legend(fontsize=7, loc="upper left")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ah.set_yscale("log")
    ah.set_xlabel("predicted P(target) (bin)")
    ah.set_ylabel("cells")
    fig.tight_layout()
    out = atomic.save_figure(fig, path, dpi=120)
    plt.close(fig)
    return out


__all__ = [
    "BeliefConfig",
    "BeliefNetConfig",
    "BeliefModel",
    "BeliefView",
    "BeliefData",
    "belief_inputs",
    "base_logits",
    "belief_loss",
    "check_temperature",
    "collect_states",
    "calibrate",
    "expected_calibration_error",
    "fit_temperature",
    "load_belief",
    "save_belief",
    "train_belief",
    "preset",
    "preset_names",
]
