"""MiniGrid's halves of the commands every world shares (`dynplan.world_parts`): `flows.evaluate --world minigrid`
(the request it makes and what it does with one) and `flows.play --world minigrid`."""

from __future__ import annotations

import argparse

from pydantic import Field

from dynplan.cli import Bounded
from dynplan.config import Config
from dynplan.evaluation.store import Run, check_run_name
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.progress import progress
from dynplan.worlds.minigrid.evaluation import TECHNIQUES, evaluate_episodes, summarise
from dynplan.worlds.minigrid.grid import MiniGridConfig
from dynplan.worlds.minigrid.play import HORIZONS, PLANNERS, MiniGridPlay
from dynplan.worlds.minigrid.results import RUNS, replay_check
from dynplan.worlds.minigrid.search import GridSearch

RESULTS_DIR = "datasets/results/minigrid"
#: The first room of the evaluation: rooms no setting was chosen on (the planner's validation rooms are 3,000,000…).
EVAL_SEED = 1_000_000


class MiniGridEvaluation(Config):
    """One evaluation: each technique over the rooms of seeds `first_seed` …, played into run `run` of the store
    at `results`, `batch` rooms a job."""

    techniques: tuple[str, ...] = ("oracle", "walk", "stand_still", "constant_velocity", "random")
    episodes: int = Field(200, ge=1, le=1_000_000, description="rooms per technique")
    first_seed: int = Field(EVAL_SEED, ge=0, le=2**62 - 1_000_000, description="seed of the first room")
    samples: int = Field(64, ge=1, le=4096, description="futures the walk technique samples a decision")
    search: GridSearch = Field(default_factory=GridSearch)
    room: MiniGridConfig = Field(default_factory=MiniGridConfig)
    results: str = RESULTS_DIR
    run: str = "evaluation"
    batch: int = Field(20, ge=1, le=10_000, description="rooms a job")

    def settings(self) -> dict:
        """What every row depends on besides its case (a run's own: another value is refused)."""
        return {
            **self.room.model_dump(),
            "horizon": self.search.horizon,
            "risk": self.search.risk,
            "samples": self.samples,
        }


