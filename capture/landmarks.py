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
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.capture.person import LANDMARKS
from bodymetry.errors import InputError

__all__ = ["LandmarkConfig", "triangulate_landmarks"]


@dataclass(frozen=True)
class LandmarkConfig:
    """Parameters of :func:`triangulate_landmarks`.

    Attributes
    ----------
    min_visibility : float
        A view's landmark is used when the model's visibility score is at least this.
    max_error : float
        Largest reprojection error of a used view, as a fraction of its image height.
    """

    min_visibility: float = 0.5
    max_error: float = 0.02

    def __post_init__(self) -> None:
        if not 0 <= self.min_visibility <= 1:
            raise InputError(
                f"landmarks.min_visibility: expected in [0, 1], got {self.min_visibility}"
            )
        if self.max_error <= 0:
            raise InputError(f"landmarks.max_error: expected > 0, got {self.max_error}")


def triangulate_landmarks(
    cameras: Sequence[Camera],
    landmarks: Sequence[np.ndarray | None],
    config: LandmarkConfig | None = None,
) -> np.ndarray:
    """World positions of the landmarks seen well enough in at least two views.

    Parameters
    ----------
    cameras : sequence of C Camera
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
    group = CameraGroup(cameras)
    limit = cfg.max_error * np.array([c.size[1] for c in cameras], float)[:, None]  # (C, 1)
    points = np.full((n, 3), np.nan)
    todo = np.arange(n)
    while todo.size:
        px = pixels[:, todo]
        X = group.triangulate(px, refine=True)
        with np.errstate(invalid="ignore"):
            err = np.linalg.norm(group.project(X) - px, axis=-1) / limit  # (C, k)
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
