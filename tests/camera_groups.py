"""Camera groups for the calibration file tests (tests/calibration/test_io.py, test_anipose.py)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from bodymetry.calibration.camera import Camera, CameraGroup


def make_group(n: int = 3, seed: int = 0) -> CameraGroup:
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        K = [[800 + 50 * rng.random(), 0.0, 320 + rng.normal()], [0.0, 805 + rng.random(), 240.5]]
        K.append([0.0, 0.0, 1.0])
        dist = rng.normal(0, 1e-3, 5) * np.array([100, 10, 1, 1, 1])
        R = Rotation.random(random_state=seed * 10 + i).as_matrix()
        cams.append(Camera(f"cam_{i:02d}", (640, 480), K, dist, R, rng.normal(0, 2, 3)))
    return CameraGroup(cams)


def assert_groups_equal(a: CameraGroup, b: CameraGroup, rot_tol: float = 0.0) -> None:
    assert a.names == b.names
    for ca, cb in zip(a, b, strict=True):
        assert ca.size == cb.size
        np.testing.assert_array_equal(ca.K, cb.K)
        np.testing.assert_array_equal(ca.dist, cb.dist)
        np.testing.assert_array_equal(ca.t, cb.t)
        if rot_tol == 0.0:
            np.testing.assert_array_equal(ca.R, cb.R)
        else:
            assert np.abs(ca.R - cb.R).max() < rot_tol
