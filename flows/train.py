"""`python -m flows.train vqvae --store STORE.zarr [--model default|paper]`: train a world-model stage as a
cached, resumable Prefect task, then encode the store with it (the `codes_<model>` array).

The run's folder is named by what determines its result — (dataset fingerprint, config, batches per epoch,
seed, code version) — so a rerun with the same inputs returns the finished checkpoint at once (a Prefect cache
hit), an interrupted run continues from its last epoch, and a larger `--epochs` extends a finished run.
`--max-minutes` stops early (resumably): rerun the same command to go on.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from prefect import flow, task
from prefect.cache_policies import NO_CACHE
from prefect.context import TaskRunContext

from dynplan.config import ConfigError
from dynplan.data.codes import build_codes
from dynplan.data.store import fingerprint
from dynplan.models.vqvae import PRESETS, VQVAEConfig
from dynplan.training import checkpoint
from dynplan.training.checkpoint import digest
from dynplan.training.vqvae import CODE_VERSION, TrainBudget, train_vqvae


def vqvae_run_dir(store: str, out: str, config: dict, budget: dict) -> Path:
    """Where a training run lives: named by what determines its result."""
    determining = {k: v for k, v in budget.items() if k not in ("epochs", "max_minutes", "threads")}
    key = digest(fingerprint(store), config, determining, CODE_VERSION)
    return Path(out) / f"vqvae-{config['name']}-{key[:12]}"


def _cache_key(context: TaskRunContext, parameters: dict) -> str | None:
    """Cache only finished runs: a key exists once the run's final checkpoint has the epochs asked for."""
    budget = parameters["budget"]
    run_dir = vqvae_run_dir(parameters["store"], parameters["out"], parameters["config"], budget)
    final = run_dir / "vqvae.pt"
    if not final.exists() or checkpoint.load(final, "vqvae")["epoch"] < budget["epochs"]:
        return None
    return digest(str(run_dir.resolve()), budget["epochs"])  # the folder's full path: a key per place on disk


@task(name="train-vqvae", cache_key_fn=_cache_key, persist_result=True)
def train_vqvae_task(store: str, out: str, config: dict, budget: dict) -> str:
    run_dir = vqvae_run_dir(store, out, config, budget)
    shown = ("epoch", "loss", "val_fn_rate", "val_fp_rate", "val_goal_exact", "val_codes_used")
    path = train_vqvae(store, run_dir, VQVAEConfig(**config), TrainBudget(**budget),
                       on_epoch=lambda row: print(json.dumps({k: row[k] for k in shown})))  # fmt: skip
    return str(path)


@task(name="build-codes", cache_policy=NO_CACHE)
def build_codes_task(store: str, checkpoint: str, name: str) -> str:
    return build_codes(store, checkpoint, name)


@flow(name="train-vqvae", log_prints=True)
def train_vqvae_flow(store: str = "datasets/frames.zarr", model: str = "default", out: str = "datasets/checkpoints",
                     budget: dict | None = None, overrides: dict | None = None) -> str:  # fmt: skip
    """Train the VQ-VAE preset `model` (with optional config `overrides`) on `store`."""
    config = PRESETS[model].model_copy(update=overrides or {})
    config = VQVAEConfig(**config.model_dump())  # validate the overrides
    path = train_vqvae_task(store, out, config.model_dump(), TrainBudget(**(budget or {})).model_dump())
    print(f"checkpoint: {path}")
    if Path(path).name == "vqvae.pt":  # finished (not stopped early by max_minutes): encode the store
        print(f"codes: {build_codes_task(store, path, model)} in {store}")
    return path


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(prog="python -m flows.train", description=__doc__)
    parser.add_argument("stage", choices=["vqvae"], help="which stage to train")
    parser.add_argument("--store", default="datasets/frames.zarr", help="frames store from flows.build_datasets")
    parser.add_argument("--model", default="default", choices=sorted(PRESETS), help="configuration preset")
    parser.add_argument("--out", default="datasets/checkpoints", help="folder for training runs")
    parser.add_argument("--epochs", type=int, default=TrainBudget().epochs)
    parser.add_argument("--steps-per-epoch", type=int, default=TrainBudget().steps_per_epoch)
    parser.add_argument("--max-minutes", type=float, help="stop after this long (resumable)")
    parser.add_argument("--threads", type=int, help="torch threads (default: all cores)")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=JSON", help="override config fields")
    args = parser.parse_args(argv)
    try:
        overrides = {k: json.loads(v) for k, v in (item.split("=", 1) for item in args.set)}
        budget = TrainBudget(epochs=args.epochs, steps_per_epoch=args.steps_per_epoch, max_minutes=args.max_minutes,
                             threads=args.threads).model_dump()  # fmt: skip
        VQVAEConfig(**{**PRESETS[args.model].model_dump(), **overrides})
        if not Path(args.store).exists():
            raise FileNotFoundError(f"{args.store}: no such store (build it with python -m flows.build_datasets)")
    except (ConfigError, ValueError, FileNotFoundError) as error:
        parser.error(str(error))
    return train_vqvae_flow(store=args.store, model=args.model, out=args.out, budget=budget, overrides=overrides)


if __name__ == "__main__":
    main()
