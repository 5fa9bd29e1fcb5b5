"""`evaluation`: episodes per second and amortised milliseconds per learned decision, the episodes of a case played
one at a time (`per_episode`) against all together in lockstep (`lockstep`), in the same process, over the same
validation episodes: 2× agent, 5 samples [default], k = 3, and 1× agent, 5 samples [default], k = 10. Both paths
must give every episode the same outcome and steps; the benchmark says how many differ."""

from __future__ import annotations

import time

import torch

from dynplan.env.config import RoadConfig
from dynplan.env.road import generate_world
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import VALIDATION_SEED_START, Case
from dynplan.evaluation.protocol import case_agent
from dynplan.planning.episode import run_episode, run_episodes

#: (case name, agent speed, k, episodes): the 1× agent's episodes are longer and k = 10 chains ten grids a decision.
CASES = (("samples5_default_2x_k3", 1.0, 3, 100), ("samples5_default_1x_k10", 0.5, 10, 10))


def bench_evaluation(episodes: int | None = None, threads: int = 2, device: str = "cpu") -> dict[str, dict[str, float]]:
    """Each case's episodes per path (the same seeds); `episodes` overrides each case's count; `device`: where the
    world model generates its batches."""
    torch.set_num_threads(threads)
    results = {}
    for name, speed, k, count in CASES:
        count = episodes or count
        worlds = [generate_world(RoadConfig(agent_speed=speed), VALIDATION_SEED_START + i) for i in range(count)]

        def agents(worlds=worlds, speed=speed, k=k):
            spec = AgentSpec(device=device)
            return [case_agent(Case("samples5", speed, k, w.seed, "default"), w, spec) for w in worlds]

        _, warm_model = agents()[0]
        warm_model.predict(worlds[0].frames[:5], k)  # compile the kernels outside the timings
        start = time.perf_counter()
        alone = [run_episode(w, p, m, speed, k) for w, (p, m) in zip(worlds, agents(), strict=True)]
        per_episode_s = time.perf_counter() - start
        planners, models = zip(*agents(), strict=True)
        start = time.perf_counter()
        together = run_episodes(worlds, planners, models, speed, k)
        lockstep_s = time.perf_counter() - start
        decisions = sum(r.steps for r in together)
        differing = sum((a.outcome, a.steps) != (b.outcome, b.steps) for a, b in zip(alone, together, strict=True))
        results[name] = {
            "episodes": count,
            "decisions": decisions,
            "per_episode_episodes_per_s": round(count / per_episode_s, 3),
            "lockstep_episodes_per_s": round(count / lockstep_s, 3),
            "per_episode_ms_per_decision": round(per_episode_s * 1e3 / sum(r.steps for r in alone), 2),
            "lockstep_ms_per_decision": round(lockstep_s * 1e3 / decisions, 2),
            "speedup": round(per_episode_s / lockstep_s, 2),
            "episodes_differing": differing,
            "threads": threads,
            "device": device,
        }
    return results
