"""The settings of a learned world model's two networks and their named presets: the VQ-VAE tokenizer's
(`VQVAEConfig`, `PRESETS`) and the conditional PixelCNN prior's (`PixelCNNConfig`, `PIXELCNN_PRESETS`).

Kept apart from the networks (`vqvae.py`, `pixelcnn.py`) so that a command can parse, check and list them
without importing torch.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from dynplan.config import Config, ConfigError
from dynplan.world import DEFAULT_WORLD, world

#: A configuration's name: part of its run folders' names, so letters, digits, '_', '.', '-' (up to 64).
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"


class VQVAEConfig(Config):
    """Architecture and optimisation of a VQ-VAE; `PRESETS` holds the named ones."""

    name: str = Field(
        "custom", pattern=NAME_PATTERN, description="preset name, recorded in checkpoints and run folders"
    )
    world: str = Field(DEFAULT_WORLD, description="the world whose frames it encodes (its pixel values)")
    height: int = Field(48, ge=8, le=512, description="frame rows")
    width: int = Field(48, ge=8, le=512, description="frame columns")
    pad_top: int = Field(
        0,
        ge=0,
        le=64,
        description="rows of the world's background added above a frame before it is encoded (and "
        "dropped after decoding), so that the code grid's rows line up with the world's lanes",
    )
    channels: tuple[int, ...] = Field((42, 32, 16, 16), description="encoder conv widths, input side first")
    strides: tuple[int, ...] = Field((2, 2, 2, 1), description="encoder conv strides (1 or 2 each)")
    residual_blocks: int = Field(0, ge=0, le=16, description="residual blocks at the code resolution")
    latent_dim: int = Field(16, ge=1, le=1024, description="channels per code")
    codebook_size: int = Field(512, ge=2, le=65536, description="K, entries per codebook")
    likelihood: Literal["dmol", "categorical"] = Field("dmol", description="decoder pixel likelihood")
    n_mixtures: int = Field(10, ge=1, le=64, description="DMoL components")
    commitment: float = Field(0.25, ge=0.0, le=10.0, description="commitment loss weight β")
    goal_weight: float = Field(1.0, gt=0.0, le=1000.0, description="loss weight of goal pixels")
    learning_rate: float = Field(1e-3, gt=0.0, le=1.0, description="Adam learning rate")
    batch_size: int = Field(32, ge=1, le=4096, description="frames per batch")
    local: bool = Field(
        False,
        description="patch-local codes: kernels equal to strides and 1 × 1 residual blocks, so each code "
        "depends only on its own patch and decodes to that patch alone",
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

    _neutral = {
        "goal_weight": 1.0,
        "local": False,
        "codebook_fit": "learned",
        "calibrate_decoder": False,
        "world": DEFAULT_WORLD,
        "pad_top": 0,
    }

    @model_validator(mode="after")
    def _check_shape(self) -> VQVAEConfig:
        if len(self.channels) != len(self.strides) or not self.channels:
            raise ValueError("channels and strides must be non-empty and of the same length")
        if any(s not in (1, 2) for s in self.strides):
            raise ValueError(f"strides must each be 1 or 2, got {self.strides}")
        try:
            world(self.world)
        except ConfigError as error:
            raise ValueError(str(error)) from None
        if self.world != DEFAULT_WORLD and self.likelihood == "dmol":
            raise ValueError(
                f"likelihood 'dmol' snaps to the road's pixel values; the {self.world} world needs 'categorical'"
            )
        scale = 2 ** sum(s == 2 for s in self.strides)
        if (self.height + self.pad_top) % scale or self.width % scale:
            raise ValueError(
                f"frame {self.height}×{self.width} (padded by {self.pad_top} rows) is not divisible by "
                f"the encoder's stride {scale}"
            )
        if self.codebook_fit == "contents" and not self.local:
            raise ValueError("codebook_fit='contents' needs local=True")
        if self.calibrate_decoder and (self.codebook_fit != "contents" or self.likelihood != "categorical"):
            raise ValueError("calibrate_decoder needs codebook_fit='contents' and likelihood='categorical'")
        return self

    @property
    def grid(self) -> tuple[int, int]:
        """(h, w) of the code grid."""
        scale = 2 ** sum(s == 2 for s in self.strides)
        return (self.height + self.pad_top) // scale, self.width // scale

    @property
    def values(self) -> tuple[int, ...]:
        """The pixel values of the world's frames, ascending."""
        return world(self.world).values()


