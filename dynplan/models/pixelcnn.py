"""The conditional gated PixelCNN (docs/protocol.md §2, stage 2): p(Z_t[i, j] | Z_t[< (i, j)], Z_{t−1 … t−4}).

A gated PixelCNN (van den Oord et al. 2016) over a code grid: a vertical stack that sees the rows above and a
horizontal stack that sees the codes to the left in the current row, fed from the vertical one; the first
layer is masked "A" (excludes the current position), the rest "B"; the horizontal stack is residual after the
first layer. The four previous code grids are embedded, mixed by a small non-causal convolution stack into a
spatial conditioning map, and added to the gates of every layer.

Shapes: codes (B, h, w) int64 in [0, K); context (B, 4, h, w); logits (B, K, h, w).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from dynplan.models.configs import PixelCNNConfig
from dynplan.models.head_loss import head_cross_entropy


class GatedLayer(nn.Module):
    """One gated layer: vertical and horizontal masked convolutions, both gated, plus the conditioning."""

    def __init__(self, mask: str, channels: int, kernel: int, condition_channels: int, residual: bool):
        super().__init__()
        if kernel % 2 != 1:
            raise ValueError(f"kernel must be odd, got {kernel}")
        self.mask, self.residual, half = mask, residual, kernel // 2
        # Vertical: rows i−half … i (cropped so that output row i never sees input rows below i; mask A drops row i).
        self.vertical = nn.Conv2d(channels, 2 * channels, (half + 1, kernel), padding=(half, half))
        # Horizontal: columns j−half … j of the current row (mask A drops column j).
        self.horizontal = nn.Conv2d(channels, 2 * channels, (1, half + 1), padding=(0, half))
        self.vertical_to_horizontal = nn.Conv2d(2 * channels, 2 * channels, 1)
        self.horizontal_out = nn.Conv2d(channels, channels, 1)
        self.condition = nn.Conv2d(condition_channels, 4 * channels, 1)

    @staticmethod
    def gate(x: torch.Tensor) -> torch.Tensor:
        a, b = x.chunk(2, dim=1)
        return torch.tanh(a) * torch.sigmoid(b)

    def forward(self, v: torch.Tensor, h: torch.Tensor, condition: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        rows, cols = v.shape[-2:]
        v_weight, h_weight = self.vertical.weight, self.horizontal.weight
        if self.mask == "A":
            v_weight = v_weight.clone()
            v_weight[:, :, -1] = 0.0
            h_weight = h_weight.clone()
            h_weight[:, :, :, -1] = 0.0
        v_pre = F.conv2d(v, v_weight, self.vertical.bias, padding=self.vertical.padding)[:, :, :rows]
        h_pre = F.conv2d(h, h_weight, self.horizontal.bias, padding=self.horizontal.padding)[:, :, :, :cols]
        c_v, c_h = self.condition(condition).chunk(2, dim=1)
        v_out = self.gate(v_pre + c_v)
        # The vertical features of row i depend on rows < i only, so the horizontal stack may use them at row i.
        h_out = self.horizontal_out(self.gate(self.vertical_to_horizontal(v_pre) + h_pre + c_h))
        return v_out, (h + h_out if self.residual else h_out)


@dataclass
class PriorOutput:
    """A training step's mean cross-entropy (differentiable) and the fraction of positions predicted exactly."""

    loss: torch.Tensor
    accuracy: torch.Tensor


