"""Fast autoregressive generation for the conditional gated PixelCNN, with per-position caching.

The naive way (`ConditionalPixelCNN.generate_naive`) runs the whole network once per position: h·w full
passes per grid. Here every feature is computed once, when its inputs exist (as in Fast PixelCNN++):

* the conditioning map, and each layer's projection of it, once per grid;
* at the start of row i, every layer's vertical stack for row i — it depends on rows above only;
* at each position (i, j), every layer's horizontal stack for that position only, and the head.

Greedy decoding — the planner's path — runs the whole grid in one compiled (numba) call: no Python or
framework overhead per row or position, and every matrix–vector product is written as a sum of weight rows
scaled by one input each (contiguous, so it vectorises, and the order of each output's sum stays fixed).
Sampling (temperature > 0) runs the same caching in torch, position by position. The arithmetic is the
network's own, so the grids equal the naive ones (up to float summation order, which the tests check does
not change an argmax).
"""

from __future__ import annotations

import numba
import numpy as np
import torch
import torch.nn.functional as F

from dynplan.models.pixelcnn import ConditionalPixelCNN, _pick


def _linear(conv: torch.nn.Conv2d, x: torch.Tensor) -> torch.Tensor:
    """A 1 × 1 convolution applied to vectors (B, C_in) → (B, C_out), without convolution overhead."""
    return F.linear(x, conv.weight.view(conv.out_channels, conv.in_channels), conv.bias)


@torch.inference_mode()
def generate_fast(model: ConditionalPixelCNN, context: torch.Tensor, temperature: float = 0.0,
                  generator: torch.Generator | None = None) -> torch.Tensor:  # fmt: skip
    """The next code grid given `context` (B, 4, h, w): greedy if `temperature` is 0, else sampled.

    Same contract as `generate_naive`, at a fraction of the cost."""
    layers = list(model.layers)
    condition = model.condition(context)
    cond_v, cond_h = zip(*(layer.condition(condition).chunk(2, dim=1) for layer in layers), strict=True)
    if temperature == 0.0:

        def channels_last(parts) -> np.ndarray:  # (L, B, 2C, h, w) → (L, B, h, w, 2C)
            return np.ascontiguousarray(torch.stack(parts).permute(0, 1, 3, 4, 2).numpy(), dtype=np.float32)

        codes = _greedy_grid(channels_last(cond_v), channels_last(cond_h), *_compiled_weights(model))
        return torch.from_numpy(codes)
    return _generate_sampled(model, cond_v, cond_h, temperature, generator)


def _generate_sampled(model: ConditionalPixelCNN, cond_v, cond_h, temperature: float,
                      generator: torch.Generator | None) -> torch.Tensor:  # fmt: skip
    """Position-by-position generation in torch with the same caching, drawing each code at `temperature`."""
    layers = list(model.layers)
    B, _, H, W = cond_v[0].shape
    C = model.config.channels
    codes = torch.zeros(B, H, W, dtype=torch.long)
    x = torch.zeros(B, C, H, W)  # embedded codes generated so far: the input of layer 0's two stacks
    v_in = [x] + [torch.zeros(B, C, H, W) for _ in layers[1:]]  # input of each layer's vertical stack
    h_in = [x] + [torch.zeros(B, C, H, W) for _ in layers]  # input of each horizontal stack; last: its output
    v_weights, h_weights = [], []
    for layer in layers:
        v_weight, h_weight = layer.vertical.weight, layer.horizontal.weight[:, :, 0]  # (2C, C, r, k), (2C, C, t)
        if layer.mask == "A":
            v_weight, h_weight = v_weight.clone(), h_weight.clone()
            v_weight[:, :, -1] = 0.0
            h_weight[:, :, -1] = 0.0
        v_weights.append(v_weight)
        h_weights.append(h_weight.reshape(2 * C, -1))  # taps flattened channel-major, as the gathered inputs are
    head = list(model.head)
    for i in range(H):
        to_horizontal = []
        for li, layer in enumerate(layers):
            rows, half = v_weights[li].shape[2], v_weights[li].shape[3] // 2
            above = v_in[li][:, :, max(0, i - rows + 1) : i + 1]
            above = F.pad(above, (half, half, rows - above.shape[2], 0))  # (B, C, rows, W + 2·half)
            v_pre = F.conv2d(above, v_weights[li], layer.vertical.bias)[:, :, 0]  # (B, 2C, W): row i
            if li + 1 < len(layers):
                v_in[li + 1][:, :, i] = layer.gate(v_pre + cond_v[li][:, :, i])
            v2h = F.conv1d(v_pre, layer.vertical_to_horizontal.weight[:, :, 0], layer.vertical_to_horizontal.bias)
            to_horizontal.append(v2h + cond_h[li][:, :, i])  # (B, 2C, W)
        for j in range(W):
            for li, layer in enumerate(layers):
                taps = h_weights[li].shape[1] // C
                row = h_in[li][:, :, i, max(0, j - taps + 1) : j + 1]
                row = F.pad(row, (taps - row.shape[2], 0))  # (B, C, taps): columns j − taps + 1 … j
                h_pre = F.linear(row.reshape(B, -1), h_weights[li], layer.horizontal.bias)
                out = _linear(layer.horizontal_out, layer.gate(to_horizontal[li][:, :, j] + h_pre))
                h_in[li + 1][:, :, i, j] = h_in[li][:, :, i, j] + out if layer.residual else out
            hidden = _linear(head[1], F.relu(h_in[-1][:, :, i, j]))
            logits = _linear(head[3], F.relu(hidden))
            code = _pick(logits, temperature, generator)
            codes[:, i, j] = code
            x[:, :, i, j] = model.embed(code)
    return codes


