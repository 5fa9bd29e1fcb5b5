"""Open a log in the offline Foxglove Studio in headless Chromium, read what the app shows, take its picture.

`capture` serves the app, the layout and the log (`server`), opens the view in Chromium (`browser`), waits until
the app has listed the log's topics and every image panel has drawn, reads the app's own account from the page
(the topics it lists, the entries of its Problems list, where each panel is) and takes a screenshot. `ViewReport`
holds what it found, with each panel's verdict read from the screenshot's pixels.
"""

from __future__ import annotations

import io
import itertools
import time
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path
from urllib.parse import urlencode

import numpy as np
from mcap.reader import make_reader
from PIL import Image

from dynplan.files import write_bytes_atomic
from dynplan.logs.format import EPOCH_NS, layout_topics, panel_topics
from dynplan.view.browser import Browser
from dynplan.view.server import ViewServer, routes

#: What the page reports, read after each poll: the data source's tabs, their content, and the panels.
STATE_JS = """(() => {
  const tabs = [...document.querySelectorAll('[role=tab]')];
  const topics = tabs.find((t) => t.textContent === 'Topics');
  const problems = tabs.find((t) => t.textContent.startsWith('Problems'));
  const content = topics?.closest('.MuiTabs-root')?.nextElementSibling?.nextElementSibling ?? null;
  const box = (e) => { const r = e.getBoundingClientRect(); return [r.x, r.y, r.width, r.height]; };
  const panels = [...document.querySelectorAll('[data-testid^="panel-mouseenter-container "]')].map((p) => {
    const canvases = [...p.querySelectorAll('canvas')].map(box).sort((a, b) => b[2] * b[3] - a[2] * a[3]);
    return { id: p.dataset.testid.split(' ')[1], box: box(p), canvas: canvases[0] ?? null,
             waiting: p.innerText.includes('Waiting for') };
  });
  const selected = [topics, problems].find((t) => t?.getAttribute('aria-selected') === 'true');
  return { tab: selected ? selected.textContent.replace(/[0-9]+$/, '') : null,
           problem_count: problems ? Number(problems.textContent.replace('Problems', '')) || 0 : null,
           lines: content ? content.innerText.split('\\n').map((s) => s.trim()).filter(Boolean) : [],
           panels, error: document.getElementById('dynplan-error')?.textContent ?? null };
})()"""
SHOW_PROBLEMS_JS = "[...document.querySelectorAll('[role=tab]')].find((t) => t.textContent.startsWith('Problems'))"
SHOW_PROBLEMS_JS += ".click()"
SETTLE_S = 1.5


@dataclass(frozen=True)
class Panel:
    """A panel of the layout as the page placed it: its id (`Type!name`), its box and its largest canvas's box
    (x, y, width, height in screenshot pixels), and whether its pixels show what it should (`drawn`)."""

    id: str
    box: tuple[float, float, float, float]
    canvas: tuple[float, float, float, float] | None
    drawn: bool

    @property
    def kind(self) -> str:
        return self.id.split("!")[0]


@dataclass(frozen=True)
class ViewReport:
    """What the app showed of a log: the topics it listed (name → schema), its Problems list, the panels, the
    requests the page sent elsewhere than the viewer's server and how many it sent for the log, the page's uncaught
    errors, and the seconds from opening the page to the picture."""

    topics: dict[str, str]
    problems: tuple[str, ...]
    panels: tuple[Panel, ...]
    outside_requests: tuple[str, ...]
    log_requests: int  # the page's requests for the log (the app reads it in byte ranges)
    page_errors: tuple[str, ...]
    seconds: float
    complete: bool  # every image panel drew before the timeout

    def summary(self) -> str:
        drawn = sum(p.drawn for p in self.panels)
        return (
            f"{len(self.topics)} topics listed, {len(self.problems)} problems, {drawn} of {len(self.panels)} "
            f"panels drawn, {len(self.outside_requests)} requests off 127.0.0.1, {self.seconds:.1f} s"
        )


@dataclass(frozen=True)
class CaptureSettings:
    """How to take the picture: at `at_s` seconds of log time (None: once every panel has something), `size` CSS
    pixels, giving up waiting for the panels after `timeout_s`, served on `port` (0: a free one)."""

    at_s: float | None = None
    size: tuple[int, int] = (1600, 1000)
    timeout_s: float = 60.0
    port: int = 0


