"""`python -m flows.evaluate`: the paper's Table 1 protocol over recorded evaluation episodes.

Records the evaluation episodes if they are missing (seeds 1,000,000 …), plays every (technique, agent speed,
rollout steps, episode) case into a named run of the results store (`RESULTS_DIR/runs/RUN/`: a manifest and one
JSON line per episode), in lockstep batches of every case of up to `--batch` recorded worlds that shares a world
model, one Prefect task each — skipping cases the run already holds and appending each row as its episode finishes,
so an interrupted evaluation resumes per episode — then aggregates the evaluation runs into table1.json /
table1.md. The run `evaluation` is Table 1's; `--first-seed 2000000` with another `--log-dir` and `--run` plays the
validation episodes instead, where a world model's settings are chosen (`--occupancy`, `--margin`, `--model-dir`);
any other run on the evaluation episodes is a candidate's. `--table1` plays every case of the complete Table 1
(both world-model configurations, every technique and speed the table lists) in one command. `--world W` evaluates
another world through its own options (`--world W --help` lists them; `flows.worlds`).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
from dataclasses import asdict
from pathlib import Path

import torch
from prefect import flow, task, unmapped
from prefect.cache_policies import NO_CACHE
from prefect.futures import as_completed

from dynplan.cli import Bounded, CommandParser, add_debug_option, bounded
from dynplan.config import ConfigError, field_help
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import (
    AGENT_SPEEDS,
    EVAL_SEED_START,
    ROLLOUT_STEPS,
    TABLE1,
    VALIDATION_SEED_START,
    Case,
    CasePlan,
    road_models,
)
from dynplan.evaluation.protocol import pending, run_cases
from dynplan.evaluation.provenance import begin_run
from dynplan.evaluation.store import EVALUATION_RUN, Run, StoreError, check_run_name, check_store
from dynplan.evaluation.table import aggregate, load_results, render_markdown, write_table
from dynplan.evaluation.techniques import TECHNIQUES
from dynplan.models.caution import Caution
from dynplan.models.checkpoint import CheckpointError
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.progress import progress
from dynplan.world import DEFAULT_WORLD, world_names
from flows.artifacts import ProgressArtifact, publish_table1
from flows.cli import run
from flows.collect import collect_episodes
from flows.runners import add_dask_option, checked_dask_address, task_runner
from flows.worlds import evaluate_main, own_command

DEFAULT_COMMAND = "python -m flows.evaluate"
RESULTS_DIR = "datasets/results"
#: Recorded worlds per lockstep batch (one task): Table 1's 100 worlds make two batches per world model, one a worker.
BATCH = 50


def run_role(run: str, first_seed: int) -> str:
    """A run's role: Table 1's run is the evaluation, other runs on the validation seeds validate, and any other
    run on the evaluation episodes is a candidate's."""
    if first_seed >= VALIDATION_SEED_START:
        return "validation"
    return "evaluation" if run == EVALUATION_RUN else "candidate"


@task(name="evaluate-episodes", cache_policy=NO_CACHE)
def evaluate_cases_task(cases: list[dict], log_dir: str, results_dir: str, run: str, agent: dict) -> list[dict]:
    """Play a batch of cases in lockstep; each row is appended as its episode finishes."""
    return run_cases([Case(**c) for c in cases], log_dir, Run(results_dir, run), AgentSpec(**agent))


def batches(todo: list[Case], size: int) -> list[list[Case]]:
    """The cases in lockstep batches: per world-model configuration (the techniques without one together), the
    cases of up to `size` recorded worlds each — every technique, agent speed and k of those worlds in one batch, so
    that each frame's prediction is made once for all the cases that see it."""
    groups: dict[str | None, dict[int, list[Case]]] = {}
    for case in todo:
        groups.setdefault(case.model, {}).setdefault(case.seed, []).append(case)
    out = []
    for by_seed in groups.values():
        seeds = sorted(by_seed)
        for start in range(0, len(seeds), size):
            out.append([case for seed in seeds[start : start + size] for case in by_seed[seed]])
    return out


