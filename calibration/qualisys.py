"""Qualisys Track Manager calibrations (``.qca.txt``), read as Pose2Sim reads them.

A QCA file is XML: one ``<camera>`` per camera under ``<cameras>``, each with

* ``serial`` (the camera's name here), ``model``, ``avg-residual`` (mm);
* ``<fov_video left top right bottom>``: the video window on the sensor, in
  pixels, inclusive, so the image is ``right - left + 1`` by ``bottom - top + 1``;
* ``<intrinsic>``: ``focalLengthU/V``, ``centerPointU/V``,
  ``radialDistortion1..3`` and ``tangentalDistortion1..2`` (QTM's spelling),
  all in 1/64 pixel units (QTM's sub-pixel unit);
* ``<transform x y z r11 .. r33>``: the camera's pose in the world, position in
  millimetres.

The conversion follows Pose2Sim 0.10.49 (``Pose2Sim/calibration.py``:
``read_qca`` and ``calib_qca_fun``; BSD-3-Clause, perfanalytics) exactly, and
``tests/calibration/test_qualisys.py`` checks it against figures computed with
Pose2Sim's own code:

* ``K = [[fU, 0, cU - left], [0, fV, cV - top], [0, 0, 1]]`` with ``fU =
  focalLengthU / 64 / binning`` (likewise V, and ``cU = centerPointU / 64 /
  binning``; the window offset ``left`` / ``top`` is not divided);
* ``dist = [k1, k2, p1, p2, k3]``, each QCA value ``/ 64 / binning`` (Pose2Sim
  divides the distortion coefficients by 64 as well and drops ``k3``, which
  QTM writes as 0; we keep it as the fifth coefficient);
* with ``M`` the 3x3 matrix of ``r11 .. r33`` written row by row and ``p`` the
  position in metres, QTM's camera looks along its -z axis with y up, so the
  OpenCV camera (z forward, y down) is QTM's turned by pi about its x axis:
  ``R = diag(1, -1, -1) @ M`` and ``t = -R @ p`` (the camera centre is ``p``).
  Pose2Sim computes the same product with ``cos(pi)`` and ``sin(pi)``; the
  results differ by about 1e-16.

The world frame is QTM's: z up, metres, as ours. ``skew`` is ignored (as
Pose2Sim does; QTM writes 0) and so is ``viewrotation`` (a warning is logged
when either is not zero).

Differences from Pose2Sim: every camera is kept (Pose2Sim keeps only cameras
whose ``model`` says ``video`` or ``none``; marker-only cameras have no video
and are simply not matched to one by :mod:`bodymetry.importers`), and cameras
are sorted by Pose2Sim's natural order of their serials.

Safety: the file is read through :func:`bodymetry.fileio.read_text_limited`
(at most :data:`QCA_MAX_BYTES`) and a document type declaration (``DOCTYPE``,
``ENTITY``) is refused before parsing, so entity expansion ("billion laughs")
cannot happen.
"""

from __future__ import annotations

import logging
import math
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.errors import InputError
from bodymetry.fileio import read_text_limited

__all__ = [
    "QCA_MAX_BYTES",
    "QCA_SUBPIXELS",
    "QcaCalibration",
    "import_qca",
    "natural_key",
    "read_qca",
]

log = logging.getLogger(__name__)

#: The largest ``.qca.txt`` read (a rig of dozens of cameras is tens of kB).
QCA_MAX_BYTES = 1_000_000
#: QTM's sub-pixel unit: intrinsics and distortion are written in 1/64 px.
QCA_SUBPIXELS = 64.0

# QTM's camera looks along -z with y up; OpenCV's along +z with y down: a turn of
# pi about the camera's x axis.
_QTM_TO_OPENCV = np.diag([1.0, -1.0, -1.0])
_ROTATION_KEYS = ("r11", "r12", "r13", "r21", "r22", "r23", "r31", "r32", "r33")
_FORBIDDEN = re.compile(r"<!\s*(DOCTYPE|ENTITY)", re.IGNORECASE)


