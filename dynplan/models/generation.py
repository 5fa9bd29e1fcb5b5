"""Fast autoregressive generation for the conditional gated PixelCNN, with per-position caching.

The naive way (`dynplan.bench.reference.generate_naive`, the tests' reference) runs the whole network once per
position: h·w full passes per grid. Here every feature is computed once, when its inputs exist (as in Fast PixelCNN++):

* the conditioning map, and each layer's projection of it, once per grid;
* at the start of row i, every layer's vertical stack for row i — it depends on rows above only;
* at each position (i, j), every layer's horizontal stack for that position only, and the head.

The whole grid is one compiled (numba) call: no Python or framework overhead per row or position, and every
matrix–vector product is written as a sum of weight rows scaled by one input each (contiguous, so it
vectorises, and the order of each output's sum stays fixed). The arithmetic is the network's own, so the grids
equal the naive ones — greedy or sampled from the same uniform numbers — up to float summation order, which
the tests check does not change a choice.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numba
import numpy as np
import torch

from dynplan.models.pixelcnn import ConditionalPixelCNN, draw_uniforms


class KernelWeights(NamedTuple):
    """A prior's weights laid out for the compiled generation (`_generate_grid`), built once per model by
    `kernel_weights`. L layers, T taps, C channels (2C gated), K codes.

    v_offsets (L, T, 2) int64, v_weight (L, T, C, 2C), v_taps (L,): each layer's vertical taps — (row, column)
    offsets from the output, weights, how many are real (the rest pad); v_bias (L, 2C); v2h_weight (L, 2C, 2C),
    v2h_bias (L, 2C): the vertical stack's 1 × 1 link into the horizontal one; h_offsets (L, T), h_weight
    (L, T, C, 2C), h_taps (L,), h_bias (L, 2C): horizontal taps (column offsets); out_weight (L, C, C), out_bias
    (L, C): each layer's 1 × 1 output; residual (L,) bool; w1 (C, hidden), b1, w2 (hidden, K), b2: the head;
    embed (K, C): the code embedding that feeds generated codes back in.
    """

    v_offsets: np.ndarray
    v_weight: np.ndarray
    v_taps: np.ndarray
    v_bias: np.ndarray
    v2h_weight: np.ndarray
    v2h_bias: np.ndarray
    h_offsets: np.ndarray
    h_weight: np.ndarray
    h_taps: np.ndarray
    h_bias: np.ndarray
    out_weight: np.ndarray
    out_bias: np.ndarray
    residual: np.ndarray
    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: np.ndarray
    embed: np.ndarray


@torch.inference_mode()
def generate_fast(
    model: ConditionalPixelCNN,
    context: torch.Tensor,
    temperature: float = 0.0,
    generator: torch.Generator | None = None,
    weights: KernelWeights | None = None,
    uniforms: torch.Tensor | None = None,
    table: np.ndarray | None = None,
) -> torch.Tensor | tuple[torch.Tensor, np.ndarray]:
    """The next code grid given `context` (B, 4, h, w): greedy if `temperature` is 0, else sampled.

    Same contract as `generate_naive` (the same codes, drawing the same random numbers), at a fraction of the
    cost. `weights`: the model's `kernel_weights`, when the caller keeps them (a frozen model generating many
    grids); else they are laid out for this call. `uniforms` (B, h, w): the numbers to sample with, when the
    caller draws them (a batch whose rows have random streams of their own); else drawn from `generator`.
    `table` (K, P) float32: also return, per position, Σ_q softmax(logits)_q · table[q] (B, h, w, P) — e.g. the
    probability of an obstacle in each pixel of the position's patch — from the logits the generation computes
    anyway (what a teacher-forced pass over the generated grid would give, up to float summation order)."""
    B, _, H, W = context.shape
    if uniforms is None:
        uniforms = draw_uniforms(B, H, W, temperature, generator)
    conditions = model.layer_conditions(model.condition(context))  # (B, h, w, L, 2, 2C)

    def channels_last(gate: int) -> np.ndarray:  # → (B, L, h, w, 2C)
        return np.ascontiguousarray(conditions[..., gate, :].permute(0, 3, 1, 2, 4).numpy(), dtype=np.float32)

    weights = kernel_weights(model) if weights is None else weights
    lookup = np.zeros((0, 1), np.float32) if table is None else np.ascontiguousarray(table.T, dtype=np.float32)
    expected = np.zeros((B, H, W, lookup.shape[0]), np.float32)
    cond_v, cond_h, numbers = channels_last(0), channels_last(1), uniforms.numpy()
    codes = np.zeros((B, H, W), np.int64)

    def rows(start: int, stop: int) -> None:
        _generate_grid(
            cond_v[start:stop],
            cond_h[start:stop],
            float(temperature),
            numbers[start:stop],
            lookup,
            expected[start:stop],
            codes[start:stop],
            weights,
        )

    # The kernel releases the GIL: torch's thread count of row blocks generate at once, each on its own grids.
    blocks = min(B, torch.get_num_threads())
    bounds = [B * n // blocks for n in range(blocks + 1)]
    if blocks > 1:
        list(_pool().map(rows, bounds[:-1], bounds[1:]))
    else:
        rows(0, B)
    return torch.from_numpy(codes) if table is None else (torch.from_numpy(codes), expected)


_POOL: list[ThreadPoolExecutor] = []


def _pool() -> ThreadPoolExecutor:
    """The process's threads for `generate_fast`'s row blocks (one per core), made when first needed."""
    if not _POOL:
        _POOL.append(ThreadPoolExecutor(max_workers=os.cpu_count() or 1, thread_name_prefix="dynplan-generate"))
    return _POOL[0]


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


@torch.inference_mode()
def kernel_weights(model: ConditionalPixelCNN) -> KernelWeights:
    """`model`'s weights laid out for the compiled generation, as they are now (build them again after the
    parameters change)."""
    layers, head = list(model.layers), list(model.head)
    v_taps = [_taps(layer.vertical.weight, layer.mask == "A") for layer in layers]
    h_taps = [_taps(layer.horizontal.weight, layer.mask == "A") for layer in layers]

    def array(t: torch.Tensor) -> np.ndarray:
        return np.ascontiguousarray(t.detach().numpy(), dtype=np.float32)

    def transposed(convs) -> np.ndarray:  # 1 × 1 convolutions → (L, C_in, C_out)
        return array(torch.stack([conv.weight[:, :, 0, 0].T for conv in convs]))

    return KernelWeights(
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


@numba.njit(cache=True, inline="always")
def _add_scaled(acc, weights, x):
    """acc += weightsᵀ · x for weights (n_in, n_out): one contiguous, vectorisable row update per input."""
    for c in range(x.shape[0]):
        value = x[c]
        if value != 0.0:  # exact: adding w · 0 changes nothing (ReLU outputs are often zero)
            row = weights[c]
            for o in range(acc.shape[0]):
                acc[o] += row[o] * value


@numba.njit(cache=True, inline="always")
def _add_product(acc, weights, x):
    """acc += weightsᵀ · x, as `_add_scaled` without its test for zero inputs (for inputs that are seldom zero)."""
    for c in range(x.shape[0]):
        value = x[c]
        row = weights[c]
        for o in range(acc.shape[0]):
            acc[o] += row[o] * value


#: exp's range reduction (Cody–Waite: ln 2 split so that n · LN2_HI is exact) and Cephes' minimax polynomial
#: for e^r on |r| ≤ ln 2 / 2 (relative error below 3e-7 over the float32 range).
_LOG2E, _LN2_HI, _LN2_LO = np.float32(1.4426950408889634), np.float32(0.693359375), np.float32(-2.12194440e-4)
_EXP_POLY = (1.9875691500e-4, 1.3981999507e-3, 8.3334519073e-3, 4.1665795894e-2, 1.6666665459e-1, 5.0000001201e-1)


@numba.njit(cache=True, fastmath=True, inline="always")
def _exp_inplace(x, bits):
    """x[q] ← exp(x[q]) for x ≤ 0 (float32), written so that the compiler vectorises it — no call per element:
    libm's expf is scalar, and it took most of the softmax's and the gates' time. `bits` (int32, at least len(x)):
    scratch for 2^n, built by bit arithmetic; below e^−87 it flushes to e^−87. Returns Σ x."""
    n_elements = x.shape[0]
    scale = bits.view(np.float32)
    p0, p1, p2, p3, p4, p5 = [np.float32(c) for c in _EXP_POLY]
    for q in range(n_elements):
        v = max(x[q], np.float32(-87.0))
        n = np.floor(v * _LOG2E + np.float32(0.5))
        r = v - n * _LN2_HI - n * _LN2_LO
        p = ((((p0 * r + p1) * r + p2) * r + p3) * r + p4) * r + p5
        x[q] = p * r * r + r + np.float32(1.0)
        bits[q] = (np.int32(n) + np.int32(127)) << np.int32(23)
    total = np.float32(0.0)
    for q in range(n_elements):
        x[q] *= scale[q]
        total += x[q]
    return total


@numba.njit(cache=True, fastmath=True, inline="always")
def _gate(pre, out, buf, bits):
    """out[c] = tanh(pre[c]) · sigmoid(pre[C + c]) for pre (2C,), out (C,), both from exp(−|·|) ≤ 1 (`_exp_inplace`,
    vectorised; absolute error below 1e-7); `buf` (≥ 2C) float32 and `bits` (≥ 2C) int32 are scratch."""
    C = out.shape[0]
    for c in range(C):
        buf[c] = np.float32(-2.0) * abs(pre[c])
        buf[C + c] = -abs(pre[C + c])
    _exp_inplace(buf[: 2 * C], bits)
    for c in range(C):
        e, f = buf[c], buf[C + c]
        t = (np.float32(1.0) - e) / (np.float32(1.0) + e)
        s = np.float32(1.0) if pre[C + c] >= 0.0 else f
        out[c] = (t if pre[c] >= 0.0 else -t) * (s / (np.float32(1.0) + f))


@numba.njit(cache=True, fastmath=True)
def _expected(logits, top, table, probs, bits, out):
    """out[p] = Σ_q softmax(logits)_q · table[p, q] for table (P, K) (vectorised: its sums' order is the compiler's,
    fixed for a build)."""
    for q in range(logits.shape[0]):
        probs[q] = logits[q] - top
    scale = np.float32(1.0) / _exp_inplace(probs, bits)
    for p in range(table.shape[0]):
        acc = np.float32(0.0)
        for q in range(logits.shape[0]):
            acc += probs[q] * table[p, q]
        out[p] = acc * scale


#: exp's float64 range reduction (Cephes' split of ln 2: n · LN2_HI is exact for the |n| < 1,100 used here) and
#: Taylor's polynomial of degree 13 for e^r on |r| ≤ ln 2 / 2 (truncation below 1e-17, relative).
_LN2_HI64, _LN2_LO64 = 6.93145751953125e-1, 1.42860682030941723212e-6
_T2, _T3, _T4, _T5, _T6, _T7 = 1 / 2, 1 / 6, 1 / 24, 1 / 120, 1 / 720, 1 / 5040
_T8, _T9, _T10, _T11, _T12, _T13 = 1 / 40320, 1 / 362880, 1 / 3628800, 1 / 39916800, 1 / 479001600, 1 / 6227020800


#: 1.5 · 2^52: adding it to a float64 of magnitude below 2^51 rounds it to an integer held in the low mantissa bits
#: (so 2^n is built with 64-bit integer lanes, which AVX2 has, rather than a float → int64 conversion, which it lacks).
_ROUND_MAGIC = 6755399441055744.0
_ROUND_MAGIC_BITS = 4843621399236968448  # its bit pattern


@numba.njit(cache=True, inline="always")
def _exp64_inplace(x, scale):
    """x[q] ← exp(x[q]) for float64 x ≤ 0, vectorisable like `_exp_inplace` (libm's exp is one call per element):
    within 1 ulp of numpy's exp (`tests/test_pixelcnn.py`); below e^−708 it flushes to e^−708. `scale` (float64, at
    least len(x)): scratch for 2^n."""
    bits = scale.view(np.int64)
    for q in range(x.shape[0]):
        v = x[q] if x[q] > -708.0 else -708.0
        rounded = v * 1.4426950408889634 + _ROUND_MAGIC
        n = rounded - _ROUND_MAGIC
        r = (v - n * _LN2_HI64) - n * _LN2_LO64
        p = ((((((_T13 * r + _T12) * r + _T11) * r + _T10) * r + _T9) * r + _T8) * r + _T7) * r + _T6
        x[q] = ((((((p * r + _T5) * r + _T4) * r + _T3) * r + _T2) * r + 1.0) * r) + 1.0
        scale[q] = rounded
    for q in range(x.shape[0]):
        bits[q] = (bits[q] - _ROUND_MAGIC_BITS + 1023) << 52
    for q in range(x.shape[0]):
        x[q] *= scale[q]


@numba.njit(cache=True, fastmath={"nnan", "ninf", "nsz", "reassoc"})
def _max(x):
    """The largest of finite float32 values, reduced in vector lanes (a maximum is the same in any order)."""
    top = x[0]
    for k in range(1, x.shape[0]):
        top = max(top, x[k])
    return top


@numba.njit(cache=True, fastmath={"contract"}, inline="always")
def _weights(logits, temperature, out, scale):
    """out[k] ← exp(logits[k] / temperature − max / temperature) in float64: the softmax's unnormalised weights."""
    top = _max(logits) / temperature
    for k in range(logits.shape[0]):
        out[k] = np.float64(logits[k]) / temperature - top
    _exp64_inplace(out, scale)


