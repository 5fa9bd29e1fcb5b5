"""Freeway's halves of the commands (`dynplan.world_parts`): the options of `flows.evaluate`, `flows.replay` and
`flows.play` with `--world freeway`, the requests they make, and what each does with one (each class's docstring is
its command's help)."""

from __future__ import annotations

import argparse
import itertools
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor

from pydantic import Field

from dynplan.cli import bounded
from dynplan.config import Config, field_help
from dynplan.evaluation.store import Run, run_argument
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.progress import progress
from dynplan.worlds.freeway.evaluation import (
    MODEL,
    PLANNERS,
    TECHNIQUES,
    FreewayPlan,
    case_of,
    evaluate_episodes,
    read_run,
    summarise,
    world_model_for,
)
from dynplan.worlds.freeway.game import FreewayEpisode
from dynplan.worlds.freeway.play import HORIZONS, FreewayPlay
from dynplan.worlds.freeway.replay import GIF_STEPS, default_replay_path, replay_freeway, replayable
from dynplan.worlds.freeway.results import (
    RUNS,
    SHOWN_RUNS,
    replay_key,
    replay_problem,
    replayed,
    settings,
    weights_entry,
)
from dynplan.worlds.freeway.search import ChickenSearch

RESULTS_DIR = "datasets/results/freeway"
MODEL_DIR_HELP = (
    "the learned technique's world model: a folder holding vqvae.pt and pixelcnn.pt (default: the "
    "committed Freeway weights)"
)


class FreewayEvaluation(Config):
    """One evaluation: every (technique, mode, episode) of the plan, played into run `run` of the store at
    `results`, a run of role `role` (None: `evaluation` for the run of that name, else `candidate`)."""

    techniques: tuple[str, ...] = Field(TECHNIQUES, min_length=1, description="techniques to play")
    modes: tuple[int, ...] = Field((0,), min_length=1, description="game modes")
    episodes: int = Field(20, ge=1, le=1000, description="episodes of each mode")
    seed: int = Field(0, ge=0, le=2**31, description="seed of the NOOP starts' draw")
    horizon: int = Field(8, ge=1, le=64, description="horizon k: predicted frames the search consults")
    batch: int = Field(10, ge=1, le=1000, description="episodes of a technique and mode played together in lockstep")
    sticky: float = Field(0.0, ge=0.0, le=1.0, description="the game's sticky actions: a run's own setting")
    results: str = Field(RESULTS_DIR, description="where runs are written")
    run: str = Field("evaluation", description="the run to play into")
    model_dir: str | None = Field(None, description="the learned technique's world model (None: the committed)")
    role: str | None = Field(None, description="the run's role (None: by its name)")

    def plans(self) -> list[FreewayPlan]:
        return [self.plan(m) for m in self.modes]

    def plan(self, mode: int) -> FreewayPlan:
        return FreewayPlan(mode=mode, episodes=self.episodes, seed=self.seed, sticky=self.sticky)


