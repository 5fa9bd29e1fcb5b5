"""The road's half of `flows.evaluate` (`dynplan.world_parts.EvaluateCommand`): the paper's Table 1 protocol over
recorded evaluation episodes.

A request plays every (technique, agent speed, rollout steps, episode) case of its plan into a named run of the
results store (`RESULTS_DIR/runs/RUN/`), in lockstep batches of every case of up to `batch` recorded worlds that
shares a world model (`batches`, one job each); the run `evaluation` is Table 1's, and its summary writes
table1.json / table1.md.
"""

from __future__ import annotations

import argparse
from dataclasses import asdict
from pathlib import Path

from pydantic import Field

from dynplan.cli import Bounded, bounded
from dynplan.config import Config, field_help
from dynplan.data.collect import log_path
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import (
    AGENT_SPEEDS,
    EVAL_SEED_START,
    ROLLOUT_STEPS,
    TABLE1,
    VALIDATION_SEED_START,
    Case,
    CasePlan,
    road_models,
)
from dynplan.evaluation.store import EVALUATION_RUN, Run, check_store, run_argument
from dynplan.evaluation.table import aggregate, load_results, render_markdown, write_table
from dynplan.evaluation.techniques import TECHNIQUES
from dynplan.files import sha256_file
from dynplan.models.caution import Caution
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.progress import progress
from dynplan.world_parts import Recordings

RESULTS_DIR = "datasets/results"
EVAL_LOGS = "datasets/eval_logs"
#: Recorded worlds per lockstep batch (one job): Table 1's 100 worlds make two batches per world model.
BATCH = 50
DEFAULT_TECHNIQUES = ("oracle", "zero", "random")


def run_role(run: str, first_seed: int) -> str:
    """A run's role: Table 1's run is the evaluation, other runs on the validation seeds validate, and any other
    run on the evaluation episodes is a candidate's."""
    if first_seed >= VALIDATION_SEED_START:
        return "validation"
    return "evaluation" if run == EVALUATION_RUN else "candidate"


def batches(todo: list[Case], size: int) -> list[list[Case]]:
    """The cases in lockstep batches: per world-model configuration (the techniques without one together), the
    cases of up to `size` recorded worlds each — every technique, agent speed and k of those worlds in one batch, so
    that each frame's prediction is made once for all the cases that see it."""
    groups: dict[str | None, dict[int, list[Case]]] = {}
    for case in todo:
        groups.setdefault(case.model, {}).setdefault(case.seed, []).append(case)
    out = []
    for by_seed in groups.values():
        seeds = sorted(by_seed)
        for start in range(0, len(seeds), size):
            out.append([case for seed in seeds[start : start + size] for case in by_seed[seed]])
    return out


class RoadEvaluation(Config):
    """One evaluation: the cases of `plan` played by the agents `agent` (playouts, weights — the committed ones or a
    pipeline's own under `agent.model_dir` — caution overrides, device) against the recorded episodes in `log_dir`
    (recorded first where missing), into run `run` of the store at `results_dir`, `batch` recorded worlds a job."""

    plan: CasePlan = Field(default_factory=CasePlan)
    agent: AgentSpec = Field(default_factory=AgentSpec)
    log_dir: str = EVAL_LOGS
    results_dir: str = RESULTS_DIR
    run: str = EVALUATION_RUN
    batch: int = Field(BATCH, ge=1, le=10_000, description="recorded worlds per lockstep batch")

    @property
    def role(self) -> str:
        return run_role(self.run, self.plan.first_seed)

    def store_run(self) -> Run:
        return Run(self.results_dir, self.run)


