"""The repository's text speaks of the project alone: it cites its own pages, not files outside it, and says
what the code is and does rather than the story of how it came to be.

Every tracked text file is checked (`git ls-files`), except binary files and the data under `datasets/`
(its Markdown is checked). Each failure names file:line, the rule and the text that matched.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
THIS_FILE = Path(__file__).resolve().relative_to(ROOT).as_posix()  # it spells out the patterns it looks for

BINARY_SUFFIXES = {".pt", ".png", ".gif", ".jpg", ".jpeg", ".mcap", ".npy", ".npz", ".zip", ".gz", ".pdf"}
DATA_SUFFIXES = {".json", ".jsonl", ".csv", ".png", ".gif", ".pt", ".mcap"}  # under datasets/: data, not prose

#: References that point outside the repository. Case-sensitive: "spec" in ordinary prose is fine.
OUTSIDE = {
    "path outside the repository": re.compile(r"\.\./shared\b"),
    "external spec (cite docs/protocol.md)": re.compile(r"\bSPEC\.md\b|\bSPEC\b"),
}

#: Wording about how, when or where the project was developed (case-insensitive).
HISTORY = {
    "work session": re.compile(r"\bsessions?\b(?![ _-]*(?:token|cookie|id)\b)", re.IGNORECASE),
    "scratch work": re.compile(r"\bscratch (?:script|run|edit|code|file)s?\b|\(scratch\)", re.IGNORECASE),
    "lent or borrowed hardware": re.compile(r"\blent\b|\bborrowed\b", re.IGNORECASE),
    "sequence of work": re.compile(r"\b(?:a|the) (?:later|earlier|previous|next) stops?\b", re.IGNORECASE),
    "the development machine": re.compile(r"\bthis (?:kind of )?machine\b", re.IGNORECASE),
    "provisional wording": re.compile(r"\bfor now\b|\bat first\b|\bTODO later\b|\bused to be\b", re.IGNORECASE),
    "commit cited as evidence": re.compile(
        r"\bcommit `?[0-9a-f]{7,40}\b|\bgit (?:checkout|show|log|diff) `?[0-9a-f]{7,40}\b", re.IGNORECASE
    ),
}

#: The record of what was tried and left the code: each entry names the commit where its code can still be read
#: ("Its code can be read at commit 0123abc"), and only there is a commit cited.
EXPERIMENTS = "docs/experiments.md"
WHERE_CODE_IS = re.compile(r"\bcan (?:still )?be read at commit `?[0-9a-f]{7,40}\b`?", re.IGNORECASE)

#: Exact phrases whose words are legitimate: removed from a line before the history rules run.
ALLOWED = (
    'scope="session"',  # pytest fixtures that live for the whole test run
    "scope='session'",
)


def tracked_text_files() -> list[Path]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: no list of tracked files")
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    files = []
    for name in listed.decode().split("\0"):
        if not name or name == THIS_FILE:
            continue
        suffix = Path(name).suffix.lower()
        if suffix in BINARY_SUFFIXES or (name.startswith("datasets/") and suffix in DATA_SUFFIXES):
            continue
        path = ROOT / name
        if path.is_file():  # a tracked file deleted in the work tree has nothing to check
            files.append(path)
    return files


def lines_of(path: Path) -> list[str]:
    data = path.read_bytes()
    if b"\0" in data[:8192]:
        return []  # binary
    return data.decode("utf-8", errors="replace").splitlines()


def hits(rules: dict[str, re.Pattern[str]], allowed: tuple[str, ...] = ()) -> list[str]:
    found = []
    for path in tracked_text_files():
        name = path.relative_to(ROOT).as_posix()
        for number, line in enumerate(lines_of(path), 1):
            for phrase in allowed:
                line = line.replace(phrase, "")
            if name == EXPERIMENTS:
                line = WHERE_CODE_IS.sub("", line)
            for rule, pattern in rules.items():
                for match in pattern.finditer(line):
                    found.append(f"{name}:{number}: {rule}: {match.group(0)!r}")
    return found


def test_no_references_outside_the_repository():
    found = hits(OUTSIDE)
    assert not found, f"{len(found)} references outside the repository:\n" + "\n".join(found)


def test_no_development_history_wording():
    found = hits(HISTORY, ALLOWED)
    assert not found, f"{len(found)} phrases about how the project was developed:\n" + "\n".join(found)
