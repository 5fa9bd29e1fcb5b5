"""Reconstruction quality of trained VQ-VAEs on held-out episodes (the evaluation seeds, never trained on),
and their training curves: `python -m lab.reconstruction CHECKPOINT … [--plot curves.png]`."""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import numpy as np
import torch

from dynplan.cli import CommandParser, run_command
from dynplan.env.config import RoadConfig
from dynplan.env.road import generate_world
from dynplan.evaluation.cases import EVAL_SEED_START
from dynplan.models.caution import merge_samples
from dynplan.models.checkpoint import VQVAE_KIND, cached
from dynplan.models.metrics import frame_errors


def held_out_errors(checkpoint: str | os.PathLike, episodes: int = 20, samples: int = 5) -> dict[str, float]:
    """Mid-point reconstruction errors and code use over `episodes` evaluation episodes (407 frames each), and the
    errors of the frames the planner's *N samples* variant sees: the mid-point merged with `samples` decoder
    samples (obstacles: union; goal: median)."""
    model = cached(VQVAE_KIND, checkpoint)
    frames = np.concatenate([generate_world(RoadConfig(agent_speed=0.5), EVAL_SEED_START + i).frames
                             for i in range(episodes)])  # fmt: skip
    generator = torch.Generator().manual_seed(0)
    decoded, merged, codes = [], [], []
    for i in range(0, len(frames), 512):
        c = model.encode(torch.from_numpy(frames[i : i + 512]))
        codes.append(c.flatten())
        mid, drawn = model.decode_with_samples(c, samples, generator)
        decoded.append(mid.numpy())
        merged.append(merge_samples(mid.numpy(), drawn.numpy()))
    counts = torch.bincount(torch.cat(codes), minlength=model.config.codebook_size).double()
    p = counts / counts.sum()
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    return {
        "run": Path(checkpoint).parent.name,
        "epoch": state["epoch"],
        # frames, or distinct patch contents for a content-fitted codebook (`codebook_fit="contents"`)
        **{key: value for key, value in state["history"][-1].items() if key.endswith("_seen")},
        "train_hours": round(state["elapsed_s"] / 3600, 2),
        "frames": len(frames),
        **frame_errors(frames, np.concatenate(decoded)),
        **{f"samples{samples}_{k}": v for k, v in frame_errors(frames, np.concatenate(merged)).items()},
        "codes_used": int((counts > 0).sum()),
        "perplexity": round(float(torch.exp(-(p * torch.log(p + 1e-12)).sum())), 1),
    }


def plot_curves(runs: dict[str, str | os.PathLike], path: str | os.PathLike) -> None:
    """Validation FN / FP rates and exact goals against frames seen, one line per run's metrics.csv."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for name, metrics in runs.items():
        with open(metrics) as stream:
            rows = list(csv.DictReader(stream))
        seen = [float(r.get("frames_seen") or r["patches_seen"]) / 1e6 for r in rows]
        keys = ("val_fn_rate", "val_fp_rate", "val_goal_exact")
        titles = ("obstacle false negatives", "false positives", "exact goals")
        for ax, key, title in zip(axes, keys, titles, strict=True):
            ax.plot(seen, [float(r[key]) for r in rows], label=name)
            ax.set_title(title)
            ax.set_xlabel("training frames or patch contents (millions)")
    for ax in axes[:2]:
        ax.set_yscale("log")
        ax.axhline(0.005, color="grey", linestyle=":", label="target 0.5 %")
    axes[2].axhline(0.99, color="grey", linestyle=":", label="target 99 %")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    parser = CommandParser(prog="python -m lab.reconstruction", description=__doc__)
    parser.add_argument("checkpoints", nargs="+", help="VQ-VAE checkpoints (checkpoint.pt or vqvae.pt)")
    parser.add_argument("--episodes", type=int, default=20, help="held-out evaluation episodes")
    parser.add_argument("--samples", type=int, default=5, help="decoder samples merged as the planner does")
    parser.add_argument("--plot", help="also plot the runs' training curves (metrics.csv beside each) here")
    args = parser.parse_args(argv)
    for path in args.checkpoints:
        print(json.dumps(held_out_errors(path, args.episodes, args.samples)))
    if args.plot:
        runs = {Path(p).parent.name: Path(p).parent / "metrics.csv" for p in args.checkpoints}
        plot_curves(runs, args.plot)


if __name__ == "__main__":
    run_command(main, "python -m lab.reconstruction")
