"""The training loop every world-model stage shares: epochs, checkpoints, resumption, metrics history.

An "epoch" is `steps_per_epoch` optimisation steps on batches drawn at random (the stores hold millions of
items; a checkpoint every few minutes is what makes an interrupted run resumable). A stage supplies
how to take one step, what to report at the end of an epoch, how to evaluate and what to draw; the loop owns
`checkpoint.pt` (latest: model, optimiser, RNG, history), `metrics.csv`, and the final `<kind>.pt`.
"""

from __future__ import annotations

import csv
import io
import json
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from dynplan.files import write_bytes_atomic
from dynplan.models import checkpoint
from dynplan.training.budget import TrainBudget


@dataclass
class Stage:
    """What a world-model stage plugs into the loop.

    step(generator) → scalars of one optimisation step on a batch it draws with `generator`
    epoch_end() → extra training metrics of the epoch just finished (and resets whatever it accumulates)
    evaluate() → validation metrics
    plot(out_dir) → draw pictures of the current model (optional)
    images() → the same as RGB images (H, W, 3) uint8 by name, for TensorBoard (optional)
    unit: what a batch item is ("frames", "windows"), for the throughput columns
    """

    kind: str
    config: dict
    model: torch.nn.Module
    optimiser: torch.optim.Optimizer
    batch_size: int
    step: Callable[[torch.Generator], dict[str, float]]
    evaluate: Callable[[], dict[str, float]]
    epoch_end: Callable[[], dict[str, float]] = dict
    plot: Callable[[Path], None] | None = None
    images: Callable[[], dict[str, np.ndarray]] | None = None
    unit: str = "frames"


def begin(out_dir: Path, kind: str, config: dict, budget: TrainBudget) -> Path | None:
    """Prepare a run in `out_dir`: return its final checkpoint if it already has the epochs asked for; else set
    torch's threads and seed — before the stage builds its model, so initialisation is reproducible. The folder is
    made by the run's first write, so a start that fails before training leaves none behind. A run that has
    trained more epochs than `budget.epochs` is a ValueError: it keeps no earlier epoch's weights."""
    trained = trained_epochs(out_dir, kind)
    if trained > budget.epochs:
        raise ValueError(
            f"epochs {budget.epochs}: the run {out_dir} has trained {trained} epochs, and keeps no earlier epoch's "
            f"weights; ask {trained} or more, or train a {budget.epochs}-epoch run in another folder"
        )
    done = finished(out_dir, kind, config, budget.epochs)
    if done is None:
        if budget.threads:
            torch.set_num_threads(budget.threads)
        torch.manual_seed(budget.seed)
    return done


def trained_epochs(out_dir: str | os.PathLike, stage_kind: str) -> int:
    """The most epochs the run in `out_dir` holds, by its final or latest checkpoint (0: none, or none readable —
    the run exports or resumes a damaged one as it would without this count)."""
    trained = 0
    for path in (Path(out_dir) / f"{stage_kind}.pt", Path(out_dir) / "checkpoint.pt"):
        try:
            trained = max(trained, checkpoint.load(path, stage_kind)["epoch"]) if path.is_file() else trained
        except checkpoint.UnreadableCheckpoint:
            continue
    return trained


def finished(out_dir: Path, stage_kind: str, config: dict, epochs: int) -> Path | None:
    """The final checkpoint of a run in `out_dir` if it has at least `epochs` (a config mismatch is an error). A
    damaged final checkpoint beside a latest one that has the epochs is exported again from it."""
    final, latest = out_dir / f"{stage_kind}.pt", out_dir / "checkpoint.pt"
    if not final.exists():
        return None
    try:
        return final if checkpoint.load(final, stage_kind, config)["epoch"] >= epochs else None
    except checkpoint.UnreadableCheckpoint as error:
        if latest.exists() and checkpoint.load(latest, stage_kind, config)["epoch"] >= epochs:
            warnings.warn(f"{error}; exported it again from {latest}", stacklevel=2)
            return export_weights(latest, final, stage_kind, config)
        if latest.exists():
            return None  # training resumes from the latest epoch and writes the final checkpoint again
        raise


def _resume(latest: Path, stage: Stage, budget: TrainBudget) -> tuple[int, float, list[dict]]:
    """(epochs done, seconds spent, history) of the run: from its latest checkpoint (the model, optimiser and
    random state restored), else from nothing, started from `budget.init_from`'s weights if given."""
    if latest.exists():
        state = checkpoint.load(latest, stage.kind, stage.config)
        stage.model.load_state_dict(state["model"])
        stage.optimiser.load_state_dict(state["optimiser"])
        if "torch_rng" in state:
            torch.set_rng_state(state["torch_rng"])  # e.g. a codebook initialisation draws from it: resume bit for bit
        return state["epoch"], state["elapsed_s"], state["history"]
    if budget.init_from:
        warm_start(stage.model, budget.init_from, stage.kind)
    return 0, 0.0, []


