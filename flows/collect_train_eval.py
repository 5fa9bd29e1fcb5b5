"""`python -m flows.collect_train_eval [--world W] [--preset quick|full|smoke] [--out DIR] [--dask-address …]`:
the whole system end to end — collect training episodes, build the frames store, train the VQ-VAE, encode the
store, train the PixelCNN prior (per world-model configuration), evaluate the planners (the road's over its
recorded evaluation episodes, another world's through its `PipelineStages`), and write the report
(`DIR/<folder>/report/report.md` and `.html`; the folder is the preset's name, `<world>-<preset>` for a world other
than the road).

Every stage is cached across runs on purpose, by what determines its result rather than by Prefect's default
policy (which includes the flow run's id and so never hits across runs): collection skips complete logs (one
per seed), the store skips logs it holds (by SHA-256), training runs are keyed by (store fingerprint, config,
budget, code version) — finished ones are Prefect cache hits, interrupted ones resume from their last epoch —,
evaluation reuses every per-episode result played with the same playouts, log and weights (another world's as its
stages say), and the report's pictures are redrawn only when the checkpoints change. A rerun therefore
does only what changed, and an interrupted run resumes where it stopped.

Outputs: `DIR/<folder>/{logs,frames.zarr,checkpoints,models,results,report}` and the road's evaluation logs,
shared by presets (they are the same recordings), in `DIR/eval_logs`. With a Dask scheduler address, collection, the
store's conversion and the evaluation episodes run on the cluster's workers; training runs in this process.
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import sys
import time
from dataclasses import asdict
from pathlib import Path

from dynplan.cli import CommandParser, run_command
from dynplan.config import ConfigError
from dynplan.files import atomic_path, sha256_file, write_bytes_atomic
from dynplan.models.weights import pretrained_path
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.pipeline.presets import PipelinePreset, pipeline_preset, pipeline_presets
from dynplan.pipeline.report import (
    StageRecord,
    checkpoint_record,
    render_report,
    write_report,
)
from dynplan.world import DEFAULT_WORLD, world, world_names
from flows.artifacts import publish_report
from flows.build_datasets import build_datasets
from flows.cli import add_console_options, temporary_api
from flows.collect import collect_episodes
from flows.deferred import NO_CACHE, flow, task
from flows.runners import add_dask_option, checked_dask_address, task_runner
from flows.worlds import evaluate_world


def _install(source: Path, target: Path) -> None:
    """Copy a final checkpoint to where the evaluation reads it, atomically, unless it is there already."""
    if target.exists() and sha256_file(target) == sha256_file(source):
        return
    with atomic_path(target) as tmp:
        shutil.copyfile(source, tmp)


def _trained(run_dir: Path, kind: str, epochs: int) -> bool:
    final = run_dir / f"{kind}.pt"
    from dynplan.models import checkpoint as checkpoints

    return final.exists() and checkpoints.load(final, kind)["epoch"] >= epochs


@task(name="world-model", cache_policy=NO_CACHE)
def world_model_task(preset: dict, model: str, store: str, work: str) -> list[dict]:
    """Train (or reuse) both stages of configuration `model`, install them in `work/models/<model>/`; return
    what happened per stage. With `pretrained`, a stage whose committed weights exist uses them (a committed
    tokenizer without a committed prior: the prior trains on the store encoded by it)."""
    from dynplan.models import checkpoint as checkpoints  # torch and the training code: on use, not for `--help`
    from flows.training import build_codes_task, pixelcnn_run_dir, train_pixelcnn_task, train_vqvae_task, vqvae_run_dir

    plan = PipelinePreset(**preset)
    target = Path(work) / "models" / model
    committed = {stage: pretrained_path(stage, model) for stage in ("vqvae", "pixelcnn")}
    use = {stage: plan.pretrained and path.exists() for stage, path in committed.items()}
    use["pixelcnn"] = use["pixelcnn"] and use["vqvae"]  # a committed prior reads only its own tokenizer's codes
    records = []
    out = str(Path(work) / "checkpoints")
    start = time.perf_counter()
    if use["vqvae"]:
        vqvae, detail = str(committed["vqvae"]), "committed weights"
    else:
        vq_config, vq_budget = plan.vqvae_config(model).model_dump(), plan.vqvae_plan(model).budget.model_dump()
        cached = _trained(vqvae_run_dir(store, out, vq_config, vq_budget), "vqvae", vq_budget["epochs"])
        vqvae = train_vqvae_task(store, out, vq_config, vq_budget)
        detail = ("cached" if cached else "trained") + f", {vq_budget['epochs']} epochs"
    if use["pixelcnn"]:
        prior = str(committed["pixelcnn"])
        records.append({"name": f"vqvae [{model}]", "wall_s": time.perf_counter() - start, "detail": detail})
        records.append({"name": f"pixelcnn [{model}]", "wall_s": 0.0, "detail": "committed weights"})
    else:  # the prior trains on the store encoded by this tokenizer
        codes = build_codes_task(store, vqvae, model)
        records.append(
            {"name": f"vqvae [{model}]", "wall_s": time.perf_counter() - start, "detail": detail + "; store encoded"}
        )
        px_config, px_budget = plan.pixelcnn_config(model).model_dump(), plan.pixelcnn_plan(model).budget.model_dump()
        px_config["codebook_size"] = checkpoints.load(vqvae, "vqvae")["config"]["codebook_size"]  # K follows it
        cached = _trained(pixelcnn_run_dir(store, codes, out, px_config, px_budget), "pixelcnn", px_budget["epochs"])
        start = time.perf_counter()
        prior = train_pixelcnn_task(store, codes, out, px_config, px_budget)
        detail = ("cached" if cached else "trained") + f", {px_budget['epochs']} epochs"
        records.append({"name": f"pixelcnn [{model}]", "wall_s": time.perf_counter() - start, "detail": detail})
    _install(Path(vqvae), target / "vqvae.pt")
    _install(Path(prior), target / "pixelcnn.pt")
    return records


def _write_report(
    plan: PipelinePreset, work: Path, command: str, results: list[str], records: list[StageRecord]
) -> str:
    """The report's Markdown and HTML (the world's `results` section, then stages and checkpoints), its artifact
    and the stages' timings; returns the Markdown's path."""
    models = {m: work / "models" / m for m in plan.models}
    ckpts = [checkpoint_record(s, m, models[m] / f"{s}.pt") for m in plan.models for s in ("vqvae", "pixelcnn")]
    markdown = render_report(plan.model_dump(mode="json"), command, results, records, ckpts)
    md, _ = write_report(work / "report", markdown)
    publish_report(markdown, plan.folder)
    timings = json.dumps([asdict(r) for r in records], indent=1).encode()
    write_bytes_atomic(work / "report" / "stages.json", timings)
    return str(md)


@task(name="report", cache_policy=NO_CACHE)
def report_task(preset: dict, work: str, results: str, command: str, stages: list[dict]) -> str:
    """The world's report: the results section its stages write (pictures into the report's folder)."""
    plan, work_dir = PipelinePreset(**preset), Path(work)
    start = time.perf_counter()
    section = world(plan.world).load().pipeline.report(plan, work_dir, work_dir / "report", command)
    records = [StageRecord(**s) for s in stages]
    records.append(StageRecord("report", time.perf_counter() - start, "pictures, Markdown and HTML"))
    return _write_report(plan, work_dir, command, section, records)


def _evaluate_world(plan: PipelinePreset, work: Path, runner, command: str) -> tuple[str, str]:
    """The preset's evaluation requests, each through the world's evaluation (its summary's artifact keyed by the
    preset's name); (the results folder, detail)."""
    requests = world(plan.world).load().pipeline.evaluations(plan, work)
    played = 0
    for request in requests:
        flow = evaluate_world.with_options(task_runner=runner)
        played += len(flow(plan.world, request.model_dump(mode="json"), command, plan.name))
    return str(work / "results"), f"{len(requests)} runs, {played} summary rows"


def _said(stage: dict) -> dict:
    """`stage` (name, wall time, detail), once its line is printed."""
    print(f"stage {stage['name']}: {stage['detail']} ({stage['wall_s']:.1f} s)")
    return stage


@flow(name="collect-train-eval", log_prints=True)
def collect_train_eval(
    preset: str = "quick",
    out: str = "datasets",
    dask_address: str | None = None,
    command: str | None = None,
    world: str = DEFAULT_WORLD,
) -> str:
    """Collect → build datasets → train both world-model stages → evaluate → report, each stage cached; returns
    the report's path."""
    plan = pipeline_preset(preset, world)
    work = Path(out) / plan.folder
    store = str(work / "frames.zarr")
    runner = task_runner(dask_address)
    shown = "" if world == DEFAULT_WORLD else f"--world {world} "
    command = command or f"python -m flows.collect_train_eval {shown}--preset {preset} --out {out}"
    stages: list[dict] = []

    def timed(name: str, call, detail=lambda result: ""):
        start = time.perf_counter()
        result = call()
        stages.append(_said({"name": name, "wall_s": time.perf_counter() - start, "detail": detail(result)}))
        return result

    timed(
        "collect",
        lambda: collect_episodes.with_options(task_runner=runner)(
            out=str(work / "logs"), episodes=plan.train_episodes, seed=0, world_name=plan.world
        ),
        lambda r: (
            f"{len(r['seeds'])} episodes, {r['written'] + r['rewritten']} recorded now"
            + ("" if r["written"] + r["rewritten"] else "; cached")
        ),
    )
    timed(
        "build datasets",
        lambda: build_datasets.with_options(task_runner=runner)(
            log_dir=str(work / "logs"), out=store, dask_address=dask_address, world_name=plan.world
        ),
        lambda r: f"{r['episodes']} episodes: {len(r['added'])} added" + ("" if r["added"] else "; cached"),
    )
    for model in plan.models:
        stages += [_said(r) for r in world_model_task(plan.model_dump(mode="json"), model, store, str(work))]
    played = timed("evaluate", lambda: _evaluate_world(plan, work, runner, command), lambda r: r[1])
    report = report_task(plan.model_dump(mode="json"), str(work), played[0], command, stages)
    print(f"report: {report}")
    return report


def main(argv: list[str] | None = None) -> str:
    parser = CommandParser(
        prog="python -m flows.collect_train_eval",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--world", choices=world_names(), default=DEFAULT_WORLD, help="the world (default road)")
    names = sorted({name for w in world_names() for name in pipeline_presets(w)})
    parser.add_argument(
        "--preset", default="quick", choices=names, help="run scale (each world has its own quick, full and smoke)"
    )
    parser.add_argument(
        "--out", type=PathArgument(PathKind.OUTPUT_FOLDER), default="datasets", help="output folder (default: datasets)"
    )
    add_dask_option(parser)
    add_console_options(parser)
    args = parser.parse_args(argv)
    try:
        check_output(args.out, "--out", "folder")
        pipeline_preset(args.preset, args.world)  # a world without it: one line, before any flow machinery
        address = checked_dask_address(args.dask_address)
    except (ConfigError, ValueError) as error:
        parser.error(str(error))
    command = shlex.join(["python", "-m", "flows.collect_train_eval", *(sys.argv[1:] if argv is None else argv)])
    with temporary_api():
        report = collect_train_eval(
            preset=args.preset, out=args.out, dask_address=address, command=command, world=args.world
        )
    print(json.dumps({"report": report}))
    return report


if __name__ == "__main__":
    run_command(main, "python -m flows.collect_train_eval")
