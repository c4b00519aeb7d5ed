"""The package's shape (docs/ARCHITECTURE.md): one-way dependencies, small modules, imports at the top,
and no library message that names a command-line option.

Read from the source with :mod:`ast` (the options from the command line's parser), so each test fails
with the offending module and line.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import pytest

from kpioed_drake.cli import build_parser

PACKAGE = Path(__file__).resolve().parents[1] / "kpioed_drake"
MAX_LINES = 500
WORKFLOWS = ("design", "simulation", "calibration", "compensation", "online", "diagnosis", "study")
CORE = ("robot", "tracker", "effects", "estimation")
MAX_ROOT_MODULES = 10
MAX_FOLDER_MODULES = 12
MAX_CODE_LINES = 80  # of one function, docstring, blank and comment lines excluded
MAX_LONG_FUNCTIONS = 3
# A module may import only from its own or a lower rank; the longest matching prefix of its name
# gives its rank (core by concern < workflows < api < cli; inside design: the shared base, the exact
# design, the approximate design and its bound, the entry points, discrimination, the file workflows).
RANK = {
    "errors": 0,
    "outputs": 0,
    "paper": 0,
    "progress": 0,
    "parallel": 0,
    "options": 0,
    "robot": 1,
    "files": 1.5,
    "tracker": 2,
    "effects": 3,
    "estimation": 4,
    "arguments": 4.5,
    "scene3d": 4.5,
    "design.settings": 5.0,
    "design.heuristic": 5.0,
    "design.exact": 5.1,
    "design.approximate": 5.2,
    "design.polish": 5.25,
    "design.starts": 5.25,
    "design.report": 5.3,
    "design.optimize": 5.3,
    "design.discriminate": 5.4,
    "design.target": 5.4,
    "design": 5.6,
    "simulation": 5.8,
    "calibration": 6,
    "compensation": 6.2,
    "online": 6.5,
    "diagnosis": 7,
    "study": 8,
    "api": 9,
    "cli": 10,
}


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


def _rank(module: str) -> float:
    parts = module.split(".")[1:]
    for k in range(len(parts), 0, -1):
        if ".".join(parts[:k]) in RANK:
            return RANK[".".join(parts[:k])]
    return 0


def test_workflows_are_subpackages():
    for name in WORKFLOWS + CORE:
        assert (PACKAGE / name / "__init__.py").is_file(), f"kpioed_drake/{name}/ is not a package"
        assert not (PACKAGE / f"{name}.py").exists(), f"kpioed_drake/{name}.py beside the package"


def _named_modules(package: Path) -> tuple[list[str], list[str]]:
    """(modules and subpackages of ``package``, those its docstring does not name as :mod:`.name`,
    :mod:`~kpioed_drake.pkg.name` or a module inside the subpackage)."""
    doc = ast.get_docstring(ast.parse((package / "__init__.py").read_text())) or ""
    dotted = _module_name(package / "__init__.py")
    names = sorted(
        [p.stem for p in package.glob("*.py") if p.stem not in ("__init__", "__main__")]
        + [p.name for p in package.iterdir() if (p / "__init__.py").is_file()]
    )
    named = re.compile(
        r":mod:`~?(\.|" + re.escape(dotted) + r"\.)(?P<name>\w+)[`.]",
    )
    found = {m.group("name") for m in named.finditer(doc)}
    return names, [n for n in names if n not in found]


@pytest.mark.parametrize(
    "package",
    sorted(
        str(p.parent.relative_to(PACKAGE))
        for name in WORKFLOWS
        for p in (PACKAGE / name).rglob("__init__.py")
    ),
)
def test_workflow_package_docstring_names_its_modules(package):
    """A workflow package's docstring is its map: every module and subpackage is named in it."""
    names, missing = _named_modules(PACKAGE / package)
    assert names and not missing, f"kpioed_drake/{package}/__init__.py does not name {missing}"


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
    tree = ast.parse("import os\n\ndef f():\n    from kpioed_drake.robot import models\n")
    assert _imports(tree, top_only=True) == []
    assert _imports(tree, top_only=False) == [(4, "kpioed_drake.robot.models")]
    assert (
        _rank("kpioed_drake.cli.design")
        > _rank("kpioed_drake.design.exact.solve")
        > _rank("kpioed_drake.robot")
    )
    assert _rank("kpioed_drake.design.optimize") > _rank("kpioed_drake.design.approximate.search")
    assert _rank("kpioed_drake.design.approximate.search") > _rank("kpioed_drake.design.exact.program")
    assert _rank("kpioed_drake.design.exact.program") > _rank("kpioed_drake.design.settings")
    lines = 'def f(x):\n    """Doc."""\n\n    # note\n' + "    x += 1\n" * 81 + "    return x\n"
    assert [n for n, _ in _long_functions({"m": (Path("m.py"), ast.parse(lines))}, {"m": lines})] == [82]


