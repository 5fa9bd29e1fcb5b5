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
from typing import get_args

from dynplan.cli import CommandParser, bounded, run_command
from dynplan.config import ConfigError, field_help
from dynplan.extras import MissingExtra
from dynplan.models.configs import PixelCNNConfig, VQVAEConfig
from dynplan.models.registry import WorldModelSpec, default_model, models_of, world_model_names, world_model_spec
from dynplan.paths import PathArgument, PathKind, check_input, check_output
from dynplan.training.budget import TrainBudget
from dynplan.training.precision import Precision
from dynplan.training.tensorboard import INSTALL, check_available
from dynplan.world import DEFAULT_WORLD, world_names
from flows.cli import add_console_options, temporary_api

# torch, zarr and the training code are imported by the functions that read a checkpoint or a store and by `main`
# before a flow runs, so that `--help` and a usage error answer at once.


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
    from dynplan.models import checkpoint
    from dynplan.models.checkpoint import CheckpointError

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
        "--precision",
        choices=get_args(Precision),
        default="float32",
        help="arithmetic of the training steps (bfloat16: autocast, on a device with bfloat16 instructions; "
        "a run folder of its own)",
    )
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
    if args.codes and args.stage == "vqvae":
        raise ValueError("--codes names the code array a PixelCNN trains on; a VQ-VAE trains on the store's frames")
    overrides = parse_overrides(args.set)
    budget = TrainBudget(
        epochs=args.epochs,
        steps_per_epoch=args.steps_per_epoch,
        max_minutes=args.max_minutes,
        threads=args.threads,
        init_from=args.init_from,
        device=args.device,
        precision=args.precision,
    ).model_dump()
    preset = world_model_spec(args.model)
    if overrides.get("world", preset.world) != preset.world:  # the store is checked against the model's world
        raise ValueError(
            f"--set world={overrides['world']!r}: --model {args.model} models the {preset.world} world; a model of "
            "another world is another --model"
        )
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
    _check_store(args, preset)
    _check_epochs(args, config.model_dump(), budget)
    return overrides, budget


def _check_epochs(args: argparse.Namespace, config: dict, budget: dict) -> None:
    """`--epochs` below what the run has trained already is refused, naming the run: its weights are of more
    epochs than asked, and a run keeps no earlier epoch's."""
    from dynplan.training.loop import trained_epochs
    from dynplan.training.runs import pixelcnn_run_dir, vqvae_run_dir

    if args.stage == "vqvae":
        run_dir = vqvae_run_dir(args.store, args.out, config, budget)
    else:
        run_dir = pixelcnn_run_dir(args.store, args.codes or f"codes_{args.model}", args.out, config, budget)
    trained = trained_epochs(run_dir, args.stage)
    if trained > args.epochs:
        raise ValueError(
            f"--epochs {args.epochs}: the run {run_dir} has trained {trained} epochs, and keeps no earlier epoch's "
            f"weights; ask --epochs {trained} or more, or train a {args.epochs}-epoch run under another --out"
        )


def _check_store(args: argparse.Namespace, preset: WorldModelSpec) -> None:
    """`--store`: a readable frames store of the configuration's world (and `--world`'s), holding the codes a
    PixelCNN trains on; a ValueError or FileNotFoundError naming what is wrong."""
    import zarr

    from dynplan.data.metadata import metadata_problem
    from dynplan.data.store import store_problem, store_world

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


def _world_of(store: str) -> str:
    """The world of `store`'s episodes, or the road where it is no readable store (`_checked` says why)."""
    import zarr

    from dynplan.data.store import store_world

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
    except (ConfigError, ValueError, FileNotFoundError, MissingExtra) as error:  # a CheckpointError is a ValueError
        parser.error(str(error))
    common = {
        "store": args.store,
        "model": args.model,
        "out": args.out,
        "budget": budget,
        "overrides": overrides,
        "tensorboard": args.tensorboard,
    }
    from flows.training import train_pixelcnn_flow, train_vqvae_flow

    with temporary_api():
        if args.stage == "vqvae":
            return train_vqvae_flow(**common)
        return train_pixelcnn_flow(**common, codes=args.codes or f"codes_{args.model}")


if __name__ == "__main__":
    run_command(main, "python -m flows.train")
