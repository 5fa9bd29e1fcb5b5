"""The commands every world shares, on one path (`dynplan.world_parts`): `flows.evaluate`, `flows.replay` and
`flows.play` hand their arguments to the world's half of the command (`world_command`; the road's without
`--world`): its options are added to a parser of the command's own, its request is made and checked before any flow
machinery starts (a bad value is one line and exit status 2), and the work runs as a Prefect flow (evaluate: one
task a lockstep batch; replay: one flow run) or a pygame window (play).
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import shlex
import sys
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from dynplan.cli import Bounded, CommandParser, named_world
from dynplan.files import atomic_path
from dynplan.paths import PathArgument, PathKind
from dynplan.progress import progress
from dynplan.world import DEFAULT_WORLD, world, world_names
from dynplan.world_parts import EvaluateCommand, PlayCommand, PlayState, ReplayCommand, WorldParts
from flows.artifacts import ProgressArtifact, artifact_key, publish_summary
from flows.cli import add_console_options, temporary_api
from flows.collect import collect_episodes
from flows.deferred import NO_CACHE, flow, task
from flows.runners import add_dask_option, checked_dask_address, task_runner
from flows.window import PanelWindow, add_window_options, checked_window_options

#: A world's half of one of the commands.
Command = EvaluateCommand | ReplayCommand | PlayCommand


def world_command(prog: str, argv: Sequence[str], command: Callable[[WorldParts], Command | None]) -> tuple[str, Any]:
    """(world, its half of a command: `command` of its parts) for the world `argv` names (the default where it
    names none); a world that is not one of dynplan's, or has no such command, exits with one line."""
    name = named_world(list(argv))
    if name not in world_names():
        parser = CommandParser(prog=prog)
        parser.add_argument("--world", choices=world_names())
        parser.parse_known_args(list(argv))  # exits: an invalid choice, naming the worlds
    own = command(world(name).load())
    if own is None:
        CommandParser(prog=prog).error(f"--world {name}: the {name} world has no `{prog}`")
    return name, own


