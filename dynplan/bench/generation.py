"""`generation`: milliseconds per predicted frame — greedy code grid from the PixelCNN prior, then the VQ-VAE's
mid-point and 5 decoder samples — with naive and with cached (fast) generation, measured in one run; and
milliseconds per grid when many grids are generated together, by the compiled kernel (grid after grid) and by the
batched generation (matrix–matrix over the batch), with the committed priors and their occupancy tables."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from functools import partial

import torch

from dynplan.bench.reference import generate_naive
from dynplan.models.batched import batched_weights, generate_batched
from dynplan.models.generation import generate_fast, kernel_weights
from dynplan.models.pixelcnn import ConditionalPixelCNN, draw_uniforms
from dynplan.models.registry import world_model_spec
from dynplan.models.vqvae import VQVAE

TARGET_MS = 20.0
#: Batch sizes of the batched case: one lockstep step's grids for a handful of episodes, and for 100.
BATCHES = (8, 32, 100)


def _ms_per_frame(generate: Callable, prior: ConditionalPixelCNN, tokenizer: VQVAE, frames: int, samples: int) -> float:
    h, w = tokenizer.config.grid
    context = torch.randint(0, prior.config.codebook_size, (1, 4, h, w))
    start = time.perf_counter()
    for _ in range(frames):
        codes = generate(prior, context)
        tokenizer.decode_with_samples(codes, samples)
        context = torch.cat([context[:, 1:], codes[:, None]], dim=1)  # chain: the prediction joins the context
    return (time.perf_counter() - start) * 1e3 / frames


def bench_generation(frames: int = 5, repeats: int = 3, samples: int = 5, threads: int = 2) -> dict:
    """Per model configuration: median ms per predicted frame, naive and fast, and their ratio."""
    torch.set_num_threads(threads)
    results = {}
    for name in ("paper", "default"):
        torch.manual_seed(0)
        spec = world_model_spec(name)
        prior, tokenizer = ConditionalPixelCNN(spec.prior).eval(), VQVAE(spec.tokenizer).eval()
        timings = {}
        kernel = kernel_weights(prior)  # laid out once, as the world model does

        def fast(model, context, kernel=kernel):
            return generate_fast(model, context, weights=kernel)

        for case, generate in (("naive", generate_naive), ("fast", fast)):
            _ms_per_frame(generate, prior, tokenizer, 1, samples)  # warm-up
            timings[case] = statistics.median(
                _ms_per_frame(generate, prior, tokenizer, frames, samples) for _ in range(repeats)
            )
        for case, ms in timings.items():
            results[f"{name}_{case}"] = {"ms_per_frame": round(ms, 2), "samples": samples, "threads": threads}
        results[f"{name}_fast"]["speedup_vs_naive"] = round(timings["naive"] / timings["fast"], 1)
        results[f"{name}_fast"]["target_ms"] = TARGET_MS
    return results | bench_batched(threads=threads)


def _median_ms_per_grid(generate: Callable[[], object], grids: int, repeats: int) -> float:
    generate()  # warm-up: compilation and the matrix library's first calls at this shape
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        generate()
        times.append((time.perf_counter() - start) * 1e3 / grids)
    return statistics.median(times)


def bench_batched(batches: tuple[int, ...] = BATCHES, repeats: int = 5, threads: int = 2) -> dict:
    """Per committed world model, batch size and kind of grid: median ms per grid by the kernel and by the batched
    generation, and their ratio. `greedy`: the argmax grid, with the configuration's occupancy table where it has
    one (the chain every learned decision makes); `sampled`: codes drawn at temperature 1 (a sampled future's)."""
    from dynplan.models.world_model import load_world_model

    torch.set_num_threads(threads)
    results = {}
    for name in ("paper", "default"):
        model = load_world_model(model=name)
        prior, (h, w) = model.prior, model.tokenizer.config.grid
        table = model.code_obstacles() if model.caution.occupancy else None
        lookup = None if table is None else table.numpy()
        kernel, batched = kernel_weights(prior), batched_weights(prior)
        for B in batches:
            draws = torch.Generator().manual_seed(B)
            context = torch.randint(0, prior.config.codebook_size, (B, 4, h, w), generator=draws)
            uniforms = draw_uniforms(B, h, w, 1.0, draws)
            kinds = {
                "greedy": ({"table": lookup}, {"table": table}),
                "sampled": ({"temperature": 1.0, "uniforms": uniforms},) * 2,
            }
            for kind, (for_kernel, for_batch) in kinds.items():
                by_kernel = _median_ms_per_grid(
                    partial(generate_fast, prior, context, weights=kernel, **for_kernel), B, repeats
                )
                by_batch = _median_ms_per_grid(
                    partial(generate_batched, prior, context, weights=batched, **for_batch), B, repeats
                )
                results[f"{name}_{kind}_batch{B}"] = {
                    "kernel_ms_per_grid": round(by_kernel, 2),
                    "batched_ms_per_grid": round(by_batch, 2),
                    "speedup_vs_kernel": round(by_kernel / by_batch, 2),
                    "occupancy_table": kind == "greedy" and table is not None,
                    "threads": threads,
                }
    return results
