"""What the machine can do: the CPU's vector extensions and whether a device runs bf16 natively.

Training under bf16 autocast halves the cost of the matrix products only where the
hardware multiplies bf16 itself: CPUs with AVX512-BF16 or AMX, and GPUs with bf16
tensor cores. Elsewhere oneDNN emulates bf16 (or falls back to reference kernels on
AVX2-only CPUs), and autocast makes an update many times slower than float32. So the
``auto`` precision is bf16 where :func:`native_bf16` says so and float32 otherwise.

:func:`describe_cpu` reads ``/proc/cpuinfo`` and needs no torch, so the benches that do
not load torch print the same line as those that do.
"""

from __future__ import annotations

import os
import platform
from functools import lru_cache
from typing import Any

AMP_MODES = ("auto", "none", "bf16")  # auto: bf16 where native_bf16(device), else none (float32)
_BF16_FLAGS = ("avx512_bf16", "amx_bf16")


@lru_cache(maxsize=1)
def cpu_flags() -> frozenset[str]:
    """The CPU's feature flags from ``/proc/cpuinfo`` (empty where there is none)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith(("flags", "Features")):
                    return frozenset(line.split(":", 1)[1].split())
    except OSError:
        pass
    return frozenset()


@lru_cache(maxsize=1)
def cpu_model() -> str:
    """The CPU's model name, or the platform's processor string."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def describe_cpu() -> str:
    """One line for a bench's header: model, cores, widest vector extension, bf16 support."""
    flags = cpu_flags()
    vec = next(
        (name for flag, name in (("avx512f", "AVX512"), ("avx2", "AVX2"), ("sve", "SVE"), ("asimd", "NEON")) if flag in flags),
        "no wide vectors",
    )
    bf16 = [f for f in _BF16_FLAGS if f in flags]
    native = f"native bf16 ({', '.join(bf16)})" if bf16 else "no native bf16"
    return f"{cpu_model()}, {os.cpu_count()} cores, {vec}, {native}"


def native_bf16(device: Any = "cpu") -> bool:
    """Whether ``device`` multiplies bf16 matrices in hardware.

    CUDA: ``torch.cuda.is_bf16_supported(including_emulation=False)`` (Ampere and newer).
    CPU: oneDNN's bf16 path is enabled (``torch.ops.mkldnn._is_mkldnn_bf16_supported()``,
    which honours ``ONEDNN_MAX_CPU_ISA``), torch dispatches above AVX2
    (``torch.backends.cpu.get_cpu_capability()``, which honours ``ATEN_CPU_CAPABILITY``)
    and the CPU has AVX512-BF16 or AMX (torch's own cpuinfo queries). Any other device: False.
    """
    import torch

    dev = torch.device(device)
    if dev.type == "cuda":
        return bool(torch.cuda.is_available() and torch.cuda.is_bf16_supported(including_emulation=False))
    if dev.type != "cpu":
        return False
    try:
        if not torch.ops.mkldnn._is_mkldnn_bf16_supported():
            return False
        if torch.backends.cpu.get_cpu_capability() in ("DEFAULT", "NO AVX", "AVX2"):
            return False
        return bool(torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported())
    except (AttributeError, RuntimeError):  # a torch build without these queries: be safe, float32
        return False


def resolve_amp(amp: str, device: Any = "cpu") -> tuple[str, str]:
    """``(mode, why)``: the precision to train in (``none`` or ``bf16``) for the requested
    ``amp`` on ``device``, and a short reason to print. ``auto`` becomes ``bf16`` where
    :func:`native_bf16`, else ``none``; the other modes are kept as asked."""
    if amp not in AMP_MODES:
        raise ValueError(f"unknown amp mode {amp!r} (choose from {', '.join(AMP_MODES)})")
    if amp != "auto":
        return amp, "as asked"
    if native_bf16(device):
        return "bf16", f"auto: {device} runs bf16 natively"
    return "none", f"auto: {device} has no native bf16, float32 is faster there"


__all__ = ["AMP_MODES", "cpu_flags", "cpu_model", "describe_cpu", "native_bf16", "resolve_amp"]
