"""Train a VQ-VAE on the frames store: resumable, a checkpoint and a metrics row every epoch.

An "epoch" here is `steps_per_epoch` batches of frames drawn at random from the training split (the store may
hold millions of frames; a checkpoint every few minutes is what makes training resumable across sessions).
After each epoch the model reconstructs a fixed set of validation frames and the row of `metrics.csv` records
the losses, codebook use and perplexity, and the reconstruction errors that matter to the planner.
"""

from __future__ import annotations

import csv
import io
import json
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from pydantic import Field

from dynplan.config import Config
from dynplan.data.datasets import FrameDataset
from dynplan.files import write_bytes_atomic
from dynplan.models.metrics import frame_errors
from dynplan.models.vqvae import VQVAE, VQVAEConfig
from dynplan.training import checkpoint

KIND = "vqvae"
#: Part of a training run's cache key. Bump it whenever a change to the model, likelihood, quantizer or this
#: loop would change what training produces; edits that do not (docs, names) keep runs resumable.
CODE_VERSION = "vqvae-1"


class TrainBudget(Config):
    """How long to train: epochs of `steps_per_epoch` batches, optionally capped in wall-clock minutes."""

    epochs: int = Field(20, ge=1, le=100_000, description="epochs to train (in total, counting resumed ones)")
    steps_per_epoch: int = Field(500, ge=1, le=1_000_000, description="batches per epoch")
    val_frames: int = Field(2000, ge=1, le=1_000_000, description="validation frames scored after each epoch")
    max_minutes: float | None = Field(None, gt=0, description="stop (resumably) after this much wall time")
    threads: int | None = Field(None, ge=1, le=256, description="torch threads (default: all cores)")
    seed: int = Field(0, ge=0, description="seed of initialisation and batch order")


