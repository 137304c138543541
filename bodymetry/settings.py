"""Nested settings dataclasses: to and from JSON, and ``key.path=value`` overrides.

Every stage's settings are frozen dataclasses that validate themselves in
``__post_init__``. This module turns such a tree into JSON (for
``results.json``), reads it back with type checks, and applies command-line
overrides such as ``annealing.n_particles=120`` (values parsed as YAML scalars:
``120``, ``0.5``, ``true``, ``[1, 2]``). It imports nothing from the stages,
so every layer may use it.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

from bodymetry.errors import InputError
from bodymetry.fileio import parse_yaml

T = TypeVar("T")

__all__ = ["apply_overrides", "from_jsonable", "parse_override", "to_jsonable"]


def to_jsonable(obj: Any) -> Any:
    """A dataclass tree as plain JSON values (tuples become lists, paths strings)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    return obj


def _field_types(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _coerce(value: Any, hint: Any, where: str) -> Any:
    """``value`` (from JSON or YAML) as the annotated type ``hint``; InputError if it is not."""
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, where)
            except InputError as exc:
                errors.append(str(exc))
        raise InputError(errors[0] if errors else f"{where}: unexpected {value!r}")
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, Mapping):
            raise InputError(f"{where}: expected a mapping, got {value!r}")
        return from_jsonable(hint, value, where)
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise InputError(f"{where}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise InputError(f"{where}: expected {len(args)} values, got {len(value)}")
        return tuple(
            _coerce(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args, strict=True))
        )
    if origin is dict or origin is Mapping:
        if not isinstance(value, Mapping):
            raise InputError(f"{where}: expected a mapping, got {value!r}")
        return dict(value)
    if hint is Any:
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise InputError(f"{where}: expected true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(f"{where}: expected an integer, got {value!r}")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise InputError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise InputError(f"{where}: expected a string, got {value!r}")
        return value
    if hint is Path:
        if not isinstance(value, str | Path):
            raise InputError(f"{where}: expected a path, got {value!r}")
        return Path(value)
    return value


def _construct(cls: type[T], kwargs: dict[str, Any], where: str) -> T:
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:
        raise InputError(f"{where}: {exc}") from exc


def from_jsonable(cls: type[T], data: Mapping[str, Any], where: str = "settings") -> T:
    """Build the dataclass ``cls`` from JSON values, checking every field's type.

    Unknown keys are an error (a misspelt setting must not be ignored); missing
    keys take the field's default.

    Raises
    ------
    InputError
        Naming ``where`` and the field, with the expected and the actual value.
    """
    hints = _field_types(cls)
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - names)
    if unknown:
        raise InputError(
            f"{where}: unknown setting(s) {', '.join(unknown)}; expected some of "
            f"{', '.join(sorted(names))}"
        )
    kwargs = {k: _coerce(v, hints[k], f"{where}.{k}") for k, v in data.items()}
    return _construct(cls, kwargs, where)


def parse_override(text: str) -> tuple[list[str], Any]:
    """``"a.b=3"`` -> (["a", "b"], 3); the value is parsed as a YAML scalar or list."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise InputError(f"--set {text!r}: expected KEY=VALUE, e.g. annealing.n_particles=120")
    try:
        value = parse_yaml(raw) if raw.strip() else ""
    except yaml.YAMLError as exc:
        raise InputError(f"--set {text!r}: the value is not valid YAML ({exc})") from exc
    return key.strip().split("."), value


def _replace_path(obj: Any, path: list[str], value: Any, where: str) -> Any:
    names = [f.name for f in dataclasses.fields(obj)]
    head = path[0]
    if head not in names:
        raise InputError(
            f"{where or 'config'}: unknown setting {head!r}; expected one of {', '.join(names)}"
        )
    hint = _field_types(type(obj))[head]
    current = getattr(obj, head)
    if len(path) == 1:
        new = _coerce(value, hint, f"{where}.{head}" if where else head)
    elif dataclasses.is_dataclass(current):
        new = _replace_path(current, path[1:], value, f"{where}.{head}" if where else head)
    else:
        raise InputError(f"{'.'.join(path)}: {head!r} has no sub-settings")
    try:
        return dataclasses.replace(obj, **{head: new})
    except (ValueError, TypeError) as exc:
        raise InputError(f"{where or type(obj).__name__}: {exc}") from exc


def apply_overrides(
    obj: T, overrides: Iterable[str], aliases: Mapping[str, str] | None = None
) -> T:
    """A copy of the dataclass tree ``obj`` with ``key.path=value`` overrides applied.

    Parameters
    ----------
    obj : dataclass instance
    overrides : iterable of str
        E.g. ``["fit.annealing.n_particles=120", "workers=2"]``.
    aliases : mapping of str to str, optional
        Short first keys and what they stand for (``{"annealing": "fit.annealing"}``).

    Raises
    ------
    InputError
        For a malformed override, an unknown key or a value of the wrong type;
        the settings' own validation errors name the setting.
    """
    for text in overrides:
        path, value = parse_override(text)
        if aliases and path[0] in aliases:
            path = aliases[path[0]].split(".") + path[1:]
        obj = _replace_path(obj, path, value, "")
    return obj
