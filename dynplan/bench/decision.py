"""`decision`: milliseconds per planning decision with the learned world model (5 decoder samples, k = 3,
100 playouts: prediction + search) — the paper's best agent took 1.7 s per decision on a GPU. The committed
trained world model of each configuration is timed where it exists; until then an untrained one of the preset's
size stands in (timing barely depends on the weights), and the result says which. The default is also timed
without its caution (`model_samples5_k3_no_occupancy`: occupancy and margin off), in the same run, to price the
occupancy pass (the margin's widening costs well under a millisecond)."""

from __future__ import annotations

import time

import numpy as np
import torch

from dynplan.env.config import RoadConfig
from dynplan.env.road import generate_world
from dynplan.models.checkpoint import CheckpointError
from dynplan.models.pixelcnn import ConditionalPixelCNN
from dynplan.models.registry import caution_for, world_model_spec
from dynplan.models.vqvae import VQVAE
from dynplan.models.world_model import LearnedWorldModel, load_world_model
from dynplan.planning.config import MCTSConfig
from dynplan.planning.mcts import MCTSPlanner

PAPER_GPU_MS = 1700.0


def bench_decision(decisions: int = 30, threads: int = 2) -> dict[str, dict[str, float]]:
    """Median over `decisions` decisions along one episode's frames (the agent held at its start)."""
    torch.set_num_threads(threads)
    world = generate_world(RoadConfig(), 2_000_000)
    results = {}
    off = {"occupancy": 0.0, "margin": 0}
    variants = (
        ("default", "model_samples5_k3", None),
        ("default", "model_samples5_k3_no_occupancy", off),
        ("paper", "model_samples5_k3_paper", None),
    )
    for name, case, caution in variants:
        try:
            model, weights = load_world_model(model=name, samples=5, caution=caution), "committed"
        except CheckpointError:
            torch.manual_seed(0)
            prior = ConditionalPixelCNN(world_model_spec(name).prior)
            model = LearnedWorldModel(
                VQVAE(world_model_spec(name).tokenizer), prior, samples=5, caution=caution_for(name, caution)
            )
            weights = "untrained"
        planner = MCTSPlanner(MCTSConfig(rollout_steps=3), agent_speed=1.0, max_steps=203)
        times = []
        for t in range(4, 5 + decisions):
            start = time.perf_counter()
            planner.act(world.agent_start, t, model.predict(world.frames[: t + 1], 3))
            times.append((time.perf_counter() - start) * 1e3)
        median = float(np.median(times[1:]))  # the first call compiles
        results[case] = {
            "median_ms": round(median, 1),
            "paper_gpu_ms": PAPER_GPU_MS,
            "speedup_vs_paper": round(PAPER_GPU_MS / median, 1),
            "threads": threads,
            "weights": weights,
        }
    return results
