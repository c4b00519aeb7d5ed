"""The package's shape (docs/ARCHITECTURE.md): one-way dependencies, small modules, imports at the top.

Read from the source with :mod:`ast`, so each test fails with the offending module and line.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "kpioed_drake"
MAX_LINES = 500
WORKFLOWS = ("design", "calibration", "diagnosis", "study")
# A module may import only from its own or a lower rank (flat core < workflows < api < cli).
RANK = {"design": 1, "calibration": 2, "diagnosis": 3, "study": 4, "api": 5, "cli": 6}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, tuple[Path, ast.Module]]:
    return {_module_name(p): (p, ast.parse(p.read_text(), str(p))) for p in sorted(PACKAGE.rglob("*.py"))}


MODULES = _modules()


def _resolve(name: str) -> str:
    """The module an import names (``from pkg import sub`` may name a submodule)."""
    while name not in MODULES and "." in name:
        name = name.rsplit(".", 1)[0]
    return name


def _imports(tree: ast.Module, *, top_only: bool) -> list[tuple[int, str]]:
    out = []
    nodes = tree.body if top_only else ast.walk(tree)
    for node in nodes:
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("kpioed_drake"):
            for alias in node.names:
                full = f"{node.module}.{alias.name}"
                out.append((node.lineno, full if full in MODULES else _resolve(node.module)))
        elif isinstance(node, ast.Import):
            out += [(node.lineno, _resolve(a.name)) for a in node.names if a.name.startswith("kpioed_drake")]
    return out


def _rank(module: str) -> int:
    parts = module.split(".")
    return RANK.get(parts[1], 0) if len(parts) > 1 else 0


def test_workflows_are_subpackages():
    for name in WORKFLOWS:
        assert (PACKAGE / name / "__init__.py").is_file(), f"kpioed_drake/{name}/ is not a package"
        assert not (PACKAGE / f"{name}.py").exists(), f"kpioed_drake/{name}.py beside the package"


@pytest.mark.parametrize("module", sorted(MODULES))
def test_module_size(module):
    path, _ = MODULES[module]
    n = len(path.read_text().splitlines())
    assert n <= MAX_LINES, f"{path.relative_to(PACKAGE.parent)}: {n} lines > {MAX_LINES}"


@pytest.mark.parametrize("module", sorted(MODULES))
def test_own_imports_at_module_top(module):
    path, tree = MODULES[module]
    top = {line for line, _ in _imports(tree, top_only=True)}
    inner = [line for line, _ in _imports(tree, top_only=False) if line not in top]
    assert not inner, (
        f"{path.relative_to(PACKAGE.parent)}: own-module imports inside functions at lines {inner}"
    )


@pytest.mark.parametrize("module", sorted(MODULES))
def test_dependencies_point_down(module):
    path, tree = MODULES[module]
    up = [(line, dep) for line, dep in _imports(tree, top_only=False) if _rank(dep) > _rank(module)]
    assert not up, f"{path.relative_to(PACKAGE.parent)} imports a higher layer: {up}"


def test_no_import_cycle():
    graph = {
        m: sorted({d for _, d in _imports(t, top_only=False) if d != m}) for m, (_, t) in MODULES.items()
    }
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for d in graph.get(m, ()):
            if state.get(d) == 1:
                cycle = stack[stack.index(d) :] + [d]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


def test_checker_sees_a_cycle_and_a_late_import():
    """The checks above can fail: a synthetic late import and a synthetic cycle are found."""
    tree = ast.parse("import os\n\ndef f():\n    from kpioed_drake import models\n")
    assert _imports(tree, top_only=True) == []
    assert _imports(tree, top_only=False) == [(4, "kpioed_drake.models")]
    assert (
        _rank("kpioed_drake.cli.design") > _rank("kpioed_drake.design.solve") > _rank("kpioed_drake.models")
    )


LITERAL_SLICE = re.compile(r"\b(p|std|H|J|JW|dJ|x|Cp|free)\[(([^]]*,) *)?\d+ *: *\d*")


def test_no_literal_slice_of_the_parameter_vector():
    """Index sets of the parameter vector come from parameters.ParameterLayout, never from numbers."""
    assert LITERAL_SLICE.search("p[24:27]") and LITERAL_SLICE.search("H[:, :, 0:24:4]")
    hits = [
        f"{path.relative_to(PACKAGE.parent)}:{k}: {line.strip()}"
        for name, (path, _) in MODULES.items()
        if name != "kpioed_drake.parameters"
        for k, line in enumerate(path.read_text().splitlines(), start=1)
        if LITERAL_SLICE.search(line)
    ]
    assert not hits, "\n".join(hits)
