"""`python -m flows.view LOG.mcap`: see an episode or replay log in Foxglove Studio, offline, with its world's layout.

Serves the open-source Foxglove Studio 1.48 (fetched once from the npm registry into a cache folder, checked against
its pinned digests), the layout of the log's world (`dynplan/logs/layouts/replay-studio-1.48.json` for the road; a
world's own, `WorldParts.studio_layout`) and the log on 127.0.0.1, prints the
URL to open, and serves until interrupted. With --screenshot it instead opens the view in headless Chromium, waits
until the app has listed the log's topics and drawn every panel whose topics have data by then, writes the picture
and says what the app showed; exit status 1 (naming the panels) if they had not drawn within --timeout.

    python -m flows.view replay.mcap                      # then open the printed URL
    python -m flows.view replay.mcap --screenshot shot.png --at 3
    python -m flows.view --install                        # fetch the app now (37 MB, once)
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from dynplan.cli import Bounded, CommandParser, InputError, add_debug_option, run_command
from dynplan.logs.format import FRAME_PERIOD_NS, STUDIO_LAYOUT, panel_topics
from dynplan.logs.reader import read_episode_log
from dynplan.paths import PathArgument, PathKind, check_output
from dynplan.view.app import default_cache, install
from dynplan.view.browser import find_chromium
from dynplan.view.capture import CaptureSettings, ViewReport, capture, view_query
from dynplan.view.server import ViewServer, check_port, routes
from dynplan.world import world, world_names


def _parser() -> argparse.ArgumentParser:
    parser = CommandParser(
        prog="python -m flows.view", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("log", nargs="?", type=PathArgument(PathKind.LOG), help="an episode or replay log (.mcap)")
    parser.add_argument(
        "--world",
        choices=world_names(),
        default=None,
        help="the log's world, checked against the log's own (default: the log's)",
    )
    parser.add_argument(
        "--port",
        type=Bounded(int, 0, 65535),
        default=0,
        help="the port to serve on at 127.0.0.1 (default 0: a free one)",
    )
    parser.add_argument(
        "--screenshot",
        type=PathArgument(PathKind.OUTPUT_PNG),
        help="write a picture (.png) of the view from headless Chromium, not serve",
    )
    parser.add_argument(
        "--at",
        type=Bounded(float, 0.0, 86400.0),
        help="seconds of log time to show; default: once every panel has a message",
    )
    parser.add_argument(
        "--timeout",
        type=Bounded(float, 1.0, 3600.0),
        help="seconds the screenshot waits for the app to draw (default 60)",
    )
    parser.add_argument(
        "--install",
        action="store_true",
        help="fetch the app into the cache (done on first use anyway); alone, only that",
    )
    parser.add_argument(
        "--cache",
        type=PathArgument(PathKind.OUTPUT_FOLDER),
        help=f"the app's cache (default $DYNPLAN_VIEWER_CACHE or {default_cache()})",
    )
    add_debug_option(parser)
    return parser


def _check(args: argparse.Namespace) -> None:
    """Refuse what the parser cannot see: no log, a screenshot that is not a .png, a time past the log's end, and a
    log that is not dynplan's or is damaged (the reader names what is wrong)."""
    if args.log is None:
        if args.install:
            return
        raise InputError("LOG: missing; give an episode or replay log (.mcap), or --install alone")
    if args.screenshot is not None:
        if Path(args.screenshot).suffix.lower() != ".png":
            raise InputError(f"--screenshot {args.screenshot}: must end in .png")
        check_output(args.screenshot, "--screenshot", "file", inputs=(args.log,))
    if args.screenshot is None and args.at is not None:
        raise InputError("--at: only with --screenshot (in the app, drag the timeline)")
    if args.screenshot is None and args.timeout is not None:
        raise InputError("--timeout: only with --screenshot (it bounds the wait for the picture)")
    if args.cache is not None:
        check_output(args.cache, "--cache", "folder", inputs=(args.log,))
    log = read_episode_log(args.log)
    if args.world is not None and log.entry.name != args.world:
        raise InputError(f"{args.log}: a log of the {log.entry.name} world, not --world {args.world}'s")
    duration = (log.n_frames - 1) * FRAME_PERIOD_NS / 1e9
    if args.at is not None and args.at > duration:
        raise InputError(f"--at={args.at:g} is past the log's end; valid range [0, {duration:g}] seconds")


def studio_layout(log: Path) -> Path:
    """The layout `log` is shown with: its world's (`WorldParts.studio_layout`), else dynplan's own."""
    return world(read_episode_log(log).entry.name).load().studio_layout or STUDIO_LAYOUT


def serve(log: Path, app: Path, port: int) -> None:
    """Serve the view of `log` until interrupted."""
    table, (log_url,) = routes(app, studio_layout(log), [log])
    with ViewServer(table, port) as server:
        print(f"Foxglove Studio with {log.name}: {server.origin}{view_query(server.origin, log_url)}", flush=True)
        print("serving on 127.0.0.1 only; Ctrl-C stops", flush=True)
        try:
            while True:
                time.sleep(3600)
        except KeyboardInterrupt:
            print("stopped")


def report_lines(report: ViewReport, out: Path, layout: Path = STUDIO_LAYOUT) -> list[str]:
    """What the command prints after a screenshot: the picture, the summary, and anything the app complained of."""
    lines = [f"wrote {out}: {report.summary()}"]
    lines += [f"problem: {p}" for p in report.problems]
    reads = panel_topics(layout)
    for panel in (p for p in report.panels if not p.drawn):
        missing = sorted(reads.get(panel.id, set()) - set(report.topics))
        lines.append(f"panel {panel.id} shows nothing" + (f": the log has no {', '.join(missing)}" if missing else ""))
    lines += [f"request off 127.0.0.1: {u}" for u in report.outside_requests]
    if not report.complete:
        lines.append("the app had not drawn every panel within --timeout; the picture shows it so")
    return lines


def main(argv: list[str] | None = None) -> ViewReport | Path | None:
    parser = _parser()
    args = parser.parse_args(argv)
    _check(args)
    chromium = find_chromium() if args.screenshot else None  # before the download: fail fast
    check_port(args.port)
    app = install(Path(args.cache) if args.cache else default_cache())
    if args.log is None:
        return app
    if args.screenshot is None:
        serve(Path(args.log), app, args.port)
        return None
    settings = CaptureSettings(at_s=args.at, timeout_s=args.timeout or CaptureSettings().timeout_s, port=args.port)
    layout = studio_layout(Path(args.log))
    report = capture(app, layout, Path(args.log), Path(args.screenshot), chromium, settings)
    print("\n".join(report_lines(report, Path(args.screenshot), layout)))
    if not report.complete:  # named above: the panels that show nothing
        raise SystemExit(1)
    return report


if __name__ == "__main__":
    run_command(main, "python -m flows.view")
