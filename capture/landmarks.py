"""The subject's body landmarks in 3D, from the segmenter's 2D landmarks in every view.

The person segmenter (:mod:`bodymetry.capture.person`) also gives BlazePose's 33
body landmarks per image. Triangulated through the calibrated cameras they put
the subject's joints in the world frame, which the fit uses to propose poses
(:mod:`bodymetry.estimation.landmark_pose`): frames whose pose the
discriminative mixtures never saw (a leg raised sideways, the trunk bent) are
found that way.

Per landmark: the views whose visibility score is at least ``min_visibility``
are triangulated (linear DLT, then Levenberg-Marquardt on the pixel error); while
more than two views remain and the worst view's reprojection error exceeds
``max_error`` (a fraction of the image height: a left/right swap, a hand
hidden behind the body), that view is dropped and the point triangulated again.

The same landmarks check the calibration (:func:`principal_point_offsets`):
over all kept frames, a camera whose detected landmarks sit systematically
beside where the calibration projects the triangulated ones (the median
reprojection residual) does not fit its video. On the Pose2Sim demo one
camera's landmarks sat 15 px to the right of its projections in every frame,
which cost the fit's mean IoU 0.04. The offset is estimated iteratively
(shift the principal points, triangulate again), the sparsest explanation is
taken, and it is applied when it exceeds ``min_shift`` of the image height.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.capture.person import LANDMARKS
from bodymetry.errors import InputError

__all__ = [
    "CameraOffset",
    "LandmarkConfig",
    "principal_point_offsets",
    "shifted_camera",
    "sparsest_offsets",
    "triangulate_landmarks",
]


@dataclass(frozen=True)
class LandmarkConfig:
    """Parameters of :func:`triangulate_landmarks`.

    Attributes
    ----------
    min_visibility : float
        A view's landmark is used when the model's visibility score is at least this.
    max_error : float
        Largest reprojection error of a used view, as a fraction of its image height.
    refine_calibration : bool
        Shift a camera's principal point when the landmarks show that it is
        systematically off (:func:`principal_point_offsets`).
    min_shift : float
        Smallest offset applied, as a fraction of the image height (below it
        the calibration is kept as given). The landmark detector's own bias
        leaves offsets of up to 0.81 % on studio sessions whose calibration is
        exact (up to 3.9 px at 480 px, the arm-raise session of the pipeline
        benchmark); the Pose2Sim demo's cam03 is 1.3 % off (25 px at 1920).
    min_observations : int
        Landmark observations a camera needs before its offset is trusted.
    """

    min_visibility: float = 0.5
    max_error: float = 0.02
    refine_calibration: bool = True
    min_shift: float = 0.01
    min_observations: int = 100

    def __post_init__(self) -> None:
        if not 0 <= self.min_visibility <= 1:
            raise InputError(
                f"landmarks.min_visibility: expected in [0, 1], got {self.min_visibility}"
            )
        if self.max_error <= 0:
            raise InputError(f"landmarks.max_error: expected > 0, got {self.max_error}")


def triangulate_landmarks(
    cameras: CameraGroup,
    landmarks: Sequence[np.ndarray | None],
    config: LandmarkConfig | None = None,
) -> np.ndarray:
    """World positions of the landmarks seen well enough in at least two views.

    Parameters
    ----------
    cameras : CameraGroup
        C cameras.
    landmarks : sequence of C ((33, 3) float or None)
        Per camera: pixel x, pixel y, visibility (:class:`capture.person.Person`);
        None where the view has none (nobody found, unreadable, inconsistent).
    config : LandmarkConfig, optional

    Returns
    -------
    (33, 3) float
        World coordinates, metres; NaN rows for landmarks with fewer than two
        consistent views.
    """
    cfg = config or LandmarkConfig()
    pixels = _detections(cameras, landmarks, cfg)
    return _triangulate(cameras, _unswapped(cameras, pixels, cfg), cfg)


def _mirror() -> np.ndarray:
    """(33,) int: each landmark's index with left and right exchanged."""
    index = {name: i for i, name in enumerate(LANDMARKS)}
    other = {"left_": "right_", "right_": "left_"}
    out = np.arange(len(LANDMARKS))
    for i, name in enumerate(LANDMARKS):
        for a, b in other.items():
            if name.startswith(a):
                out[i] = index[b + name[len(a) :]]
    return out


