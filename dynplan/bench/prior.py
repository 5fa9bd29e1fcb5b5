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
    hidden, out = model.head_input(target, model.condition(context)), model.head[-1]
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


def alternated_rates(
    setup: tuple[ConditionalPixelCNN, torch.optim.Optimizer, torch.Tensor, torch.Tensor],
    losses: dict[str, Callable],
    steps: int,
    repeats: int,
) -> dict[str, float]:
    """Each loss's median windows/s over `repeats` rounds of `steps` training batches, the losses in turn within a
    round (after one warm-up batch each), on `setup`'s model, optimiser, context and target."""
    model, optimiser, context, target = setup
    for loss in losses.values():
        train_rate(model, loss, optimiser, context, target, 1)
    rates: dict[str, list[float]] = {kind: [] for kind in losses}
    for _ in range(repeats):
        for kind, loss in losses.items():
            rates[kind].append(train_rate(model, loss, optimiser, context, target, steps))
    return {kind: statistics.median(values) for kind, values in rates.items()}


def bench_prior(
    steps: int = 4, repeats: int = 3, threads: int = 2, presets: tuple[str, ...] = ("paper", "default")
) -> dict[str, dict[str, float]]:
    """Median over `repeats` of `steps` training batches per preset, the three formulations alternated."""
    torch.set_num_threads(threads)
    results = {}
    for name in presets:
        model, optimiser, context, target = training_setup(name)
        rates = alternated_rates((model, optimiser, context, target), FORMULATIONS, steps, repeats)
        ours, rows, baseline = rates["ours"], rates["rows"], rates["baseline"]
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
