"""The shape of the code and the tree: in the product (all but the lab, `dynplan/analysis` and `dynplan/bench`) no
function is longer than 60 lines; nowhere does one take more than 8 parameters (ruff's PLR0913, which the suite
runs with the rest of the lint and the formatter's check); the docs a newcomer reads stay short; the tracked tree
stays under 32 MB."""

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAB = ("dynplan/analysis", "dynplan/bench")
MAX_LINES = 60


def product_files() -> list[Path]:
    files = [*sorted((ROOT / "dynplan").rglob("*.py")), *sorted((ROOT / "flows").rglob("*.py"))]
    return [p for p in files if not p.relative_to(ROOT).as_posix().startswith(LAB)]


def test_no_product_function_is_longer_than_60_lines():
    long = []
    for path in product_files():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_LINES:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}: {lines} lines")
    assert not long, "\n".join(long)


@pytest.mark.parametrize("command", [["check", "."], ["format", "--check", "."]])
def test_ruff_is_clean(command):
    ruff = shutil.which("ruff") or str(Path(sys.executable).parent / "ruff")
    if not Path(ruff).exists():
        pytest.skip("ruff is not installed (the dev extra has it)")
    proc = subprocess.run([ruff, *command], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-1000:]


#: What a newcomer reads, kept short enough to read: the design record, the experiments, the results page, README.
DOC_LIMITS = {"docs/design.md": 25_000, "docs/experiments.md": 21_000, "docs/results.md": 22_000, "README.md": 12_000}


@pytest.mark.parametrize(("path", "limit"), DOC_LIMITS.items())
def test_the_docs_a_newcomer_reads_stay_short(path, limit):
    assert len((ROOT / path).read_bytes()) <= limit


def test_the_tracked_tree_stays_under_32_mb():
    """Weights of candidates that were not adopted leave the tree (their records stay); the store's rows are compact.
    Each world's adopted weights stay: the road's two configurations and Freeway's (1.3 MB)."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: no list of tracked files")
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    sizes = {name: (ROOT / name).stat().st_size for name in listed.decode().split("\0") if (ROOT / name).is_file()}
    assert sum(sizes.values()) <= 32_000_000, sorted(sizes.items(), key=lambda item: -item[1])[:5]
