"""Camera rays and projection with lens distortion, for the studio's rasterizer.

The studio renders bodies by projecting their vertices *with* the camera's lens
distortion (:func:`project_for_raster`) and the room and board by intersecting
each pixel's undistorted ray (:func:`pixel_rays`) with their planes. Points
beyond the lens model's monotonic range (:func:`lens_radius_limit`) are not
projected: a polynomial model can fold them back into the image.
"""

from __future__ import annotations

import cv2
import numpy as np

from bodymetry.calibration.camera import Camera


def pixel_rays(camera: Camera) -> np.ndarray:
    """Undistorted ray of every pixel centre, camera frame, z = 1.

    Returns
    -------
    (H, W, 3) float64
        ``(x, y, 1)`` with ``camera.project`` of ``camera.center + R.T @ ray``
        landing on the pixel centre (to ~1e-10 px).
    """
    w, h = camera.size
    grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), -1)
    if np.any(camera.dist != 0):
        und = cv2.undistortPoints(
            grid.reshape(-1, 1, 2),
            camera.K,
            camera.dist,
            R=np.eye(3),
            P=np.eye(3),
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14),
        ).reshape(h, w, 2)
    else:
        kinv = np.linalg.inv(camera.K)
        und = grid @ kinv[:2, :2].T + kinv[:2, 2]
    return np.concatenate([und, np.ones((h, w, 1))], axis=-1)


def _radial_limit(camera: Camera, r_image: float) -> float:
    """Largest undistorted radius (normalized) where the lens model is still
    monotonic, capped at 1.5x the image corner radius: beyond it a polynomial
    model can fold far-away points back into the image."""
    d = np.zeros(8)
    d[: min(8, camera.dist.size)] = camera.dist[:8]
    k1, k2, _, _, k3, k4, k5, k6 = d
    r = np.linspace(0.0, 4.0 * max(r_image, 0.1), 4001)
    r2 = r * r
    rd = r * (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    bad = np.flatnonzero(np.diff(rd) <= 0)
    r_mono = r[bad[0]] * 0.98 if bad.size else r[-1]
    return float(min(1.5 * r_image, r_mono))


def lens_radius_limit(camera: Camera) -> float:
    """The lens model's valid normalized radius for ``camera`` (from its image border's
    rays): points beyond it may fold back into the image and are not projected
    (``project_for_raster``'s ``r_limit``)."""
    w, h = camera.size
    border = np.concatenate(
        [
            np.stack([np.arange(w), np.zeros(w)], 1),
            np.stack([np.arange(w), np.full(w, h - 1)], 1),
            np.stack([np.zeros(h), np.arange(h)], 1),
            np.stack([np.full(h, w - 1), np.arange(h)], 1),
        ]
    ).astype(np.float64)
    if np.any(camera.dist != 0):
        und = cv2.undistortPoints(
            border.reshape(-1, 1, 2), camera.K, camera.dist, R=np.eye(3), P=np.eye(3),
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14),
        ).reshape(-1, 2)  # fmt: skip
    else:
        kinv = np.linalg.inv(camera.K)
        und = border @ kinv[:2, :2].T + kinv[:2, 2]
    return _radial_limit(camera, float(np.sqrt((und**2).sum(-1)).max()))


def project_for_raster(
    camera: Camera, points: np.ndarray, supersample: int = 1, r_limit: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Project world points for :func:`rasterize` (with lens distortion).

    Parameters
    ----------
    camera : Camera
    points : (N, 3) float
        World points, metres.
    supersample : int
        Pixel grid refinement: pixel centres of the ``s``-times finer grid.
    r_limit : float, optional
        Normalized radius beyond which points are marked invalid (see
        ``_radial_limit``); None: no limit.

    Returns
    -------
    xy : (N, 2) float
        Pixel coordinates on the (supersampled) grid.
    z : (N,) float
        Camera depth, metres.
    valid : (N,) bool
        In front of the camera and within the lens model's range.
    """
    pc = camera.to_camera(points)
    z = pc[:, 2]
    valid = z > 1e-6
    with np.errstate(divide="ignore", invalid="ignore"):
        n = pc[:, :2] / np.where(valid, z, 1.0)[:, None]
    if r_limit is not None:
        valid &= np.einsum("ij,ij->i", n, n) < r_limit**2
    xy = camera.distort_normalized(n) @ camera.K[:2, :2].T + camera.K[:2, 2]
    if supersample != 1:
        xy = supersample * (xy + 0.5) - 0.5
    return xy, z, valid
