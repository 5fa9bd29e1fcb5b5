"""The slow reference generation: the prior run whole once per position. The compiled kernel
(`dynplan.models.generation`) and the batched generation (`dynplan.models.batched`) must give its codes exactly —
the tests compare them with it — and `python -m dynplan.bench generation` measures how much faster they are."""

from __future__ import annotations

import torch

from dynplan.models.pixelcnn import ConditionalPixelCNN, draw_uniforms, pick


@torch.inference_mode()
def generate_naive(
    model: ConditionalPixelCNN,
    context: torch.Tensor,
    temperature: float = 0.0,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """The next code grid, one full forward pass per position: greedy (argmax) when `temperature` is 0, else
    sampled at that temperature with numbers drawn up front (`draw_uniforms`). context (B, 4, h, w) → codes
    (B, h, w)."""
    B, _, h, w = context.shape
    condition = model.condition(context)
    uniforms = draw_uniforms(B, h, w, temperature, generator)
    codes = torch.zeros(B, h, w, dtype=torch.long)
    for i in range(h):
        for j in range(w):
            logits = model.logits(codes, condition)[:, :, i, j]
            codes[:, i, j] = pick(logits, temperature, uniforms[:, i, j])
    return codes
