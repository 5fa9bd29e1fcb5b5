"""Vector quantization of a latent grid with one codebook (van den Oord et al. 2017).

Each latent vector (D channels at one grid position) is replaced by its nearest entry of the codebook (K × D).
Gradients pass straight through to the encoder; the codebook loss moves the codes towards the encoder's outputs
and the commitment loss keeps the encoder near its codes.

Shapes: latent (B, D, h, w); codes (B, h, w) int64 in [0, K).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn


@dataclass
class Quantized:
    """quantized: (B, D, h, w) straight-through latent; codes: (B, h, w) int64; loss: scalar; perplexity:
    exp(entropy of code use in the batch); counts: (K,) code use."""

    quantized: torch.Tensor
    codes: torch.Tensor
    loss: torch.Tensor
    perplexity: torch.Tensor
    counts: torch.Tensor


#: Latent vectors per block of the nearest-code search (keeps its distance matrix in cache-sized pieces).
NEAREST_ROWS = 2048


class VectorQuantizer(nn.Module):
    def __init__(self, codebook_size: int, dim: int, commitment: float = 0.25):
        super().__init__()
        self.K, self.D, self.commitment = codebook_size, dim, commitment
        self.embed = nn.Parameter(torch.randn(codebook_size, dim) / dim**0.5)

    def lookup(self, codes: torch.Tensor) -> torch.Tensor:
        """codes (B, h, w) → latent (B, D, h, w)."""
        return F.embedding(codes, self.embed).permute(0, 3, 1, 2).contiguous()

    def nearest(self, z: torch.Tensor) -> torch.Tensor:
        """Latent (B, D, h, w) → codes (B, h, w)."""
        B, _, h, w = z.shape
        flat = z.permute(0, 2, 3, 1).reshape(-1, self.D)  # (N, D)
        e = self.embed
        e_squared = e.pow(2).sum(1)
        nearest = []
        for part in flat.split(NEAREST_ROWS):  # an (N, K) distance matrix of a whole batch is ~1 GB
            # ‖z‖² − 2 z·e + ‖e‖², in place: the same floats as the plain expression, a third of the time.
            distance = part @ e.t()
            distance.mul_(-2).add_(part.pow(2).sum(1, keepdim=True)).add_(e_squared)
            nearest.append(distance.argmin(1))
        return torch.cat(nearest).view(B, h, w)

    def forward(self, z: torch.Tensor) -> Quantized:
        codes = self.nearest(z)
        q = self.lookup(codes)
        counts = torch.bincount(codes.reshape(-1), minlength=self.K).float()  # (K,)
        loss = F.mse_loss(q, z.detach()) + self.commitment * F.mse_loss(z, q.detach())
        probs = counts / counts.sum()
        perplexity = torch.exp(-(probs * torch.log(probs + 1e-10)).sum())
        return Quantized(z + (q - z).detach(), codes, loss, perplexity, counts)
