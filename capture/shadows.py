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

:func:`floor_shadows` keeps the shadow labels that pass (the *floor shadows*);
the others are left for the evidence fusion (:mod:`bodymetry.capture.fusion`)
to weigh as person. The segmenter's soft outline spreads over the shadow where
it touches the feet: there (:func:`at_feet`: the floor point within reach of
the body's footprint) the capture stage keeps a confirmed floor shadow out of
the silhouette where the segmenter is unsure. "Plainly lit" is strict on
purpose (well below the change
threshold, and a pixel from any changed pixel) so that a soft shadow's faint
penumbra, labelled shadow in one view and just below the threshold in another,
does not count as lit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from bodymetry.calibration.camera import CameraGroup
from bodymetry.errors import InputError

__all__ = ["FloorShadow", "at_feet", "floor_points", "floor_shadows"]


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

    Returns
    -------
    list of (FloorShadow or None)
        Per camera the shadow pixels whose floor point another camera sees dark
        (labelled shadow, within ``margin``) and no other camera sees lit, with
        those floor points (None where ``shadows`` is None).
    """
    if not len(cameras) == len(shadows) == len(lit):
        raise InputError(
            f"floor_shadows: {len(cameras)} cameras, {len(shadows)} shadow masks, "
            f"{len(lit)} lit masks"
        )
    kernel = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    plain = [None if m is None else cv2.erode(m.astype(np.uint8), kernel).astype(bool) for m in lit]
    dark = [
        None if m is None else cv2.dilate(m.astype(np.uint8), kernel).astype(bool) for m in shadows
    ]
    out: list[FloorShadow | None] = []
    for c, shadow in enumerate(shadows):
        if shadow is None:
            out.append(None)
            continue
        ys, xs = np.nonzero(shadow)
        floor = np.zeros(shadow.shape, bool)
        points = np.zeros((0, 3))
        if ys.size:
            points, lit_elsewhere, dark_elsewhere = _seen_from_others(
                cameras, c, np.column_stack([xs, ys]), plain, dark
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
) -> tuple[np.ndarray, np.ndarray]:
    """The floor points of camera ``c``'s ``pixels`` (N, 2), whether another camera
    sees them as plainly lit background, and whether one sees them dark.

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
        for seen, masks in ((lit, plain), (seen_dark, dark)):
            hit = np.zeros(len(q), bool)
            hit[inside] = masks[k][v[inside], u[inside]]
            seen[valid] |= hit
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
