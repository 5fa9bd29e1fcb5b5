"""The library's layers: no module imports a higher layer, at module level or inside a function; no modules import
each other in a circle; the product (`dynplan/` and `flows/`) never imports the lab (`lab/`, `dynplan/bench/`) and
the library never imports the flows. The order: the root helpers → env → logs and rendering → data and planning →
models → training → evaluation → benchmarks → pipeline → the worlds' packages → the lab. The registry of worlds
(`dynplan.world`, and the types of `dynplan.world_parts`) sits with the environment: every layer may look
a world up, and a world's package, which may import every layer, is imported only through the registry."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "dynplan"
#: The lab's analysis and validation runs: a top-level package beside the installed one, above every layer.
LAB_PACKAGE = ROOT / "lab"
#: Subpackage (or top-level module) → layer; a module may import its own layer and those below.
LAYERS = {
    "arguments": 0, "cli": 0, "config": 0, "extras": 0, "files": 0, "interrupts": 0, "lazy": 0, "paths": 0,
    "progress": 0, "version": 0,
    "env": 1,
    "logs": 2, "render": 2,
    "data": 3, "planning": 3, "view": 3,
    "models": 4,
    "training": 5,
    "evaluation": 6,
    "bench": 7,
    "pipeline": 8,
    "world": 1, "world_parts": 1,
    "worlds": 9, "worlds.road": 9, "worlds.freeway": 9,
}  # fmt: skip
LAB_LAYER = 10


def _imports(path: Path) -> list[tuple[int, str]]:
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found += [(node.lineno, node.module)] + [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
        elif isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
    return found


def _name(parts: tuple[str, ...] | list[str]) -> str:
    """The part of the package a module belongs to, from its dotted path's parts after `dynplan`: a subpackage or
    top-level module, or a world's package (`worlds.freeway`)."""
    nested = ".".join(parts[:2]).removesuffix(".py")
    return nested if nested in LAYERS else parts[0].removesuffix(".py")


def _layer(module: str) -> int | None:
    parts = module.split(".")
    return LAYERS.get(_name(parts[1:])) if parts[0] == "dynplan" and len(parts) > 1 else None


def _part(relative: Path) -> tuple[str, int]:
    """A file's part of the code (`lab`, or its part of dynplan) and its layer."""
    if relative.parts[0] == "lab":
        return "lab", LAB_LAYER
    part = _name(relative.parts[1:])
    return part, LAYERS[part]


def _files() -> list[Path]:
    return [*sorted(PACKAGE.rglob("*.py")), *sorted(LAB_PACKAGE.rglob("*.py"))]


def test_every_part_of_the_package_has_a_layer():
    # a folder without a Python file (only caches left in it) is no part
    parts = {p.stem if p.is_file() else p.name for p in PACKAGE.iterdir()
             if p.suffix == ".py" or (p.is_dir() and any(p.rglob("*.py")))}  # fmt: skip
    assert parts - {"__init__", "__pycache__", "weights"} <= set(LAYERS), sorted(parts - set(LAYERS))


def test_no_module_imports_a_higher_layer_or_the_flows():
    wrong = []
    for path in _files():
        relative = path.relative_to(ROOT)
        if relative == Path("dynplan/__init__.py"):
            continue  # the package's front door re-exports from any layer
        part, own = _part(relative)
        for line, module in _imports(path):
            if module.split(".")[0] == "flows":
                wrong.append(f"{relative}:{line} imports {module} (the library never imports the flows)")
            elif module == "dynplan":
                wrong.append(f"{relative}:{line} imports the package front door; import the module instead")
            elif (layer := _layer(module)) is not None and layer > own:
                wrong.append(f"{relative}:{line} ({part}, layer {own}) imports {module} (layer {layer})")
    assert not wrong, "\n".join(wrong)


#: The lab: how the project finds out what to build. Nothing in the product imports it; a world's benchmarks
#: (`dynplan/worlds/<world>/bench.py`) are the lab's too.
LAB = ("lab", "dynplan.bench")


def _world_bench(path: Path) -> bool:
    return path.match("dynplan/worlds/*/bench.py")


def _graph() -> dict[str, set[str]]:
    """Module → the dynplan and lab modules it imports, at module level or inside a function. A package's `__init__`
    (which re-exports) is no node: `from dynplan.models import checkpoint` is an edge to dynplan.models.checkpoint."""
    files = {p: ".".join(p.relative_to(ROOT).with_suffix("").parts) for p in _files() if p.name != "__init__.py"}
    modules = set(files.values())
    return {name: {m for _, m in _imports(path) if m in modules and m != name} for path, name in files.items()}


def test_no_import_circle():
    graph, state, circles = _graph(), {}, []

    def visit(node: str, path: list[str]) -> None:
        state[node] = "open"
        for target in sorted(graph.get(node, ())):
            if state.get(target) == "open":
                circles.append(" → ".join([*path[path.index(target) :], target]))
            elif target not in state:
                visit(target, [*path, target])
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert not circles, "\n".join(circles)


@pytest.mark.parametrize("lab", LAB)
def test_the_product_never_imports_the_lab(lab):
    """No file of dynplan/ or flows/ outside the lab imports it, its `__init__` files included."""
    code = [*PACKAGE.rglob("*.py"), *(ROOT / "flows").rglob("*.py")]
    product = [p for p in code if p.relative_to(ROOT).parts[:2] != ("dynplan", "bench") and not _world_bench(p)]
    wrong = [f"{path.relative_to(ROOT)}:{line} imports {module}" for path in sorted(product)
             for line, module in _imports(path) if module == lab or module.startswith(lab + ".")]  # fmt: skip
    assert not wrong, "\n".join(wrong)
