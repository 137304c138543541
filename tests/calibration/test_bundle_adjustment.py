"""The bundle adjustment's parameter layout and rotations (calibration/bundle_adjustment.py).

The solver itself is tested through calibrate_cameras (tests/calibration/test_solve.py).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from bodymetry.calibration.bundle_adjustment import (
    CAMERA_PARAMS,
    pack_parameters,
    rodrigues,
    rotation_vector,
    unpack_parameters,
)


def test_rodrigues_inverts_rotation_vector() -> None:
    R = Rotation.random(5, random_state=0).as_matrix()
    back = rodrigues(np.stack([rotation_vector(r) for r in R]))
    np.testing.assert_allclose(back, R, atol=1e-12)
    np.testing.assert_array_equal(rodrigues(np.zeros(3)), np.eye(3))


def test_pack_and_unpack_share_one_layout() -> None:
    K = np.array([[800.0, 0.0, 320.0], [0.0, 810.0, 240.0], [0.0, 0.0, 1.0]])
    dist = np.array([-0.1, 0.01, 0.001, -0.002, 0.0])
    R = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()
    poses = np.stack([np.eye(4), np.eye(4)])
    poses[1, :3, 3] = [1.0, 2.0, 3.0]
    x = pack_parameters([(K, dist, R, np.array([0.5, 0.0, 2.0]))], poses)
    assert x.shape == (CAMERA_PARAMS + 2 * 6,)
    cam, pose = unpack_parameters(x, 1, 2)
    np.testing.assert_allclose(cam[0, :3], [0.1, -0.2, 0.3], atol=1e-12)
    np.testing.assert_array_equal(
        cam[0, 3:], [0.5, 0.0, 2.0, 800, 810, 320, 240, -0.1, 0.01, 0.001, -0.002]
    )
    np.testing.assert_array_equal(pose[1, 3:], [1.0, 2.0, 3.0])
