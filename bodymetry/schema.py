"""Parsed YAML/JSON document trees: validated reading and deterministic YAML writing.

Every stage's side files (``calibration.yaml``, ``session.yaml``, ...) are read
through this toolkit so that every problem raises
:class:`bodymetry.errors.InputError` with one message shape: the file, the field
(``cameras[2].K``), what was expected and what was found.

* :func:`read_yaml_mapping` reads a YAML file whose top level is a mapping;
* :class:`Fields` checks the values of a parsed tree (mappings and their keys,
  strings, booleans, numbers, fixed-shape arrays);
* :func:`check_format` checks a ``format: <kind>/<version>`` key;
* :func:`describe`, :func:`plain_number` and :func:`join_field` word messages;
* :func:`dump_yaml` writes plain data as deterministic block YAML whose floats
  read back bit for bit (:func:`plain_data` turns numpy values into plain ones).
"""

from __future__ import annotations

import datetime as _dt
import difflib
import json
import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bodymetry.errors import InputError
from bodymetry.fileio import parse_yaml, read_text_limited

__all__ = [
    "YAML_MAX_BYTES",
    "Fields",
    "check_format",
    "describe",
    "dump_yaml",
    "join_field",
    "plain_data",
    "plain_number",
    "read_yaml_mapping",
]

#: The largest YAML file :func:`read_yaml_mapping` reads unless told otherwise.
YAML_MAX_BYTES = 1_000_000


