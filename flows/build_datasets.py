"""`python -m flows.build_datasets LOG_DIR --out STORE.zarr`: turn episode logs into the Zarr frames store.

Logs are inspected one Prefect task each and copied with dask; logs already in the store (by SHA-256) are
skipped, so rerunning after new logs arrive appends only those, after checking the episodes already in (and
repairing any damaged one from its log). Damaged logs are reported and skipped.

A store holds the episodes of one world (`--world`; default the store's, else road); a log of another world is
refused.

`python -m flows.build_datasets --verify STORE.zarr [LOG_DIR]` re-reads every chunk of the store, names each
damaged one with its episodes and, given the logs, repairs them; exit status 1 if damage remains.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from dynplan.cli import CommandParser, run_command
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.progress import progress
from dynplan.world import DEFAULT_WORLD, world_names
from flows.cli import add_console_options, temporary_api
from flows.deferred import NO_CACHE, flow, task
from flows.runners import add_dask_option, checked_dask_address, dask_scheduler, task_runner

if TYPE_CHECKING:
    from dynplan.data.store import LogInfo

# zarr and dask are imported by the functions that read or write a store, so that `--help` and a usage error
# answer at once.


@task(name="inspect-log", cache_policy=NO_CACHE)
def inspect_log_task(path: str, world_name: str = DEFAULT_WORLD) -> LogInfo:
    from dynplan.data.store import inspect_for_store

    info = inspect_for_store(path)
    if not info.error and info.world != world_name:
        return replace(info, error=f"{path}: a log of the {info.world} world; this build is --world {world_name}'s")
    return info


@flow(name="build-datasets", log_prints=True)
def build_datasets(
    log_dir: str = "datasets/logs",
    out: str = "datasets/frames.zarr",
    dask_address: str | None = None,
    world_name: str = DEFAULT_WORLD,
) -> dict:
    """Append every new log of the world `world_name` in `log_dir` to the frames store `out`."""
    from prefect import unmapped
    from prefect.futures import as_completed

    from dynplan.data.build import build_frame_store
    from dynplan.data.store import list_logs

    logs = [str(p) for p in list_logs(log_dir)]
    futures = inspect_log_task.map(logs, world_name=unmapped(world_name))
    infos = [f.result() for f in progress(as_completed(futures), total=len(futures), description="inspect logs")]
    with dask_scheduler(dask_address):
        report = build_frame_store(out, infos)
    for line in report.repaired:
        print(f"repaired: {line}")
    for reason in report.failed.values():
        print(f"skipped: {reason}")
    print(
        f"{out}: {len(report.added)} added, {len(report.skipped)} already in, {len(report.failed)} failed; "
        f"{report.episodes} episodes"
    )
    return report.to_dict()


def verify(store: str, log_dir: str | None, as_json: bool) -> dict:
    """Check every chunk of `store`, repairing from `log_dir` if given; exit 1 if damage remains."""
    from dynplan.data.verify import verify_store

    report = verify_store(store, log_dir)
    for damage in report.damage:
        print(f"{store}: {damage.describe()}", file=sys.stderr)
    repaired = len(report.damage) - len(report.unrepaired)
    print(
        f"{store}: {report.chunks} chunks of {report.episodes} episodes checked; {len(report.damage)} damaged, "
        f"{repaired} repaired"
    )
    if as_json:
        print(json.dumps(report.to_dict()))
    if report.unrepaired:
        hint = "" if log_dir else "; give the folder of its logs to repair what they determine"
        print(
            f"python -m flows.build_datasets: {len(report.unrepaired)} damaged chunks or metadata remain in "
            f"{store}{hint}",
            file=sys.stderr,
        )
        raise SystemExit(1)
    return report.to_dict()


def _parser() -> CommandParser:
    parser = CommandParser(
        prog="python -m flows.build_datasets", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "log_dir",
        nargs="?",
        type=PathArgument(PathKind.LOG_FOLDER),
        help="folder of episode logs (*.mcap); with --verify, optional",
    )
    parser.add_argument(
        "--out",
        type=PathArgument(PathKind.OUTPUT_FOLDER),
        default="datasets/frames.zarr",
        help="Zarr store to create or extend",
    )
    parser.add_argument(
        "--verify",
        metavar="STORE",
        type=PathArgument(PathKind.STORE),
        help="check every chunk of STORE (and repair it from LOG_DIR)",
    )
    parser.add_argument(
        "--world",
        choices=world_names(),
        default=None,
        help=f"the world of the store's logs (default: the store's, else {DEFAULT_WORLD})",
    )
    add_dask_option(parser)
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    add_console_options(parser)
    return parser


def main(argv: list[str] | None = None) -> dict:
    parser = _parser()
    args = parser.parse_args(argv)
    from dynplan.data.store import store_problem

    try:
        address = checked_dask_address(args.dask_address) if args.verify is None else None
        if args.log_dir is not None and not any(Path(args.log_dir).glob("*.mcap")):
            raise ValueError(f"log_dir {args.log_dir}: holds no episode logs (*.mcap)")
        if args.verify is not None:
            if not Path(args.verify, "zarr.json").is_file():
                raise FileNotFoundError(f"--verify {args.verify}: no Zarr store there")
            problem = store_problem(args.verify)
            if problem and "format version" not in problem:
                raise ValueError(f"--verify {problem}")
            _check_world(args.world, args.verify)
            return verify(args.verify, args.log_dir, args.json)
        if args.log_dir is None:
            raise ValueError("give LOG_DIR, the folder of episode logs (or --verify STORE)")
        check_output(args.out, "--out", "folder", inputs=(args.log_dir,))
        problem = store_problem(args.out)
        if problem:
            raise ValueError(f"--out {problem}")
        _check_world(args.world, args.out)
    except (FileNotFoundError, ValueError) as error:
        parser.error(str(error))
    not_logs = sorted(p.name for p in Path(args.log_dir).glob("*.mcap") if not p.is_file())
    for name in not_logs:
        print(f"python -m flows.build_datasets: skipped {Path(args.log_dir) / name}: not a file", file=sys.stderr)
    with temporary_api():
        report = build_datasets.with_options(task_runner=task_runner(address))(
            log_dir=args.log_dir, out=args.out, dask_address=address, world_name=args.world or _store_world(args.out)
        )
    if args.json:
        print(json.dumps(report))
    if report["failed"]:  # each failed log is named, with what was wrong, by the flow's own "skipped:" line
        print(
            f"python -m flows.build_datasets: failed on {len(report['failed'])} of its inputs (each skipped above); "
            "the rest are in the store",
            file=sys.stderr,
        )
        raise SystemExit(1)
    return report


def _check_world(name: str | None, store: str) -> None:
    """`--world` must be the world of the store it names, where that store exists."""
    found = _store_world(store) if name is not None and Path(store, "zarr.json").is_file() else name
    if found != name:
        raise ValueError(f"--world {name}: {store} holds the {found} world's episodes")


def _store_world(store: str) -> str:
    """The world of the frames store at `store` (the road where there is none yet, or it names none)."""
    from dynplan.data.store import store_world

    meta = Path(store, "zarr.json")
    return store_world(json.loads(meta.read_text()).get("attributes", {})) if meta.is_file() else DEFAULT_WORLD


if __name__ == "__main__":
    run_command(main, "python -m flows.build_datasets")
