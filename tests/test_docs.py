"""The README and the guides in docs/: sizes, no history words, links that resolve, shell blocks that run.

The README's shell blocks are run as written, in order, in a fresh copy of the repository. The
copy's `.venv` stands in for `make setup` (which needs the network): its `python` and `kpioed` are
this interpreter with the copy's package first on the path, and its install stamp is up to date, so
`make setup` and `make demo` run as on a machine where the setup has been done. Quick blocks (every
command a `kpioed info`) run in the default set; the whole README, `make demo` and the walk-through
included, in the slow set.
"""

import os
import re
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
GUIDES = sorted((ROOT / "docs").glob("*.md"))

HISTORY = {
    "an issue number": re.compile(r"\bissues? \d+|#\d+", re.IGNORECASE),
    "a date": re.compile(r"\b\d{4}-\d{2}-\d{2}\b"),
    '"since"': re.compile(r"\bsince\b", re.IGNORECASE),
    '"was <number>"': re.compile(r"\bwas \d", re.IGNORECASE),
}
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
BLOCK = re.compile(r"^```(?:bash|sh|shell)\n(.*?)^```", re.MULTILINE | re.DOTALL)


def _commands(block: str) -> list[str]:
    """The command lines of a shell block (continuations joined, comments and blanks dropped)."""
    text = block.replace("\\\n", " ")
    lines = [line.split("  #")[0].strip() for line in text.splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


def _blocks() -> list[str]:
    return BLOCK.findall(README.read_text())


def _is_quick(block: str) -> bool:
    return all(command.startswith("kpioed info ") for command in _commands(block))


def test_sizes():
    n_readme = len(README.read_text().splitlines())
    assert n_readme <= 300, f"README.md has {n_readme} lines (at most 300)"
    for guide in GUIDES:
        n = len(guide.read_text().splitlines())
        assert n <= 500, f"{guide.relative_to(ROOT)} has {n} lines (at most 500)"


def test_readme_starts_with_the_two_commands():
    head = "\n".join(README.read_text().splitlines()[:40])
    assert "make demo" in head and "make test" in head
    assert "make test" in (ROOT / ".ci" / "run").read_text()


def test_no_history_words():
    found = []
    for path in [README, *GUIDES]:
        for number, line in enumerate(path.read_text().splitlines(), start=1):
            for what, pattern in HISTORY.items():
                if pattern.search(line):
                    found.append(f"{path.relative_to(ROOT)}:{number}: {what}: {line.strip()[:90]}")
    assert not found, "history belongs in bench/ or studies/results/:\n" + "\n".join(found)


def test_relative_links_resolve():
    broken = []
    for path in [README, *GUIDES]:
        for target in LINK.findall(path.read_text()):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            file = target.split("#")[0]
            if not (path.parent / file).exists():
                broken.append(f"{path.relative_to(ROOT)}: {target}")
    assert not broken, "links to files that do not exist:\n" + "\n".join(broken)


def test_every_block_is_classified():
    blocks = _blocks()
    assert len(blocks) >= 3
    assert any(_is_quick(b) for b in blocks), "no quick block left for the default run"
    assert all(_commands(b) for b in blocks), "an empty shell block"


def _fresh_copy(tmp_path: Path) -> Path:
    """The repository's files (tracked and new, not ignored) in tmp_path/repo, as after `make setup`."""
    listed = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
        cwd=ROOT,
        check=True,
        capture_output=True,
    ).stdout.decode()
    repo = tmp_path / "repo"
    for name in filter(None, listed.split("\0")):
        source = ROOT / name
        if source.is_file():
            (repo / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, repo / name)
    bin_dir = repo / ".venv" / "bin"
    bin_dir.mkdir(parents=True)
    scripts = {
        "python": f'PYTHONPATH="{repo}" exec "{sys.executable}" "$@"\n',
        "kpioed": f'PYTHONPATH="{repo}" exec "{sys.executable}" -m kpioed_drake.cli "$@"\n',
    }
    for name, body in scripts.items():
        (bin_dir / name).write_text("#!/bin/sh\n" + body)
        (bin_dir / name).chmod(stat.S_IRWXU)
    (bin_dir / "activate").write_text(f'export PATH="{bin_dir}:$PATH"\n')
    stamp = repo / ".venv" / ".installed-stamp"
    stamp.touch()
    later = (repo / "pyproject.toml").stat().st_mtime + 60
    os.utime(stamp, (later, later))
    return repo


def _script(blocks: list[str]) -> str:
    """One bash script of the blocks, in order; `make test` is checked with a dry run (it is this suite)."""
    lines = ["set -euo pipefail"]
    for block in blocks:
        for command in _commands(block):
            lines.append("make -n test >/dev/null" if command == "make test" else command)
    return "\n".join(lines) + "\n"


def _run(repo: Path, script: str, timeout: float) -> None:
    env = {**os.environ, "PATH": f"{repo / '.venv' / 'bin'}:{os.environ['PATH']}"}
    env.pop("PYTHONPATH", None)
    result = subprocess.run(
        ["bash", "-c", script], cwd=repo, env=env, capture_output=True, text=True, timeout=timeout
    )
    assert result.returncode == 0, (
        f"README shell commands failed (status {result.returncode}):\n{script}\n"
        f"--- stdout ---\n{result.stdout[-3000:]}\n--- stderr ---\n{result.stderr[-3000:]}"
    )


def test_quick_readme_blocks_run(tmp_path):
    quick = [b for b in _blocks() if _is_quick(b)]
    _run(_fresh_copy(tmp_path), _script(quick), timeout=120)


@pytest.mark.slow
def test_every_readme_block_runs_in_order(tmp_path):
    repo = _fresh_copy(tmp_path)
    _run(repo, _script(_blocks()), timeout=2400)
    assert (repo / "out" / "demo" / "kr16-kpi-design.csv").exists()
