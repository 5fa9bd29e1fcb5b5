"""Vector quantization of a latent grid, with one or several codebooks per position.

The latent (B, n·D, h, w) is split into n groups of D channels; group i is replaced by its nearest entry of
codebook i (K × D). Gradients pass straight through to the encoder; the commitment loss keeps the encoder near
its codes. Codebooks learn either by the codebook loss (van den Oord et al. 2017) or by exponential moving
averages (EMA, as in VQ-VAE-2), optionally restarting codes that fall out of use onto random encoder outputs.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn


@dataclass
class Quantized:
    """quantized: (B, n·D, h, w) straight-through latent; codes: (B, h, w, n) int64; loss: scalar;
    perplexity: mean over codebooks of exp(entropy of code use in the batch); counts: (n, K) code use."""

    quantized: torch.Tensor
    codes: torch.Tensor
    loss: torch.Tensor
    perplexity: torch.Tensor
    counts: torch.Tensor


#: Latent vectors per block of the nearest-code search (keeps its distance matrix in cache-sized pieces).
NEAREST_ROWS = 2048


class VectorQuantizer(nn.Module):
    def __init__(self, codebook_size: int, dim: int, n_codebooks: int = 1, commitment: float = 0.25,
                 ema: bool = True, decay: float = 0.99, restart_dead: bool = True, eps: float = 1e-5,
                 restart_onto: str = "random"):  # fmt: skip
        super().__init__()
        if restart_onto not in ("random", "worst"):
            raise ValueError(f"restart_onto must be 'random' or 'worst', got {restart_onto!r}")
        self.restart_onto = restart_onto
        self.K, self.D, self.n = codebook_size, dim, n_codebooks
        self.commitment, self.ema, self.decay, self.restart_dead, self.eps = commitment, ema, decay, restart_dead, eps
        embed = torch.randn(n_codebooks, codebook_size, dim) / dim**0.5
        if ema:
            self.register_buffer("embed", embed)
            # With restarts, zero use at the start: codes the first batches do not pick are restarted onto encoder
            # outputs. Without, one pseudo-vector per code, so an unpicked code stays where it is.
            initial_use = torch.zeros if restart_dead else torch.ones
            self.register_buffer("cluster_size", initial_use(n_codebooks, codebook_size))
            self.register_buffer("embed_sum", embed.clone())
        else:
            self.embed = nn.Parameter(embed)

    def lookup(self, codes: torch.Tensor) -> torch.Tensor:
        """codes (B, h, w, n) → latent (B, n·D, h, w)."""
        parts = [F.embedding(codes[..., i], self.embed[i]) for i in range(codes.shape[-1])]  # each (B, h, w, D)
        return torch.cat(parts, dim=-1).permute(0, 3, 1, 2).contiguous()

    def nearest(self, z: torch.Tensor) -> torch.Tensor:
        """Latent (B, n·D, h, w) → codes (B, h, w, n)."""
        B, _, h, w = z.shape
        flat = z.permute(0, 2, 3, 1).reshape(-1, self.n, self.D)  # (N, n, D)
        codes = []
        for i in range(self.n):
            e = self.embed[i]
            e_squared = e.pow(2).sum(1)
            nearest = []
            for part in flat[:, i].split(NEAREST_ROWS):  # an (N, K) distance matrix of a whole batch is ~1 GB
                # ‖z‖² − 2 z·e + ‖e‖², in place: the same floats as the plain expression, a third of the time.
                distance = part @ e.t()
                distance.mul_(-2).add_(part.pow(2).sum(1, keepdim=True)).add_(e_squared)
                nearest.append(distance.argmin(1))
            codes.append(torch.cat(nearest))
        return torch.stack(codes, dim=-1).view(B, h, w, self.n)

    def forward(self, z: torch.Tensor) -> Quantized:
        codes = self.nearest(z)
        q = self.lookup(codes)
        one_hot = F.one_hot(codes.reshape(-1, self.n), self.K).float()  # (N, n, K)
        counts = one_hot.sum(0)  # (n, K)
        if self.training and self.ema:
            self._ema_update(z, one_hot, counts, codes)
            q = self.lookup(codes)
            loss = self.commitment * F.mse_loss(z, q.detach())
        else:
            loss = F.mse_loss(q, z.detach()) + self.commitment * F.mse_loss(z, q.detach())
        probs = counts / counts.sum(1, keepdim=True)
        perplexity = torch.exp(-(probs * torch.log(probs + 1e-10)).sum(1)).mean()
        return Quantized(z + (q - z).detach(), codes, loss, perplexity, counts)

    @torch.no_grad()
    def _ema_update(self, z: torch.Tensor, one_hot: torch.Tensor, counts: torch.Tensor, codes: torch.Tensor) -> None:
        flat = z.permute(0, 2, 3, 1).reshape(-1, self.n, self.D)
        if self.restart_dead and self.restart_onto == "worst":  # each output's error under the codebook it met
            picked = torch.stack([self.embed[i][codes.reshape(-1, self.n)[:, i]] for i in range(self.n)], 1)
            error = (flat - picked).pow(2).sum(-1)  # (N, n)
        self.cluster_size.mul_(self.decay).add_(counts, alpha=1 - self.decay)
        self.embed_sum.mul_(self.decay).add_(torch.einsum("nik,nid->ikd", one_hot, flat), alpha=1 - self.decay)
        total = self.cluster_size.sum(1, keepdim=True)
        size = (self.cluster_size + self.eps) / (total + self.K * self.eps) * total
        self.embed.copy_(self.embed_sum / size.unsqueeze(-1))
        if self.restart_dead:
            # Codes whose running use fell below a hundredth of a vector per batch (never used, or unused for
            # ~500 batches) move onto encoder outputs of this batch: uniformly at random, or ("worst") drawn in
            # proportion to their squared quantisation error, as k-means++ seeds. Where one content fills most of
            # the batch (empty road), random restarts land on it again and die; error-weighted ones reach the rare
            # contents that have no code yet.
            dead = self.cluster_size < 0.01
            for i in range(self.n):
                idx = dead[i].nonzero().squeeze(1)
                if len(idx):
                    if self.restart_onto == "worst":
                        pick = torch.multinomial(error[:, i] + 1e-12, len(idx), replacement=True)
                    else:
                        pick = torch.randint(0, flat.shape[0], (len(idx),), device=z.device)
                    self.embed[i, idx] = flat[pick, i]
                    self.embed_sum[i, idx] = flat[pick, i]
                    self.cluster_size[i, idx] = 1.0
