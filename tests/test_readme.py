"""Every snippet of README.md runs as written: its Python blocks, and its shell blocks other than set-up and servers
(which CI, the deployment test and the viewer's browser test run) in a fresh clone of the checkout, which they must
leave clean: no README command writes a tracked file or leaves an output git does not ignore."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
BLOCKS = re.findall(r"```(\w+)\n(.*?)```", README, flags=re.S)
#: Shell blocks these tests leave to others: set-up (CI runs it), long-running servers (the deployment test, the
#: viewer's browser test in tests/test_view.py) and the check of the committed results, which reads the checkout's
#: store (tests/test_committed_results.py runs it).
NOT_HERE = ("pip install", "prefect server", "flows.serve", "flows.view", "--check")


def test_the_readme_is_small_and_has_its_snippets():
    assert len(README.encode()) <= 12_000
    assert [lang for lang, _ in BLOCKS].count("python") >= 1 and any("flows.replay" in b for _, b in BLOCKS)


@pytest.mark.slow
@pytest.mark.parametrize("index", [i for i, (lang, _) in enumerate(BLOCKS) if lang == "python"])
def test_python_snippet_runs(index, tmp_path):
    proc = subprocess.run([sys.executable, "-c", BLOCKS[index][1]], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip(), "a README snippet that prints nothing shows nothing"


@pytest.mark.slow
@pytest.mark.parametrize(
    "index", [i for i, (lang, body) in enumerate(BLOCKS) if lang == "bash" and not any(s in body for s in NOT_HERE)]
)
def test_shell_snippet_runs(index, tmp_path):
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: nothing to clone")
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True, timeout=300)
    for line in BLOCKS[index][1].splitlines():
        command = line.split("#", 1)[0].strip()
        if not command:
            continue
        assert command.startswith(".venv/bin/python -m "), command
        argv = [sys.executable, *command.removeprefix(".venv/bin/python").split()]
        proc = subprocess.run(argv, cwd=clone, capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, f"{command}\n{proc.stderr[-3000:]}"
    status = subprocess.run(["git", "status", "--porcelain"], cwd=clone, capture_output=True, text=True, check=True)
    assert status.stdout == "", f"the README's commands left the checkout changed:\n{status.stdout}"