#: Landmark index with left and right exchanged.
MIRROR = _mirror()
#: The groups whose left/right labels a view may swap on its own (the detector
#: confuses the legs of a lunge without the arms, or the whole body), each with
#: the pair that says which side is left: face (ears), arms (shoulders), legs (hips).
SWAP_GROUPS: tuple[tuple[np.ndarray, tuple[int, int]], ...] = (
    (np.arange(1, 11), (7, 8)),
    (np.arange(11, 23), (11, 12)),
    (np.arange(23, 33), (23, 24)),
)


def _unswapped(cameras: CameraGroup, pixels: np.ndarray, cfg: LandmarkConfig) -> np.ndarray:
    """``pixels`` (C, 33, 2) with the views whose left and right labels disagree
    with the other views' exchanged, per :data:`SWAP_GROUPS` group.

    Dropping the worst view per landmark (:func:`_triangulate`) mends one swapped
    view of four, not two: in a lunge the detector swaps the legs or the arms in
    some views (Demo_MultiPerson, frame 60: the arms in two cameras of four), and
    the triangulated limbs land between the sides. So every labelling of a group
    (each view as detected or mirrored) is triangulated, and scored by its
    observations' reprojection errors in units of ``cfg.max_error``, capped at 1
    (an observation that does not fit counts once, however far off). The views
    are relabelled only when the best labelling scores at least one observation
    better than the detected one. A labelling and its mirror (every view
    swapped) score the same; of the two, the one whose left landmarks lie on the
    body's left is taken: left is up x forward, up from the hips' to the
    shoulders' midpoint, forward from the ears' midpoint to the nose (midpoints
    and the nose do not depend on the labels); without those, the one that
    relabels fewer views.
    """
    seen = np.isfinite(pixels[..., 0])
    views = np.flatnonzero(seen.any(axis=1))
    if views.size < 3:
        return pixels  # two views: any labelling triangulates to something
    limit = cfg.max_error * np.array(cameras.sizes, float)[:, 1:]  # (C, 1)
    out = pixels.copy()
    # A labelling and its mirror score the same: the first view stays as detected.
    labellings = [
        np.array([(k >> i) & 1 for i in range(views.size)], bool)
        for k in range(0, 2**views.size, 2)
    ]

    def errors(trials: np.ndarray) -> np.ndarray:
        """(T, L) capped error sums over the views of each landmark of labellings
        (T, C, L, 2), triangulated in one go."""
        t, _, n, _ = trials.shape
        stacked = trials.transpose(1, 0, 2, 3).reshape(len(pixels), t * n, 2)
        X = _triangulate(cameras, stacked, cfg)
        with np.errstate(invalid="ignore"):
            err = np.linalg.norm(cameras.project(X) - stacked, axis=-1) / limit
        seen = np.isfinite(stacked[..., 0])
        err = np.where(seen, np.where(np.isnan(err), 1.0, np.fmin(err, 1.0)), 0.0)
        return err.reshape(len(pixels), t, n).sum(axis=0)

    def scores(trials: np.ndarray) -> np.ndarray:
        return errors(trials).sum(axis=1)

    detected = errors(pixels[None])[0]
    as_detected = [detected[group].sum() for group, _ in SWAP_GROUPS]
    best_of = []
    for (group, _), score in zip(SWAP_GROUPS, as_detected, strict=True):
        if score < 1.0:
            best_of.append(None)  # the views agree as detected
            continue
        trials = np.repeat(pixels[None][:, :, group], len(labellings), axis=0)
        for t, flip in enumerate(labellings):
            trials[t, views[flip]] = pixels[views[flip]][:, MIRROR[group]]
        scored = scores(trials)
        k = int(np.argmin(scored))
        best_of.append(labellings[k] if scored[k] < scored[0] - 1.0 else None)
    # Each group's chosen labelling or its mirror: the one that puts its left on the left.
    for (group, _), flip in zip(SWAP_GROUPS, best_of, strict=True):
        if flip is not None:
            out[views[flip][:, None], group] = pixels[views[flip]][:, MIRROR[group]]
    left = _left_direction(_triangulate(cameras, out, cfg))
    for (group, (a, b)), flip in zip(SWAP_GROUPS, best_of, strict=True):
        if flip is None:
            continue
        X = _triangulate(cameras, out[:, [a, b]], cfg)
        side = float((X[0] - X[1]) @ left) if left is not None else np.nan
        mirrored = side < 0 if np.isfinite(side) else flip.sum() > views.size / 2
        if mirrored:
            # The mirror labelling: the views kept as detected are swapped instead.
            keep = views[~flip]
            out[views[flip][:, None], group] = pixels[views[flip][:, None], group]
            out[keep[:, None], group] = pixels[keep][:, MIRROR[group]]
    return out