def view_query(origin: str, log_url: str, at_s: float | None = None) -> str:
    """The app's deep link for a log served at `log_url`, with dynplan's layout, at `at_s` seconds of log time."""
    query = {"ds": "remote-file", "ds.url": origin + log_url, "layoutId": "dynplan"}
    if at_s is not None:
        moment = datetime.fromtimestamp(EPOCH_NS // 10**9, timezone.utc) + timedelta(seconds=at_s)
        query["time"] = moment.isoformat(timespec="milliseconds").replace("+00:00", "Z")
    return "/?" + urlencode(query)


def capture(app: Path, layout: Path, log: Path, out: Path, chromium: str, settings: CaptureSettings) -> ViewReport:
    """Show `log` in the app at `app` with `layout`, write the screenshot to `out` (atomically) and report. The
    time shown is `settings.at_s`, or else the first at which every topic the layout reads has had a message."""
    table, (log_url,) = routes(app, layout, [log])
    with ViewServer(table, settings.port) as server, Browser(chromium, *settings.size) as browser:
        start = time.monotonic()
        firsts = first_times(log)
        at_s = settings.at_s if settings.at_s is not None else max(firsts.get(t, 0.0) for t in layout_topics(layout))
        browser.open(server.origin + view_query(server.origin, log_url, at_s))
        reads = panel_topics(layout)
        due = {key for key, topics in reads.items() if topics and max(firsts.get(t, np.inf) for t in topics) <= at_s}
        state, complete = _wait(browser, due, settings.timeout_s)
        if state["problem_count"]:
            browser.evaluate(SHOW_PROBLEMS_JS)
            time.sleep(0.3)
            problems = tuple(browser.evaluate(STATE_JS)["lines"])
        else:
            problems = ()
        png = browser.screenshot()
        seconds = time.monotonic() - start
        outside = tuple(
            u
            for u in browser.requests
            if u.split(":")[0] in ("http", "https", "ws", "wss") and not u.startswith(server.origin + "/")
        )
        errors = tuple(browser.errors)
        log_requests = sum(u == server.origin + log_url for u in browser.requests)
    write_bytes_atomic(out, png)
    pixels = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
    panels = tuple(
        Panel(p["id"], tuple(p["box"]), p["canvas"] and tuple(p["canvas"]), _drawn(p, pixels)) for p in state["panels"]
    )
    return ViewReport(_topics(state["lines"]), problems, panels, outside, log_requests, errors, seconds, complete)


def first_times(log: Path) -> dict[str, float]:
    """Each topic's first message, in seconds of log time (from the log's start, EPOCH)."""
    firsts: dict[str, float] = {}
    with open(log, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            seconds = (message.log_time - EPOCH_NS) / 1e9
            firsts[channel.topic] = min(firsts.get(channel.topic, seconds), seconds)
    return firsts


def _wait(browser: Browser, due: set[str], timeout_s: float) -> tuple[dict, bool]:
    """Poll the page until it lists topics and every panel `due` (those whose topics all have a message by the time
    shown) has drawn — none waits for its data and its pixels show content (`_drawn`) — or the app lists a problem
    (a refused topic's panels never draw); the last state and whether it got there within `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while True:
        state = browser.evaluate(STATE_JS)
        if state["error"]:
            raise RuntimeError(state["error"])
        listed = state["tab"] == "Topics" and bool(_topics(state["lines"]))
        ready = listed and not any(p["waiting"] and p["id"] in due for p in state["panels"])
        if ready and not state["problem_count"]:
            pixels = np.asarray(Image.open(io.BytesIO(browser.screenshot())).convert("RGB"))
            ready = all(_drawn(p, pixels) for p in state["panels"] if p["id"] in due)
        if ready or time.monotonic() > deadline:
            time.sleep(SETTLE_S)  # let the plots and images finish their frame
            return browser.evaluate(STATE_JS), bool(ready)
        time.sleep(0.25)


def _topics(lines: list[str]) -> dict[str, str]:
    """The Topics tab's entries: a topic's name line (it starts with '/') followed by its schema's line."""
    return {name: schema for name, schema in itertools.pairwise(lines) if name.startswith("/") and "." in schema}


def _drawn(panel: dict, pixels: np.ndarray) -> bool:
    """Whether a panel's pixels show content: an image panel (either dialect) a world — the road's (≥ 10 % black road
    and some grey obstacles) or any other's (≥ 3 colours on ≥ 1 % of it each; an empty panel shows its background and
    a line of text) —, a plot lines (≥ 0.2 % of its canvas in saturated colour); other panels count as drawn."""
    kind = panel["id"].split("!")[0]
    box = panel["canvas"] or panel["box"]
    x, y, w, h = (round(v) for v in box)
    crop = pixels[max(y, 0) : y + h, max(x, 0) : x + w].astype(np.int16)
    if crop.size == 0:
        return False
    spread = crop.max(axis=2) - crop.min(axis=2)
    if kind in ("ImageViewPanel", "Image"):
        black = (crop.max(axis=2) < 24).mean()
        grey = ((spread < 8) & (crop.min(axis=2) >= 24) & (crop.max(axis=2) <= 250)).mean()
        _, counts = np.unique(crop.reshape(-1, 3) // 16, axis=0, return_counts=True)
        colours = int((counts >= 0.01 * counts.sum()).sum())
        return bool(black >= 0.10 and grey >= 0.002) or colours >= 3
    if kind == "Plot":
        return bool((spread > 80).mean() >= 0.002)
    return True
