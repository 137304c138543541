"""The anipose / FreeMoCap / Pose2Sim ``calibration.toml``: import and export.

The layout: one ``[cam_N]`` table per camera with ``name``, ``size`` ``[w, h]``,
``matrix`` (3x3 K), ``distortions`` (OpenCV order), ``rotation`` (Rodrigues
vector; a 3x3 matrix is accepted too) and ``translation``, with the same
``x_cam = R x_world + t`` convention as ``calibration.yaml``
(:mod:`calibration.io`); an optional ``[metadata]`` table.
"""

from __future__ import annotations

import json
import math
import os
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.calibration.io import (
    CALIBRATION_MAX_BYTES,
    DIST_LENGTHS,
    Calibration,
    intrinsics_from_data,
    rotation_from_data,
)
from bodymetry.errors import InputError
from bodymetry.fileio import read_text_limited, write_text_atomic
from bodymetry.schema import Fields, describe, join_field, plain_data

__all__ = ["export_anipose_toml", "import_anipose_toml"]

_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
_TOML_KEYS = ("name", "size", "matrix", "distortions", "rotation", "translation")


def _unit_scale(units: str | float, fields: Fields, field: str) -> float:
    """Metres per unit of ``units`` (a unit name or a positive factor)."""
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
    data = _read_toml(path)
    scale, stated = _translation_scale(path, fields, data, units)
    group = _cameras_from_tables(path, fields, data, scale)
    _check_centres_plausible(path, group, stated)
    return group


def _read_toml(path: Path) -> dict[str, Any]:
    """Read and parse the TOML file (size-limited); every failure is an InputError."""
    if not path.is_file():
        raise InputError(f"{path}: calibration TOML file not found")
    try:
        return tomllib.loads(
            read_text_limited(path, CALIBRATION_MAX_BYTES, "calibration TOML file")
        )
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the calibration TOML file: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML: {exc}") from exc


def _translation_scale(
    path: Path, fields: Fields, data: dict[str, Any], units: str | float | None
) -> tuple[float, Any]:
    """The factor from the file's translation unit to metres, and the unit as stated.

    ``units`` (the argument) wins when given but must agree with
    ``metadata.units`` when the file has it; without either it is an error.
    The stated unit (argument, else the file's) is returned for messages.
    """
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
    return scale, units if units is not None else file_units


def _cameras_from_tables(
    path: Path, fields: Fields, data: dict[str, Any], scale: float
) -> CameraGroup:
    """Every table but ``[metadata]`` as a camera, in file order; names must be unique."""
    cameras: list[Camera] = []
    first: dict[str, str] = {}
    for section, table in data.items():
        if section == "metadata":
            continue
        name, size, K, dist, R, t = _camera_table(fields, section, table, scale)
        if name in first:
            raise fields.error(
                join_field(section, "name"),
                f"duplicate camera name {name!r} (also [{first[name]}])",
            )
        first[name] = section
        try:
            cameras.append(Camera(name=name, size=size, K=K, dist=dist, R=R, t=t))
        except ValueError as exc:
            raise fields.error(section, str(exc)) from exc
    if not cameras:
        raise InputError(f"{path}: no camera tables ([cam_0], [cam_1], ...) found")
    return CameraGroup(cameras)


def _camera_table(
    fields: Fields, section: str, value: Any, scale: float
) -> tuple[str, tuple[int, int], np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The checked fields of one ``[cam_N]`` table.

    Returns
    -------
    tuple
        ``(name, (width, height), K (3, 3), dist (n,), R (3, 3), t (3,))``, t in
        metres (the file's translation times ``scale``).
    """
    cam = fields.mapping(value, section)
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
    K = intrinsics_from_data(fields, cam["matrix"], join_field(section, "matrix"))
    dist = fields.array(cam["distortions"], join_field(section, "distortions"), (DIST_LENGTHS,))
    rot_field = join_field(section, "rotation")
    rot = cam["rotation"]
    if isinstance(rot, list) and rot and isinstance(rot[0], list):
        R = rotation_from_data(fields, rot, rot_field)
    else:
        rvec = fields.array(rot, rot_field, (3,), "a Rodrigues rotation vector (3 numbers)")
        R = Rotation.from_rotvec(rvec).as_matrix()
    t = fields.array(cam["translation"], join_field(section, "translation"), (3,)) * scale
    return name, (w, h), K, dist, R, t


def _check_centres_plausible(path: Path, group: CameraGroup, stated: Any) -> None:
    """Refuse camera centres over 1 km from the origin (a file in mm read as metres)."""
    far = float(np.linalg.norm(group.centers, axis=1).max())
    if far > 1000.0:
        raise InputError(
            f"{path}: camera centres lie up to {far:.0f} m from the origin after reading "
            f"translations as {stated!r}; "
            "the file is probably in millimetres: pass units='mm'"
        )


def _toml_value(value: Any) -> str:
    value = plain_data(value)
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
