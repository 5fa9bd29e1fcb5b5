"""How many distinct contents the world's frame patches take, and how much of it K codes could cover.

A VQ-VAE whose codes each stand for one patch can only reproduce a frame exactly if every patch of it is among
the K contents its codebook holds. This counts, over recorded-style episodes, the distinct patch contents for
a patch size and the fraction of patches — and of whole frames — covered by the K most frequent ones:
`python -m lab.patches [--episodes 300]`.
"""

from __future__ import annotations

import json

import numpy as np

from dynplan.cli import CommandParser, run_command
from dynplan.data.patches import tiles
from dynplan.env.config import RoadConfig
from dynplan.env.road import generate_world


def patch_coverage(frames: np.ndarray, patch: tuple[int, int], ks: tuple[int, ...]) -> dict[str, float]:
    """Distinct contents of `patch`-sized tiles of `frames` (N, H, W) and their top-K coverage."""
    ph, pw = patch
    N, H, W = frames.shape
    gh, gw = H // ph, W // pw
    keys = tiles(frames, patch).view(np.dtype((np.void, ph * pw))).ravel()
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    order = np.argsort(-counts, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    frame_rank = rank[inverse.ravel()].reshape(N, gh * gw).max(axis=1)
    out: dict[str, float] = {"grid": f"{gh}x{gw}", "tokens": gh * gw, "distinct": len(counts)}
    for k in ks:
        out[f"patches_top{k}"] = round(float(counts[order[:k]].sum() / counts.sum()), 4)
        out[f"frames_top{k}"] = round(float((frame_rank < k).mean()), 4)
    return out


def main(argv: list[str] | None = None) -> None:
    parser = CommandParser(prog="python -m lab.patches", description=__doc__)
    parser.add_argument("--episodes", type=int, default=300, help="407-frame episodes to count over (seeds 0…)")
    args = parser.parse_args(argv)
    config = RoadConfig(agent_speed=0.5)
    frames = np.concatenate([generate_world(config, s).frames for s in range(args.episodes)])
    for patch in ((8, 8), (6, 6), (4, 8), (2, 8), (4, 4), (3, 3)):
        print(json.dumps({"patch": f"{patch[0]}x{patch[1]}", **patch_coverage(frames, patch, (512, 1024, 4096))}))


if __name__ == "__main__":
    run_command(main, "python -m lab.patches")
