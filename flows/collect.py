"""`python -m flows.collect`: record episodes as MCAP logs, one Prefect task per episode, resumably.

Episode i uses seed S + i, within the world's seeds (an error names their range and what a seed is there). Rerunning
skips complete logs and rewrites damaged ones, so an interrupted collection is finished by running the same command
again.
"""

from __future__ import annotations

import json
from collections import Counter

from dynplan.cli import CommandParser, bounded, run_command
from dynplan.config import field_help
from dynplan.data.collect import CollectPlan, all_recorded, record_episode, stale_temporaries
from dynplan.env.config import RoadConfig
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.progress import progress
from dynplan.world import DEFAULT_WORLD, world, world_names
from flows.cli import add_console_options, temporary_api
from flows.deferred import NO_CACHE, flow, task
from flows.runners import add_dask_option, checked_dask_address, task_runner

#: Episodes a collection records unless told: 10, or fewer where the world has fewer from the first seed on.
DEFAULT_EPISODES = 10


@task(name="record-episode", cache_policy=NO_CACHE)
def record_episode_task(
    out: str, seed: int, config: dict, n_frames: int | None = None, world_name: str = DEFAULT_WORLD
) -> dict:
    return record_episode(out, seed, config, n_frames, world_name).to_dict()


@flow(name="collect-episodes", log_prints=True)
def collect_episodes(
    out: str = "datasets/logs",
    episodes: int = 10,
    seed: int = 0,
    config: dict | None = None,
    n_frames: int | None = None,
    world_name: str = DEFAULT_WORLD,
) -> dict:
    """Record episodes seed … seed+episodes−1 of the world `world_name` under `config` into `out`."""
    from prefect import unmapped
    from prefect.futures import as_completed

    plan, entry = CollectPlan(episodes=episodes, seed=seed), world(world_name)
    recording = entry.config(config) if config else entry.recording
    for seed_ in (seed, seed + episodes - 1):
        entry.check_seed(seed_)
    for leftover in stale_temporaries(out):
        leftover.unlink(missing_ok=True)
    seeds = plan.seeds
    futures = record_episode_task.map(
        out,
        seeds,
        config=unmapped(recording.model_dump()),
        n_frames=unmapped(n_frames),
        world_name=unmapped(entry.name),
    )
    results = [f.result() for f in progress(as_completed(futures), total=len(futures), description="collect")]
    return _summary(out, seeds, Counter(r["status"] for r in results))


def _summary(out: str, seeds: list[int], counts: Counter) -> dict:
    """What a collection did, printed in one line."""
    print(f"{out}: {counts['written']} written, {counts['rewritten']} rewritten, {counts['skipped']} already complete")
    return {"out": out, "seeds": seeds, **{k: counts[k] for k in ("written", "rewritten", "skipped")}}


def main(argv: list[str] | None = None) -> dict:
    parser = CommandParser(prog="python -m flows.collect", description=__doc__)
    parser.add_argument(
        "--world", choices=world_names(), default=DEFAULT_WORLD, help=f"the world to record (default {DEFAULT_WORLD})"
    )
    parser.add_argument(
        "--episodes",
        type=bounded(CollectPlan, "episodes"),
        default=None,
        help=field_help(
            CollectPlan,
            "episodes",
            "10, or the world's episodes from --seed on if fewer (a world of 8 episodes: its 8)",
        ),
    )
    parser.add_argument("--seed", type=bounded(CollectPlan, "seed"), default=0, help=field_help(CollectPlan, "seed"))
    parser.add_argument(
        "--out",
        type=PathArgument(PathKind.OUTPUT_FOLDER),
        default="datasets/logs",
        help="folder for the logs (default datasets/logs)",
    )
    parser.add_argument(
        "--level",
        type=bounded(RoadConfig, "level"),
        default=None,
        help=field_help(RoadConfig, "level", str(RoadConfig().level)) + "; the road's",
    )
    parser.add_argument(
        "--agent-speed",
        type=bounded(RoadConfig, "agent_speed"),
        default=None,
        help="sets the road's episode length T (default 0.5: 407 frames, enough for both paper agents)",
    )
    add_dask_option(parser)
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_console_options(parser)
    args = parser.parse_args(argv)
    try:
        config = _recording(args)
        entry = world(args.world)
        entry.check_seed(args.seed, "--seed")
        episodes = args.episodes or min(DEFAULT_EPISODES, entry.seeds[1] - args.seed + 1)
        plan = CollectPlan(episodes=episodes, seed=args.seed)
        entry.check_seed(plan.seed + plan.episodes - 1, "--seed + --episodes − 1")
        check_output(args.out, "--out", "folder")
        address = checked_dask_address(args.dask_address)
    except ValueError as error:
        parser.error(str(error))
    if all_recorded(args.out, plan.seeds, config, world_name=args.world):  # nothing to do: no flow to run
        summary = _summary(args.out, plan.seeds, Counter(skipped=plan.episodes))
    else:
        with temporary_api():
            summary = collect_episodes.with_options(task_runner=task_runner(address))(
                out=args.out, episodes=plan.episodes, seed=args.seed, config=config, world_name=args.world
            )
    if args.json:
        print(json.dumps(summary))
    return summary


def _recording(args) -> dict:
    """The recording's config from the command line: the road's level and agent speed; other worlds take none."""
    road = {"level": args.level, "agent_speed": args.agent_speed}
    if args.world != DEFAULT_WORLD:
        given = [f"--{name.replace('_', '-')}" for name, value in road.items() if value is not None]
        if given:
            raise ValueError(f"{' and '.join(given)}: the road world's, not --world {args.world}'s")
        return world(args.world).recording.model_dump()
    chosen = {k: v for k, v in road.items() if v is not None}
    return RoadConfig.from_dict(world(DEFAULT_WORLD).recording.model_dump(), **chosen).model_dump()


if __name__ == "__main__":
    run_command(main, "python -m flows.collect")