def read_yaml_mapping(
    path: str | os.PathLike[str], kind: str, max_bytes: int = YAML_MAX_BYTES
) -> dict[str, Any]:
    """Read a YAML file whose top level must be a mapping.

    Parameters
    ----------
    path
        The file.
    kind
        What the file is, for messages (e.g. ``"calibration file"``).
    max_bytes
        The largest file read (bytes).

    Raises
    ------
    InputError
        Missing, unreadable or too large file, malformed YAML (with line and
        column), duplicate keys, a top level that is not a mapping.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: {kind} not found")
    if not path.is_file():
        raise InputError(f"{path}: expected a {kind} (a file), found a folder or special file")
    try:
        text = read_text_limited(path, max_bytes, kind)
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the {kind}: {exc}") from exc
    try:
        data = parse_yaml(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise InputError(f"{path}: not valid YAML{where}: {problem}") from exc
    if not isinstance(data, dict):
        raise InputError(
            f"{path}: expected a mapping (key: value lines) at the top level, got {describe(data)}"
        )
    return data


# --------------------------------------------------------------------------
# Validation toolkit
# --------------------------------------------------------------------------
def plain_number(value: Any) -> str:
    """A number as a person writes it: ``-706.03``, ``0``, never ``np.float64(-706.03)``.

    Under numpy 2 the ``repr`` of a numpy scalar names its type, which reads as
    noise in an error message; Python numbers are kept as they are (``repr``,
    which reads back to the same value).
    """
    if isinstance(value, np.generic):
        value = value.item()
    return repr(value)


def describe(value: Any) -> str:
    """Short human description of a parsed YAML/TOML value, for error messages."""
    if value is None:
        return "nothing (null)"
    if isinstance(value, bool):
        return f"the boolean {str(value).lower()}"
    if isinstance(value, int):
        return f"the integer {value}"
    if isinstance(value, float):
        return f"the number {plain_number(value)}"
    if isinstance(value, str):
        shown = value if len(value) <= 60 else value[:57] + "..."
        return f"the string {shown!r}"
    if isinstance(value, dict):
        keys = list(value)[:8]
        return f"a mapping with keys {keys}" if keys else "an empty mapping"
    if isinstance(value, list):
        return f"a list of {len(value)} item{'s' if len(value) != 1 else ''}"
    return f"a {type(value).__name__}"


def join_field(parent: str, child: str | int) -> str:
    """``join_field("cameras", 2) == "cameras[2]"``, ``join_field("cameras[2]", "K")``."""
    if isinstance(child, int):
        return f"{parent}[{child}]"
    return f"{parent}.{child}" if parent else child


class Fields:
    """Typed access to a parsed document; every failure names file and field.

    Parameters
    ----------
    source
        The file (or a description of the in-memory source) for messages.
    """

    def __init__(self, source: str | os.PathLike[str]) -> None:
        self.source = str(source)

    def error(self, field: str, message: str) -> InputError:
        """An :class:`InputError` reading ``"<file>: <field>: <message>"``."""
        if field:
            return InputError(f"{self.source}: {field}: {message}")
        return InputError(f"{self.source}: {message}")

    def mapping(self, value: Any, field: str) -> dict[str, Any]:
        """``value`` as a mapping with string keys."""
        if not isinstance(value, dict):
            raise self.error(field, f"expected a mapping (key: value), got {describe(value)}")
        for key in value:
            if not isinstance(key, str):
                raise self.error(field, f"keys must be strings, got {describe(key)}")
        return value

    def keys(
        self,
        mapping: Mapping[str, Any],
        field: str,
        required: Iterable[str],
        optional: Iterable[str] = (),
        *,
        allow_unknown: bool = False,
    ) -> None:
        """Check that required keys are present and (unless allowed) no others."""
        required = tuple(required)
        optional = tuple(optional)
        allowed = required + optional
        for key in required:
            if key not in mapping:
                strays = [k for k in mapping if k not in allowed]
                close = difflib.get_close_matches(key, strays, n=1)
                hint = f"; found {close[0]!r}: a typo?" if close else ""
                raise self.error(
                    join_field(field, key),
                    f"missing key {key!r} (required keys here: {', '.join(required)}){hint}",
                )
        if not allow_unknown:
            for key in mapping:
                if key not in allowed:
                    raise self.error(
                        join_field(field, key),
                        f"unknown key {key!r}; allowed keys here: {', '.join(allowed)}",
                    )

    def string(self, value: Any, field: str, *, allow_empty: bool = False) -> str:
        """``value`` as a string (non-blank unless ``allow_empty``)."""
        if not isinstance(value, str):
            raise self.error(field, f"expected a string, got {describe(value)}")
        if not allow_empty and not value.strip():
            raise self.error(field, "expected a non-empty string, got an empty one")
        return value

    def boolean(self, value: Any, field: str) -> bool:
        """``value`` as ``true`` or ``false`` (not 0 / 1)."""
        if not isinstance(value, bool):
            raise self.error(field, f"expected true or false, got {describe(value)}")
        return value

    def integer(self, value: Any, field: str, *, minimum: int | None = None) -> int:
        """``value`` as an integer (a whole float is accepted), at least ``minimum``."""
        ok = isinstance(value, int) and not isinstance(value, bool)
        if isinstance(value, float) and value.is_integer():
            ok, value = True, int(value)
        if not ok:
            raise self.error(field, f"expected an integer, got {describe(value)}")
        if minimum is not None and value < minimum:
            raise self.error(field, f"expected an integer >= {minimum}, got {value}")
        return int(value)

    def number(
        self, value: Any, field: str, *, positive: bool = False, minimum: float | None = None
    ) -> float:
        """``value`` as a finite float; ``positive``: > 0; at least ``minimum``."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(field, f"expected a number, got {describe(value)}")
        x = float(value)
        if not math.isfinite(x):
            raise self.error(field, f"expected a finite number, got {plain_number(value)}")
        if positive and not x > 0:
            raise self.error(field, f"expected a number > 0, got {plain_number(value)}")
        if minimum is not None and x < minimum:
            raise self.error(
                field, f"expected a number >= {plain_number(minimum)}, got {plain_number(value)}"
            )
        return x

    def array(
        self, value: Any, field: str, shape: Sequence[int | Sequence[int]], what: str = ""
    ) -> np.ndarray:
        """A nested list of finite numbers with the given shape.

        ``shape`` entries are lengths or tuples of allowed lengths (e.g.
        ``[(4, 5, 8, 12, 14)]`` for a distortion vector).
        """
        label = what or _shape_label(shape)
        return np.asarray(self._array(value, field, tuple(shape), label), dtype=float)

    def _array(self, value: Any, field: str, shape: tuple, label: str) -> list:
        allowed = shape[0] if isinstance(shape[0], tuple) else (shape[0],)
        if not isinstance(value, list):
            raise self.error(field, f"expected {label}, got {describe(value)}")
        if len(value) not in allowed:
            n = " or ".join(str(a) for a in allowed)
            raise self.error(field, f"expected {label}: {n} items, got {len(value)}")
        if len(shape) == 1:
            return [self.number(v, join_field(field, i)) for i, v in enumerate(value)]
        inner = _shape_label(shape[1:])
        return [self._array(v, join_field(field, i), shape[1:], inner) for i, v in enumerate(value)]


def _shape_label(shape: Sequence[int | Sequence[int]]) -> str:
    def n(s: int | Sequence[int]) -> str:
        return str(s) if isinstance(s, int) else " or ".join(map(str, s))

    if len(shape) == 1:
        return f"a list of {n(shape[0])} numbers"
    if len(shape) == 2:
        return f"a {n(shape[0])}x{n(shape[1])} matrix (a list of {n(shape[0])} rows)"
    return f"a nested list of shape {tuple(shape)}"


def check_format(fields: Fields, data: Mapping[str, Any], expected: str) -> None:
    """Check the ``format:`` key against ``expected`` (``"<kind>/<version>"``)."""
    if "format" not in data:
        raise fields.error("format", f"missing key 'format' (expected format: {expected})")
    value = data["format"]
    if not isinstance(value, str):
        raise fields.error("format", f"expected the string {expected!r}, got {describe(value)}")
    if value != expected:
        kind = expected.split("/")[0]
        if value.split("/")[0] == kind:
            raise fields.error(
                "format",
                f"unknown format version {value!r}; this version of bodymetry reads {expected!r}",
            )
        raise fields.error("format", f"expected {expected!r}, got {value!r} (wrong kind of file?)")


