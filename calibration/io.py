"""Calibration files: our ``calibration.yaml`` and the anipose / FreeMoCap ``calibration.toml``.

The YAML format is documented in ``docs/calibration-format.md``. In short::

    format: bodymetry-calibration/1
    world: {frame: ..., note: ...}          # optional
    cameras:
      - name: cam_00
        size: [640, 480]                    # width, height (px)
        K: [[fx, s, cx], [0, fy, cy], [0, 0, 1]]
        dist: [k1, k2, p1, p2, k3]          # OpenCV order; 4, 5, 8, 12 or 14 values
        R: [[...], [...], [...]]            # x_cam = R @ x_world + t
        t: [tx, ty, tz]                     # metres
    quality: {...}                          # optional, free-form figures

Reading validates everything and raises :class:`bodymetry.errors.InputError`
whose message names the file, the field (``cameras[2].K``), what was expected
and what was found. Writing is atomic and exact: every float is written with
``repr`` (shortest string that reads back to the same bits), so reading a file
we wrote and writing it again gives the same bytes.

This module also holds the small validated-YAML toolkit that
:mod:`capture.session` uses for ``session.yaml`` (:func:`read_yaml_mapping`,
:class:`Fields`, :func:`dump_yaml`).
"""

from __future__ import annotations

import datetime as _dt
import difflib
import json
import math
import os
import re
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.errors import InputError
from bodymetry.fileio import parse_yaml, read_text_limited, write_text_atomic

__all__ = [
    "CALIBRATION_FORMAT",
    "CALIBRATION_MAX_BYTES",
    "Calibration",
    "Fields",
    "calibration_from_data",
    "calibration_to_yaml",
    "check_format",
    "describe",
    "dump_yaml",
    "export_anipose_toml",
    "import_anipose_toml",
    "join_field",
    "load_calibration",
    "plain_number",
    "read_calibration",
    "read_yaml_mapping",
    "save_calibration",
]

CALIBRATION_FORMAT = "bodymetry-calibration/1"
#: The largest calibration.yaml or calibration.toml read (a rig of dozens of
#: cameras is a few kB; anything near this is the wrong file).
CALIBRATION_MAX_BYTES = 1_000_000

_CAMERA_KEYS = ("name", "size", "K", "dist", "R", "t")
_TOP_REQUIRED = ("format", "cameras")
_TOP_OPTIONAL = ("world", "quality")
_DIST_LENGTHS = (4, 5, 8, 12, 14)
# R R^T may deviate from I by this much and is used bit for bit as written (a
# rotation computed in double precision deviates by ~1e-15).
_ROT_EXACT_TOL = 1e-9
# Up to this deviation (a matrix typed with few digits) R is projected onto the
# nearest rotation; beyond it the file is refused.
_ROT_ROUNDED_TOL = 1e-3

_YAML_HEADER = (
    "bodymetry camera calibration (docs/calibration-format.md)\n"
    "x_cam = R @ x_world + t; t in metres; K and dist in OpenCV conventions"
)


