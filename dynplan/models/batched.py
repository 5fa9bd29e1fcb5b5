"""Batched autoregressive generation for the conditional gated PixelCNN: many grids at once, position by position.

`generation.generate_fast` runs one compiled kernel per grid of a batch: every product is a matrix–vector
product, and a batch costs its size times one grid. Here the batch is the matrix: at each position, each layer's
horizontal stack and the head are one matrix–matrix product over all B grids (B × 32 · 32 × 4096 for the
default prior's head); each layer's vertical stack is one product per row over the B · w windows; the softmax
against the occupancy table is one vectorised pass and one product over (B, K). Per-operator overhead is paid
once per position, not per grid, so the cost per grid falls with B until the arithmetic dominates; and the same
code runs on a GPU (`device`).

The caching is `generate_fast`'s (as in Fast PixelCNN++): the conditioning map once per grid (its projection
into every layer's gates one product per row, which stays in the caches), the vertical stacks once per row, the
horizontal stacks and the head once per position. The arithmetic is the network's own; the order of float sums is
the matrix library's, so a choice can differ from the kernel's where two codes' logits tie to rounding (how often
is measured in docs/design.md §4).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from dynplan.models.generation import draw_rows
from dynplan.models.pixelcnn import ConditionalPixelCNN, draw_uniforms

#: The most grids generated together: larger batches run in blocks of this many rows. On a 2-core CPU the cost per
#: grid of the default prior falls to 128 rows and rises beyond (the working set leaves the caches).
BLOCK_ROWS = 128


@dataclass(frozen=True)
class BatchedWeights:
    """A prior's weights laid out for `generate_batched` on one device, built once per model by
    `batched_weights`: per layer, the masked vertical kernel (2C, C, rows, cols), the horizontal taps as one matrix
    ((half + 1) · C, 2C) over the channels-last window of columns j − half … j, the 1 × 1 convolutions as
    (C_in, C_out) matrices; the head's two matrices, the code embedding (K, C) and every layer's conditioning
    convolution as one matrix."""

    v_weight: tuple[torch.Tensor, ...]
    v_bias: tuple[torch.Tensor, ...]
    v_half: tuple[int, ...]
    v2h_weight: tuple[torch.Tensor, ...]
    h_weight: tuple[torch.Tensor, ...]
    out_weight: tuple[torch.Tensor, ...]
    out_bias: tuple[torch.Tensor, ...]
    residual: tuple[bool, ...]
    w1: torch.Tensor
    b1: torch.Tensor
    w2: torch.Tensor
    b2: torch.Tensor
    embed: torch.Tensor
    cond_weight: torch.Tensor  # (c, L · 4C): every layer's conditioning convolution, as `layer_conditions` lays it
    cond_bias: torch.Tensor  # (L · 4C,): their biases; the horizontal halves also carry both biases of the
    # horizontal pre-activation (the vertical-to-horizontal link's and the horizontal stack's), added at every position
    descending: torch.Tensor  # K, K − 1, …, 1: ranks codes for `_first_argmax`
    device: torch.device


@torch.inference_mode()
def batched_weights(model: ConditionalPixelCNN, device: str | torch.device = "cpu") -> BatchedWeights:
    """`model`'s weights laid out for `generate_batched` on `device`, as they are now."""
    device = torch.device(device)

    def on(t: torch.Tensor) -> torch.Tensor:
        return t.detach().to(device=device, dtype=torch.float32, copy=True).contiguous()  # never the parameter itself

    v_weight, v_half, h_weight = [], [], []
    for layer in model.layers:
        v, h = layer.vertical.weight.clone(), layer.horizontal.weight.clone()
        if layer.mask == "A":  # the output's own row (vertical) and column (horizontal) are not seen
            v[:, :, -1] = 0.0
            h[:, :, :, -1] = 0.0
        # (2C, C, rows, cols) → rows ordered (row, column, channel), as a channels-last window flattens
        v_weight.append(on(v.permute(2, 3, 1, 0).reshape(-1, v.shape[0])))
        v_half.append(v.shape[3] // 2)
        # (2C, C, 1, half + 1) → rows ordered (column, channel), as a channels-last window flattens
        h_weight.append(on(h[:, :, 0, :].permute(2, 1, 0).reshape(-1, h.shape[0])))
    layers, head = list(model.layers), list(model.head)
    C = model.config.channels
    cond_bias = torch.cat([layer.condition.bias for layer in layers]).reshape(len(layers), 2, 2 * C).clone()
    cond_bias[:, 1] += torch.stack([layer.vertical_to_horizontal.bias + layer.horizontal.bias for layer in layers])
    return BatchedWeights(
        v_weight=tuple(v_weight),
        v_bias=tuple(on(layer.vertical.bias) for layer in layers),
        v_half=tuple(v_half),
        v2h_weight=tuple(on(layer.vertical_to_horizontal.weight[:, :, 0, 0].T) for layer in layers),
        h_weight=tuple(h_weight),
        out_weight=tuple(on(layer.horizontal_out.weight[:, :, 0, 0].T) for layer in layers),
        out_bias=tuple(on(layer.horizontal_out.bias) for layer in layers),
        residual=tuple(bool(layer.residual) for layer in layers),
        w1=on(head[1].weight[:, :, 0, 0].T),
        b1=on(head[1].bias),
        w2=on(head[3].weight[:, :, 0, 0].T),
        b2=on(head[3].bias),
        embed=on(model.embed.weight),
        cond_weight=on(torch.cat([layer.condition.weight[:, :, 0, 0] for layer in layers]).T),
        cond_bias=on(cond_bias.reshape(-1)),
        descending=torch.arange(model.config.codebook_size, 0, -1, dtype=torch.float32, device=device),
        device=device,
    )


def _first_argmax(logits: torch.Tensor, descending: torch.Tensor, work: torch.Tensor) -> torch.Tensor:
    """`logits.argmax(-1)` (B,) — the first maximum — from vectorised float operations only: sign(x − max) + 1 is
    1 exactly at the maxima and 0 elsewhere, and ranking by `descending` (K … 1) finds the first. A CPU reduces
    floats several times faster than it finds an index. `work` (B, K) float32 holds the intermediates."""
    torch.sub(logits, logits.amax(-1, keepdim=True), out=work).sign_()
    return (len(descending) - torch.addcmul(descending, work, descending, out=work).amax(-1)).long()


def _pick(
    logits: torch.Tensor, temperature: float, uniforms: torch.Tensor, work: torch.Tensor, cdf: torch.Tensor
) -> torch.Tensor:
    """Codes (B,) from logits (B, K) by inverse transform of the softmax at `temperature` > 0 (in float64) with
    one uniform number per row — `pixelcnn.pick`'s rule, with its numbers: the maximum is taken in float32 (division
    by `temperature` > 0 is monotone, so max(x / T) is max(x) / T) and x / 1.0 is x. `work` and `cdf` (B, K)
    float64 receive the weights and their cumulative sums: a buffer per generation, not two allocations per
    position."""
    top = logits.amax(-1, keepdim=True).double()
    work.copy_(logits)
    if temperature != 1.0:
        work /= temperature
        top /= temperature
    torch.cumsum(work.sub_(top).exp_(), -1, out=cdf)
    index = torch.searchsorted(cdf, (uniforms * cdf[:, -1]).unsqueeze(-1), right=True)
    return index.squeeze(-1).clamp(max=logits.shape[-1] - 1)


@torch.inference_mode()
def generate_batched(
    model: ConditionalPixelCNN,
    context: torch.Tensor,
    temperature: float = 0.0,
    generator: torch.Generator | None = None,
    weights: BatchedWeights | None = None,
    uniforms: torch.Tensor | None = None,
    table: torch.Tensor | None = None,
) -> torch.Tensor | tuple[torch.Tensor, ...]:
    """The next code grids (B, h, w) given `context` (B, 4, h, w): greedy if `temperature` is 0, else sampled.

    `generate_fast`'s contract, computed over the batch at once on `weights.device` (the model's weights laid out
    by `batched_weights`; for the CPU when None). `uniforms` (B, h, w) float64: the numbers to sample with, else
    drawn from `generator` as `generate_fast` draws them. `table` (K, P): also return, per position,
    Σ_q softmax(logits)_q · table[q] (B, h, w, P) from the logits the generation computes. Results come back on
    the CPU."""
    B, _, H, W = context.shape
    weights = batched_weights(model) if weights is None else weights
    if uniforms is None:
        uniforms = draw_uniforms(B, H, W, temperature, generator)
    if B > BLOCK_ROWS:  # blocks whose working set stays in the caches
        parts = [
            generate_batched(
                model, context[s : s + BLOCK_ROWS], temperature, None, weights, uniforms[s : s + BLOCK_ROWS], table
            )
            for s in range(0, B, BLOCK_ROWS)
        ]
        return torch.cat(parts) if table is None else tuple(torch.cat(p) for p in zip(*parts, strict=True))
    return _Generation(model, context, temperature, weights, uniforms.to(weights.device), table).run()


class _Generation:
    """One block of `generate_batched`: its buffers, made once, and the grid generated row by row (the vertical
    stacks of the whole row at once), position by position (the horizontal stacks, the head and the code)."""

    def __init__(
        self,
        model: ConditionalPixelCNN,
        context: torch.Tensor,
        temperature: float,
        weights: BatchedWeights,
        uniforms: torch.Tensor,
        table: torch.Tensor | None,
    ):
        B, _, H, W = context.shape
        device, L, C = weights.device, len(weights.v_weight), weights.embed.shape[1]
        self.shape, self.w, self.temperature, self.uniforms = (B, H, W, L, C), weights, temperature, uniforms
        home = next(model.parameters()).device  # the conditioning map comes from the model where it lives
        # Channels-last (H, B · W, c): each row's slice is one matrix for every layer's conditioning at once.
        self.condition = model.condition(context.to(home)).to(device).permute(2, 0, 3, 1).reshape(H, B * W, -1)
        self.top = max(weights.v_half)  # every vertical window reaches `top` rows up and columns aside at most
        # Inputs of each layer's vertical stack, channels-last with `top` zero rows above and zero columns either
        # side (layer 0: the embedded codes).
        self.v_in = torch.zeros(L, B, self.top + H, self.top + W + self.top, C, device=device)
        # The current row's horizontal features, channels-last with `left` zero columns: h[0] is the embedded codes.
        self.left = max(w.shape[0] // C for w in weights.h_weight) - 1
        self.h = torch.zeros(L + 1, B, self.left + W, C, device=device)
        self.codes = torch.zeros(B, H, W, dtype=torch.long, device=device)
        K = weights.embed.shape[0]
        self.logits = torch.empty(B, K, device=device)
        self._draw_buffers(B, K, device)
        self.expected = None
        if table is not None:
            self.probs = torch.empty(B, K, device=device)
            self.table = table.to(device=device, dtype=torch.float32)
            self.expected = torch.empty(B, H, W, self.table.shape[1], device=device)
        # Views, made once, of what each position reads and writes: layer l's window of columns j − taps + 1 … j
        # (B, taps · C, contiguous within a row) and its output column j (B, C).
        h, left = self.h, self.left
        self.windows = [
            [h[layer, :, left + j - w.shape[0] // C + 1 : left + j + 1].reshape(B, -1) for j in range(W)]
            for layer, w in enumerate(weights.h_weight)
        ]
        self.columns = [[h[layer, :, left + j] for j in range(W)] for layer in range(L + 1)]
        self.layers = list(zip(weights.h_weight, weights.out_weight, weights.out_bias, weights.residual, strict=True))
        self.row_terms = [torch.empty(0)] * L

    def _draw_buffers(self, B: int, K: int, device: torch.device) -> None:
        """Buffers every position reuses (a fresh B × K array per operation costs the allocator more than the
        arithmetic): the draw's float64 weights and sums, or the argmax's intermediates."""
        self.on_cpu = device.type == "cpu"
        if self.temperature > 0.0 and self.on_cpu:  # the kernel's draw, row by row (`draw_rows`), per position
            self.drawn = torch.empty(B, dtype=torch.long)
            # (H, W, B): each position's numbers contiguous
            self.numbers = self.uniforms.permute(1, 2, 0).contiguous().numpy()
            self.scratch = (np.empty((4, K)), np.empty(K), self.logits.numpy(), self.drawn.numpy())
        elif self.temperature > 0.0:
            self.work, self.cdf = (torch.empty(B, K, dtype=torch.float64, device=device) for _ in range(2))
        else:
            self.work = torch.empty(B, K, device=device)

    def run(self) -> torch.Tensor | tuple[torch.Tensor, ...]:
        _, H, W, _, _ = self.shape
        top, left = self.top, self.left
        for i in range(H):
            self._vertical_row(i)
            self.h[0].zero_()
            for j in range(W):
                self._position(i, j)
                code = self._choose(i, j)
                self.codes[:, i, j] = code
                self.columns[0][j].copy_(self.w.embed[code])
            self.v_in[0, :, top + i, top : top + W] = self.h[0, :, left:]
        codes = self.codes.cpu()
        return codes if self.expected is None else (codes, self.expected.cpu())

    def _vertical_row(self, i: int) -> None:
        """Row i of every layer's vertical stack, and its terms of the horizontal stacks' pre-activations."""
        B, _, W, L, C = self.shape
        weights, top = self.w, self.top
        # Row i's conditioning of every layer's vertical and horizontal gates (B, W, L, 2, 2C), computed per row so
        # that it stays in the caches; the horizontal one also carries both biases of the horizontal pre-activation.
        conditions = torch.addmm(weights.cond_bias, self.condition[i], weights.cond_weight).reshape(B, W, L, 2, 2 * C)
        for layer in range(L):
            half = weights.v_half[layer]
            rows = self.v_in[
                layer, :, top + i - half : top + i + 1, top - half : top + W + half
            ]  # (B, half+1, W+2half, C)
            window = rows.unfold(2, 2 * half + 1, 1).permute(0, 2, 1, 4, 3).reshape(B * W, -1)
            v_pre = torch.addmm(weights.v_bias[layer], window, weights.v_weight[layer])  # (B·W, 2C)
            if layer + 1 < L:
                gate = v_pre.reshape(B, W, -1) + conditions[:, :, layer, 0]
                self.v_in[layer + 1, :, top + i, top : top + W] = torch.tanh(gate[..., :C]) * torch.sigmoid(
                    gate[..., C:]
                )
            self.row_terms[layer] = torch.addmm(
                conditions[:, :, layer, 1].reshape(B * W, -1), v_pre, weights.v2h_weight[layer]
            ).reshape(B, W, -1)

    def _position(self, i: int, j: int) -> None:
        """Position (i, j): every layer's horizontal stack, the head's logits and (with a table) the expected row."""
        _, _, _, L, C = self.shape
        weights = self.w
        for layer, (h_weight, out_weight, out_bias, residual) in enumerate(self.layers):
            pre = torch.addmm(self.row_terms[layer][:, j], self.windows[layer][j], h_weight)
            gated = torch.tanh(pre[:, :C]) * torch.sigmoid(pre[:, C:])
            out = torch.addmm(out_bias, gated, out_weight)
            if residual:
                out += self.columns[layer][j]
            self.columns[layer + 1][j].copy_(out)
        hidden = torch.addmm(weights.b1, torch.relu(self.columns[L][j]), weights.w1).relu_()
        torch.addmm(weights.b2, hidden, weights.w2, out=self.logits)  # (B, K)
        if self.expected is not None:
            self.expected[:, i, j] = torch.ops.aten._softmax.out(self.logits, -1, False, out=self.probs) @ self.table

    def _choose(self, i: int, j: int) -> torch.Tensor:
        """The codes (B,) at (i, j): drawn as the kernel draws them (on the CPU), by the batched draw, or the argmax."""
        if self.temperature > 0.0 and self.on_cpu:
            cdf_rows, scale, logits_np, drawn_np = self.scratch
            draw_rows(logits_np, float(self.temperature), self.numbers[i, j], cdf_rows, scale, drawn_np)
            return self.drawn
        if self.temperature > 0.0:
            return _pick(self.logits, self.temperature, self.uniforms[:, i, j], self.work, self.cdf)
        return _first_argmax(self.logits, self.w.descending, self.work)