class Evaluate:
    """`python -m flows.evaluate`: the paper's Table 1 protocol over recorded evaluation episodes.

    Records the evaluation episodes if they are missing (seeds 1,000,000 …), plays every (technique, agent speed,
    rollout steps, episode) case into a named run of the results store (`RESULTS_DIR/runs/RUN/`: a manifest and one
    JSON line per episode), in lockstep batches of every case of up to `--batch` recorded worlds that shares a world
    model, one Prefect task each — skipping cases the run already holds and appending each row as its episode
    finishes, so an interrupted evaluation resumes per episode — then aggregates the evaluation runs into
    table1.json / table1.md. The run `evaluation` is Table 1's; `--first-seed 2000000` with another `--log-dir` and
    `--run` plays the validation episodes instead, where a world model's settings are chosen (`--occupancy`,
    `--margin`, `--model-dir`); any other run on the evaluation episodes is a candidate's. `--table1` plays every
    case of the complete Table 1 (both world-model configurations, every technique and speed the table lists) in
    one command. `--world W` evaluates another world through its own options (`--world W --help`).
    """

    request_type = RoadEvaluation
    summary_key = "table1"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        _add_case_options(parser)
        _add_agent_options(parser)
        _add_store_options(parser)

    def request(self, args: argparse.Namespace) -> RoadEvaluation:
        """The evaluation the arguments ask for, every value checked by its config and each learned agent's weights
        loaded once, before any flow machinery starts."""
        from dynplan.models.checkpoint import CheckpointError  # torch: imported by the work, not by `--help`

        if args.first_seed != EVAL_SEED_START and args.run == EVALUATION_RUN:
            raise ValueError(
                f"--first-seed={args.first_seed} needs its own --run: the run {EVALUATION_RUN!r} holds the "
                f"evaluation's results (seeds {EVAL_SEED_START:,} …), all of which Table 1 counts"
            )
        check_output(args.log_dir, "--log-dir", "folder")
        check_output(args.results_dir, "--results-dir", "folder", inputs=(args.log_dir,))
        if Path(args.results_dir).is_dir():
            check_store(args.results_dir)  # every run through its schema: a damaged one is named now, not mid-run
        plan, agent = _plan(args), _agent(args)
        for technique, model in plan.pairs():  # each technique and configuration's weights
            try:
                agent.for_case(technique, model, None, 0).check_weights()
            except CheckpointError as error:
                message = f"--model-dir {args.model_dir}: {error}" if args.model_dir else str(error)
                raise CheckpointError(message) from None
        return RoadEvaluation(
            plan=plan, agent=agent, log_dir=args.log_dir, results_dir=args.results_dir, run=args.run, batch=args.batch
        )

    def recordings(self, request: RoadEvaluation) -> Recordings:
        plan = request.plan
        return Recordings(folder=request.log_dir, episodes=plan.episodes, first_seed=plan.first_seed)

    def start(self, request: RoadEvaluation, command: str) -> list[dict]:
        """Begin (or extend) the run's manifest; the cases it does not hold yet, in lockstep batches (one job each)."""
        from dynplan.evaluation.protocol import pending
        from dynplan.evaluation.provenance import begin_run

        run, all_cases = request.store_run(), request.plan.cases()
        begin_run(run, request.role, all_cases, request.log_dir, command, request.agent)
        todo = pending(all_cases, run, request.log_dir, request.agent)
        return [{"cases": [asdict(c) for c in b], "episodes": len(b)} for b in batches(todo, request.batch)]

    def play(self, request: RoadEvaluation, job: dict) -> dict:
        from dynplan.evaluation.protocol import run_cases

        cases = [Case(**c) for c in job["cases"]]
        rows = run_cases(cases, request.log_dir, request.store_run(), request.agent)
        return {"episodes": len(rows)}

    def summary(self, request: RoadEvaluation) -> list[dict]:
        """The run's Table 1 rows; the evaluation's also rewrite table1.json / table1.md from every evaluation run
        (so a stopped evaluation still leaves an up-to-date table)."""
        if request.store_run().manifest()["role"] == "evaluation":
            write_table(aggregate(load_results(request.results_dir)), request.results_dir)
        return aggregate(request.store_run().current())

    def describe(self, summary: list[dict]) -> list[str]:
        return render_markdown(summary).splitlines()

    def check(self, request: RoadEvaluation) -> list[str]:
        """Each row's recorded episode as it was played: one line per row whose log is missing or differs from the
        digest the row records (a road row holds no actions; its episode is replayed from the log it names)."""
        problems, digests, run = [], {}, request.store_run()
        for number, row in progress(run.counted(), description="rows checked"):
            path = log_path(request.log_dir, row["seed"])
            if path not in digests:
                digests[path] = sha256_file(path) if path.exists() else None
            if digests[path] != row["log_sha256"]:
                found = "missing" if digests[path] is None else f"sha256 {digests[path][:12]}…"
                problems.append(
                    f"{run.place(number)}: technique={row['technique']} seed={row['seed']}: log {path} is {found}, "
                    f"the row was played on {row['log_sha256'][:12]}…"
                )
        return problems


def _plan(args: argparse.Namespace) -> CasePlan:
    """The cases the arguments name; `--table1` plays the table's own techniques, models and speeds."""
    if args.table1:
        defaults = {"techniques": list(DEFAULT_TECHNIQUES), "models": ["default"], "agent_speeds": list(AGENT_SPEEDS)}
        given = [f"--{name.replace('_', '-')}" for name, value in defaults.items() if getattr(args, name) != value]
        if given:
            raise ValueError(f"--table1 plays the table's own techniques, models and speeds; drop {' '.join(given)}")
    return CasePlan(
        techniques=args.techniques,
        models=args.models,
        agent_speeds=args.agent_speeds,
        rollout_steps=args.rollout_steps,
        episodes=args.episodes,
        first_seed=args.first_seed,
        table1=args.table1,
    )


