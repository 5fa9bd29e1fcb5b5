"""Pixel likelihoods for the VQ-VAE decoder, over the world's few pixel values.

* `DMoL`: the discretized mixture of logistics of PixelCNN++ (the paper's choice), on [−1, 1] with 256 bins;
  its mid-point is the most probable component's mean, and both it and samples snap to the nearest world value.
* `Categorical`: a softmax over the values a world uses (the road's 7 — free, 5 obstacle classes, goal — by
  default; another world's legend when given); mid-point argmax.

Both map decoder outputs (B, C, H, W) to a per-pixel negative log-likelihood, a mid-point frame and samples,
as uint8 on the world's values.
"""

from __future__ import annotations

import numba
import numpy as np
import torch
import torch.nn.functional as F

from dynplan.env.config import FREE, GOAL_VALUE, obstacle_classes

#: (sample, frame) pairs `DMoL.sample_with` draws together on the CPU: their Gumbel noise (n_mix floats a pixel, 92 KB
#: a 48 × 48 frame at 10 components) stays in the caches.
SAMPLE_ROWS = 4

#: The pixel values a world frame can hold, ascending: free, the obstacle classes, the goal.
WORLD_VALUES = tuple(sorted({FREE, GOAL_VALUE, *(c.value for c in obstacle_classes(48))}))


def to_unit(frames: torch.Tensor) -> torch.Tensor:
    """uint8 frames → float in [−1, 1] (the VQ-VAE's input scale)."""
    return frames.float() / 127.5 - 1.0


def value_index(frames: torch.Tensor, values: tuple[int, ...] = WORLD_VALUES) -> torch.Tensor:
    """uint8 frames on `values` (ascending) → class indices 0 … len(values) − 1 (int64)."""
    lut = torch.zeros(256, dtype=torch.long, device=frames.device)
    lut[list(values)] = torch.arange(len(values), device=frames.device)
    return lut[frames.long()]


def snap(unit: torch.Tensor) -> torch.Tensor:
    """Values in [−1, 1] → uint8 frames on the nearest world value (the first of two equally near): one compiled
    pass on the CPU, `snap_tensor`'s numbers elsewhere."""
    if unit.device.type == "cpu" and unit.dtype == torch.float32:
        out = np.empty(unit.shape, np.uint8)
        _snap_into(np.ascontiguousarray(unit.numpy()).reshape(-1), np.array(WORLD_VALUES, np.float32), out.reshape(-1))
        return torch.from_numpy(out)
    return snap_tensor(unit)


def snap_tensor(unit: torch.Tensor) -> torch.Tensor:
    """`snap` as tensor operations (any device): argmin over the values of |(u + 1) · 127.5 − value|."""
    values = torch.tensor(WORLD_VALUES, dtype=torch.float32, device=unit.device)
    nearest = ((unit.unsqueeze(-1) + 1.0) * 127.5 - values).abs().argmin(-1)
    return values[nearest].to(torch.uint8)


@numba.njit(cache=True, inline="always")
def _nearest(unit, values):
    """The world value nearest (u + 1) · 127.5 in float32 arithmetic, as `snap`'s tensor form computes it."""
    y = (unit + np.float32(1.0)) * np.float32(127.5)
    best, distance = 0, abs(y - values[0])
    for v in range(1, values.shape[0]):
        d = abs(y - values[v])
        if d < distance:
            best, distance = v, d
    return np.uint8(values[best])


@numba.njit(cache=True, nogil=True)
def _snap_into(unit, values, out):
    """out[q] ← the world value nearest unit[q] (flat float32 → uint8): one pass, no (…, values) intermediates."""
    for q in range(unit.shape[0]):
        out[q] = _nearest(unit[q], values)


@numba.njit(cache=True, nogil=True)
def _mid_into(params, n, values, out):
    """out[b, y, x] ← the world value nearest the mean of the first most probable of n components, clamped to
    [−1, 1]: `DMoL.mid` over (B, ≥ 2n, H, W) float32 parameters (mixture logits, then means) in one pass."""
    B, _, H, W = params.shape
    one = np.float32(1.0)
    for b in range(B):
        for y in range(H):
            for x in range(W):
                best, top = 0, params[b, 0, y, x]
                for c in range(1, n):
                    if params[b, c, y, x] > top:
                        best, top = c, params[b, c, y, x]
                out[b, y, x] = _nearest(min(max(params[b, n + best, y, x], -one), one), values)


