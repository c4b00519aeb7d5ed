"""Options records from YAML: the frozen dataclasses that hold a command's settings
(:class:`~kpioed_drake.design.options.DesignOptions`,
:class:`~kpioed_drake.calibration.common.CalibrationOptions`,
:class:`~kpioed_drake.simulation.truth.SimulationOptions`,
:class:`~kpioed_drake.diagnosis.common.DiagnosisOptions`), read with Drake's ``yaml_load_typed``,
and the check that turns keyword arguments into one of them.
"""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path

from pydrake.common.yaml import yaml_load_typed

from kpioed_drake.errors import InputError


def _yaml_schema(cls) -> type:
    """A mutable dataclass with the fields of the frozen ``cls`` for ``yaml_load_typed``, which
    fills a schema field by field (``tuple[T, ...]`` read as ``list[T]``)."""

    def listed(t):
        args = typing.get_args(t)
        if typing.get_origin(t) is tuple:
            return list[args[0]]
        if args and type(None) in args:
            return listed(args[0]) | None
        return t

    hints = typing.get_type_hints(cls)
    fields = [
        (f.name, listed(hints[f.name]), dataclasses.field(default=_default(f)))
        for f in dataclasses.fields(cls)
    ]
    return dataclasses.make_dataclass(f"{cls.__name__}Yaml", fields)


def _default(field: dataclasses.Field):
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return field.default


def load_options(cls, *, filename: str | Path | None = None, data: str | None = None):
    """An options record ``cls`` from a YAML file or text: a field left out keeps its default; an
    unknown field is an error. Lists in the YAML become the record's tuples.

    Raises:
        InputError: unknown field or a value of the wrong type, naming the file.
    """
    where = str(filename) if filename is not None else "options"
    try:
        raw = yaml_load_typed(
            schema=_yaml_schema(cls), filename=None if filename is None else str(filename), data=data
        )
    except RuntimeError as exc:
        raise InputError(f"{where}: {exc}") from None
    values = {f.name: getattr(raw, f.name) for f in dataclasses.fields(cls)}
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


def options_from(cls, options=None, **fields):
    """``options`` (a ``cls`` record, default ``cls()``) with ``fields`` replaced: the keyword
    arguments of a command function that are settings, not inputs or outputs.

    Raises:
        InputError: a keyword that is not a field of ``cls``, naming it and the fields there are.
    """
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(fields) - names)
    if unknown:
        raise InputError(
            f"{cls.__name__}: unknown option {', '.join(unknown)}; "
            f"the options are {', '.join(sorted(names))}",
            fields=tuple(unknown),
        )
    if options is None:
        return cls(**fields)
    if not isinstance(options, cls):
        what = f"options: expected a {cls.__name__}, got {type(options).__name__}"
        raise InputError(what, fields=("options",))
    return dataclasses.replace(options, **fields) if fields else options
