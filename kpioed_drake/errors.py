"""Error types shown to users, the command line's exit statuses, and the interrupt flag.

Every error a user can cause by bad input is an :class:`InputError`; the command line prints its
message on one line and exits with status 2 (:data:`EXIT_INPUT`). A solver failure or an infeasible
result exits with 3 (:data:`EXIT_SOLVER`), an interrupt (Ctrl-C) with 130. Anything else is a bug:
one line and status 1, the traceback with ``kpioed --debug``.

Drake calls our cost and constraint functions from inside SNOPT/IPOPT; a ``KeyboardInterrupt``
raised there is turned into a failed solve by the solver. :func:`interrupted` lets long loops (solve
starts, study tasks) notice that the user pressed Ctrl-C and stop instead of going on.
"""

from __future__ import annotations

import contextlib
import signal
import threading

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_INPUT = 2
EXIT_SOLVER = 3
EXIT_INTERRUPTED = 130


class InputError(ValueError):
    """Bad input: an unknown robot, a malformed file, an impossible setting.

    The message names the file, row or field and says what was expected.
    """


class SolverError(RuntimeError):
    """A solver failed or every attempt ended infeasible: not the user's input (exit status 3)."""


_INTERRUPTED = threading.Event()


def interrupted() -> bool:
    """True once SIGINT arrived while :func:`catch_interrupts` was active."""
    return _INTERRUPTED.is_set()


def raise_if_interrupted() -> None:
    """Raise ``KeyboardInterrupt`` if the user pressed Ctrl-C (even if a solver swallowed it)."""
    if _INTERRUPTED.is_set():
        raise KeyboardInterrupt


@contextlib.contextmanager
def catch_interrupts():
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
