"""How Freeway's prior size costs a learned decision: milliseconds to chain the prior over Freeway's 40 × 38 grid.

Each size is the `freeway` prior's configuration with other channels and layers (random weights: the cost does not
depend on them), chaining k grids from one observation on one core, every grid generated (nothing kept from an
earlier chain), the median of `--repeats`; as whole grids (1,520 positions in sequence) and as the 10 lane strips
of 4 × 38 codes generated together (152 in sequence).

`python -m lab.freeway_priors --sizes 16x4 32x4 32x8 --k 8`
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from dynplan.cli import Bounded, CommandParser, run_command
from dynplan.models.chain import ChainSpec, chain, forget_greedy
from dynplan.models.configs import PIXELCNN_PRESETS, PRESETS
from dynplan.models.pixelcnn import ConditionalPixelCNN


def chain_ms(channels: int, layers: int, strips: bool, k: int, repeats: int) -> float:
    """Median ms to chain k grids with the `freeway` prior resized to `channels` × `layers`, by strips or whole."""
    config = PIXELCNN_PRESETS["freeway"].model_copy(
        update={"channels": channels, "layers": layers, "strip_rows": 4 if strips else None}
    )
    torch.manual_seed(0)
    prior = ConditionalPixelCNN(config).eval()
    h, w = PRESETS["freeway"].grid
    context = torch.randint(0, config.codebook_size, (1, config.context, h, w))
    times = []
    for _ in range(repeats + 1):  # the first lays the weights out
        forget_greedy()
        start = time.perf_counter()
        chain(prior, context, [k], ChainSpec())
        times.append((time.perf_counter() - start) * 1e3)
    return round(float(np.median(times[1:])), 1)


def main(argv: list[str] | None = None) -> list[dict]:
    parser = CommandParser(prog="python -m lab.freeway_priors", description=__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--sizes", nargs="+", default=["16x4", "32x4", "32x8"], help="CHANNELSxLAYERS each")
    parser.add_argument("--k", type=Bounded(int, 1, 32), default=8, help="grids chained (default 8)")
    parser.add_argument("--repeats", type=Bounded(int, 1, 100), default=3, help="timed chains a case (default 3)")
    parser.add_argument("--whole", action="store_true", help="also time whole grids (minutes at 32 × 8)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    for size in args.sizes:
        try:
            channels, layers = (int(part) for part in size.split("x"))
        except ValueError:
            parser.error(f"--sizes: {size!r} is not CHANNELSxLAYERS, e.g. 16x4")
        row = {"channels": channels, "layers": layers, "k": args.k,
               "strips_ms": chain_ms(channels, layers, True, args.k, args.repeats)}  # fmt: skip
        if args.whole:
            row["whole_ms"] = chain_ms(channels, layers, False, args.k, args.repeats)
        print(json.dumps(row), flush=True)
        rows.append(row)
    return rows


if __name__ == "__main__":
    run_command(main, "python -m lab.freeway_priors")