def read_yaml_mapping(
    path: str | os.PathLike[str], kind: str, max_bytes: int = CALIBRATION_MAX_BYTES
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
        if not isinstance(value, str):
            raise self.error(field, f"expected a string, got {describe(value)}")
        if not allow_empty and not value.strip():
            raise self.error(field, "expected a non-empty string, got an empty one")
        return value

    def boolean(self, value: Any, field: str) -> bool:
        if not isinstance(value, bool):
            raise self.error(field, f"expected true or false, got {describe(value)}")
        return value

    def integer(self, value: Any, field: str, *, minimum: int | None = None) -> int:
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


def _plain_data(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, tuple):
        return list(value)
    return value


def _flow(value: Any) -> str | None:
    """Flow text for a scalar or a (nested) list of scalars, else None."""
    value = _plain_data(value)
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
    value = _plain_data(value)
    if isinstance(value, Mapping) and value:
        lines.append(f"{pad}{prefix}")
        _emit_mapping(value, indent + 2, lines)
        return
    if isinstance(value, list) and value:
        # A matrix (list of lists of scalars): one flow row per line.
        rows = [_flow(v) for v in value]
        is_matrix = all(isinstance(_plain_data(v), list) for v in value)
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
            item = _plain_data(item)
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


# --------------------------------------------------------------------------
# calibration.yaml
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Calibration:
    """Everything a ``calibration.yaml`` holds.

    Attributes
    ----------
    cameras : CameraGroup
        The cameras, in file order.
    world : dict or None
        How the world frame was defined (``frame``, ``note``, ...).
    quality : dict or None
        Free-form quality figures (see docs/calibration-format.md).
    """

    cameras: CameraGroup
    world: dict[str, Any] | None = None
    quality: dict[str, Any] | None = None


def _rotation(fields: Fields, value: Any, field: str) -> np.ndarray:
    R = fields.array(value, field, (3, 3), "a 3x3 rotation matrix (a list of 3 rows)")
    dev = float(np.abs(R @ R.T - np.eye(3)).max())
    if dev > _ROT_ROUNDED_TOL:
        raise fields.error(
            field,
            f"expected a rotation matrix (R @ R.T = I), but R @ R.T deviates from I by {dev:.3g}",
        )
    det = float(np.linalg.det(R))
    if det < 0:
        raise fields.error(
            field,
            f"expected a rotation (det = +1), got det = {det:.6g}: a reflection "
            "(a mirrored axis; check the handedness of the world and camera frames)",
        )
    if dev > _ROT_EXACT_TOL:
        # Typed with few digits: use the nearest rotation (polar decomposition).
        u, _, vt = np.linalg.svd(R)
        R = u @ vt
    return R


def _intrinsics(fields: Fields, value: Any, field: str) -> np.ndarray:
    K = fields.array(value, field, (3, 3), "a 3x3 intrinsic matrix (a list of 3 rows)")
    if not (K[2, 0] == 0 and K[2, 1] == 0 and K[2, 2] == 1 and K[1, 0] == 0):
        raise fields.error(
            field,
            f"expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}",
        )
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise fields.error(
            field,
            f"expected positive focal lengths, got fx={plain_number(K[0, 0])}, "
            f"fy={plain_number(K[1, 1])}",
        )
    return K


def _camera_from_data(fields: Fields, value: Any, field: str) -> Camera:
    cam = fields.mapping(value, field)
    fields.keys(cam, field, _CAMERA_KEYS)
    name = fields.string(cam["name"], join_field(field, "name"))
    size_field = join_field(field, "size")
    size = cam["size"]
    if not isinstance(size, list) or len(size) != 2:
        raise fields.error(size_field, f"expected [width, height] in pixels, got {describe(size)}")
    w = fields.integer(size[0], join_field(size_field, 0), minimum=1)
    h = fields.integer(size[1], join_field(size_field, 1), minimum=1)
    K = _intrinsics(fields, cam["K"], join_field(field, "K"))
    dist = fields.array(
        cam["dist"],
        join_field(field, "dist"),
        (_DIST_LENGTHS,),
        "a list of distortion coefficients in OpenCV order (4, 5, 8, 12 or 14 numbers; "
        "[0, 0, 0, 0, 0] for none)",
    )
    R = _rotation(fields, cam["R"], join_field(field, "R"))
    t = fields.array(cam["t"], join_field(field, "t"), (3,), "a list of 3 numbers (metres)")
    try:
        return Camera(name=name, size=(w, h), K=K, dist=dist, R=R, t=t)
    except ValueError as exc:  # anything Camera checks that we did not
        raise fields.error(field, str(exc)) from exc


def _cameras_from_list(fields: Fields, value: Any, field: str) -> CameraGroup:
    if not isinstance(value, list):
        raise fields.error(field, f"expected a list of cameras, got {describe(value)}")
    if not value:
        raise fields.error(field, "expected at least one camera, got an empty list")
    cameras: list[Camera] = []
    first: dict[str, int] = {}
    for i, item in enumerate(value):
        cam = _camera_from_data(fields, item, join_field(field, i))
        if cam.name in first:
            raise fields.error(
                join_field(join_field(field, i), "name"),
                f"duplicate camera name {cam.name!r} (also {field}[{first[cam.name]}])",
            )
        first[cam.name] = i
        cameras.append(cam)
    return CameraGroup(cameras)


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


def calibration_from_data(data: Any, source: str | os.PathLike[str]) -> Calibration:
    """Validate parsed ``calibration.yaml`` content (``source`` names it in errors)."""
    fields = Fields(source)
    if not isinstance(data, dict):
        raise fields.error("", f"expected a mapping at the top level, got {describe(data)}")
    fields.mapping(data, "")
    check_format(fields, data, CALIBRATION_FORMAT)
    fields.keys(data, "", _TOP_REQUIRED, _TOP_OPTIONAL)
    world = None
    if "world" in data and data["world"] is not None:
        world = fields.mapping(data["world"], "world")
        for key in ("frame", "note"):
            if key in world:
                fields.string(world[key], join_field("world", key), allow_empty=True)
    quality = None
    if "quality" in data and data["quality"] is not None:
        quality = fields.mapping(data["quality"], "quality")
    group = _cameras_from_list(fields, data["cameras"], "cameras")
    return Calibration(cameras=group, world=world, quality=quality)


def read_calibration(path: str | os.PathLike[str]) -> Calibration:
    """Read and validate a ``calibration.yaml`` (cameras plus world and quality notes).

    Raises
    ------
    InputError
        For every problem, naming the file, the field, expected and actual.
    """
    data = read_yaml_mapping(path, "calibration file")
    return calibration_from_data(data, path)


def load_calibration(path: str | os.PathLike[str]) -> CameraGroup:
    """Read a ``calibration.yaml`` and return its cameras (file order)."""
    return read_calibration(path).cameras


def _camera_to_data(cam: Camera) -> dict[str, Any]:
    return {
        "name": cam.name,
        "size": [int(cam.size[0]), int(cam.size[1])],
        "K": cam.K.tolist(),
        "dist": cam.dist.tolist(),
        "R": cam.R.tolist(),
        "t": cam.t.tolist(),
    }


def calibration_to_yaml(
    group: CameraGroup | Calibration, extra: Mapping[str, Any] | None = None
) -> str:
    """The text of a ``calibration.yaml`` (what :func:`save_calibration` writes).

    Parameters
    ----------
    group
        The cameras, or a :class:`Calibration` (its ``world`` / ``quality`` are kept).
    extra
        Optional top-level ``world`` and ``quality`` mappings (override ``group``'s).
    """
    world = quality = None
    if isinstance(group, Calibration):
        world, quality, group = group.world, group.quality, group.cameras
    if not isinstance(group, CameraGroup):
        raise TypeError(f"expected a CameraGroup or Calibration, got {type(group).__name__}")
    extra = dict(extra or {})
    unknown = set(extra) - set(_TOP_OPTIONAL)
    if unknown:
        raise ValueError(
            f"extra may hold only {list(_TOP_OPTIONAL)}, got unknown keys {sorted(unknown)}"
        )
    world = extra.get("world", world)
    quality = extra.get("quality", quality)
    data: dict[str, Any] = {"format": CALIBRATION_FORMAT}
    if world is not None:
        data["world"] = world
    data["cameras"] = [_camera_to_data(cam) for cam in group]
    if quality is not None:
        data["quality"] = quality
    text = dump_yaml(data, header=_YAML_HEADER)
    # What we write must read back (catches bad `extra` content early).
    calibration_from_data(parse_yaml(text), "calibration to be written")
    return text


def save_calibration(
    path: str | os.PathLike[str],
    group: CameraGroup | Calibration,
    extra: Mapping[str, Any] | None = None,
) -> None:
    """Write a ``calibration.yaml`` atomically.

    Floats are written exactly: ``save_calibration(p, read_calibration(p))``
    reproduces a file we wrote byte for byte.
    """
    write_text_atomic(path, calibration_to_yaml(group, extra))


# --------------------------------------------------------------------------
# anipose / FreeMoCap calibration.toml
# --------------------------------------------------------------------------
_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
_TOML_KEYS = ("name", "size", "matrix", "distortions", "rotation", "translation")


def _unit_scale(units: str | float, fields: Fields, field: str) -> float:
    if isinstance(units, str):
        if units not in _UNITS:
            raise fields.error(field, f"unknown unit {units!r}; expected one of {list(_UNITS)}")
        return _UNITS[units]
    if isinstance(units, bool) or not isinstance(units, (int, float)) or not units > 0:
        raise fields.error(field, f"expected 'm', 'cm', 'mm' or a positive factor, got {units!r}")
    return float(units)


def import_anipose_toml(
    path: str | os.PathLike[str], units: str | float | None = None
) -> CameraGroup:
    """Read an anipose / FreeMoCap / Pose2Sim ``calibration.toml``.

    The layout: one ``[cam_N]`` table per camera with ``name``, ``size``
    ``[w, h]``, ``matrix`` (3x3 K), ``distortions`` (OpenCV order), ``rotation``
    (Rodrigues vector; a 3x3 matrix is accepted too) and ``translation``, with
    the same ``x_cam = R x_world + t`` convention as ours; an optional
    ``[metadata]`` table. Other keys are ignored; ``fisheye = true`` is refused.

    Parameters
    ----------
    path
        The TOML file.
    units
        Unit of ``translation``: ``"m"``, ``"cm"``, ``"mm"`` or a factor to metres.
        anipose stores whatever unit the board square size was given in
        (usually mm). Default: ``metadata.units`` when the file has it (files we
        export say ``"m"``), else an error asking for it.

    Returns
    -------
    CameraGroup
        Cameras in file order, translations in metres.
    """
    path = Path(path)
    fields = Fields(path)
    if not path.is_file():
        raise InputError(f"{path}: calibration TOML file not found")
    try:
        data = tomllib.loads(
            read_text_limited(path, CALIBRATION_MAX_BYTES, "calibration TOML file")
        )
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the calibration TOML file: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML: {exc}") from exc
    meta = data.get("metadata", {})
    if not isinstance(meta, dict):
        raise fields.error("metadata", f"expected a table, got {describe(meta)}")
    file_units = meta.get("units")
    if file_units is not None:
        file_scale = _unit_scale(file_units, fields, "metadata.units")
    if units is None:
        if file_units is None:
            raise InputError(
                f"{path}: the file does not say the unit of 'translation' (no metadata.units); "
                "pass units='mm' (anipose and FreeMoCap default), 'cm' or 'm'"
            )
        scale = file_scale
    else:
        scale = _unit_scale(units, fields, "units (argument)")
        if file_units is not None and not math.isclose(scale, file_scale):
            raise InputError(
                f"{path}: metadata.units: the file says {file_units!r} "
                f"but units={units!r} was passed"
            )
    cameras: list[Camera] = []
    first: dict[str, str] = {}
    for section, cam in data.items():
        if section == "metadata":
            continue
        cam = fields.mapping(cam, section)
        fields.keys(cam, section, _TOML_KEYS, allow_unknown=True)
        if cam.get("fisheye", False):
            raise fields.error(
                join_field(section, "fisheye"),
                "fisheye cameras are not supported (bodymetry uses the OpenCV pinhole model)",
            )
        name = cam["name"]
        if isinstance(name, int) and not isinstance(name, bool):
            name = str(name)
        name = fields.string(name, join_field(section, "name"))
        size = cam["size"]
        size_field = join_field(section, "size")
        if not isinstance(size, list) or len(size) != 2:
            raise fields.error(size_field, f"expected [width, height], got {describe(size)}")
        w = fields.integer(size[0], join_field(size_field, 0), minimum=1)
        h = fields.integer(size[1], join_field(size_field, 1), minimum=1)
        K = _intrinsics(fields, cam["matrix"], join_field(section, "matrix"))
        dist = fields.array(
            cam["distortions"], join_field(section, "distortions"), (_DIST_LENGTHS,)
        )
        rot_field = join_field(section, "rotation")
        rot = cam["rotation"]
        if isinstance(rot, list) and rot and isinstance(rot[0], list):
            R = _rotation(fields, rot, rot_field)
        else:
            rvec = fields.array(rot, rot_field, (3,), "a Rodrigues rotation vector (3 numbers)")
            R = Rotation.from_rotvec(rvec).as_matrix()
        t = fields.array(cam["translation"], join_field(section, "translation"), (3,)) * scale
        if name in first:
            raise fields.error(
                join_field(section, "name"),
                f"duplicate camera name {name!r} (also [{first[name]}])",
            )
        first[name] = section
        try:
            cameras.append(Camera(name=name, size=(w, h), K=K, dist=dist, R=R, t=t))
        except ValueError as exc:
            raise fields.error(section, str(exc)) from exc
    if not cameras:
        raise InputError(f"{path}: no camera tables ([cam_0], [cam_1], ...) found")
    group = CameraGroup(cameras)
    far = float(np.linalg.norm(group.centers, axis=1).max())
    if far > 1000.0:
        raise InputError(
            f"{path}: camera centres lie up to {far:.0f} m from the origin after reading "
            f"translations as {units if units is not None else file_units!r}; "
            "the file is probably in millimetres: pass units='mm'"
        )
    return group


def _toml_value(value: Any) -> str:
    value = _plain_data(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=True)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} to the calibration TOML")


