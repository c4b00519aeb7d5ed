"""Options records from YAML: the frozen dataclasses that hold a command's settings
(:class:`~kpioed_drake.design.options.DesignOptions`,
:class:`~kpioed_drake.calibration.options.CalibrationOptions`,
:class:`~kpioed_drake.simulation.options.SimulationOptions`,
:class:`~kpioed_drake.diagnosis.options.DiagnosisOptions`), read with Drake's ``yaml_load_typed``,
and the check that turns keyword arguments into one of them.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import yaml
from pydrake.common.yaml import yaml_load_typed

from kpioed_drake.errors import InputError

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

T = TypeVar("T", bound="DataclassInstance")
"""An options record type (a dataclass)."""


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


def load_options(cls: type[T], *, filename: str | Path | None = None, data: str | None = None) -> T:
    """An options record ``cls`` from a YAML file or text: a field left out keeps its default; an
    unknown field is an error. Lists in the YAML become the record's tuples.

    Raises:
        InputError: unknown field or a value of the wrong type, naming the file.
    """
    where = str(filename) if filename is not None else "options"
    schema = _yaml_schema(cls)
    try:
        parsed = yaml.safe_load(
            Path(filename).read_text(encoding="utf-8") if filename is not None else data or ""
        )
    except (OSError, UnicodeDecodeError, yaml.YAMLError, RecursionError) as exc:
        what = str(exc).splitlines()[0] if str(exc).strip() else "nested too deeply"
        raise InputError(f"{where}: not a readable YAML file ({what})") from None
    mismatch = yaml_mismatch({} if parsed is None else parsed, schema)
    if mismatch:
        raise InputError(f"{where}: {mismatch}")
    try:
        raw = yaml_load_typed(schema=schema, filename=None if filename is None else str(filename), data=data)
    except RuntimeError as exc:
        raise InputError(f"{where}: {exc}") from None
    values = {f.name: getattr(raw, f.name) for f in dataclasses.fields(cls)}
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


def options_from(cls: type[T], options: T | None = None, **fields: Any) -> T:
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


_KINDS = {bool: "true or false", int: "a whole number", float: "a finite number", str: "text"}


def _got(value) -> str:
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return "nothing" if value is None else repr(value)


def _scalar_ok(kind: type, value) -> bool:
    if kind is bool or isinstance(value, bool):
        return kind is bool and isinstance(value, bool)
    if kind is float:
        return isinstance(value, int | float) and math.isfinite(value)
    if kind is int:
        return isinstance(value, int) or (isinstance(value, float) and value.is_integer())
    return isinstance(value, kind)


def yaml_mismatch(data: Any, schema: Any, field: str = "") -> str | None:
    """Where the parsed YAML ``data`` does not fit the type ``schema`` (a dataclass as the YAML
    loaders take it): ``"field: expected ..., got ..."`` naming the first field that does not
    (``effects[0].values[2]``), or None when all fit. Numbers must be finite.

    The typed loader's own messages name no field (``could not convert string to float``) or
    accept what they should not (text given for a list of numbers is read letter by letter).
    """
    at = field or "the top level"
    origin, args = typing.get_origin(schema), typing.get_args(schema)
    if type(None) in args:  # an optional field
        rest = [a for a in args if a is not type(None)]
        return None if data is None else yaml_mismatch(data, rest[0], field)
    if dataclasses.is_dataclass(schema):
        if not isinstance(data, dict):
            return f"{at}: expected a mapping (key: value), got {_got(data)}"
        hints = typing.get_type_hints(schema)
        for key, value in data.items():
            if key not in hints:
                return f"{at}: unknown field {key!r} (fields: {', '.join(hints)})"
            found = yaml_mismatch(value, hints[key], f"{field}.{key}" if field else str(key))
            if found:
                return found
        return None
    if origin is list:
        if not isinstance(data, list):
            return f"{at}: expected a list [...], got {_got(data)}"
        return next(
            (m for k, v in enumerate(data) if (m := yaml_mismatch(v, args[0], f"{field}[{k}]"))), None
        )
    if origin is dict:
        if not isinstance(data, dict):
            return f"{at}: expected a mapping (key: value), got {_got(data)}"
        return next((m for k, v in data.items() if (m := yaml_mismatch(v, args[1], f"{field}.{k}"))), None)
    if schema in _KINDS and not _scalar_ok(schema, data):
        return f"{at}: expected {_KINDS[schema]}, got {_got(data)}"
    return None
