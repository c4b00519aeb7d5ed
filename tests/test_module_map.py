"""One module map: each package's docstring names every module of the package, docs/ARCHITECTURE.md's
map names every module too, and the API's table and names are real.

The package docstrings are the source (what each module computes); ARCHITECTURE.md is the overview
that links to them. Read from the source with :mod:`ast`, so a new module without its line fails here.
"""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest

from kpioed_drake import api

PACKAGE = Path(__file__).resolve().parents[1] / "kpioed_drake"
ARCHITECTURE = PACKAGE.parent / "docs" / "ARCHITECTURE.md"


def _packages() -> list[Path]:
    return sorted(p.parent for p in PACKAGE.rglob("__init__.py"))


def _members(pkg: Path) -> list[str]:
    """The package's modules and subpackages (``__main__`` is an entry point, not a module)."""
    mods = [p.stem for p in pkg.glob("*.py") if p.stem not in ("__init__", "__main__")]
    subs = [p.name for p in pkg.iterdir() if (p / "__init__.py").is_file()]
    return sorted(mods + subs)


def _named(name: str, text: str) -> bool:
    return re.search(rf"(?<![\w]){re.escape(name)}(?![\w])", text) is not None


@pytest.mark.parametrize("pkg", _packages(), ids=lambda p: str(p.relative_to(PACKAGE.parent)))
def test_the_package_docstring_names_every_module(pkg):
    doc = ast.get_docstring(ast.parse((pkg / "__init__.py").read_text())) or ""
    missing = [m for m in _members(pkg) if not _named(m, doc)]
    assert not missing, f"{pkg.relative_to(PACKAGE.parent)}/__init__.py's docstring does not name {missing}"


def test_the_architecture_map_names_every_module():
    text = ARCHITECTURE.read_text()
    missing = [
        f"{pkg.relative_to(PACKAGE.parent)}/{m}"
        for pkg in _packages()
        for m in _members(pkg)
        if not _named(m, text)
    ]
    assert not missing, f"docs/ARCHITECTURE.md's module map does not name {missing}"


def test_the_api_table_names_functions_that_exist():
    rows = re.findall(r"^\| ``kpioed (\w+)`` \| :func:`(\w+)` \| (.+?) \|$", api.__doc__, flags=re.MULTILINE)
    assert len(rows) == len(api.__all__)
    for command, function, where in rows:
        assert function in api.__all__, command
        target = re.fullmatch(r":func:`([\w.]+)`", where)
        if where == "here":
            continue
        assert target, f"{command}: {where!r}"
        module, _, name = target.group(1).rpartition(".")
        assert hasattr(importlib.import_module(module), name), f"{command}: {target.group(1)} does not exist"


def test_the_api_names_are_defined_in_the_api():
    """Every name of ``api.__all__`` is a function written in api.py (its signature and docstring are
    the API's), not an alias of a workflow's function."""
    for name in api.__all__:
        assert getattr(api, name).__module__ == "kpioed_drake.api", name