LITERAL_SLICE = re.compile(r"\b(p|std|H|J|JW|dJ|x|Cp|free)\[(([^]]*,) *)?\d+ *: *\d*")


def test_no_literal_slice_of_the_parameter_vector():
    """Index sets of the parameter vector come from parameters.ParameterLayout, never from numbers."""
    assert LITERAL_SLICE.search("p[24:27]") and LITERAL_SLICE.search("H[:, :, 0:24:4]")
    hits = [
        f"{path.relative_to(PACKAGE.parent)}:{k}: {line.strip()}"
        for name, (path, _) in MODULES.items()
        if name != "kpioed_drake.robot.parameters"
        for k, line in enumerate(path.read_text().splitlines(), start=1)
        if LITERAL_SLICE.search(line)
    ]
    assert not hits, "\n".join(hits)


def _folders() -> dict[Path, list[Path]]:
    out: dict[Path, list[Path]] = {}
    for path, _ in MODULES.values():
        out.setdefault(path.parent, []).append(path)
    return out


def test_root_and_folder_sizes():
    """The package root holds a few entry modules; every folder stays small enough to read."""
    folders = _folders()
    root = sorted(p.name for p in folders[PACKAGE])
    assert len(root) <= MAX_ROOT_MODULES, f"{len(root)} modules at the package root: {root}"
    big = {
        str(d.relative_to(PACKAGE.parent)): len(ps)
        for d, ps in folders.items()
        if d != PACKAGE and len(ps) > MAX_FOLDER_MODULES
    }
    assert not big, f"folders over {MAX_FOLDER_MODULES} modules: {big}"


def _code_lines(lines: list[str], node: ast.FunctionDef) -> int:
    body = node.body
    first = body[0]
    doc = (
        isinstance(first, ast.Expr)
        and isinstance(first.value, ast.Constant)
        and isinstance(first.value.value, str)
    )
    if doc and len(body) == 1:
        return 0
    start = body[1].lineno if doc else first.lineno
    return sum(
        1 for line in lines[start - 1 : node.end_lineno] if line.strip() and not line.strip().startswith("#")
    )


def _long_functions(modules, texts) -> list[tuple[int, str]]:
    out = []
    for name, (path, tree) in modules.items():
        lines = texts[name].splitlines()
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = _code_lines(lines, node)
                if n > MAX_CODE_LINES:
                    out.append((n, f"{path}:{node.lineno} {node.name}"))
    return sorted(out, reverse=True)


def test_few_long_functions():
    """Functions are short enough to read at once: at most a few over 80 lines of code."""
    texts = {name: path.read_text() for name, (path, _) in MODULES.items()}
    long = _long_functions(MODULES, texts)
    assert len(long) <= MAX_LONG_FUNCTIONS, f"{len(long)} functions over {MAX_CODE_LINES} lines: {long}"


HISTORY = re.compile(r"\bissues? \d+|#\d+|\b20\d\d-\d\d-\d\d\b|\bbench/\w*results", re.IGNORECASE)
"""An issue number, a date or a benchmark run: history, which belongs in git and docs/, not in the code."""
HISTORY_UNCHECKED: tuple[str, ...] = ()
"""Packages left out of :func:`test_docstrings_and_comments_carry_no_history` (empty when all pass)."""


def _notes(text: str, tree: ast.Module) -> list[tuple[int, str]]:
    """The comments and docstrings (every bare string statement) of a module, with their first line."""
    tokens = tokenize.generate_tokens(io.StringIO(text).readline)
    out = [(t.start[0], t.string) for t in tokens if t.type == tokenize.COMMENT]
    out += [
        (node.lineno, node.value.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Expr)
        and isinstance(node.value, ast.Constant)
        and isinstance(node.value.value, str)
    ]
    return out