@dataclass(frozen=True)
class QcaCalibration:
    """A QCA file, converted.

    Attributes
    ----------
    cameras : CameraGroup
        One camera per ``<camera>``, named by its ``serial``, in natural order
        of the serials (``cam2`` before ``cam10``); ``x_cam = R x_world + t``,
        metres.
    models : mapping of str to str
        Camera name -> the ``model`` attribute (``"Miqus Video"``, ``"none"``, ...).
    residuals_mm : mapping of str to float
        Camera name -> ``avg-residual`` (QTM's mean residual, millimetres).
    """

    cameras: CameraGroup
    models: Mapping[str, str]
    residuals_mm: Mapping[str, float]


def natural_key(text: str) -> list[int | str]:
    """Sort key of Pose2Sim's ``natural_sort_key``: ``cam2`` before ``cam10``."""
    return [int(c) if c.isdigit() else c.lower() for c in re.split(r"(\d+)", str(text))]


def _parse(path: Path) -> ET.Element:
    if not path.is_file():
        raise InputError(f"{path}: Qualisys calibration (.qca.txt) not found")
    try:
        text = read_text_limited(path, QCA_MAX_BYTES, "Qualisys calibration file")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the Qualisys calibration file: {exc}") from exc
    if _FORBIDDEN.search(text):
        raise InputError(
            f"{path}: the file declares a DOCTYPE or ENTITY; a Qualisys calibration has "
            "none, and such declarations are refused (entity expansion)"
        )
    try:
        return ET.fromstring(text.lstrip("\ufeff"))
    except ET.ParseError as exc:
        raise InputError(f"{path}: not valid XML: {exc}") from exc


def _number(path: Path, element: ET.Element, key: str, where: str, *, default=None) -> float:
    raw = element.get(key)
    if raw is None:
        if default is not None:
            return default
        raise InputError(f"{path}: {where}: <{element.tag}> has no attribute {key!r}")
    try:
        value = float(raw)
    except ValueError:
        raise InputError(
            f"{path}: {where}: <{element.tag} {key}=...>: expected a number, got {raw!r}"
        ) from None
    if not math.isfinite(value):
        raise InputError(f"{path}: {where}: <{element.tag} {key}=...>: got {raw!r}")
    return value


def _child(path: Path, camera: ET.Element, tag: str, where: str) -> ET.Element:
    element = camera.find(tag)
    if element is None:
        raise InputError(f"{path}: {where}: the <camera> has no <{tag}> element")
    return element


def read_qca(path: str | os.PathLike[str], *, binning_factor: int = 1) -> QcaCalibration:
    """Read a Qualisys ``.qca.txt`` calibration (conventions in the module docstring).

    Parameters
    ----------
    path
        The file.
    binning_factor
        Pose2Sim's ``[calibration.convert.qualisys] binning_factor``: 2 when the
        video was filmed binned (e.g. 540p on a 1080p sensor), else 1.

    Returns
    -------
    QcaCalibration

    Raises
    ------
    InputError
        A missing, oversized or malformed file, a DOCTYPE, a camera without a
        required element or attribute, duplicate serials, a ``transform`` that is
        not a rotation; the message names the file and the camera.
    """
    path = Path(path)
    if isinstance(binning_factor, bool) or not isinstance(binning_factor, int):
        raise InputError(f"binning_factor: expected an integer >= 1, got {binning_factor!r}")
    if binning_factor < 1:
        raise InputError(f"binning_factor: expected an integer >= 1, got {binning_factor}")
    root = _parse(path)
    elements = root.findall("cameras/camera")
    if not elements:
        raise InputError(
            f"{path}: no <cameras><camera> elements (<{root.tag}> at the top); "
            "not a Qualisys calibration?"
        )
    found: list[tuple[Camera, str, float]] = []
    first: dict[str, int] = {}
    for index, element in enumerate(elements):
        where = f"camera {index}"
        serial = (element.get("serial") or "").strip()
        if not serial:
            raise InputError(f"{path}: {where}: the <camera> has no 'serial' (its name)")
        where = f"camera {index} (serial {serial!r})"
        if serial in first:
            raise InputError(f"{path}: {where}: duplicate serial (also camera {first[serial]})")
        first[serial] = index
        residual = _number(path, element, "avg-residual", where, default=math.nan)
        camera = _camera(path, element, serial, where, binning_factor)
        found.append((camera, element.get("model", ""), residual))
    found.sort(key=lambda item: natural_key(item[0].name))
    return QcaCalibration(
        cameras=CameraGroup([cam for cam, _, _ in found]),
        models={cam.name: model for cam, model, _ in found},
        residuals_mm={cam.name: res for cam, _, res in found},
    )


