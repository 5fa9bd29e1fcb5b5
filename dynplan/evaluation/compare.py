"""Compare two runs of the results store case by case: `python -m dynplan.evaluation.compare STORE_A RUN_A STORE_B
RUN_B`.

For the cases both runs hold (technique, model, agent speed, k, seed), it counts those whose outcome or steps
differ and those played with different provenance (playouts, log, weights, caution), and gives each side's goals
and median decision time — e.g. to check that two ways of playing the same episodes agree.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics

from dynplan.cli import CommandParser, run_command
from dynplan.evaluation.store import Run, StoreError, case_key, provenance_of
from dynplan.paths import PathArgument, PathKind


def _median_ms(rows) -> float:
    return round(statistics.median(ms for row in rows for ms in row["decision_ms"]), 1)


def compare_runs(a: Run, b: Run) -> dict:
    """Per (technique, model, agent speed, k): the shared cases, how many differ in outcome or steps (with their
    seeds) and in provenance, and each run's goals and median decision milliseconds."""
    rows_a = {case_key(r): r for r in a.current()}
    rows_b = {case_key(r): r for r in b.current()}
    groups: dict[str, list[tuple]] = {}
    for key in sorted(set(rows_a) & set(rows_b), key=str):
        technique, model, speed, k, _ = key
        groups.setdefault(f"{technique} {model or '-'} speed {speed} k {k}", []).append(key)
    out = {}
    for name, keys in groups.items():
        pairs = [(rows_a[key], rows_b[key]) for key in keys]
        sides = list(zip(*pairs, strict=True))
        differing = [x["seed"] for x, y in pairs if (x["outcome"], x["steps"]) != (y["outcome"], y["steps"])]
        out[name] = {
            "cases": len(pairs),
            "outcome_or_steps_differ": len(differing),
            "differing_seeds": differing,
            "provenance_differs": sum(provenance_of(x) != provenance_of(y) for x, y in pairs),
            "goals": [sum(r["outcome"] == "goal" for r in side) for side in sides],
            "median_decision_ms": [_median_ms(side) for side in sides],
        }
    return out


def main(argv: list[str] | None = None) -> dict:
    """The command: both runs are read through the store's schema first; a missing run or a damaged or invalid
    manifest or row is one line on stderr and exit status 2."""
    parser = CommandParser(
        prog="python -m dynplan.evaluation.compare",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    for side in ("a", "b"):
        parser.add_argument(
            f"store_{side}",
            type=PathArgument(PathKind.RESULTS_FOLDER),
            help=f"results store {side.upper()} (e.g. datasets/results)",
        )
        parser.add_argument(f"run_{side}", help=f"the run of store {side.upper()}")
    args = parser.parse_args(argv)
    runs = []
    try:
        for store, name in ((args.store_a, args.run_a), (args.store_b, args.run_b)):
            run = Run(store, name)
            if not run.exists():
                parser.error(f"{os.path.join(store, 'runs', name)}: no such run")
            runs.append(run)
        result = compare_runs(*runs)
    except StoreError as error:
        parser.error(str(error))
    print(json.dumps(result, indent=1))
    return result


if __name__ == "__main__":
    run_command(main, "python -m dynplan.evaluation.compare")