@flow(name="evaluate-planner", log_prints=True)
def evaluate_planner(
    plan: CasePlan | None = None,
    agent: AgentSpec | None = None,
    log_dir: str = "datasets/eval_logs",
    results_dir: str = RESULTS_DIR,
    run: str = EVALUATION_RUN,
    command: str = DEFAULT_COMMAND,
    batch: int = BATCH,
    artifacts: str | None = None,
) -> list[dict]:
    """Play the cases of `plan` that `run` lacks with the agents' settings `agent` (playouts, weights — the
    committed ones, or a pipeline's own under `agent.model_dir` — caution overrides, device), in lockstep batches of
    up to `batch` recorded worlds (one Prefect task each; see `batches`), and write the aggregated table. Publishes
    the episodes' progress and the table as Prefect artifacts, the table keyed `table1-<artifacts>` (default: the
    run's name)."""
    plan, agent = plan or CasePlan(), agent or AgentSpec()
    collect_episodes(out=log_dir, episodes=plan.episodes, seed=plan.first_seed)
    store_run = Run(results_dir, run)
    all_cases = plan.cases()
    begin_run(store_run, run_role(run, plan.first_seed), all_cases, log_dir, command, agent)
    todo = pending(all_cases, store_run, log_dir, agent)
    work = batches(todo, batch)
    print(f"{len(todo)} episodes to play into {store_run.dir}, in {len(work)} lockstep batches")
    futures = evaluate_cases_task.map(
        [[asdict(c) for c in b] for b in work],
        unmapped(log_dir),
        unmapped(results_dir),
        unmapped(run),
        unmapped(agent.model_dump()),
    )
    role = store_run.manifest()["role"]
    played = ProgressArtifact(f"episodes played into run {run!r}", len(todo))
    sizes = {future.task_run_id: len(b) for future, b in zip(futures, work, strict=True)}
    for future in progress(as_completed(futures), total=len(futures), description="evaluate batches"):
        future.result()
        played.advance(sizes[future.task_run_id])
        if role == "evaluation":  # a stopped evaluation still leaves an up-to-date table
            write_table(aggregate(load_results(results_dir)), results_dir)
    rows = aggregate(store_run.current())
    table = aggregate(load_results(results_dir)) if role == "evaluation" else rows  # Table 1: every evaluation run's
    if role == "evaluation":
        write_table(table, results_dir)
    publish_table1(table, artifacts or run)
    print(f"\nrun {run!r} ({role}):\n" + render_markdown(rows))
    return rows


def _parser() -> argparse.ArgumentParser:
    parser = CommandParser(prog="python -m flows.evaluate", description=__doc__)
    parser.add_argument(
        "--world",
        choices=world_names(),
        default=DEFAULT_WORLD,
        help="the world (default road; `--world W --help` lists another world's options)",
    )
    parser.add_argument(
        "--techniques",
        nargs="+",
        default=["oracle", "zero", "random"],
        choices=list(TECHNIQUES),
        metavar="TECHNIQUE",
        help="; ".join(f"{n}: {t.description}" for n, t in TECHNIQUES.items()) + " (default: oracle zero random)",
    )
    parser.add_argument(
        "--models",
        nargs="+",
        default=["default"],
        choices=road_models(),
        help="world-model configurations for the learned techniques ("
        + ", ".join(n for n, t in TECHNIQUES.items() if t.world_model)
        + ")",
    )
    parser.add_argument(
        "--agent-speeds",
        nargs="+",
        type=float,
        choices=AGENT_SPEEDS,
        default=list(AGENT_SPEEDS),
        help=field_help(CasePlan, "agent_speeds", " ".join(map(str, AGENT_SPEEDS))),
    )
    parser.add_argument(
        "--rollout-steps",
        nargs="+",
        type=bounded(AgentSpec, "rollout_steps"),
        default=list(ROLLOUT_STEPS),
        help=field_help(CasePlan, "rollout_steps", " ".join(map(str, ROLLOUT_STEPS))),
    )
    _add_agent_options(parser)
    _add_store_options(parser)
    parser.add_argument(
        "--table1",
        action="store_true",
        help="play the complete Table 1: "
        + "; ".join(f"{speed * 2:g}x: {' '.join(names)}" for speed, names in TABLE1.items())
        + f" (learned ones with {' and '.join(road_models())}); instead of --techniques, --models "
        "and --agent-speeds",
    )
    parser.add_argument("--device", default="cpu", help=field_help(AgentSpec, "device"))
    parser.add_argument("--json", action="store_true", help="print the table rows as JSON")
    add_debug_option(parser)
    return parser


def _add_agent_options(parser: argparse.ArgumentParser) -> None:
    """The episodes played and the agents' search settings."""
    for name, flag in (("episodes", "--episodes"), ("first_seed", "--first-seed")):
        default = CasePlan.model_fields[name].default
        parser.add_argument(flag, type=bounded(CasePlan, name), default=default, help=field_help(CasePlan, name))
    parser.add_argument(
        "--playouts", type=bounded(AgentSpec, "playouts"), default=100, help=field_help(AgentSpec, "playouts")
    )
    parser.add_argument(
        "--model-dir", type=PathArgument(PathKind.MODEL_FOLDER), help=field_help(AgentSpec, "model_dir")
    )
    for name in Caution.model_fields:  # the caution's fields, types, ranges and words
        own = "each configuration's own"
        parser.add_argument(f"--{name}", type=bounded(Caution, name), help=field_help(Caution, name, own))


