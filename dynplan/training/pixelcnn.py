"""Train the conditional PixelCNN prior on a Z-code array: windows of `context` code grids (4 in both presets;
frame 0 repeated before an episode's start, `dynplan.data.history`) + 1 target.

Runs in the shared loop (`training/loop.py`): resumable, a checkpoint and a metrics row per epoch. After each
epoch it scores a fixed set of validation windows: teacher-forced code accuracy, and — decoding its greedy
prediction with the VQ-VAE that made the codes — the next frame's pixel errors against the true frame.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import zarr

from dynplan.data.datasets import WindowDataset
from dynplan.data.history import context_indices, first_target
from dynplan.models.checkpoint import PIXELCNN_KIND, load_vqvae_checkpoint
from dynplan.models.configs import PixelCNNConfig
from dynplan.models.generation import generate_fast
from dynplan.models.metrics import frame_errors
from dynplan.models.pixelcnn import ConditionalPixelCNN, from_strips, to_strips
from dynplan.models.vqvae import VQVAE
from dynplan.render import comparison_columns
from dynplan.training import loop
from dynplan.training.budget import TrainBudget
from dynplan.training.precision import autocast

KIND = PIXELCNN_KIND
#: Part of a training run's cache key; bump it when a change would change what training produces.
CODE_VERSION = "pixelcnn-1"


def _windows(dataset: WindowDataset) -> np.ndarray:
    """All of a split's code grids in memory: (E, T, h, w) uint16, as stored, each episode read checked."""
    return np.stack([dataset.read_episode(i) for i in range(len(dataset.episodes))])


def train_pixelcnn(
    store: str | os.PathLike,
    codes: str,
    out_dir: str | os.PathLike,
    config: PixelCNNConfig,
    budget: TrainBudget,
    on_epoch: Callable[[dict], None] | None = None,
    tensorboard: str | os.PathLike | None = None,
) -> Path:
    """Train (or resume) the prior of the code array `codes` (e.g. "codes_default") of `store` in `out_dir`;
    `tensorboard`: a folder that also receives every epoch's figures and its predicted next frames."""
    store, out_dir = str(store), Path(out_dir)
    done = loop.begin(out_dir, KIND, config.model_dump(), budget)
    if done is not None:
        return done
    group = zarr.open_group(store, mode="r", use_consolidated=False)
    tokenizer = load_vqvae_checkpoint(group[codes].attrs["checkpoint"])
    device = budget.torch_device
    model = _prior(codes, tokenizer, config, budget).to(device)
    optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    train_set = WindowDataset(store, "train", array=codes, context=config.context)
    if len(train_set.episodes) == 0:
        train_set = WindowDataset(store, "all", array=codes, context=config.context)
    grids = _windows(train_set)
    E, T = grids.shape[:2]
    first = first_target(config.context)
    val_context, val_target, val_frames = _validation(store, codes, budget.val_frames, config.context)

    def step(generator: torch.Generator) -> dict[str, float]:
        e = torch.randint(0, E, (config.batch_size,), generator=generator).numpy()
        target = first + torch.randint(0, T - first, (config.batch_size,), generator=generator).numpy()
        frames = np.concatenate([context_indices(target, config.context), target[:, None]], axis=1)
        window = grids[e[:, None], frames].astype(np.int64)  # (B, context + 1, h, w)
        window = torch.from_numpy(window).to(device, non_blocking=True)
        if config.strip_rows:  # one strip of each window, drawn at random
            strips = window.shape[2] // config.strip_rows
            pick = torch.randint(0, strips, (len(window),), generator=generator).to(device)
            window = to_strips(window, config.strip_rows)[torch.arange(len(window), device=device) * strips + pick]
        if config.learning_rate_halflife:
            for group in optimiser.param_groups:
                group["lr"] = learning_rate(config, _steps_taken(optimiser))
        with autocast(device, budget.precision):
            out = model(window[:, :-1], window[:, -1])
        optimiser.zero_grad(set_to_none=True)
        out.loss.backward()
        optimiser.step()
        rate = optimiser.param_groups[0]["lr"]
        return {"loss": out.loss.item(), "accuracy": out.accuracy.item(), "learning_rate": rate}

    evaluate, images = _validation_scores(model, tokenizer, (val_context, val_target, val_frames), device)
    stage = loop.Stage(
        KIND, config.model_dump(), model, optimiser, config.batch_size, step, evaluate, images=images, unit="windows"
    )
    return loop.train(out_dir, stage, budget, on_epoch, tensorboard)


