"""People in the capture volume, counted from the persons each view's segmenter finds.

Without an empty-scene clip capture has no source that sees everyone: the
learned segmenter returns one person per call, so it is asked again with the
people found hidden (:meth:`bodymetry.capture.person.PersonSegmenter.detect_others`).
Counting those detections through the visual hull does not work: where two
people stand apart, the cone of one in some views crosses the cone of the
other in the others, and the hull holds phantom bodies between them (on the
real two-person Pose2Sim recording the hull of all detections had 1 to 4
person-sized bodies in frames with two people). Nor does the floor under the
feet: in a lunge the back heel leaves the floor, and its ray meets the floor
up to a metre away, differently in every camera.

The skeletons do not have phantoms. Two detections in two cameras are the
same person when their body landmarks (shoulders to ankles), triangulated from
the two views, reproject onto both within :data:`MATCH_ERROR` of the image
height, inside the capture volume. A person is a group of detections, at most
one per camera, every two of which match (complete linkage), that
``min_views`` cameras agree on: a bystander seen by one or two cameras, or
standing outside the volume, is nobody's count.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.optimize import linear_sum_assignment

from bodymetry.calibration.camera import CameraGroup
from bodymetry.capture.person import LANDMARKS
from bodymetry.errors import InputError

__all__ = [
    "BODY_LANDMARKS",
    "MATCH_ERROR",
    "PersonGroup",
    "count_people",
    "group_people",
    "landmark_pixels",
    "match_error",
]

#: The landmarks compared between views (the face is small and the hands often hidden).
BODY_LANDMARKS = (
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist",
    "right_wrist", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle",
    "right_ankle",
)  # fmt: skip
_BODY = [LANDMARKS.index(n) for n in BODY_LANDMARKS]

#: A landmark counts where the landmark model's visibility is at least this.
MIN_VISIBILITY = 0.5
#: Two detections are compared on at least this many landmarks both show.
MIN_SHARED = 4
#: Two detections are one person when the median reprojection error of their shared
#: landmarks, triangulated from the two views, is below this fraction of the image
#: height (measured on the real Pose2Sim rig: see docs/capture.md).
MATCH_ERROR = 0.03
#: Height range (metres) of the capture volume for the triangulated landmarks.
_Z_RANGE = (-0.3, 2.6)
#: Stand-in error of two detections that cannot be one person.
_APART = 1e6


def _seen(landmarks: np.ndarray, visibility: float = MIN_VISIBILITY) -> np.ndarray:
    """(..., L) bool: the landmarks (..., L, 3) that are known and at least ``visibility``
    visible."""
    return np.isfinite(landmarks).all(axis=-1) & (landmarks[..., 2] >= visibility)


def landmark_pixels(
    views: Sequence[np.ndarray | None], rows: Sequence[int], visibility: float = MIN_VISIBILITY
) -> np.ndarray:
    """(C, L, 2) pixels of the landmarks ``rows`` (L) of each camera's (33, 3)
    detection (None: not seen), NaN where not seen well enough, for
    :meth:`CameraGroup.triangulate`."""
    pixels = np.full((len(views), len(rows), 2), np.nan)
    for c, lm in enumerate(views):
        if lm is not None:
            body = np.asarray(lm, float)[rows]
            seen = _seen(body, visibility)
            pixels[c, seen] = body[seen, :2]
    return pixels


def match_error(
    cameras: CameraGroup, a: np.ndarray, b: np.ndarray, floor_box: tuple | None = None
) -> float:
    """How far two cameras' detections are from being one person.

    Parameters
    ----------
    cameras : CameraGroup
        The two cameras.
    a, b : (33, 3) float
        Their landmarks (:attr:`bodymetry.capture.person.Person.landmarks`).
    floor_box : ((2,) float, (2,) float), optional
        The capture volume's floor (x, y) box.

    Returns
    -------
    float
        The median reprojection error of their shared body landmarks, as a
        fraction of the image height (the larger of the two cameras'); inf with
        fewer than :data:`MIN_SHARED` shared landmarks or when the triangulated
        body lies outside the capture volume.
    """
    pair = np.stack([np.asarray(a, float), np.asarray(b, float)])[:, _BODY]  # (2, L, 3)
    shared = _seen(pair).all(axis=0)
    if shared.sum() < MIN_SHARED:
        return np.inf
    pixels = pair[:, shared, :2]
    points = cameras.triangulate(pixels)
    if not np.isfinite(points).all():
        return np.inf
    centre = np.median(points, axis=0)
    if not _Z_RANGE[0] <= centre[2] <= _Z_RANGE[1]:
        return np.inf
    if floor_box is not None:
        lo, hi = (np.asarray(v, float) for v in floor_box)
        if not ((centre[:2] >= lo) & (centre[:2] <= hi)).all():
            return np.inf
    # Behind a camera the DLT still returns a point; its projection is meaningless.
    if any((cam.to_camera(points)[:, 2] <= 0).any() for cam in cameras):
        return np.inf
    error = np.linalg.norm(cameras.project(points) - pixels, axis=2)  # (2, S)
    height = max(size[1] for size in cameras.sizes)
    return float(np.median(error) / height)


@dataclass(frozen=True)
class PersonGroup:
    """One person as the cameras' detections agree on them (:func:`group_people`).

    Attributes
    ----------
    detections : tuple of (int or None)
        Per camera, the index of their detection in that camera's list, or
        None where the camera did not find them (hidden, or missed).
    position : (3,) float
        World point, metres: the median of their body landmarks triangulated
        from every camera that found them.
    """

    detections: tuple[int | None, ...]
    position: np.ndarray

    @property
    def views(self) -> int:
        """Cameras that found them."""
        return sum(d is not None for d in self.detections)


def group_people(
    cameras: CameraGroup,
    people: Sequence[Sequence[np.ndarray]],
    floor_box: tuple | None = None,
    min_views: int = 3,
    match: float = MATCH_ERROR,
) -> list[PersonGroup]:
    """The people that ``min_views`` cameras agree on (module docstring), most
    cameras first, then from left to right along the world x axis.

    Parameters
    ----------
    cameras : CameraGroup
        C cameras, at the resolution of the landmarks' pixels.
    people : sequence of C sequences of (33, 3) float
        Per camera, the landmarks of each person detected in its image.
    floor_box : ((2,) float, (2,) float), optional
        The capture volume's floor (x, y) box.
    min_views : int
    match : float
        :data:`MATCH_ERROR`.

    Returns
    -------
    list of PersonGroup
    """
    if len(people) != len(cameras):
        raise InputError(f"expected detections for {len(cameras)} cameras, got {len(people)}")
    found = [[np.asarray(lm, float) for lm in view] for view in people]
    nodes = [(c, k, lm) for c, view in enumerate(found) for k, lm in enumerate(view)]
    if len({c for c, _, _ in nodes}) < min_views:
        return []
    n = len(nodes)
    distance = np.full((n, n), _APART)
    np.fill_diagonal(distance, 0.0)
    for i in range(n):
        for j in range(i + 1, n):
            (ci, _, a), (cj, _, b) = nodes[i], nodes[j]
            if ci != cj:
                error = match_error(cameras.select([ci, cj]), a, b, floor_box)
                distance[i, j] = distance[j, i] = min(error, _APART)
    condensed = distance[np.triu_indices(n, k=1)]
    labels = fcluster(linkage(condensed, method="complete"), t=match, criterion="distance")
    groups: list[list[int | None]] = []
    for g in np.unique(labels):
        members = [nodes[i] for i in np.flatnonzero(labels == g)]
        if len({c for c, _, _ in members}) < min_views:
            continue
        detections: list[int | None] = [None] * len(cameras)
        for c, k, _ in members:
            detections[c] = k
        groups.append(detections)
    groups = _reassigned(cameras, found, groups, match)
    out = []
    for detections in groups:
        if sum(k is not None for k in detections) < min_views:
            continue
        points = cameras.triangulate(_body_pixels(found, detections))
        position = np.nanmedian(points, axis=0) if np.isfinite(points).any() else np.full(3, np.nan)
        out.append(PersonGroup(tuple(detections), position))
    out.sort(key=lambda p: (-p.views, float(np.nan_to_num(p.position[0]))))
    return out


def _body_pixels(
    found: Sequence[Sequence[np.ndarray]], detections: Sequence[int | None]
) -> np.ndarray:
    """(C, L, 2) pixels of a group's body landmarks (NaN: not seen well enough)."""
    return landmark_pixels(
        [None if k is None else found[c][k] for c, k in enumerate(detections)], _BODY
    )


def _reassigned(
    cameras: CameraGroup,
    found: Sequence[Sequence[np.ndarray]],
    groups: list[list[int | None]],
    match: float,
) -> list[list[int | None]]:
    """Each camera's detections given again to the groups, by how well each matches
    the group's skeleton triangulated from the group's *other* cameras.

    Two views can be fooled (a shift along their epipolar lines costs nothing),
    and complete linkage judges pairs: with one person hidden behind another in a
    camera, that camera's one detection can join the hidden person's group. Three
    or more other views pin a skeleton down; an optimal assignment per camera
    (:func:`scipy.optimize.linear_sum_assignment`) then gives each detection to
    the skeleton it lies on, within ``match`` of the image height.
    """
    if len(groups) < 2:
        return groups
    out = [list(g) for g in groups]
    height = max(size[1] for size in cameras.sizes)
    for c, camera in enumerate(cameras):
        if not found[c]:
            continue
        cost = np.full((len(groups), len(found[c])), np.inf)
        for g, detections in enumerate(groups):
            others = [None if v == c else k for v, k in enumerate(detections)]
            if sum(k is not None for k in others) < 2:
                continue
            points = cameras.triangulate(_body_pixels(found, others))
            for k, lm in enumerate(found[c]):
                body = lm[_BODY]
                seen = _seen(body) & np.isfinite(points).all(axis=1)
                if seen.sum() < MIN_SHARED:
                    continue
                error = np.linalg.norm(camera.project(points[seen]) - body[seen, :2], axis=1)
                cost[g, k] = np.median(error) / height
        if not np.isfinite(cost).any():
            continue
        rows, cols = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e6))
        for g in range(len(groups)):
            out[g][c] = None
        for g, k in zip(rows, cols, strict=True):
            if cost[g, k] <= match:
                out[g][c] = int(k)
            elif groups[g][c] == k:
                out[g][c] = int(k)  # no better skeleton: the clustering's choice stands
    return out


def count_people(
    cameras: CameraGroup,
    people: Sequence[Sequence[np.ndarray]],
    floor_box: tuple | None = None,
    min_views: int = 3,
    match: float = MATCH_ERROR,
) -> int:
    """How many people ``min_views`` cameras agree on (:func:`group_people`)."""
    return len(group_people(cameras, people, floor_box, min_views, match))