def _camera(
    path: Path, element: ET.Element, serial: str, where: str, binning_factor: int
) -> Camera:
    """One ``<camera>`` as a :class:`Camera` named ``serial`` (``where`` names it in errors)."""
    b = float(binning_factor)
    fov = _child(path, element, "fov_video", where)
    left, top, right, bottom = (
        _number(path, fov, key, where) for key in ("left", "top", "right", "bottom")
    )
    width, height = (right - left + 1) / b, (bottom - top + 1) / b
    if not (width >= 1 and height >= 1 and width.is_integer() and height.is_integer()):
        raise InputError(
            f"{path}: {where}: <fov_video> gives an image of {width:g}x{height:g} px "
            f"(binning factor {binning_factor}); expected whole positive sizes"
        )
    K, dist = _lens(path, element, where, left, top, b)
    R, t = _pose(path, element, where)
    try:
        return Camera(
            name=serial, size=(int(width), int(height)), K=K, dist=np.array(dist), R=R, t=t
        )
    except ValueError as exc:
        raise InputError(f"{path}: {where}: {exc}") from exc


def _lens(
    path: Path, element: ET.Element, where: str, left: float, top: float, b: float
) -> tuple[np.ndarray, list[float]]:
    """K (3, 3) and ``[k1, k2, p1, p2, k3]`` from ``<intrinsic>`` (1/64 px units, binned by
    ``b``; the principal point shifted by the video window's ``left`` / ``top``)."""
    intr = _child(path, element, "intrinsic", where)

    def sub(key: str, default: float | None = None) -> float:
        return _number(path, intr, key, where, default=default) / QCA_SUBPIXELS / b

    # QTM spells it "tangental"; accept the dictionary spelling too.
    tangential = [
        sub(k) if intr.get(k) is not None else sub(k.replace("tangental", "tangential"))
        for k in ("tangentalDistortion1", "tangentalDistortion2")
    ]
    dist = [sub("radialDistortion1"), sub("radialDistortion2"), *tangential]
    dist.append(sub("radialDistortion3", 0.0))
    K = np.array(
        [
            [sub("focalLengthU"), 0.0, sub("centerPointU") - left],
            [0.0, sub("focalLengthV"), sub("centerPointV") - top],
            [0.0, 0.0, 1.0],
        ]
    )
    for key in ("skew", "viewrotation"):
        source = intr if key == "skew" else element
        if _number(path, source, key, where, default=0.0) != 0:
            log.warning(
                "%s: %s: %s=%s is ignored (as Pose2Sim does)", path, where, key, source.get(key)
            )
    return K, dist


def _pose(path: Path, element: ET.Element, where: str) -> tuple[np.ndarray, np.ndarray]:
    """The OpenCV camera_from_world ``R`` (3, 3) and ``t`` (3,) in metres from ``<transform>``."""
    tr = _child(path, element, "transform", where)
    position = np.array([_number(path, tr, k, where) for k in ("x", "y", "z")]) / 1000.0
    M = np.array([_number(path, tr, k, where) for k in _ROTATION_KEYS]).reshape(3, 3)
    if not np.allclose(M @ M.T, np.eye(3), atol=1e-6) or np.linalg.det(M) <= 0:
        raise InputError(
            f"{path}: {where}: <transform r11..r33> is not a rotation "
            f"(|M M^T - I| = {np.abs(M @ M.T - np.eye(3)).max():.2g}, "
            f"det = {np.linalg.det(M):.6g})"
        )
    R = _QTM_TO_OPENCV @ M
    t = -R @ position
    return R, t


def import_qca(path: str | os.PathLike[str], *, binning_factor: int = 1) -> CameraGroup:
    """The cameras of a Qualisys ``.qca.txt`` (:func:`read_qca` without the notes)."""
    return read_qca(path, binning_factor=binning_factor).cameras