# --------------------------------------------------------------------------
# YAML writing: deterministic, exact floats, readable matrices.
# --------------------------------------------------------------------------
# Plain (unquoted) strings: a conservative set that YAML cannot misread.
_PLAIN = re.compile(r"^[A-Za-z_./](?:[A-Za-z0-9_./\- ]*[A-Za-z0-9_./\-])?$")


def _format_float(x: float) -> str:
    if math.isnan(x):
        return ".nan"
    if math.isinf(x):
        return ".inf" if x > 0 else "-.inf"
    s = repr(x)
    if "e" in s:
        mantissa, exponent = s.split("e")
        if "." not in mantissa:
            mantissa += ".0"  # YAML 1.1 (PyYAML) needs a dot to read it as a float
        if exponent[0] not in "+-":
            exponent = "+" + exponent
        s = f"{mantissa}e{exponent}"
    elif "." not in s:
        s += ".0"
    return s


def _format_scalar(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return _format_float(float(value))
    if isinstance(value, (_dt.date, _dt.datetime)):
        return value.isoformat()
    if isinstance(value, str):
        if _PLAIN.match(value) and parse_yaml(value) == value:
            return value
        return json.dumps(value, ensure_ascii=True)
    raise TypeError(f"cannot write {type(value).__name__} to YAML: {value!r}")


def _is_scalar(value: Any) -> bool:
    return value is None or isinstance(
        value, (bool, int, float, str, np.generic, _dt.date, _dt.datetime)
    )


def plain_data(value: Any) -> Any:
    """Plain Python data for writing: arrays become (nested) lists, numpy scalars
    Python numbers, tuples lists; anything else is returned as it is."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, tuple):
        return list(value)
    return value


def _flow(value: Any) -> str | None:
    """Flow text for a scalar or a (nested) list of scalars, else None."""
    value = plain_data(value)
    if _is_scalar(value):
        return _format_scalar(value)
    if isinstance(value, list):
        parts = [_flow(v) for v in value]
        if any(p is None for p in parts):
            return None
        return "[" + ", ".join(parts) + "]"  # type: ignore[arg-type]
    if isinstance(value, Mapping) and not value:
        return "{}"
    return None


def _emit(value: Any, indent: int, lines: list[str], prefix: str) -> None:
    """Append ``prefix`` + value; ``prefix`` is ``"key:"`` or ``"-"`` (block context)."""
    pad = " " * indent
    value = plain_data(value)
    if isinstance(value, Mapping) and value:
        lines.append(f"{pad}{prefix}")
        _emit_mapping(value, indent + 2, lines)
        return
    if isinstance(value, list) and value:
        # A matrix (list of lists of scalars): one flow row per line.
        rows = [_flow(v) for v in value]
        is_matrix = all(isinstance(plain_data(v), list) for v in value)
        if is_matrix and all(r is not None for r in rows):
            lines.append(f"{pad}{prefix}")
            lines.extend(f"{pad}  - {r}" for r in rows)
            return
        flow = _flow(value)
        if flow is not None:
            lines.append(f"{pad}{prefix} {flow}")
            return
        lines.append(f"{pad}{prefix}")
        for item in value:
            item = plain_data(item)
            if isinstance(item, Mapping) and item:
                sub: list[str] = []
                _emit_mapping(item, indent + 4, sub)
                first = sub[0][indent + 4 :]
                lines.append(f"{pad}  - {first}")
                lines.extend(sub[1:])
            else:
                _emit(item, indent + 2, lines, "-")
        return
    flow = _flow(value)
    if flow is None:
        raise TypeError(f"cannot write {type(value).__name__} to YAML")
    lines.append(f"{pad}{prefix} {flow}")


def _emit_mapping(mapping: Mapping[str, Any], indent: int, lines: list[str]) -> None:
    for key, value in mapping.items():
        if not isinstance(key, str):
            raise TypeError(f"YAML keys must be strings, got {key!r}")
        _emit(value, indent, lines, f"{_format_scalar(key)}:")


def dump_yaml(data: Mapping[str, Any], header: str | None = None) -> str:
    """Deterministic block-style YAML for plain data (dicts, lists, scalars, arrays).

    Floats are written with ``repr`` (with ``.0`` added where YAML 1.1 needs it),
    so they read back bit-exactly; lists of scalars are written inline and lists
    of lists as one inline row per line. ``header`` lines become comments.
    """
    lines = [f"# {h}".rstrip() for h in header.splitlines()] if header else []
    _emit_mapping(data, 0, lines)
    return "\n".join(lines) + "\n"