def _add_store_options(parser: argparse.ArgumentParser) -> None:
    """Where the logs and results go, and how the batches are played."""
    parser.add_argument(
        "--log-dir",
        type=PathArgument(PathKind.OUTPUT_FOLDER),
        default="datasets/eval_logs",
        help="evaluation logs (recorded if missing)",
    )
    parser.add_argument(
        "--results-dir",
        type=PathArgument(PathKind.OUTPUT_FOLDER),
        default=RESULTS_DIR,
        help="the results store (runs and Table 1)",
    )
    parser.add_argument(
        "--run",
        default=EVALUATION_RUN,
        help=f"the run to play into (default {EVALUATION_RUN!r}, "
        "Table 1's; name another for validation or a candidate)",
    )
    add_dask_option(parser)
    parser.add_argument(
        "--workers",
        type=Bounded(int, 1, 256),
        help="batches played at once locally, in [1, 256] (default: one per core)",
    )
    parser.add_argument(
        "--batch",
        type=Bounded(int, 1, 10_000),
        default=BATCH,
        help=f"recorded worlds per lockstep batch, in [1, 10000] (default {BATCH})",
    )


def _specs(parser: argparse.ArgumentParser, args: argparse.Namespace) -> tuple[CasePlan, AgentSpec]:
    """The plan and the agents' settings, every value checked by their configs before any flow machinery starts
    (a bad one exits with one line); each learned agent's weights are loaded once to check them."""
    if args.table1:
        given = [
            f"--{name.replace('_', '-')}"
            for name in ("techniques", "models", "agent_speeds")
            if getattr(args, name) != parser.get_default(name)
        ]
        if given:
            parser.error(f"--table1 plays the table's own techniques, models and speeds; drop {' '.join(given)}")
    overrides = {name: value for name in Caution.model_fields if (value := getattr(args, name)) is not None}
    try:
        plan = CasePlan(
            techniques=args.techniques,
            models=args.models,
            agent_speeds=args.agent_speeds,
            rollout_steps=args.rollout_steps,
            episodes=args.episodes,
            first_seed=args.first_seed,
            table1=args.table1,
        )
        Caution(**overrides)  # its ranges, named as the caution's
        agent = AgentSpec(playouts=args.playouts, model_dir=args.model_dir, caution=overrides, device=args.device)
        agents = [agent.for_case(t, m, None, 0) for t, m in plan.pairs()]  # each technique and configuration
        for one in agents:
            one.check_weights()
    except CheckpointError as error:  # (a ValueError too: named first)
        parser.error(f"--model-dir {args.model_dir}: {error}" if args.model_dir else str(error))
    except (ConfigError, ValueError) as error:
        parser.error(str(error).removeprefix("AgentSpec: "))
    return plan, agent


def main(argv: list[str] | None = None) -> list[dict]:
    argv = sys.argv[1:] if argv is None else argv
    if (own := own_command(argv, lambda parts: parts.evaluate)) is not None:
        return evaluate_main(*own, argv)
    parser = _parser()
    args = parser.parse_args(argv)
    if args.world != DEFAULT_WORLD:  # an abbreviated --world reaches here: spell it out to dispatch
        parser.error(f"--world {args.world}: give it as --world {args.world} (in full) for its own options")
    try:
        check_run_name(args.run)
    except StoreError as error:
        parser.error(f"--run: {error}")
    if args.first_seed != EVAL_SEED_START and args.run == EVALUATION_RUN:
        parser.error(
            f"--first-seed={args.first_seed} needs its own --run: the run {EVALUATION_RUN!r} holds the "
            f"evaluation's results (seeds {EVAL_SEED_START:,} …), all of which Table 1 counts"
        )
    try:
        check_output(args.log_dir, "--log-dir", "folder")
        check_output(args.results_dir, "--results-dir", "folder", inputs=(args.log_dir,))
        if Path(args.results_dir).is_dir():
            check_store(args.results_dir)  # every run through its schema: a damaged one is named now, not mid-run
        address = checked_dask_address(args.dask_address)
    except ValueError as error:
        parser.error(str(error))
    plan, agent = _specs(parser, args)
    command = shlex.join(["python", "-m", "flows.evaluate", *argv])
    if not address:  # the local pool's episodes share the cores; more threads only contend
        cores = os.cpu_count() or 1
        torch.set_num_threads(max(1, cores // (args.workers or cores)))
    runner = task_runner(address, args.workers)
    rows = evaluate_planner.with_options(task_runner=runner)(
        plan=plan,
        agent=agent,
        log_dir=args.log_dir,
        results_dir=args.results_dir,
        run=args.run,
        command=command,
        batch=args.batch,
    )
    if args.json:
        print(json.dumps(rows))
    return rows


if __name__ == "__main__":
    run(main, "python -m flows.evaluate")
