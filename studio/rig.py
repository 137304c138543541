"""Camera rigs for the studio: cameras around a capture volume, looking at it."""

from __future__ import annotations

import numpy as np

from bodymetry.calibration.camera import Camera, CameraGroup


def look_at(
    center: np.ndarray, target: np.ndarray, up: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Extrinsics of a camera at ``center`` looking at ``target`` (OpenCV axes).

    Parameters
    ----------
    center, target : (3,) float
        World points, metres.
    up : (3,) float, optional
        World up (default +z); the image's "down" is opposite it.

    Returns
    -------
    R : (3, 3) float
        ``camera_from_world`` rotation (rows: image right, image down, forward).
    t : (3,) float
    """
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=float)
    forward = np.asarray(target, dtype=float) - np.asarray(center, dtype=float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("look_at: viewing direction is parallel to 'up'")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    return R, -R @ np.asarray(center, dtype=float)


def studio_rig(
    n_cameras: int = 4,
    size: tuple[int, int] = (640, 480),
    radius: float = 3.6,
    seed: int = 0,
    target: tuple[float, float, float] = (0.0, 0.0, 0.95),
) -> CameraGroup:
    """Cameras evenly spread around a ~3 x 3 m volume (like HumanEva-II's rig).

    Each camera stands at a corner-like azimuth (45° + k·360°/n, jittered),
    ``radius`` metres from the volume centre, 1.7-2.3 m high, looking at
    ``target`` (roughly the chest of a standing person), with a focal length
    that frames a 2.2 m tall person at the centre, a principal point near the
    image centre and mild barrel distortion, all drawn from ``seed``.

    Returns
    -------
    CameraGroup
        The rig, cameras named ``cam_00`` ...
    """
    if n_cameras < 1:
        raise ValueError(f"n_cameras: expected at least 1, got {n_cameras}")
    w, h = size
    rng = np.random.default_rng(seed)
    cameras = []
    for k in range(n_cameras):
        azimuth = np.deg2rad(45.0 + 360.0 * k / n_cameras + rng.uniform(-8, 8))
        r = radius * rng.uniform(0.93, 1.07)
        center = np.array([r * np.cos(azimuth), r * np.sin(azimuth), rng.uniform(1.7, 2.3)])
        aim = np.asarray(target) + rng.normal(0.0, 0.05, 3)
        R, t = look_at(center, aim)
        distance = np.linalg.norm(aim - center)
        # Vertical field of view that holds 2.6 m at the volume centre.
        f = (h / 2.0) / np.tan(np.arctan2(1.3, distance)) * rng.uniform(0.97, 1.03)
        K = np.array(
            [
                [f, 0.0, w / 2.0 + rng.uniform(-8, 8)],
                [0.0, f * rng.uniform(0.998, 1.002), h / 2.0 + rng.uniform(-6, 6)],
                [0.0, 0.0, 1.0],
            ]
        )
        dist = np.array(
            [
                rng.uniform(-0.22, -0.08),
                rng.uniform(0.0, 0.08),
                rng.normal(0, 5e-4),
                rng.normal(0, 5e-4),
                0.0,
            ]
        )
        cameras.append(Camera(f"cam_{k:02d}", (w, h), K, dist, R, t))
    return CameraGroup(cameras)
