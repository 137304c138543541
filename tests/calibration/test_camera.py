"""Camera and CameraGroup: projection vs OpenCV, undistortion, triangulation, indexing."""

from __future__ import annotations

import pickle

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodymetry.calibration.camera import Camera, CameraGroup

K = np.array([[900.0, 0.0, 330.0], [0.0, 905.0, 235.0], [0.0, 0.0, 1.0]])
_D12 = [-0.2, 0.05, 0.001, -0.0005, 0.01, 0.02, 0.001, 0.003, 0.001, -0.002, 0.0015, 5e-4]
DISTORTIONS = {
    4: [-0.2, 0.05, 0.001, -0.0005],
    5: [-0.2, 0.05, 0.001, -0.0005, 0.01],
    8: [-0.2, 0.05, 0.001, -0.0005, 0.01, 0.02, 0.001, 0.003],
    12: _D12,
    14: [*_D12, 0.01, -0.02],
}


def _look_at(center: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    z = target - center
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ center


def make_rig(n: int = 4, seed: int = 0) -> CameraGroup:
    """``n`` cameras on a 3 m circle looking at the middle of a 2 m tall volume."""
    rng = np.random.default_rng(seed)
    cams = []
    for i, angle in enumerate(np.linspace(0, 2 * np.pi, n, endpoint=False)):
        center = np.array([3 * np.cos(angle), 3 * np.sin(angle), 1.2 + 0.6 * rng.random()])
        R, t = _look_at(center, np.array([0.0, 0.0, 1.0]) + rng.normal(0, 0.05, 3))
        Ki = K.copy()
        Ki[:2, :2] *= 1 + rng.normal(0, 0.02)
        dist = [-0.15 + rng.normal(0, 0.02), 0.03, 0.001, -0.001, 0.0]
        cams.append(Camera(f"cam_{i:02d}", (640, 480), Ki, dist, R, t))
    return CameraGroup(cams)


def _volume_points(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform([-0.8, -0.8, 0.0], [0.8, 0.8, 2.0], (n, 3))


# -- Camera ---------------------------------------------------------------------
@pytest.mark.parametrize("n_coeffs", sorted(DISTORTIONS))
def test_project_matches_opencv(n_coeffs: int) -> None:
    R = Rotation.from_rotvec([0.1, -0.2, 0.05]).as_matrix()
    cam = Camera("a", (640, 480), K, DISTORTIONS[n_coeffs], R, [0.1, 0.2, 3.0])
    X = np.random.default_rng(1).uniform(-1, 1, (300, 3))
    ref, _ = cv2.projectPoints(X, cv2.Rodrigues(R)[0], cam.t, K, cam.dist)
    np.testing.assert_allclose(cam.project(X), ref[:, 0], atol=1e-9)


def test_project_behind_camera_is_nan_and_projection_matrix() -> None:
    cam = Camera("a", (640, 480), K, [0.0] * 5, np.eye(3), [0.0, 0.0, 0.0])
    px = cam.project(np.array([[0.1, 0.2, 2.0], [0.1, 0.2, -2.0]]))
    assert np.all(np.isfinite(px[0])) and np.all(np.isnan(px[1]))
    X = np.array([0.3, -0.2, 4.0])
    h = cam.projection_matrix @ np.append(X, 1.0)
    np.testing.assert_allclose(h[:2] / h[2], cam.project(X, distort=False), atol=1e-12)


@pytest.mark.parametrize("n_coeffs", sorted(DISTORTIONS))
def test_undistort_round_trip_within_image(n_coeffs: int) -> None:
    cam = Camera("a", (640, 480), K, DISTORTIONS[n_coeffs])
    u, v = np.meshgrid(np.linspace(0, 639, 41), np.linspace(0, 479, 31))
    px = np.stack([u, v], axis=-1)  # (31, 41, 2): any leading shape
    xy = cam.undistort_points(px)
    assert xy.shape == px.shape and np.all(np.isfinite(xy))
    back = cam.distort_normalized(xy) @ cam.K[:2, :2].T + cam.K[:2, 2]
    assert np.abs(back - px).max() < 1e-6
    ref = cv2.undistortPoints(
        px.reshape(-1, 1, 2),
        cam.K,
        cam.dist,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-16),
    )
    np.testing.assert_allclose(xy.reshape(-1, 2), ref[:, 0], atol=1e-9)
    ideal = cam.undistort_points(px, normalized=False)
    np.testing.assert_allclose(ideal, xy @ cam.K[:2, :2].T + cam.K[:2, 2], atol=1e-9)


def test_undistort_nan_and_shape() -> None:
    cam = Camera("a", (640, 480), K, DISTORTIONS[5])
    out = cam.undistort_points(np.array([[np.nan, 3.0], [320.0, 240.0]]))
    assert np.all(np.isnan(out[0])) and np.all(np.isfinite(out[1]))
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        cam.undistort_points(np.zeros((4, 3)))


def test_ray_passes_through_point() -> None:
    cam = make_rig(1)[0]
    X = _volume_points(50, 3)
    d = cam.ray(cam.project(X))
    v = X - cam.center
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    np.testing.assert_allclose(d, v, atol=1e-10)


# -- CameraGroup ---------------------------------------------------------------------
def test_triangulate_noise_free_exact() -> None:
    group = make_rig()
    X = _volume_points(500, 1)
    px = group.project(X)
    assert px.shape == (4, 500, 2)
    np.testing.assert_allclose(group.triangulate(px), X, atol=1e-9)
    np.testing.assert_allclose(group.triangulate(px, refine=True), X, atol=1e-9)
    err = group.reprojection_error(X, px)
    assert err.shape == (4, 500) and err.max() < 1e-9


def test_triangulate_with_missing_views() -> None:
    group = make_rig()
    X = _volume_points(300, 2)
    px = group.project(X)
    px[0, :200] = np.nan  # seen by 3 cameras
    px[1, :100] = np.nan  # seen by 2
    px[2, :10] = np.nan  # seen by 1: not triangulable
    px[3, 299, 0] = np.nan  # half-NaN counts as missing
    Y = group.triangulate(px)
    assert np.all(np.isnan(Y[:10]))
    np.testing.assert_allclose(Y[10:], X[10:], atol=1e-9)
    Y3 = group.triangulate(px, min_views=3)
    assert np.all(np.isnan(Y3[:100])) and np.all(np.isfinite(Y3[200:299]))
    err = group.reprojection_error(Y, px)
    assert np.all(np.isnan(err[0, :200])) and np.nanmax(err) < 1e-9


def test_refinement_lowers_reprojection_error() -> None:
    group = make_rig()
    X = _volume_points(400, 4)
    px = group.project(X) + np.random.default_rng(5).normal(0, 1.0, (4, 400, 2))
    lin = group.triangulate(px)
    ref = group.triangulate(px, refine=True)
    e_lin = np.nanmean(group.reprojection_error(lin, px) ** 2)
    e_ref = np.nanmean(group.reprojection_error(ref, px) ** 2)
    assert e_ref <= e_lin
    assert np.linalg.norm(ref - X, axis=1).mean() < 0.01


def test_group_validation_errors() -> None:
    group = make_rig(3)
    with pytest.raises(ValueError, match=r"\(C, N, 2\) with C = 3"):
        group.triangulate(np.zeros((2, 5, 2)))
    with pytest.raises(ValueError, match=r"N = 5"):
        group.reprojection_error(np.zeros((4, 3)), np.zeros((3, 5, 2)))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        group.project(np.zeros((5, 2)))
    with pytest.raises(ValueError, match="min_views"):
        group.triangulate(np.zeros((3, 5, 2)), min_views=1)


def test_group_indexing_and_subset() -> None:
    group = make_rig(4)
    assert len(group) == 4
    assert group.names == ("cam_00", "cam_01", "cam_02", "cam_03")
    assert group[1].name == "cam_01" and group[-1].name == "cam_03"
    assert group["cam_02"] is group[2]
    assert "cam_03" in group and "nope" not in group
    assert [c.name for c in group] == list(group.names)
    assert group.index("cam_03") == 3
    sub = group.subset(["cam_03", "cam_00"])
    assert sub.names == ("cam_03", "cam_00") and sub[0] is group[3]
    assert group.centers.shape == (4, 3)
    X = _volume_points(5, 0)
    np.testing.assert_array_equal(sub.project(X), group.project(X)[[3, 0]])
    with pytest.raises(KeyError, match="cam_09"):
        group["cam_09"]
    with pytest.raises(KeyError, match="cam_09"):
        group.subset(["cam_00", "cam_09"])
    with pytest.raises(IndexError):
        group[4]
    with pytest.raises(TypeError):
        group[1.5]  # type: ignore[index]


def test_group_construction_errors() -> None:
    cam = make_rig(1)[0]
    with pytest.raises(ValueError, match="duplicate camera name 'cam_00'"):
        CameraGroup([cam, cam])
    with pytest.raises(ValueError, match="at least one camera"):
        CameraGroup([])
    with pytest.raises(ValueError, match="must be a Camera"):
        CameraGroup([cam, "cam_01"])  # type: ignore[list-item]


def test_five_coefficient_lens_projects_bit_for_bit_like_the_general_model() -> None:
    """The 5-coefficient fast path drops only zero terms: identical numbers (cached
    training sets rendered before it stay valid)."""
    rng = np.random.default_rng(2)
    R = Rotation.from_rotvec(rng.normal(0, 0.2, 3)).as_matrix()
    five = Camera("a", (640, 480), K, DISTORTIONS[5], R, np.array([0.1, -0.2, 3.0]))
    # k6 = 1e-300 takes the general path and adds exactly nothing.
    eight = Camera("a", (640, 480), K, [*DISTORTIONS[5], 0.0, 0.0, 1e-300], R, five.t)
    pts = rng.uniform(-1.0, 1.0, (500, 3))
    np.testing.assert_array_equal(five.project(pts), eight.project(pts))


@pytest.mark.parametrize("factor", [0.5, 1 / 3, 0.25, 1.25])
def test_scaled_camera_projects_to_the_scaled_pixel(factor: float) -> None:
    """A world point lands on the same spot of the image: x' = (x + 0.5) s - 0.5."""
    for cam in make_rig(3, seed=2):
        cam = Camera(cam.name, (1088, 1920), cam.K, DISTORTIONS[5], cam.R, cam.t)
        small = cam.scaled(factor)
        pts = _volume_points(50, seed=3)
        np.testing.assert_allclose(
            small.project(pts), (cam.project(pts) + 0.5) * factor - 0.5, atol=1e-9
        )
        assert small.size == (round(1088 * factor), round(1920 * factor))
        np.testing.assert_array_equal(small.dist, cam.dist)
        np.testing.assert_array_equal(small.R, cam.R)
        np.testing.assert_array_equal(small.t, cam.t)
        assert small.name == cam.name


def test_scaled_camera_round_trip_and_identity() -> None:
    cam = make_rig(1)[0]
    assert cam.scaled(1.0).size == cam.size
    np.testing.assert_array_equal(cam.scaled(1.0).K, cam.K)
    back = cam.scaled(1 / 3).scaled(3.0)
    np.testing.assert_allclose(back.K, cam.K, atol=1e-9)
    pts = _volume_points(20, seed=1)
    np.testing.assert_allclose(back.project(pts), cam.project(pts), atol=1e-9)
    # A working image keeps the pixels of the last partial block: 1088 / 3 -> 363.
    portrait = Camera("p", (1088, 1920), K)
    assert portrait.scaled(1 / 3).size == (363, 640)
    assert Camera("q", (1080, 1920), K).scaled(1 / 3).size == (360, 640)


@pytest.mark.parametrize("factor", [0.0, -1.0, float("nan"), float("inf"), "2"])
def test_scaled_camera_rejects_bad_factors(factor) -> None:
    with pytest.raises(ValueError, match="scale factor must be a positive number"):
        make_rig(1)[0].scaled(factor)


def test_group_scaled_per_camera_and_one_factor() -> None:
    group = make_rig(3)
    half = group.scaled(0.5)
    assert half.names == group.names
    assert [c.size for c in half] == [(320, 240)] * 3
    mixed = group.scaled([1.0, 0.5, 0.25])
    assert [c.size for c in mixed] == [(640, 480), (320, 240), (160, 120)]
    with pytest.raises(ValueError, match="expected one factor or 3, got 2"):
        group.scaled([1.0, 0.5])


def test_group_sizes_select_and_slices() -> None:
    group = make_rig(4).scaled([1.0, 0.5, 1.0, 0.25])
    assert group.sizes == ((640, 480), (320, 240), (640, 480), (160, 120))
    assert not group.same_size and make_rig(3).same_size
    usable = group.select(np.flatnonzero([True, False, True, True]))
    assert usable.names == ("cam_00", "cam_02", "cam_03") and usable[1] is group[2]
    assert isinstance(group[1:3], CameraGroup) and group[1:3].names == ("cam_01", "cam_02")
    with pytest.raises(IndexError):
        group.select([4])


def test_group_check_masks_names_the_camera() -> None:
    group = make_rig(2).scaled([1.0, 0.5])
    masks = group.check_masks([np.zeros((480, 640), np.uint8), np.ones((240, 320), bool)])
    assert [m.dtype for m in masks] == [bool, bool] and masks[1].all()
    with pytest.raises(ValueError, match=r"expected one mask per camera \(2\), got 1"):
        group.check_masks([np.zeros((480, 640), bool)])
    with pytest.raises(ValueError, match=r"cam_01: mask is 640x480 .* image is 320x240"):
        group.check_masks([np.zeros((480, 640), bool)] * 2)


def test_group_pickles() -> None:
    """A rig travels to pool and Dask workers by pickle."""
    group = make_rig(3)
    back = pickle.loads(pickle.dumps(group))
    assert isinstance(back, CameraGroup) and back.names == group.names
    assert back.index("cam_02") == 2 and back["cam_01"] is back[1]
    X = _volume_points(5, 1)
    np.testing.assert_array_equal(back.project(X), group.project(X))