def _run_epoch(stage: Stage, budget: TrainBudget, epoch: int, elapsed: float) -> dict:
    """Epoch `epoch` + 1's steps, from its own random stream, and its row of the history (means of the steps'
    figures, the stage's epoch-end figures, throughput, time spent in all, the evaluation)."""
    generator = torch.Generator().manual_seed(budget.seed * 1_000_003 + epoch)
    totals: dict[str, float] = {}
    t0 = time.perf_counter()
    for _ in range(budget.steps_per_epoch):
        for name, value in stage.step(generator).items():
            totals[name] = totals.get(name, 0.0) + value
    epoch_s = time.perf_counter() - t0
    items = budget.steps_per_epoch * stage.batch_size
    return {
        "epoch": epoch + 1,
        f"{stage.unit}_seen": (epoch + 1) * items,
        **{k: v / budget.steps_per_epoch for k, v in totals.items()},
        **stage.epoch_end(),
        f"train_{stage.unit}_per_s": items / epoch_s,
        "elapsed_s": elapsed + epoch_s,
        **stage.evaluate(),
    }


def train(
    out_dir: Path,
    stage: Stage,
    budget: TrainBudget,
    on_epoch: Callable[[dict], None] | None = None,
    tensorboard: str | os.PathLike | None = None,
) -> Path:
    """Run `stage` in `out_dir` up to `budget.epochs`, resuming from `checkpoint.pt`; return the final checkpoint,
    or the latest if `budget.max_minutes` stopped it first. `tensorboard`: a folder that also receives every
    epoch's figures and the stage's images (`dynplan.training.tensorboard`)."""
    latest, final = out_dir / "checkpoint.pt", out_dir / f"{stage.kind}.pt"
    epoch, elapsed, history = _resume(latest, stage, budget)
    write_bytes_atomic(out_dir / "config.json", json.dumps(stage.config, indent=1).encode())
    board = None
    if tensorboard is not None:
        from dynplan.training.tensorboard import EpochWriter

        board = EpochWriter(tensorboard)
        board.history(history)  # a resumed run's earlier epochs, where the folder lacks them
    started = time.perf_counter()
    while epoch < budget.epochs:
        if budget.max_minutes and (time.perf_counter() - started) / 60 >= budget.max_minutes:
            break
        row = _run_epoch(stage, budget, epoch, elapsed)
        epoch, elapsed = row["epoch"], row["elapsed_s"]
        history.append(row)
        checkpoint.save(
            latest,
            {
                "kind": stage.kind,
                "config": stage.config,
                "model": _cpu(stage.model.state_dict()),
                "optimiser": _cpu(stage.optimiser.state_dict()),
                "epoch": epoch,
                "elapsed_s": elapsed,
                "history": history,
                "torch_rng": torch.get_rng_state(),
                "init_from": budget.init_from,
                "precision": budget.precision,
            },
        )
        write_csv(out_dir / "metrics.csv", history)
        if stage.plot is not None:
            stage.plot(out_dir)
        if board is not None:
            board.epoch(row, stage.images() if stage.images else None)
        if on_epoch:
            on_epoch(row)
    if board is not None:
        board.close()
    if epoch < budget.epochs:
        return latest
    return export_weights(latest, final, stage.kind, stage.config)


def export_weights(latest: str | os.PathLike, final: str | os.PathLike, kind: str, config: dict | None = None) -> Path:
    """Write the weights of checkpoint `latest` to `final` without the optimiser's state (a third of the size):
    the end of a run, or a snapshot of one still training to commit as pretrained weights."""
    state = checkpoint.load(latest, kind, config)
    kept = ("kind", "config", "model", "epoch", "elapsed_s", "history", "init_from")
    # a checkpoint written before runs recorded their precision trained in float32
    return checkpoint.save(
        final, {**{key: state.get(key) for key in kept}, "precision": state.get("precision", "float32")}
    )


def _cpu(state):
    """`state` with every tensor on the CPU: a checkpoint written on an accelerator loads anywhere."""
    if isinstance(state, torch.Tensor):
        return state.cpu()
    if isinstance(state, dict):
        return {k: _cpu(v) for k, v in state.items()}
    if isinstance(state, list | tuple):
        return type(state)(_cpu(v) for v in state)
    return state


def warm_start(model: torch.nn.Module, path: str, kind: str) -> None:
    """Start `model` from the weights of the checkpoint at `path`, checked first (`checkpoint.verify`). Tensors of
    the same shape are copied; a tensor grown along one dimension (a larger codebook) gets the old entries first
    and keeps its fresh ones after them (unused codes). Anything else is a CheckpointError
    (`checkpoint.warm_weights`)."""
    target = model.state_dict()
    shapes = {name: tuple(value.shape) for name, value in target.items()}
    source = checkpoint.warm_weights(path, checkpoint.verify(path, kind), kind, shapes)
    with torch.no_grad():
        for name, value in source.items():
            into = target[name]
            grown = [d for d in range(into.dim()) if into.shape[d] != value.shape[d]]
            (into.narrow(grown[0], 0, value.shape[grown[0]]) if grown else into).copy_(value)
    model.load_state_dict(target)


def write_csv(path: Path, rows: list[dict]) -> None:
    """Write the metrics history as CSV, atomically (rewritten whole each epoch, so it always matches the
    checkpoint it sits beside)."""
    buffer = io.StringIO()
    columns = list(dict.fromkeys(key for row in rows for key in row))  # rows from older code may lack new metrics
    writer = csv.DictWriter(buffer, fieldnames=columns, restval="")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (round(v, 6) if isinstance(v, float) else v) for k, v in row.items()})
    write_bytes_atomic(path, buffer.getvalue().encode())
