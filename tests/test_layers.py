"""The library's layers: no module imports a higher layer, at module level or inside a function; no modules import
each other in a circle; the product never imports the lab (analysis, benchmarks) and the library never imports
the flows. The order: the root helpers → env → logs and rendering → data and planning → models → training →
evaluation → analysis and benchmarks → pipeline."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "dynplan"
#: Subpackage (or top-level module) → layer; a module may import its own layer and those below.
LAYERS = {
    "cli": 0, "config": 0, "extras": 0, "files": 0, "paths": 0, "progress": 0, "version": 0,
    "env": 1,
    "logs": 2, "render": 2,
    "data": 3, "planning": 3, "view": 3,
    "models": 4,
    "training": 5,
    "evaluation": 6,
    "analysis": 7, "bench": 7, "play": 7,
    "pipeline": 8,
}  # fmt: skip


def _imports(path: Path) -> list[tuple[int, str]]:
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found += [(node.lineno, node.module)] + [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
        elif isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
    return found


def _layer(module: str) -> int | None:
    parts = module.split(".")
    return LAYERS.get(parts[1]) if parts[0] == "dynplan" and len(parts) > 1 else None


def test_every_part_of_the_package_has_a_layer():
    parts = {p.stem if p.is_file() else p.name for p in PACKAGE.iterdir() if p.suffix == ".py" or p.is_dir()}
    assert parts - {"__init__", "__pycache__", "weights"} <= set(LAYERS), sorted(parts - set(LAYERS))


def test_no_module_imports_a_higher_layer_or_the_flows():
    wrong = []
    for path in sorted(PACKAGE.rglob("*.py")):
        relative = path.relative_to(PACKAGE.parent)
        if relative == Path("dynplan/__init__.py"):
            continue  # the package's front door re-exports from any layer
        own = LAYERS[relative.parts[1].removesuffix(".py")]
        for line, module in _imports(path):
            if module.split(".")[0] == "flows":
                wrong.append(f"{relative}:{line} imports {module} (the library never imports the flows)")
            elif module == "dynplan":
                wrong.append(f"{relative}:{line} imports the package front door; import the module instead")
            elif (layer := _layer(module)) is not None and layer > own:
                wrong.append(f"{relative}:{line} ({relative.parts[1]}, layer {own}) imports {module} (layer {layer})")
    assert not wrong, "\n".join(wrong)


#: The lab: how the project finds out what to build. Nothing in the product imports it.
LAB = ("analysis", "bench")


def _graph() -> dict[str, set[str]]:
    """Module → the dynplan modules it imports, at module level or inside a function. A package's `__init__`
    (which re-exports) is no node: `from dynplan.models import checkpoint` is an edge to dynplan.models.checkpoint."""
    package = PACKAGE
    files = {p: ".".join(p.relative_to(package.parent).with_suffix("").parts) for p in package.rglob("*.py")
             if p.name != "__init__.py"}  # fmt: skip
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
    wrong = [f"{name} imports {target}" for name, targets in _graph().items() if name.split(".")[1] not in LAB
             for target in targets if target.split(".")[1:2] == [lab]]  # fmt: skip
    assert not wrong, "\n".join(wrong)
