"""`generation`: milliseconds per predicted frame — greedy code grid from the PixelCNN prior, then the VQ-VAE's
mid-point and 5 decoder samples — with naive and with cached (fast) generation, measured in one run."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import torch

from dynplan.models.generation import generate_fast, kernel_weights
from dynplan.models.pixelcnn import ConditionalPixelCNN
from dynplan.models.registry import world_model_spec
from dynplan.models.vqvae import VQVAE

TARGET_MS = 20.0


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

        for case, generate in (("naive", ConditionalPixelCNN.generate_naive), ("fast", fast)):
            _ms_per_frame(generate, prior, tokenizer, 1, samples)  # warm-up
            timings[case] = statistics.median(
                _ms_per_frame(generate, prior, tokenizer, frames, samples) for _ in range(repeats)
            )
        for case, ms in timings.items():
            results[f"{name}_{case}"] = {"ms_per_frame": round(ms, 2), "samples": samples, "threads": threads}
        results[f"{name}_fast"]["speedup_vs_naive"] = round(timings["naive"] / timings["fast"], 1)
        results[f"{name}_fast"]["target_ms"] = TARGET_MS
    return results