@numba.njit(cache=True, inline="always")
def _first_above(cdf, threshold):
    """The first k with cdf[k] > threshold in non-decreasing `cdf` (binary search), else the last index."""
    lo, hi = 0, cdf.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if cdf[mid] > threshold:
            hi = mid
        else:
            lo = mid + 1
    return min(lo, cdf.shape[0] - 1)


@numba.njit(cache=True, fastmath={"contract"})
def _draw(logits, temperature, u, cdf, scale):
    """The first code whose cumulative softmax weight (at `temperature` > 0, float64, summed in code order) exceeds
    u · total — `pixelcnn.pick`'s rule, with a vectorised exp (`_exp64_inplace`) in place of one libm call per code.
    `cdf` and `scale` (float64, at least K long): scratch."""
    K = logits.shape[0]
    cdf = cdf[:K]
    _weights(logits, temperature, cdf, scale)
    total = 0.0
    for k in range(K):
        total += cdf[k]
        cdf[k] = total
    return _first_above(cdf, u * total)


@numba.njit(cache=True, nogil=True, fastmath={"contract"})
def draw_rows(logits, temperature, uniforms, cdf, scale, codes):
    """codes[b] ← `_draw` of row b of logits (B, K) float32 with uniforms[b] (float64) — the batched generation's
    draw, each row with the kernel's arithmetic — four rows at a time, whose running sums advance together (four
    independent chains instead of one: the sum's latency, not its arithmetic, bounds a single row). `cdf` (4, K)
    and `scale` (K,) float64: scratch."""
    B, K = logits.shape
    for start in range(0, B - B % 4, 4):
        for r in range(4):
            _weights(logits[start + r], temperature, cdf[r], scale)
        c0, c1, c2, c3 = cdf[0], cdf[1], cdf[2], cdf[3]
        t0 = t1 = t2 = t3 = 0.0
        for k in range(K):
            t0 += c0[k]
            t1 += c1[k]
            t2 += c2[k]
            t3 += c3[k]
            c0[k], c1[k], c2[k], c3[k] = t0, t1, t2, t3
        for r in range(4):
            codes[start + r] = _first_above(cdf[r], uniforms[start + r] * cdf[r, K - 1])
    for b in range(B - B % 4, B):
        codes[b] = _draw(logits[b], temperature, uniforms[b], cdf[0], scale)


