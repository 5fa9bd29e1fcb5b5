"""On-demand benchmarks: `python -m dynplan.bench NAME [--json]`.

Each benchmark is a function returning `{case: {figure: value}}`; speeds are medians over repeats and, where a
baseline exists, reported as a ratio against it measured in the same process. Targets live here, never in
timed unit tests. A world adds its own (`WorldParts.benches`: name → "module:function").
"""

from __future__ import annotations

from collections.abc import Callable

from dynplan.bench.data import bench_data
from dynplan.bench.decision import bench_decision
from dynplan.bench.decoding import bench_decoding
from dynplan.bench.evaluation import bench_evaluation
from dynplan.bench.generation import bench_generation
from dynplan.bench.mcts import bench_mcts
from dynplan.bench.pipeline import bench_pipeline
from dynplan.bench.precision import bench_precision
from dynplan.bench.prior import bench_prior
from dynplan.bench.sharing import bench_sharing
from dynplan.bench.startup import bench_startup
from dynplan.bench.vqvae import bench_vqvae
from dynplan.bench.world import bench_world
from dynplan.world import resolve, world, world_names

Results = dict[str, dict[str, float]]

#: name → benchmark: what `python -m dynplan.bench NAME` runs.
BENCHMARKS: dict[str, Callable[..., Results]] = {
    "world": bench_world,
    "data": bench_data,
    "mcts": bench_mcts,
    "vqvae": bench_vqvae,
    "prior": bench_prior,
    "precision": bench_precision,
    "generation": bench_generation,
    "decoding": bench_decoding,
    "decision": bench_decision,
    "evaluation": bench_evaluation,
    "sharing": bench_sharing,
    "pipeline": bench_pipeline,
    "startup": bench_startup,
}


def benchmarks() -> dict[str, Callable[..., Results]]:
    """Every benchmark by name: `BENCHMARKS`, then each world's own (their functions imported now)."""
    found = dict(BENCHMARKS)
    for name in world_names():
        for bench, reference in world(name).load().benches.items():
            found[bench] = resolve(reference)
    return found


__all__ = ["BENCHMARKS", "Results", "benchmarks"]