class ConditionalPixelCNN(nn.Module):
    def __init__(self, config: PixelCNNConfig):
        super().__init__()
        self.config = c = config
        self.embed = nn.Embedding(c.codebook_size, c.channels)
        self.context_embed = nn.Embedding(c.codebook_size, c.embed_dim)
        kernel, padding = (3, c.condition_width), (1, c.condition_width // 2)
        self.conditioner = nn.Sequential(
            nn.Conv2d(c.context * c.embed_dim, c.condition_channels, kernel, padding=padding),
            nn.ReLU(),
            nn.Conv2d(c.condition_channels, c.condition_channels, kernel, padding=padding),
        )
        self.layers = nn.ModuleList(
            GatedLayer(
                "A" if i == 0 else "B",
                c.channels,
                c.first_kernel if i == 0 else c.kernel,
                c.condition_channels,
                residual=i > 0,
            )
            for i in range(c.layers)
        )
        self.head = nn.Sequential(
            nn.ReLU(), nn.Conv2d(c.channels, c.channels, 1), nn.ReLU(), nn.Conv2d(c.channels, c.codebook_size, 1)
        )

    @torch.no_grad()
    def embed_codebook(self, codebook: torch.Tensor, generator: torch.Generator | None = None) -> None:
        """Start both code embeddings from the tokenizer's codebook (K, D), standardised and mapped to each
        embedding's width by a random orthonormal matrix: codes whose patches look alike start alike, so the
        prior need not discover from scratch which of the K codes are near each other."""
        entries, D = codebook.shape
        if entries != self.config.codebook_size:
            raise ValueError(f"codebook has {entries} entries; the prior is configured for {self.config.codebook_size}")
        standard = (codebook - codebook.mean(0)) / codebook.std()
        for table in (self.embed, self.context_embed):
            width = table.weight.shape[1]
            q, _ = torch.linalg.qr(torch.randn(max(D, width), min(D, width), generator=generator))
            table.weight.copy_(standard @ (q if width <= D else q.T))

    def condition(self, context: torch.Tensor) -> torch.Tensor:
        """context (B, 4, h, w) codes → conditioning map (B, condition_channels, h, w)."""
        B, n, h, w = context.shape
        e = self.context_embed(context.long())  # (B, n, h, w, E)
        return self.conditioner(e.permute(0, 1, 4, 2, 3).reshape(B, n * self.config.embed_dim, h, w))

    def layer_conditions(self, condition: torch.Tensor) -> torch.Tensor:
        """Every layer's conditioning of its vertical and horizontal gates from the conditioning map (B, c, h, w), as
        one product: channels-last (B, h, w, layers, 2, 2 · channels) — [..., l, 0, :] is layer l's vertical, [..., l,
        1, :] its horizontal (each layer's `condition` convolution, chunked in two)."""
        weight = torch.cat([layer.condition.weight[:, :, 0, 0] for layer in self.layers])
        bias = torch.cat([layer.condition.bias for layer in self.layers])
        B, _, h, w = condition.shape
        return F.linear(condition.permute(0, 2, 3, 1), weight, bias).reshape(B, h, w, len(self.layers), 2, -1)

    def logits(self, codes: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
        """codes (B, h, w), conditioning map → logits (B, K, h, w); position (i, j) sees only codes before it."""
        return self.head[-1](self.head_input(codes, condition))

    def head_input(self, codes: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
        """What the output layer reads at every position (B, channels, h, w), each given the codes before it."""
        return self.head[:-1](self._features(self.embed(codes.long()).permute(0, 3, 1, 2), condition))

    def logits_from_embedding(self, x: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
        """As `logits`, from the embedded grid (B, channels, h, w) — differentiable, for the causality test."""
        return self.head(self._features(x, condition))

    def _features(self, x: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
        """The horizontal stack's output (B, channels, h, w), before the head."""
        v, h = x, x
        for layer in self.layers:
            v, h = layer(v, h, condition)
        return h

    def forward(self, context: torch.Tensor, target: torch.Tensor) -> PriorOutput:
        """Teacher-forced training step: cross-entropy of `target` (B, h, w) given `context` (B, 4, h, w), the
        output layer and its loss taken together a block of positions at a time (`head_loss`)."""
        target = target.long()
        hidden, out = self.head_input(target, self.condition(context)), self.head[-1]
        rows = hidden.permute(0, 2, 3, 1).reshape(-1, hidden.shape[1])
        return PriorOutput(*head_cross_entropy(rows, out.weight[:, :, 0, 0], out.bias, target.reshape(-1)))


def to_strips(grids: torch.Tensor, rows: int | None) -> torch.Tensor:
    """Code grids (B, n, h, w) → strips (B · h / rows, n, rows, w): strip s of grid b is row b · h / rows + s,
    its code rows s · rows … (s + 1) · rows − 1 (unchanged when `rows` is None)."""
    if rows is None:
        return grids
    B, n, h, w = grids.shape
    if h % rows:
        raise ValueError(f"a grid of {h} code rows does not cut into strips of {rows}")
    return grids.reshape(B, n, h // rows, rows, w).transpose(1, 2).reshape(B * (h // rows), n, rows, w)


def from_strips(strips: torch.Tensor, grids: int) -> torch.Tensor:
    """`to_strips` undone: strips (grids · S, n, rows, w) → grids (grids, n, S · rows, w)."""
    total, n, rows, w = strips.shape
    if grids < 1 or total % grids:
        raise ValueError(f"{total} strips are not the strips of {grids} grids")
    per = total // grids
    return strips.reshape(grids, per, n, rows, w).transpose(1, 2).reshape(grids, n, per * rows, w)


def draw_uniforms(B: int, h: int, w: int, temperature: float, generator: torch.Generator | None) -> torch.Tensor:
    """The uniform numbers a sampled grid uses, one per position, drawn up front (float64 (B, h, w); unused
    zeros when greedy): every generator of the next grid consumes the random stream the same way."""
    if temperature == 0.0:
        return torch.zeros(B, h, w, dtype=torch.float64)
    if temperature < 0.0:
        raise ValueError(f"temperature must be >= 0, got {temperature}")
    return torch.rand(B, h, w, generator=generator, dtype=torch.float64)


def pick(logits: torch.Tensor, temperature: float, uniforms: torch.Tensor) -> torch.Tensor:
    """Codes (B,) from logits (B, K): the argmax if `temperature` is 0, else by inverse transform of the
    softmax at `temperature` with one uniform number per row."""
    if temperature == 0.0:
        return logits.argmax(-1)
    scaled = logits.double() / temperature
    weights = torch.exp(scaled - scaled.max(-1, keepdim=True).values)
    cdf = weights.cumsum(-1)
    index = torch.searchsorted(cdf, (uniforms * cdf[:, -1]).unsqueeze(-1).contiguous(), right=True)
    return index.squeeze(-1).clamp(max=logits.shape[-1] - 1)
