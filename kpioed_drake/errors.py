"""Error types shown to users, the command line's exit statuses, and the interrupt flag.

Every error a user can cause by bad input is an :class:`InputError`; the command line prints its
message on one line and exits with status 2 (:data:`EXIT_INPUT`). A solver failure or an infeasible
result exits with 3 (:data:`EXIT_SOLVER`), an interrupt (Ctrl-C) with 130. Anything else is a bug:
one line and status 1, the traceback with ``kpioed --debug``.

Messages name the Python API's parameters (``sigma_mm``), never a command-line option: an
:class:`InputError` lists the parameters it names in ``fields``, and the command line shows each as
its option (``--sigma-mm``). Text that is not an error (a report's warnings and advice) names a
parameter through :func:`param`, which gives the option while the command line runs a command
(:func:`param_names`).

Drake calls our cost and constraint functions from inside SNOPT/IPOPT; a ``KeyboardInterrupt``
raised there is turned into a failed solve by the solver. :func:`interrupted` lets long loops (solve
starts, study tasks) notice that the user pressed Ctrl-C and stop instead of going on.
"""

from __future__ import annotations

import contextlib
import contextvars
import math
import numbers
import os
import re
import signal
import sys
import threading
import types
from collections.abc import Iterable, Iterator, Mapping

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_INPUT = 2
EXIT_SOLVER = 3
EXIT_INTERRUPTED = 130


class InputError(ValueError):
    """Bad input: an unknown robot, a malformed file, an impossible setting.

    The message names the file, row or field and says what was expected. ``fields`` are the API
    parameters it names (``("sigma_mm",)``), each written as a word of its own and only where it
    means the parameter: the command line replaces those words by the options
    (:func:`name_fields`).
    """

    def __init__(self, message: str = "", *, fields: Iterable[str] = ()):
        super().__init__(message)
        self.fields: tuple[str, ...] = tuple(fields)


class SolverError(RuntimeError):
    """A solver failed or every attempt ended infeasible: not the user's input (exit status 3).

    ``fields``: the API parameters the message names, as for :class:`InputError`.
    """

    def __init__(self, message: str = "", *, fields: Iterable[str] = ()):
        super().__init__(message)
        self.fields: tuple[str, ...] = tuple(fields)


def check_sigma(sigma_mm: object, *, zero_ok: bool = False, allow_none: bool = False) -> float | None:
    """The noise standard deviation per coordinate [mm] as a float: a finite number > 0 (>= 0 with
    ``zero_ok``: noise-free simulated data; None with ``allow_none``: the cell's); else InputError
    naming ``sigma_mm``."""
    if sigma_mm is None and allow_none:
        return None
    number = isinstance(sigma_mm, numbers.Real) and not isinstance(sigma_mm, bool)
    value = float(sigma_mm) if number else math.nan
    if not (math.isfinite(value) and (value >= 0 if zero_ok else value > 0)):
        what = "non-negative" if zero_ok else "positive"
        raise InputError(
            f"sigma_mm must be a {what} number of millimetres, got {sigma_mm!r}", fields=("sigma_mm",)
        )
    return value


_PARAM_NAMES: contextvars.ContextVar[Mapping[str, str]] = contextvars.ContextVar(
    "names", default=types.MappingProxyType({})
)
"""API parameter -> the name :func:`param` gives (empty: the API's own names)."""


def param(field: str) -> str:
    """How the user calls the API parameter ``field``: its name, or the option of the running command
    (:func:`param_names`), for text that is not an error (a warning, a report's advice)."""
    return _PARAM_NAMES.get().get(field, field)


@contextlib.contextmanager
def param_names(names: Mapping[str, str]) -> Iterator[None]:
    """Within the block, :func:`param` gives ``names[field]`` (API parameter -> option string)."""
    token = _PARAM_NAMES.set(types.MappingProxyType(dict(names)))
    try:
        yield
    finally:
        _PARAM_NAMES.reset(token)


def name_fields(text: str, fields: Iterable[str], names: Mapping[str, str]) -> str:
    """``text`` with every word that is one of ``fields`` replaced by its name in ``names`` (kept where
    ``names`` has none); a word is delimited by anything but letters, digits, ``_`` and ``-`` (and is
    no file name's stem or extension: ``out.csv``, ``a.out``). Kept as they are: text in backticks (a
    command such as `dask scheduler`), a quoted value without spaces (``'out'``), and a path
    (``out/try.yaml``, ``/tmp/out``: a token starting with ``/``, ``~`` or ``.``, or holding a ``/``
    and a ``.``)."""
    words = [f for f in fields if f in names]
    if not words:
        return text
    word = re.compile(r"(?<![\w.-])(" + "|".join(map(re.escape, words)) + r")(?![\w-]|\.\w)")

    def token(m: re.Match) -> str:
        t = m.group()
        if t.startswith(("/", "~", ".")) or ("/" in t and "." in t):
            return t
        return word.sub(lambda w: names[w.group(1)], t)

    parts = re.split(r"(`[^`]*`|(?<!\w)'[^'\s]*'(?!\w))", text)  # odd parts: quoted
    return "".join(p if k % 2 else re.sub(r"\S+", token, p) for k, p in enumerate(parts))


_INTERRUPTED = threading.Event()


def interrupted() -> bool:
    """True once SIGINT arrived while :func:`catch_interrupts` was active."""
    return _INTERRUPTED.is_set()


def raise_if_interrupted() -> None:
    """Raise ``KeyboardInterrupt`` if the user pressed Ctrl-C (even if a solver swallowed it)."""
    if _INTERRUPTED.is_set():
        raise KeyboardInterrupt


@contextlib.contextmanager
def catch_interrupts() -> Iterator[None]:
    """Within the block, SIGINT is remembered (see :func:`interrupted`) and raises KeyboardInterrupt.

    Only the main thread can install signal handlers; elsewhere the block changes nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        _INTERRUPTED.set()
        raise KeyboardInterrupt

    _INTERRUPTED.clear()
    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def exit_on_interrupt(line: str) -> Iterator[None]:
    """Within the block, SIGINT ends the process at once: ``line`` on stderr and status 130.

    For a command's start-up, while its imports (Drake, numpy, scipy) take their seconds: nothing
    is written yet, and a ``KeyboardInterrupt`` raised inside an extension's initialisation would
    end as its traceback (``ImportError: initialization failed``). Only the main thread can
    install signal handlers; elsewhere the block changes nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        try:
            sys.stderr.write(line + "\n")
            sys.stderr.flush()
        finally:
            os._exit(EXIT_INTERRUPTED)

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
