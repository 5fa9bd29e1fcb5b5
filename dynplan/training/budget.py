"""How long a world-model stage trains (`TrainBudget`), apart from the training loop (`loop.py`) so that a
command, preset or registry entry can name and check a budget without importing torch."""

from __future__ import annotations

from typing import TYPE_CHECKING

from pydantic import Field, field_validator, model_validator

from dynplan.config import Config
from dynplan.training.precision import Precision, bfloat16_missing

if TYPE_CHECKING:
    import torch


class TrainBudget(Config):
    """How long to train: epochs of `steps_per_epoch` batches, optionally capped in wall-clock minutes."""

    epochs: int = Field(20, ge=1, le=100_000, description="epochs to train (in total, counting resumed ones)")
    steps_per_epoch: int = Field(500, ge=1, le=1_000_000, description="batches per epoch")
    val_frames: int = Field(2000, ge=1, le=1_000_000, description="validation items scored after each epoch")
    max_minutes: float | None = Field(None, gt=0, description="stop (resumably) after this much wall time")
    threads: int | None = Field(None, ge=1, le=256, description="torch threads (default: all cores)")
    seed: int = Field(0, ge=0, le=2**62, description="seed of initialisation and batch order")
    init_from: str | None = Field(None, description="checkpoint whose model weights start the run (fine-tuning)")
    device: str | None = Field(None, description="torch device to train on, e.g. 'cuda' (default: the CPU)")
    precision: Precision = Field(
        "float32", description="arithmetic of the training steps: bfloat16 autocast needs a device that has it"
    )

    _neutral = {"init_from": None, "device": None, "precision": "float32"}

    @field_validator("device")
    @classmethod
    def _known_device(cls, value: str | None) -> str | None:
        if value is not None:
            import torch  # only to check a device named: the budget itself is read without torch

            try:
                device = torch.device(value)
            except RuntimeError:
                raise ValueError(f"unknown torch device {value!r} (e.g. 'cpu', 'cuda', 'cuda:1')") from None
            if device.type == "cuda" and not torch.cuda.is_available():
                raise ValueError(f"device {value!r}: this torch build sees no CUDA device (torch {torch.__version__})")
        return value

    @model_validator(mode="after")
    def _device_has_precision(self) -> TrainBudget:
        if self.precision == "bfloat16":
            missing = bfloat16_missing(self.torch_device)
            if missing:
                raise ValueError(f"precision='bfloat16': {missing}; valid here: float32")
        return self

    @property
    def torch_device(self) -> torch.device:
        import torch

        return torch.device(self.device or "cpu")
