"""The VQ-VAE tokenizer (docs/protocol.md §2, stage 1): a 48 × 48 frame ↔ an h × w grid of discrete codes.

Encoder: 4 × 4 convolutions (stride 2 halves the grid, stride 1 keeps it), optional residual blocks, a 1 × 1
projection to latent_dim channels; vector quantization with one codebook; a mirrored decoder of transposed
convolutions ending in a pixel likelihood (`likelihood.py`). The paper's configuration is `configs.PRESETS["paper"]`:
channels 42, 32, 16, 16, strides 2, 2, 2, 1 (6 × 6 codes), K = 512, DMoL with 10 components, codebook loss.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from dynplan.data.patches import tiles
from dynplan.env.config import GOAL_VALUE
from dynplan.models.configs import VQVAEConfig
from dynplan.models.likelihood import Categorical, DMoL, to_unit, value_index
from dynplan.models.quantize import VectorQuantizer
from dynplan.world import world

#: Frames the decoder decodes in one pass at inference: the paper's convolutional decoder is faster per frame in
#: blocks of about this many than over hundreds at once, whose activations leave the caches.
DECODE_ROWS = 64

#: The logit scales (inverse temperatures, 0.1 … 100) a calibrated decoder picks from, per code.
SHARPNESS_GRID = torch.logspace(-1, 2, 61)


def padded(frames: np.ndarray, config: VQVAEConfig) -> np.ndarray:
    """uint8 frames (..., height, W) with `config.pad_top` rows of the world's background above (row 0 is the
    bottom), as the tokenizer encodes them."""
    if not config.pad_top:
        return frames
    pad = np.full((*frames.shape[:-2], config.pad_top, frames.shape[-1]), world(config.world).background, np.uint8)
    return np.concatenate([frames, pad], axis=-2)


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
        self.block = nn.Sequential(
            nn.ReLU(),
            nn.Conv2d(channels, channels, kernel, padding=kernel // 2),
            nn.ReLU(),
            nn.Conv2d(channels, channels, 1),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.block(x)


@dataclass
class VQVAEOutput:
    """params: decoder output (B, C, H, W); codes (B, h, w); losses by name; perplexity; code use (K,)."""

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
        latent = c.latent_dim
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
        self.quantizer = VectorQuantizer(c.codebook_size, c.latent_dim, c.commitment)
        self.pixel = DMoL(c.n_mixtures) if c.likelihood == "dmol" else Categorical(c.values)
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

    @classmethod
    def from_checkpoint(cls, config: dict, weights: dict[str, torch.Tensor]) -> VQVAE:
        """The tokenizer a checkpoint holds: its recorded `config` and `weights`. A checkpoint records the whole
        config of the code that trained it; settings this code does not have (training-only ones, which do not
        change what the trained model computes: docs/experiments.md, tokenizers) are left out, as is the codebook's
        running statistics, and the weights must fit the architecture the rest builds (a RuntimeError naming the
        tensors otherwise). A codebook recorded with a leading axis of one is that codebook."""
        model = cls(cls.recorded_config(config))
        model.load_state_dict(cls.recorded_weights(weights, model.state_dict()))
        return model

    @staticmethod
    def recorded_config(config: dict) -> VQVAEConfig:
        """The config a checkpoint records, less the settings this code does not have (training-only ones)."""
        return VQVAEConfig(**{k: v for k, v in config.items() if k in VQVAEConfig.model_fields})

    @staticmethod
    def recorded_weights(weights: dict, own: Collection[str]) -> dict:
        """A checkpoint's weights as a model whose state has the keys `own` takes them: the codebook's running
        statistics (training-only) left out, a codebook recorded with a leading axis of one as that codebook."""
        weights = {k: v for k, v in weights.items() if k in own or not k.startswith("quantizer.")}
        embed = weights.get("quantizer.embed")
        if isinstance(embed, torch.Tensor) and embed.dim() == 3 and embed.shape[0] == 1:
            weights["quantizer.embed"] = embed[0]
        return weights

    def forward(self, frames: torch.Tensor) -> VQVAEOutput:
        """uint8 frames (B, H, W) → reconstruction parameters, codes and the training losses (on the padded
        frames)."""
        frames = self._padded(frames)
        z = self.encoder(to_unit(frames).unsqueeze(1))
        q = self.quantizer(z)
        params = self.decoder(q.quantized)
        losses = {"reconstruction": self.reconstruction_loss(params, frames), "vq": q.loss}
        return VQVAEOutput(params, q.codes, losses, q.perplexity, q.counts)

    def reconstruction_loss(self, params: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
        """Mean per-pixel negative log-likelihood of uint8 `frames`, goal pixels weighted by `goal_weight`."""
        nll = self.pixel.nll(params, frames)
        if self.config.goal_weight != 1.0:
            nll = nll * torch.where(frames == GOAL_VALUE, self.config.goal_weight, 1.0)
        return nll.mean()

    @property
    def patch(self) -> tuple[int, int]:
        """(rows, columns) of the frame patch one code covers."""
        h, w = self.config.grid
        return (self.config.height + self.config.pad_top) // h, self.config.width // w

    def _padded(self, frames: torch.Tensor) -> torch.Tensor:
        """uint8 frames (B, height, W) → (B, height + pad_top, W), the background above (`padded`)."""
        if not self.config.pad_top:
            return frames
        pad = frames.new_full((len(frames), self.config.pad_top, frames.shape[-1]), world(self.config.world).background)
        return torch.cat([frames, pad], dim=1)

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
        q.embed.copy_(self.encoder(to_unit(contents).unsqueeze(1)).flatten(1))

    @torch.inference_mode()
    def encode(self, frames: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
        """uint8 frames (N, H, W), or one frame (H, W) → integer codes (N, h, w), or (h, w). Returns the kind it
        is given: numpy in, numpy (int64) out; a tensor in, a tensor out."""
        frames, numpy_in, single = _array_in(
            frames, "frames", "encode", "uint8 frames (N, H, W) or one (H, W)", (2, 3), integer=False
        )
        codes = self._encode(frames)
        return _array_out(codes, numpy_in, single)

    def _encode(self, frames: torch.Tensor) -> torch.Tensor:
        frames = self._padded(frames)
        if self.config.local:
            return self._encode_distinct_patches(frames)
        return self.quantizer.nearest(self.encoder(to_unit(frames).unsqueeze(1)))

    def _encode_distinct_patches(self, frames: torch.Tensor) -> torch.Tensor:
        """A patch-local code is a function of its patch alone: encode each distinct patch once (most of this
        world's patches are empty road, so a store encodes tens of times faster) and spread the codes back."""
        ph, pw = self.patch
        h, w = frames.shape[-2] // ph, frames.shape[-1] // pw
        flat = tiles(frames.cpu().numpy(), (ph, pw))
        keys, inverse = np.unique(flat.view(f"V{ph * pw}").ravel(), return_inverse=True)
        contents = torch.from_numpy(keys.view(np.uint8).reshape(-1, ph, pw)).to(frames.device)
        codes = self.quantizer.nearest(self.encoder(to_unit(contents).unsqueeze(1)))  # (U, 1, 1)
        index = torch.from_numpy(inverse.reshape(-1)).to(frames.device)
        return codes.reshape(len(keys))[index].reshape(len(frames), h, w)

    @torch.inference_mode()
    def decode_params(self, codes: torch.Tensor, channels: int | None = None) -> torch.Tensor:
        """Integer codes (N, h, w) → the decoder's likelihood parameters (N, C, H, W), in blocks of `DECODE_ROWS`
        frames (a frame's output does not depend on the others in its block). `channels`: only the first `channels`
        of C where that is cheaper (a last transposed convolution computes only those output channels, the same
        numbers; what a DMoL mid-point needs). The padded rows are dropped: (N, C, height, W)."""
        if len(codes) > DECODE_ROWS:
            return torch.cat(
                [self.decode_params(codes[s : s + DECODE_ROWS], channels) for s in range(0, len(codes), DECODE_ROWS)]
            )
        latent = self.quantizer.lookup(codes.long())
        last = self.decoder[-1]
        if (
            channels is not None
            and isinstance(last, nn.ConvTranspose2d)
            and channels < last.out_channels
            and not self.config.calibrate_decoder
        ):
            params = F.conv_transpose2d(
                self.decoder[:-1](latent),
                last.weight[:, :channels].contiguous(),
                last.bias[:channels],
                last.stride,
                last.padding,
                last.output_padding,
                last.groups,
                last.dilation,
            )
        else:
            params = self.decoder(latent)
        if self.config.calibrate_decoder:
            ph, pw = self.patch
            scale = self.code_sharpness[codes.long()].repeat_interleave(ph, 1).repeat_interleave(pw, 2)
            params = params * scale[:, None]
        return params[:, :, : self.config.height] if self.config.pad_top else params

    @torch.inference_mode()
    def decode_by_code(self, codes: torch.Tensor) -> torch.Tensor:
        """Integer codes (N, h, w) → uint8 mid-point frames (N, H, W) of a patch-local model, each of the K codes'
        patches decoded once and laid out by `codes`: `decode`'s mid-points up to float summation order (a code
        decodes to its own patch alone), for the cost of K patches instead of N · h · w."""
        if not self.config.local:
            raise ValueError("VQVAE.decode_by_code: a code decodes to its own patch only in a patch-local model")
        K, (ph, pw) = self.config.codebook_size, self.patch
        each = torch.arange(K, device=codes.device)[:, None, None]
        table = self.pixel.mid(self.decode_params(each, self.pixel.mid_channels))  # (K, ph, pw)
        N, h, w = codes.shape
        frames = table[codes.long()].permute(0, 1, 3, 2, 4).reshape(N, h * ph, w * pw)
        return frames[:, : self.config.height] if self.config.pad_top else frames

    @torch.no_grad()
    def calibrate(
        self, contents: torch.Tensor, counts: torch.Tensor, scales: torch.Tensor = SHARPNESS_GRID
    ) -> torch.Tensor:
        """Temperature scaling, one temperature per code: set each code's logit scale to the one of `scales` that
        maximises the likelihood of the distinct patch `contents` (U, ph, pw), weighted by their `counts`, that
        encode to it; codes no content encodes to keep scale 1. Returns the scales (K,)."""
        codes = self.quantizer.nearest(self.encoder(to_unit(contents).unsqueeze(1))).reshape(-1)
        logits = self.decoder(self.quantizer.lookup(codes[:, None, None]))  # (U, values, ph, pw)
        target = value_index(contents, self.pixel.values)
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
        """Integer codes (N, h, w), or one grid (h, w) → uint8 mid-point frames (N, H, W), or (H, W), on the
        world's pixel values; numpy in, numpy out."""
        codes, numpy_in, single = _array_in(
            codes, "codes", "decode", "integer codes (N, h, w) or one grid (h, w)", (2, 3), integer=True
        )
        if codes.numel() and (int(codes.min()) < 0 or int(codes.max()) >= self.config.codebook_size):
            raise ValueError(
                f"VQVAE.decode: codes must lie in [0, {self.config.codebook_size}); got values in "
                f"[{int(codes.min())}, {int(codes.max())}]"
            )
        return _array_out(self.pixel.mid(self.decode_params(codes, self.pixel.mid_channels)), numpy_in, single)

    @torch.inference_mode()
    def decode_samples(self, codes: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """codes (N, …) → n samples per frame from the pixel likelihood: uint8 (n, N, H, W)."""
        return self.decode_with_samples(codes, n, generator)[1]

    @torch.inference_mode()
    def decode_with_samples(
        self, codes: torch.Tensor, n: int, generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """codes (N, …) → the mid-point frames (N, H, W) and n samples per frame (n, N, H, W), uint8, from one
        pass of the decoder (what the planner's *N samples* variants need)."""
        params = self.decode_params(codes)
        return self.pixel.mid(params), self.pixel.sample_with(params, self.pixel.noise(params.shape, n, generator))


def _array_in(
    x, name: str, method: str, expect: str, dims: tuple[int, int], integer: bool
) -> tuple[torch.Tensor, bool, bool]:
    """`x` as a batched tensor, whether it came as numpy, and whether it was a single item (one dimension less);
    a wrong type, dtype or rank is one line naming the argument."""
    numpy_in = isinstance(x, np.ndarray)
    if not numpy_in and not isinstance(x, torch.Tensor):
        raise TypeError(
            f"VQVAE.{method}: {name} must be a numpy array or a torch tensor of {expect}; got {type(x).__name__}"
        )
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
