"""`python -m flows.serve [--out DIR] [--dask-address …]`: serve the collect-train-eval flow as Prefect deployments, one
per run-scale preset, so that a Prefect server's users can trigger it:

    prefect server start                           # a real server (http://127.0.0.1:4200 by default)
    export PREFECT_API_URL=http://127.0.0.1:4200/api
    python -m flows.serve                          # keeps running: it executes the triggered runs
    prefect deployment run collect-train-eval/quick --watch

The deployments are every world's presets: the road's `collect-train-eval/quick`, `/full` and `/smoke`, another world's
`/<world>-quick`, `/<world>-full` and `/<world>-smoke`; parameters can be overridden per run (`-p out=/data/dynplan`).
This process runs the flows it receives; with a Dask scheduler address the flows' collection, conversion and evaluation
tasks go to that cluster.
"""

from __future__ import annotations

import argparse

from prefect import serve

from dynplan.cli import Bounded, CommandParser, run_command
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.pipeline.presets import pipeline_presets
from dynplan.world import world_names
from flows.collect_train_eval import collect_train_eval
from flows.runners import add_dask_option, checked_dask_address

#: Every preset of every world by its deployment's name: the preset's folder (`quick`, `<world>-quick`, …).
PRESETS_BY_DEPLOYMENT = {p.folder: p for name in world_names() for p in pipeline_presets(name).values()}


def deployments(out: str, address: str | None, presets: list[str]) -> list:
    """One RunnerDeployment per preset, named by `PRESETS_BY_DEPLOYMENT`."""
    chosen = [PRESETS_BY_DEPLOYMENT[name] for name in presets]
    return [
        collect_train_eval.to_deployment(
            name=p.folder,
            parameters={"preset": p.name, "world": p.world, "out": out, "dask_address": address},
            description=p.description,
            tags=["dynplan", p.world, p.name],
        )
        for p in chosen
    ]


def main(argv: list[str] | None = None) -> None:
    parser = CommandParser(
        prog="python -m flows.serve", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--out",
        type=PathArgument(PathKind.OUTPUT_FOLDER),
        default="datasets",
        help="output folder of the runs (default: datasets)",
    )
    names = list(PRESETS_BY_DEPLOYMENT)
    parser.add_argument(
        "--presets", nargs="+", default=names, choices=names, help="the deployments to serve (default: all)"
    )
    add_dask_option(parser)
    parser.add_argument("--limit", type=Bounded(int, 1, 256), default=1, help="flow runs executed at once (default 1)")
    args = parser.parse_args(argv)
    try:
        check_output(args.out, "--out", "folder")
        address = checked_dask_address(args.dask_address)
    except ValueError as error:
        parser.error(str(error))
    serve(*deployments(args.out, address, args.presets), limit=args.limit)


if __name__ == "__main__":
    run_command(main, "python -m flows.serve")
