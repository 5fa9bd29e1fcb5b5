"""`decoding`: milliseconds per frame to decode predicted code grids as a decision does, and per position to draw
sampled codes, each against its plain formulation in the same process, on one thread (as the world model decodes).

* `decode`: mid-point frames of a sampled future's grids (`VQVAE.decode`: blocks of `DECODE_ROWS` frames, a DMoL
  decoder's last layer computing only the channels a mid-point reads, the mid-point and snapping compiled) against
  the whole batch through the decoder at once with the mid-point and snapping as tensor operations
  (`mid_tensor`); and mid-point + 5 decoder samples from one pass of the decoder, as the greedy future is decoded.
* `samples` (a DMoL decoder's): the decoder samples of those frames drawn a few (sample, frame) pairs at a time in
  place (`DMoL.sample_with`) against the whole batch's noise at once (`DMoL.sample_tensor`).
* `draw`: one position's codes for a block of rows drawn by inverse transform of the float64 softmax over the
  codebook — the compiled draw the kernel and the CPU's batched generation share (`generation.draw_rows`) against
  the same rule as tensor operations (`batched._pick`, what a GPU runs).
"""

from __future__ import annotations

import numpy as np
import torch

from dynplan.bench.timing import median_seconds
from dynplan.evaluation.cases import road_models
from dynplan.models.batched import BLOCK_ROWS, _pick
from dynplan.models.device import one_thread
from dynplan.models.generation import draw_rows
from dynplan.models.world_model import load_world_model

#: Frames decoded per timed call: one lockstep step's 5 futures × 10 frames for a dozen episodes.
FRAMES = 640


def _plain_decode(tokenizer, codes: torch.Tensor) -> torch.Tensor:
    """Mid-point frames from one pass of the decoder over every frame, the mid-point as tensor operations."""
    params = tokenizer.decoder(tokenizer.quantizer.lookup(codes))
    if tokenizer.config.calibrate_decoder:
        return tokenizer.pixel.mid(params)  # a categorical mid-point: an argmax either way
    return tokenizer.pixel.mid_tensor(params)


def _bench_configuration(name: str, repeats: int, samples: int, generator: torch.Generator) -> dict[str, float]:
    model = load_world_model(model=name)
    tokenizer, K = model.tokenizer, model.prior.config.codebook_size
    codes = torch.randint(0, K, (FRAMES, *tokenizer.config.grid), generator=generator)
    if not torch.equal(torch.from_numpy(tokenizer.decode(codes.numpy())), _plain_decode(tokenizer, codes)):
        raise AssertionError(f"{name}: the decoding and its plain formulation disagree")
    plain = median_seconds(lambda: _plain_decode(tokenizer, codes), repeats) * 1e3 / FRAMES
    fast = median_seconds(lambda: tokenizer.decode(codes), repeats) * 1e3 / FRAMES

    def with_samples():
        params = tokenizer.decode_params(codes)
        tokenizer.pixel.mid(params)
        return tokenizer.pixel.sample_with(params, tokenizer.pixel.noise(params.shape, samples, generator))

    sampled = median_seconds(with_samples, repeats) * 1e3 / FRAMES
    blocks = {}
    if hasattr(tokenizer.pixel, "sample_tensor"):  # a decoder whose samples are drawn in blocks
        params = tokenizer.decode_params(codes)
        noise = tokenizer.pixel.noise(params.shape, samples, generator)
        if not torch.equal(tokenizer.pixel.sample_with(params, noise), tokenizer.pixel.sample_tensor(params, noise)):
            raise AssertionError(f"{name}: the decoder samples in blocks and the whole batch's disagree")
        whole = median_seconds(lambda: tokenizer.pixel.sample_tensor(params, noise), repeats) * 1e3 / FRAMES
        blocked = median_seconds(lambda: tokenizer.pixel.sample_with(params, noise), repeats) * 1e3 / FRAMES
        blocks = {
            f"{samples}_samples_whole_ms_per_frame": round(whole, 3),
            f"{samples}_samples_blocked_ms_per_frame": round(blocked, 3),
            "samples_ratio": round(whole / blocked, 2),
        }
    logits = torch.randn(BLOCK_ROWS, K, generator=generator) * 3.0
    uniforms = torch.rand(BLOCK_ROWS, generator=generator, dtype=torch.float64)
    work, cdf = torch.empty(BLOCK_ROWS, K, dtype=torch.float64), torch.empty(BLOCK_ROWS, K, dtype=torch.float64)
    drawn, scratch = np.empty(BLOCK_ROWS, np.int64), (np.empty((4, K)), np.empty(K))

    def compiled():
        draw_rows(logits.numpy(), 1.0, uniforms.numpy(), *scratch, drawn)

    compiled()
    if not np.array_equal(drawn, _pick(logits, 1.0, uniforms, work, cdf).numpy()):
        raise AssertionError(f"{name}: the compiled draw and the tensor draw disagree")
    tensor_draw = median_seconds(lambda: _pick(logits, 1.0, uniforms, work, cdf), repeats * 4) * 1e3
    compiled_draw = median_seconds(compiled, repeats * 4) * 1e3
    return {
        "decode_plain_ms_per_frame": round(plain, 3),
        "decode_ms_per_frame": round(fast, 3),
        "decode_ratio": round(plain / fast, 2),
        f"decode_with_{samples}_samples_ms_per_frame": round(sampled, 3),
        **blocks,
        "draw_tensor_ms_per_position": round(tensor_draw, 3),
        "draw_compiled_ms_per_position": round(compiled_draw, 3),
        "draw_ratio": round(tensor_draw / compiled_draw, 2),
        "rows": BLOCK_ROWS,
        "codes": K,
        "threads": 1,
    }


def bench_decoding(repeats: int = 5, samples: int = 5) -> dict[str, dict[str, float]]:
    """Per world-model configuration: median ms per frame (decode) and per position of `BLOCK_ROWS` rows (draw)."""
    generator = torch.Generator().manual_seed(0)
    with torch.inference_mode(), one_thread():
        return {name: _bench_configuration(name, repeats, samples, generator) for name in road_models()}
