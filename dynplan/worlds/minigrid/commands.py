"""MiniGrid's halves of the commands every world shares (`dynplan.world_parts`): `flows.evaluate --world minigrid`
(the request it makes and what it does with one), `flows.play --world minigrid` and `flows.replay --world
minigrid`."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pydantic import Field

from dynplan.cli import Bounded
from dynplan.config import Config
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.provenance import world_model_entry
from dynplan.evaluation.store import Run, run_argument
from dynplan.logs.reader import EpisodeLog
from dynplan.logs.recording import read_world_recording
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.progress import progress
from dynplan.render import write_gif
from dynplan.worlds.minigrid.evaluation import TECHNIQUES, Player, evaluate_episodes, summarise
from dynplan.worlds.minigrid.grid import MiniGridConfig, record_world
from dynplan.worlds.minigrid.models import NAME
from dynplan.worlds.minigrid.play import HORIZONS, PLANNERS, MiniGridPlay, play_out
from dynplan.worlds.minigrid.results import LEARNED_SAMPLES, RUNS, replay_check
from dynplan.worlds.minigrid.search import GridSearch

RESULTS_DIR = "datasets/results/minigrid"
#: The first room of the evaluation: rooms no setting was chosen on (the planner's validation rooms are 3,000,000…).
EVAL_SEED = 1_000_000

if TYPE_CHECKING:
    from dynplan.worlds.minigrid.imagine import MiniGridModel


def _learned_model(model_dir: str | os.PathLike | None) -> MiniGridModel:
    """The learned world model in `model_dir` (None: the committed weights), its checkpoints checked; torch is
    imported here, when a command first plays with it, not by `--help`."""
    from dynplan.worlds.minigrid.imagine import MiniGridModel

    return MiniGridModel(model_dir)


class MiniGridEvaluation(Config):
    """One evaluation: each technique over the rooms of seeds `first_seed` …, played into run `run` of the store
    at `results`, `batch` rooms a job."""

    techniques: tuple[str, ...] = TECHNIQUES
    episodes: int = Field(200, ge=1, le=1_000_000, description="rooms per technique")
    first_seed: int = Field(EVAL_SEED, ge=0, le=2**62 - 1_000_000, description="seed of the first room")
    samples: int = Field(64, ge=1, le=4096, description="futures the walk technique samples a decision")
    search: GridSearch = Field(default_factory=GridSearch)
    room: MiniGridConfig = Field(default_factory=MiniGridConfig)
    results: str = RESULTS_DIR
    run: str = "evaluation"
    batch: int = Field(20, ge=1, le=10_000, description="rooms a job")
    model_dir: str | None = Field(
        None, description="folder of world-model configurations the learned techniques load (None: the committed)"
    )

    @property
    def learned(self) -> bool:
        """Whether a technique plans with the world model."""
        return any(t in LEARNED_SAMPLES for t in self.techniques)

    def player(self, technique: str) -> Player:
        """What plays the technique's episodes: the search, the walk's samples, the world model when it is learned
        (the random numbers are each episode's own)."""
        model = _learned_model(self.model_dir) if technique in LEARNED_SAMPLES else None
        return Player(self.search, self.samples, np.random.default_rng(0), model)

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
        parser.add_argument(
            "--run", type=run_argument, default="evaluation", help="the run to play into (default 'evaluation')"
        )
        models = "folder holding minigrid/{vqvae,pixelcnn}.pt for the learned techniques (default: the committed)"
        parser.add_argument("--model-dir", type=PathArgument(PathKind.MODEL_FOLDER), default=None, help=models)

    def request(self, args: argparse.Namespace) -> MiniGridEvaluation:
        check_output(args.results_dir, "--results-dir", "folder")
        request = MiniGridEvaluation(
            techniques=args.techniques,
            episodes=args.episodes,
            first_seed=args.first_seed,
            samples=args.samples,
            results=args.results_dir,
            run=args.run,
            batch=args.batch,
            model_dir=args.model_dir,
        )
        if request.learned:
            _learned_model(request.model_dir)  # its checkpoints checked now, not in the first task
        return request

    def recordings(self, request: MiniGridEvaluation) -> None:
        """None: each room is recorded from its seed where it is played."""
        return None

    def start(self, request: MiniGridEvaluation, command: str) -> list[dict]:
        """Begin (or extend) the run's manifest; the rooms it does not hold yet, `batch` a job per technique."""
        run = Run(request.results, request.run, RUNS)
        role = "evaluation" if request.run == "evaluation" else "candidate"
        models = {NAME: world_model_entry(NAME, AgentSpec(model_dir=request.model_dir))} if request.learned else {}
        manifest = run.start(role, request.settings(), models, command)
        jobs = []
        for technique in request.techniques:
            seeds = range(request.first_seed, request.first_seed + request.episodes)
            model = NAME if technique in LEARNED_SAMPLES else None
            cases = [{"technique": technique, "model": model, "seed": s} for s in seeds]
            missing = [c["seed"] for c in cases if run.find(c, RUNS.expected(manifest, c)) is None]
            for first in range(0, len(missing), request.batch):
                batch = missing[first : first + request.batch]
                jobs.append({"technique": technique, "seeds": batch, "episodes": len(batch)})
        return jobs

    def play(self, request: MiniGridEvaluation, job: dict) -> dict:
        run = Run(request.results, request.run, RUNS)
        rows = evaluate_episodes(run, job["technique"], job["seeds"], request.room, request.player(job["technique"]))
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
        for number, row in progress(run.counted(), description="rows replayed"):
            problem = replay_check(row, settings)
            if problem is not None:
                problems.append(f"{run.place(number)}: technique={row['technique']} seed={row['seed']}: {problem}")
        return problems


class Play:
    """`python -m flows.play --world minigrid`: steer the agent through a room with the keyboard, or watch the
    planner play it, with what the technique sees k steps ahead beside the truth.

    Turn-based, as the planner plays: each key press is one step of the agent and of the balls. The right-hand
    panels show, at every step, the true room k steps on, what the technique (--technique: walk, a sample of the
    balls' move rule; learned10, learned5, learned1, the world model's samples; oracle, the true future;
    stand_still; constant_velocity) searches there and its chance of a ball in each cell, whoever plays.

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
        models = "folder holding minigrid/{vqvae,pixelcnn}.pt for a learned technique (default: the committed)"
        parser.add_argument("--model-dir", type=PathArgument(PathKind.MODEL_FOLDER), default=None, help=models)

    def state(self, args: argparse.Namespace) -> MiniGridPlay:
        model = _learned_model(args.model_dir) if args.technique in LEARNED_SAMPLES else None
        room = record_world(MiniGridConfig(), args.seed)
        return MiniGridPlay(room, args.technique, args.horizon, args.samples, model)


class MiniGridReplay(Config):
    """One replay: the room recorded in `log` played by `technique` into the replay log `out` (and a GIF)."""

    log: str
    technique: str = Field("learned10", description="who plays")
    horizon: int = Field(5, ge=1, le=8, description="the planner's horizon k")
    samples: int = Field(64, ge=1, le=4096, description="futures the walk technique samples a decision")
    out: str
    model_dir: str | None = None
    gif: str | None = None


def default_replay_path(log: str | os.PathLike, technique: str) -> Path:
    """Where a replay of `log` goes by default: beside the log's folder, in `replays/`."""
    log = Path(log)
    return log.parent.parent / "replays" / f"{log.stem}.replay-{technique}.mcap"


def replayable(log: str | os.PathLike) -> EpisodeLog:
    """`log`, read and checked: a MiniGrid room's recording, as `flows.collect --world minigrid` writes it; else a
    LogError."""
    wanted = "a MiniGrid replay plays a room's recording (flows.collect --world minigrid)"
    return read_world_recording(log, "minigrid", wanted)


class Replay:
    """`python -m flows.replay --world minigrid LOG.mcap`: play a recorded room and write its replay.

    LOG is a room's recording (`flows.collect --world minigrid`); the technique (`learned10` by default: the world
    model's 10 sampled futures) plays it from the agent's start; the replay log (default
    `../replays/<log>.replay-<technique>.mcap` from the log) holds the room, the agent's track and a room the
    planner searched at each decision, for `python -m flows.view`.
    """

    request_type = MiniGridReplay

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        planners = [t for t in TECHNIQUES if t != "random"]
        parser.add_argument("--technique", choices=planners, default="learned10", help="who plays (default learned10)")
        parser.add_argument("-k", "--horizon", type=Bounded(int, 1, 8), default=5, help="the planner's horizon")
        samples = "futures the walk technique samples a decision (default 64)"
        parser.add_argument("--samples", type=Bounded(int, 1, 4096), default=64, help=samples)
        parser.add_argument("--out", type=PathArgument(PathKind.OUTPUT_LOG), help="the replay log to write")
        models = "folder holding minigrid/{vqvae,pixelcnn}.pt for a learned technique (default: the committed)"
        parser.add_argument("--model-dir", type=PathArgument(PathKind.MODEL_FOLDER), default=None, help=models)
        gif = "also write a GIF of the episode: the room now, the true and an imagined room k steps on, the chances"
        parser.add_argument("--gif", type=PathArgument(PathKind.OUTPUT_GIF), help=gif)

    def request(self, args: argparse.Namespace) -> MiniGridReplay:
        out = args.out or str(default_replay_path(args.log, args.technique))
        check_output(out, "--out", "file", inputs=(args.log,))
        if args.gif:
            check_output(args.gif, "--gif", "file", inputs=(args.log, out))
        replayable(args.log)
        if args.technique in LEARNED_SAMPLES:
            _learned_model(args.model_dir)  # its checkpoints checked now
        fields = ("log", "technique", "horizon", "samples", "model_dir", "gif")
        return MiniGridReplay(out=out, **{name: getattr(args, name) for name in fields})

    def replay(self, request: MiniGridReplay) -> dict:
        room = replayable(request.log).world()
        model = _learned_model(request.model_dir) if request.technique in LEARNED_SAMPLES else None
        state = MiniGridPlay(room, request.technique, request.horizon, request.samples, model)
        pictures = play_out(state, len(room.frames))
        state.record(request.out)
        if request.gif:
            write_gif(request.gif, np.stack(pictures), fps=4, scale=8)
        return {"outcome": state.outcomes[-1], "steps": state.t, "seed": room.seed, "out": request.out}

    def describe(self, result: dict) -> str:
        return f"room {result['seed']}: {result['outcome']} after {result['steps']} steps; replay log: {result['out']}"
