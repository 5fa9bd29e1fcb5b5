"""The environment a flow runs in, checked as Prefect is loaded: a bad `PREFECT_*` variable, an API that is not
there and a Prefect home that cannot be written are each one line naming the variable, not Prefect's validation
report, a connection traceback or the temporary server's dying words.

- Prefect's settings are read from the environment when Prefect is imported; it prints what it cannot validate and
  goes on with defaults. `load_prefect` imports it with stderr held back, validates its settings again and names
  each variable whose value was refused.
- `PREFECT_API_URL` must be an http(s) URL where a Prefect API answers its health check.
- The folder Prefect keeps its database and files in (`PREFECT_HOME`, default `~/.prefect`) must be writable.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from dynplan.cli import InputError

#: Seconds to wait for an external API's health check.
API_TIMEOUT_S = 10.0


class EnvironmentProblem(InputError):
    """A variable of the environment the command cannot run with; the message names it and what it takes."""


@contextmanager
def _held_stderr() -> Iterator[list[str]]:
    """Within the block, what is written to file descriptor 2 is kept (yielded as one string, once the block
    ends) instead of shown."""
    said: list[str] = []
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            yield said
        except BaseException:  # what was said is shown after all: it may say why
            _restore(saved, held, said)
            sys.stderr.write(said[0])
            raise
        _restore(saved, held, said)


def _restore(saved: int, held, said: list[str]) -> None:
    """Point file descriptor 2 back at `saved` and keep what `held` took in `said`."""
    sys.stderr.flush()
    os.dup2(saved, 2)
    os.close(saved)
    held.seek(0)
    said.append(held.read().decode(errors="replace"))


def load_prefect() -> str:
    """Import Prefect with its settings from the environment checked: an `EnvironmentProblem` naming each
    `PREFECT_*` variable whose value Prefect refuses; else what Prefect said on import, for the caller to show
    once the rest of the environment is checked (a home it could not create is then named, not warned about)."""
    from pydantic import ValidationError

    problems: list[str] = []
    with _held_stderr() as said:
        import prefect  # noqa: F401
        from prefect.settings import Settings

        try:
            Settings()
        except ValidationError as error:
            problems = [_named(e["input"], e["msg"]) for e in error.errors() if isinstance(e.get("input"), str)]
            problems = problems or [" ".join(str(error).split())]  # no value to name a variable by: Prefect's words
    if problems:
        raise EnvironmentProblem("; ".join(problems))
    return said[0]


def _named(value: str, why: str) -> str:
    """A refused setting, named by the environment variable that gave it."""
    names = [k for k, v in os.environ.items() if k.startswith("PREFECT_") and v == value] or ["a PREFECT_ setting"]
    return f"{' and '.join(sorted(names))}={value!r} is invalid ({why.rstrip('.')})"


def check_api(url: str) -> None:
    """`PREFECT_API_URL`: an http(s) URL where a Prefect API answers; an `EnvironmentProblem` saying what is there
    instead."""
    parts = urllib.parse.urlsplit(url)
    fix = "; unset PREFECT_API_URL to run on a temporary server of the command's own"
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise EnvironmentProblem(f"PREFECT_API_URL={url!r} is not an http(s) URL of a Prefect API, e.g. "
                                 f"http://127.0.0.1:4200/api{fix}")  # fmt: skip
    try:
        with urllib.request.urlopen(url.rstrip("/") + "/health", timeout=API_TIMEOUT_S) as answer:
            body = answer.read(64)
    except urllib.error.HTTPError as error:
        raise EnvironmentProblem(f"PREFECT_API_URL={url}: answers, but not as a Prefect API (its /health: HTTP "
                                 f"{error.code}){fix}") from None  # fmt: skip
    except (urllib.error.URLError, OSError) as error:
        reason = getattr(error, "reason", error)
        raise EnvironmentProblem(f"PREFECT_API_URL={url}: nothing answers there ({reason}){fix}") from None
    try:
        healthy = json.loads(body) is True
    except ValueError:
        healthy = False
    if not healthy:
        raise EnvironmentProblem(f"PREFECT_API_URL={url}: answers, but not as a Prefect API (its /health said "
                                 f"{body[:40]!r}){fix}")  # fmt: skip


def check_home() -> None:
    """The folder Prefect keeps its database and files in: writable, else an `EnvironmentProblem` naming the
    variable that chose it (`PREFECT_HOME`, else `HOME`)."""
    from prefect.settings import get_current_settings

    home = Path(get_current_settings().home).expanduser()
    variable = "PREFECT_HOME" if "PREFECT_HOME" in os.environ else "HOME"
    try:
        home.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=home, prefix=".write-check-"):
            pass
    except OSError as error:
        raise EnvironmentProblem(
            f"{variable}: Prefect keeps its database in {home}, which cannot be written ({error.strerror}); set "
            "PREFECT_HOME to a folder you can write"
        ) from None


def checked_environment() -> str | None:
    """Prefect loaded, its settings checked, then the API it is told to use (`PREFECT_API_URL`: returned), else the
    home its temporary server keeps its database in (None returned)."""
    said = load_prefect()
    from prefect.settings import PREFECT_API_URL

    url = PREFECT_API_URL.value()
    if url:
        check_api(url)
    else:
        check_home()
    sys.stderr.write(said)
    return url or None
