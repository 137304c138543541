"""Shadows without colour: a cast shadow lies on the floor, and every camera agrees.

The colour test of background subtraction calls a pixel *shadow* when it is
darker than the background with the same chromaticity
(:mod:`bodymetry.capture.background`). In a grey room the shaded side of a
white, grey or black garment passes that test too. Geometry tells them apart:

A cast shadow is a patch of the floor. Follow a shadow-labelled pixel's viewing
ray to the floor plane (z = 0) and look at that floor point from the other
calibrated cameras: if it is a shadow, every camera that sees it sees it dark
(or has the person in front of it), and the cameras around the person see it
(a cast shadow lies beside the feet, in the capture volume). If any other
camera sees it as plainly lit background, or none sees it dark, the floor
there is not a shadow all cameras agree on, so what the first camera saw was
not the floor: it was something standing in the room, darker than the wall
behind it, i.e. the person's shaded side (whose floor point, far behind the
person, is lit, or outside the other cameras' views).

Where the floor point really is in shadow (soft light darkens the floor all
round the feet), the shaded back of a calf in front of it would pass that test.
Photometry settles it: a shadow on a matte floor dims the floor by the same
factor in every camera (the brightness ratio to the empty scene depends on the
light that reaches the floor, not on the viewing direction), while a garment in
front of the shadow has its own brightness, whatever the floor behind it. So
with ``brightness`` given, a camera confirms a floor point as dark only where
its brightness ratio there matches the first camera's within
``brightness_tol`` (log units, over the ``margin`` neighbourhood). Measured on
eight studio sessions (white, light grey, black, wall-coloured and saturated
clothing; docs/capture.md), a tolerance of 0.05 keeps 99.2 % of the true floor
shadow at the feet and returns 51.5 % of the body pixels the plain test took
for floor shadow there.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from bodymetry.calibration.camera import CameraGroup
from bodymetry.errors import InputError

__all__ = ["BRIGHTNESS_TOL", "FloorShadow", "at_feet", "floor_points", "floor_shadows"]

#: Two cameras see the same floor shadow when their brightness ratios to the empty
#: scene differ by less than this (log units, about 5 %).
BRIGHTNESS_TOL = 0.05


def floor_points(camera, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the viewing rays of ``pixels`` meet the floor plane z = 0.

    Parameters
    ----------
    camera : Camera
    pixels : (N, 2) float
        Observed (distorted) pixel coordinates.

    Returns
    -------
    points : (N, 3) float
        The floor points (NaN where the ray does not go down to the floor).
    valid : (N,) bool
    """
    d = camera.ray(np.asarray(pixels, float))
    c = camera.center
    with np.errstate(invalid="ignore", divide="ignore"):
        valid = np.isfinite(d).all(axis=1) & (d[:, 2] < -1e-6)
        t = np.where(valid, -c[2] / d[:, 2], np.nan)
    return c + t[:, None] * d, valid


@dataclass(frozen=True)
class FloorShadow:
    """One view's confirmed floor shadow (:func:`floor_shadows`).

    Attributes
    ----------
    mask : (H, W) bool
        The shadow-labelled pixels the other views confirm on the floor.
    points : (N, 3) float
        Their floor points, in the order of ``np.nonzero(mask)`` (kept so that
        :func:`at_feet` does not follow the rays again).
    """

    mask: np.ndarray
    points: np.ndarray


