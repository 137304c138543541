"""Every person of a kept frame, with the pixels that are theirs in each camera.

Capture measures one subject per frame by default. To measure a chosen person
of a multi-person recording (``bodymetry process --person N``), each person's
silhouette in each camera is needed, with the cameras in which someone else
hides part of them.

Without an empty-scene clip the people are the learned segmenter's
detections: the most prominent person of each image and the others found with
the first ones hidden (:meth:`bodymetry.capture.person.PersonSegmenter.detect_others`),
grouped across cameras by their skeletons (:func:`bodymetry.capture.headcount.group_people`).
A person's silhouette in a camera is the part of the camera's person pixels
(the union of its detections' masks) nearer to their skeleton than to anyone
else's (:func:`partition`): the segmenter marks every person inside the crop
it looks at, so one detection's mask can hold another's head. Where someone
nearer to a camera covers part of a person's skeleton (the landmark model
places hidden limbs too), part of them is hidden: the view is ``occluded`` for
them, and the fit leaves it out (a hidden part is unknown, not background).
Where no detection of a camera is theirs, the camera did not see them.

Identities across kept frames are given by :mod:`bodymetry.capture.tracks`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from bodymetry.calibration.camera import CameraGroup
from bodymetry.capture.headcount import group_people
from bodymetry.capture.person import LANDMARKS, Person

__all__ = ["BONES", "Sighting", "partition", "sightings", "skeleton_mask"]

#: The skeleton drawn for :func:`partition`: pairs of landmarks (the face as a chain
#: from ear to ear, so a head is claimed by its own face).
BONES = tuple(
    (LANDMARKS.index(a), LANDMARKS.index(b))
    for a, b in (
        ("left_ear", "left_eye"), ("left_eye", "nose"), ("nose", "right_eye"),
        ("right_eye", "right_ear"), ("nose", "left_shoulder"), ("nose", "right_shoulder"),
        ("left_shoulder", "right_shoulder"), ("left_shoulder", "left_elbow"),
        ("left_elbow", "left_wrist"), ("right_shoulder", "right_elbow"),
        ("right_elbow", "right_wrist"), ("left_shoulder", "left_hip"),
        ("right_shoulder", "right_hip"), ("left_hip", "right_hip"), ("left_hip", "left_knee"),
        ("left_knee", "left_ankle"), ("right_hip", "right_knee"), ("right_knee", "right_ankle"),
        ("left_ankle", "left_heel"), ("left_heel", "left_foot_index"),
        ("right_ankle", "right_heel"), ("right_heel", "right_foot_index"),
    )
)  # fmt: skip
#: Landmarks less visible than this are not drawn.
BONE_VISIBILITY = 0.3
#: A person's pixels lie within this fraction of their skeleton's height of a bone (the
#: torso is about a fifth of a person's height wide, the bones run down its middle).
REACH = 0.2
#: A person is ``occluded`` in a camera when someone nearer to it covers more than
#: this share of their skeleton there, drawn :data:`BONE_WIDTH` of the image height
#: wide (the landmark model places hidden limbs too).
OCCLUDED_SHARE = 0.02
BONE_WIDTH = 0.01


@dataclass(frozen=True)
class Sighting:
    """One person found in one kept frame.

    Attributes
    ----------
    position : (3,) float
        World point, metres: the middle of their triangulated body landmarks.
    masks : tuple of ((H_c, W_c) bool or None), length C
        Per camera, the pixels that are theirs; None where the camera did not
        find them.
    landmarks : tuple of ((33, 3) float or None), length C
        Per camera, their landmarks (:attr:`Person.landmarks`), None as ``masks``.
    occluded : tuple of bool, length C
        Per camera, whether someone nearer to it touches their silhouette
        (part of them may be hidden: the view is left out of their fit).
    """

    position: np.ndarray
    masks: tuple[np.ndarray | None, ...]
    landmarks: tuple[np.ndarray | None, ...]
    occluded: tuple[bool, ...]

    @property
    def views(self) -> int:
        """Cameras that found them."""
        return sum(m is not None for m in self.masks)


def sightings(
    cameras: CameraGroup,
    detections: Sequence[Sequence[Person]],
    threshold: float,
    floor_box: tuple | None = None,
    min_views: int = 3,
) -> list[Sighting]:
    """The people of one frame that ``min_views`` cameras agree on.

    Parameters
    ----------
    cameras : CameraGroup
        C cameras, at the resolution of the detections.
    detections : sequence of C sequences of Person
        Per camera, every person its segmenter found, most prominent first.
    threshold : float
        The segmenter's probability threshold (:attr:`PersonConfig.threshold`).
    floor_box : ((2,) float, (2,) float), optional
        The capture volume's floor (x, y) box.
    min_views : int

    Returns
    -------
    list of Sighting
        In :func:`~bodymetry.capture.headcount.group_people`'s order.
    """
    groups = group_people(
        cameras, [[p.landmarks for p in found] for found in detections], floor_box, min_views
    )
    masks = [partition(found, threshold) for found in detections]
    out = []
    for g in groups:
        occluded = []
        for c, k in enumerate(g.detections):
            hidden = False
            if k is not None:
                h = masks[c][k].shape[0]
                bones = skeleton_mask(
                    detections[c][k].landmarks, masks[c][k].shape, round(BONE_WIDTH * h)
                )
                mine = _distance(cameras[c], g.position)
                nearer = np.zeros_like(masks[c][k])
                for other in groups:
                    j = other.detections[c]
                    if j is not None and j != k and _distance(cameras[c], other.position) < mine:
                        nearer |= masks[c][j]
                hidden = bones is not None and (
                    np.count_nonzero(bones & nearer) > OCCLUDED_SHARE * np.count_nonzero(bones)
                )
            occluded.append(hidden)
        out.append(
            Sighting(
                position=g.position,
                masks=tuple(None if k is None else masks[c][k] for c, k in enumerate(g.detections)),
                landmarks=tuple(
                    None if k is None else detections[c][k].landmarks
                    for c, k in enumerate(g.detections)
                ),
                occluded=tuple(occluded),
            )
        )
    return out


def skeleton_mask(
    landmarks: np.ndarray, shape: tuple[int, int], width: int = 3
) -> np.ndarray | None:
    """(H, W) bool: the :data:`BONES` of ``landmarks`` (33, 3) drawn ``width`` pixels
    wide (bones with a landmark less visible than :data:`BONE_VISIBILITY` left
    out); None when no bone can be drawn."""
    canvas = np.zeros(shape, np.uint8)
    lm = np.asarray(landmarks, float)
    drawn = False
    for a, b in BONES:
        if (np.isfinite(lm[[a, b]]).all() and lm[a, 2] >= BONE_VISIBILITY
                and lm[b, 2] >= BONE_VISIBILITY):  # fmt: skip
            pa, pb = (tuple(round(v) for v in lm[i, :2]) for i in (a, b))
            cv2.line(canvas, pa, pb, 1, max(int(width), 1))
            drawn = True
    return canvas > 0 if drawn else None


def partition(found: Sequence[Person], threshold: float) -> list[np.ndarray]:
    """Each detected person's pixels in one image: the union of the detections'
    masks, each pixel to the person whose skeleton (:data:`BONES`) is nearest.

    Parameters
    ----------
    found : sequence of Person
        The image's detections.
    threshold : float
        The segmenter's probability threshold.

    Returns
    -------
    list of (H, W) bool
        One per detection, disjoint; pixels further than :data:`REACH` from
        every skeleton are nobody's; a detection without a drawable skeleton
        claims its own mask.
    """
    if len(found) < 2:
        return [p.mask(threshold) for p in found]
    masks = [p.mask(threshold) for p in found]
    union = np.logical_or.reduce(masks)
    h, w = union.shape
    distance = np.empty((len(found), h, w), np.float32)
    for k, person in enumerate(found):
        bones = skeleton_mask(person.landmarks, (h, w))
        if bones is not None:
            distance[k] = cv2.distanceTransform((~bones).astype(np.uint8), cv2.DIST_L2, 3)
            # Pixels far from every bone are nobody's (a bystander the segmenter
            # marked in the crop but did not detect).
            rows = np.flatnonzero(bones.any(axis=1))
            distance[k][distance[k] > REACH * (rows[-1] - rows[0] + 1)] = np.inf
        else:
            # No skeleton to measure from: the person claims their own mask only.
            distance[k] = np.where(masks[k], 0.0, np.inf)
    owner = np.argmin(distance, axis=0)
    claimed = np.isfinite(distance.min(axis=0))
    return [union & claimed & (owner == k) for k in range(len(found))]


def _distance(camera, point: np.ndarray) -> float:
    """Distance (metres) from ``camera``'s centre to ``point`` (inf when unknown)."""
    d = float(np.linalg.norm(np.asarray(point, float) - camera.center))
    return d if np.isfinite(d) else np.inf
