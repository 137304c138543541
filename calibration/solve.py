"""Multi-camera calibration from ChArUco detections.

Pipeline (docs/calibration.md):

1. **Intrinsics** per camera: ``cv2.calibrateCamera`` on the board views with
   enough corners; k3 = 0 and, unless the corners reach the image borders,
   k2 = 0 (see :class:`CalibrationOptions`); 5 coefficients are stored.
2. **Board poses** per camera and frame: IPPE PnP (both planar solutions tried)
   refined by Levenberg-Marquardt.
3. **Initial extrinsics**: a camera graph whose edges are pairs of cameras that
   saw the board in the same frames; each edge's relative pose is the per-frame
   estimate that best explains all the pair's shared frames (a RANSAC-like
   choice); poses are chained along the maximum spanning tree (edge weight =
   shared frames) from the camera that sees the floor board best.
4. **World frame**: the board lying still on the floor in ``floor_frames``
   defines it: ``world_from_board = [diag(1, -1, -1) | 0]`` (pattern origin at
   the world origin, board x along world x, printed side up, z up). The scale is
   metric because the board's object points are in metres.
5. **Bundle adjustment** over every camera's pose and intrinsics (fx, fy, cx,
   cy, k1[, k2], p1, p2) and every moving board pose; the floor pose is fixed
   (it is the gauge). Corners that the corner refiner could not place
   (:class:`calibration.charuco.CornerRefiner`) are down-weighted.
   Levenberg-Marquardt (:mod:`calibration.bundle_adjustment`) on sparse
   normal equations with a sparse
   forward-difference Jacobian (column grouping: 20 residual evaluations per
   Jacobian), robust ``soft_l1`` loss (1 px scale) by IRLS, then outlier
   rejection (4 sigma of the robust error spread, at least ``outlier_min_px``)
   and a second solve. (``scipy.optimize.least_squares`` with ``jac_sparsity``
   was the first version: its LSMR steps stalled at the evaluation limit after
   27 s on a studio session; this solver reaches the same optimum in 2-5 s.)

Every failure raises :class:`bodymetry.errors.InputError` naming the camera and
the problem; a result is only returned when it is finite and its RMS is sane.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from bodymetry.calibration.bundle_adjustment import (
    CAMERA_PARAMS,
    BundleProblem,
    SolveResult,
    pack_parameters,
    reprojection_residuals,
    rodrigues,
    solve_bundle,
    unpack_parameters,
)
from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.calibration.charuco import BoardGeometry, CameraDetections
from bodymetry.errors import InputError

log = logging.getLogger(__name__)

__all__ = [
    "FLOOR_BOARD_POSE",
    "CalibrationError",
    "CalibrationOptions",
    "CalibrationResult",
    "calibrate_cameras",
]

#: world_from_board of the board lying face up on the floor (4, 4).
FLOOR_BOARD_POSE = np.diag([1.0, -1.0, -1.0, 1.0])


class CalibrationError(InputError):
    """The clips do not allow a trustworthy calibration (message says why)."""


@dataclass(frozen=True)
class CalibrationOptions:
    """Settings of :func:`calibrate_cameras`.

    Attributes
    ----------
    floor_frames : (int, int) or None
        Clip frames ``[start, end)`` in which the board lies still on the
        floor, face up; it defines the world frame. None: the world is the
        first camera's frame (z is then *not* up).
    min_corners : int
        Corners a view needs to count (intrinsics, PnP).
    min_shared_views : int
        Frames two cameras must both see the board in to link them.
    max_intrinsic_views : int
        Views given to ``cv2.calibrateCamera`` per camera (evenly subsampled).
    refine_intrinsics : bool
        Bundle-adjust intrinsics too (else keep the per-camera ones).
    tangential : bool
        Solve the tangential distortion p1, p2 (default). Fixed at 0 they bias
        the principal point: measured on studio lenses with |p| ~ 5e-4, by up
        to 3 px even from exact corners, and the camera rotation with it
        (1 px ~ 0.08 deg). Free, they need accurate corners
        (:class:`calibration.charuco.CornerRefiner`).
    square_pixels : bool
        Solve one focal length (fx = fy).
    radial : int or None
        Radial distortion terms solved: 2 (k1, k2), 1 (k1; k2 = 0) or 0. None
        (default): per camera, k2 only when the detected corners reach at least
        ``k2_min_coverage`` of the image half-diagonal; otherwise k2 cannot be
        told apart from noise and, left free, extrapolates wildly towards the
        image corners (measured: up to 100 px off there with k2 free).
    k2_min_coverage : float
        See ``radial``.
    floor_weight : ``"frames"`` or ``"one"``
        The floor board's corners are the median over the still frames; weight
        them as that many observations (``"frames"``: what they are worth) or as
        one view.
    unrefined_weight : float
        Weight (on the squared error) of corners that the corner refiner could
        not place (their detector position is ~5-10x less accurate) when the
        detections say which were refined.
    loss, f_scale_px : robust loss (``soft_l1``, ``huber``, ``cauchy``, ``linear``) on
        each corner's 2-D error, and its scale (pixels).
    max_iterations : Levenberg-Marquardt iterations per solve.
    outlier_sigma, outlier_min_px : outlier threshold ``max(min, sigma * s)``
        where ``s`` is the robust spread of the reprojection errors.
    max_rms_px : a final RMS above this is a failure, not a calibration.
    """

    floor_frames: tuple[int, int] | None = (0, 60)
    min_corners: int = 6
    min_shared_views: int = 3
    max_intrinsic_views: int = 60
    refine_intrinsics: bool = True
    tangential: bool = True
    square_pixels: bool = False
    radial: int | None = None
    k2_min_coverage: float = 0.7
    floor_weight: str = "one"
    unrefined_weight: float = 0.04
    loss: str = "soft_l1"
    f_scale_px: float = 1.0
    outlier_sigma: float = 4.0
    outlier_min_px: float = 1.0
    max_rms_px: float = 2.0
    max_iterations: int = 100


@dataclass
class CalibrationResult:
    """Solved cameras and the figures that say how good they are."""

    cameras: CameraGroup
    rms_px: float
    per_camera: dict[str, dict[str, Any]]
    frames_used: int
    observations: int
    outliers: int
    world: dict[str, Any] = field(default_factory=dict)
    solver: dict[str, Any] = field(default_factory=dict)

    def report(self) -> dict[str, Any]:
        """JSON-ready summary (``calibration-report.json``)."""
        return {
            "rms_px": self.rms_px,
            "frames_used": self.frames_used,
            "observations": self.observations,
            "outliers_rejected": self.outliers,
            "world": self.world,
            "solver": self.solver,
            "cameras": self.per_camera,
        }

    def quality(self) -> dict[str, Any]:
        """The ``quality:`` block of ``calibration.yaml``."""
        out: dict[str, Any] = {"overall": {"rms_px": round(self.rms_px, 4)}}
        for name, figures in self.per_camera.items():
            out[name] = {
                k: figures[k]
                for k in ("frames_read", "boards_detected", "corners_used", "rms_px")
                if k in figures
            }
        return out


# ---------------------------------------------------------------------------------------
# small geometry helpers
# ---------------------------------------------------------------------------------------


def _T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t).reshape(3)
    return T


def _inv(T: np.ndarray) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    return _T(R.T, -R.T @ t)


def _spans_plane(ids: np.ndarray, sx: int) -> bool:
    """Corners ``ids`` are not all on one board row or column (a homography needs that)."""
    cols, rows = ids % (sx - 1), ids // (sx - 1)
    return len(np.unique(cols)) >= 2 and len(np.unique(rows)) >= 2 and len(ids) >= 4


def _project(
    K: np.ndarray, dist: np.ndarray, R: np.ndarray, t: np.ndarray, X: np.ndarray
) -> np.ndarray:
    return Camera("x", (1, 1), K, dist, R, t)._project_any(X)


# ---------------------------------------------------------------------------------------
# stage 1-2: intrinsics and per-view board poses
# ---------------------------------------------------------------------------------------
@dataclass
class _CamData:
    det: CameraDetections
    K: np.ndarray
    dist: np.ndarray
    intrinsic_rms: float
    intrinsic_views: int
    radial: int
    coverage: float
    #: sample index -> camera_from_board (4, 4) for views with a good PnP
    poses: dict[int, np.ndarray]


def _never_found(det: CameraDetections, geom: BoardGeometry) -> CalibrationError:
    sx, sy = geom.squares
    return CalibrationError(
        f"camera {det.name!r}: the ChArUco board was never found in {det.source or 'its clip'} "
        f"({det.frames_read} frames read). Likely causes: the board in the clip uses another "
        f"ArUco dictionary or size than session.yaml says ({sx}x{sy} squares), the board is "
        "too small or too blurred in this view, or the video is mirrored (a mirrored board "
        "cannot be decoded)."
    )


def _coverage(det: CameraDetections) -> float:
    """Farthest detected corner from the image centre / the half-diagonal."""
    w, h = det.size
    uv = det.corners[det.found]
    if uv.size == 0:
        return 0.0
    r = np.linalg.norm(uv - [(w - 1) / 2, (h - 1) / 2], axis=1).max()
    return float(r / np.hypot(w / 2, h / 2))


def _intrinsics(
    det: CameraDetections,
    geom: BoardGeometry,
    floor_mask: np.ndarray,
    opts: CalibrationOptions,
    radial: int,
) -> tuple[np.ndarray, np.ndarray, float, int]:
    found = det.found
    n = found.sum(axis=1)
    sx = geom.squares[0]
    good = [
        i
        for i in np.flatnonzero(n >= opts.min_corners)
        if _spans_plane(np.flatnonzero(found[i]), sx)
    ]
    # Floor frames are one board pose: one view is enough.
    floor_views = [i for i in good if floor_mask[i]]
    moving = [i for i in good if not floor_mask[i]]
    if len(moving) > opts.max_intrinsic_views:
        pick = np.linspace(0, len(moving) - 1, opts.max_intrinsic_views).round().astype(int)
        moving = [moving[i] for i in pick]
    views = moving + floor_views[:1]
    if len(views) < 4:
        if det.boards_detected == 0:
            raise _never_found(det, geom)
        raise CalibrationError(
            f"camera {det.name!r}: the board was found in {det.boards_detected} of "
            f"{det.frames_read} frames read, but only {len(views)} views have >= "
            f"{opts.min_corners} corners spanning the board; intrinsics need at least 4 "
            "(move the board closer to this camera and tilt it through more angles)"
        )
    obj = [geom.points[found[i]].astype(np.float32) for i in views]
    img = [det.corners[i][found[i]].astype(np.float32) for i in views]
    w, h = det.size
    K0 = np.array([[max(w, h), 0, (w - 1) / 2], [0, max(w, h), (h - 1) / 2], [0, 0, 1.0]])
    flags = cv2.CALIB_FIX_K3 | cv2.CALIB_USE_INTRINSIC_GUESS
    if not opts.tangential:
        flags |= cv2.CALIB_ZERO_TANGENT_DIST
    if opts.square_pixels:
        flags |= cv2.CALIB_FIX_ASPECT_RATIO
    if radial < 2:
        flags |= cv2.CALIB_FIX_K2
    if radial < 1:
        flags |= cv2.CALIB_FIX_K1
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    try:
        rms, K, dist, _, _ = cv2.calibrateCamera(
            obj, img, (w, h), K0, np.zeros(5), flags=flags, criteria=crit
        )
    except cv2.error as exc:
        raise CalibrationError(
            f"camera {det.name!r}: OpenCV could not solve the intrinsics from {len(views)} "
            f"board views ({exc.err})"
        ) from exc
    K = np.asarray(K, dtype=float)
    dist = np.asarray(dist, dtype=float).reshape(-1)[:5]
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(dist)) and np.isfinite(rms)):
        raise CalibrationError(f"camera {det.name!r}: the intrinsic solve gave NaN")
    return K, dist, float(rms), len(views)


def _pnp(
    K: np.ndarray, dist: np.ndarray, obj: np.ndarray, img: np.ndarray
) -> tuple[np.ndarray, float] | None:
    """camera_from_board (4, 4) and its RMS (px), or None."""
    try:
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
            obj.astype(np.float64), img.astype(np.float64), K, dist, flags=cv2.SOLVEPNP_IPPE
        )
    except cv2.error:
        return None
    best = None
    for rv, tv in zip(rvecs[:n], tvecs[:n], strict=True):
        rv, tv = cv2.solvePnPRefineLM(obj, img, K, dist, rv.copy(), tv.copy())
        R = cv2.Rodrigues(rv)[0]
        proj = _project(K, dist, R, tv.reshape(3), obj)
        rms = float(np.sqrt(np.mean(np.sum((proj - img) ** 2, axis=1))))
        if np.isfinite(rms) and tv.reshape(3)[2] > 0 and (best is None or rms < best[1]):
            best = (_T(R, tv.reshape(3)), rms)
    return best


def _board_poses(
    det: CameraDetections, geom: BoardGeometry, K: np.ndarray, dist: np.ndarray, min_corners: int
) -> dict[int, np.ndarray]:
    found = det.found
    sx = geom.squares[0]
    out: dict[int, np.ndarray] = {}
    for i in np.flatnonzero(found.sum(axis=1) >= min_corners):
        ids = np.flatnonzero(found[i])
        if not _spans_plane(ids, sx):
            continue
        res = _pnp(K, dist, geom.points[ids], det.corners[i, ids])
        if res is not None and res[1] < 3.0:
            out[int(i)] = res[0]
    return out


# ---------------------------------------------------------------------------------------
# stage 3: camera graph
# ---------------------------------------------------------------------------------------
def _spanning_tree(
    cams: list[_CamData],
    root: int,
    geom: BoardGeometry,
    opts: CalibrationOptions,
    floor_mask: np.ndarray,
) -> list[np.ndarray]:
    """camera_from_root (4, 4) per camera, chained over the maximum spanning tree."""
    C = len(cams)
    # frame -> sample index per camera; shared frames use clip frame numbers.
    views = [
        {int(c.det.frames[i]): i for i in c.poses if not floor_mask[c.det.frames[i]]} for c in cams
    ]
    shared = {}
    for i in range(C):
        for j in range(i + 1, C):
            common = sorted(set(views[i]) & set(views[j]))
            shared[i, j] = shared[j, i] = common
    in_tree = {root}
    T_from_root = {root: np.eye(4)}
    while len(in_tree) < C:
        best = None
        for i in in_tree:
            for j in range(C):
                if j in in_tree:
                    continue
                n = len(shared[i, j])
                if n >= opts.min_shared_views and (best is None or n > best[2]):
                    best = (i, j, n)
        if best is None:
            missing = [cams[j].det.name for j in range(C) if j not in in_tree]
            counts = {
                cams[j].det.name: {cams[i].det.name: len(shared[i, j]) for i in range(C) if i != j}
                for j in range(C)
                if j not in in_tree
            }
            raise CalibrationError(
                f"too few shared views to link camera(s) {missing} to the others: frames in "
                f"which the board was seen well by both cameras {counts}; need >= "
                f"{opts.min_shared_views} with at least one camera already linked. Show the "
                "board to these cameras and a neighbour at the same time."
            )
        i, j, _ = best
        a, b = cams[i], cams[j]
        fr = shared[i, j]
        T_ij, score = _edge(a, b, views[i], views[j], fr, geom)
        log.info(
            "linked %s to %s over %d shared views (median %.2f px)",
            b.det.name,
            a.det.name,
            len(fr),
            score,
        )
        T_from_root[j] = _inv(T_ij) @ T_from_root[i]  # b_from_root = b_from_a a_from_root
        in_tree.add(j)
    return [T_from_root[c] for c in range(C)]


def _edge(
    a: _CamData,
    b: _CamData,
    va: dict[int, int],
    vb: dict[int, int],
    frames: list[int],
    geom: BoardGeometry,
) -> tuple[np.ndarray, float]:
    """a_from_b (4, 4) that best explains every shared frame, and its median error (px).

    Candidates are the per-frame estimates ``a_from_board @ board_from_b``; each is
    scored by the median reprojection error in ``a`` of the board seen by ``b`` in
    all shared frames (a RANSAC-like choice: one bad PnP cannot spoil the edge).
    ``va``/``vb`` map clip frame numbers to each camera's sample index.
    """
    pa = {f: a.poses[va[f]] for f in frames}
    pb = {f: b.poses[vb[f]] for f in frames}
    cands = [pa[f] @ _inv(pb[f]) for f in frames]
    if len(cands) > 40:
        cands = [cands[i] for i in np.linspace(0, len(cands) - 1, 40).round().astype(int)]
    best = (cands[0], np.inf)
    for T in cands:
        errs = []
        for f in frames:
            Tb = T @ pb[f]
            ids = a.det.found[va[f]]
            X = geom.points[ids] @ Tb[:3, :3].T + Tb[:3, 3]
            if np.any(X[:, 2] <= 0):
                errs.append(1e6)
                continue
            proj = _project(a.K, a.dist, np.eye(3), np.zeros(3), X)
            errs.append(float(np.median(np.linalg.norm(proj - a.det.corners[va[f], ids], axis=1))))
        score = float(np.median(errs))
        if score < best[1]:
            best = (T, score)
    return best


# ---------------------------------------------------------------------------------------
# main entry point
# ---------------------------------------------------------------------------------------
def calibrate_cameras(
    detections: Sequence[CameraDetections],
    geom: BoardGeometry,
    options: CalibrationOptions | None = None,
) -> CalibrationResult:
    """Solve every camera's intrinsics and pose from board detections.

    Parameters
    ----------
    detections : one :class:`CameraDetections` per camera, sampled at the same
        clip frames (the clips are synchronized).
    geom : the board's corner geometry (metres).
    options : :class:`CalibrationOptions`.

    Raises
    ------
    CalibrationError (an InputError)
        Board never found in a camera; too few views for intrinsics; too few
        shared views to link a camera; no camera sees the floor board; the
        bundle adjustment does not converge, gives NaN or a large RMS.
    """
    opts = options or CalibrationOptions()
    if not detections:
        raise CalibrationError("no cameras to calibrate")
    for det in detections:
        if det.boards_detected == 0:
            raise _never_found(det, geom)
    floor_frame = _floor_frame_mask(detections, opts)
    cams = _cameras_intrinsics(detections, geom, floor_frame, opts)
    floor = _floor_board_views(cams, geom, floor_frame, opts)
    root = _root_camera(floor)
    cam_from_world = _initial_extrinsics(cams, root, geom, floor, floor_frame, opts)
    frames, poses0 = _initial_board_poses(cams, cam_from_world, floor_frame)
    pb = _bundle_problem(cams, geom, frames, floor, root, opts)
    x0 = pack_parameters(
        [(c.K, c.dist, T[:3, :3], T[:3, 3]) for c, T in zip(cams, cam_from_world, strict=True)],
        poses0,
    )
    fit = _bundle_adjust(pb, x0, opts)
    out_cams, per_camera = _solved_cameras(cams, fit, floor, opts)
    _check_converged(fit, opts)
    return CalibrationResult(
        cameras=out_cams,
        rms_px=fit.rms,
        per_camera=per_camera,
        frames_used=len(frames),
        observations=len(fit.problem.cam),
        outliers=fit.outliers,
        world=_world_description(cams, root, floor, opts),
        solver={
            "initial_median_px": round(float(np.median(fit.initial_error)), 4),
            "outlier_threshold_px": round(fit.threshold, 4),
            "evaluations": int(fit.first.nfev + fit.second.nfev),
            "iterations": int(fit.first.iterations + fit.second.iterations),
            "status": int(fit.second.status),
            "message": str(fit.second.message),
            "root_camera": cams[root].det.name,
        },
    )


def _floor_frame_mask(
    detections: Sequence[CameraDetections], opts: CalibrationOptions
) -> np.ndarray:
    """Which clip frames show the board lying on the floor: (max frame + 2,) bool."""
    max_frame = max(int(d.frames.max()) for d in detections) + 1
    floor_frame = np.zeros(max_frame + 1, dtype=bool)
    if opts.floor_frames is not None:
        a, b = opts.floor_frames
        if not 0 <= a < b:
            raise CalibrationError(
                f"floor frames must be START:END with 0 <= START < END, got {a}:{b}"
            )
        floor_frame[a : min(b, max_frame + 1)] = True
    return floor_frame


def _cameras_intrinsics(
    detections: Sequence[CameraDetections],
    geom: BoardGeometry,
    floor_frame: np.ndarray,
    opts: CalibrationOptions,
) -> list[_CamData]:
    """Steps 1-2: each camera's intrinsics and its per-view board poses."""
    cams: list[_CamData] = []
    for det in detections:
        fmask = floor_frame[det.frames]
        coverage = _coverage(det)
        if opts.radial is not None:
            radial = opts.radial
        else:
            radial = 2 if coverage >= opts.k2_min_coverage else 1
        K, dist, rms, nv = _intrinsics(det, geom, fmask, opts, radial)
        poses = _board_poses(det, geom, K, dist, opts.min_corners)
        cams.append(_CamData(det, K, dist, rms, nv, radial, coverage, poses))
        log.info("%s: intrinsics from %d views, RMS %.3f px", det.name, nv, rms)
    return cams


