"""Progress of long runs: what a command is doing and how far, on stderr.

A stage (:func:`stage`) is a tqdm bar with a description; the code it runs reports each finished
step with :func:`step` without knowing whether a bar is shown (no bar: nothing happens), so that
the numerical modules take no progress arguments. :func:`note` writes one line (an estimate before
a long run).

Shown where stderr is a terminal; ``KPIOED_PROGRESS=1`` shows it always (a log file),
``KPIOED_PROGRESS=0`` never. Tests and pipes see nothing unless they ask.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import sys
from collections.abc import Iterator

from tqdm.auto import tqdm

ENV = "KPIOED_PROGRESS"
"""``1``: show progress on any stderr; ``0``: never; unset: where stderr is a terminal."""

_CURRENT: contextvars.ContextVar[tqdm | None] = contextvars.ContextVar("kpioed_progress", default=None)


def shown() -> bool:
    """Whether progress is written (:data:`ENV`, else stderr is a terminal)."""
    value = os.environ.get(ENV, "").strip()
    if value in ("0", "1"):
        return value == "1"
    return bool(getattr(sys.stderr, "isatty", lambda: False)())


@contextlib.contextmanager
def stage(desc: str, *, total: int | None = None, unit: str = "step") -> Iterator[None]:
    """A bar ``desc`` of ``total`` steps (None: counted without an end) while the block runs;
    :func:`step` inside it advances this bar (the innermost stage)."""
    bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=False, disable=not shown())
    token = _CURRENT.set(bar)
    try:
        yield
    finally:
        _CURRENT.reset(token)
        bar.close()


def step(n: int = 1, **status: float | int | str) -> None:
    """The innermost stage advanced by ``n`` steps, ``status`` shown beside it (e.g. ``g_max``)."""
    bar = _CURRENT.get()
    if bar is None or bar.disable:
        return
    if status:
        shown_status = {k: f"{v:.4g}" if isinstance(v, float) else v for k, v in status.items()}
        bar.set_postfix(shown_status, refresh=False)
    bar.update(n)


def note(line: str) -> None:
    """``line`` on stderr where progress is shown (:func:`shown`)."""
    if shown():
        tqdm.write(f"kpioed: {line}", file=sys.stderr)
