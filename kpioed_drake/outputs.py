"""Writing results: atomically, with the user's umask, only after everything succeeded.

- :func:`atomic_write_text` / :func:`atomic_write_bytes` / :func:`atomic_write_json`: a temporary
  file in the target's folder, then ``os.replace``; a reader never sees half a file. A new file gets
  the permissions of the user's umask, an existing file keeps its own; an output that is a symbolic
  link is written through (the file it points to is replaced, the link stays).
- :func:`check_output_paths`: refuses, before any work, an output that would overwrite an input,
  names a folder, is named twice, is an empty string or cannot be written (its folder is
  read-only or no folder), and a plots folder that is a file.
- :class:`Outputs`: a command stages its files (text, JSON, picture folders) while it works and writes
  them all at the end with :meth:`Outputs.commit`; a command that fails on the way writes nothing.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from kpioed_drake.errors import InputError


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _target(path: str | Path) -> Path:
    path = Path(path)
    if path.is_symlink():
        path = Path(os.path.realpath(path))
    if path.is_dir():
        raise InputError(f"{path}: is a folder; expected a file name")
    return path


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder, then rename)."""
    path = _target(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    mode = (path.stat().st_mode & 0o7777) if path.exists() else (0o666 & ~_umask())
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:  # named after the user's file, not the temporary one
        raise OSError(exc.errno, exc.strerror, str(path)) from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def jsonable(obj: Any) -> Any:
    """``obj`` as plain JSON data: numpy arrays and scalars to Python, NaN/inf to None, keys to str.

    JSON has no NaN; every result record of the package goes through this one function.
    """
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return jsonable(obj.item())
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def json_text(data: Any) -> str:
    """``data`` as indented JSON text with a final newline."""
    return json.dumps(data, indent=2, default=_json_default) + "\n"


def atomic_write_json(path: str | Path, data: Any) -> None:
    """Write ``data`` as indented JSON to ``path`` atomically."""
    atomic_write_text(path, json_text(data))


def _same(a: str | Path, b: str | Path) -> bool:
    return os.path.realpath(a) == os.path.realpath(b)


def check_output_paths(
    *,
    inputs: Sequence[str | Path | None] = (),
    outputs: Sequence[str | Path | None] = (),
    folders: Sequence[str | Path | None] = (),
    suffixes: dict | None = None,
) -> None:
    """Refuse output paths that cannot be right, before any work is done.

    Args:
        inputs: paths the command reads (None entries are ignored).
        outputs: file paths the command writes (None and ``"-"`` ignored).
        folders: folder paths the command writes into (None ignored).
        suffixes: ``{path: (".png", ...)}`` allowed endings for some outputs.

    Raises:
        InputError: an output equals an input or another output, is a folder, lies below a file,
            is an empty string or cannot be written; a folder is a file; an ending not allowed.
    """
    ins = [p for p in inputs if p]
    for p in [*outputs, *folders]:
        if p is not None and not str(p).strip():
            raise InputError(f"output {str(p)!r}: expected a file or folder name, got an empty string")
    seen: list[str | Path] = []
    for p in [o for o in outputs if o and o != "-"] + [f for f in folders if f]:
        for i in ins:
            if _same(p, i):
                raise InputError(f"{p}: this output would overwrite the input {i}; choose another name")
        for s in seen:
            if _same(p, s):
                raise InputError(f"{p}: named twice as an output")
        seen.append(p)
        parent = Path(os.path.realpath(p)).parent
        while not parent.exists():
            parent = parent.parent
        if not parent.is_dir():
            raise InputError(f"{p}: cannot be created: {parent} is a file, not a folder")
        own = Path(os.path.realpath(p))
        _check_writable(p, own if p in folders and own.is_dir() else parent)  # a folder's files go into it
    for p in [o for o in outputs if o and o != "-"]:
        if Path(p).is_dir():
            raise InputError(f"{p}: is a folder; expected a file name")
        allowed = (suffixes or {}).get(p)
        if allowed and Path(p).suffix.lower() not in allowed:
            raise InputError(f"{p}: expected a file name ending in {', '.join(allowed)}")
    for f in folders:
        if f and Path(f).exists() and not Path(f).is_dir():
            raise InputError(f"{f}: is a file; expected a folder")


def _check_writable(path, folder: Path) -> None:
    """A file can be created in ``folder`` (the nearest existing folder of the output ``path``): a
    probe file made and removed at once, as only trying tells (a read-only file system, a virtual
    one such as /proc, permissions; the root user passes every permission test)."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".kpioed-probe.", dir=folder)
    except OSError as exc:
        raise InputError(f"{path}: cannot be written: {exc.strerror or exc} (in {folder})") from None
    os.close(fd)
    os.unlink(probe)


def pyplot() -> ModuleType:
    """matplotlib's ``pyplot`` with the Agg backend (pictures to files, no display).

    The backend is selected on first use, before ``pyplot`` is imported, so that importing a
    module that can draw stays cheap; every picture of the package goes through this function.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


class Outputs:
    """Files staged by a command and written together at the end.

    ``add_text``/``add_json``/``add_bytes`` keep the content in memory; :meth:`folder` gives a
    temporary folder (beside the destination) that picture writers fill. :meth:`commit` writes every
    file atomically and moves the staged folders' files into place; used as a context manager, the
    temporary folders are removed whatever happens, so a command that fails writes nothing.
    """

    def __init__(self) -> None:
        self._files: list[tuple[Path, bytes]] = []
        self._folders: list[tuple[Path, Path]] = []

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, *exc) -> None:
        for _, tmp in self._folders:
            shutil.rmtree(tmp, ignore_errors=True)

    def add_bytes(self, path: str | Path, data: bytes) -> None:
        self._files.append((Path(path), data))

    def add_text(self, path: str | Path, text: str) -> None:
        self.add_bytes(path, text.encode("utf-8"))

    def add_json(self, path: str | Path, data: Any) -> None:
        self.add_text(path, json_text(data))

    def folder(self, dest: str | Path) -> Path:
        """A temporary folder whose files :meth:`commit` moves into ``dest``."""
        dest = Path(dest)
        anchor = dest.resolve()
        while not anchor.is_dir():  # the nearest existing folder: same file system, nothing created
            anchor = anchor.parent
        tmp = Path(tempfile.mkdtemp(prefix=".kpioed-staged.", dir=anchor))
        self._folders.append((dest, tmp))
        return tmp

    def commit(self) -> list[Path]:
        """Write every staged file atomically and move the staged folders' files; returns the paths."""
        written = []
        for path, data in self._files:
            atomic_write_bytes(path, data)
            written.append(path)
        mode = 0o666 & ~_umask()
        for dest, tmp in self._folders:
            dest.mkdir(parents=True, exist_ok=True)
            for f in sorted(tmp.iterdir()):
                os.chmod(f, mode)
                os.replace(f, dest / f.name)
                written.append(dest / f.name)
        return written
