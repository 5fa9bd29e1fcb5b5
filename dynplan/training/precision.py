"""The arithmetic a world-model stage trains in: float32, or bfloat16 under `torch.autocast` where the device has
bfloat16 instructions (weights, optimiser and validation stay float32; only the steps' forward passes are cast).

A CPU without them (AVX2, or AVX-512 without its BF16 extension) would emulate bfloat16 more slowly than float32,
so asking for it there is refused, naming what the CPU has: float32 trains there.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:
    import torch

#: The arithmetic of a stage's training steps. (torch is imported where it is used: a budget names a precision
#: without it.)
Precision = Literal["float32", "bfloat16"]

#: CPU flags (Linux /proc/cpuinfo) of native bfloat16 arithmetic.
BF16_FLAGS = ("avx512_bf16", "amx_bf16")


def _cpu_flags() -> set[str] | None:
    """The CPU's feature flags, or None where /proc/cpuinfo does not list them."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return None
    for line in text.splitlines():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return None


def bfloat16_missing(device: torch.device) -> str | None:
    """None when `device` has bfloat16 arithmetic of its own; else why it has not."""
    import torch

    if device.type == "cuda":
        return None if torch.cuda.is_bf16_supported() else f"{torch.cuda.get_device_name(device)} has no bfloat16"
    if device.type != "cpu":
        return f"bfloat16 training on {device.type} is not supported by dynplan"
    flags = _cpu_flags()
    native = (
        any(flag in flags for flag in BF16_FLAGS) if flags is not None else torch.ops.mkldnn._is_mkldnn_bf16_supported()
    )
    if native:
        return None
    capability = torch.backends.cpu.get_cpu_capability()
    return f"this CPU has no bfloat16 instructions ({' or '.join(BF16_FLAGS)}; torch sees {capability})"


def autocast(device: torch.device, precision: Precision) -> contextlib.AbstractContextManager:
    """The context a training step's forward pass runs in: bfloat16 autocast, or nothing for float32."""
    if precision == "float32":
        return contextlib.nullcontext()
    import torch

    return torch.autocast(device.type, dtype=torch.bfloat16)
