"""The shape of the code and the tree: in the product (all but the lab, `lab/` and `dynplan/bench/`) no function is
longer than 60 lines as the formatter lays it out (it lays out all but ≤ 30 aligned tables); nowhere does one take
more than 8 parameters (ruff's PLR0913, which the suite runs with the rest of the lint and the formatter's check);
the docs a newcomer reads stay short; the tracked tree stays under 32 MB; the wheel holds the product and not the
lab."""

import ast
import shutil
import subprocess
import sys
import zipfile
from importlib import metadata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAB = ("lab", "dynplan/bench")
MAX_LINES = 60


def product_files() -> list[Path]:
    files = [*sorted((ROOT / "dynplan").rglob("*.py")), *sorted((ROOT / "flows").rglob("*.py"))]
    lab = [p for p in files if p.relative_to(ROOT).as_posix().startswith(LAB) or p.match("dynplan/worlds/*/bench.py")]
    return [p for p in files if p not in lab]


def test_no_product_function_is_longer_than_60_lines():
    long = []
    for path in product_files():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_LINES:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}: {lines} lines")
    assert not long, "\n".join(long)


def test_the_formatter_lays_out_the_product():
    """`# fmt: skip` only for aligned tables: at most 30 in `dynplan/` and `flows/`."""
    files = [*(ROOT / "dynplan").rglob("*.py"), *(ROOT / "flows").rglob("*.py")]
    skipped = [f"{p.relative_to(ROOT)}" for p in files for line in p.read_text().splitlines() if "# fmt: skip" in line]
    assert len(skipped) <= 30, f"{len(skipped)} lines keep the formatter out: {sorted(set(skipped))}"


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


def _setuptools_builds_wheels() -> bool:
    """Whether this environment's setuptools builds a wheel by itself (bdist_wheel is part of setuptools ≥ 70.1)."""
    try:
        version = tuple(int(part) for part in metadata.version("setuptools").split(".")[:2])
    except (metadata.PackageNotFoundError, ValueError):
        return False
    return version >= (70, 1)


def test_the_wheel_holds_the_product_and_not_the_lab(tmp_path):
    """The lab lives at the top level (`lab/`), and the wheel that `pip` builds from a copy of the tree (so that no
    build folder of the checkout leaks into it) has dynplan and flows, nothing of `lab/` (its modules, its runs)
    and no `dynplan/analysis`."""
    assert not list((ROOT / "dynplan" / "analysis").rglob("*.py")) and (ROOT / "lab" / "__init__.py").is_file()
    source = tmp_path / "source"
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "build")
    for name in ("dynplan", "flows", "lab"):
        shutil.copytree(ROOT / name, source / name, ignore=ignore)
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, source / name)
    isolation = ["--no-build-isolation"] if _setuptools_builds_wheels() else []  # else pip fetches setuptools
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", *isolation, "-q",
                           "-w", str(tmp_path / "wheels")], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    (wheel,) = (tmp_path / "wheels").glob("dynplan-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert {"dynplan/__init__.py", "flows/__init__.py"} <= set(names)
    lab = [n for n in names if n.startswith(("lab/", "dynplan/analysis/")) or n.endswith("episodes.jsonl")]
    assert not lab, lab[:5]  # no lab module and no run of a results store (the lab's are in lab/results/)