def _left_direction(points: np.ndarray) -> np.ndarray | None:
    """(3,) the body's left (unit) from (33, 3) world landmarks: up x forward, up
    from the hips' to the shoulders' midpoint, forward from the ears' midpoint
    to the nose; None where those are not known."""
    up = points[[11, 12]].mean(axis=0) - points[[23, 24]].mean(axis=0)
    forward = points[0] - points[[7, 8]].mean(axis=0)
    left = np.cross(up, forward)
    norm = np.linalg.norm(left)
    return left / norm if np.isfinite(norm) and norm > 0 else None


def _detections(
    cameras: CameraGroup, landmarks: Sequence[np.ndarray | None], cfg: LandmarkConfig
) -> np.ndarray:
    """(C, 33, 2) pixels of the landmarks seen well enough per view; NaN otherwise."""
    if len(landmarks) != len(cameras):
        raise InputError(f"expected landmarks for {len(cameras)} cameras, got {len(landmarks)}")
    n = len(LANDMARKS)
    pixels = np.full((len(cameras), n, 2), np.nan)
    for c, lm in enumerate(landmarks):
        if lm is None:
            continue
        lm = np.asarray(lm, float)
        if lm.shape != (n, 3):
            raise InputError(
                f"camera {cameras[c].name!r}: landmarks must be ({n}, 3), got {lm.shape}"
            )
        seen = lm[:, 2] >= cfg.min_visibility
        pixels[c, seen] = lm[seen, :2]
    return pixels


def _triangulate(cameras: CameraGroup, pixels: np.ndarray, cfg: LandmarkConfig) -> np.ndarray:
    """(N, 3) world points of detections (C, N, 2), each triangulated on its own.

    A point whose worst view reprojects further than ``cfg.max_error`` of the
    image height loses that view while it keeps two; NaN rows where fewer than
    two consistent views remain. Points are independent, so the landmarks of
    many frames can be stacked along N.
    """
    pixels = pixels.copy()
    n = pixels.shape[1]
    limit = cfg.max_error * np.array(cameras.sizes, float)[:, 1:]  # (C, 1): image heights
    points = np.full((n, 3), np.nan)
    todo = np.arange(n)
    while todo.size:
        px = pixels[:, todo]
        X = cameras.triangulate(px, refine=True)
        with np.errstate(invalid="ignore"):
            err = np.linalg.norm(cameras.project(X) - px, axis=-1) / limit  # (C, k)
        err = np.where(np.isfinite(px[..., 0]), err, -np.inf)
        worst = np.argmax(err, axis=0)
        bad = err[worst, np.arange(todo.size)] > 1.0
        views = np.isfinite(px[..., 0]).sum(axis=0)
        ok = np.all(np.isfinite(X), axis=1) & ~bad
        points[todo[ok]] = X[ok]
        # Drop the worst view of the inconsistent points that keep at least two.
        again = bad & (views > 2)
        pixels[worst[again], todo[again]] = np.nan
        todo = todo[again]
    return points


@dataclass(frozen=True)
class CameraOffset:
    """A camera's systematic landmark offset (:func:`principal_point_offsets`).

    Attributes
    ----------
    camera : str
    dx, dy : float
        Median of (detected - projected) landmark pixels, after convergence.
    observations : int
        Landmark observations it rests on.
    applied : bool
        Large enough (and well enough supported) to shift the principal point.
    """

    camera: str
    dx: float
    dy: float
    observations: int
    applied: bool

    def describe(self) -> str:
        return (
            f"camera {self.camera!r}: the subject's landmarks sit {self.dx:+.1f} px in x and "
            f"{self.dy:+.1f} px in y from where the calibration projects them (median of "
            f"{self.observations} observations over the kept frames)"
        )


def shifted_camera(camera: Camera, dx: float, dy: float) -> Camera:
    """``camera`` with its principal point moved by (dx, dy) pixels: every projection
    moves by exactly that (the lens model acts before the intrinsics)."""
    K = camera.K.copy()
    K[0, 2] += dx
    K[1, 2] += dy
    return dataclasses.replace(camera, K=K)


