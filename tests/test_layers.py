"""Every import in torchik points one way: down the layers, and never round in a circle.

Layers, bottom up: errors and `torchik/data/` (the package's version and files); the method
(`torchik/method/`); data (`torchik/io/`, `torchik/synthetic/`, the live sources `torchik/live/`);
pipelines (`torchik/pipelines/`); the command line (`torchik/cli/`); the package's root API
(`torchik/__init__.py`, `__main__.py`). Read from the source with `ast`, imports inside functions
included: a lazy import is still a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "torchik"
LAYERS = {"errors": 0, "data": 0, "method": 1, "io": 2, "synthetic": 2, "live": 2, "pipelines": 3, "cli": 4}
ROOT_LAYER = 5


def module_name(path: Path) -> str:
    parts = ("torchik",) + path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def layer(module: str) -> int:
    parts = module.split(".")
    return LAYERS[parts[1]] if len(parts) > 1 and parts[1] in LAYERS else ROOT_LAYER


def imports(module: str) -> list[tuple[str, int]]:
    """The torchik modules `module` imports, with the line of each import."""
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names if alias.name.split(".")[0] == "torchik"]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "torchik":
                continue
            # `from package import submodule` depends on the submodule, not on the package's __init__
            subs = [f"{target}.{alias.name}" for alias in node.names if f"{target}.{alias.name}" in MODULES]
            found += [(name, node.lineno) for name in subs] if len(subs) == len(node.names) else [(target, node.lineno)]
    return [(name, line) for name, line in found if name in MODULES]


def test_no_import_reaches_up_a_layer():
    upward = [f"{MODULES[m].relative_to(PACKAGE.parent)}:{line} imports {target} (layer {layer(target)} above "
              f"layer {layer(m)})" for m in MODULES for target, line in imports(m) if layer(target) > layer(m)]
    assert not upward, "\n".join(upward)


def test_no_import_cycle():
    graph = {m: sorted({t for t, _ in imports(m) if t != m}) for m in MODULES}
    cycles, state = [], {}

    def visit(node: str, path: list[str]) -> None:  # depth-first search; grey nodes are on the path
        state[node] = "grey"
        for nxt in graph[node]:
            if state.get(nxt) == "grey":
                cycles.append(" -> ".join(path[path.index(nxt):] + [node, nxt]) if nxt in path else f"{node} -> {nxt}")
            elif nxt not in state:
                visit(nxt, path + [node])
        state[node] = "black"

    for module in graph:
        if module not in state:
            visit(module, [])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_the_layer_map_covers_every_folder():
    folders = {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert folders <= set(LAYERS), f"folders without a layer: {folders - set(LAYERS)}"
