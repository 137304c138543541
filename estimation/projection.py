"""Model silhouettes: project the body's level of detail into camera images.

Used to render the discriminative training set and by the generative
likelihood. Triangles are rasterized by the studio's vectorized coverage test
(``bodymetry.estimation.raster.coverage``, the inside rule of its z-buffer without the
depth): one ``cv2.fillPoly`` call with all triangles would apply the even-odd
rule and punch holes where the body overlaps itself (front and back faces, an
arm before the torso). The body is a closed mesh, so only its front faces are
drawn: the same pixels at 1.6x (quarter resolution) to 2.8x (full resolution)
the speed, measured on the level of detail.

Cameras of one rig may differ in image size: each silhouette is at its own
camera's size, and :meth:`CameraGroup.check_masks
<bodymetry.calibration.camera.CameraGroup.check_masks>` checks observed masks
against their cameras for the stages that take them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from bodymetry.calibration.camera import Camera, CameraGroup, tilt_matrix
from bodymetry.estimation.raster import coverage


def fill_silhouette(
    pixels: np.ndarray, faces: np.ndarray, size: tuple[int, int], closed: bool = True
) -> np.ndarray:
    """Rasterize projected triangles into a binary mask.

    Parameters
    ----------
    pixels : (V, 2) float
        Projected vertices (x, y) in pixels; NaN marks vertices behind the camera
        (their triangles are skipped).
    faces : (T, 3) int
    size : (int, int)
        Image ``(width, height)``.
    closed : bool
        ``faces`` form a closed mesh with outward counter-clockwise triangles
        (the body model's): only the front faces are drawn. False draws all.

    Returns
    -------
    (H, W) bool
    """
    valid = np.all(np.isfinite(pixels), axis=1)
    xy = np.where(valid[:, None], pixels, 0.0)
    return coverage(xy, faces, size, closed=closed, valid=valid)


def project_silhouettes(
    vertices: np.ndarray, faces: np.ndarray, cameras: CameraGroup | Sequence[Camera]
) -> np.ndarray | list[np.ndarray]:
    """Silhouettes of one mesh in every camera, each at its camera's own size.

    Parameters
    ----------
    vertices : (V, 3) float
        World coordinates, metres.
    faces : (T, 3) int
    cameras : CameraGroup (or any sequence of Camera)
        Their image sizes may differ.

    Returns
    -------
    (C, H, W) bool or list of (H_c, W_c) bool
        One mask per camera: stacked when every camera has the same size (as
        before mixed rigs were supported), a list otherwise. Either way
        ``masks[c]`` is camera ``c``'s mask, the same as that camera alone gives.
    """
    masks = [fill_silhouette(cam.project(vertices), faces, cam.size) for cam in cameras]
    if len({m.shape for m in masks}) <= 1 and masks:
        return np.stack(masks)
    return masks


def view_ious(
    cameras: CameraGroup,
    model: Sequence[np.ndarray],
    observed: Sequence[np.ndarray],
    used: Sequence[bool],
    unknown: Sequence[np.ndarray | None] | None = None,
) -> dict[str, float]:
    """Silhouette IoU per used view, keyed by camera name.

    Parameters
    ----------
    cameras : CameraGroup
        C cameras.
    model, observed : sequences of C (H_c, W_c) bool
    used : sequence of C bool
        The views to score (the others are left out).
    unknown : sequence of C ((H_c, W_c) bool or None), optional
        Pixels that are neither the person's nor background (someone nearer
        covers them): left out of both the intersection and the union, so the
        IoU is measured on the pixels that are the person's or background.
    """
    out = {}
    hidden = list(unknown) if unknown else [None] * len(model)
    for cam, m, o, u, h in zip(cameras, model, observed, used, hidden, strict=True):
        if u:
            if h is not None:
                m, o = m & ~h, o & ~h
            union = np.logical_or(m, o).sum()
            out[cam.name] = float(np.logical_and(m, o).sum() / max(union, 1))
    return out


def camera_arrays(cameras: CameraGroup | Sequence[Camera]) -> tuple[np.ndarray, ...]:
    """The cameras' parameters as the compiled projection kernel takes them.

    Parameters
    ----------
    cameras : CameraGroup (or any sequence of C Camera)

    Returns
    -------
    R : (C, 3, 3), t : (C, 3), K : (C, 3, 3) float64
    dist : (C, 14) float64
        Distortion coefficients, zero-padded.
    tilt : (C, 3, 3) float64
        Tilted-sensor matrices (identity where untilted).
    mode : (C,) int64
        0: the five-coefficient lens (``Camera.distort_normalized``'s short
        path, same expressions); 1: rational and thin prism terms; 2: also a
        tilted sensor.
    """
    C = len(cameras)
    R, t, K = np.zeros((C, 3, 3)), np.zeros((C, 3)), np.zeros((C, 3, 3))
    dist, tilt = np.zeros((C, 14)), np.tile(np.eye(3), (C, 1, 1))
    mode = np.zeros(C, np.int64)
    for c, cam in enumerate(cameras):
        R[c], t[c], K[c] = cam.R, cam.t, cam.K
        dist[c, : cam.dist.size] = cam.dist
        if dist[c, 5:].any():
            mode[c] = 1
        if dist[c, 12] != 0 or dist[c, 13] != 0:
            tilt[c] = tilt_matrix(dist[c, 12], dist[c, 13])
            mode[c] = 2
    return R, t, K, dist, tilt, mode
