"""`vqvae`: training throughput and encode + decode throughput (frames/s) of each VQ-VAE preset, on 2 cores.

Training is timed as each preset trains: batches of frames through encoder, quantizer and decoder, or, for a
content-fitted codebook (`codebook_fit="contents"`), batches of patch contents through the autoencoder."""

from __future__ import annotations

import statistics
import time

import torch

from dynplan.data.patches import tiles
from dynplan.env.config import RoadConfig
from dynplan.env.road import generate_world
from dynplan.models.registry import WORLD_MODELS
from dynplan.models.vqvae import VQVAE
from dynplan.world import DEFAULT_WORLD


def _train_rate(model: VQVAE, optimiser: torch.optim.Optimizer, batch: torch.Tensor, steps: int) -> float:
    """Items (frames, or patch contents for a content-fitted model) per second of training steps on `batch`."""
    model.train()
    contents = model.config.codebook_fit == "contents"
    start = time.perf_counter()
    for _ in range(steps):
        if contents:
            loss = model.reconstruction_loss(model.autoencode_params(batch), batch)
        else:
            loss = sum(model(batch).losses.values())
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    return steps * len(batch) / (time.perf_counter() - start)


def _codec_rate(model: VQVAE, frames: torch.Tensor, n: int = 1024, batch: int = 256) -> float:
    model.eval()
    start = time.perf_counter()
    for i in range(0, n, batch):
        model.decode(model.encode(frames[i % 128 : i % 128 + batch]))
    return n / (time.perf_counter() - start)


def bench_vqvae(steps: int = 20, repeats: int = 3, threads: int = 2) -> dict[str, dict[str, float]]:
    """Median over `repeats` of `steps` training batches, and of encoding + decoding 1,024 frames."""
    torch.set_num_threads(threads)
    frames = torch.from_numpy(generate_world(RoadConfig(agent_speed=0.5), 0).frames.copy())
    results = {}
    for name, config in ((name, spec.tokenizer) for name, spec in WORLD_MODELS.items() if spec.world == DEFAULT_WORLD):
        model = VQVAE(config)
        optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
        unit = "patches" if config.codebook_fit == "contents" else "frames"
        if unit == "patches":  # a batch of patches, timed as a step of the contents fit
            patches = torch.from_numpy(tiles(frames.numpy(), model.patch)).reshape(-1, *model.patch)
            batch = patches[torch.randint(0, len(patches), (config.batch_size,), generator=torch.Generator())]
        else:
            batch = frames[: config.batch_size]
        _train_rate(model, optimiser, batch, 2)  # warm-up
        _codec_rate(model, frames, 256)
        train = [_train_rate(model, optimiser, batch, steps) for _ in range(repeats)]
        results[name] = {
            f"train_{unit}_per_s": round(statistics.median(train)),
            "encode_decode_frames_per_s": round(statistics.median(_codec_rate(model, frames) for _ in range(repeats))),
            "threads": threads,
            "parameters": sum(p.numel() for p in model.parameters()),
        }
    return results