class Evaluate:
    """`python -m flows.evaluate --world freeway`: Freeway's techniques on the real game, one Prefect task a
    lockstep batch (`--batch` episodes of a technique and mode played together).

    Plays `--episodes` NOOP starts (drawn from `--seed`) of each `--modes` game mode with each technique (`oracle`:
    the true future, `learned`: the future Freeway's world model imagines, `extrapolate`: each lane's cars moved on
    at their recent speed, `zero`: no cars after the frame now, `up`: always UP, `random`) into the run `--run` of
    the results store at `--results-dir` (a row per episode with its actions, appended as it finishes; the episodes
    the run holds are skipped, so an interrupted evaluation resumes); then prints each technique's mean score ± std,
    knocks an episode and median decision milliseconds. `--check` plays nothing: it replays every row's actions in a
    fresh emulator and names any whose score, knocks or steps differ.
    """

    request_type = FreewayEvaluation
    summary_key = "freeway"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--techniques",
            nargs="+",
            choices=TECHNIQUES,
            default=list(TECHNIQUES),
            help="techniques to play (default: all)",
        )
        parser.add_argument(
            "--modes",
            nargs="+",
            type=bounded(FreewayPlan, "mode"),
            default=[0],
            help=field_help(FreewayPlan, "mode", "0") + ", one or more",
        )
        parser.add_argument(
            "--episodes", type=bounded(FreewayPlan, "episodes"), default=20, help=field_help(FreewayPlan, "episodes")
        )
        parser.add_argument(
            "--seed", type=bounded(FreewayPlan, "seed"), default=0, help=field_help(FreewayPlan, "seed")
        )
        parser.add_argument(
            "--horizon", type=bounded(ChickenSearch, "horizon"), default=8, help=field_help(ChickenSearch, "horizon")
        )
        parser.add_argument(
            "--sticky",
            type=bounded(FreewayPlan, "sticky"),
            default=None,
            help="probability that the game repeats its last action at a frame, a run's own setting (default: "
            + ", ".join(f"{p:g} for run {r!r}" for r, p in SHOWN_RUNS.items())
            + ", else 0)",
        )
        parser.add_argument(
            "--batch",
            type=bounded(FreewayEvaluation, "batch"),
            default=FreewayEvaluation.model_fields["batch"].default,
            help=field_help(FreewayEvaluation, "batch"),
        )
        parser.add_argument(
            "--results-dir",
            type=PathArgument(PathKind.OUTPUT_FOLDER),
            default=RESULTS_DIR,
            help=f"where runs are written (default {RESULTS_DIR})",
        )
        parser.add_argument(
            "--run", type=run_argument, default="evaluation", help="the run to play into (default 'evaluation')"
        )
        parser.add_argument("--model-dir", type=PathArgument(PathKind.MODEL_FOLDER), help=MODEL_DIR_HELP)

    def request(self, args: argparse.Namespace) -> FreewayEvaluation:
        check_output(args.results_dir, "--results-dir", "folder")
        if "learned" in args.techniques:
            world_model_for("learned", args.model_dir)  # its checkpoints checked now, not in the first task
        return FreewayEvaluation(
            techniques=args.techniques,
            modes=args.modes,
            episodes=args.episodes,
            seed=args.seed,
            horizon=args.horizon,
            batch=args.batch,
            sticky=SHOWN_RUNS.get(args.run, 0.0) if args.sticky is None else args.sticky,
            results=args.results_dir,
            run=args.run,
            model_dir=args.model_dir,
        )

    def recordings(self, request: FreewayEvaluation) -> None:
        """None: every episode is played in a fresh emulator."""
        return None

    def start(self, request: FreewayEvaluation, command: str) -> list[dict]:
        """Begin (or extend) the run's manifest; the episodes it does not hold yet, one job each."""
        run = Run(request.results, request.run, RUNS)
        role = request.role or ("evaluation" if request.run in SHOWN_RUNS else "candidate")
        learned = "learned" in request.techniques
        models = {MODEL: weights_entry(MODEL, request.model_dir)} if learned else {}
        manifest = run.start(role, settings(request.sticky), models, command)
        jobs = []
        for plan in request.plans():
            for technique in request.techniques:
                missing = [
                    i
                    for i in range(request.episodes)
                    if run.find(case := case_of(technique, plan, i, request.horizon), RUNS.expected(manifest, case))
                    is None
                ]
                for first in range(0, len(missing), request.batch):
                    batch = missing[first : first + request.batch]
                    jobs.append({"mode": plan.mode, "technique": technique, "indices": batch, "episodes": len(batch)})
        return jobs

    def play(self, request: FreewayEvaluation, job: dict) -> dict:
        search = ChickenSearch(horizon=request.horizon)
        model = world_model_for(job["technique"], request.model_dir)
        plan, run = request.plan(job["mode"]), Run(request.results, request.run, RUNS)
        rows = evaluate_episodes(run, job["technique"], plan, job["indices"], search, model)
        return {"mode": job["mode"], "technique": job["technique"], "episodes": len(rows)}

    def summary(self, request: FreewayEvaluation) -> list[dict]:
        return summarise(read_run(request.results, request.run))

    def check(self, request: FreewayEvaluation) -> list[str]:
        """Replay every counted row of the run in a fresh game, on every core (each distinct replay once, alone in a
        worker process): one line per row whose actions do not give its score, knocks and steps (none: every score
        holds)."""
        problems, run = [], Run(request.results, request.run, RUNS)
        run_settings = run.manifest()["settings"]
        numbered = run.counted()
        rows = [row for _, row in numbered]
        keys = [replay_key(row, run_settings) for row in rows]
        distinct = list({key: row for key, row in zip(keys, rows, strict=True)}.items())  # same game, same actions
        spawn = multiprocessing.get_context("spawn")  # fresh workers: nothing of this process's threads
        workers = min(os.cpu_count() or 1, len(distinct) or 1)
        with ProcessPoolExecutor(max_workers=workers, mp_context=spawn) as pool:
            played = pool.map(replayed, [row for _, row in distinct], itertools.repeat(run_settings))
            shown = progress(played, total=len(distinct), description="rows replayed")
            replays = {key: replay for (key, _), replay in zip(distinct, shown, strict=True)}
        for key, (number, row) in zip(keys, numbered, strict=True):
            problem = replay_problem(row, replays[key])
            if problem is not None:
                case = " ".join(f"{k}={row[k]}" for k in RUNS.case_keys)
                problems.append(f"{run.place(number)}: {case}: {problem}")
        return problems

    def describe(self, summary: list[dict]) -> list[str]:
        lines = []
        for row in summary:
            ms = "" if row["decision_ms"] is None else f", {row['decision_ms']:g} ms a decision"
            lines.append(
                f"mode {row['mode']} {row['technique']} k={row['horizon']}: {row['score']:g} ± "
                f"{row['std']:g} over {row['episodes']} episodes, {row['knocks']:g} knocks an episode{ms}"
            )
        return lines


class FreewayReplay(Config):
    """One replay: the episode of `log`'s mode from `noop_start`, played by `technique`, written to `out`."""

    log: str
    technique: str = "oracle"
    noop_start: int = Field(0, ge=0, le=30)
    horizon: int = Field(8, ge=1, le=64)
    out: str
    model_dir: str | None = None
    gif: str | None = None


