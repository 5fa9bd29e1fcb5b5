"""Command line: `python -m dynplan.bench NAME [--json]`."""

from __future__ import annotations

import argparse
import json
import sys

from dynplan.bench import BENCHMARKS


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dynplan.bench", description=__doc__)
    parser.add_argument("name", choices=sorted(BENCHMARKS), help="which benchmark to run")
    parser.add_argument("--json", action="store_true", help="print {case: {figure: value}} as JSON")
    args = parser.parse_args(argv)
    results = BENCHMARKS[args.name]()
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"benchmark: {args.name}")
    for column in ("case", "figure", "value"):
        table.add_column(column)
    for case, figures in results.items():
        for figure, value in figures.items():
            table.add_row(case, figure, f"{value:,}" if isinstance(value, int | float) else str(value))
    Console().print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