def _agent(args: argparse.Namespace) -> AgentSpec:
    """The agents' settings: playouts, weights, caution overrides (checked as the caution's), device."""
    overrides = {name: value for name in Caution.model_fields if (value := getattr(args, name)) is not None}
    Caution(**overrides)  # its ranges, named as the caution's
    try:
        return AgentSpec(playouts=args.playouts, model_dir=args.model_dir, caution=overrides, device=args.device)
    except ValueError as error:
        raise ValueError(str(error).removeprefix("AgentSpec: ")) from None


def _add_case_options(parser: argparse.ArgumentParser) -> None:
    """The cases: techniques, world models, agent speeds and horizons, or the complete Table 1."""
    parser.add_argument(
        "--techniques",
        nargs="+",
        default=list(DEFAULT_TECHNIQUES),
        choices=list(TECHNIQUES),
        metavar="TECHNIQUE",
        help="; ".join(f"{n}: {t.description}" for n, t in TECHNIQUES.items()) + " (default: oracle zero random)",
    )
    learned = ", ".join(n for n, t in TECHNIQUES.items() if t.world_model)
    parser.add_argument(
        "--models",
        nargs="+",
        default=["default"],
        choices=road_models(),
        help=f"world-model configurations for the learned techniques ({learned})",
    )
    speeds, ks = " ".join(map(str, AGENT_SPEEDS)), " ".join(map(str, ROLLOUT_STEPS))
    parser.add_argument(
        "--agent-speeds",
        nargs="+",
        type=float,
        choices=AGENT_SPEEDS,
        default=list(AGENT_SPEEDS),
        help=field_help(CasePlan, "agent_speeds", speeds),
    )
    parser.add_argument(
        "--rollout-steps",
        nargs="+",
        type=bounded(AgentSpec, "rollout_steps"),
        default=list(ROLLOUT_STEPS),
        help=field_help(CasePlan, "rollout_steps", ks),
    )
    table = "; ".join(f"{speed * 2:g}x: {' '.join(names)}" for speed, names in TABLE1.items())
    parser.add_argument(
        "--table1",
        action="store_true",
        help=f"play the complete Table 1: {table} (learned ones with {' and '.join(road_models())}); instead of "
        "--techniques, --models and --agent-speeds",
    )


def _add_agent_options(parser: argparse.ArgumentParser) -> None:
    """The episodes played and the agents' search settings."""
    for name, flag in (("episodes", "--episodes"), ("first_seed", "--first-seed")):
        default = CasePlan.model_fields[name].default
        parser.add_argument(flag, type=bounded(CasePlan, name), default=default, help=field_help(CasePlan, name))
    parser.add_argument(
        "--playouts", type=bounded(AgentSpec, "playouts"), default=100, help=field_help(AgentSpec, "playouts")
    )
    parser.add_argument(
        "--model-dir", type=PathArgument(PathKind.MODEL_FOLDER), help=field_help(AgentSpec, "model_dir")
    )
    for name in Caution.model_fields:  # the caution's fields, types, ranges and words
        own = "each configuration's own"
        parser.add_argument(f"--{name}", type=bounded(Caution, name), help=field_help(Caution, name, own))
    parser.add_argument("--device", default="cpu", help=field_help(AgentSpec, "device"))


def _add_store_options(parser: argparse.ArgumentParser) -> None:
    """Where the logs and results go, and how many recorded worlds a lockstep batch holds."""
    parser.add_argument(
        "--log-dir",
        type=PathArgument(PathKind.OUTPUT_FOLDER),
        default=EVAL_LOGS,
        help="evaluation logs (recorded if missing)",
    )
    parser.add_argument(
        "--results-dir",
        type=PathArgument(PathKind.OUTPUT_FOLDER),
        default=RESULTS_DIR,
        help="the results store (runs and Table 1)",
    )
    parser.add_argument(
        "--run",
        type=run_argument,
        default=EVALUATION_RUN,
        help=f"the run to play into (default {EVALUATION_RUN!r}, Table 1's; name another for validation or a "
        "candidate)",
    )
    parser.add_argument(
        "--batch",
        type=Bounded(int, 1, 10_000),
        default=BATCH,
        help=f"recorded worlds per lockstep batch, in [1, 10000] (default {BATCH})",
    )
