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
it looks at, so one detection's mask can hold another's head. With an
empty-scene clip, those pixels are snapped to everyone's fused, edge-refined
silhouette (:func:`partition`'s ``silhouette``), whose outline is the image's,
not the segmenter's coarser one. Where someone
nearer to a camera covers part of a person, those pixels are ``hidden``:
unknown to the fit, not background. They are estimated as the nearer people's
pixels within :data:`BODY_REACH` of the person's skeleton in that camera (their
own landmarks and their skeleton triangulated from the other cameras and
projected, which places the limbs the nearer person hides); the nearer
person's other pixels stay background for them, so a fit cannot grow into
them for free. A view where more than :data:`OCCLUDED_SHARE` of their pixels
is hidden is ``occluded`` (too little of them to fit there; left out), and so is
a view whose camera did not detect them where someone nearer covers more than
:data:`MISSED_SHARE` of their skeleton (their pixels there are only what their
projected skeleton claims).
A camera that did not detect someone the others agree on may still show them,
in part behind another person or in full (whose pixels another detection's
mask then holds): their skeleton, triangulated from the other cameras and
projected, claims those pixels, and the same occlusion test applies; where
nobody nearer covers them and those pixels leave most of their skeleton on
background, the masks there follow someone else and the view is ``mixed``
(:data:`BACKGROUND_BONES`). A camera whose segmenter found nobody at all is
asked again where the other cameras put each person (:func:`people_boxes`).

Identities across kept frames are given over all of them by
:func:`bodymetry.capture.persons.track_ids`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np

from bodymetry.calibration.camera import CameraGroup
from bodymetry.capture.consistency import VisualHull
from bodymetry.capture.headcount import MATCH_ERROR, group_people
from bodymetry.capture.landmarks import LandmarkConfig, triangulate_landmarks
from bodymetry.capture.person import LANDMARKS, Person
from bodymetry.capture.persons import PersonObservation

__all__ = [
    "BONES",
    "MIXED_SHARE",
    "Sighting",
    "astray",
    "body_region",
    "partition",
    "people_boxes",
    "sighting_of",
    "sightings",
    "skeleton_mask",
    "within_hulls",
]

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
#: The limbs' three joints: where the middle one is not seen, :func:`skeleton_mask`
#: draws the limb straight from end to end (the arm lies about there; two cameras
#: that triangulate a skeleton lose a joint only one of them sees well).
LIMBS = tuple(
    tuple(LANDMARKS.index(f"{side}_{joint}") for joint in joints)
    for side in ("left", "right")
    for joints in (("shoulder", "elbow", "wrist"), ("hip", "knee", "ankle"))
)
#: Landmarks less visible than this are not drawn.
BONE_VISIBILITY = 0.3
#: The torso's corners, in order round it: left and right shoulder, right and left hip.
TORSO = tuple(
    LANDMARKS.index(n) for n in ("left_shoulder", "right_shoulder", "right_hip", "left_hip")
)
#: A person's pixels lie within this fraction of their skeleton's height of a bone (the
#: torso is about a fifth of a person's height wide, the bones run down its middle).
REACH = 0.2
#: A person of the hull's split is ``occluded`` in a camera where a nearer person covers
#: more than this share of the silhouette pixels of their projection (the hull is
#: fatter than the body, so its ``hidden`` pixels are 4-7 times the truly hidden ones).
HIDDEN_SHARE = 0.1
#: A pixel within this fraction of a person's skeleton height of their bones lies on
#: their body (limbs are about a tenth of a person's height thick).
CORE = 0.05
#: A person is ``occluded`` in a camera (the view is left out of their fit) when
#: more than this share of their pixels there (theirs and ``hidden``) is hidden:
#: too little of them left to fit. Below it the hidden pixels are unknown to the
#: fit and the view is fitted. On the clipless two-person studio session and on
#: Demo_MultiPerson, a detected person's view is hidden up to 34 % (docs/capture.md).
OCCLUDED_SHARE = 0.5
#: A person is ``occluded`` in a camera whose segmenter did not detect them when
#: someone nearer covers more than this share of their skeleton there (drawn
#: :data:`BONE_WIDTH` of the image height wide): their pixels there are only
#: what their projected skeleton claims from another's detection.
MISSED_SHARE = 0.02
BONE_WIDTH = 0.01
#: A nearer person's pixel within this fraction of a person's skeleton height of
#: their bones may hide part of them (``hidden``). Measured against the studio's
#: truth of hidden pixels (docs/capture.md, two-person session seed 7): reach 0.04
#: finds 59 % of them at 57 % precision, 0.05 67 % at 53 %, 0.06 72 % at 48 %,
#: 0.08 80 % at 38 %; wrongly unknown pixels are ones a fit may grow into for free.
BODY_REACH = 0.05
#: With everyone's fused silhouette known (an empty-scene clip), a person's pixels are
#: its pixels within this fraction of their skeleton height of their pixels from the
#: detections' masks (:func:`partition`): the segmenter's masks, upsampled from 256 px
#: crops about a person high, are a pixel or two of the crop off along the outline.
SNAP = 0.01
#: What the detectors missed of the background's silhouette near a person is
#: unknown to them where it is wider than this share of their height: thinner
#: slivers along their outline are the gap between a detection's mask and the
#: background's silhouette, not body the fit may grow into for free.
MISSED_WIDTH = 0.02


