"""`python -m flows.evaluate --world freeway`: Freeway's techniques on the real game, one Prefect task an episode.

Plays `--episodes` NOOP starts (drawn from `--seed`) of each `--modes` game mode with each technique (`oracle`:
the true future, `learned`: the future Freeway's world model imagines, `zero`: no cars after the frame now, `up`:
always UP, `random`), writing one result file per episode under `RESULTS/RUN/` and skipping the episodes the run
holds, so an interrupted evaluation resumes; then prints each technique's mean score ± std, knocks an episode and
median decision milliseconds, and writes them to `RESULTS/RUN/summary.json`.
"""

from __future__ import annotations

import argparse
import json

from prefect import flow, task
from prefect.cache_policies import NO_CACHE
from prefect.futures import as_completed

from dynplan.cli import Bounded, CommandParser, add_debug_option, bounded
from dynplan.config import field_help
from dynplan.evaluation.freeway import (
    TECHNIQUES,
    FreewayPlan,
    evaluate_episode,
    read_run,
    summarise,
    world_model_for,
)
from dynplan.evaluation.store import StoreError, check_run_name
from dynplan.files import write_bytes_atomic
from dynplan.models.checkpoint import CheckpointError
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.planning.chicken import ChickenSearch
from dynplan.progress import progress
from flows.runners import task_runner

RESULTS_DIR = "datasets/results/freeway"


@task(name="play-freeway-episode", cache_policy=NO_CACHE)
def episode_task(results: str, run: str, technique: str, plan: dict, index: int, horizon: int,
                 model_dir: str | None = None) -> dict:  # fmt: skip
    search, model = ChickenSearch(horizon=horizon), world_model_for(technique, model_dir)
    return evaluate_episode(results, run, technique, FreewayPlan(**plan), index, search, model).to_dict()


@flow(name="evaluate-freeway", log_prints=True)
def evaluate_freeway(
    techniques: list[str],
    modes: list[int],
    episodes: int = 20,
    seed: int = 0,
    horizon: int = 8,
    results: str = RESULTS_DIR,
    run: str = "evaluation",
    model_dir: str | None = None,
) -> list[dict]:
    """Play every (technique, mode, episode) not yet in the run; summarise the run. `model_dir`: the learned
    technique's world model (`vqvae.pt`, `pixelcnn.pt`; default: the committed weights)."""
    plans = [FreewayPlan(mode=m, episodes=episodes, seed=seed) for m in modes]
    futures = [episode_task.submit(results, run, technique, plan.model_dump(), i, horizon, model_dir)
               for plan in plans for technique in techniques for i in range(episodes)]  # fmt: skip
    for _ in progress(as_completed(futures), total=len(futures), description="freeway episodes"):
        pass
    summary = summarise(read_run(results, run))
    write_bytes_atomic(f"{results}/{run}/summary.json", (json.dumps(summary, indent=1) + "\n").encode())
    for row in summary:
        ms = "" if row["decision_ms"] is None else f", {row['decision_ms']:g} ms a decision"
        print(f"mode {row['mode']} {row['technique']} k={row['horizon']}: {row['score']:g} ± {row['std']:g} over "
              f"{row['episodes']} episodes, {row['knocks']:g} knocks an episode{ms}")  # fmt: skip
    return summary


def parser() -> argparse.ArgumentParser:
    parser = CommandParser(prog="python -m flows.evaluate --world freeway", description=__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--world", choices=["freeway"], default="freeway", help="freeway")
    parser.add_argument("--techniques", nargs="+", choices=TECHNIQUES, default=list(TECHNIQUES),
                        help="techniques to play (default: all)")  # fmt: skip
    parser.add_argument("--modes", nargs="+", type=bounded(FreewayPlan, "mode"), default=[0],
                        help=field_help(FreewayPlan, "mode", "0") + ", one or more")  # fmt: skip
    parser.add_argument("--episodes", type=bounded(FreewayPlan, "episodes"), default=20,
                        help=field_help(FreewayPlan, "episodes"))  # fmt: skip
    parser.add_argument("--seed", type=bounded(FreewayPlan, "seed"), default=0, help=field_help(FreewayPlan, "seed"))
    parser.add_argument("--horizon", type=bounded(ChickenSearch, "horizon"), default=8,
                        help=field_help(ChickenSearch, "horizon"))  # fmt: skip
    parser.add_argument("--results-dir", type=PathArgument(PathKind.OUTPUT_FOLDER), default=RESULTS_DIR,
                        help=f"where runs are written (default {RESULTS_DIR})")  # fmt: skip
    parser.add_argument("--run", default="evaluation", help="the run to play into (default 'evaluation')")
    parser.add_argument("--model-dir", type=PathArgument(PathKind.MODEL_FOLDER),
                        help="the learned technique's world model: a folder holding vqvae.pt and pixelcnn.pt "
                        "(default: the committed Freeway weights)")  # fmt: skip
    parser.add_argument("--workers", type=Bounded(int, 1, 64), default=None, help="episodes at once (default: cores)")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_debug_option(parser)
    return parser


def main(argv: list[str] | None = None) -> list[dict]:
    commands = parser()
    args = commands.parse_args(argv)
    try:
        check_run_name(args.run)
        check_output(args.results_dir, "--results-dir", "folder")
        if "learned" in args.techniques:
            world_model_for("learned", args.model_dir)
    except (StoreError, ValueError, CheckpointError) as error:
        commands.error(str(error))
    summary = evaluate_freeway.with_options(task_runner=task_runner(None, args.workers))(
        techniques=args.techniques, modes=args.modes, episodes=args.episodes, seed=args.seed, horizon=args.horizon,
        results=args.results_dir, run=args.run, model_dir=args.model_dir,
    )  # fmt: skip
    if args.json:
        print(json.dumps(summary))
    return summary