def export_anipose_toml(
    path: str | os.PathLike[str],
    group: CameraGroup | Calibration,
    metadata: Mapping[str, Any] | None = None,
) -> None:
    """Write the cameras in the anipose / FreeMoCap ``calibration.toml`` layout.

    Translations are written in **metres** and ``[metadata] units = "m"`` says so
    (anipose ignores unknown metadata); rotations as Rodrigues vectors written
    with ``repr`` so :func:`import_anipose_toml` recovers R to ~1e-16. K,
    distortion and t read back bit-exactly.

    Parameters
    ----------
    metadata
        Extra scalar ``[metadata]`` entries (e.g. ``{"error": 0.31}``).
    """
    if isinstance(group, Calibration):
        group = group.cameras
    lines = [
        "# Camera calibration in the anipose / FreeMoCap layout, written by bodymetry.",
        "# x_cam = R x_world + t; rotation is a Rodrigues vector; translation in metres.",
    ]
    for i, cam in enumerate(group):
        lines += [
            "",
            f"[cam_{i}]",
            f"name = {_toml_value(cam.name)}",
            f"size = {_toml_value(list(cam.size))}",
            f"matrix = {_toml_value(cam.K)}",
            f"distortions = {_toml_value(cam.dist)}",
            f"rotation = {_toml_value(Rotation.from_matrix(cam.R).as_rotvec())}",
            f"translation = {_toml_value(cam.t)}",
            "fisheye = false",
        ]
    meta: dict[str, Any] = {"units": "m"}
    for key, value in (metadata or {}).items():
        if key == "units":
            raise ValueError("metadata 'units' is set by export_anipose_toml (always 'm')")
        if not re.fullmatch(r"[A-Za-z0-9_-]+", key):
            raise ValueError(f"metadata key {key!r} must be a bare TOML key")
        meta[key] = value
    lines += ["", "[metadata]"] + [f"{k} = {_toml_value(v)}" for k, v in meta.items()]
    write_text_atomic(path, "\n".join(lines) + "\n")
