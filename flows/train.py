"""`python -m flows.train vqvae|pixelcnn --store STORE.zarr [--model default|paper]`: train a world-model stage
as a cached, resumable Prefect task. After the VQ-VAE the flow encodes the store with it (`codes_<model>`),
which the PixelCNN prior of the same model then trains on.

The run's folder is named by what determines its result — (dataset fingerprint, config, batches per epoch,
seed, code version) — so a rerun with the same inputs returns the finished checkpoint at once (a Prefect cache
hit), an interrupted run continues from its last epoch, and a larger `--epochs` extends a finished run.
`--max-minutes` stops early (resumably): rerun the same command to go on.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

import zarr

from dynplan.cli import CommandParser, bounded, run_command
from dynplan.config import ConfigError, field_help
from dynplan.data.metadata import metadata_problem
from dynplan.data.store import store_problem, store_world
from dynplan.models import checkpoint
from dynplan.models.checkpoint import CheckpointError, digest
from dynplan.models.pixelcnn import PixelCNNConfig
from dynplan.models.registry import default_model, models_of, world_model_names, world_model_spec
from dynplan.models.vqvae import VQVAEConfig
from dynplan.paths import PathArgument, PathKind, check_input, check_output
from dynplan.progress import StepBar
from dynplan.training.codes import build_codes
from dynplan.training.loop import TrainBudget
from dynplan.training.pixelcnn import train_pixelcnn
from dynplan.training.runs import pixelcnn_run_dir, vqvae_run_dir
from dynplan.training.tensorboard import INSTALL, MissingExtra, check_available
from dynplan.training.vqvae import train_vqvae
from dynplan.world import DEFAULT_WORLD, world_names
from flows.artifacts import ProgressArtifact
from flows.cli import add_console_options, temporary_api
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


def parse_overrides(items: list[str]) -> dict:
    """`--set KEY=JSON …` as a dict; a malformed item is a ValueError naming it."""
    overrides = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--set {item!r}: expected KEY=JSON, e.g. codebook_size=1024 or 'strides=[2, 2]'")
        try:
            overrides[key] = json.loads(value)
        except json.JSONDecodeError:
            raise ValueError(
                f"--set {item!r}: the value {value!r} is not JSON (strings need quotes: '{key}=\"{value}\"')"
            ) from None
    return overrides


def check_init_from(path: str, stage: str, config: dict) -> None:
    """`--init-from`, checked before any flow starts, one line naming it: a readable checkpoint of `stage` whose
    tensors are its recorded configuration's, finite, as its model card says, and able to start a run of `config`
    (`checkpoint.warm_weights`)."""
    try:
        state = checkpoint.verify(path, stage)  # a missing file: "no such checkpoint"
        checkpoint.warm_weights(path, state, stage, checkpoint.module_shapes(stage, config))
    except CheckpointError as error:
        raise CheckpointError(f"--init-from {error}") from None


#: The frames store a stage trains on unless --store says otherwise.
STORE = "datasets/frames.zarr"


def _parser() -> CommandParser:
    parser = CommandParser(prog="python -m flows.train", description=__doc__)
    parser.add_argument("stage", choices=["vqvae", "pixelcnn"], help="which stage to train")
    parser.add_argument(
        "--store", type=PathArgument(PathKind.STORE), help=f"frames store from flows.build_datasets (default {STORE})"
    )
    parser.add_argument(
        "--world",
        choices=world_names(),
        default=None,
        help="the store's world, checked against the store's own (default: the store's)",
    )
    parser.add_argument(
        "--model",
        choices=world_model_names(),
        help="world-model configuration (default: the store's world's own: default for the road, "
        "a world's configuration of its own name for another)",
    )
    parser.add_argument(
        "--out",
        type=PathArgument(PathKind.OUTPUT_FOLDER),
        default="datasets/checkpoints",
        help="folder for training runs",
    )
    for name in ("epochs", "steps_per_epoch", "max_minutes", "threads"):
        default = TrainBudget.model_fields[name].default
        parser.add_argument(
            f"--{name.replace('_', '-')}",
            type=bounded(TrainBudget, name),
            default=default,
            help=field_help(TrainBudget, name),
        )
    parser.add_argument("--device", help="torch device to train on, e.g. cuda (default: the CPU); same run folder")
    parser.add_argument(
        "--init-from",
        type=PathArgument(PathKind.WEIGHTS),
        metavar="CHECKPOINT",
        help="start from these weights (same architecture)",
    )
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=JSON", help="override config fields")
    parser.add_argument("--codes", help="pixelcnn: the store's code array to train on (default: codes_<model>)")
    parser.add_argument(
        "--tensorboard",
        type=PathArgument(PathKind.OUTPUT_FOLDER),
        metavar="DIR",
        help=f"also write TensorBoard scalars and images to DIR/<run folder>/ (needs the tensorboard extra: {INSTALL})",
    )
    add_console_options(parser)
    return parser


def _checked(args: argparse.Namespace) -> tuple[dict, dict]:
    """The run's (config overrides, budget), every value and path checked before any flow starts; an error is a
    ValueError naming the bad one."""
    overrides = parse_overrides(args.set)
    budget = TrainBudget(
        epochs=args.epochs,
        steps_per_epoch=args.steps_per_epoch,
        max_minutes=args.max_minutes,
        threads=args.threads,
        init_from=args.init_from,
        device=args.device,
    ).model_dump()
    preset = world_model_spec(args.model)
    try:
        if args.stage == "vqvae":
            config = VQVAEConfig(**{**preset.tokenizer.model_dump(), **overrides})
        else:
            config = PixelCNNConfig(**{**preset.prior.model_dump(), **overrides})
    except ConfigError as error:  # the preset is valid: an override is not
        raise ConfigError(f"--set: {error}") from None
    if args.init_from:
        check_init_from(args.init_from, args.stage, config.model_dump())
    inputs = (args.store,)  # a run folder is new: --init-from may be a checkpoint under --out
    check_output(args.out, "--out", "folder", inputs=inputs)
    if args.tensorboard:
        check_output(args.tensorboard, "--tensorboard", "folder", inputs=inputs)
        check_available()
    check_input(args.store, "--store", PathKind.STORE)
    problem = store_problem(args.store) or metadata_problem(args.store)
    if problem:
        raise ValueError(f"--store {problem}")
    group = zarr.open_group(args.store, mode="r", use_consolidated=False)
    world = store_world(dict(group.attrs))
    if args.world is not None and world != args.world:
        raise ValueError(f"--store {args.store}: holds the {world} world's episodes, not --world {args.world}'s")
    if world != preset.world:
        raise ValueError(
            f"--store {args.store}: holds the {world} world's episodes; --model {args.model} models the "
            f"{preset.world} world's (the {world} world's: {', '.join(models_of(world))})"
        )
    codes = args.codes or f"codes_{args.model}"
    if args.stage == "pixelcnn" and codes not in group:
        raise FileNotFoundError(
            f"{args.store}: no {codes}; train the VQ-VAE first (python -m flows.train vqvae --model {args.model})"
        )
    return overrides, budget


def _world_of(store: str) -> str:
    """The world of `store`'s episodes, or the road where it is no readable store (`_checked` says why)."""
    try:
        return store_world(dict(zarr.open_group(store, mode="r", use_consolidated=False).attrs))
    except (OSError, ValueError, KeyError, zarr.errors.BaseZarrError):  # named by the checks that follow
        return DEFAULT_WORLD


def main(argv: list[str] | None = None) -> str:
    parser = _parser()
    args = parser.parse_args(argv)
    args.store = args.store or STORE  # checked with the rest, after the values that need no store
    args.model = args.model or default_model(args.world or _world_of(args.store))
    try:
        overrides, budget = _checked(args)
    except (ConfigError, ValueError, FileNotFoundError, CheckpointError, MissingExtra) as error:
        parser.error(str(error))
    common = {
        "store": args.store,
        "model": args.model,
        "out": args.out,
        "budget": budget,
        "overrides": overrides,
        "tensorboard": args.tensorboard,
    }
    with temporary_api():
        if args.stage == "vqvae":
            return train_vqvae_flow(**common)
        return train_pixelcnn_flow(**common, codes=args.codes or f"codes_{args.model}")


if __name__ == "__main__":
    run_command(main, "python -m flows.train")
