"""``calibration.yaml``: our calibration file format (reading, validating, writing).

The format is documented in ``docs/calibration-format.md``. In short::

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

The generic validation and YAML-writing toolkit lives in :mod:`bodymetry.schema`;
the anipose / FreeMoCap ``calibration.toml`` in :mod:`calibration.anipose`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.fileio import parse_yaml, write_text_atomic
from bodymetry.schema import (
    Fields,
    check_format,
    describe,
    dump_yaml,
    join_field,
    plain_number,
    read_yaml_mapping,
)

__all__ = [
    "CALIBRATION_FORMAT",
    "CALIBRATION_MAX_BYTES",
    "DIST_LENGTHS",
    "Calibration",
    "calibration_from_data",
    "calibration_to_yaml",
    "intrinsics_from_data",
    "load_calibration",
    "read_calibration",
    "rotation_from_data",
    "save_calibration",
]

CALIBRATION_FORMAT = "bodymetry-calibration/1"
#: The largest calibration.yaml or calibration.toml read (a rig of dozens of
#: cameras is a few kB; anything near this is the wrong file).
CALIBRATION_MAX_BYTES = 1_000_000
#: The lengths of distortion vector OpenCV accepts.
DIST_LENGTHS = (4, 5, 8, 12, 14)

_CAMERA_KEYS = ("name", "size", "K", "dist", "R", "t")
_TOP_REQUIRED = ("format", "cameras")
_TOP_OPTIONAL = ("world", "quality")
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


def rotation_from_data(fields: Fields, value: Any, field: str) -> np.ndarray:
    """A rotation matrix (3, 3) from a parsed 3x3 list, checked (and made exact if rounded).

    Raises (through ``fields``) when ``R @ R.T`` deviates from I by more than
    1e-3 or when R is a reflection; between 1e-9 and 1e-3 the nearest rotation
    (polar decomposition) is returned.
    """
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


def intrinsics_from_data(fields: Fields, value: Any, field: str) -> np.ndarray:
    """An intrinsic matrix K (3, 3) from a parsed 3x3 list.

    The matrix must read ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` with positive
    focal lengths (raises through ``fields`` otherwise).
    """
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
    K = intrinsics_from_data(fields, cam["K"], join_field(field, "K"))
    dist = fields.array(
        cam["dist"],
        join_field(field, "dist"),
        (DIST_LENGTHS,),
        "a list of distortion coefficients in OpenCV order (4, 5, 8, 12 or 14 numbers; "
        "[0, 0, 0, 0, 0] for none)",
    )
    R = rotation_from_data(fields, cam["R"], join_field(field, "R"))
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
    data = read_yaml_mapping(path, "calibration file", CALIBRATION_MAX_BYTES)
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