class Evaluate:
    """`python -m flows.evaluate --world minigrid`: MiniGrid's planner told each technique's futures (`oracle`: the
    true one, `walk`: samples of the balls' move rule, `stand_still`, `constant_velocity`) and `random` actions,
    over `--episodes` rooms from `--first-seed`, one Prefect task a batch; each row (outcome, steps, median decision
    ms, actions) appended as its episode ends, so an interrupted evaluation resumes; then each technique's success
    rate ± its standard error. `--check` plays nothing: it plays every row's actions in its room again.
    """

    request_type = MiniGridEvaluation
    summary_key = "minigrid"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        default = MiniGridEvaluation()
        parser.add_argument("--techniques", nargs="+", choices=TECHNIQUES, default=list(default.techniques))
        parser.add_argument("--episodes", type=Bounded(int, 1, 1_000_000), default=default.episodes, help="rooms")
        seeds = f"seed of the first room (default {EVAL_SEED:,}; the planner's settings were chosen on 3,000,000…)"
        parser.add_argument("--first-seed", type=Bounded(int, 0, 2**62 - 1_000_000), default=EVAL_SEED, help=seeds)
        samples = "futures the walk technique samples a decision (default 64)"
        parser.add_argument("--samples", type=Bounded(int, 1, 4096), default=default.samples, help=samples)
        parser.add_argument("--batch", type=Bounded(int, 1, 10_000), default=default.batch, help="rooms a job")
        out = f"where runs are written (default {RESULTS_DIR})"
        parser.add_argument("--results-dir", type=PathArgument(PathKind.OUTPUT_FOLDER), default=RESULTS_DIR, help=out)
        parser.add_argument("--run", default="evaluation", help="the run to play into (default 'evaluation')")

    def request(self, args: argparse.Namespace) -> MiniGridEvaluation:
        check_run_name(args.run)
        check_output(args.results_dir, "--results-dir", "folder")
        return MiniGridEvaluation(
            techniques=args.techniques,
            episodes=args.episodes,
            first_seed=args.first_seed,
            samples=args.samples,
            results=args.results_dir,
            run=args.run,
            batch=args.batch,
        )

    def recordings(self, request: MiniGridEvaluation) -> None:
        """None: each room is recorded from its seed where it is played."""
        return None

    def start(self, request: MiniGridEvaluation, command: str) -> list[dict]:
        """Begin (or extend) the run's manifest; the rooms it does not hold yet, `batch` a job per technique."""
        run = Run(request.results, request.run, RUNS)
        role = "evaluation" if request.run == "evaluation" else "candidate"
        run.start(role, request.settings(), {}, command)
        jobs = []
        for technique in request.techniques:
            seeds = range(request.first_seed, request.first_seed + request.episodes)
            missing = [s for s in seeds if run.find({"technique": technique, "model": None, "seed": s}, {}) is None]
            for first in range(0, len(missing), request.batch):
                batch = missing[first : first + request.batch]
                jobs.append({"technique": technique, "seeds": batch, "episodes": len(batch)})
        return jobs

    def play(self, request: MiniGridEvaluation, job: dict) -> dict:
        run = Run(request.results, request.run, RUNS)
        rows = evaluate_episodes(run, job["technique"], job["seeds"], request.room, request.search, request.samples)
        return {"technique": job["technique"], "episodes": len(rows)}

    def summary(self, request: MiniGridEvaluation) -> list[dict]:
        return summarise(Run(request.results, request.run, RUNS).current())

    def describe(self, summary: list[dict]) -> list[str]:
        return [
            f"{r['technique']}: {r['success']:.2f} ± {r['se']:.2f} over {r['episodes']} rooms, {r['deaths']} deaths,"
            f" {'–' if r['steps'] is None else r['steps']} steps to the goal, {r['decision_ms']:g} ms a decision"
            for r in summary
        ]

    def check(self, request: MiniGridEvaluation) -> list[str]:
        """Play every row's actions in its room again: a line per row that does not end as it says."""
        run = Run(request.results, request.run, RUNS)
        settings = run.manifest()["settings"]
        problems = []
        for row in progress(run.current(), description="rows replayed"):
            problem = replay_check(row, settings)
            if problem is not None:
                problems.append(f"technique={row['technique']} seed={row['seed']}: {problem}")
        return problems


class Play:
    """`python -m flows.play --world minigrid`: steer the agent through a room with the keyboard, or watch the
    planner play it, with what the technique sees k steps ahead beside the truth.

    Turn-based, as the planner plays: each key press is one step of the agent and of the balls. The right-hand
    panels show, at every step, the true room k steps on and what the technique (--technique: walk, a sample of
    the balls' move rule; oracle, the true future; stand_still; constant_velocity) searches there, whoever plays.

    Keys:
      A or LEFT         turn left
      D or RIGHT        turn right
      W or UP           move forward
      K                 the planner's horizon k: 3, 5, 6
      P                 the planner plays / you play
      SPACE             pause or resume the planner
      R                 restart the episode
      ESC               quit (with --record, the replay log is written first)
    """

    scale = 24
    fps = 8.0

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        seed = f"the room's seed (default {EVAL_SEED:,}, the evaluation's first)"
        parser.add_argument("--seed", type=Bounded(int, 0, 2**62), default=EVAL_SEED, help=seed)
        technique = "the planner that plays (P) and whose futures are shown (default walk)"
        parser.add_argument("--technique", default="walk", choices=PLANNERS, help=technique)
        horizon = "the planner's horizon (K cycles through 3, 5, 6)"
        parser.add_argument("-k", "--horizon", type=int, default=5, choices=HORIZONS, help=horizon)
        samples = "futures the walk technique samples a decision (default 64)"
        parser.add_argument("--samples", type=Bounded(int, 1, 4096), default=64, help=samples)

    def state(self, args: argparse.Namespace) -> MiniGridPlay:
        return MiniGridPlay(args.seed, args.technique, args.horizon, args.samples)
