"""The world model's training stages as cached, resumable Prefect tasks and flows: `train_vqvae_flow` (then the
store's codes, `build_codes_task`) and `train_pixelcnn_flow`; `flows.train` is their command and
`flows.collect_train_eval` runs them as pipeline stages.

A task's cache key is its run folder's path once the run has the epochs asked for (`dynplan.training.runs` names the
folder by what determines its result), so a rerun returns the finished checkpoint at once and an interrupted one
resumes from its last epoch.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from dynplan.config import digest
from dynplan.models import checkpoint
from dynplan.models.configs import PixelCNNConfig, VQVAEConfig
from dynplan.models.registry import world_model_spec
from dynplan.progress import StepBar
from dynplan.training.budget import TrainBudget
from dynplan.training.codes import build_codes
from dynplan.training.pixelcnn import train_pixelcnn
from dynplan.training.runs import pixelcnn_run_dir, vqvae_run_dir
from dynplan.training.vqvae import train_vqvae
from flows.artifacts import ProgressArtifact
from flows.deferred import NO_CACHE, flow, task

if TYPE_CHECKING:
    from prefect.context import TaskRunContext


def _finished_key(run_dir: Path, kind: str, epochs: int) -> str | None:
    """Cache only finished runs: a key exists once the run's final checkpoint has the epochs asked for. The key
    is the folder's full path, so each place on disk caches its own run."""
    final = run_dir / f"{kind}.pt"
    try:
        if not final.exists() or checkpoint.load(final, kind)["epoch"] < epochs:
            return None
    except checkpoint.UnreadableCheckpoint:
        return None  # damaged: the task runs, and exports it again from the run's latest checkpoint
    return digest(str(run_dir.resolve()), epochs)


def _vqvae_key(context: TaskRunContext, p: dict) -> str | None:
    return _finished_key(vqvae_run_dir(p["store"], p["out"], p["config"], p["budget"]), "vqvae", p["budget"]["epochs"])


def _pixelcnn_key(context: TaskRunContext, p: dict) -> str | None:
    run_dir = pixelcnn_run_dir(p["store"], p["codes"], p["out"], p["config"], p["budget"])
    return _finished_key(run_dir, "pixelcnn", p["budget"]["epochs"])


def _show(run_dir: Path, epochs: int):
    """Each finished epoch: the console's bar and the task's progress artifact moved on, the bar saying the epoch's
    loss (its every figure is in the run folder's metrics.csv)."""
    done = ProgressArtifact(f"epochs of {run_dir.name}", epochs)
    bar = StepBar(epochs, f"epochs of {run_dir.name}")

    def show(row: dict) -> None:
        done.update(int(row["epoch"]))
        bar.update(int(row["epoch"]), f"(loss {row['loss']:.4f})")

    return show


def _board(tensorboard: str | None, run_dir: Path) -> Path | None:
    """The run's TensorBoard folder: its own under `tensorboard`, named as the run folder."""
    return None if tensorboard is None else Path(tensorboard) / run_dir.name


@task(name="train-vqvae", cache_key_fn=_vqvae_key, persist_result=True)
def train_vqvae_task(store: str, out: str, config: dict, budget: dict, tensorboard: str | None = None) -> str:
    run_dir = vqvae_run_dir(store, out, config, budget)
    shown = _show(run_dir, budget["epochs"])
    return str(
        train_vqvae(
            store,
            run_dir,
            VQVAEConfig(**config),
            TrainBudget(**budget),
            on_epoch=shown,
            tensorboard=_board(tensorboard, run_dir),
        )
    )


@task(name="train-pixelcnn", cache_key_fn=_pixelcnn_key, persist_result=True)
def train_pixelcnn_task(
    store: str, codes: str, out: str, config: dict, budget: dict, tensorboard: str | None = None
) -> str:
    run_dir = pixelcnn_run_dir(store, codes, out, config, budget)
    shown = _show(run_dir, budget["epochs"])
    path = train_pixelcnn(
        store,
        codes,
        run_dir,
        PixelCNNConfig(**config),
        TrainBudget(**budget),
        on_epoch=shown,
        tensorboard=_board(tensorboard, run_dir),
    )
    return str(path)


@task(name="build-codes", cache_policy=NO_CACHE)
def build_codes_task(store: str, checkpoint: str, name: str) -> str:
    return build_codes(store, checkpoint, name)


@flow(name="train-vqvae", log_prints=True)
def train_vqvae_flow(
    store: str = "datasets/frames.zarr",
    model: str = "default",
    out: str = "datasets/checkpoints",
    budget: dict | None = None,
    overrides: dict | None = None,
    tensorboard: str | None = None,
) -> str:
    """Train the VQ-VAE preset `model` (with optional config `overrides`) on `store`; `tensorboard`: a folder for
    TensorBoard event files (one subfolder per run)."""
    config = world_model_spec(model).tokenizer.model_copy(update=overrides or {})
    config = VQVAEConfig(**config.model_dump())  # validate the overrides
    path = train_vqvae_task(store, out, config.model_dump(), TrainBudget(**(budget or {})).model_dump(), tensorboard)
    print(f"checkpoint: {path}")
    if Path(path).name == "vqvae.pt":  # finished (not stopped early by max_minutes): encode the store
        # A run with overrides is an experiment: its codes go beside the preset's, not over them.
        name = Path(path).parent.name if overrides else model
        print(f"codes: {build_codes_task(store, path, name)} in {store}")
    return path


@flow(name="train-pixelcnn", log_prints=True)
def train_pixelcnn_flow(
    store: str = "datasets/frames.zarr",
    model: str = "default",
    out: str = "datasets/checkpoints",
    budget: dict | None = None,
    overrides: dict | None = None,
    codes: str | None = None,
    tensorboard: str | None = None,
) -> str:
    """Train the PixelCNN prior preset `model` on the store's `codes_<model>` (made by the VQ-VAE flow), or on
    the code array `codes` (an experiment's tokenizer); `tensorboard` as for the VQ-VAE."""
    config = PixelCNNConfig(**world_model_spec(model).prior.model_copy(update=overrides or {}).model_dump())
    path = train_pixelcnn_task(
        store,
        codes or f"codes_{model}",
        out,
        config.model_dump(),
        TrainBudget(**(budget or {})).model_dump(),
        tensorboard,
    )
    print(f"checkpoint: {path}")
    return path
