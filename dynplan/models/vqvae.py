"""The VQ-VAE tokenizer (docs/protocol.md §2, stage 1): a 48 × 48 frame ↔ an h × w grid of discrete codes.

Encoder: 4 × 4 convolutions (stride 2 halves the grid, stride 1 keeps it), optional residual blocks, a 1 × 1
projection to n_codebooks × latent_dim channels; vector quantization; a mirrored decoder of transposed
convolutions ending in a pixel likelihood (`likelihood.py`). The paper's configuration is `PRESETS["paper"]`:
channels 42, 32, 16, 16, strides 2, 2, 2, 1 (6 × 6 codes), K = 512, DMoL with 10 components, codebook loss.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
import torch.nn.functional as F
from pydantic import Field, model_validator
from torch import nn

from dynplan.config import Config
from dynplan.data.patches import tiles
from dynplan.env.config import FREE, GOAL_VALUE
from dynplan.models.likelihood import Categorical, DMoL, to_unit, value_index
from dynplan.models.quantize import VectorQuantizer

#: Frames the decoder decodes in one pass at inference: the paper's convolutional decoder is faster per frame in
#: blocks of about this many than over hundreds at once, whose activations leave the caches.
DECODE_ROWS = 64

#: The logit scales (inverse temperatures, 0.1 … 100) a calibrated decoder picks from, per code.
SHARPNESS_GRID = torch.logspace(-1, 2, 61)


class VQVAEConfig(Config):
    """Architecture and optimisation of a VQ-VAE; `PRESETS` holds the named ones."""

    name: str = Field("custom", description="preset name, recorded in checkpoints")
    height: int = Field(48, ge=8, le=512, description="frame rows")
    width: int = Field(48, ge=8, le=512, description="frame columns")
    channels: tuple[int, ...] = Field((42, 32, 16, 16), description="encoder conv widths, input side first")
    strides: tuple[int, ...] = Field((2, 2, 2, 1), description="encoder conv strides (1 or 2 each)")
    residual_blocks: int = Field(0, ge=0, le=16, description="residual blocks at the code resolution")
    latent_dim: int = Field(16, ge=1, le=1024, description="channels per code")
    codebook_size: int = Field(512, ge=2, le=65536, description="K, entries per codebook")
    n_codebooks: int = Field(1, ge=1, le=16, description="codes per grid position")
    likelihood: Literal["dmol", "categorical"] = Field("dmol", description="decoder pixel likelihood")
    n_mixtures: int = Field(10, ge=1, le=64, description="DMoL components")
    ema: bool = Field(False, description="EMA codebook updates instead of the codebook loss")
    restart_dead: bool = Field(False, description="move unused codes onto encoder outputs (EMA only)")
    commitment: float = Field(0.25, ge=0.0, le=10.0, description="commitment loss weight β")
    obstacle_weight: float = Field(1.0, gt=0.0, le=100.0, description="loss weight of non-free pixels")
    goal_weight: float = Field(1.0, gt=0.0, le=1000.0, description="loss weight of goal pixels")
    learning_rate: float = Field(1e-3, gt=0.0, le=1.0, description="Adam learning rate")
    batch_size: int = Field(32, ge=1, le=4096, description="frames per batch")
    local: bool = Field(
        False,
        description="patch-local codes: kernels equal to strides and 1 × 1 residual blocks, so each code "
        "depends only on its own patch and decodes to that patch alone",
    )
    restart_onto: Literal["random", "worst"] = Field(
        "random", description="where dead codes restart: random encoder outputs, or ones drawn by quantisation error"
    )
    ema_decay: float = Field(
        0.99, gt=0.0, lt=1.0, description="EMA decay of the codebook; an unused code dies after ~4.6/(1−decay) batches"
    )
    codebook_fit: Literal["learned", "contents"] = Field(
        "learned",
        description="learned: the usual VQ-VAE training on frames; contents (patch-local only): train encoder and "
        "decoder as an autoencoder of the distinct patch contents, and set the codebook to the encoder's outputs "
        "of the K most frequent ones, so that each of them has a code of its own and decodes exactly",
    )

    calibrate_decoder: bool = Field(
        False,
        description="contents fit: after each codebook fit, scale each code's decoder logits by the temperature "
        "that maximises the likelihood of the training patches (as often as they occur) given their codes, so "
        "that decoder samples are as certain as the data make them (mid-point frames are unchanged)",
    )

    _neutral = {"goal_weight": 1.0, "local": False, "restart_onto": "random", "ema_decay": 0.99,
                "codebook_fit": "learned", "calibrate_decoder": False}  # fmt: skip

    @model_validator(mode="after")
    def _check_shape(self) -> VQVAEConfig:
        if len(self.channels) != len(self.strides) or not self.channels:
            raise ValueError("channels and strides must be non-empty and of the same length")
        if any(s not in (1, 2) for s in self.strides):
            raise ValueError(f"strides must each be 1 or 2, got {self.strides}")
        scale = 2 ** sum(s == 2 for s in self.strides)
        if self.height % scale or self.width % scale:
            raise ValueError(f"frame {self.height}×{self.width} is not divisible by the encoder's stride {scale}")
        if self.restart_dead and not self.ema:
            raise ValueError("restart_dead needs ema=True")
        if self.codebook_fit == "contents" and not (self.local and self.n_codebooks == 1):
            raise ValueError("codebook_fit='contents' needs local=True and n_codebooks=1")
        if self.calibrate_decoder and (self.codebook_fit != "contents" or self.likelihood != "categorical"):
            raise ValueError("calibrate_decoder needs codebook_fit='contents' and likelihood='categorical'")
        return self

    @property
    def grid(self) -> tuple[int, int]:
        """(h, w) of the code grid."""
        scale = 2 ** sum(s == 2 for s in self.strides)
        return self.height // scale, self.width // scale


PRESETS: dict[str, VQVAEConfig] = {
    # The paper's model (docs/protocol.md §2), as published: 6 × 6 codes from a 512-entry codebook, DMoL likelihood.
    "paper": VQVAEConfig(name="paper"),
    # Ours: a 12 × 12 grid of patch-local codes, one per 4 × 4 patch, from 4096 entries, a categorical likelihood
    # over the world's 7 values. The codebook is content-fitted: encoder and decoder are trained as an autoencoder
    # of the distinct patch contents and each of the 4096 most frequent (99.98 % of patches) gets a code of its own;
    # each code's decoder temperature is then calibrated to how often the patches occur. Goal pixels weigh 10× in
    # the loss; the EMA fields are unused by the content fit but part of the committed run's config (and key).
    # The committed weights are run `vqvae-default-1de9881c4f7e` (docs/design.md, tokenizer).
    "default": VQVAEConfig(
        name="default",
        channels=(32, 64),
        strides=(2, 2),
        residual_blocks=2,
        latent_dim=32,
        codebook_size=4096,
        likelihood="categorical",
        ema=True,
        restart_dead=True,
        goal_weight=10.0,
        learning_rate=1e-3,
        batch_size=1024,
        local=True,
        codebook_fit="contents",
        calibrate_decoder=True,
    ),
}


def _conv(c_in: int, c_out: int, stride: int, local: bool = False) -> nn.Module:
    if local:  # non-overlapping: each output sees exactly its own stride × stride input block
        return nn.Conv2d(c_in, c_out, stride, stride=stride)
    if stride == 2:
        return nn.Conv2d(c_in, c_out, 4, stride=2, padding=1)
    # A 4 × 4 kernel keeps the size with padding 1 before and 2 after.
    return nn.Sequential(nn.ZeroPad2d((1, 2, 1, 2)), nn.Conv2d(c_in, c_out, 4))


def _deconv(c_in: int, c_out: int, stride: int, local: bool = False) -> nn.Module:
    if local:
        return nn.ConvTranspose2d(c_in, c_out, stride, stride=stride)
    if stride == 2:
        return nn.ConvTranspose2d(c_in, c_out, 4, stride=2, padding=1)
    return _conv(c_in, c_out, 1)  # a stride-1 "transpose" is a convolution


class Residual(nn.Module):
    def __init__(self, channels: int, kernel: int = 3):
        super().__init__()
        self.block = nn.Sequential(nn.ReLU(), nn.Conv2d(channels, channels, kernel, padding=kernel // 2), nn.ReLU(),
                                   nn.Conv2d(channels, channels, 1))  # fmt: skip

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.block(x)


@dataclass
class VQVAEOutput:
    """params: decoder output (B, C, H, W); codes (B, h, w, n); losses by name; perplexity; code use (n, K)."""

    params: torch.Tensor
    codes: torch.Tensor
    losses: dict[str, torch.Tensor]
    perplexity: torch.Tensor
    counts: torch.Tensor


class VQVAE(nn.Module):
    def __init__(self, config: VQVAEConfig):
        super().__init__()
        self.config = config
        c = config
        latent = c.latent_dim * c.n_codebooks
        widths = (1, *c.channels)
        layers: list[nn.Module] = []
        for i, stride in enumerate(c.strides):
            layers += [_conv(widths[i], widths[i + 1], stride, c.local)] + (
                [nn.ReLU()] if i < len(c.strides) - 1 else []
            )
        kernel = 1 if c.local else 3
        layers += [Residual(widths[-1], kernel) for _ in range(c.residual_blocks)]
        if c.residual_blocks:
            layers.append(nn.ReLU())
        if latent != widths[-1] or c.residual_blocks:
            layers.append(nn.Conv2d(widths[-1], latent, 1))
        self.encoder = nn.Sequential(*layers)
        self.quantizer = VectorQuantizer(c.codebook_size, c.latent_dim, c.n_codebooks, c.commitment, c.ema,
                                         decay=c.ema_decay, restart_dead=c.restart_dead,
                                         restart_onto=c.restart_onto)  # fmt: skip
        self.pixel = DMoL(c.n_mixtures) if c.likelihood == "dmol" else Categorical()
        layers = []
        if latent != widths[-1] or c.residual_blocks:
            layers.append(nn.Conv2d(latent, widths[-1], 1))
        layers += [Residual(widths[-1], kernel) for _ in range(c.residual_blocks)]
        outs = (*reversed(widths[1:-1]), self.pixel.channels)
        ins = tuple(reversed(widths[1:]))
        for i, stride in enumerate(reversed(c.strides)):
            layers += [nn.ReLU(), _deconv(ins[i], outs[i], stride, c.local)]
        self.decoder = nn.Sequential(*layers)
        if c.calibrate_decoder:  # per-code logit scale (inverse temperature), set by `calibrate`
            self.register_buffer("code_sharpness", torch.ones(c.codebook_size))

    def forward(self, frames: torch.Tensor) -> VQVAEOutput:
        """uint8 frames (B, H, W) → reconstruction parameters, codes and the training losses."""
        z = self.encoder(to_unit(frames).unsqueeze(1))
        q = self.quantizer(z)
        params = self.decoder(q.quantized)
        losses = {"reconstruction": self.reconstruction_loss(params, frames), "vq": q.loss}
        return VQVAEOutput(params, q.codes, losses, q.perplexity, q.counts)

    def reconstruction_loss(self, params: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
        """Mean per-pixel negative log-likelihood of uint8 `frames`, obstacle and goal pixels weighted."""
        nll = self.pixel.nll(params, frames)
        c = self.config
        if c.obstacle_weight != 1.0 or c.goal_weight != 1.0:
            weight = torch.where(frames != FREE, c.obstacle_weight, 1.0)  # goal pixels too (not FREE)
            nll = nll * weight * torch.where(frames == GOAL_VALUE, c.goal_weight, 1.0)
        return nll.mean()

    @property
    def patch(self) -> tuple[int, int]:
        """(rows, columns) of the frame patch one code covers."""
        h, w = self.config.grid
        return self.config.height // h, self.config.width // w

    def autoencode_params(self, patches: torch.Tensor) -> torch.Tensor:
        """uint8 patches (N, ph, pw) → likelihood parameters, without quantisation (patch-local models only):
        what `codebook_fit="contents"` trains."""
        return self.decoder(self.encoder(to_unit(patches).unsqueeze(1)))

    @torch.no_grad()
    def fit_codebook(self, contents: torch.Tensor) -> None:
        """Set the codebook to the encoder's outputs of uint8 patch `contents` (K, ph, pw), one code each."""
        q = self.quantizer
        if contents.shape[0] != q.K:
            raise ValueError(f"need {q.K} contents for the codebook, got {contents.shape[0]}")
        z = self.encoder(to_unit(contents).unsqueeze(1)).flatten(1)
        q.embed[0].copy_(z)
        if q.ema:  # consistent EMA state: each code its own cluster of one
            q.embed_sum[0].copy_(z)
            q.cluster_size[0].fill_(1.0)

    @torch.inference_mode()
    def encode(self, frames: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
        """uint8 frames (N, H, W), or one frame (H, W) → integer codes (N, h, w), or (h, w) (with several
        codebooks, (…, n)). Returns the kind it is given: numpy in, numpy (int64) out; a tensor in, a tensor out."""
        frames, numpy_in, single = _array_in(frames, "frames", "encode", "uint8 frames (N, H, W) or one (H, W)",
                                             (2, 3), integer=False)  # fmt: skip
        codes = self._encode(frames)
        return _array_out(codes, numpy_in, single)

    def _encode(self, frames: torch.Tensor) -> torch.Tensor:
        if self.config.local:
            codes = self._encode_distinct_patches(frames)
        else:
            codes = self.quantizer.nearest(self.encoder(to_unit(frames).unsqueeze(1)))
        return codes.squeeze(-1) if self.config.n_codebooks == 1 else codes

    def _encode_distinct_patches(self, frames: torch.Tensor) -> torch.Tensor:
        """A patch-local code is a function of its patch alone: encode each distinct patch once (most of this
        world's patches are empty road, so a store encodes tens of times faster) and spread the codes back."""
        ph, pw = self.patch
        h, w = frames.shape[-2] // ph, frames.shape[-1] // pw
        flat = tiles(frames.cpu().numpy(), (ph, pw))
        keys, inverse = np.unique(flat.view(f"V{ph * pw}").ravel(), return_inverse=True)
        contents = torch.from_numpy(keys.view(np.uint8).reshape(-1, ph, pw)).to(frames.device)
        codes = self.quantizer.nearest(self.encoder(to_unit(contents).unsqueeze(1)))  # (U, 1, 1, n)
        index = torch.from_numpy(inverse.reshape(-1)).to(frames.device)
        return codes.reshape(len(keys), -1)[index].reshape(len(frames), h, w, -1)

    @torch.inference_mode()
    def decode_params(self, codes: torch.Tensor, channels: int | None = None) -> torch.Tensor:
        """Integer codes (N, h, w[, n]) → the decoder's likelihood parameters (N, C, H, W), in blocks of `DECODE_ROWS`
        frames (a frame's output does not depend on the others in its block). `channels`: only the first `channels`
        of C where that is cheaper (a last transposed convolution computes only those output channels, the same
        numbers; what a DMoL mid-point needs)."""
        if codes.dim() == 3:
            codes = codes.unsqueeze(-1)
        if len(codes) > DECODE_ROWS:
            return torch.cat([self.decode_params(codes[s : s + DECODE_ROWS], channels)
                              for s in range(0, len(codes), DECODE_ROWS)])  # fmt: skip
        latent = self.quantizer.lookup(codes.long())
        last = self.decoder[-1]
        if (channels is not None and isinstance(last, nn.ConvTranspose2d) and channels < last.out_channels
                and not self.config.calibrate_decoder):  # fmt: skip
            return F.conv_transpose2d(self.decoder[:-1](latent), last.weight[:, :channels].contiguous(),
                                      last.bias[:channels], last.stride, last.padding, last.output_padding,
                                      last.groups, last.dilation)  # fmt: skip
        params = self.decoder(latent)
        if self.config.calibrate_decoder:
            ph, pw = self.patch
            scale = self.code_sharpness[codes[..., 0].long()].repeat_interleave(ph, 1).repeat_interleave(pw, 2)
            params = params * scale[:, None]
        return params

    @torch.no_grad()
    def calibrate(self, contents: torch.Tensor, counts: torch.Tensor,
                  scales: torch.Tensor = SHARPNESS_GRID) -> torch.Tensor:  # fmt: skip
        """Temperature scaling, one temperature per code: set each code's logit scale to the one of `scales` that
        maximises the likelihood of the distinct patch `contents` (U, ph, pw), weighted by their `counts`, that
        encode to it; codes no content encodes to keep scale 1. Returns the scales (K,)."""
        codes = self.quantizer.nearest(self.encoder(to_unit(contents).unsqueeze(1))).reshape(-1)
        logits = self.decoder(self.quantizer.lookup(codes[:, None, None, None]))  # (U, values, ph, pw)
        target = value_index(contents)
        nll = torch.stack([F.cross_entropy(logits * s, target, reduction="none").sum((1, 2)) for s in scales], 1)
        per_code = torch.zeros(self.config.codebook_size, len(scales), dtype=torch.float64, device=nll.device)
        per_code.index_add_(0, codes, nll.double() * counts.double()[:, None])
        used = torch.bincount(codes, minlength=self.config.codebook_size) > 0
        # ties (a likelihood of 1 to float precision) go to the sharpest scale
        best = scales.to(nll.device).flip(0)[per_code.flip(1).argmin(1)]
        self.code_sharpness.copy_(torch.where(used, best, torch.ones_like(best)))
        return self.code_sharpness.clone()

    @torch.inference_mode()
    def decode(self, codes: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
        """Integer codes (N, h, w), or one grid (h, w) (with several codebooks, (…, n)) → uint8 mid-point frames
        (N, H, W), or (H, W), on the world's pixel values; numpy in, numpy out."""
        n = self.config.n_codebooks
        dims = (2, 3) if n == 1 else (3, 4)
        codes, numpy_in, single = _array_in(codes, "codes", "decode", "integer codes (N, h, w) or one grid (h, w)",
                                            dims, integer=True)  # fmt: skip
        if codes.numel() and (int(codes.min()) < 0 or int(codes.max()) >= self.config.codebook_size):
            raise ValueError(f"VQVAE.decode: codes must lie in [0, {self.config.codebook_size}); got values in "
                             f"[{int(codes.min())}, {int(codes.max())}]")  # fmt: skip
        return _array_out(self.pixel.mid(self.decode_params(codes, self.pixel.mid_channels)), numpy_in, single)

    @torch.inference_mode()
    def decode_samples(self, codes: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """codes (N, …) → n samples per frame from the pixel likelihood: uint8 (n, N, H, W)."""
        return self.decode_with_samples(codes, n, generator)[1]

    @torch.inference_mode()
    def decode_with_samples(self, codes: torch.Tensor, n: int,
                            generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
        """codes (N, …) → the mid-point frames (N, H, W) and n samples per frame (n, N, H, W), uint8, from one
        pass of the decoder (what the planner's *N samples* variants need)."""
        params = self.decode_params(codes)
        return self.pixel.mid(params), self.pixel.sample_with(params, self.pixel.noise(params.shape, n, generator))


def _array_in(x, name: str, method: str, expect: str, dims: tuple[int, int],
              integer: bool) -> tuple[torch.Tensor, bool, bool]:  # fmt: skip
    """`x` as a batched tensor, whether it came as numpy, and whether it was a single item (one dimension less);
    a wrong type, dtype or rank is one line naming the argument."""
    numpy_in = isinstance(x, np.ndarray)
    if not numpy_in and not isinstance(x, torch.Tensor):
        raise TypeError(f"VQVAE.{method}: {name} must be a numpy array or a torch tensor of {expect}; "
                        f"got {type(x).__name__}")  # fmt: skip
    if numpy_in:
        good = np.issubdtype(x.dtype, np.integer) if integer else x.dtype == np.uint8
        dtype = str(x.dtype)
    else:
        good = (
            (not x.is_floating_point() and not x.is_complex() and x.dtype != torch.bool)
            if integer
            else (x.dtype == torch.uint8)
        )
        dtype = str(x.dtype).removeprefix("torch.")
    if not good or x.ndim not in dims:
        raise ValueError(f"VQVAE.{method}: {name} must be {expect}; got {dtype} of shape {tuple(x.shape)}")
    t = torch.from_numpy(np.ascontiguousarray(x, dtype=np.int64 if integer else np.uint8)) if numpy_in else x
    single = x.ndim == dims[0]
    return (t.unsqueeze(0) if single else t), numpy_in, single


def _array_out(t: torch.Tensor, numpy_in: bool, single: bool) -> np.ndarray | torch.Tensor:
    t = t[0] if single else t
    return t.cpu().numpy() if numpy_in else t