@numba.njit(cache=True)
def _work(L, H, W, C2, hidden, K):
    """The generation's scratch arrays: (v_in (L, H, W, C): each layer's vertical input, h (L + 1, W, C): the current
    row's horizontal features, to_h (L, W, 2C), row (W, 2C), acc (2C,), out (C,), gated (C,), hidden, logits (K,),
    scratch (2C,), bits (int32), cdf (K,) and scale (K,) float64, probs (K,))."""
    C = C2 // 2
    return (
        np.zeros((L, H, W, C), np.float32),
        np.zeros((L + 1, W, C), np.float32),
        np.zeros((L, W, C2), np.float32),
        np.zeros((W, C2), np.float32),
        np.zeros(C2, np.float32),
        np.zeros(C, np.float32),
        np.zeros(C, np.float32),
        np.zeros(hidden, np.float32),
        np.zeros(K, np.float32),
        np.zeros(C2, np.float32),
        np.zeros(max(K, C2), np.int32),
        np.zeros(K, np.float64),
        np.zeros(K, np.float64),
        np.zeros(K, np.float32),
    )


@numba.njit(cache=True, inline="always")
def _vertical_row(i, cond, x, weights, work):
    """Row i of every layer's vertical stack, from the rows above it: the gated features into the next layer's input
    (`v_in`) and the link into the horizontal stack (`to_h`). cond (L, H, W, 2C): this grid's vertical
    conditioning; x (H, W, C): the embedded codes generated so far (layer 0's input). Tap by tap over the whole
    row: each weight matrix is read once per row, not once per position."""
    v_in, to_h, row, acc, scratch, bits = work[0], work[2], work[3], work[4], work[9], work[10]
    L, W = v_in.shape[0], v_in.shape[2]
    for layer in range(L):
        source = x if layer == 0 else v_in[layer]
        for j in range(W):
            row[j] = weights.v_bias[layer]
        for t in range(weights.v_taps[layer]):
            r, dc = i + weights.v_offsets[layer, t, 0], weights.v_offsets[layer, t, 1]
            if r >= 0:
                for j in range(max(0, -dc), min(W, W - dc)):
                    _add_product(row[j], weights.v_weight[layer, t], source[r, j + dc])
        for j in range(W):
            if layer + 1 < L:
                for o in range(acc.shape[0]):
                    acc[o] = row[j, o] + cond[layer, i, j, o]
                _gate(acc, v_in[layer + 1, i, j], scratch, bits)
            to_h[layer, j] = weights.v2h_bias[layer]
            _add_product(to_h[layer, j], weights.v2h_weight[layer], row[j])


