"""The prior's output layer and its cross-entropy in one step, a block of positions at a time.

A prior's training step ends in a K-way output layer over every position of its batch — for the default, 9,216
positions × 4,096 codes: 38 M logits, 151 MB, written by the layer, read and written again by the log-softmax, its
backward and the gradient's one-hot. Here each block of `HEAD_CHUNK` positions computes its logits, keeps only their
log-sum-exp, the target's logit and whether the target is the most probable code, and lets them go; the backward
computes the block's logits again and turns them into the gradient in place (softmax less the one-hot). The
numbers are the cross-entropy's to float rounding (`tests/test_pixelcnn.py`) and the block stays in the caches:
`python -m dynplan.bench prior` times it against the plain formulations. Both passes run in float32, also under
bfloat16 autocast (the output layer and its loss are where reduced precision costs most).
"""

from __future__ import annotations

import torch

#: Positions whose logits one block computes (256 × 4,096 float32 logits: 4 MB).
HEAD_CHUNK = 256


class _HeadCrossEntropy(torch.autograd.Function):
    @staticmethod
    def forward(ctx, hidden, weight, bias, target, chunk):
        with torch.autocast(hidden.device.type, enabled=False):
            hidden, weight, bias = hidden.float(), weight.float(), bias.float()
            n = hidden.shape[0]
            lse, picked = hidden.new_empty(n), hidden.new_empty(n)
            correct = torch.empty(n, dtype=torch.bool, device=hidden.device)
            for start in range(0, n, chunk):
                end, goal = min(n, start + chunk), target[start : start + chunk]
                logits = torch.addmm(bias, hidden[start:end], weight.t())
                picked[start:end] = logits.gather(1, goal[:, None])[:, 0]
                top, best = logits.max(1)
                correct[start:end] = best == goal
                lse[start:end] = top + logits.sub_(top[:, None]).exp_().sum(1).log_()
        ctx.save_for_backward(hidden, weight, bias, target, lse)
        ctx.chunk = chunk
        return (lse - picked).mean(), correct.float().mean()

    @staticmethod
    def backward(ctx, grad_loss, grad_accuracy):
        hidden, weight, bias, target, lse = ctx.saved_tensors
        n, chunk = hidden.shape[0], ctx.chunk
        grad_hidden = torch.empty_like(hidden)
        grad_weight, grad_bias = torch.zeros_like(weight), torch.zeros_like(bias)
        with torch.autocast(hidden.device.type, enabled=False):
            for start in range(0, n, chunk):
                end = min(n, start + chunk)
                p = torch.addmm(bias, hidden[start:end], weight.t()).sub_(lse[start:end, None]).exp_()
                p[torch.arange(end - start, device=p.device), target[start:end]] -= 1.0
                p.mul_(grad_loss / n)
                torch.mm(p, weight, out=grad_hidden[start:end])
                grad_weight.addmm_(p.t(), hidden[start:end])
                grad_bias.add_(p.sum(0))
        return grad_hidden, grad_weight, grad_bias, None, None


def head_cross_entropy(
    hidden: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, target: torch.Tensor, chunk: int = HEAD_CHUNK
) -> tuple[torch.Tensor, torch.Tensor]:
    """The mean cross-entropy of `target` (N,) under the logits `hidden @ weight.T + bias` ((N, C) rows, a (K, C)
    layer), differentiable in all three, and the fraction of positions whose target is the most probable code —
    without keeping the (N, K) logits."""
    return _HeadCrossEntropy.apply(hidden, weight, bias, target, chunk)