#: A camera's detection of a person is ``mixed`` (the view is left out of their fit)
#: when more than this share of its drawn landmarks lie further than
#: :data:`~bodymetry.capture.headcount.MATCH_ERROR` of the image height from where the
#: other cameras put them (:func:`astray`): the detector built one skeleton from
#: two people, and the mask follows it. Demo_MultiPerson: 0 to 0.15 for detections
#: of one person; 0.21 to 0.67 where a detection mixed the two (0.48 and 0.58 in
#: cam03 at frames 80 and 60, where the man's mask left out his shorts and held
#: the woman's face). A detection below the bound keeps its view and only its
#: stray landmarks are mended (:func:`_mended`); a bound of 0.2 left the man's
#: frame 60 with one camera.
MIXED_SHARE = 0.35
#: A camera that did not detect a person whom nobody nearer covers must show them:
#: where more than this share of their projected skeleton's bones (drawn
#: :data:`BONE_WIDTH` of the image height wide) lies on pixels their fit would
#: read as background (neither theirs nor unknown to them), the view is ``mixed``
#: (the masks there follow someone else). Measured on the views of that kind,
#: 2026-12-06: 0.59 on Demo_MultiPerson's (frame 90, cam03, fit IoU 0.28 there);
#: 0.03-0.47 on the six two-person studio sessions' 21.
BACKGROUND_BONES = 0.5