@numba.njit(cache=True, inline="always")
def _horizontal_position(i, j, cond, x, weights, work):
    """Position (i, j) of every layer's horizontal stack, from the positions to its left, into `h[layer + 1, j]`.
    cond (L, H, W, 2C): this grid's horizontal conditioning."""
    h, to_h, acc, out, gated, scratch, bits = work[1], work[2], work[4], work[5], work[6], work[9], work[10]
    L, C = to_h.shape[0], out.shape[0]
    for layer in range(L):
        source = x[i] if layer == 0 else h[layer]
        for o in range(acc.shape[0]):
            acc[o] = weights.h_bias[layer, o] + (to_h[layer, j, o] + cond[layer, i, j, o])
        for t in range(weights.h_taps[layer]):
            c = j + weights.h_offsets[layer, t]
            if c >= 0:
                _add_product(acc, weights.h_weight[layer, t], source[c])
        _gate(acc, gated, scratch, bits)
        out[:] = weights.out_bias[layer]
        _add_product(out, weights.out_weight[layer], gated)
        for c in range(C):
            h[layer + 1, j, c] = out[c] + (source[j, c] if weights.residual[layer] else 0.0)


@numba.njit(cache=True, inline="always")
def _head(j, weights, work):
    """The head's logits (K,) at column j of the current row, from the last layer's horizontal features."""
    h, gated, hidden, logits = work[1], work[6], work[7], work[8]
    L = h.shape[0] - 1
    for c in range(gated.shape[0]):
        gated[c] = max(h[L, j, c], 0.0)
    hidden[:] = weights.b1
    _add_scaled(hidden, weights.w1, gated)
    for o in range(hidden.shape[0]):
        hidden[o] = max(hidden[o], 0.0)
    logits[:] = weights.b2
    _add_scaled(logits, weights.w2, hidden)


