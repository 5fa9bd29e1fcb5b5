"""`precision`: the default prior's training throughput (windows/s) in float32 and under bfloat16 autocast, rounds
alternated in one process, on the local CPU cores.

What `python -m flows.train pixelcnn --precision bfloat16` would gain here. A CPU without bfloat16 instructions
(`dynplan.training.precision.bfloat16_missing`) runs the bfloat16 rounds emulated, and the case says so: there
training refuses bfloat16 and float32 stays.
"""

from __future__ import annotations

import torch

from dynplan.bench.prior import alternated_rates, product_loss, training_setup
from dynplan.models.pixelcnn import ConditionalPixelCNN
from dynplan.training.precision import autocast, bfloat16_missing

CPU = torch.device("cpu")


def _bfloat16_loss(model: ConditionalPixelCNN, context: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    with autocast(CPU, "bfloat16"):
        return model(context, target).loss


def bench_precision(
    steps: int = 4,
    repeats: int = 5,
    threads: int = 2,
    presets: tuple[str, ...] = ("default",),
    batch: int | None = None,
) -> dict[str, dict[str, float | str]]:
    """Median over `repeats` alternated rounds of `steps` training batches (of the preset's size, or `batch`) in each
    precision, per preset's prior."""
    torch.set_num_threads(threads)
    missing = bfloat16_missing(CPU)
    results: dict[str, dict[str, float | str]] = {}
    for name in presets:
        setup = training_setup(name, batch)
        losses = {"float32": product_loss, "bfloat16": _bfloat16_loss}
        rates = alternated_rates(setup, losses, steps, repeats)
        float32, bfloat16 = rates["float32"], rates["bfloat16"]
        results[f"prior {name}"] = {
            "float32_windows_per_s": round(float32, 1),
            "bfloat16_windows_per_s": round(bfloat16, 1),
            "bfloat16_speedup": round(bfloat16 / float32, 2),
            "bfloat16_native": "yes" if missing is None else f"no: {missing}",
            "batch": len(setup[3]),
            "threads": threads,
            "rounds": repeats,
        }
    return results
