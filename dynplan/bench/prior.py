"""`prior`: training throughput (windows/s) of each PixelCNN prior preset on the local CPU cores.

Random code windows at each preset's batch size, three formulations of the same loss timed in turn in one process:
the plain one (the baseline: the cross-entropy over the channel axis of (B, K, h, w) logits), the K-way
log-softmax over channels-last rows (`rows`), and the product's (`ConditionalPixelCNN.forward`: the output layer
and its cross-entropy a block of positions at a time, `dynplan.models.head_loss`).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import torch
import torch.nn.functional as F

from dynplan.models.pixelcnn import ConditionalPixelCNN
from dynplan.models.registry import world_model_spec


def _channel_axis_loss(model: ConditionalPixelCNN, context: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    return F.cross_entropy(model.logits(target, model.condition(context)), target)


def _rows_loss(model: ConditionalPixelCNN, context: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    hidden = model.head[:-1](model._features(model.embed(target).permute(0, 3, 1, 2), model.condition(context)))
    out = model.head[-1]
    logits = F.linear(hidden.permute(0, 2, 3, 1), out.weight[:, :, 0, 0], out.bias)
    return F.cross_entropy(logits.reshape(-1, logits.shape[-1]), target.reshape(-1))


def product_loss(model: ConditionalPixelCNN, context: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    return model(context, target).loss


FORMULATIONS = {"baseline": _channel_axis_loss, "rows": _rows_loss, "ours": product_loss}


def train_rate(
    model: ConditionalPixelCNN,
    loss_fn: Callable,
    optimiser: torch.optim.Optimizer,
    context: torch.Tensor,
    target: torch.Tensor,
    steps: int,
) -> float:
    start = time.perf_counter()
    for _ in range(steps):
        loss = loss_fn(model, context, target)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
    return steps * len(target) / (time.perf_counter() - start)


def training_setup(
    name: str, batch: int | None = None
) -> tuple[ConditionalPixelCNN, torch.optim.Optimizer, torch.Tensor, torch.Tensor]:
    """Preset `name`'s prior (seeded), its Adam optimiser, and random context and target codes of the preset's batch
    size (or `batch`) on the grid of the tokenizer the prior belongs to."""
    config = world_model_spec(name).prior
    torch.manual_seed(0)
    model = ConditionalPixelCNN(config).train()
    optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    h, w = world_model_spec(name).tokenizer.grid
    size = batch or config.batch_size
    context = torch.randint(0, config.codebook_size, (size, config.context, h, w))
    target = torch.randint(0, config.codebook_size, (size, h, w))
    return model, optimiser, context, target


def bench_prior(
    steps: int = 4, repeats: int = 3, threads: int = 2, presets: tuple[str, ...] = ("paper", "default")
) -> dict[str, dict[str, float]]:
    """Median over `repeats` of `steps` training batches per preset, alternating baseline and ours."""
    torch.set_num_threads(threads)
    results = {}
    for name in presets:
        model, optimiser, context, target = training_setup(name)
        rates: dict[str, list[float]] = {kind: [] for kind in FORMULATIONS}
        for fn in FORMULATIONS.values():  # warm-up
            train_rate(model, fn, optimiser, context, target, 1)
        for _ in range(repeats):
            for kind, fn in FORMULATIONS.items():
                rates[kind].append(train_rate(model, fn, optimiser, context, target, steps))
        ours, rows, baseline = (statistics.median(rates[kind]) for kind in ("ours", "rows", "baseline"))
        results[name] = {
            "train_windows_per_s": round(ours, 1),
            "rows_windows_per_s": round(rows, 1),
            "baseline_windows_per_s": round(baseline, 1),
            "speedup_vs_baseline": round(ours / baseline, 2),
            "speedup_vs_rows": round(ours / rows, 2),
            "batch": len(target),
            "threads": threads,
            "parameters": sum(p.numel() for p in model.parameters()),
        }
    return results
