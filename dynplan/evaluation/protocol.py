"""Playing the evaluation's cases (docs/protocol.md §4): each case's agent, cases played in lockstep into their run
of the results store (`run_cases`, `run_case`), what a resumed run still has to play (`pending`), and one episode
on its own (`plan_episode`). The cases live in `cases.py`, what results depend on in `provenance.py`, the rows in
`store.py`.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import asdict
from typing import Annotated

import numpy as np

from dynplan.arguments import Bounds, checked
from dynplan.data.collect import log_path
from dynplan.env.config import RoadConfig
from dynplan.env.road import World, generate_world
from dynplan.evaluation.agent import AgentSpec, Planner
from dynplan.evaluation.cases import Case, case_group, planner_seed
from dynplan.evaluation.provenance import provenance as case_provenance
from dynplan.evaluation.store import Run, code_version
from dynplan.logs.reader import LogError, read_episode_log
from dynplan.planning.episode import EpisodeResult, run_episode, run_episodes
from dynplan.planning.forward import ForwardModel


def case_agent(case: Case, world: World, spec: AgentSpec | None = None) -> tuple[Planner, ForwardModel | None]:
    """The planner and forward model that play `case` on its recorded `world` with the settings of `spec`: the
    world model draws from the world's seed (so the cases of a world share each frame's draws), the planner from
    the case's own."""
    agent = (spec or AgentSpec()).for_case(case.technique, case.model, case.rollout_steps, case.seed)
    return agent.build(world, case.agent_speed, case.planner_seed())


@checked
def plan_episode(
    world: World | Annotated[int, Bounds(0, 2**62)],
    spec: AgentSpec | None = None,
    agent_speed: Annotated[float, Bounds(0.0, 8.0)] = 1.0,
) -> EpisodeResult:
    """Play one episode — a recorded `world`, or the world of a seed — with the agent `spec` (default: samples5 on
    the default world model at k = 3), its planner seeded as the evaluation seeds it. Returns the outcome, steps,
    decision times and the agent's track."""
    config = RoadConfig(agent_speed=agent_speed)  # the speed checked whatever the world
    if isinstance(world, int | np.integer):
        world = generate_world(config, int(world))
    spec = spec or AgentSpec()
    planner, forward = world_agent(world, spec, agent_speed)
    return run_episode(world, planner, forward, agent_speed, spec.rollout_steps)


def world_agent(world: World, spec: AgentSpec, agent_speed: float) -> tuple[Planner, ForwardModel | None]:
    """The agent `spec` on the recorded `world` at `agent_speed`, seeded as the evaluation seeds its case: the
    world model from the world's seed, the planner from the case's own (any technique, "model" included)."""
    chosen = spec.plans_with
    k, model = (spec.rollout_steps if chosen.search else None), (spec.model if chosen.world_model else None)
    agent = spec.for_case(spec.technique, model, k, int(world.seed))
    return agent.build(world, agent_speed, planner_seed(case_group(spec.technique, model, agent_speed, k), world.seed))


def run_case(case: Case, log_dir: str | os.PathLike, run: Run, spec: AgentSpec | None = None) -> dict:
    """Play one case against its recorded episode and append its row to `run` (the batch of one of `run_cases`)."""
    return run_cases([case], log_dir, run, spec)[0]


def run_cases(cases: Sequence[Case], log_dir: str | os.PathLike, run: Run, spec: AgentSpec | None = None) -> list[dict]:
    """Play `cases` against their recorded episodes in one lockstep batch (`run_episodes`: whatever their technique,
    agent speed and k, the learned models on the same weights predict together, and the cases on the same recorded
    world share each prediction of a frame they all see) and append each one's row to `run` the moment its episode
    finishes — or return the run's row of a case, if one was played with the same playouts, against the same log
    and (learned techniques) the same weights and caution. `spec`: the agents' settings each case specialises
    (playouts, weights, caution overrides — all part of a row's provenance — and the device, which is not: the same
    arithmetic, up to float summation order). A row's `wall_s` is its episode's share of the batch: reading its log,
    building its agent and its decisions."""
    spec = spec or AgentSpec()
    rows: list[dict | None] = [None] * len(cases)
    provenances = [case_provenance(case, log_dir, spec) for case in cases]
    for i, case in enumerate(cases):
        rows[i] = run.find(asdict(case), provenances[i])
    members = [i for i, row in enumerate(rows) if row is None]
    if not members:
        return rows  # type: ignore[return-value]
    recorded: dict[int, World] = {}  # each log read once, its world shared by every case that plays it
    worlds, agents, setup_s = [], [], []
    for i in members:
        start = time.perf_counter()
        seed = cases[i].seed
        if seed not in recorded:
            source = log_path(log_dir, seed)
            log = read_episode_log(source)
            if log.seed != seed:
                raise LogError(source, f"holds seed {log.seed}, but the evaluation case is seed {seed}")
            recorded[seed] = log.world()
        worlds.append(recorded[seed])
        agents.append(case_agent(cases[i], worlds[-1], spec))
        setup_s.append(time.perf_counter() - start)

    def finish(j: int, result: EpisodeResult) -> None:
        i = members[j]
        rows[i] = {
            **asdict(cases[i]),
            "outcome": result.outcome,
            "steps": result.steps,
            **provenances[i],
            "decision_ms": [round(ms, 4) for ms in result.decision_ms],
            "wall_s": round(setup_s[j] + sum(result.decision_ms) / 1e3, 4),
            "code_version": code_version(),
        }
        run.append(rows[i])

    planners, models = zip(*agents, strict=True)
    run_episodes(
        worlds,
        planners,
        models,
        [cases[i].agent_speed for i in members],
        [cases[i].rollout_steps or 1 for i in members],
        on_finish=finish,
    )
    return rows  # type: ignore[return-value]


def pending(all_cases: list[Case], run: Run, log_dir: str | os.PathLike, spec: AgentSpec | None = None) -> list[Case]:
    """The cases without a row of the same provenance in `run` (what a resumed evaluation still has to play)."""
    spec = spec or AgentSpec()
    return [c for c in all_cases if run.find(asdict(c), case_provenance(c, log_dir, spec)) is None]