def _validation_frames(store: str, n: int) -> np.ndarray:
    val = FrameDataset(store, "validation")
    if len(val.episodes) == 0:
        val = FrameDataset(store, "all")  # tiny stores: score on what there is
    per_episode = max(1, -(-n // len(val.episodes)))
    frames = [val.episode(i)[np.linspace(0, val.n_frames - 1, per_episode).astype(int)]
              for i in range(len(val.episodes))]  # fmt: skip
    return np.concatenate(frames)[:n]


def evaluate(model: VQVAE, frames: np.ndarray, batch: int = 256) -> dict[str, float]:
    """Reconstruction errors of `model` on uint8 `frames` (mid-point decoding), plus codebook use."""
    model.eval()
    decoded, codes = [], []
    for i in range(0, len(frames), batch):
        x = torch.from_numpy(frames[i : i + batch])
        c = model.encode(x)
        codes.append(c.reshape(len(x), -1))
        decoded.append(model.decode(c).numpy())
    model.train()
    all_codes = torch.cat(codes).flatten()
    counts = torch.bincount(all_codes, minlength=model.config.codebook_size).double()
    p = counts / counts.sum()
    return {
        **{f"val_{k}": v for k, v in frame_errors(frames, np.concatenate(decoded)).items()},
        "val_codes_used": int((counts > 0).sum()),
        "val_perplexity": float(torch.exp(-(p * torch.log(p + 1e-12)).sum())),
    }


def plot_reconstructions(model: VQVAE, frames: np.ndarray, path: Path, n: int = 6) -> None:
    """A PNG: true frames over their mid-point reconstructions and the error panel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dynplan.render import colorize, error_image

    picks = frames[np.linspace(0, len(frames) - 1, n).astype(int)]
    model.eval()
    decoded = model.decode(model.encode(torch.from_numpy(picks))).numpy()
    model.train()
    fig, axes = plt.subplots(3, n, figsize=(2 * n, 6.4))
    for j in range(n):
        for i, (image, title) in enumerate([(colorize(picks[j]), "true"), (colorize(decoded[j]), "decoded"),
                                            (error_image(picks[j], decoded[j]), "error")]):  # fmt: skip
            axes[i, j].imshow(image, interpolation="nearest")
            axes[i, j].set_axis_off()
            axes[i, j].set_title(title, fontsize=8)
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=80)
    plt.close(fig)
    os.replace(tmp, path)


def train_vqvae(store: str | os.PathLike, out_dir: str | os.PathLike, config: VQVAEConfig, budget: TrainBudget,
                on_epoch: Callable[[dict], None] | None = None) -> Path:  # fmt: skip
    """Train (or resume training of) a VQ-VAE in `out_dir` up to `budget.epochs`; returns the final checkpoint
    `out_dir/vqvae.pt`, or the latest one if `budget.max_minutes` stopped it first.

    `out_dir/checkpoint.pt` holds the latest epoch (model, optimiser); rerunning continues from it — also to
    extend a finished run with a larger `epochs` — and a checkpoint made with another config is an error
    rather than silently reused.
    """
    store, out_dir = str(store), Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    final = out_dir / "vqvae.pt"
    if final.exists() and checkpoint.load(final, KIND, config.model_dump())["epoch"] >= budget.epochs:
        return final
    if budget.threads:
        torch.set_num_threads(budget.threads)
    torch.manual_seed(budget.seed)
    model = VQVAE(config)
    optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    epoch, elapsed, history = 0, 0.0, []
    latest = out_dir / "checkpoint.pt"
    if latest.exists():
        state = checkpoint.load(latest, KIND, config.model_dump())
        model.load_state_dict(state["model"])
        optimiser.load_state_dict(state["optimiser"])
        epoch, elapsed, history = state["epoch"], state["elapsed_s"], state["history"]
        if "torch_rng" in state:
            torch.set_rng_state(state["torch_rng"])  # code restarts draw from it: resume bit for bit
    write_bytes_atomic(out_dir / "config.json", json.dumps(config.model_dump(), indent=1).encode())

    train = FrameDataset(store, "train" if len(FrameDataset(store, "train").episodes) else "all")
    frames = np.stack([train.array[int(e)] for e in train.episodes])  # (E, T, H, W) in memory, read once
    E, T = frames.shape[:2]
    val = _validation_frames(store, budget.val_frames)
    started = time.perf_counter()
    while epoch < budget.epochs:
        if budget.max_minutes and (time.perf_counter() - started) / 60 >= budget.max_minutes:
            break
        generator = torch.Generator().manual_seed(budget.seed * 1_000_003 + epoch)
        totals: dict[str, float] = {}
        counts = torch.zeros(config.n_codebooks, config.codebook_size)
        t0 = time.perf_counter()
        for _ in range(budget.steps_per_epoch):
            e = torch.randint(0, E, (config.batch_size,), generator=generator).numpy()
            t = torch.randint(0, T, (config.batch_size,), generator=generator).numpy()
            out = model(torch.from_numpy(frames[e, t]))
            loss = sum(out.losses.values())
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            counts += out.counts
            for name, value in {**out.losses, "loss": loss, "perplexity": out.perplexity}.items():
                totals[name] = totals.get(name, 0.0) + value.item()
        epoch_s = time.perf_counter() - t0
        elapsed += epoch_s
        epoch += 1
        row = {
            "epoch": epoch,
            "frames_seen": epoch * budget.steps_per_epoch * config.batch_size,
            **{k: v / budget.steps_per_epoch for k, v in totals.items()},
            "codebook_usage": float((counts > 0).float().mean()),
            "train_frames_per_s": budget.steps_per_epoch * config.batch_size / epoch_s,
            "elapsed_s": elapsed,
            **evaluate(model, val),
        }
        history.append(row)
        checkpoint.save(latest, {"kind": KIND, "config": config.model_dump(), "model": model.state_dict(),
                                 "optimiser": optimiser.state_dict(), "epoch": epoch, "elapsed_s": elapsed,
                                 "history": history, "torch_rng": torch.get_rng_state()})  # fmt: skip
        write_csv(out_dir / "metrics.csv", history)
        plot_reconstructions(model, val, out_dir / "reconstructions.png")
        if on_epoch:
            on_epoch(row)
    if epoch >= budget.epochs:
        state = checkpoint.load(latest, KIND, config.model_dump())
        checkpoint.save(final, {"kind": KIND, "config": state["config"], "model": state["model"],
                                "epoch": state["epoch"], "elapsed_s": state["elapsed_s"],
                                "history": state["history"]})  # fmt: skip
        return final
    return latest


def write_csv(path: Path, rows: list[dict]) -> None:
    """Write the metrics history as CSV, atomically (rewritten whole each epoch, so it always matches the
    checkpoint it sits beside)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (round(v, 6) if isinstance(v, float) else v) for k, v in row.items()})
    write_bytes_atomic(path, buffer.getvalue().encode())


def load_vqvae_checkpoint(path: str | os.PathLike, config: VQVAEConfig | None = None) -> VQVAE:
    """A VQ-VAE from a checkpoint (final or latest); with `config`, it must be the one trained."""
    state = checkpoint.load(path, KIND, None if config is None else config.model_dump())
    model = VQVAE(VQVAEConfig(**state["config"]))
    model.load_state_dict(state["model"])
    return model.eval()