@dataclass
class _FloorBoard:
    """The board lying on the floor as each camera saw it (cameras that did not: absent).

    Attributes
    ----------
    obs : camera index -> (N, 2) median corner positions over the floor frames
        (NaN for corners not seen in at least half of them).
    count : camera index -> (N,) number of floor frames each corner was found in.
    pose_cam : camera index -> (camera_from_board (4, 4), PnP error) of the floor board.
    """

    obs: dict[int, np.ndarray] = field(default_factory=dict)
    count: dict[int, np.ndarray] = field(default_factory=dict)
    pose_cam: dict[int, tuple[np.ndarray, float]] = field(default_factory=dict)


def _floor_board_views(
    cams: list[_CamData], geom: BoardGeometry, floor_frame: np.ndarray, opts: CalibrationOptions
) -> _FloorBoard:
    """Step 4a: the floor board as seen by each camera (median over the still frames).

    Raises when the board moved during the floor frames or no camera saw it
    there; empty when no floor frames are given.
    """
    floor = _FloorBoard()
    if opts.floor_frames is None:
        return floor
    for ci, c in enumerate(cams):
        fm = floor_frame[c.det.frames]
        if not np.any(fm):
            continue
        pts = c.det.corners[fm]  # (n, N, 2)
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN corners
            med = np.nanmedian(pts, axis=0)
        seen = np.isfinite(pts).all(-1)
        # a corner counts when found in at least half the floor frames
        ok = np.isfinite(med).all(-1) & (seen.sum(0) >= max(1, fm.sum() // 2))
        ids = np.flatnonzero(ok)
        if len(ids) < opts.min_corners or not _spans_plane(ids, geom.squares[0]):
            continue
        spread = np.nanmax(np.linalg.norm(pts[:, ids] - med[ids], axis=-1))
        if spread > 5.0:
            raise CalibrationError(
                f"camera {c.det.name!r}: the board moved during the floor frames "
                f"{opts.floor_frames[0]}:{opts.floor_frames[1]} (corners move by up to "
                f"{spread:.1f} px); it must lie still on the floor there (--floor-frames)"
            )
        obs = np.full_like(med, np.nan)
        obs[ids] = med[ids]
        res = _pnp(c.K, c.dist, geom.points[ids], med[ids])
        if res is None:
            continue
        floor.obs[ci] = obs
        floor.count[ci] = seen.sum(0)
        floor.pose_cam[ci] = res
    if not floor.obs:
        raise CalibrationError(
            f"no camera saw the board lying on the floor in frames "
            f"{opts.floor_frames[0]}:{opts.floor_frames[1]} (it defines the world frame); "
            "lay the board flat, printed side up, where at least one camera sees it, at "
            "the start of the clip, or give its frames with --floor-frames START:END"
        )
    return floor


def _root_camera(floor: _FloorBoard) -> int:
    """The camera that sees the floor board best (most corners, least PnP error); else 0."""
    if floor.obs:
        return max(
            floor.obs,
            key=lambda ci: np.isfinite(floor.obs[ci]).all(-1).sum() - floor.pose_cam[ci][1],
        )
    return 0


def _initial_extrinsics(
    cams: list[_CamData],
    root: int,
    geom: BoardGeometry,
    floor: _FloorBoard,
    floor_frame: np.ndarray,
    opts: CalibrationOptions,
) -> list[np.ndarray]:
    """Steps 3 and 4b: each camera's camera_from_world (4, 4), chained along the
    camera graph from ``root`` and placed by the floor board (else root = world)."""
    cam_from_root = _spanning_tree(cams, root, geom, opts, floor_frame)
    root_from_world = floor.pose_cam[root][0] @ _inv(FLOOR_BOARD_POSE) if floor.obs else np.eye(4)
    return [T @ root_from_world for T in cam_from_root]


def _initial_board_poses(
    cams: list[_CamData], cam_from_world: list[np.ndarray], floor_frame: np.ndarray
) -> tuple[list[int], np.ndarray]:
    """The moving board's frames (sorted) and its initial world_from_board (F, 4, 4),
    each from the camera with the most corners in that frame."""
    frame_views: dict[int, list[tuple[int, int]]] = {}
    for ci, c in enumerate(cams):
        for i in c.poses:
            f = int(c.det.frames[i])
            if not floor_frame[f]:
                frame_views.setdefault(f, []).append((ci, i))
    frames = sorted(frame_views)
    pose_index = {f: k for k, f in enumerate(frames)}
    poses0 = np.empty((len(frames), 4, 4))
    for f in frames:
        ci, i = max(frame_views[f], key=lambda v: cams[v[0]].det.found[v[1]].sum())
        poses0[pose_index[f]] = _inv(cam_from_world[ci]) @ cams[ci].poses[i]
    return frames, poses0


def _bundle_problem(
    cams: list[_CamData],
    geom: BoardGeometry,
    frames: list[int],
    floor: _FloorBoard,
    root: int,
    opts: CalibrationOptions,
) -> BundleProblem:
    """The bundle adjustment: every detected corner of a frame with an initial pose,
    the floor board's corners, and which parameters are free."""
    C = len(cams)
    pose_index = {f: k for k, f in enumerate(frames)}
    cam_l, pose_l, pt_l, uv_l, sw_l = [], [], [], [], []
    for ci, c in enumerate(cams):
        for i, f in enumerate(c.det.frames):
            f = int(f)
            if f not in pose_index:
                continue
            ids = np.flatnonzero(c.det.found[i])
            cam_l.append(np.full(len(ids), ci))
            pose_l.append(np.full(len(ids), pose_index[f]))
            pt_l.append(ids)
            uv_l.append(c.det.corners[i, ids])
            if c.det.refined is None:
                sw_l.append(np.ones(len(ids)))
            else:
                sw_l.append(np.where(c.det.refined[i, ids], 1.0, np.sqrt(opts.unrefined_weight)))
        if ci in floor.obs:
            ids = np.flatnonzero(np.isfinite(floor.obs[ci]).all(-1))
            cam_l.append(np.full(len(ids), ci))
            pose_l.append(np.full(len(ids), -1))
            pt_l.append(ids)
            uv_l.append(floor.obs[ci][ids])
            n_still = floor.count[ci][ids] if opts.floor_weight == "frames" else np.ones(len(ids))
            sw_l.append(np.sqrt(n_still))
    return BundleProblem(
        cam=np.concatenate(cam_l).astype(int),
        pose=np.concatenate(pose_l).astype(int),
        point=np.concatenate(pt_l).astype(int),
        uv=np.concatenate(uv_l),
        n_cams=C,
        n_poses=len(frames),
        obj=geom.points,
        fixed_pose=FLOOR_BOARD_POSE,
        free=_free_parameters(cams, len(frames), root, bool(floor.obs), opts),
        sw=np.concatenate(sw_l),
        square=opts.square_pixels,
    )


def _free_parameters(
    cams: list[_CamData], n_frames: int, root: int, has_floor: bool, opts: CalibrationOptions
) -> np.ndarray:
    """Which of the C * 14 + F * 6 parameters the bundle adjustment moves (bool)."""
    C = len(cams)
    n_params = C * CAMERA_PARAMS + n_frames * 6
    free = np.ones(n_params, dtype=bool)
    if not opts.refine_intrinsics:
        for ci in range(C):
            free[ci * CAMERA_PARAMS + 6 : (ci + 1) * CAMERA_PARAMS] = False
    if not opts.tangential:
        for ci in range(C):
            free[ci * CAMERA_PARAMS + 12 : ci * CAMERA_PARAMS + 14] = False
    if opts.square_pixels:
        for ci in range(C):
            free[ci * CAMERA_PARAMS + 7] = False
    for ci in range(C):
        free[ci * CAMERA_PARAMS + 10 + cams[ci].radial : ci * CAMERA_PARAMS + 12] = False
    if not has_floor:
        free[root * CAMERA_PARAMS : root * CAMERA_PARAMS + 6] = (
            False  # gauge: the root camera is the world
        )
    return free


@dataclass
class _BundleFit:
    """The outcome of :func:`_bundle_adjust`.

    Attributes
    ----------
    x : the solution (parameters of :func:`pack_parameters`'s layout).
    problem : the problem without the rejected outliers (M observations).
    error : (M,) reprojection error of each kept corner (px).
    rms : RMS of ``error`` (px).
    initial_error : (M0,) reprojection error of every corner at the start (px).
    threshold : the outlier threshold (px).
    outliers : how many corners were rejected.
    keep : (M0,) bool, the corners kept.
    all_cam : (M0,) camera index of every corner before the rejection.
    first, second : the two solves.
    """

    x: np.ndarray
    problem: BundleProblem
    error: np.ndarray
    rms: float
    initial_error: np.ndarray
    threshold: float
    outliers: int
    keep: np.ndarray
    all_cam: np.ndarray
    first: SolveResult
    second: SolveResult


def _bundle_adjust(pb: BundleProblem, x0: np.ndarray, opts: CalibrationOptions) -> _BundleFit:
    """Step 5: robust solve, reject outliers, solve again (raises on NaN)."""
    C, n_frames = pb.n_cams, pb.n_poses
    init_err = np.linalg.norm(reprojection_residuals(x0, pb).reshape(-1, 2), axis=1)
    log.info(
        "bundle adjustment: %d cameras, %d board poses, %d corners; initial median %.2f px",
        C,
        n_frames,
        len(pb.cam),
        float(np.median(init_err)),
    )
    x1, res1 = solve_bundle(pb, x0, opts, opts.loss)
    err = np.linalg.norm(reprojection_residuals(x1, pb).reshape(-1, 2), axis=1)
    _check_finite(err, x1, "first")
    sigma = float(np.median(err)) / 1.1774  # Rayleigh: median = 1.1774 sigma
    thr = max(opts.outlier_min_px, opts.outlier_sigma * sigma)
    keep = err <= thr
    n_out = int((~keep).sum())
    pb2 = pb.subset(keep)
    x2, res2 = solve_bundle(pb2, x1, opts, opts.loss)
    err2 = np.linalg.norm(reprojection_residuals(x2, pb2).reshape(-1, 2), axis=1)
    _check_finite(err2, x2, "second")
    rms = float(np.sqrt(np.mean(err2**2)))
    return _BundleFit(x2, pb2, err2, rms, init_err, thr, n_out, keep, pb.cam, res1, res2)


def _solved_cameras(
    cams: list[_CamData], fit: _BundleFit, floor: _FloorBoard, opts: CalibrationOptions
) -> tuple[CameraGroup, dict[str, dict[str, Any]]]:
    """The solved cameras and each one's quality figures; raises for a camera whose
    principal point left the image or whose RMS is not trustworthy."""
    cam_params, _ = unpack_parameters(fit.x, len(cams), fit.problem.n_poses)
    out_cams = []
    per_camera: dict[str, dict[str, Any]] = {}
    for ci, c in enumerate(cams):
        p = cam_params[ci]
        fy = p[6] if opts.square_pixels else p[7]
        K = np.array([[p[6], 0, p[8]], [0, fy, p[9]], [0, 0, 1.0]])
        dist = np.array([p[10], p[11], p[12], p[13], 0.0])
        R = rodrigues(p[:3])
        try:
            cam = Camera(c.det.name, c.det.size, K, dist, R, p[3:6])
        except ValueError as exc:
            raise CalibrationError(
                f"bundle adjustment gave an invalid camera {c.det.name!r}: {exc}"
            ) from exc
        out_cams.append(cam)
        mine = fit.problem.cam == ci
        e = fit.error[mine]
        crms = float(np.sqrt(np.mean(e**2))) if e.size else float("nan")
        w, h = c.det.size
        if not (0 < p[8] < w and 0 < p[9] < h):
            raise CalibrationError(
                f"camera {c.det.name!r}: the principal point ({p[8]:.1f}, {p[9]:.1f}) px left "
                f"the {w}x{h} image in the bundle adjustment; the views do not constrain this "
                "camera (show the board closer and at more angles)"
            )
        per_camera[c.det.name] = _camera_quality(c, ci, fit, mine, crms, floor)
        if not np.isfinite(crms) or crms > opts.max_rms_px:
            raise CalibrationError(
                f"camera {c.det.name!r}: bundle adjustment did not converge to a trustworthy "
                f"solution (reprojection RMS {crms:.2f} px > {opts.max_rms_px} px); check that "
                "the clips are synchronized and the board description is right"
            )
    return CameraGroup(out_cams), per_camera


def _camera_quality(
    c: _CamData, ci: int, fit: _BundleFit, mine: np.ndarray, crms: float, floor: _FloorBoard
) -> dict[str, Any]:
    """One camera's entry of :attr:`CalibrationResult.per_camera`."""
    return {
        "frames_read": int(c.det.frames_read),
        "boards_detected": int(c.det.boards_detected),
        "corners_detected": int(c.det.corners_detected),
        "corners_refined": c.det.corners_refined,
        "corners_used": int(mine.sum()),
        "outliers_rejected": int((fit.all_cam[~fit.keep] == ci).sum()),
        "rms_px": round(crms, 4),
        "intrinsic_views": c.intrinsic_views,
        "intrinsic_only_rms_px": round(c.intrinsic_rms, 4),
        "sees_floor": ci in floor.obs,
        "image_coverage": round(c.coverage, 3),
        "radial_terms": ["k1", "k2"][: c.radial],
    }


def _check_converged(fit: _BundleFit, opts: CalibrationOptions) -> None:
    """Raise unless the second solve converged to an RMS under ``max_rms_px``."""
    if not fit.second.success:
        raise CalibrationError(
            f"bundle adjustment did not converge within {opts.max_iterations} iterations "
            f"(RMS {fit.rms:.3f} px); the views may be too few or inconsistent"
        )
    if fit.rms > opts.max_rms_px:
        raise CalibrationError(
            f"bundle adjustment did not converge to a trustworthy solution: RMS {fit.rms:.2f} px "
            f"> {opts.max_rms_px} px"
        )


def _world_description(
    cams: list[_CamData], root: int, floor: _FloorBoard, opts: CalibrationOptions
) -> dict[str, str]:
    """The calibration's ``world`` note: how the world frame was defined."""
    if floor.obs:
        return {
            "frame": "ChArUco board on the floor, z up, metres",
            "note": (
                f"origin at the board's pattern origin, x along its columns; floor frames "
                f"{opts.floor_frames[0]}:{opts.floor_frames[1]}; seen by "
                f"{[cams[ci].det.name for ci in sorted(floor.obs)]}"
            ),
        }
    return {
        "frame": f"camera {cams[root].det.name} (no floor board: z is NOT up)",
        "note": "no floor frames were given",
    }


def _check_finite(err: np.ndarray, x: np.ndarray, which: str) -> None:
    if not (np.all(np.isfinite(err)) and np.all(np.isfinite(x))):
        raise CalibrationError(
            f"bundle adjustment gave NaN or infinite values in its {which} solve; "
            "the initial camera poses are inconsistent (check synchronization and the board)"
        )
