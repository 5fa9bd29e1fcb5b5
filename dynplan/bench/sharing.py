"""`sharing`: what an evaluation gains by playing every case of a recorded world in one lockstep batch.

The world does not depend on the agent, so every case that has seen the same frames — any technique on the same
world model, either agent speed, any k — asks the same question of the prior: its greedy chain is one chain, as
long as the longest horizon asking, and its sampled futures are one set (`LearnedWorldModel.predict_batch`).
Two measurements, in one run:

* `default_2x`: the 2× agent's learned cases of Table 1 with the default world model (mid, 5 and 10 samples,
  futures5 at k = 1, 3, 5, 10) on the same validation worlds, one case per lockstep batch (`per_case`) against
  all of them in one batch (`shared`, as `flows.evaluate` plays them): wall time, and how many episodes' outcome
  or steps differ.
* `grids_<model>`: the grids the complete Table 1 generates either way, counted from the steps of a run's rows
  (the committed evaluation's): per case Σ min(k, T − 1 − t) · (1 + futures) over its decisions; shared, per
  world and frame, the longest horizon's greedy chain and futures.
"""

from __future__ import annotations

import json
import time
from collections import defaultdict
from pathlib import Path

import torch

from dynplan.env.config import RoadConfig
from dynplan.env.road import generate_world
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import ROLLOUT_STEPS, TABLE1, VALIDATION_SEED_START, Case
from dynplan.evaluation.protocol import case_agent
from dynplan.evaluation.techniques import technique
from dynplan.planning.episode import run_episodes

#: The run whose rows `grids_<model>` counts: Table 1's evaluation.
EVALUATION_ROWS = Path(__file__).parents[2] / "datasets/results/runs/evaluation/episodes.jsonl"
#: The first decision's frame (docs/protocol.md: frames 0–4 seen).
FIRST_DECISION = 4


def table1_grids(rows: list[dict]) -> dict[str, dict[str, int | float]]:
    """Per world model: the grids its cases generate played one case per batch, and shared per world and frame."""
    per_case: dict[str, int] = defaultdict(int)
    greedy: dict[tuple, int] = defaultdict(int)
    futures: dict[tuple, int] = defaultdict(int)
    for row in rows:
        if row.get("model") is None:
            continue
        count = technique(row["technique"]).futures
        frames = RoadConfig(agent_speed=row["agent_speed"]).max_steps
        for step in range(row["steps"]):
            t = FIRST_DECISION + step
            k = min(row["rollout_steps"], frames - 1 - t)
            per_case[row["model"]] += k * (1 + count)
            key = (row["model"], row["seed"], t)
            greedy[key] = max(greedy[key], k)
            if count:
                futures[key, count] = max(futures[key, count], k)
    out = {}
    for model in sorted(per_case):
        shared = sum(k for key, k in greedy.items() if key[0] == model)
        shared += sum(count * k for (key, count), k in futures.items() if key[0] == model)
        out[f"grids_{model}"] = {
            "per_case": per_case[model],
            "shared": shared,
            "ratio": round(per_case[model] / shared, 2),
        }
    return out


def bench_sharing(worlds: int = 4, threads: int = 2, device: str = "cpu") -> dict[str, dict[str, float]]:
    """`default_2x` over `worlds` validation worlds, then the grid counts of the committed evaluation."""
    torch.set_num_threads(threads)
    recorded = [generate_world(RoadConfig(), VALIDATION_SEED_START + i) for i in range(worlds)]
    groups = [(name, k) for name in TABLE1[1.0] if technique(name).world_model for k in ROLLOUT_STEPS]

    def agents(name: str, k: int) -> list:
        return [case_agent(Case(name, 1.0, k, w.seed, "default"), w, AgentSpec(device=device)) for w in recorded]

    _, warm = agents("samples5", 3)[0]
    warm.predict(recorded[0].frames[:5], 3)  # compile the kernels outside the timings
    start = time.perf_counter()
    alone = []
    for name, k in groups:
        planners, models = zip(*agents(name, k), strict=True)
        alone += run_episodes(recorded, planners, models, 1.0, k)
    per_case_s = time.perf_counter() - start
    planners, models = zip(*(agent for name, k in groups for agent in agents(name, k)), strict=True)
    start = time.perf_counter()
    together = run_episodes(recorded * len(groups), planners, models, 1.0, [k for _, k in groups for _ in recorded])
    shared_s = time.perf_counter() - start
    differing = sum((a.outcome, a.steps) != (b.outcome, b.steps) for a, b in zip(alone, together, strict=True))
    results = {
        "default_2x": {
            "worlds": worlds,
            "cases": len(groups),
            "decisions": sum(r.steps for r in together),
            "per_case_s": round(per_case_s, 1),
            "shared_s": round(shared_s, 1),
            "speedup": round(per_case_s / shared_s, 2),
            "episodes_differing": differing,
            "threads": threads,
            "device": device,
        }
    }
    rows = [json.loads(line) for line in EVALUATION_ROWS.read_text().splitlines() if line.strip()]
    return results | table1_grids(rows)
