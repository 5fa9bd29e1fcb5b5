"""The prior chained ahead: k code grids from observed context codes, each generated grid joining the context of
the next, greedy or sampled from per-row random streams, with the prior's per-pixel obstacle probability taken
from the generation's own logits.

The generation path is chosen by how many grids are generated together: the compiled kernel
(`generation.generate_fast`) for small batches on the CPU, the batched generation (`batched.generate_batched`:
matrix–matrix products over the batch) for large ones and on a GPU. Both give the codes of the naive
one-position-at-a-time generation (`dynplan.bench.reference.generate_naive`), which the tests compare them with.
"""

from __future__ import annotations

import weakref
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch

from dynplan.models.batched import BatchedWeights, batched_weights, generate_batched
from dynplan.models.generation import KernelWeights, generate_fast, kernel_weights
from dynplan.models.pixelcnn import ConditionalPixelCNN, draw_uniforms, from_strips, to_strips

#: Grids generated together from which the batched generation is used on the CPU instead of the compiled kernel
#: (whose row blocks run on torch's threads); measured by `python -m dynplan.bench generation` (on 2 cores the
#: batched generation is cheaper per grid of the default prior from between 32 and 100 rows).
BATCHED_FROM = 64

#: A sampled code is drawn from the prior's softmax as it is (temperature 1); greedy codes are its argmax.
SAMPLED = 1.0

#: Greedy next grids each prior keeps, by context (the most recently used; `_greedy_next`).
GREEDY_MEMO = 4096

_LAYOUTS: weakref.WeakKeyDictionary[ConditionalPixelCNN, dict] = weakref.WeakKeyDictionary()
_MEMOS: weakref.WeakKeyDictionary[ConditionalPixelCNN, OrderedDict] = weakref.WeakKeyDictionary()


def generation_weights(prior: ConditionalPixelCNN, layout: str) -> KernelWeights | BatchedWeights:
    """The prior's weights laid out for generation — "kernel" for the compiled kernel, else a device for the batched
    generation — once per prior: a world model never trains its prior, and an evaluation builds one model per
    episode on the same prior."""
    layouts = _LAYOUTS.setdefault(prior, {})
    if layout not in layouts:
        layouts[layout] = kernel_weights(prior) if layout == "kernel" else batched_weights(prior, layout)
    return layouts[layout]


@dataclass(frozen=True)
class ChainSpec:
    """How to chain: on which `device` the batched generation runs; `streams`, when sampling, are consecutive
    groups of rows (generator, rows), each drawing its numbers from its own generator, one grid after another and
    only for its rows' length (equal within a group), so a shorter chain is a longer one's prefix; `table` (K, P)
    float32: each code's obstacle pixels (P = ph · pw), to return the per-pixel obstacle probability too, laid out
    as frames by `patch` (ph, pw), the pixels one code covers."""

    device: str = "cpu"
    streams: Sequence[tuple[torch.Generator, int]] = ()
    table: torch.Tensor | None = None
    patch: tuple[int, int] = (1, 1)


def _kernel_path(spec: ChainSpec, rows: int) -> bool:
    """Whether `rows` grids generate with the compiled kernel (else the batched generation)."""
    return spec.device == "cpu" and rows < BATCHED_FROM


def _greedy_next(prior: ConditionalPixelCNN, context: torch.Tensor, spec: ChainSpec) -> torch.Tensor:
    """The greedy next grid of each row of `context` (B, context, h, w), each context's generated once (on the
    path the count of new ones calls for) and kept: the greedy chain is a function of its context, so a decision
    whose newest observed grid is the one the last decision predicted first continues that decision's chain, and
    only its last grid is new. A kept grid is the one generated again up to float summation order (the
    conditioning is one convolution over the rows generated together). Priors of strips only (`keeps_greedy`)."""
    memo = _MEMOS.setdefault(prior, OrderedDict())
    keys = [(row.shape, row.numpy().tobytes()) for row in context]
    missing = list(dict.fromkeys(key for key in keys if key not in memo))
    if missing:
        first = {key: i for i, key in enumerate(keys)}
        grids, _ = _next_grids(prior, context[[first[key] for key in missing]], None, spec)
        memo.update(zip(missing, grids.clone(), strict=True))
    out = torch.stack([memo[key] for key in keys])
    for key in keys:
        memo.move_to_end(key)
    while len(memo) > GREEDY_MEMO:
        memo.popitem(last=False)
    return out


