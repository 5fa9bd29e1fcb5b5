"""Train a VQ-VAE on the frames store: resumable, a checkpoint and a metrics row every epoch.

An "epoch" here is `steps_per_epoch` batches of frames drawn at random from the training split (the store may
hold millions of frames; a checkpoint every few minutes is what makes an interrupted run resumable).
After each epoch the model reconstructs a fixed set of validation frames and the row of `metrics.csv` records
the losses, codebook use and perplexity, and the reconstruction errors that matter to the planner.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from dynplan.data.datasets import FrameDataset
from dynplan.data.patches import distinct_patches
from dynplan.models.checkpoint import VQVAE_KIND
from dynplan.models.configs import VQVAEConfig
from dynplan.models.metrics import frame_errors
from dynplan.models.vqvae import SHARPNESS_GRID, VQVAE, padded
from dynplan.training import loop
from dynplan.training.budget import TrainBudget
from dynplan.training.precision import Precision, autocast

KIND = VQVAE_KIND
#: Part of a training run's cache key. Bump it whenever a change to the model, likelihood, quantizer or this
#: loop would change what training produces; edits that do not (docs, names) keep runs resumable.
CODE_VERSION = "vqvae-1"
#: Frames whose patches `codebook_fit="contents"` counts (evenly spaced over the training split).
CONTENT_FRAMES = 100_000


def _validation_frames(store: str, n: int) -> np.ndarray:
    val = FrameDataset(store, "validation")
    if len(val.episodes) == 0:
        val = FrameDataset(store, "all")  # tiny stores: score on what there is
    per_episode = max(1, -(-n // len(val.episodes)))
    frames = [
        val.episode(i)[np.linspace(0, val.n_frames - 1, per_episode).astype(int)] for i in range(len(val.episodes))
    ]
    return np.concatenate(frames)[:n]


def evaluate(model: VQVAE, frames: np.ndarray, batch: int = 256) -> dict[str, float]:
    """Reconstruction errors of `model` on uint8 `frames` (mid-point decoding), plus codebook use."""
    model.eval()
    device = next(model.parameters()).device
    decoded, codes = [], []
    for i in range(0, len(frames), batch):
        x = torch.from_numpy(frames[i : i + batch]).to(device)
        c = model.encode(x)
        codes.append(c.reshape(-1).cpu())
        decoded.append(model.decode(c).cpu().numpy())
    model.train()
    counts = torch.bincount(torch.cat(codes), minlength=model.config.codebook_size).double()
    p = counts / counts.sum()
    return {
        **{f"val_{k}": v for k, v in frame_errors(frames, np.concatenate(decoded), model.config.world).items()},
        "val_codes_used": float((counts > 0).sum()),
        "val_perplexity": float(torch.exp(-(p * torch.log(p + 1e-12)).sum())),
    }


def _reconstructed(model: VQVAE, frames: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """n validation frames spread over `frames` and their mid-point reconstructions."""
    picks = frames[np.linspace(0, len(frames) - 1, n).astype(int)]
    model.eval()
    device = next(model.parameters()).device
    decoded = model.decode(model.encode(torch.from_numpy(picks).to(device))).cpu().numpy()
    model.train()
    return picks, decoded


def reconstruction_image(model: VQVAE, frames: np.ndarray, n: int = 6) -> np.ndarray:
    """RGB (3 · 48 + 2, n · 49 − 1, 3): per column a true frame over its reconstruction over the error panel."""
    from dynplan.render import comparison_columns

    return comparison_columns(*_reconstructed(model, frames, n))


def plot_reconstructions(model: VQVAE, frames: np.ndarray, path: Path, n: int = 6) -> None:
    """A PNG: true frames over their mid-point reconstructions and the error panel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dynplan.env.colors import colorize
    from dynplan.render import error_image

    picks, decoded = _reconstructed(model, frames, n)
    fig, axes = plt.subplots(3, n, figsize=(2 * n, 6.4))
    for j in range(n):
        for i, (image, title) in enumerate(
            [
                (colorize(picks[j]), "true"),
                (colorize(decoded[j]), "decoded"),
                (error_image(picks[j], decoded[j]), "error"),
            ]
        ):
            axes[i, j].imshow(image, interpolation="nearest")
            axes[i, j].set_axis_off()
            axes[i, j].set_title(title, fontsize=8)
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=80)
    plt.close(fig)
    os.replace(tmp, path)


def train_vqvae(
    store: str | os.PathLike,
    out_dir: str | os.PathLike,
    config: VQVAEConfig,
    budget: TrainBudget,
    on_epoch: Callable[[dict], None] | None = None,
    tensorboard: str | os.PathLike | None = None,
) -> Path:
    """Train (or resume training of) a VQ-VAE in `out_dir` up to `budget.epochs`; returns the final checkpoint
    `out_dir/vqvae.pt`, or the latest one if `budget.max_minutes` stopped it first.

    `out_dir/checkpoint.pt` holds the latest epoch (model, optimiser); rerunning continues from it — also to
    extend a finished run with a larger `epochs` — and a checkpoint made with another config is an error
    rather than silently reused.
    """
    store, out_dir = str(store), Path(out_dir)
    done = loop.begin(out_dir, KIND, config.model_dump(), budget)
    if done is not None:
        return done
    device = budget.torch_device
    model = VQVAE(config).to(device)
    optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    train = FrameDataset(store, "train" if len(FrameDataset(store, "train").episodes) else "all")
    frames = np.stack([train.read_episode(i) for i in range(len(train.episodes))])  # (E, T, H, W), read once, checked
    val = _validation_frames(store, budget.val_frames)

    if config.codebook_fit == "contents":
        step, epoch_end = _content_fit(model, optimiser, frames, config, budget.precision)
    else:
        step, epoch_end = _frame_steps(model, optimiser, frames, config, budget.precision)

    def plot(folder: Path) -> None:
        plot_reconstructions(model, val, folder / "reconstructions.png")

    stage = loop.Stage(
        KIND,
        config.model_dump(),
        model,
        optimiser,
        config.batch_size,
        step,
        evaluate=lambda: evaluate(model, val),
        epoch_end=epoch_end,
        plot=plot,
        images=lambda: {"reconstructions": reconstruction_image(model, val)},
        unit="frames" if config.codebook_fit == "learned" else "patches",
    )
    return loop.train(out_dir, stage, budget, on_epoch, tensorboard)


