"""Command line: `python -m dynplan.bench NAME [--json] [--device DEVICE]`."""

from __future__ import annotations

import inspect
import json
import sys

from dynplan.bench import benchmarks
from dynplan.cli import CommandParser, run_command


def main(argv: list[str] | None = None) -> int:
    parser = CommandParser(prog="python -m dynplan.bench", description=__doc__)
    every = benchmarks()
    parser.add_argument("name", choices=sorted(every), help="which benchmark to run")
    parser.add_argument("--json", action="store_true", help="print {case: {figure: value}} as JSON")
    with_device = sorted(n for n, b in every.items() if "device" in inspect.signature(b).parameters)
    parser.add_argument("--device", help=f"where the world model generates: cpu or cuda[:N] ({', '.join(with_device)})")
    args = parser.parse_args(argv)
    options = {}
    if args.device is not None:
        if args.name not in with_device:
            parser.error(
                f"--device: the {args.name} benchmark runs on the CPU only; --device applies to "
                f"{', '.join(with_device)}"
            )
        from dynplan.models.device import check_device

        try:
            options["device"] = check_device(args.device)
        except ValueError as error:
            parser.error(f"--device: {error}")
    results = every[args.name](**options)
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
    sys.exit(run_command(main, "python -m dynplan.bench"))