def keeps_greedy(prior: ConditionalPixelCNN) -> bool:
    """Whether `prior`'s greedy grids are kept (`_greedy_next`): a strip prior's are, each strip's by its own
    context (a decision mostly predicted each lane right), and its world model decodes their mid-points code by
    code (`VQVAE.decode_by_code`); the road's committed evaluations generate and decode every grid."""
    return prior.config.strip_rows is not None


def forget_greedy() -> None:
    """Drop every prior's kept greedy grids (`_greedy_next`): the next chains generate every grid."""
    _MEMOS.clear()


def _next_grids(
    prior: ConditionalPixelCNN, context: torch.Tensor, uniforms: torch.Tensor | None, spec: ChainSpec
) -> tuple[torch.Tensor, np.ndarray | None]:
    """One grid per row of `context` (B, context, h, w), on the path its batch size calls for, and (with a table)
    its (B, h, w, P) expected obstacle pixels."""
    temperature = SAMPLED if uniforms is not None else 0.0
    batched = not _kernel_path(spec, len(context))
    weights = generation_weights(prior, spec.device if batched else "kernel")
    if batched:
        out = generate_batched(prior, context, temperature, None, weights, uniforms, spec.table)
    else:
        table = None if spec.table is None else spec.table.numpy()
        out = generate_fast(prior, context, temperature, None, weights, uniforms, table)
    if spec.table is None:
        return out, None
    grid, expected = out
    return grid, np.asarray(expected)


@torch.inference_mode()
def chain(
    prior: ConditionalPixelCNN, context: torch.Tensor, lengths: Sequence[int], spec: ChainSpec
) -> tuple[torch.Tensor, np.ndarray | None]:
    """The prior chained ahead from `context` (B, context, h, w), row b for `lengths[b]` grids: codes
    (B, max length, h, w), zero past a row's length, and with `spec.table` each grid's per-pixel obstacle
    probability (B, max length, H, W). Sampled when `spec.streams` is given, else greedy. A prior of strips
    (`strip_rows`) chains every strip of a grid as a row of its own, drawing from its grid's stream."""
    rows = prior.config.strip_rows
    if rows is None:
        return _chain(prior, context, lengths, spec)
    per = context.shape[2] // rows
    streams = [(generator, count * per) for generator, count in spec.streams]
    strips = to_strips(context, rows)
    grids, probability = _chain(prior, strips, np.repeat(lengths, per), replace(spec, streams=streams))
    if probability is not None:
        probability = from_strips(torch.from_numpy(probability), len(context)).numpy()
    return from_strips(grids, len(context)), probability


def _chain(
    prior: ConditionalPixelCNN, context: torch.Tensor, lengths: Sequence[int], spec: ChainSpec
) -> tuple[torch.Tensor, np.ndarray | None]:
    """`chain` of whole grids."""
    B, _, h, w = context.shape
    lengths = np.asarray(lengths)
    steps = int(lengths.max())
    grids = torch.zeros(B, steps, h, w, dtype=torch.long)
    ph, pw = spec.patch
    probability = None if spec.table is None else np.zeros((B, steps, h * ph, w * pw), np.float32)
    firsts = np.cumsum([0, *(rows for _, rows in spec.streams)])[:-1]
    stream_lengths = lengths[firsts] if len(spec.streams) else lengths[:0]  # a group's rows share their length
    for step in range(steps):
        live = np.flatnonzero(lengths > step)
        rows = live if len(live) < B else slice(None)
        uniforms = None
        if spec.streams:
            pairs = zip(spec.streams, stream_lengths, strict=True)
            uniforms = torch.cat(
                [draw_uniforms(count, h, w, SAMPLED, generator) for (generator, count), n in pairs if n > step]
            )
        if uniforms is None and spec.table is None and keeps_greedy(prior):
            grid, expected = _greedy_next(prior, context[rows], spec), None
        else:
            grid, expected = _next_grids(prior, context[rows], uniforms, spec)
        if probability is not None:
            expected = expected.reshape(len(live), h, w, ph, pw)
            probability[live, step] = expected.transpose(0, 1, 3, 2, 4).reshape(len(live), h * ph, w * pw)
        grids[live, step] = grid
        if len(live) == B:
            context = torch.cat([context[:, 1:], grid[:, None]], dim=1)
        else:  # the finished rows keep their context; no step reads it again
            context = context.clone()
            context[live] = torch.cat([context[live, 1:], grid[:, None]], dim=1)
    return grids, probability
