"""Headless Chromium driven over the Chrome DevTools Protocol: open a page, evaluate in it, take a screenshot.

The browser starts with its own temporary profile, no background networking, a host resolver that resolves
nothing but 127.0.0.1 and, for addresses, a proxy on a closed local port (loopback bypasses it), so a page it
shows reaches nothing but the loopback interface; every request the page makes is recorded (`requests`) so that
a caller can check that none was meant to go elsewhere.
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
from websockets.sync.client import connect

from dynplan.cli import InputError, die_with_parent

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
FLAGS = (
    "--headless=new",
    "--remote-debugging-port=0",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
    "--disable-dev-shm-usage",
    "--hide-scrollbars",
    "--mute-audio",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
    "--proxy-server=127.0.0.1:9",
)  # fmt: skip  (names resolve nowhere; addresses go to a closed proxy port)
START_TIMEOUT_S = 30.0


def find_chromium() -> str:
    """The Chromium executable: `$DYNPLAN_CHROMIUM`, or the first of CANDIDATES on PATH."""
    name = os.environ.get("DYNPLAN_CHROMIUM")
    found = shutil.which(name) if name else next(filter(None, map(shutil.which, CANDIDATES)), None)
    if found is None:
        wanted = f"{name!r}" if name else "Chromium (" + ", ".join(CANDIDATES) + ")"
        raise InputError(f"{wanted} not found on PATH: the screenshot needs it (Debian: apt-get install chromium)")
    return found


class Browser:
    """One headless Chromium page, `width` × `height` CSS pixels; a context manager that ends the browser."""

    def __init__(self, executable: str, width: int = 1600, height: int = 1000) -> None:
        self.executable, self.size = executable, (width, height)
        self.requests: list[str] = []
        self.errors: list[str] = []
        self._next_id = 0

    def __enter__(self) -> Browser:
        self._profile = tempfile.TemporaryDirectory(prefix="dynplan-chromium-", ignore_cleanup_errors=True)
        flags = [*FLAGS, f"--user-data-dir={self._profile.name}", f"--window-size={self.size[0]},{self.size[1]}"]
        if hasattr(os, "geteuid") and os.geteuid() == 0:
            flags.append("--no-sandbox")  # Chromium refuses to start its sandbox as root
        try:  # its own process group, so that its helpers end with it; and it ends if this process dies
            self._process = subprocess.Popen(
                [self.executable, *flags, "about:blank"],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                start_new_session=True,
                preexec_fn=die_with_parent,
            )
        except OSError as error:
            self._profile.cleanup()
            raise InputError(f"{self.executable}: cannot start ({error.strerror})") from None
        try:
            self._socket = connect(self._page_socket(), max_size=None, open_timeout=START_TIMEOUT_S)
            self.call(
                "Emulation.setDeviceMetricsOverride",
                width=self.size[0],
                height=self.size[1],
                deviceScaleFactor=1,
                mobile=False,
            )
            for domain in ("Page", "Network", "Runtime"):
                self.call(f"{domain}.enable")
            # the app reads files in web workers: attach to each as it starts, paused until it is watched too
            self.call("Target.setAutoAttach", autoAttach=True, waitForDebuggerOnStart=True, flatten=True)
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc) -> None:
        if getattr(self, "_socket", None) is not None:
            self._socket.close()
        self._signal_all(signal.SIGTERM)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self._process.wait(timeout=10)
        self._signal_all(signal.SIGKILL)  # the helpers (renderers, crash handler) that outlived the browser
        self._process.wait()
        self._profile.cleanup()

    def _signal_all(self, signum: int) -> None:
        """Signal the browser and every process it started (its own process group)."""
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self._process.pid, signum)

    def _page_socket(self) -> str:
        """The DevTools WebSocket of the browser's first page, once the browser has written its port."""
        port_file = Path(self._profile.name) / "DevToolsActivePort"
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if self._process.poll() is not None:
                raise InputError(f"{self.executable} exited with status {self._process.returncode} as it started")
            if port_file.exists() and (lines := port_file.read_text().split()):
                targets = httpx.get(f"http://127.0.0.1:{lines[0]}/json/list", timeout=5).json()
                pages = [t["webSocketDebuggerUrl"] for t in targets if t.get("type") == "page"]
                if pages:
                    return pages[0]
            time.sleep(0.05)
        raise InputError(f"{self.executable} did not open its DevTools port within {START_TIMEOUT_S:g} s")

    def call(self, method: str, **params) -> dict:
        """Send one DevTools command to the page and return its result, recording the events that arrive meanwhile."""
        sent = self._send(method, None, **params)
        while True:
            message = json.loads(self._socket.recv(timeout=120))
            if message.get("id") == sent and "sessionId" not in message:
                if "error" in message:
                    raise RuntimeError(f"DevTools {method}: {message['error'].get('message')}")
                return message.get("result", {})
            self._event(message)

    def _send(self, method: str, worker: str | None, **params) -> int:
        """Send a command to the page (`worker` None) or to the attached worker of that DevTools sessionId, not
        waiting for its answer."""
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params}
        self._socket.send(json.dumps(message | ({"sessionId": worker} if worker else {})))
        return self._next_id

    def _event(self, message: dict) -> None:
        method, params = message.get("method"), message.get("params", {})
        if method == "Network.requestWillBeSent":
            self.requests.append(params["request"]["url"])
        elif method == "Target.attachedToTarget":  # a worker: watch its requests and errors, then let it run
            worker = params["sessionId"]
            for command in ("Network.enable", "Runtime.enable", "Runtime.runIfWaitingForDebugger"):
                self._send(command, worker)
            self._send("Target.setAutoAttach", worker, autoAttach=True, waitForDebuggerOnStart=True, flatten=True)
        elif method == "Page.loadEventFired":
            self._loaded = True
        elif method == "Runtime.exceptionThrown":
            details = params["exceptionDetails"]
            self.errors.append(details.get("exception", {}).get("description") or details.get("text", ""))

    def open(self, url: str, timeout_s: float = START_TIMEOUT_S) -> None:
        """Navigate to `url` and wait for its load event (so that what is evaluated next is evaluated in it)."""
        self._loaded = False
        self.call("Page.navigate", url=url)
        deadline = time.monotonic() + timeout_s
        while not self._loaded and time.monotonic() < deadline:
            with contextlib.suppress(TimeoutError):
                self._event(json.loads(self._socket.recv(timeout=max(deadline - time.monotonic(), 0.01))))

    def evaluate(self, expression: str) -> Any:
        """The value of a JavaScript expression in the page (awaited where it is a promise)."""
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            raise RuntimeError(f"in the page: {details.get('exception', {}).get('description') or details.get('text')}")
        return result["result"].get("value")

    def screenshot(self) -> bytes:
        """The page's viewport as PNG bytes."""
        return base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
