"""Training curves of PixelCNN priors: validation code accuracy and the decoded next frame's obstacle false
negatives, against training windows and against wall-clock minutes (what a CPU-bound choice is judged by).

    python -m lab.prior_curves NAME=METRICS_CSV[@WINDOWS] ... --plot curves.png

A run started from another's weights (`flows.train --init-from`) counts its windows from 0: `@WINDOWS` places it
after the windows its start had seen, so a continued prior draws as one curve.
"""

from __future__ import annotations

import argparse
import csv
import os

from dynplan.cli import CommandParser, run_command


def read_metrics(path: str | os.PathLike) -> dict[str, list[float]]:
    """A metrics.csv as columns of floats (empty cells, e.g. before a column existed, become NaN)."""
    with open(path) as stream:
        rows = list(csv.DictReader(stream))
    if not rows:
        raise ValueError(f"{path}: no epochs recorded")
    return {key: [float(r[key]) if r.get(key) not in (None, "") else float("nan") for r in rows] for key in rows[0]}


def plot_prior_curves(
    runs: dict[str, str | os.PathLike], path: str | os.PathLike, offsets: dict[str, float] | None = None
) -> None:
    """One line per run: accuracy and next-frame FN against windows (thousands; a run's `offsets` entry added) and
    against minutes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharey="row")
    for name, metrics in runs.items():
        m = read_metrics(metrics)
        start = (offsets or {}).get(name, 0.0)
        windows, minutes = [(start + w) / 1e3 for w in m["windows_seen"]], [s / 60 for s in m["elapsed_s"]]
        for col, x in enumerate((windows, minutes)):
            axes[0, col].plot(x, [100 * a for a in m["val_accuracy"]], marker=".", label=name)
            axes[1, col].plot(x, [100 * f for f in m["val_next_fn_rate"]], marker=".", label=name)
    for col, label in enumerate(("training windows (thousands)", "training minutes (wall clock)")):
        axes[1, col].set_xlabel(label)
    axes[0, 0].set_ylabel("validation code accuracy (%)")
    axes[1, 0].set_ylabel("next frame obstacle FN (%, greedy)")
    axes[0, 0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    parser = CommandParser(prog="python -m lab.prior_curves", description=__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument(
        "runs", nargs="+", metavar="NAME=METRICS_CSV[@WINDOWS]", help="a label, a prior's metrics.csv, its start"
    )
    parser.add_argument("--plot", required=True, help="where to write the figure (PNG)")
    args = parser.parse_args(argv)
    runs, offsets = {}, {}
    for item in args.runs:
        name, sep, path = item.partition("=")
        path, at, start = path.partition("@")
        if not sep or not name or not path or (at and not start.isdigit()):
            parser.error(f"run {item!r} is not NAME=METRICS_CSV[@WINDOWS] (WINDOWS a whole number)")
        runs[name], offsets[name] = path, float(start or 0)
    plot_prior_curves(runs, args.plot, offsets)


if __name__ == "__main__":
    run_command(main, "python -m lab.prior_curves")
