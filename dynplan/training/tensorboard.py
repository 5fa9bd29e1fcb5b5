"""TensorBoard output of a training run: every epoch's figures as scalars and the stage's pictures as images.

Asked for with a folder (`flows.train … --tensorboard DIR`): each run writes to `DIR/<run folder name>/`, so that
`tensorboard --logdir DIR` lays runs side by side. It is opt-in because the `tensorboard` package is an extra
(`pip install -e '.[tensorboard]'`) and the run folder already holds the same figures in `metrics.csv`. A resumed
run, or one asked for TensorBoard only after some epochs, first writes the epochs its history holds that the
folder lacks, so the curves are whole.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from dynplan.extras import MissingExtra, install_hint, require

INSTALL = install_hint("tensorboard")
__all__ = ["INSTALL", "EpochWriter", "MissingExtra", "check_available", "read_images", "read_scalars"]


def _summary_writer():
    require("tensorboard", "tensorboard", "TensorBoard output")
    from torch.utils.tensorboard import SummaryWriter

    return SummaryWriter


def check_available() -> None:
    """Raise `MissingExtra`, saying how to install it, when TensorBoard output cannot be written."""
    _summary_writer()


def _tag(name: str) -> str:
    """`val_fn_rate` → `val/fn_rate`, `loss` → `train/loss`: TensorBoard groups scalars by their prefix."""
    return name.replace("val_", "val/", 1) if name.startswith("val_") else f"train/{name}"


class EpochWriter:
    """Scalars and images of a run's epochs in `log_dir`, at step = epoch."""

    def __init__(self, log_dir: str | os.PathLike):
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self._writer = _summary_writer()(log_dir=str(self.log_dir))
        self._written = _epochs_written(self.log_dir)

    def epoch(self, row: Mapping[str, float], images: Mapping[str, np.ndarray] | None = None) -> None:
        """Write one epoch's row (every finite number but the epoch itself) and images (H, W, 3) uint8, once."""
        epoch = int(row["epoch"])
        if epoch in self._written:
            return
        for name, value in row.items():
            if name != "epoch" and isinstance(value, int | float) and math.isfinite(value):
                self._writer.add_scalar(_tag(name), float(value), epoch)
        for name, image in (images or {}).items():
            self._writer.add_image(name, np.asarray(image), epoch, dataformats="HWC")
        self._writer.add_scalar("epoch", float(epoch), epoch)  # the marker `_epochs_written` reads back
        self._writer.flush()
        self._written.add(epoch)

    def history(self, rows: Sequence[Mapping[str, float]]) -> None:
        """The epochs of `rows` (a resumed run's history) that the folder lacks, as scalars."""
        for row in rows:
            self.epoch(row)

    def close(self) -> None:
        self._writer.close()


def _epochs_written(log_dir: Path) -> set[int]:
    """The epochs whose `epoch` marker the event files in `log_dir` already hold."""
    if not any(log_dir.glob("events.out.tfevents.*")):
        return set()
    return {int(step) for step, _ in read_scalars(log_dir).get("epoch", [])}


def read_scalars(log_dir: str | os.PathLike) -> dict[str, list[tuple[int, float]]]:
    """Every scalar tag in the event files of `log_dir` → its (step, value) pairs, in step order."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(Path(log_dir).glob("events.out.tfevents.*")):
        events = EventAccumulator(str(path), size_guidance={"scalars": 0})
        events.Reload()
        for tag in events.Tags()["scalars"]:
            out.setdefault(tag, []).extend((e.step, e.value) for e in events.Scalars(tag))
    return {tag: sorted(values) for tag, values in out.items()}


def read_images(log_dir: str | os.PathLike) -> dict[str, list[tuple[int, tuple[int, int]]]]:
    """Every image tag in the event files of `log_dir` → its (step, (width, height)) entries."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out: dict[str, list[tuple[int, tuple[int, int]]]] = {}
    for path in sorted(Path(log_dir).glob("events.out.tfevents.*")):
        events = EventAccumulator(str(path), size_guidance={"images": 0})
        events.Reload()
        for tag in events.Tags()["images"]:
            out.setdefault(tag, []).extend((e.step, (e.width, e.height)) for e in events.Images(tag))
    return out