def _joint_offsets(
    cameras: CameraGroup,
    frames: Sequence[Sequence[np.ndarray | None]],
    cfg: LandmarkConfig,
    iterations: int = 8,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offsets (C, 2) that make the detections agree with the points triangulated
    through the shifted cameras (iterated to a fixed point), the observation counts
    (C,), and the landmarks' centroid (3,) over all frames."""
    n_cam = len(cameras)
    total = np.zeros((n_cam, 2))
    counts = np.zeros(n_cam, int)
    current = cameras
    # Every frame's landmarks in one stack: the triangulation of each point is
    # its own, and one call for all frames is far cheaper than one per frame.
    pixels = np.concatenate([_detections(cameras, views, cfg) for views in frames], axis=1)
    for _ in range(iterations):
        X = _triangulate(current, pixels, cfg)  # (F * 33, 3)
        found = np.all(np.isfinite(X), axis=1)
        step = np.zeros((n_cam, 2))
        for c in range(n_cam):
            ok = found & np.isfinite(pixels[c, :, 0])
            if ok.any():
                r = pixels[c, ok] - current[c].project(X[ok])
                counts[c], step[c] = len(r), np.median(r, axis=0)
        total += step
        current = CameraGroup([shifted_camera(cam, *total[c]) for c, cam in enumerate(cameras)])
        if np.abs(step).max() < 0.05:
            break
    return total, counts, np.nanmean(X, axis=0)


def sparsest_offsets(cameras: CameraGroup, offsets: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Among the offsets that explain the detections equally well, the sparsest.

    Moving the triangulated points by t moves every camera's projections by
    J_c t (J_c the projection's Jacobian at the subject), so offsets are only
    known up to ``offsets - J t``. Most cameras of a rig are right: t minimizes
    the sum over cameras of the offsets' lengths (a group-sparse choice), which
    puts the error on the camera(s) that are off instead of spreading it.

    Parameters
    ----------
    cameras : CameraGroup
        C cameras, at the resolution of the offsets' pixels.
    offsets : (C, 2) float
        Pixels.
    centre : (3,) float
        The subject's position, world metres.

    Returns
    -------
    (C, 2) float
    """
    J = []
    for cam in cameras:
        h = 1e-4
        cols = [
            (cam.project(centre + h * e) - cam.project(centre - h * e)) / (2 * h) for e in np.eye(3)
        ]
        J.append(np.column_stack(cols))  # (2, 3)
    J = np.asarray(J)

    def cost(t: np.ndarray) -> float:
        return float(np.linalg.norm(offsets - J @ t, axis=1).sum())

    t = minimize(cost, np.zeros(3), method="Nelder-Mead", options={"xatol": 1e-7, "fatol": 1e-6}).x
    return offsets - J @ t


def principal_point_offsets(
    cameras: CameraGroup,
    frames: Sequence[Sequence[np.ndarray | None]],
    config: LandmarkConfig | None = None,
    max_frames: int = 30,
) -> tuple[CameraGroup, list[CameraOffset]]:
    """Shift the principal points of the cameras that the subject's landmarks show off.

    The median reprojection residual of each camera's detections, iterated with
    the triangulation to a fixed point, gives offsets that are known only up to
    a common motion of the subject; of those, the sparsest set is taken
    (:func:`sparsest_offsets`: most cameras are right). A camera whose offset exceeds
    ``min_shift`` of its image height, on at least ``min_observations``
    detections, gets its principal point shifted.

    Parameters
    ----------
    cameras : CameraGroup
        C cameras as calibrated, at the resolution of the landmarks' pixels.
    frames : sequence of (sequence of C ((33, 3) float or None))
        Per kept frame, the per-camera landmarks
        (:attr:`SilhouetteFrame.view_landmarks`).
    config : LandmarkConfig, optional
    max_frames : int
        At most this many frames, evenly spread, are used.

    Returns
    -------
    cameras : CameraGroup
        The rig with the applied offsets (the others are the same objects).
    offsets : list of CameraOffset
        Per camera, applied or not.
    """
    cfg = config or LandmarkConfig()
    frames = [f for f in frames if sum(v is not None for v in f) >= 3]
    if len(frames) > max_frames:
        frames = [frames[i] for i in np.linspace(0, len(frames) - 1, max_frames).astype(int)]
    if not frames:
        return cameras, [CameraOffset(c.name, 0.0, 0.0, 0, False) for c in cameras]
    joint, counts, centre = _joint_offsets(cameras, frames, cfg)
    sparse = sparsest_offsets(cameras, joint, centre)
    limit = cfg.min_shift * np.array(cameras.sizes, float)[:, 1]  # image heights
    applied = (np.hypot(sparse[:, 0], sparse[:, 1]) >= limit) & (counts >= cfg.min_observations)
    out = CameraGroup(
        [shifted_camera(cam, *sparse[c]) if applied[c] else cam for c, cam in enumerate(cameras)]
    )
    offsets = [
        CameraOffset(
            cam.name, float(sparse[c, 0]), float(sparse[c, 1]), int(counts[c]), bool(applied[c])
        )
        for c, cam in enumerate(cameras)
    ]
    return out, offsets
