"""Checks of the arguments a user gives a command, shared by the workflows behind :mod:`kpioed_drake.api`.

Each check raises :class:`~kpioed_drake.errors.InputError` naming the argument (in its ``fields``:
the command line shows it as the option) and what was expected, before any work is done; the
command line maps it to exit status 2.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.outputs import check_output_paths
from kpioed_drake.robot.models import robot_path

PICTURE_SUFFIXES = (".png", ".pdf", ".svg")
"""Endings of picture outputs (matplotlib formats)."""
HTML_SUFFIXES = (".html", ".htm")
"""Endings of 3-D page outputs."""


def require(ok: bool, message: str, *, fields: tuple[str, ...] = ()) -> None:
    """Raise InputError(message, fields=fields) unless ``ok``."""
    if not ok:
        raise InputError(message, fields=fields)


def check_seed(seed: object) -> None:
    """A random seed: an integer >= 0."""
    ok = isinstance(seed, int | np.integer) and not isinstance(seed, bool) and seed >= 0
    require(ok, f"seed: expected an integer >= 0, got {seed!r}", fields=("seed",))


def check_count(name: str, value: object, *, at_least: int = 1, allow_none: bool = False) -> None:
    """An integer >= ``at_least`` (None allowed with ``allow_none``)."""
    if value is None and allow_none:
        return
    ok = isinstance(value, int | np.integer) and not isinstance(value, bool) and value >= at_least
    require(ok, f"{name}: expected an integer >= {at_least}, got {value!r}", fields=(name,))


def check_positive(name: str, value: object, *, allow_none: bool = False, zero_ok: bool = False) -> None:
    """A finite number > 0 (>= 0 with ``zero_ok``; None allowed with ``allow_none``)."""
    if value is None and allow_none:
        return
    ok = isinstance(value, int | float | np.number) and not isinstance(value, bool) and math.isfinite(value)
    ok = ok and (value >= 0 if zero_ok else value > 0)
    what = f"{name}: expected a finite number {'>= 0' if zero_ok else '> 0'}, got {value!r}"
    require(ok, what, fields=(name,))


def robot_file(robot: str) -> str | None:
    """The robot's file when the user named one (an input that no output may overwrite)."""
    return str(robot_path(robot)) if Path(str(robot)).suffix in (".yaml", ".yml", ".urdf") else None


def check_paths(
    *,
    robot: str,
    inputs: Sequence[str | Path | None] = (),
    outputs: Sequence[str | Path | None] = (),
    folders: Sequence[str | Path | None] = (),
    plot: str | Path | None = None,
    html: str | Path | None = None,
) -> None:
    """Output paths checked against the inputs (the robot file among them) and their endings.

    Args:
        robot: the robot argument (a model name or a file).
        inputs: other files the command reads; outputs: files it writes (``plot`` and ``html``
            included automatically); folders: folders it writes into.
        plot: a picture output (.png, .pdf or .svg); html: a 3-D page output (.html).
    """
    suffixes = {p: s for p, s in ((plot, PICTURE_SUFFIXES), (html, HTML_SUFFIXES)) if p}
    check_output_paths(
        inputs=[robot_file(robot), *inputs],
        outputs=[*outputs, plot, html],
        folders=folders,
        suffixes=suffixes,
    )
