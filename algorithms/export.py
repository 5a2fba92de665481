"""A run's policy as one self-contained file for onboard use: TorchScript or ONNX (``aerohrl export-policy``).

The exported graph is the whole action path of :meth:`aerohrl.algorithms.base.Algorithm.act`
plus the evaluation's clip (:class:`aerohrl.envs.rollout.PolicyFn`)::

    x = ([v, R, w, p_g - p, v_g, R_g] (+ p in a world with obstacles) - in_mean) / in_std
    u = policy(x)                         in [-1, 1]^4 (the EMA weights when the run kept them)
    a = clip(act_center + act_half u, act_center - act_half, act_center + act_half)

Inputs ``state`` (B, 18) ``[p (m), v (m/s), R (row-major body-to-world), w (rad/s)]``
(B, 21 ``+ [d_hat (m/s^2)]`` for a policy that observes its disturbance observer's estimate) and
``goal`` (B, 15) ``[p, v, R]``, float32, world frame z up; output ``action`` (B, 4) CTBR
``[c (m/s^2, mass-normalised collective thrust), wx, wy, wz (rad/s)]``. The same layout,
the normalisation constants and the run's identity are written into the file
(:func:`metadata`: TorchScript ``_extra_files["aerohrl.json"]``, ONNX ``metadata_props``).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from aerohrl import atomic, task
from aerohrl.algorithms.networks import fourier_inputs
from aerohrl.errors import UserError

FORMATS = ("torchscript", "onnx")
META_KEY = "aerohrl.json"


class ExportedPolicy(nn.Module):
    """``(state (B, 18), goal (B, 15)) -> action (B, 4)``: the normaliser, the policy network and the clip."""

    in_mean: torch.Tensor
    in_std: torch.Tensor
    act_center: torch.Tensor
    act_half: torch.Tensor

    def __init__(self, algo: Any):
        super().__init__()
        n = algo.normalizer
        self.net = algo.policy_ema.module if getattr(algo, "policy_ema", None) is not None else algo.policy_net()
        self.absolute_position = bool(n.absolute_position)
        self.state_width = int(n.state_width)
        self.register_buffer("in_mean", n.in_mean.detach().clone().float())
        self.register_buffer("in_std", n.in_std.detach().clone().float())
        self.register_buffer("act_center", n.act_center.detach().clone().float())
        self.register_buffer("act_half", n.act_half.detach().clone().float())
        self.pos_octaves = n.pos_octaves
        self.register_buffer("pos_freq", n.pos_freq.detach().clone().float() if n.pos_octaves else torch.zeros(0))

    def forward(self, state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """The action (B, 4) in physical units for states (B, 18) and goals (B, 15)."""
        parts = [state[:, 3:18], goal[:, 0:3] - state[:, 0:3], goal[:, 3:15]]
        if self.absolute_position:
            parts.append(state[:, 0:3])
        if self.state_width > task.STATE_DIM:  # the disturbance estimate
            parts.append(state[:, task.STATE_DIM : self.state_width])
        raw = torch.cat(parts, 1)
        x = (raw - self.in_mean) / self.in_std
        if self.pos_octaves:
            x = torch.cat([x, fourier_inputs(raw, self.in_mean, self.in_std, self.pos_freq)], 1)
        a = self.act_center + self.act_half * self.net(x)
        return torch.maximum(torch.minimum(a, self.act_center + self.act_half), self.act_center - self.act_half)


def metadata(algo: Any, ck: dict, run_path: Path) -> dict:
    """What an onboard implementer needs beside the graph: layout, units, normalisation, provenance."""
    n = algo.normalizer
    return {
        "format": "aerohrl-policy/1",
        "inputs": {
            "state": {
                "shape": ["B", n.state_width],
                "names": list(task.STATE_NAMES) + (["d_x", "d_y", "d_z"] if n.dist_dim else []),
            },
            "goal": {"shape": ["B", task.GOAL_DIM], "names": list(task.GOAL_NAMES)},
        },
        "output": {"action": {"shape": ["B", task.ACTION_DIM], "names": ["c", "wx", "wy", "wz"]}},
        "units": "p m, v m/s, R body-to-world row-major, w rad/s (body); c m/s^2 (mass-normalised collective thrust)",
        "frame": "world frame, z up, gravity -9.81 m/s^2 along z",
        **(
            {
                "disturbance_observer": {
                    "tau_s": n.disturbance_tau,
                    "gains": "l1 = 2 / tau, l2 = 1 / tau^2 (both error poles at -1 / tau)",
                    "update": "each control step, after the command (c, w) from the observed state with velocity v and "
                    "body z-axis b3: e = v - v_hat; v_hat += dt (c b3 - 9.81 e3 + d_hat + l1 e); d_hat += dt l2 e; "
                    "d_hat and v_hat start at 0 and at the first observed v",
                }
            }
            if n.dist_dim
            else {}
        ),
        "network_input": "([v, R, w, p_g - p, v_g, R_g]"
        + (" + [p]" if n.absolute_position else "")
        + (" + [d_hat]" if n.dist_dim else "")
        + " - in_mean) / in_std"
        + (
            ", then [sin(f p_n), cos(f p_n)] for p_n the standardised p and p_g (by in_mean/in_std of p), f = pos_freq"
            if n.pos_octaves
            else ""
        ),
        "normalisation": {
            "in_mean": n.in_mean.tolist(),
            "in_std": n.in_std.tolist(),
            "act_center": n.act_center.tolist(),
            "act_half": n.act_half.tolist(),
            **({"pos_freq": n.pos_freq.tolist()} if n.pos_octaves else {}),
        },
        "action_clip": "[act_center - act_half, act_center + act_half]",
        "control_rate_hz": 100,
        "run": str(run_path),
        "algorithm": type(algo).__name__,
        "checkpoint_step": int(ck.get("step", -1)),
    }


def export_policy(run: str | Path, fmt: str, out: str | Path) -> tuple[Path, dict]:
    """Write the newest checkpoint's policy of ``run`` to ``out`` as ``fmt`` (:data:`FORMATS`); returns the path and metadata."""
    from aerohrl.algorithms.base import load_policy
    from aerohrl.algorithms.run import Run

    if fmt not in FORMATS:
        raise UserError(f"--format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    r = Run.open(run, kind="train")
    ckpts = r.checkpoints()
    if not ckpts:
        raise UserError(f"run {r.path} has no checkpoint")
    algo, ck = load_policy(ckpts[-1], "cpu", r)
    algo.eval()
    model = ExportedPolicy(algo).eval()
    meta = metadata(algo, ck, r.path)
    example = (torch.zeros(1, algo.normalizer.state_width), torch.zeros(1, task.GOAL_DIM))
    out = Path(out)
    with torch.no_grad():
        if fmt == "torchscript":
            traced = torch.jit.trace(model, example)
            with atomic.atomic_path(out) as tmp:
                torch.jit.save(traced, str(tmp), _extra_files={META_KEY: json.dumps(meta)})
        else:
            _write_onnx(model, example, meta, out)
    return out, meta


def _write_onnx(model: nn.Module, example: tuple, meta: dict, out: Path) -> None:
    try:
        import onnx
    except ImportError:
        raise UserError("--format onnx needs the onnx package: pip install 'aerohrl[export]'") from None
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "policy.onnx"
        _onnx_export(model, example, raw)
        proto = onnx.load(str(raw))
    entry = proto.metadata_props.add()
    entry.key, entry.value = META_KEY, json.dumps(meta)
    atomic.write_bytes(out, proto.SerializeToString())


def _onnx_export(model: nn.Module, example: tuple, path: Path) -> None:
    torch.onnx.export(
        model,
        example,
        str(path),
        input_names=["state", "goal"],
        output_names=["action"],
        dynamic_axes={"state": {0: "B"}, "goal": {0: "B"}, "action": {0: "B"}},
        opset_version=17,
        dynamo=False,
    )


def load_exported(path: str | Path) -> tuple[Any, dict]:
    """``(predict, metadata)`` of an exported file: ``predict(states (B, 18), goals (B, 15)) -> (B, 4)`` NumPy float32."""
    path = Path(path)
    if path.suffix == ".onnx":
        import onnx
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = opts.inter_op_num_threads = 1
        sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        meta = json.loads({p.key: p.value for p in onnx.load(str(path)).metadata_props}[META_KEY])

        def predict_onnx(s: np.ndarray, g: np.ndarray) -> np.ndarray:
            return sess.run(["action"], {"state": np.asarray(s, np.float32), "goal": np.asarray(g, np.float32)})[0]

        return predict_onnx, meta
    files = {META_KEY: ""}
    module = torch.jit.load(str(path), _extra_files=files)

    @torch.no_grad()
    def predict_ts(s: np.ndarray, g: np.ndarray) -> np.ndarray:
        return module(torch.as_tensor(np.asarray(s, np.float32)), torch.as_tensor(np.asarray(g, np.float32))).numpy()

    return predict_ts, json.loads(files[META_KEY])


def single_sample_latency(predict: Any, repeats: int = 2000, state_width: int = task.STATE_DIM) -> float:
    """Median seconds of one ``predict`` call on a single state (``state_width`` wide: the
    exported file's metadata ``inputs.state.shape``) and goal (the onboard case)."""
    s, g = np.zeros((1, state_width), np.float32), np.zeros((1, task.GOAL_DIM), np.float32)
    s[0, 6] = s[0, 10] = s[0, 14] = 1.0
    g[0, 6] = g[0, 10] = g[0, 14] = 1.0
    for _ in range(50):
        predict(s, g)
    times = np.empty(repeats)
    for i in range(repeats):
        t0 = time.perf_counter()
        predict(s, g)
        times[i] = time.perf_counter() - t0
    return float(np.median(times))