def _prior(codes: str, tokenizer: VQVAE, config: PixelCNNConfig, budget: TrainBudget) -> ConditionalPixelCNN:
    """The prior to train on `codes`, its code embedding started from the tokenizer's codebook where configured."""
    if tokenizer.config.codebook_size != config.codebook_size:
        raise ValueError(
            f"{codes} holds codes of K={tokenizer.config.codebook_size}; the prior is configured "
            f"for codebook_size={config.codebook_size}"
        )
    model = ConditionalPixelCNN(config)
    if config.codebook_init:  # a warm start (`init_from`), loaded later, replaces this
        model.embed_codebook(tokenizer.quantizer.embed, torch.Generator().manual_seed(budget.seed))
    return model


def _validation_scores(
    model: ConditionalPixelCNN, tokenizer: VQVAE, validation: tuple, device: torch.device
) -> tuple[Callable[[], dict[str, float]], Callable[[], dict[str, np.ndarray]]]:
    """The epoch's evaluation on the `validation` windows (context, target, true frames) — loss, accuracy, and the
    greedy generation's grids and decoded frames — and the images of its last predicted next frames."""
    val_context, val_target, val_frames = validation
    generated = np.linspace(0, len(val_target) - 1, min(256, len(val_target))).astype(int)  # spread evenly
    shown: dict[str, np.ndarray] = {}  # the last evaluation's first predicted next frames, and the truth
    rows = model.config.strip_rows
    # chunks: the logits of all windows at once are large (256 windows of the default's 12 × 12 grid)
    chunk = max(1, 256 * 144 // (val_target.shape[1] * val_target.shape[2]))

    def evaluate() -> dict[str, float]:
        model.eval()
        loss = accuracy = 0.0
        with torch.inference_mode():
            for i in range(0, len(val_target), chunk):
                context, target = val_context[i : i + chunk], val_target[i : i + chunk]
                out = model(to_strips(context, rows).to(device), to_strips(target[:, None], rows)[:, 0].to(device))
                loss += out.loss.item() * len(target)
                accuracy += out.accuracy.item() * len(target)
            # Generation is the planner's CPU path (numba rows): score that, on a CPU copy when training elsewhere,
            # with the weights laid out afresh (a world model's chains keep them once per prior object).
            on_cpu = model if device.type == "cpu" else copy.deepcopy(model).cpu()
            strips = generate_fast(on_cpu, to_strips(val_context[generated], rows))
            predicted = from_strips(strips[:, None], len(generated))[:, 0]
            frames = tokenizer.decode(predicted).numpy()
        model.train()
        shown["true"], shown["predicted"] = val_frames[generated[:6]], frames[:6]
        errors = frame_errors(val_frames[generated], frames, tokenizer.config.world)
        exact = (predicted == val_target[generated]).all(dim=(1, 2)).float().mean()
        return {
            "val_loss": loss / len(val_target),
            "val_accuracy": accuracy / len(val_target),
            "val_greedy_grid_exact": float(exact),
            **{f"val_next_{k}": v for k, v in errors.items()},
        }

    def images() -> dict[str, np.ndarray]:
        return {"next_frame": comparison_columns(shown["true"], shown["predicted"])}

    return evaluate, images


def learning_rate(config: PixelCNNConfig, steps: int) -> float:
    """The rate after `steps` optimisation steps: constant, or halving every `learning_rate_halflife` windows."""
    if not config.learning_rate_halflife:
        return config.learning_rate
    return config.learning_rate * 0.5 ** (steps * config.batch_size / config.learning_rate_halflife)


def _steps_taken(optimiser: torch.optim.Optimizer) -> int:
    """Steps the optimiser has taken (kept in its state, so a resumed run continues the schedule)."""
    state = optimiser.state.get(optimiser.param_groups[0]["params"][0], {})
    return int(state["step"]) if "step" in state else 0


def _validation(store: str, codes: str, n: int, context: int) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """A fixed set of validation windows (evenly spread) and the true frames of their targets."""
    val = WindowDataset(store, "validation", array=codes, context=context)
    if len(val.episodes) == 0:
        val = WindowDataset(store, "all", array=codes, context=context)
    picks = np.linspace(0, len(val) - 1, min(n, len(val))).astype(int)
    contexts, targets = zip(*(val[int(i)] for i in picks), strict=True)
    frames_array = zarr.open_group(store, mode="r", use_consolidated=False)["frames"]
    frames = np.stack([frames_array[int(val.episodes[e]), t] for e, t in map(val.target, picks)])
    return torch.stack(contexts).long(), torch.stack(targets).long(), frames
