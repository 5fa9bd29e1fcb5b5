"""The evaluation protocol (docs/protocol.md §4): every technique plays the same recorded episodes.

One case = (technique, agent speed, rollout steps, episode seed). Each case's result is a row of its run in the
results store (`dynplan.evaluation.store`), appended as it finishes, so an evaluation resumes where it stopped and
can be spread over a Dask cluster. Techniques build their planner and forward model from the recorded world.
"""

from __future__ import annotations

import os
import time
import zlib
from collections.abc import Mapping
from dataclasses import asdict, dataclass

import numpy as np

from dynplan.data.collect import log_path
from dynplan.data.store import sha256_file
from dynplan.env.config import RoadConfig
from dynplan.env.road import World, generate_world
from dynplan.evaluation.store import Run, code_version
from dynplan.evaluation.techniques import AgentInputs, technique
from dynplan.logs.reader import LogError, read_episode_log
from dynplan.models.checkpoint import weights_sha256
from dynplan.models.registry import WORLD_MODELS
from dynplan.models.world_model import world_model_paths
from dynplan.planning.episode import EpisodeResult, run_episode
from dynplan.planning.forward import ForwardModel
from dynplan.planning.mcts import MCTSConfig, MCTSPlanner, RandomPlanner

#: The evaluation episodes' seeds: a range of their own, far from training seeds (which start at 0).
EVAL_SEED_START = 1_000_000
#: Validation episodes: where a world model's settings (prior epoch, occupancy threshold) are chosen, so that the
#: evaluation episodes only ever score a choice already made.
VALIDATION_SEED_START = 2_000_000
EVAL_EPISODES = 100
AGENT_SPEEDS = (1.0, 0.5)
ROLLOUT_STEPS = (1, 3, 5, 10)


@dataclass(frozen=True)
class Case:
    """One evaluation episode. `rollout_steps` is None for the random agent, which does not search."""

    technique: str
    agent_speed: float
    rollout_steps: int | None
    seed: int
    model: str | None = None  # the world-model configuration of a learned technique ("default" or "paper")

    def __post_init__(self) -> None:
        needs = technique(self.technique).world_model
        if needs != (self.model is not None):
            uses = "needs a world model" if needs else "does not use a world model"
            raise ValueError(f"technique {self.technique!r} {uses} (got model={self.model!r})")
        if self.model is not None and self.model not in WORLD_MODELS:
            raise ValueError(f"model must be one of {sorted(WORLD_MODELS)}, got {self.model!r}")

    @property
    def group(self) -> str:
        k = "none" if self.rollout_steps is None else self.rollout_steps
        technique = self.technique if self.model is None else f"{self.technique}-{self.model}"
        return f"{technique}/speed{self.agent_speed:g}_k{k}"

    def planner_seed(self) -> int:
        """A seed for the planner's own randomness, fixed per case."""
        return zlib.crc32(f"{self.group}/{self.seed}".encode())


def cases(techniques: list[str], speeds: tuple[float, ...] = AGENT_SPEEDS,
          rollout_steps: tuple[int, ...] = ROLLOUT_STEPS, episodes: int = EVAL_EPISODES,
          first_seed: int = EVAL_SEED_START, models: tuple[str, ...] = ("default",)) -> list[Case]:  # fmt: skip
    """Every case of the table: the random agent once per speed, searching techniques once per horizon, learned
    techniques once per world-model configuration in `models`."""
    out = []
    for name in techniques:
        t = technique(name)
        ks: tuple[int | None, ...] = rollout_steps if t.search else (None,)
        for model in models if t.world_model else (None,):
            for speed in speeds:
                for k in ks:
                    out += [Case(name, speed, k, first_seed + i, model) for i in range(episodes)]
    return out


def _world_model_identity(model: str, model_dir: str | None) -> str:
    """SHA-256 of the checkpoints a learned technique of configuration `model` plays with."""
    return "+".join(weights_sha256(p) if p.exists() else "missing" for p in world_model_paths(model, model_dir))


def _provenance(case: Case, log_dir: str | os.PathLike, playouts: int, model_dir: str | None = None,
                caution: Mapping[str, float] | None = None) -> dict:  # fmt: skip
    """What a result depends on besides the case: playouts, the log's bytes, and the world model's weights and
    caution (the configuration's own where `caution` does not override it; only the settings that are on are
    recorded, so that results from before a setting existed stay valid)."""
    from dynplan.models.registry import caution_for

    source = log_path(log_dir, case.seed)
    provenance = {"playouts": playouts, "log_sha256": sha256_file(source) if source.exists() else None}
    if case.model is not None:
        provenance["world_model_sha256"] = _world_model_identity(case.model, model_dir)
        provenance.update(caution_for(case.model, caution).recorded())
    return provenance