Step = Callable[[torch.Generator], dict[str, float]]


def _frame_steps(
    model: VQVAE, optimiser: torch.optim.Optimizer, frames: np.ndarray, config: VQVAEConfig, precision: Precision
) -> tuple[Step, Callable[[], dict[str, float]]]:
    """The usual VQ-VAE training: batches of whole frames through encoder, quantizer and decoder."""
    E, T = frames.shape[:2]
    device = next(model.parameters()).device
    counts = torch.zeros(config.codebook_size, device=device)

    def step(generator: torch.Generator) -> dict[str, float]:
        e = torch.randint(0, E, (config.batch_size,), generator=generator).numpy()
        t = torch.randint(0, T, (config.batch_size,), generator=generator).numpy()
        with autocast(device, precision):
            out = model(torch.from_numpy(frames[e, t]).to(device, non_blocking=True))
            loss = sum(out.losses.values())
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        counts.add_(out.counts)
        return {
            name: value.item() for name, value in {**out.losses, "loss": loss, "perplexity": out.perplexity}.items()
        }

    def epoch_end() -> dict[str, float]:
        usage = float((counts > 0).float().mean())
        counts.zero_()
        return {"codebook_usage": usage}

    return step, epoch_end


def content_sample(frames: np.ndarray, patch: tuple[int, int], k: int) -> tuple[np.ndarray, float]:
    """The `k` most frequent patch contents among (at most `CONTENT_FRAMES` evenly spaced of) `frames` (E, T, H, W),
    padded with the most frequent where there are fewer, and the share of patches they cover."""
    return _most_frequent(*patch_counts(frames, patch), k)


def _most_frequent(contents: np.ndarray, counts: np.ndarray, k: int) -> tuple[np.ndarray, float]:
    coverage = float(counts[:k].sum() / counts.sum())
    if len(contents) < k:
        contents = np.concatenate([contents, np.repeat(contents[:1], k - len(contents), 0)])
    return contents[:k], coverage


def patch_counts(frames: np.ndarray, patch: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The distinct patch contents of (at most `CONTENT_FRAMES` evenly spaced of) `frames` (E, T, H, W), most
    frequent first, and how often each occurs."""
    flat = frames.reshape(-1, *frames.shape[2:])
    picked = flat[np.linspace(0, len(flat) - 1, min(len(flat), CONTENT_FRAMES)).astype(int)]
    return distinct_patches(picked, patch)


def _content_fit(
    model: VQVAE, optimiser: torch.optim.Optimizer, frames: np.ndarray, config: VQVAEConfig, precision: Precision
) -> tuple[Step, Callable[[], dict[str, float]]]:
    """`codebook_fit="contents"`: a patch-local model sees each patch alone, so it can be trained on the distinct
    patch contents instead of frames — drawn uniformly, so a content seen once in 10⁵ patches is learned as well as
    the empty road. Each step autoencodes a batch of them (no quantisation); each epoch ends by setting the
    codebook to the encoder's outputs of the K most frequent contents, which then encode to codes of their own
    and decode as the autoencoder does — and, with `calibrate_decoder`, by fitting each code's temperature to
    how often the patches occur (uniform draws leave the decoder ~0.2 % unsure of each empty-road pixel)."""
    device = next(model.parameters()).device
    every, counts = patch_counts(padded(frames, config), model.patch)
    contents, coverage = _most_frequent(every, counts, config.codebook_size)
    contents = torch.from_numpy(contents).to(device)
    every, counts = torch.from_numpy(every).to(device), torch.from_numpy(counts).to(device)

    def step(generator: torch.Generator) -> dict[str, float]:
        batch = contents[torch.randint(0, len(contents), (config.batch_size,), generator=generator).to(device)]
        with autocast(device, precision):
            loss = model.reconstruction_loss(model.autoencode_params(batch), batch)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        return {"reconstruction": loss.item(), "loss": loss.item()}

    @torch.no_grad()
    def epoch_end() -> dict[str, float]:
        model.fit_codebook(contents)
        exact = (model.pixel.mid(model.autoencode_params(contents)) == contents).flatten(1).all(1)
        metrics = {"contents_exact": float(exact.float().mean()), "contents_coverage": coverage}
        if config.calibrate_decoder:
            sharpness = model.calibrate(every, counts)
            metrics["median_code_sharpness"] = float(sharpness.median())
            # codes whose patches disagree most (rare contents mapped onto them): flat at the grid's lower end
            metrics["codes_at_lowest_sharpness"] = float((sharpness == SHARPNESS_GRID.min()).float().mean())
        return metrics

    return step, epoch_end