@numba.njit(cache=True, nogil=True)  # episodes on a thread pool generate in parallel
def _generate_grid(cond_v, cond_h, temperature, uniforms, table, expected, codes, weights):
    """Generation of whole code grids (compiled): vertical stacks row by row, horizontal stacks and the head
    position by position; each code the argmax (temperature 0) or drawn by inverse transform of the softmax at
    `temperature` with that position's number from `uniforms` (B, H, W) — as `pixelcnn.pick` does.

    cond_v, cond_h: (B, L, H, W, 2C) each layer's conditioning for its vertical and horizontal gates
    table (P, K): with rows, `expected` (B, H, W, P) receives Σ_q softmax(logits)_q · table[:, q] at each position
    weights: the prior's `KernelWeights`; codes (B, H, W) int64 receives the codes
    """
    B, L, H, W, C2 = cond_v.shape
    x = np.zeros((H, W, C2 // 2), np.float32)  # embedded codes generated so far: input of layer 0's stacks
    work = _work(L, H, W, C2, weights.w1.shape[1], weights.w2.shape[1])
    v_in, logits, bits, cdf, scale64, probs = work[0], work[8], work[10], work[11], work[12], work[13]
    for b in range(B):
        x[:] = 0.0
        v_in[:] = 0.0
        for i in range(H):
            _vertical_row(i, cond_v[b], x, weights, work)
            for j in range(W):
                _horizontal_position(i, j, cond_h[b], x, weights, work)
                _head(j, weights, work)
                if table.shape[0] > 0 or temperature == 0.0:
                    code = np.argmax(logits)
                    if table.shape[0] > 0:
                        _expected(logits, logits[code], table, probs, bits, expected[b, i, j])
                if temperature > 0.0:
                    code = _draw(logits, temperature, uniforms[b, i, j], cdf, scale64)
                codes[b, i, j] = code
                x[i, j] = weights.embed[code]