def world_model_entry(model: str, model_dir: str | None = None, caution: Mapping[str, float] | None = None) -> dict:
    """What a run's manifest records of world-model configuration `model`: its weights and their SHA-256, and the
    caution it plays with (only the settings that are on)."""
    from dynplan.models.registry import caution_for

    return {"weights_sha256": _world_model_identity(model, model_dir),
            "weights": [str(p) for p in world_model_paths(model, model_dir)],
            "caution": caution_for(model, caution).recorded()}  # fmt: skip


def case_agent(
    case: Case,
    world: World,
    playouts: int = 100,
    model_dir: str | None = None,
    caution: Mapping[str, float] | None = None,
) -> tuple[MCTSPlanner | RandomPlanner, ForwardModel | None]:
    """The planner and forward model that play `case` on its recorded `world`. `caution`: what overrides a learned
    model's configuration's own (field → value)."""
    model = technique(case.technique).forward(AgentInputs(world, case.model, case.planner_seed(), model_dir, caution))
    if case.rollout_steps is None:
        return RandomPlanner(case.planner_seed()), model
    config = MCTSConfig(rollout_steps=case.rollout_steps, playouts=playouts)
    max_steps = RoadConfig.from_dict(world.config.model_dump(), agent_speed=case.agent_speed).max_steps
    return MCTSPlanner(config, case.agent_speed, max_steps, seed=case.planner_seed()), model


def plan_episode(world: World | int, technique_name: str = "samples5", model: str | None = "default",
                 agent_speed: float = 1.0, rollout_steps: int | None = 3, playouts: int = 100,
                 caution: Mapping[str, float] | None = None) -> EpisodeResult:  # fmt: skip
    """Play one episode — a recorded `world`, or the world of a seed — with a technique (`TECHNIQUES`), its planner
    seeded as the evaluation seeds it; `model`: the world-model configuration of a learned technique (ignored
    otherwise). Returns the outcome, steps, decision times and the agent's track."""
    if isinstance(world, int | np.integer):
        world = generate_world(RoadConfig(agent_speed=agent_speed), int(world))
    chosen = technique(technique_name)
    case = Case(technique_name, agent_speed, rollout_steps if chosen.search else None, int(world.seed),
                model if chosen.world_model else None)  # fmt: skip
    planner, forward = case_agent(case, world, playouts, caution=caution)
    return run_episode(world, planner, forward, agent_speed, case.rollout_steps or 1)


def run_case(case: Case, log_dir: str | os.PathLike, run: Run, playouts: int = 100, model_dir: str | None = None,
             caution: Mapping[str, float] | None = None) -> dict:  # fmt: skip
    """Play one case against its recorded episode and append its row to `run` — or return the run's row of it, if
    one was played with the same playouts, against the same log and (learned techniques) the same weights and
    caution. `model_dir`: where the learned techniques' checkpoints are (see `world_model_paths`); `caution`:
    what overrides the learned model's configuration's own (field → value, e.g. {"occupancy": 0.05})."""
    provenance = _provenance(case, log_dir, playouts, model_dir, caution)
    existing = run.find(asdict(case), provenance)
    if existing is not None:
        return existing
    source = log_path(log_dir, case.seed)
    start = time.perf_counter()
    log = read_episode_log(source)
    if log.seed != case.seed:
        raise LogError(source, f"holds seed {log.seed}, but the evaluation case is seed {case.seed}")
    world = log.world()
    planner, model = case_agent(case, world, playouts, model_dir, caution)
    result = run_episode(world, planner, model, case.agent_speed, case.rollout_steps or 1)
    record = {
        **asdict(case),
        "outcome": result.outcome,
        "steps": result.steps,
        **provenance,
        "decision_ms": [round(ms, 4) for ms in result.decision_ms],
        "wall_s": round(time.perf_counter() - start, 4),
        "code_version": code_version(),
    }
    run.append(record)
    return record


def pending(all_cases: list[Case], run: Run, log_dir: str | os.PathLike, playouts: int = 100,
            model_dir: str | None = None, caution: Mapping[str, float] | None = None) -> list[Case]:  # fmt: skip
    """The cases without a row of the same provenance in `run` (what a resumed evaluation still has to play)."""
    return [c for c in all_cases
            if run.find(asdict(c), _provenance(c, log_dir, playouts, model_dir, caution)) is None]  # fmt: skip


def begin_run(run: Run, role: str, all_cases: list[Case], log_dir: str | os.PathLike, playouts: int, command: str,
              model_dir: str | None = None, caution: Mapping[str, float] | None = None) -> dict:  # fmt: skip
    """Write (or extend) `run`'s manifest with what these cases play with: seeds, logs, weights, caution."""
    seeds = sorted({c.seed for c in all_cases})
    logs = {s: sha256_file(p) if (p := log_path(log_dir, s)).exists() else None for s in seeds}
    models = {c.model for c in all_cases if c.model is not None}
    return run.begin(role, playouts, seeds, logs, {m: world_model_entry(m, model_dir, caution) for m in sorted(models)},
                     command)  # fmt: skip