class Replay:
    """`python -m flows.replay --world freeway LOG.mcap --noop-start N`: play a Freeway episode and write its replay.

    LOG is a mode's recording (`flows.collect --world freeway`); the technique (`oracle` by default: the true
    future) plays the real game from NOOP start N; the replay log (default
    `../replays/<log>.replay-<technique>-noop<N>.mcap` from the log) holds the lanes, the chicken's track and the
    lanes the planner searched at each decision, for `python -m flows.view`.
    """

    request_type = FreewayReplay

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--noop-start",
            type=bounded(FreewayEpisode, "noop_start"),
            default=0,
            help=field_help(FreewayEpisode, "noop_start"),
        )
        parser.add_argument("--technique", choices=TECHNIQUES, default="oracle", help="who plays (default oracle)")
        parser.add_argument(
            "--horizon", type=bounded(ChickenSearch, "horizon"), default=8, help=field_help(ChickenSearch, "horizon")
        )
        parser.add_argument("--out", type=PathArgument(PathKind.OUTPUT_LOG), help="the replay log to write")
        parser.add_argument("--model-dir", type=PathArgument(PathKind.MODEL_FOLDER), help=MODEL_DIR_HELP)
        parser.add_argument(
            "--gif",
            type=PathArgument(PathKind.OUTPUT_GIF),
            help=f"also write a GIF of the first {GIF_STEPS} steps: the lanes now, the true and the "
            "searched lanes k steps on, their error (planning techniques)",
        )

    def request(self, args: argparse.Namespace) -> FreewayReplay:
        out = args.out or str(default_replay_path(args.log, args.technique, args.noop_start))
        check_output(out, "--out", "file", inputs=(args.log,))
        replayable(args.log)
        world_model_for(args.technique, args.model_dir)
        if args.gif:
            if args.technique not in PLANNERS:
                raise ValueError(f"--gif shows the lanes a planner searched; {args.technique} does not plan")
            check_output(args.gif, "--gif", "file", inputs=(args.log, out))
        return FreewayReplay(
            log=args.log,
            technique=args.technique,
            noop_start=args.noop_start,
            horizon=args.horizon,
            out=out,
            model_dir=args.model_dir,
            gif=args.gif,
        )

    def replay(self, request: FreewayReplay) -> dict:
        model = world_model_for(request.technique, request.model_dir)
        search = ChickenSearch(horizon=request.horizon)
        return replay_freeway(
            request.log, request.technique, request.noop_start, search, request.out, model, request.gif
        ).to_dict() | {"out": request.out}

    def describe(self, result: dict) -> str:
        ms = "" if result["decision_ms"] is None else f", {result['decision_ms']:g} ms a decision (median)"
        return (
            f"score {result['score']:g}, {result['knocks']} knocks in {result['steps']} steps{ms}; replay log: "
            + (result["out"])
        )


class Play:
    """`python -m flows.play --world freeway`: steer the chicken across the real game with the keyboard, or watch
    the planner play it, with the lanes the planner sees k steps ahead beside the truth.

    The game is turn-based here, as the planner plays it: each key press is one agent step of the emulator (and of
    its NOOP shadow, the world without the chicken). The right-hand panels show, at every step, the true lanes k
    steps on and the lanes the technique (--technique: oracle, the true future; learned, what Freeway's world model
    imagines; zero, empty lanes) searches there, whoever plays.

    Keys:
      W or UP           the chicken steps up
      X or DOWN         the chicken steps down
      S                 the chicken waits (NOOP)
      K                 the planner's horizon k: 4, 8, 16
      P                 the planner plays / you play
      SPACE             pause or resume the planner
      R                 restart the episode
      ESC               quit (with --record, the replay log is written first)
    """

    scale = 3
    fps = 15.0

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--mode", type=bounded(FreewayEpisode, "mode"), default=0, help="the game mode (0 … 7)")
        parser.add_argument(
            "--noop-start",
            type=bounded(FreewayEpisode, "noop_start"),
            default=0,
            help="NOOP steps before the episode starts (0 … 30)",
        )
        parser.add_argument(
            "--technique",
            default="learned",
            choices=PLANNERS,
            help="the planner that plays (P) and whose lanes are shown (default learned)",
        )
        parser.add_argument("--model-dir", type=PathArgument(PathKind.MODEL_FOLDER), help=MODEL_DIR_HELP)
        parser.add_argument(
            "-k",
            "--horizon",
            type=bounded(ChickenSearch, "horizon"),
            default=8,
            help=f"the planner's horizon (K cycles through {', '.join(map(str, HORIZONS))})",
        )

    def state(self, args: argparse.Namespace) -> FreewayPlay:
        if args.model_dir is not None and args.technique != "learned":
            raise ValueError(
                f"--model-dir: only with --technique learned (--technique {args.technique} reads no world model)"
            )
        model = world_model_for(args.technique, args.model_dir)
        episode = FreewayEpisode(mode=args.mode, noop_start=args.noop_start)
        return FreewayPlay(episode, args.technique, args.horizon, model)