def _history(text: str, tree: ast.Module) -> list[tuple[int, str]]:
    """(line, match) of every :data:`HISTORY` match in the module's comments and docstrings."""
    return sorted(
        (line + note[: m.start()].count("\n"), m.group())
        for line, note in _notes(text, tree)
        for m in HISTORY.finditer(note)
    )


def test_docstrings_and_comments_carry_no_history():
    """Docstrings and comments say what a thing is and why; no issue numbers, dates or benchmark runs."""
    hits = [
        f"{path.relative_to(PACKAGE.parent)}:{line}: {what}"
        for name, (path, tree) in MODULES.items()
        if not name.startswith(HISTORY_UNCHECKED)
        for line, what in _history(path.read_text(), tree)
    ]
    assert not hits, "history in docstrings or comments (move it to docs/):\n" + "\n".join(hits)


def test_history_check_can_fail():
    """The check finds each kind of reference in a docstring or a comment, and nothing in plain prose."""
    for sample in (
        "issue 13",
        "see Issue #14",
        "until 2026-12-02",
        "bench/results.md",
        "bench/bound_results.md",
    ):
        assert HISTORY.search(sample), sample
    for sample in (
        "paper eq. 24",
        "# 1e-5 (SNOPT's default 1e-6)",
        'issue "model discrepancy"',
        "2026 poses",
    ):
        assert not HISTORY.search(sample), sample
    text = (
        '"""A module (issue 13)."""\n\nX = 1\n"""Set on\n2026-12-02 (bench/results.md)."""\n'
        'Y = "issue 14"  # not a note: a string in code\n\n\ndef f():\n    return X  # see #15\n'
    )
    found = _history(text, ast.parse(text))
    assert found == [(1, "issue 13"), (5, "2026-12-02"), (5, "bench/results"), (10, "#15")]


def _option_strings() -> set[str]:
    """Every option string of the ``kpioed`` parser and of its subcommands (``--sigma-mm``, ...)."""
    out: set[str] = set()
    parsers = [build_parser()]
    while parsers:
        parser = parsers.pop()
        for action in parser._actions:
            out.update(action.option_strings)
            if isinstance(action.choices, dict):  # the subcommands
                parsers += [p for p in action.choices.values() if hasattr(p, "_actions")]
    return out


def _docstring_nodes(tree: ast.Module) -> set[int]:
    """ids of the string constants that stand alone as statements: docstrings of modules, classes,
    functions and attributes."""
    return {
        id(node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Expr)
        and isinstance(node.value, ast.Constant)
        and isinstance(node.value.value, str)
    }


def _options_named(tree: ast.Module, options: set[str]) -> list[tuple[int, str]]:
    """(line, option) of each string constant that is not a docstring and names an option as a whole
    word (not ``--n`` in ``--no-certify``)."""
    words = re.compile(
        r"(?<![\w-])(" + "|".join(sorted(map(re.escape, options), key=len, reverse=True)) + r")(?![\w-])"
    )
    docs = _docstring_nodes(tree)
    return [
        (node.lineno, m.group(1))
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs
        for m in words.finditer(node.value)
    ]


def test_no_library_string_names_an_option():
    """Only the command line names its options; the library names the API's parameters
    (``InputError(fields=...)``, :func:`kpioed_drake.errors.param`)."""
    options = _option_strings()
    assert {"--sigma-mm", "--force", "--target-var", "--q-work", "--n"} <= options
    hits = [
        f"{path.relative_to(PACKAGE.parent)}:{line}: {option}"
        for name, (path, tree) in MODULES.items()
        if not (name == "kpioed_drake.cli" or name.startswith("kpioed_drake.cli."))
        for line, option in _options_named(tree, options)
    ]
    assert not hits, "\n".join(hits)


def test_option_scanner_sees_an_option_in_a_message():
    """The scan above can fail: a message naming ``--sigma-mm`` is found, its docstring and
    ``--no-certify`` (not ``--n``) are not."""
    tree = ast.parse(
        '"""Run with ``--sigma-mm``."""\n\n'
        "def f(x):\n"
        '    """Uses --n."""\n'
        '    raise ValueError(f"--sigma-mm must be positive, got {x}; --no-certify")\n'
    )
    assert _options_named(tree, {"--sigma-mm", "--n", "--no-certify"}) == [
        (5, "--sigma-mm"),
        (5, "--no-certify"),
    ]