def _taps(weight: torch.Tensor, mask_a: bool) -> tuple[np.ndarray, np.ndarray]:
    """A masked convolution's taps as (row offset, column offset) pairs relative to the output position, and
    their weights transposed to (taps, C_in, C_out); mask A drops the taps on the output's own row (vertical)
    or column (horizontal) — the last kernel row or column."""
    rows, cols = weight.shape[2:]
    offsets, weights = [], []
    for r in range(rows - 1 if mask_a and rows > 1 else rows):
        for c in range(cols - 1 if mask_a and rows == 1 else cols):
            # Vertical kernels (rows > 1) end on the output's row and are centred on its column; horizontal ones
            # (a single row) end on the output's column.
            offsets.append((r - (rows - 1), c - (cols // 2 if rows > 1 else cols - 1)))
            weights.append(weight[:, :, r, c].T)
    return np.array(offsets, np.int64), torch.stack(weights).detach().numpy()


def _stack(arrays: list[np.ndarray]) -> np.ndarray:
    """Per-layer arrays of differing first dimension, zero-padded into one float32/int64 array."""
    longest = max(len(a) for a in arrays)
    out = np.zeros((len(arrays), longest, *arrays[0].shape[1:]), arrays[0].dtype)
    for i, a in enumerate(arrays):
        out[i, : len(a)] = a
    return np.ascontiguousarray(out)


def _compiled_weights(model: ConditionalPixelCNN) -> tuple[np.ndarray, ...]:
    """The network's weights laid out for `_greedy_grid`, cached on the model until a parameter changes."""
    version = tuple((id(p), p._version) for p in model.parameters())
    cached = getattr(model, "_greedy_weights", None)
    if cached is not None and cached[0] == version:
        return cached[1]
    layers, head = list(model.layers), list(model.head)
    v_taps = [_taps(layer.vertical.weight, layer.mask == "A") for layer in layers]
    h_taps = [_taps(layer.horizontal.weight, layer.mask == "A") for layer in layers]

    def array(t: torch.Tensor) -> np.ndarray:
        return np.ascontiguousarray(t.detach().numpy(), dtype=np.float32)

    def transposed(convs) -> np.ndarray:  # 1 × 1 convolutions → (L, C_in, C_out)
        return array(torch.stack([conv.weight[:, :, 0, 0].T for conv in convs]))

    weights = (
        _stack([offsets for offsets, _ in v_taps]),
        _stack([w for _, w in v_taps]).astype(np.float32),
        np.array([len(offsets) for offsets, _ in v_taps], np.int64),
        array(torch.stack([layer.vertical.bias for layer in layers])),
        transposed([layer.vertical_to_horizontal for layer in layers]),
        array(torch.stack([layer.vertical_to_horizontal.bias for layer in layers])),
        _stack([offsets[:, 1] for offsets, _ in h_taps]),
        _stack([w for _, w in h_taps]).astype(np.float32),
        np.array([len(offsets) for offsets, _ in h_taps], np.int64),
        array(torch.stack([layer.horizontal.bias for layer in layers])),
        transposed([layer.horizontal_out for layer in layers]),
        array(torch.stack([layer.horizontal_out.bias for layer in layers])),
        np.array([layer.residual for layer in layers]),
        array(head[1].weight[:, :, 0, 0].T),
        array(head[1].bias),
        array(head[3].weight[:, :, 0, 0].T),
        array(head[3].bias),
        array(model.embed.weight),
    )
    model._greedy_weights = (version, weights)
    return weights


@numba.njit(cache=True, inline="always")
def _add_scaled(acc, weights, x):
    """acc += weightsᵀ · x for weights (n_in, n_out): one contiguous, vectorisable row update per input."""
    for c in range(x.shape[0]):
        value = x[c]
        if value != 0.0:  # exact: adding w · 0 changes nothing (ReLU outputs are often zero)
            row = weights[c]
            for o in range(acc.shape[0]):
                acc[o] += row[o] * value


@numba.njit(cache=True, nogil=True)  # episodes on a thread pool generate in parallel
def _greedy_grid(cond_v, cond_h, v_offsets, v_weight, v_taps, v_bias, v2h_weight, v2h_bias, h_offsets,
                 h_weight, h_taps, h_bias, out_weight, out_bias, residual, w1, b1, w2, b2, embed):  # fmt: skip
    """Greedy generation of whole code grids (compiled): vertical stacks row by row, horizontal stacks and the
    head position by position.

    cond_v, cond_h: (L, B, H, W, 2C) each layer's conditioning for its vertical and horizontal gates
    v_offsets (L, T, 2) / v_weight (L, T, C, 2C) / v_taps (L,): each layer's vertical taps, (row, col) offsets
    h_offsets (L, T) / h_weight (L, T, C, 2C) / h_taps (L,): horizontal taps, column offsets
    *_weight of 1 × 1 convolutions and the head: (C_in, C_out); embed (K, C)
    returns codes (B, H, W) int64
    """
    L, B, H, W, C2 = cond_v.shape
    C = C2 // 2
    codes = np.zeros((B, H, W), np.int64)
    x = np.zeros((H, W, C), np.float32)  # embedded codes generated so far: input of layer 0's stacks
    v_in = np.zeros((L, H, W, C), np.float32)  # input of each layer's vertical stack (layer 0 reads x)
    h = np.zeros((L + 1, W, C), np.float32)  # the current row's horizontal features; h[0] unused (x)
    to_h = np.zeros((L, W, C2), np.float32)
    acc = np.zeros(C2, np.float32)
    out = np.zeros(C, np.float32)
    gated = np.zeros(C, np.float32)
    hidden = np.zeros(w1.shape[1], np.float32)
    logits = np.zeros(w2.shape[1], np.float32)
    for b in range(B):
        x[:] = 0.0
        v_in[:] = 0.0
        for i in range(H):
            for layer in range(L):
                source = x if layer == 0 else v_in[layer]
                for j in range(W):
                    acc[:] = v_bias[layer]
                    for t in range(v_taps[layer]):
                        r, c = i + v_offsets[layer, t, 0], j + v_offsets[layer, t, 1]
                        if r >= 0 and 0 <= c < W:
                            _add_scaled(acc, v_weight[layer, t], source[r, c])
                    if layer + 1 < L:
                        for c in range(C):
                            a = acc[c] + cond_v[layer, b, i, j, c]
                            g = acc[C + c] + cond_v[layer, b, i, j, C + c]
                            v_in[layer + 1, i, j, c] = np.tanh(a) / (1.0 + np.exp(-g))
                    to_h[layer, j] = v2h_bias[layer]
                    _add_scaled(to_h[layer, j], v2h_weight[layer], acc)
            for j in range(W):
                for layer in range(L):
                    source = x[i] if layer == 0 else h[layer]
                    for o in range(C2):
                        acc[o] = h_bias[layer, o] + (to_h[layer, j, o] + cond_h[layer, b, i, j, o])
                    for t in range(h_taps[layer]):
                        c = j + h_offsets[layer, t]
                        if c >= 0:
                            _add_scaled(acc, h_weight[layer, t], source[c])
                    for c in range(C):
                        gated[c] = np.tanh(acc[c]) / (1.0 + np.exp(-acc[C + c]))
                    out[:] = out_bias[layer]
                    _add_scaled(out, out_weight[layer], gated)
                    for c in range(C):
                        h[layer + 1, j, c] = out[c] + (source[j, c] if residual[layer] else 0.0)
                for c in range(C):
                    gated[c] = max(h[L, j, c], 0.0)
                hidden[:] = b1
                _add_scaled(hidden, w1, gated)
                for o in range(hidden.shape[0]):
                    hidden[o] = max(hidden[o], 0.0)
                logits[:] = b2
                _add_scaled(logits, w2, hidden)
                best = np.argmax(logits)
                codes[b, i, j] = best
                x[i, j] = embed[best]
    return codes