class DMoL:
    """Discretized mixture of `n_mix` logistics for one channel (PixelCNN++, Salimans et al. 2017)."""

    def __init__(self, n_mix: int = 10, bins: int = 256):
        self.n_mix, self.bins = n_mix, bins

    @property
    def channels(self) -> int:
        return 3 * self.n_mix

    @property
    def mid_channels(self) -> int:
        """The leading channels `mid` reads: the mixture logits and the means."""
        return 2 * self.n_mix

    def _split(self, params: torch.Tensor):
        logit_pi, mu, log_s = params.split(self.n_mix, dim=1)
        return logit_pi, mu, log_s.clamp(min=-7.0)

    def nll(self, params: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
        """(B, 3·n_mix, H, W), uint8 (B, H, W) → nats per pixel (B, H, W)."""
        x = to_unit(frames).unsqueeze(1)
        logit_pi, mu, log_s = self._split(params)
        centered = x - mu
        inv_s = torch.exp(-log_s)
        half_bin = 1.0 / (self.bins - 1)
        plus_in, min_in = inv_s * (centered + half_bin), inv_s * (centered - half_bin)
        cdf_delta = torch.sigmoid(plus_in) - torch.sigmoid(min_in)
        log_cdf_plus = plus_in - F.softplus(plus_in)  # x at the lowest bin
        log_one_minus_cdf_min = -F.softplus(min_in)  # x at the highest bin
        mid_in = inv_s * centered
        log_pdf_mid = mid_in - log_s - 2.0 * F.softplus(mid_in) - torch.log(torch.tensor((self.bins - 1) / 2.0))
        inner = torch.where(cdf_delta > 1e-5, torch.log(cdf_delta.clamp(min=1e-12)), log_pdf_mid)
        log_probs = torch.where(x < -0.999, log_cdf_plus, torch.where(x > 0.999, log_one_minus_cdf_min, inner))
        return -torch.logsumexp(log_probs + F.log_softmax(logit_pi, dim=1), dim=1)

    def mid(self, params: torch.Tensor) -> torch.Tensor:
        """The most probable component's mean, snapped: uint8 (B, H, W); `params` may stop after the means."""
        if params.device.type == "cpu" and params.dtype == torch.float32:  # one compiled pass
            out = np.empty((len(params), *params.shape[2:]), np.uint8)
            _mid_into(np.ascontiguousarray(params.numpy()), self.n_mix, np.array(WORLD_VALUES, np.float32), out)
            return torch.from_numpy(out)
        return self.mid_tensor(params)

    def mid_tensor(self, params: torch.Tensor) -> torch.Tensor:
        """`mid` as tensor operations (any device)."""
        logit_pi, mu = params[:, : self.n_mix], params[:, self.n_mix : 2 * self.n_mix]
        best = _channel_argmax(logit_pi).unsqueeze(1)
        return snap_tensor(mu.gather(1, best).squeeze(1).clamp(-1.0, 1.0))

    def noise(self, shape: torch.Size, n: int, generator: torch.Generator | None = None) -> tuple[torch.Tensor, ...]:
        """The uniform numbers n samples of params of `shape` (B, 3·n_mix, H, W) use: per sample, one per component
        and pixel (which component) and one per pixel (where in its logistic), drawn in that order."""
        B, _, H, W = shape
        draws = [(_uniform((B, self.n_mix, H, W), generator), _uniform((B, H, W), generator)) for _ in range(n)]
        return torch.stack([u for u, _ in draws]), torch.stack([v for _, v in draws])

    def sample_with(self, params: torch.Tensor, noise: tuple[torch.Tensor, ...]) -> torch.Tensor:
        """Samples (n, B, H, W) uint8 from the mixture given `noise` as `noise` draws it: a component by the Gumbel
        trick, then a point of its logistic by inverse transform, snapped. On the CPU in blocks of `SAMPLE_ROWS`
        (sample, frame) pairs, operation by operation in place, so that the n_mix-fold Gumbel noise stays in the
        caches instead of passing through memory once per operation (`sample_tensor`: the whole batch at once; the
        same numbers, `tests/test_vqvae.py`)."""
        u, v = (t.to(params.device) for t in noise)
        if params.device.type != "cpu":
            return self.sample_tensor(params, (u, v))
        logit_pi, mu, log_s = self._split(params)
        n, B, H, W = v.shape
        u, v = u.reshape(n * B, self.n_mix, H, W), v.reshape(n * B, H, W)
        frame = torch.arange(B).repeat(n)  # (sample, frame) pair r reads frame r mod B's parameters
        out = torch.empty(n * B, H, W, dtype=torch.uint8)
        for start in range(0, n * B, SAMPLE_ROWS):
            rows, of = slice(start, start + SAMPLE_ROWS), frame[start : start + SAMPLE_ROWS]
            gumbel = torch.log(u[rows])  # −log(−log u), negated: logit − log(−log u) is logit + Gumbel noise
            gumbel.neg_().log_()
            component = _channel_argmax(torch.sub(logit_pi[of], gumbel, out=gumbel)).unsqueeze(1)
            point = torch.log(v[rows])
            point -= torch.log1p(-v[rows])
            point *= log_s[of].gather(1, component).squeeze(1).exp_()
            point += mu[of].gather(1, component).squeeze(1)
            out[rows] = snap(point.clamp_(-1.0, 1.0))
        return out.reshape(n, B, H, W)

    def sample_tensor(self, params: torch.Tensor, noise: tuple[torch.Tensor, ...]) -> torch.Tensor:
        """`sample_with` over the whole batch at once (any device)."""
        logit_pi, mu, log_s = self._split(params)
        u, v = (t.to(params.device) for t in noise)
        component = _channel_argmax((logit_pi - torch.log(-torch.log(u))).flatten(0, 1))
        component = component.reshape(v.shape).unsqueeze(2)  # (n, B, 1, H, W)
        expand = (v.shape[0], *mu.shape)
        mu = mu.expand(expand).gather(2, component).squeeze(2)
        log_s = log_s.expand(expand).gather(2, component).squeeze(2)
        return snap((mu + torch.exp(log_s) * (torch.log(v) - torch.log1p(-v))).clamp(-1.0, 1.0))

    def sample(self, params: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """One sample per pixel from the mixture, snapped: uint8 (B, H, W)."""
        return self.sample_with(params, self.noise(params.shape, 1, generator))[0]


class Categorical:
    """A softmax over a world's pixel `values` (ascending; the road's 7 by default)."""

    def __init__(self, values: tuple[int, ...] = WORLD_VALUES):
        if list(values) != sorted(set(values)) or not all(0 <= v <= 255 for v in values):
            raise ValueError(f"values must be distinct pixel values in [0, 255], ascending; got {values}")
        self.values = tuple(values)
        self.channels = self.mid_channels = len(values)

    def nll(self, logits: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
        return F.cross_entropy(logits, value_index(frames, self.values), reduction="none")

    def mid(self, logits: torch.Tensor) -> torch.Tensor:
        return torch.tensor(self.values, dtype=torch.uint8, device=logits.device)[_channel_argmax(logits)]

    def noise(self, shape: torch.Size, n: int, generator: torch.Generator | None = None) -> tuple[torch.Tensor, ...]:
        """The uniform numbers n samples of logits of `shape` (B, values, H, W) use: one per sample and pixel."""
        B, _, H, W = shape
        return (_uniform((n, B, H, W), generator),)

    def sample_with(self, logits: torch.Tensor, noise: tuple[torch.Tensor, ...]) -> torch.Tensor:
        """Samples (n, B, H, W) uint8 given `noise` as `noise` draws it: each pixel's value by inverse transform
        of its softmax (the first value whose cumulative probability exceeds the pixel's number)."""
        cdf = torch.softmax(logits, dim=1).cumsum(1)  # (B, values, H, W)
        u = noise[0].to(logits.device)
        index = torch.zeros(u.shape, dtype=torch.uint8, device=u.device)
        for value in range(cdf.shape[1] - 1):  # how many cumulative probabilities the number reaches: the last
            index += u >= cdf[:, value]  # value takes whatever rounding leaves above cdf[-2]
        return torch.tensor(self.values, dtype=torch.uint8, device=logits.device)[index.long()]

    def sample(self, logits: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        return self.sample_with(logits, self.noise(logits.shape, 1, generator))[0]


def _uniform(shape: tuple[int, ...], generator: torch.Generator | None) -> torch.Tensor:
    """Uniform numbers in [1e-5, 1 − 1e-5] (their logarithms stay finite)."""
    return torch.rand(shape, generator=generator).clamp(1e-5, 1 - 1e-5)


def _channel_argmax(x: torch.Tensor) -> torch.Tensor:
    """argmax over dim 1 of (B, C, H, W), reduced over contiguous rows (channels last): the same index, several
    times faster than reducing over the strided channel axis."""
    return x.permute(0, 2, 3, 1).contiguous().argmax(-1)