@dataclass(frozen=True)
class Sighting:
    """One person found in one kept frame.

    Attributes
    ----------
    position : (3,) float
        World point, metres: the middle of their triangulated body landmarks.
    masks : tuple of ((H_c, W_c) bool or None), length C
        Per camera, the pixels that are theirs; None where the camera shows
        nothing of them.
    landmarks : tuple of ((33, 3) float or None), length C
        Per camera, their detection's landmarks (:attr:`Person.landmarks`);
        None where the camera did not detect them.
    occluded : tuple of bool, length C
        Per camera, whether someone nearer to it hides most of them (the view
        is left out of their fit).
    height : float
        Their top above the floor, metres, where known (the hull's split);
        NaN from the segmenter's detections (a lunge lowers the head, so the
        tracking does not compare it).
    hidden : tuple of ((H_c, W_c) bool or None)
        Per camera, the pixels of theirs a nearer person covers (unknown, not
        background); None where nobody nearer covers them. The segmenter's
        detections give the nearer people's pixels near their skeleton
        (:func:`body_region`), the hull's split its own estimate. Also unknown:
        the pixels near their skeleton that their detector could not see (the
        people found before, painted over:
        :attr:`~bodymetry.capture.person.Person.unseen`) and nobody's mask holds,
        and, with an empty-scene clip, the parts of the background's silhouette
        near them wider than :data:`MISSED_WIDTH` that nobody's mask holds.
    source : {"segmenter", "hull"}
        How they were told apart: the segmenter's detections matched across
        cameras (:func:`sightings`), or the split of the multi-view hull
        (:func:`sighting_of`).
    mixed : tuple of bool
        Per camera, whether its detection of them is partly someone else's
        (:data:`MIXED_SHARE`; the view is left out of their fit); empty: none.
    contrast : float or None
        How plainly they stand out from the empty scene along the part of their
        outline that borders it
        (:func:`~bodymetry.capture.fusion.outline_contrast`, as for one subject);
        None without an empty-scene clip.
    """

    position: np.ndarray
    masks: tuple[np.ndarray | None, ...]
    landmarks: tuple[np.ndarray | None, ...]
    occluded: tuple[bool, ...]
    height: float = float("nan")
    hidden: tuple[np.ndarray | None, ...] = ()
    source: str = "segmenter"
    mixed: tuple[bool, ...] = ()
    contrast: float | None = None

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
    expected: int = 0,
    foreground: Sequence[np.ndarray | None] | None = None,
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
    expected : int, optional
        How many people another source (the multi-view hull of background
        subtraction) counts in the frame. Where fewer than that are seen by
        ``min_views`` cameras, people two cameras agree on (on detections no
        one else holds) make up the count.
    foreground : sequence of ((H_c, W_c) bool or None), optional
        Per camera, everyone's silhouette where the session has an empty-scene
        clip (background subtraction fused with every detection and the hull:
        :meth:`~bodymetry.capture.segmentation.FrameSegmenter.everyone`). The
        people's pixels are then its pixels, each to the person whose skeleton
        is nearest (:func:`partition`), not the detections' coarser masks; its
        pixels near a person's skeleton that no skeleton claims, in parts wider
        than :data:`MISSED_WIDTH` of their height, are unknown to that person
        (``hidden``).

    Returns
    -------
    list of Sighting
        In :func:`~bodymetry.capture.headcount.group_people`'s order.
    """
    landmarks = [[p.landmarks for p in found] for found in detections]
    groups = group_people(cameras, landmarks, floor_box, min_views)
    if len(groups) < expected and min_views > 2:
        # Two people one behind the other in a camera are one detection there (the
        # segmenter's mask holds both, its skeleton the nearer one's): in two such
        # cameras the one behind is found by two cameras only (two-person studio
        # session seed 31, frame 150: the man behind the woman in cam_01 and in
        # front of her in cam_03), and the hull's split, which cannot tell apart
        # people whose silhouettes merge, would measure them instead. The
        # background's hull says they are there; two cameras agreeing on a skeleton
        # say where.
        held = {(c, k) for g in groups for c, k in enumerate(g.detections) if k is not None}
        pairs = [
            g
            for g in group_people(cameras, landmarks, floor_box, 2)
            if g.views < min_views
            and not any((c, k) in held for c, k in enumerate(g.detections) if k is not None)
        ]
        groups += pairs[: expected - len(groups)]
    # Each person's skeleton as the cameras agree on it (a view whose labels are
    # swapped relabelled, a landmark that disagrees with the other views dropped).
    skeletons = [
        _triangulated(
            cameras,
            [None if j is None else detections[v][j].landmarks for v, j in enumerate(g.detections)],
        )
        for g in groups
    ]
    # Each skeleton as each camera sees it (None: mostly behind it or outside its image).
    projections = [[_projected(camera, skeleton) for camera in cameras] for skeleton in skeletons]
    # A detection's own landmarks may lie partly on someone else (in a crowd the
    # detector builds one skeleton from two people: Demo_MultiPerson, cam03, frames
    # 40-80, the man's head drawn on the woman's face behind him): where one lies
    # further than MATCH_ERROR of the image height from where the other cameras put
    # it, the partition draws the other cameras' landmark instead. Where many do,
    # the mask followed the wrong skeleton too: the view is ``mixed``.
    found = [list(view) for view in detections]
    mixed = [[False] * len(cameras) for _ in groups]
    for g, projected, flags in zip(groups, projections, mixed, strict=True):
        for c, k in enumerate(g.detections):
            if k is not None:
                person = found[c][k]
                flags[c] = astray(person.landmarks, projected[c], cameras[c]) > MIXED_SHARE
                mended = _mended(person.landmarks, projected[c], cameras[c])
                found[c][k] = replace(person, landmarks=mended)
    # A person a camera did not find may still be there, hidden behind someone whose
    # mask then holds their visible bits: their skeleton, triangulated from the
    # cameras that found them, claims those pixels in the partition below.
    index = [list(g.detections) for g in groups]
    for ids, projected in zip(index, projections, strict=True):
        for c, k in enumerate(ids):
            if k is not None:
                continue
            if projected[c] is not None:
                shape = (cameras[c].size[1], cameras[c].size[0])
                found[c].append(Person(np.zeros(shape, np.float32), projected[c]))
                ids[c] = len(found[c]) - 1
    depths = [[np.inf] * len(view) for view in found]
    for g, ids in zip(groups, index, strict=True):
        for c, k in enumerate(ids):
            if k is not None:
                depths[c][k] = _distance(cameras[c], g.position)
    masks = [
        partition(view, threshold, d, None if foreground is None else foreground[c])
        for c, (view, d) in enumerate(zip(found, depths, strict=True))
    ]
    claimed = [np.logical_or.reduce(view) if view else None for view in masks]
    regions: dict[tuple[int, int], np.ndarray | None] = {}

    def region(p: int, c: int) -> np.ndarray | None:
        # Person p's body region in camera c (p has a detection there), once.
        if (p, c) not in regions:
            person = found[c][index[p][c]]
            regions[p, c] = body_region(
                [person.landmarks, projections[p][c]], person.probability.shape
            )
        return regions[p, c]

    unsure = _merged(groups, index, region, foreground is not None)
    out = []
    for p, (g, ids, flags) in enumerate(zip(groups, index, mixed, strict=True)):
        occluded, mine_masks, hidden_masks = [], [], []
        for c, k in enumerate(ids):
            hidden, mask, covered = False, None, None
            if k is not None:
                mask = masks[c][k]
                if unsure[p][c] is not None:
                    # Where one detection held them and someone else, their bodies'
                    # regions overlap: unknown to both (added to ``covered`` below).
                    mask = mask & ~unsure[p][c]
                nearer = np.zeros_like(mask)
                for other, others in zip(groups, index, strict=True):
                    j = others[c]
                    if other is not g and j is not None and depths[c][j] < depths[c][k]:
                        nearer |= masks[c][j]
                # What their detector could not see: the people found before,
                # painted over (Person.unseen), and what everyone's silhouette
                # holds near them that nobody's pixels are.
                unseen = found[c][k].unseen
                everyone = None if foreground is None else foreground[c]
                if unseen is not None and everyone is not None:
                    unseen = unseen & everyone  # the background's change saw it all
                lm = found[c][k].landmarks
                body = bones = None
                if nearer.any() or unseen is not None or everyone is not None:
                    body = region(p, c)
                if g.detections[c] is None:
                    # A camera that did not detect them: their projected skeleton's bones.
                    bones = skeleton_mask(lm, mask.shape, round(BONE_WIDTH * mask.shape[0]))
                if nearer.any():
                    covered = None if body is None else nearer & body & ~mask
                    if g.detections[c] is None:
                        # A camera that did not detect them has only the pixels their
                        # projected skeleton claims from someone else's detection: where
                        # that someone covers part of their skeleton, too unsure to fit
                        # (on Demo_MultiPerson the woman's such masks in cam03 fitted at
                        # IoU 0.1-0.5).
                        hidden = bones is not None and (
                            np.count_nonzero(bones & nearer)
                            > MISSED_SHARE * np.count_nonzero(bones)
                        )
                    else:
                        n_hidden = 0 if covered is None else np.count_nonzero(covered)
                        hidden = n_hidden > OCCLUDED_SHARE * (n_hidden + np.count_nonzero(mask))
                if body is not None and (unseen is not None or everyone is not None):
                    # Where nobody's pixels are, their detector could not see them or
                    # missed them, not saw background (Demo_MultiPerson, frame 30,
                    # cam03: bits of the woman's hands and foot in the man's mask,
                    # grown, punched holes into hers; frames 40-80, cam01: the
                    # margin around the woman's raised hand hid the man's hanging
                    # arm; two-person studio session seed 31, frame 125, cam_01: the
                    # one detection of both people left out the woman's forearm,
                    # which the background's change holds). Unknown, like the pixels
                    # a nearer person hides, but not counted as hidden.
                    lost = np.zeros_like(mask)
                    if unseen is not None:
                        lost |= unseen & body & ~claimed[c] & ~mask
                    if everyone is not None:
                        width = MISSED_WIDTH * _tall(body)
                        lost |= _solid(everyone & body & ~claimed[c] & ~mask, width)
                    if lost.any():
                        covered = lost if covered is None else covered | lost
                if unsure[p][c] is not None:
                    zone = unsure[p][c] & claimed[c]
                    covered = zone if covered is None else covered | zone
                if bones is not None and not hidden and mask.any():
                    # Nobody nearer covers them, so the camera shows them, and their
                    # projected skeleton lies on their pixels, or on pixels unknown to
                    # them. Where most of it lies on pixels their fit would read as
                    # background, the masks there followed someone else
                    # (Demo_MultiPerson, frame 90, cam03: the man in front,
                    # undetected; the woman's detection behind him held his leg and
                    # not his trunk, 59 % of his bones on background; the fit's IoU
                    # there was 0.28).
                    read = mask if covered is None else mask | covered
                    on_background = np.count_nonzero(bones & ~read)
                    flags[c] = on_background > BACKGROUND_BONES * np.count_nonzero(bones)
                if g.detections[c] is None and not mask.any():
                    mask = None  # nothing of them is left in that camera
            occluded.append(hidden and mask is not None)
            mine_masks.append(mask)
            hidden_masks.append(
                covered if mask is not None and covered is not None and covered.any() else None
            )
        out.append(
            Sighting(
                position=g.position,
                masks=tuple(mine_masks),
                landmarks=tuple(
                    None if k is None else detections[c][k].landmarks
                    for c, k in enumerate(g.detections)
                ),
                occluded=tuple(occluded),
                hidden=tuple(hidden_masks),
                mixed=tuple(f and m is not None for f, m in zip(flags, mine_masks, strict=True)),
            )
        )
    return out


def _merged(
    groups: Sequence,
    index: Sequence[Sequence[int | None]],
    region: Callable[[int, int], np.ndarray | None],
    clip: bool,
) -> list[list[np.ndarray | None]]:
    """Per person and camera (:func:`sightings`' order), the pixels where their
    body's region (``region(person, camera)``: :func:`body_region` of their drawn
    and projected skeleton) and that of someone the camera's detector did not
    find overlap, or None; all None without an empty-scene clip (``clip``).

    A person the detector missed in a camera is there only as pixels of someone
    else's detection, given to the nearest skeleton (:func:`partition`); where
    the two bodies overlap, the skeletons cannot tell whose a pixel is (two-person
    studio session seed 42, frame 75, cam_03: the woman behind took the arm of
    the person in front, who took her trunk; that person's frames read +3 to
    +7 kg). Only with everyone's silhouette (an empty-scene clip): the other
    cameras then measure the person without those pixels.
    """
    out: list[list[np.ndarray | None]] = [[None] * len(index[0]) for _ in index] if index else []
    if not clip:
        return out
    for c in range(len(out[0]) if out else 0):
        missed = [p for p, (g, ids) in enumerate(zip(groups, index, strict=True))
                  if g.detections[c] is None and ids[c] is not None]  # fmt: skip
        if not missed:
            continue
        regions = [None if ids[c] is None else region(p, c) for p, ids in enumerate(index)]
        for m in missed:
            for p, theirs in enumerate(regions):
                if p == m or theirs is None or regions[m] is None:
                    continue
                zone = theirs & regions[m]
                if zone.any():
                    for q in (p, m):
                        out[q][c] = zone if out[q][c] is None else out[q][c] | zone
    return out


def people_boxes(
    cameras: CameraGroup,
    landmarks: Sequence[Sequence[np.ndarray]],
    camera: int,
    floor_box: tuple | None = None,
) -> list[tuple[int, int, int, int]]:
    """Where the people that two other cameras agree on stand in camera ``camera``'s image.

    Parameters
    ----------
    cameras : CameraGroup
        C cameras, at the resolution of the landmarks' pixels.
    landmarks : sequence of C sequences of (33, 3) float
        Per camera, the landmarks of each person its segmenter found (camera
        ``camera``'s own are not used).
    camera : int
        The camera to look in.
    floor_box : ((2,) float, (2,) float), optional
        The capture volume's floor (x, y) box (people outside it are not placed).

    Returns
    -------
    list of (x0, y0, x1, y1) int
        Per person (most cameras first, :func:`~bodymetry.capture.headcount.group_people`),
        the pixel box of their triangulated skeleton as ``camera`` sees it; none
        for a person mostly behind it or outside its image.
    """
    others = [[] if c == camera else list(view) for c, view in enumerate(landmarks)]
    w, h = cameras[camera].size
    boxes = []
    for group in group_people(cameras, others, floor_box, min_views=2):
        views = [None if k is None else others[c][k] for c, k in enumerate(group.detections)]
        projected = _projected(cameras[camera], _triangulated(cameras, views))
        if projected is None:
            continue
        xy = projected[np.isfinite(projected[:, 0]), :2]
        (x0, y0), (x1, y1) = np.floor(xy.min(axis=0)), np.ceil(xy.max(axis=0))
        boxes.append((max(int(x0), 0), max(int(y0), 0), min(int(x1), w), min(int(y1), h)))
    return boxes


def _tall(mask: np.ndarray) -> int:
    """Rows from the top to the bottom of a non-empty (H, W) bool ``mask``."""
    rows = np.flatnonzero(mask.any(axis=1))
    return int(rows[-1] - rows[0] + 1)


def _solid(mask: np.ndarray, width: float) -> np.ndarray:
    """(H, W) bool: the parts of ``mask`` wider than ``width`` pixels (an opening)."""
    r = max(1, round(0.5 * width))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    return cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, kernel) > 0


def body_region(
    skeletons: Sequence[np.ndarray | None], shape: tuple[int, int], reach: float = BODY_REACH
) -> np.ndarray | None:
    """(H, W) bool: the pixels within ``reach`` of the skeleton height of the
    :data:`BONES` of any of ``skeletons`` (each (33, 3) landmarks or None), where a
    person's body may be; None when no bone can be drawn."""
    bones = [skeleton_mask(lm, shape) for lm in skeletons if lm is not None]
    bones = [b for b in bones if b is not None]
    if not bones:
        return None
    drawn = np.logical_or.reduce(bones)
    distance = cv2.distanceTransform((~drawn).astype(np.uint8), cv2.DIST_L2, 3)
    return distance <= reach * _tall(drawn)


def _triangulated(cameras: CameraGroup, views: Sequence[np.ndarray | None]) -> np.ndarray:
    """(33, 3) world landmarks from the cameras' (33, 3) detections (None: not seen);
    NaN where fewer than two consistent cameras saw a landmark well enough
    (:func:`~bodymetry.capture.landmarks.triangulate_landmarks`: views whose left
    and right are swapped relabelled, a view that disagrees dropped)."""
    return triangulate_landmarks(cameras, views, _SKELETON)


#: The triangulation of a person's skeleton: every landmark drawn is used.
_SKELETON = LandmarkConfig(min_visibility=BONE_VISIBILITY, refine_calibration=False)


def _mended(landmarks: np.ndarray, projected: np.ndarray | None, camera) -> np.ndarray:
    """(33, 3) ``landmarks`` of one camera with each drawn landmark that lies
    further than :data:`~bodymetry.capture.headcount.MATCH_ERROR` of the image
    height from ``projected`` (the other cameras' skeleton as this one sees it,
    (33, 3) or None) moved there, and each one it does not draw (unseen, or
    less visible than :data:`BONE_VISIBILITY`) drawn there: a limb the camera's
    detector barely sees, e.g. behind someone, still claims its own pixels
    (Demo_MultiPerson, frame 50, cam04: the woman's legs, visibility 0.04-0.22,
    went to the man's nearest bones)."""
    lm = np.array(landmarks, float)
    if projected is None:
        return lm
    drawn, known, elsewhere = _placed(lm, projected, camera)
    moved = elsewhere | (known & ~drawn)
    lm[moved, :2] = projected[moved, :2]
    lm[moved & ~drawn, 2] = BONE_VISIBILITY
    # A middle joint the other cameras cannot place, on a limb whose end this
    # camera put elsewhere than they do, is no surer than that end: not drawn (the
    # limb is then drawn from end to end). Two-person studio session seed 8, frame
    # 125, cam_02: one detection of both people put the woman's right elbow and
    # wrist on the arm of the man behind her; the wrist was moved back, the elbow
    # stayed, and her forearm bone cut across his shirt, which the partition gave
    # her.
    for a, middle, b in LIMBS:
        if drawn[middle] and not known[middle] and (elsewhere[a] or elsewhere[b]):
            lm[middle, 2] = 0.0
    return lm


def astray(landmarks: np.ndarray, projected: np.ndarray | None, camera) -> float:
    """The share of a camera's detection's drawn ``landmarks`` (33, 3) (visibility
    at least :data:`BONE_VISIBILITY`) that lie further than
    :data:`~bodymetry.capture.headcount.MATCH_ERROR` of the image height from
    ``projected`` (the other cameras' skeleton as this camera sees it, (33, 3) or
    None); 0 where nothing can be compared."""
    if projected is None:
        return 0.0
    drawn, known, elsewhere = _placed(np.asarray(landmarks, float), projected, camera)
    both = drawn & known
    return float(np.mean(elsewhere[both])) if both.any() else 0.0


def _placed(
    landmarks: np.ndarray, projected: np.ndarray, camera
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Three (33,) bool of one camera's ``landmarks`` (33, 3) against ``projected``
    (33, 3), the other cameras' skeleton as it sees it: which it draws (finite,
    visibility at least :data:`BONE_VISIBILITY`), which the others place, and
    which lie further than :data:`~bodymetry.capture.headcount.MATCH_ERROR` of the
    image height from where the others put them."""
    drawn = np.isfinite(landmarks).all(axis=1) & (np.nan_to_num(landmarks[:, 2]) >= BONE_VISIBILITY)
    known = np.isfinite(projected[:, :2]).all(axis=1)
    with np.errstate(invalid="ignore"):
        off = np.linalg.norm(landmarks[:, :2] - projected[:, :2], axis=1)
    return drawn, known, known & (off > MATCH_ERROR * camera.size[1])


def _projected(camera, points: np.ndarray) -> np.ndarray | None:
    """(33, 3) landmarks (x, y, visibility 1) of world ``points`` (33, 3) as ``camera``
    sees them; None when most of them fall behind it or outside its image."""
    known = np.isfinite(points).all(axis=1)
    if known.sum() < len(BONES) // 2:
        return None
    out = np.full((len(points), 3), np.nan)
    depth = camera.to_camera(points[known])[:, 2]
    pixels = camera.project(points[known])
    w, h = camera.size
    inside = (depth > 0) & (pixels[:, 0] >= 0) & (pixels[:, 0] < w) & (pixels[:, 1] >= 0)
    inside &= pixels[:, 1] < h
    if inside.mean() < 0.5:
        return None
    rows = np.flatnonzero(known)[inside]
    out[rows, :2] = pixels[inside]
    out[rows, 2] = 1.0
    return out


def sighting_of(observed: PersonObservation, share: float = HIDDEN_SHARE) -> Sighting:
    """A person of the hull's split (:func:`bodymetry.capture.persons.observe_persons`)
    as a :class:`Sighting`: their explained pixels per camera (None where the
    camera does not see them), ``occluded`` where a nearer person covers more
    than ``share`` of their projection's silhouette pixels, no landmarks."""
    masks, occluded, hidden = [], [], []
    for view in observed.views:
        if view.box is None:
            masks.append(None)
            occluded.append(False)
            hidden.append(None)
            continue
        mine, covered = np.count_nonzero(view.explained), np.count_nonzero(view.hidden)
        masks.append(view.mask if mine else None)
        occluded.append(bool(mine) and covered > share * (mine + covered))
        hidden.append(view.occluded if covered else None)
    x, y = np.asarray(observed.position, float)[:2]
    return Sighting(
        position=np.array([x, y, observed.height / 2.0]),
        masks=tuple(masks),
        landmarks=(None,) * len(masks),
        occluded=tuple(occluded),
        height=float(observed.height),
        hidden=tuple(hidden),
        source="hull",
    )


def within_hulls(
    people: Sequence[Sighting],
    hull: VisualHull,
    silhouettes: Sequence[np.ndarray | None] | None = None,
) -> list[Sighting]:
    """``people`` with each camera's pixels that lie on someone else's hull and off
    their own made unknown to them (``hidden``).

    One detection can hold two people, one behind the other, and the partition
    gives the nearer one what their skeleton's :data:`CORE` covers, the edges of
    the one behind included (two-person studio session seed 31, frames 0-50,
    cam_01: the shoulders and legs of the man behind the woman; those frames read
    +9 to +13 kg). The other cameras may see them apart: each person's hull,
    carved from their pixels in the other cameras (:meth:`VisualHull.carved`),
    says where they can be in this one. Their pixels count only from cameras
    that detected them and whose detection is not ``mixed`` (a skeleton placed
    from elsewhere claims an unsure part of them); in the others everyone's
    silhouette, which holds them whether seen or hidden, bounds them (two
    cameras alone carve a hull several times a person's size in a third:
    seed 42, frame 125, cam_03, 90,000 pixels for 15,000). A pixel off their own
    hull's projection and on someone else's may be that someone's: neither body
    nor background for them. Their pixels in the other cameras leave out what
    someone hides there, so their hull may lack a part that is theirs: unknown,
    not background, is what that can afford. Off every hull is not enough: a
    hand seen edge-on is thinner than a voxel, and the hull, which samples voxel
    centres, can miss it.

    Parameters
    ----------
    people : sequence of Sighting
        One frame's people.
    hull : VisualHull
        The rig's capture volume, at the resolution of the masks.
    silhouettes : sequence of ((H_c, W_c) bool or None), optional
        Per camera everyone's silhouette (None: the camera abstains).

    Returns
    -------
    list of Sighting
    """
    n = len(hull.cameras)
    everyone = list(silhouettes) if silhouettes is not None else [None] * n
    # Per person and camera, where their hull carved by the other cameras projects.
    support: list[list[np.ndarray | None]] = []
    for person in people:
        views = [
            m if m is not None and person.landmarks[c] is not None
            and not (person.mixed and person.mixed[c]) else everyone[c]
            for c, m in enumerate(person.masks)
        ]  # fmt: skip
        mine: list[np.ndarray | None] = []
        for c in range(n):
            others = [None if k == c else m for k, m in enumerate(views)]
            body = hull.carved(others) if sum(m is not None for m in others) >= 2 else None
            mine.append(hull.support(body, c) if body is not None and body.any() else None)
        support.append(mine)
    out = []
    for k, person in enumerate(people):
        masks, hidden = list(person.masks), list(person.hidden or (None,) * n)
        changed = False
        for c, mask in enumerate(person.masks):
            theirs = [s[c] for j, s in enumerate(support) if j != k and s[c] is not None]
            if mask is None or support[k][c] is None or not theirs:
                continue
            unsure = mask & np.logical_or.reduce(theirs) & ~support[k][c]
            if unsure.any():
                changed = True
                masks[c] = mask & ~unsure
                hidden[c] = unsure if hidden[c] is None else hidden[c] | unsure
        if changed:
            person = replace(person, masks=tuple(masks), hidden=tuple(hidden))
        out.append(person)
    return out


def skeleton_mask(
    landmarks: np.ndarray, shape: tuple[int, int], width: int = 3, torso: bool = False
) -> np.ndarray | None:
    """(H, W) bool: the :data:`BONES` of ``landmarks`` (33, 3) drawn ``width`` pixels
    wide (bones with a landmark less visible than :data:`BONE_VISIBILITY` left
    out; a limb whose middle joint is left out drawn from end to end,
    :data:`LIMBS`), with ``torso`` the quadrilateral of the shoulders and hips filled (where
    all four are seen); None when no bone can be drawn."""
    canvas = np.zeros(shape, np.uint8)
    lm = np.asarray(landmarks, float)
    seen = np.isfinite(lm).all(axis=1) & (np.nan_to_num(lm[:, 2]) >= BONE_VISIBILITY)
    if torso and seen[list(TORSO)].all():
        cv2.fillPoly(canvas, [np.round(lm[list(TORSO), :2]).astype(np.int32)], 1)
    bones = [(a, b) for a, b in BONES if seen[a] and seen[b]]
    shortcuts = [(a, b) for a, middle, b in LIMBS if seen[a] and seen[b] and not seen[middle]]
    for a, b in bones + shortcuts:
        pa, pb = (tuple(round(v) for v in lm[i, :2]) for i in (a, b))
        cv2.line(canvas, pa, pb, 1, max(int(width), 1))
    return canvas > 0 if bones else None


def partition(
    found: Sequence[Person],
    threshold: float,
    depths: Sequence[float] | None = None,
    silhouette: np.ndarray | None = None,
) -> list[np.ndarray]:
    """Each detected person's pixels in one image: the union of the detections'
    masks, each pixel to the person whose skeleton (:data:`BONES`) is nearest,
    except where it lies on the body of someone nearer to the camera; with
    ``silhouette``, those pixels snapped to it.

    Parameters
    ----------
    found : sequence of Person
        The image's detections (a person the camera's detector missed, placed
        there by the other cameras, has an all-zero probability).
    threshold : float
        The segmenter's probability threshold.
    depths : sequence of float, optional
        Each detection's distance from the camera (metres; inf: unknown). A
        pixel within :data:`CORE` of the skeleton height of a nearer person's
        bone is theirs: where two people overlap in the image, the nearer one
        is the one seen.
    silhouette : (H, W) bool, optional
        Everyone's pixels, where another source knows them better than the
        detections' masks (everyone's fused, edge-refined silhouette, with an
        empty-scene clip). Each person's pixels are then their pixels from the
        masks inside the silhouette, and the silhouette's outline band within
        :data:`SNAP` of their skeleton height of them (the masks' outline,
        upsampled from the segmenter's 256 px, is a pixel or two off; snapping
        into the silhouette's inside would take the edge of someone beside
        them). The rest of it goes to the people the detector missed, by their
        nearest skeleton (their pixels are the ones no detection's mask holds);
        what is left is nobody's.

    Returns
    -------
    list of (H, W) bool
        One per detection, disjoint; pixels further than :data:`REACH` from
        every skeleton are nobody's; a detection without a drawable skeleton
        claims its own mask.
    """
    masks = [p.mask(threshold) for p in found]
    if len(found) < 2 and silhouette is None:
        return masks
    union = np.logical_or.reduce(masks)
    h, w = union.shape
    distance = np.empty((len(found), h, w), np.float32)
    core = np.zeros((len(found), h, w), bool)
    tall = np.zeros(len(found))
    for k, person in enumerate(found):
        # The torso filled: a wide trunk's sides lie further from its bones than
        # CORE, and in front of someone its middle was given to their spine
        # (two-person studio session, seed 8, cam_02: a wedge of the man's shirt
        # given to the woman behind him).
        bones = skeleton_mask(person.landmarks, (h, w), torso=True)
        if bones is not None:
            distance[k] = cv2.distanceTransform((~bones).astype(np.uint8), cv2.DIST_L2, 3)
            tall[k] = _tall(bones)
            core[k] = distance[k] <= CORE * tall[k]
            # Pixels far from every bone are nobody's (a bystander the segmenter
            # marked in the crop but did not detect).
            distance[k][distance[k] > REACH * tall[k]] = np.inf
        else:
            # No skeleton to measure from: the person claims their own mask only.
            distance[k] = np.where(masks[k], 0.0, np.inf)
            tall[k] = _tall(masks[k]) if masks[k].any() else 0.0
    owner = np.argmin(distance, axis=0)
    if depths is not None:
        # Front to back: the nearest person whose body covers a pixel owns it.
        order = np.argsort(np.asarray(depths, float), kind="stable")
        taken = np.zeros((h, w), bool)
        for k in order:
            if np.isfinite(depths[k]):
                mine = core[k] & ~taken
                owner[mine] = k
                taken |= mine
    claimed = np.isfinite(distance.min(axis=0))
    out = [union & claimed & (owner == k) for k in range(len(found))]
    if silhouette is None:
        return out
    return _snapped(out, np.asarray(silhouette, bool), distance, tall, [m.any() for m in masks])


def _snapped(
    owned: Sequence[np.ndarray],
    silhouette: np.ndarray,
    distance: np.ndarray,
    tall: np.ndarray,
    detected: Sequence[bool],
) -> list[np.ndarray]:
    """:func:`partition`'s pixels ``owned`` (K of (H, W) bool) snapped to
    ``silhouette`` (H, W) bool: their pixels inside it, and each pixel of its
    outline band (:data:`SNAP` of a person's skeleton height ``tall`` (K,) wide)
    within that of their pixels, to the nearest such person; the rest to the
    nearest skeleton (``distance`` (K, H, W), inf beyond reach) of the people
    whose detector missed them (``detected`` False)."""
    h, w = silhouette.shape
    # How far inside the silhouette each pixel lies: a mask's outline is snapped
    # out to the silhouette's own outline only, not into someone beside the person
    # (their mask's edge there runs through the silhouette's inside).
    inside = cv2.distanceTransform(silhouette.astype(np.uint8), cv2.DIST_L2, 3)
    near = np.full((len(owned), h, w), np.inf, np.float32)
    for k, mine in enumerate(owned):
        if mine.any():
            snap = max(SNAP * tall[k], 1.0)
            near[k] = cv2.distanceTransform((~mine).astype(np.uint8), cv2.DIST_L2, 3)
            near[k][(near[k] > snap) | ((near[k] > 0) & (inside > snap))] = np.inf
    held = np.isfinite(near.min(axis=0))
    closest = np.argmin(near, axis=0)
    out = [silhouette & held & (closest == k) for k in range(len(owned))]
    missed = [k for k, seen in enumerate(detected) if not seen]
    if missed:
        rest = silhouette & ~held
        reach = distance[missed]
        who = np.asarray(missed)[np.argmin(reach, axis=0)]
        rest &= np.isfinite(reach.min(axis=0))
        for k in missed:
            out[k] |= rest & (who == k)
    return out


def _distance(camera, point: np.ndarray) -> float:
    """Distance (metres) from ``camera``'s centre to ``point`` (inf when unknown)."""
    d = float(np.linalg.norm(np.asarray(point, float) - camera.center))
    return d if np.isfinite(d) else np.inf
