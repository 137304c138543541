"""The calibration board in a studio image: where its sheet is seen, and its albedo there.

Each candidate pixel's ray is intersected with the board's plane
(:func:`board_hits`) inside the bounding box of the projected sheet
(:func:`board_region`); the printed texture is sampled trilinearly over its mip
levels at the pixel's footprint (:func:`texture_footprint`, :func:`board_albedo`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from bodymetry.calibration.camera import Camera
from bodymetry.studio.lens import project_for_raster
from bodymetry.studio.scene import BoardPose, BoardTexture


def sample_image(
    image: np.ndarray, x: np.ndarray, y: np.ndarray, interp: int, border: float | None = None
) -> np.ndarray:
    """Sample a single-channel float32 image at points with ``cv2.remap``.

    Parameters
    ----------
    image : (h, w) float32
        Pixel centres at integer coordinates.
    x, y : (N,) float
        Sample points.
    interp : int
        OpenCV interpolation flag.
    border : float or None
        Value outside the image; None: replicate the edge.

    Returns
    -------
    (N,) float32
    """
    n = x.size
    cols = 4096
    rows = max(1, -(-n // cols))
    mx = np.zeros(rows * cols, np.float32)
    my = np.zeros(rows * cols, np.float32)
    mx[:n] = x
    my[:n] = y
    if border is None:
        out = cv2.remap(
            image, mx.reshape(rows, cols), my.reshape(rows, cols), interp,
            borderMode=cv2.BORDER_REPLICATE,
        )  # fmt: skip
    else:
        out = cv2.remap(
            image, mx.reshape(rows, cols), my.reshape(rows, cols), interp,
            borderMode=cv2.BORDER_CONSTANT, borderValue=float(border),
        )  # fmt: skip
    return out.reshape(-1)[:n]


@dataclass
class BoardSheet:
    """A calibration board placed in the scene.

    Attributes
    ----------
    texture : BoardTexture
        The printed sheet.
    pose : BoardPose
        world_from_board.
    mips : list of (h, w) float32
        The texture's mip levels (level ``l`` is ``2**l`` times coarser).
    """

    texture: BoardTexture
    pose: BoardPose
    mips: list[np.ndarray] = field(default_factory=list)


def board_region(
    camera: Camera, r_limit: float, board: BoardSheet
) -> tuple[int, int, int, int] | None:
    """Candidate pixels of the board: the bounding box of its projected sheet outline.

    Parameters
    ----------
    r_limit : float
        The lens model's valid normalized radius (:func:`lens_radius_limit`).

    Returns
    -------
    (x0, x1, y0, y1) or None
        Inclusive pixel bounds (the whole image when the outline is partly behind
        the camera or beyond the lens range); None when the board cannot be seen.
    """
    w, h = camera.size
    tex, pose = board.texture, board.pose
    c = tex.corners()
    outline = np.concatenate(
        [c[i] + np.linspace(0, 1, 33)[:, None] * (c[(i + 1) % 4] - c[i]) for i in range(4)]
    )
    pw = pose.to_world(outline)
    xy, _, valid = project_for_raster(camera, pw, 1, r_limit)
    if valid.sum() < 3:
        return None
    x0 = max(int(np.floor(xy[valid, 0].min())) - 2, 0)
    x1 = min(int(np.ceil(xy[valid, 0].max())) + 2, w - 1)
    y0 = max(int(np.floor(xy[valid, 1].min())) - 2, 0)
    y1 = min(int(np.ceil(xy[valid, 1].max())) + 2, h - 1)
    if not np.all(valid):  # partly behind the camera or beyond the lens range
        x0, x1, y0, y1 = 0, w - 1, 0, h - 1
    if x1 < x0 or y1 < y0:
        return None
    return x0, x1, y0, y1


def board_hits(
    camera: Camera, board: BoardSheet, d: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Intersect pixel rays with the board's plane.

    Parameters
    ----------
    d : (N, 3) float
        World ray directions of the candidate pixels.

    Returns
    -------
    lam : (N,) float
        Ray parameter of the hit (depth along the ray).
    p : (N, 3) float
        Hit points, world frame.
    pb : (N, 3) float
        Hit points, board frame.
    inside : (N,) bool
        The hit is in front of the camera and on the sheet (pattern plus margin).
    """
    tex, pose = board.texture, board.pose
    origin = camera.center
    nrm = pose.R[:, 2]
    denom = d @ nrm
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = ((pose.t - origin) @ nrm) / denom
    p = origin + lam[:, None] * d
    pb = (p - pose.t) @ pose.R  # board frame
    m = tex.margin
    pwid, phei = tex.pattern_size
    inside = (
        np.isfinite(lam)
        & (lam > 1e-6)
        & (pb[:, 0] >= -m)
        & (pb[:, 0] <= pwid + m)
        & (pb[:, 1] >= -m)
        & (pb[:, 1] <= phei + m)
    )
    return lam, p, pb, inside


def texture_footprint(
    tex: BoardTexture, pb: np.ndarray, gh: int, gw: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Texel coordinates of the candidate pixels and their footprint.

    Parameters
    ----------
    pb : (gh * gw, 3) float
        Hit points in the board frame, row-major over the candidate box.

    Returns
    -------
    u, v : (gh, gw) float
        Texel coordinates.
    foot : (gh * gw,) float
        Texels per pixel, from the coordinates' gradients.
    """
    m = tex.margin
    ppm = tex.image.shape[1] / tex.sheet_size[0]  # texels per metre
    u = ((pb[:, 0] + m) * ppm).reshape(gh, gw)
    vv = ((pb[:, 1] + m) * ppm).reshape(gh, gw)
    with np.errstate(invalid="ignore"):
        gu = np.hypot(*np.gradient(u)) if min(gh, gw) > 1 else np.ones_like(u)
        gv = np.hypot(*np.gradient(vv)) if min(gh, gw) > 1 else np.ones_like(u)
    foot = np.nan_to_num(np.maximum(gu, gv), nan=1.0, posinf=1.0).reshape(-1)
    return u, vv, foot


def board_albedo(board: BoardSheet, us: np.ndarray, vs: np.ndarray, foot: np.ndarray) -> np.ndarray:
    """Printed-side albedo (N,) float32, trilinear over the board's mip levels.

    Parameters
    ----------
    us, vs : (N,) float
        Texel coordinates.
    foot : (N,) float
        Texels per pixel (picks the mip levels).
    """
    level = np.clip(np.log2(np.maximum(foot, 1e-6)), 0, len(board.mips) - 1)
    l0 = np.floor(level).astype(int)
    frac = (level - l0).astype(np.float32)
    alb = np.zeros(us.size, np.float32)
    for lev in np.unique(np.concatenate([l0, np.minimum(l0 + 1, len(board.mips) - 1)])):
        wgt = np.where(l0 == lev, 1 - frac, 0) + np.where(
            np.minimum(l0 + 1, len(board.mips) - 1) == lev, frac, 0
        )
        use = np.flatnonzero(wgt > 0)
        if use.size == 0:
            continue
        sc = 2.0**lev
        val = sample_image(
            board.mips[lev], us[use] / sc - 0.5, vs[use] / sc - 0.5, cv2.INTER_LINEAR
        )
        alb[use] += wgt[use] * val
    return alb
