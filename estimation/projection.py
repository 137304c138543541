"""Model silhouettes: project the body's level of detail into camera images.

Used to render the discriminative training set and by the generative
likelihood. The ~3,000-triangle LOD is filled with one ``cv2.fillPoly`` call per
view (sub-pixel vertex positions, 1/16 px); a silhouette needs no depth order.
"""

from __future__ import annotations

import cv2
import numpy as np

from calibration.camera import Camera

#: Fixed-point bits of cv2.fillPoly vertex coordinates.
_SHIFT = 4


def fill_silhouette(pixels: np.ndarray, faces: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Rasterize projected triangles into a binary mask.

    Parameters
    ----------
    pixels : (V, 2) float
        Projected vertices (x, y) in pixels; NaN marks vertices behind the camera
        (their triangles are skipped).
    faces : (T, 3) int
    size : (int, int)
        Image ``(width, height)``.

    Returns
    -------
    (H, W) bool
    """
    w, h = size
    mask = np.zeros((h, w), np.uint8)
    tri = pixels[faces]  # (T, 3, 2)
    ok = np.all(np.isfinite(tri), axis=(1, 2))
    # Keep coordinates in a range fillPoly's fixed point can hold.
    tri = np.clip(tri[ok], -4 * max(w, h), 5 * max(w, h))
    if len(tri):
        cv2.fillPoly(mask, np.round(tri * (1 << _SHIFT)).astype(np.int32), 1, shift=_SHIFT)
    return mask.astype(bool)


def project_silhouettes(
    vertices: np.ndarray, faces: np.ndarray, cameras: list[Camera]
) -> np.ndarray:
    """Silhouettes of one mesh in every camera.

    Parameters
    ----------
    vertices : (V, 3) float
        World coordinates, metres.
    faces : (T, 3) int
    cameras : list of Camera, all of one image size

    Returns
    -------
    (C, H, W) bool
    """
    return np.stack([fill_silhouette(cam.project(vertices), faces, cam.size) for cam in cameras])
