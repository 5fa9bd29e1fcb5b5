"""How a tokenizer's codes relate to the patches they cover: whether a code is a function of its own patch.

A prior learns the codes, not the pixels: if the same patch content (above all the empty road) is given many
different codes depending on its neighbours, the prior must predict which of them the encoder would pick, and
its code accuracy says little about the frames it predicts. For a store's code array this reports the share of
patches that are empty, how many codes the empty patch receives and how concentrated they are, and how many
distinct patch contents there are and what share of patches the K most frequent ones cover (what a patch-local
codebook of K entries could represent exactly).
`python -m lab.codes --codes codes_default [--episodes 20]`.
"""

from __future__ import annotations

import json

import numpy as np
import zarr

from dynplan.cli import CommandParser, run_command
from dynplan.data.patches import tiles
from dynplan.env.config import FREE


def patch_keys(frames: np.ndarray, grid: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """uint8 frames (N, H, W) → (key, empty) per patch of the (h, w) code grid, each (N, h, w): keys are equal
    iff the patches' pixels are; `empty` marks patches of free road only."""
    n, H, W = frames.shape
    h, w = grid
    ph, pw = H // h, W // w
    patches = tiles(frames, (ph, pw))
    _, keys = np.unique(patches.view(f"V{ph * pw}").ravel(), return_inverse=True)
    return keys.reshape(n, h, w), (patches == FREE).all(1).reshape(n, h, w)


def code_statistics(store: str, codes: str, episodes: int = 20, coverage_at: tuple[int, ...] = (512, 1024, 4096)
                    ) -> dict[str, float]:  # fmt: skip
    """Statistics of `codes` against the frames of the first `episodes` episodes of `store` (see module doc)."""
    group = zarr.open_group(store, mode="r", use_consolidated=False)
    grids = np.asarray(group[codes][:episodes])
    frames = np.asarray(group["frames"][: len(grids)])
    grid = grids.shape[-2:]
    keys, empty = (a.ravel() for a in patch_keys(frames.reshape(-1, *frames.shape[-2:]), grid))
    flat = grids.reshape(-1).astype(np.int64)
    _, empty_counts = np.unique(flat[empty], return_counts=True)
    contents, counts = np.unique(keys, return_counts=True)
    cumulative = np.cumsum(np.sort(counts)[::-1]) / len(keys)
    pairs = np.unique(np.stack([keys, flat], 1), axis=0)
    return {
        "patches": len(keys),
        "empty_share": float(empty.mean()),
        "codes_of_empty_patch": len(empty_counts),
        "top_code_share_of_empty": float(empty_counts.max() / empty.sum()) if empty.any() else 0.0,
        "codes_per_content": float(len(pairs) / len(contents)),
        "distinct_contents": len(contents),
        **{f"top{k}_content_coverage": float(cumulative[min(k, len(cumulative)) - 1]) for k in coverage_at},
    }


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = CommandParser(prog="python -m lab.codes", description=__doc__)
    parser.add_argument("--store", default="datasets/frames.zarr")
    parser.add_argument("--codes", default="codes_default", help="the store's code array")
    parser.add_argument("--episodes", type=int, default=20, help="episodes read (from the first)")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes={args.episodes} is invalid; valid range [1, inf)")
    group = zarr.open_group(args.store, mode="r", use_consolidated=False)
    if args.codes not in group:
        parser.error(f"{args.store}: no code array {args.codes!r} (arrays: {', '.join(sorted(group.array_keys()))})")
    result = code_statistics(args.store, args.codes, args.episodes)
    print(json.dumps(result, indent=1))
    return result


if __name__ == "__main__":
    run_command(main, "python -m lab.codes")