def parser_for(prog: str, name: str, own: Command) -> CommandParser:
    """A command's parser for world `name`: its half's docstring, `--world`, then the options its half adds."""
    description = inspect.cleandoc(type(own).__doc__ or "")
    shown = prog if name == DEFAULT_WORLD else f"{prog} --world {name}"
    parser = CommandParser(prog=shown, description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    help = f"the world (default {DEFAULT_WORLD}; `--world W --help` lists another world's options)"
    parser.add_argument("--world", choices=world_names(), default=name, help=help)
    own.add_arguments(parser)
    return parser


def parsed(parser: argparse.ArgumentParser, name: str, argv: Sequence[str]) -> argparse.Namespace:
    """`argv` parsed as world `name`'s command (an abbreviated `--world` of another world exits, naming it)."""
    args = parser.parse_args(list(argv))
    if args.world != name:
        parser.error(f"--world {args.world}: give it as --world {args.world} (in full) for its own options")
    return args


def _request(parser: argparse.ArgumentParser, own: EvaluateCommand | ReplayCommand, args: argparse.Namespace) -> Any:
    """The request `args` make, checked (a bad value or input exits with one line)."""
    try:
        return own.request(args)
    except ValueError as error:  # an InputError, a ConfigError, a CheckpointError too
        parser.error(str(error))


@task(name="play-world-job", cache_policy=NO_CACHE)
def world_job_task(world_name: str, request: dict, job: dict) -> dict:
    """One job of a world's evaluation, played into its results."""
    own = world(world_name).load().evaluate
    return own.play(own.request_type(**request), job)


@flow(name="evaluate-world", log_prints=True)
def evaluate_world(world_name: str, request: dict, command: str, artifacts: str | None = None) -> list[dict]:
    """Record the episodes `request` (a world's evaluation request, as a dict; `command`: what its manifest
    records) plays against where missing, begin its run and play every episode it lacks, one task a job (the
    world's: a lockstep batch of episodes); print and return the summary of its run. Publishes the episodes'
    progress and the summary as Prefect artifacts, the summary keyed `<summary_key>-<artifacts>` (default: the
    run's name)."""
    from prefect.futures import as_completed

    own = world(world_name).load().evaluate
    checked = own.request_type(**request)
    recordings = own.recordings(checked)
    if recordings is not None:
        collect_episodes(recordings.folder, recordings.episodes, recordings.first_seed, world_name=world_name)
    jobs = own.start(checked, command)
    total = sum(job["episodes"] for job in jobs)
    if total:
        print(f"{total} episodes to play into {world_name} run {checked.run!r}, in {len(jobs)} batches, one task each")
    futures = [world_job_task.submit(world_name, request, job) for job in jobs]
    played = ProgressArtifact(f"episodes played into run {checked.run!r}", total)
    for future in progress(as_completed(futures), total=len(futures), description=f"{world_name} batches"):
        played.advance(future.result()["episodes"])
        own.summary(checked)  # a world that writes a table from its run keeps it current
    summary = own.summary(checked)
    lines = own.describe(summary)
    publish_summary(summary, artifact_key(own.summary_key, artifacts or checked.run), "\n".join(lines))
    if total:
        print(f"\n{world_name} run {checked.run!r}:\n" + "\n".join(lines))
    else:  # a rerun: its table is the one printed before
        print(f"{world_name} run {checked.run!r}: every episode already played (`--check` prints its summary)")
    return summary


def evaluate_main(name: str, own: EvaluateCommand, argv: Sequence[str]) -> list[dict]:
    """`flows.evaluate [--world NAME] …`: the batches run on the local cores (`--workers` at once, torch's
    threads shared among them) or on a Dask cluster (`--dask-address`)."""
    parser = parser_for("python -m flows.evaluate", name, own)
    add_dask_option(parser)
    parser.add_argument(
        "--workers", type=Bounded(int, 1, 256), help="batches played at once locally, in [1, 256] (default: cores)"
    )
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    check = "play nothing: check each row of the run against what it records (exit 1 naming misfits)"
    parser.add_argument("--check", action="store_true", help=check)
    add_console_options(parser)
    args = parsed(parser, name, argv)
    try:
        address = checked_dask_address(args.dask_address)
    except ValueError as error:
        parser.error(str(error))
    request = _request(parser, own, args)
    if args.check:
        return _check(own, request)
    if not address:  # the local pool's batches share the cores; more threads only contend
        import torch

        cores = os.cpu_count() or 1
        torch.set_num_threads(max(1, cores // (args.workers or cores)))
    command = shlex.join(["python", "-m", "flows.evaluate", *argv])
    with temporary_api():
        summary = evaluate_world.with_options(task_runner=task_runner(address, args.workers))(
            world_name=name, request=request.model_dump(mode="json"), command=command
        )
    if args.json:
        print(json.dumps(summary))
    return summary


def _check(own: EvaluateCommand, request: Any) -> list[dict]:
    """`--check`: every row's actions replayed; exit 1 naming the rows that do not hold."""
    problems = own.check(request)
    if problems:
        print("\n".join(problems), file=sys.stderr)
        raise SystemExit(1)
    summary = own.summary(request)
    print("\n".join(own.describe(summary)))
    print("every row of the run holds")
    return summary


@flow(name="replay-world-episode", log_prints=True)
def replay_world(world_name: str, request: dict) -> dict:
    """Replay one episode of a world (its replay request, as a dict) into a log; print the result in one line."""
    own = world(world_name).load().replay
    result = own.replay(own.request_type(**request))
    print(own.describe(result))
    return result


def replay_main(name: str, own: ReplayCommand, argv: Sequence[str]) -> dict:
    """`flows.replay --world NAME LOG …`."""
    parser = parser_for("python -m flows.replay", name, own)
    parser.add_argument("log", type=PathArgument(PathKind.LOG), help=f"a {name} log (.mcap) from flows.collect")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    add_console_options(parser)
    args = parsed(parser, name, argv)
    request = _request(parser, own, args)
    with temporary_api():
        result = replay_world(world_name=name, request=request.model_dump(mode="json"))
    if args.json:
        print(json.dumps(result))
    return result


def play_main(name: str, own: PlayCommand, argv: Sequence[str]) -> PlayState:
    """`flows.play --world NAME …`: the window around the world's play state."""
    parser = parser_for("python -m flows.play", name, own)
    parser.add_argument("--watch", action="store_true", help="start with the planner playing")
    parser.add_argument(
        "--record",
        type=PathArgument(PathKind.OUTPUT_LOG),
        default=None,
        help="write what was played to this replay log (.mcap) at the end",
    )
    add_window_options(parser, own.scale, own.fps, f"pixel of the world (default {own.scale})")
    args = parsed(parser, name, argv)
    script = checked_window_options(parser, args)
    try:
        state = own.state(args)
    except ValueError as error:  # a CheckpointError and a LogError too
        parser.exit(2, f"python -m flows.play: error: {error}\n")
    return play_window(state, PlayOptions(args.scale, args.fps, args.watch, script, args.record, args.screenshot))


class PlayOptions:
    """How a play window runs: its scale and frame rate, whether the planner starts playing, a headless script of
    key names, and where the replay log and the last picture go (None: nowhere)."""

    def __init__(
        self,
        scale: int = 3,
        fps: float = 15.0,
        watch: bool = False,
        script: Iterable[str] | None = None,
        record: str | None = None,
        screenshot: str | None = None,
    ) -> None:
        self.scale, self.fps, self.watch, self.record, self.screenshot = scale, fps, watch, record, screenshot
        self.script = None if script is None else list(script)


def window_key(state: PlayState, name: str, planner_plays: bool, paused: bool) -> tuple[bool, bool] | None:
    """A key every play window has — R restarts, K changes the horizon, P hands over to the planner, SPACE pauses —
    and its effect; (planner_plays, paused) after it, or None for another key."""
    if name == "r":
        state.reset()
    elif name == "k":
        state.cycle_horizon()
    elif name in ("p", "space"):
        return (not planner_plays, paused) if name == "p" else (planner_plays, not paused)
    else:
        return None
    return planner_plays, paused


def _handle(state: PlayState, name: str, planner_plays: bool, paused: bool) -> tuple[bool, bool]:
    """One key press: its effect on the state; returns (planner_plays, paused)."""
    modes = window_key(state, name, planner_plays, paused)
    if modes is not None:
        return modes
    if state.key(name):
        return planner_plays, paused
    if name in state.keys and state.running and not planner_plays:
        state.step(state.keys[name])
    return planner_plays, paused


def play_window(state: PlayState, options: PlayOptions | None = None) -> PlayState:
    """Run the window until ESC or the window closes. `options.script`: key names fed in as real key events, one
    per frame (then the window quits) — how the tests play it headless."""
    import pygame

    options = options or PlayOptions()
    panels, lines = state.panels(), state.status(options.watch, False)
    window = PanelWindow(panels[0][0].shape[:2], len(panels), options.scale, state.caption, 50 + 24 * len(lines))
    clock, paused, planner_plays, keys = pygame.time.Clock(), False, options.watch, options.script
    try:
        while keys is None or keys:
            if keys is not None:
                pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.key.key_code(keys.pop(0))))
            events = pygame.event.get()
            names = [pygame.key.name(e.key) for e in events if e.type == pygame.KEYDOWN]
            for name in names:
                planner_plays, paused = _handle(state, name, planner_plays, paused)
            if any(e.type == pygame.QUIT for e in events) or "escape" in names:
                break
            if planner_plays and not paused and state.running:
                state.step(*state.planner_action())
            window.show(state.panels(), state.status(planner_plays, paused))
            clock.tick(options.fps)
        if options.screenshot is not None:
            with atomic_path(options.screenshot, keep_suffix=True) as tmp:
                pygame.image.save(window.screen, str(tmp))
    finally:
        pygame.quit()
        state.close()
        if options.record is not None and state.turns:
            print(f"recorded {state.record(options.record)}")
    return state