def floor_shadows(
    cameras: CameraGroup,
    shadows: Sequence[np.ndarray | None],
    lit: Sequence[np.ndarray | None],
    margin: int = 1,
    brightness: Sequence[np.ndarray | None] | None = None,
    brightness_tol: float = BRIGHTNESS_TOL,
) -> list[FloorShadow | None]:
    """Per view, the shadow-labelled pixels that can be a shadow on the floor.

    Parameters
    ----------
    cameras : CameraGroup
        The calibrated rig (world z up, floor z = 0).
    shadows : sequence of ((H_c, W_c) bool or None)
        Per camera the colour test's shadow label (None: no background).
    lit : sequence of ((H_c, W_c) bool or None)
        Per camera the pixels that plainly show the unchanged background.
    margin : int
        A lit pixel counts only when every pixel within ``margin`` is lit too.
    brightness : sequence of ((H_c, W_c) float32 or None), optional
        Per camera the log brightness ratio to the empty scene (``log alpha`` of
        the colour test). Given, a camera sees a floor point dark only where its
        ratio matches (module docstring); None: any shadow label confirms.
    brightness_tol : float
        Log units.

    Returns
    -------
    list of (FloorShadow or None)
        Per camera the shadow pixels whose floor point another camera sees dark
        (labelled shadow, within ``margin``, as bright as here) and no other
        camera sees lit, with those floor points (None where ``shadows`` is None).
    """
    if not len(cameras) == len(shadows) == len(lit):
        raise InputError(
            f"floor_shadows: {len(cameras)} cameras, {len(shadows)} shadow masks, "
            f"{len(lit)} lit masks"
        )
    if brightness is not None and len(brightness) != len(cameras):
        raise InputError(
            f"floor_shadows: {len(cameras)} cameras, {len(brightness)} brightness maps"
        )
    if not brightness_tol > 0:
        raise InputError(f"floor_shadows: brightness_tol must be > 0, got {brightness_tol}")
    kernel = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    plain = [None if m is None else cv2.erode(m.astype(np.uint8), kernel).astype(bool) for m in lit]
    dark = [
        None if m is None else cv2.dilate(m.astype(np.uint8), kernel).astype(bool) for m in shadows
    ]
    # The brightness range over each pixel's neighbourhood, widened by the tolerance
    # (calibration and rounding move a floor point by about a pixel).
    ranges = [None] * len(cameras)
    if brightness is not None:
        ranges = [
            None if b is None else (
                cv2.erode(np.asarray(b, np.float32), kernel) - np.float32(brightness_tol),
                cv2.dilate(np.asarray(b, np.float32), kernel) + np.float32(brightness_tol),
            )
            for b in brightness
        ]  # fmt: skip
    out: list[FloorShadow | None] = []
    for c, shadow in enumerate(shadows):
        if shadow is None:
            out.append(None)
            continue
        ys, xs = np.nonzero(shadow)
        floor = np.zeros(shadow.shape, bool)
        points = np.zeros((0, 3))
        if ys.size:
            here = None if brightness is None else brightness[c]
            points, lit_elsewhere, dark_elsewhere = _seen_from_others(
                cameras,
                c,
                np.column_stack([xs, ys]),
                plain,
                dark,
                None if here is None else (np.asarray(here)[ys, xs], ranges),
            )
            keep = dark_elsewhere & ~lit_elsewhere
            floor[ys[keep], xs[keep]] = True
            points = points[keep]  # row-major, as np.nonzero(floor) lists them
        out.append(FloorShadow(floor, points))
    return out


def _seen_from_others(
    cameras: CameraGroup,
    c: int,
    pixels: np.ndarray,
    plain: Sequence[np.ndarray | None],
    dark: Sequence[np.ndarray | None],
    photometry: tuple[np.ndarray, Sequence[tuple[np.ndarray, np.ndarray] | None]] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The floor points of camera ``c``'s ``pixels`` (N, 2), whether another camera
    sees them as plainly lit background, and whether one sees them dark (and, with
    ``photometry`` = (the pixels' (N,) log brightness, per camera its (low, high)
    (H, W) range or None), as bright as camera ``c`` does).

    Returns
    -------
    points : (N, 3) float
        NaN where the ray misses the floor.
    lit, dark : (N,) bool
        A ray that misses the floor counts as lit (it cannot be a floor shadow).
    """
    points, valid = floor_points(cameras[c], pixels.astype(float))
    lit = ~valid
    seen_dark = np.zeros(len(pixels), bool)
    for k, cam in enumerate(cameras):
        if k == c or plain[k] is None or not valid.any():
            continue
        w, h = cam.size
        q = cam.project(points[valid])
        with np.errstate(invalid="ignore"):
            inside = np.isfinite(q).all(axis=1)
            u = np.where(inside, np.round(q[:, 0]), -1).astype(int)
            v = np.where(inside, np.round(q[:, 1]), -1).astype(int)
        inside &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
        hit = np.zeros(len(q), bool)
        hit[inside] = plain[k][v[inside], u[inside]]
        lit[valid] |= hit
        hit = np.zeros(len(q), bool)
        hit[inside] = dark[k][v[inside], u[inside]]
        if photometry is not None and photometry[1][k] is not None:
            low, high = photometry[1][k]
            b = photometry[0][valid][inside]
            hit[inside] &= (b >= low[v[inside], u[inside]]) & (b <= high[v[inside], u[inside]])
        seen_dark[valid] |= hit
    return points, lit, seen_dark


def at_feet(
    floor: Sequence[FloorShadow | None], footprint: np.ndarray, reach: float
) -> list[np.ndarray | None]:
    """Per view, the floor-shadow pixels whose floor point lies within ``reach`` of
    the body's footprint: the part of a cast shadow that touches the feet.

    Parameters
    ----------
    floor : sequence of (FloorShadow or None)
        :func:`floor_shadows`.
    footprint : (M, 2) float
        Floor-plane (x, y) of the body (e.g. its hull voxels), metres.
    reach : float
        Metres.

    Returns
    -------
    list of ((H_c, W_c) bool or None)
    """
    footprint = np.asarray(footprint, float).reshape(-1, 2)
    tree = cKDTree(footprint) if len(footprint) else None
    out: list[np.ndarray | None] = []
    for view in floor:
        if view is None:
            out.append(None)
            continue
        near = np.zeros(view.mask.shape, bool)
        if len(view.points) and tree is not None:
            ys, xs = np.nonzero(view.mask)
            close = tree.query(view.points[:, :2], distance_upper_bound=reach)[0] <= reach
            near[ys[close], xs[close]] = True
        out.append(near)
    return out
