"""Pinhole camera with OpenCV lens distortion, and a group of synchronized cameras.

Conventions (DESIGN.md): world right-handed, z up, metres; camera frame OpenCV
(x right, y down, z forward); extrinsics ``x_cam = R @ x_world + t``. Distortion
coefficients in OpenCV order ``(k1, k2, p1, p2[, k3[, k4, k5, k6]])``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Camera:
    """One calibrated camera.

    Attributes
    ----------
    name : str
        Identifier (e.g. ``"cam_00"``), unique within a rig.
    size : tuple of int
        Image ``(width, height)`` in pixels.
    K : (3, 3) float
        Intrinsic matrix.
    dist : (n,) float
        Distortion coefficients, OpenCV order, n in {4, 5, 8}.
    R : (3, 3) float
        Rotation ``camera_from_world``.
    t : (3,) float
        Translation ``camera_from_world``, metres.
    """

    name: str
    size: tuple[int, int]
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float)
        dist = np.asarray(self.dist, dtype=float).reshape(-1)
        R = np.asarray(self.R, dtype=float)
        t = np.asarray(self.t, dtype=float).reshape(-1)
        where = f"camera {self.name!r}"
        if K.shape != (3, 3):
            raise ValueError(f"{where}: K must be 3x3, got shape {K.shape}")
        if not (K[0, 0] > 0 and K[1, 1] > 0 and K[2, 2] == 1 and np.allclose(K[2, :2], 0)):
            raise ValueError(
                f"{where}: K must have positive focal lengths and last row [0, 0, 1], "
                f"got {K.tolist()}"
            )
        if dist.size not in (4, 5, 8, 12, 14):
            raise ValueError(
                f"{where}: distortion must have 4, 5, 8, 12 or 14 values, got {dist.size}"
            )
        if R.shape != (3, 3):
            raise ValueError(f"{where}: R must be 3x3, got shape {R.shape}")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError(f"{where}: R must be a rotation (orthonormal, det +1)")
        if t.shape != (3,):
            raise ValueError(f"{where}: t must have 3 values, got shape {t.shape}")
        if len(self.size) != 2 or min(self.size) <= 0:
            raise ValueError(f"{where}: size must be (width, height) > 0, got {self.size}")
        for arr in (K, dist, R, t):
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{where}: parameters contain NaN or infinity")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "size", (int(self.size[0]), int(self.size[1])))

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates (3,)."""
        return -self.R.T @ self.t

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> camera frame (..., 3)."""
        return np.asarray(points, dtype=float) @ self.R.T + self.t

    def distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Apply the lens model to normalized image coordinates (..., 2) (z = 1 plane)."""
        d = np.zeros(8)
        d[: min(8, self.dist.size)] = self.dist[:8]
        k1, k2, p1, p2, k3, k4, k5, k6 = d
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def project(self, points: np.ndarray, distort: bool = True) -> np.ndarray:
        """Project world points to pixels.

        Parameters
        ----------
        points : (..., 3) float
            World coordinates, metres.
        distort : bool
            Apply lens distortion (False: ideal pinhole).

        Returns
        -------
        (..., 2) float
            Pixel coordinates; points behind the camera give NaN.
        """
        pc = self.to_camera(points)
        z = pc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = pc[..., :2] / z[..., None]
        xy = np.where((z > 1e-9)[..., None], xy, np.nan)
        if distort:
            xy = self.distort_normalized(xy)
        return xy @ self.K[:2, :2].T + self.K[:2, 2]
