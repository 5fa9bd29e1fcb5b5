"""The code's shape: in the product (everything but the lab, `dynplan/analysis` and `dynplan/bench`) no function is
longer than 60 lines; nowhere does one take more than 8 parameters (ruff's PLR0913, which the suite runs with the
rest of the lint and the formatter's check)."""

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