PRESETS: dict[str, VQVAEConfig] = {
    # The paper's model (docs/protocol.md §2), as published: 6 × 6 codes from a 512-entry codebook, DMoL likelihood.
    "paper": VQVAEConfig(name="paper"),
    # Ours: a 12 × 12 grid of patch-local codes, one per 4 × 4 patch, from 4096 entries, a categorical likelihood
    # over the world's 7 values. The codebook is content-fitted: encoder and decoder are trained as an autoencoder
    # of the distinct patch contents and each of the 4096 most frequent (99.98 % of patches) gets a code of its own;
    # each code's decoder temperature is then calibrated to how often the patches occur. Goal pixels weigh 10× in
    # the loss. The committed weights are run `vqvae-default-1de9881c4f7e` (docs/design.md, tokenizer), whose
    # recorded config also names the training-only settings of the code that trained it (`VQVAE.from_checkpoint`).
    "default": VQVAEConfig(
        name="default",
        channels=(32, 64),
        strides=(2, 2),
        residual_blocks=2,
        latent_dim=32,
        codebook_size=4096,
        likelihood="categorical",
        goal_weight=10.0,
        learning_rate=1e-3,
        batch_size=1024,
        local=True,
        codebook_fit="contents",
        calibrate_decoder=True,
    ),
}


class PixelCNNConfig(Config):
    """Size of the prior; `PIXELCNN_PRESETS` holds the named ones."""

    name: str = Field(
        "custom", pattern=NAME_PATTERN, description="preset name, recorded in checkpoints and run folders"
    )
    codebook_size: int = Field(512, ge=2, le=65536, description="K: code values (the VQ-VAE's codebook size)")
    context: int = Field(4, ge=1, le=16, description="previous code grids conditioned on")
    channels: int = Field(64, ge=4, le=1024, description="channels of both stacks")
    layers: int = Field(8, ge=2, le=64, description="gated layers (the first is masked A)")
    first_kernel: int = Field(7, ge=3, le=15, description="kernel of the first layer (odd)")
    kernel: int = Field(3, ge=3, le=15, description="kernel of the other layers (odd)")
    embed_dim: int = Field(32, ge=1, le=512, description="embedding size of one code")
    condition_channels: int = Field(64, ge=1, le=1024, description="channels of the conditioning map")
    learning_rate: float = Field(3e-4, gt=0, le=1.0, description="Adam learning rate")
    learning_rate_halflife: int | None = Field(
        None,
        ge=1,
        le=10**12,
        description="windows after which the learning rate halves (exponential decay; None: constant)",
    )
    batch_size: int = Field(64, ge=1, le=8192, description="windows per batch")
    codebook_init: bool = Field(
        False, description="start both code embeddings from the tokenizer's codebook (else random)"
    )
    condition_width: int = Field(
        3, ge=3, le=31, description="columns of the conditioning convolutions' kernels (odd; rows: 3)"
    )
    strip_rows: int | None = Field(
        None,
        ge=1,
        le=64,
        description="a world of lanes: each grid is cut into strips of this many code rows, each "
        "modelled (and generated) as a grid of its own, all strips of a grid at once (None: whole grids)",
    )

    _neutral = {"learning_rate_halflife": None, "codebook_init": False, "condition_width": 3, "strip_rows": None}

    @model_validator(mode="after")
    def _check_kernels(self) -> PixelCNNConfig:
        if self.condition_width % 2 != 1:
            raise ValueError(f"condition_width must be odd, got {self.condition_width}")
        return self


PIXELCNN_PRESETS: dict[str, PixelCNNConfig] = {
    # Priors for the two tokenizers (K follows each one's codebook), sized so that planning samples them fast on a
    # CPU. The paper's: 64 channels × 8 layers, batches of 256 at rate 1e-3 (trained on a GPU, `--device`).
    "paper": PixelCNNConfig(name="paper", codebook_size=512, batch_size=256, learning_rate=1e-3),
    # The default's 12 × 12 grid has 4× the positions and an 8× wider head: 32 channels and a 5 × 5 first kernel
    # train 2× faster per window on a CPU than 64 and 7 and learn as fast per minute; embeddings started from the
    # codebook reach 15.6 % code accuracy in 4 minutes against 11.2 % from random (docs/design.md, prior).
    "default": PixelCNNConfig(
        name="default",
        codebook_size=4096,
        channels=32,
        first_kernel=5,
        codebook_init=True,
        batch_size=64,
        learning_rate=1e-3,
    ),
}
