"""Persons in the capture volume: split one frame's hull into people, and track them.

The multi-view check (:mod:`bodymetry.capture.consistency`) counts the people of
a frame from the tops of its visual hull; this module says which voxels and
which pixels are whose (docs/capture.md, "Persons and occlusion"):

1. **Split** (:func:`split_hull`): every person-sized body of the hull is seeded
   at the people's tops (:func:`~bodymetry.capture.consistency.person_tops`, the
   heads :func:`~bodymetry.capture.consistency.count_persons` counts), each seed
   being the occupied column under a top within
   :data:`~bodymetry.capture.consistency.PERSON_REACH`; a person-sized body with
   no top (a raised hand its only top) is seeded under its highest voxel. Each
   voxel goes to the seed nearest *within the hull* (geodesic distance over
   26-connected voxels, Dijkstra), so two people whose hulls touch at a shoulder
   or a hand split at the contact, not along a straight line. A part that is too
   short or too small to be a person (:data:`PERSON_MIN_HEIGHT`,
   :data:`PERSON_MIN_VOLUME`) is nobody.
2. **Views** (:func:`person_views`): per camera, each person's voxels are
   splatted into a depth buffer (camera depth, nearest voxel per pixel). The
   person *explains* the silhouette's pixels inside their projection where no
   other person's projection is nearer; the pixels of their projection that a
   nearer person covers are *occluded*: unknown for that person, neither body
   nor background.
3. **Tracking** (:class:`PersonTracker`, :func:`track_persons`): observations
   of consecutive kept frames are associated by floor position (the last one,
   or moved on by the last step, whichever is nearer) and height, by the
   Hungarian assignment with gates (:data:`TRACK_GATE` metres on the floor,
   :data:`TRACK_HEIGHT_GATE` metres in height). A track not seen in a frame is
   kept: a person who leaves and comes back where they left, with the same
   height, keeps the identity; anyone else gets a new one.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from scipy import ndimage, sparse
from scipy.optimize import linear_sum_assignment
from scipy.sparse.csgraph import dijkstra

from bodymetry.calibration.camera import CameraGroup
from bodymetry.capture.consistency import (
    PERSON_MIN_HEIGHT,
    PERSON_MIN_VOLUME,
    PERSON_REACH,
    PERSON_SPACING,
    HullBodies,
    VisualHull,
    person_tops,
)
from bodymetry.capture.person import LANDMARKS
from bodymetry.errors import InputError

log = logging.getLogger(__name__)

__all__ = [
    "PERSON_AXIS_RADIUS",
    "PERSON_OWN_SHARE",
    "TRACK_GATE",
    "TRACK_HEIGHT_GATE",
    "PersonObservation",
    "PersonTrack",
    "PersonTracker",
    "PersonView",
    "everyone_silhouettes",
    "observe_persons",
    "person_views",
    "raised_hands",
    "side_by_side",
    "split_hull",
    "track_ids",
    "track_persons",
]

#: Metres on the floor: a person is the same as a track when their floor position lies
#: within this of the track's last position or of its predicted one (the last moved
#: by its last step): people walk 0.6 m between kept frames at 1.4 m/s and
#: frame_step 25 at 60 fps, and a hull position jumps by a few decimetres in a frame
#: where the hull's phantoms join a person; two people pass no closer than their
#: bodies allow, and the assignment gives each track the nearer one.
TRACK_GATE = 0.8
#: Metres: ... and their hull height within this of the track's last height (a hand
#: raised over the head adds up to about 0.2 m; children and adults differ more).
TRACK_HEIGHT_GATE = 0.25
#: Metres: a person's floor position is the centroid of their voxels within this of
#: their axis (the column under their top): the trunk and legs of an adult.
PERSON_AXIS_RADIUS = 0.3
#: A person explains at least this share of their projection's silhouette pixels that
#: no taller person explains (else the body is a phantom of the visual hull).
PERSON_OWN_SHARE = 0.25
#: Metres on the floor: a hull top lies at a raised hand when one of the hand's
#: triangulated landmarks (wrist, index, pinky, thumb) lies within this of it (the
#: top is a plateau's centre, a few 4 cm voxels wide; an adult's hand is 0.19 m long).
HAND_REACH = 0.15
#: Metres: ... and the top stands at most this far above that landmark (the fingers
#: above the wrist, the hull a voxel or two above the body) ...
HAND_ABOVE = 0.35
#: ... and at most this far below it.
HAND_BELOW = 0.1
#: The landmarks of the hands (:data:`~bodymetry.capture.person.LANDMARKS`).
_HANDS = [
    LANDMARKS.index(f"{side}_{part}")
    for side in ("left", "right")
    for part in ("wrist", "index", "pinky", "thumb")
]
#: Which of :data:`_HANDS` are the left hand's.
_LEFT = np.array([LANDMARKS[i].startswith("left_") for i in _HANDS])
#: The face landmarks (nose, eyes, ears, mouth): a raised hand is above them all.
_FACE = list(range(LANDMARKS.index("mouth_right") + 1))
#: The assignment's cost of a pair outside the gates (never chosen over a real pair).
_FORBIDDEN = 1e6
#: :func:`side_by_side`: a blob stands as tall as a person where its height is at least
#: this share of the hull's projection's, and two such blobs stand side by side where
#: their columns overlap by at most :data:`SIDE_OVERLAP` of the narrower one's width.
STANDING_SHARE = 0.7
SIDE_OVERLAP = 0.25
#: Depth buffer value of a pixel no voxel covers (finite: cv2.erode pads with the
#: largest float32, so an infinite "nothing" would read as covered near the border).
_NOTHING = np.float32(1e9)


@dataclass(frozen=True)
class PersonView:
    """One person in one camera, as a crop around their projection.

    Attributes
    ----------
    size : (int, int)
        The image's ``(width, height)``.
    box : (x0, y0, x1, y1) or None
        The crop: the box of the person's projection (None: the camera does
        not see the person; both crops are then (0, 0)).
    explained : (y1 - y0, x1 - x0) bool
        The silhouette's pixels this person explains: inside their projection
        and not covered by a nearer person.
    hidden : (y1 - y0, x1 - x0) bool
        The silhouette's pixels of their projection that a nearer person covers
        (unknown for this person: neither body nor background).
    """

    size: tuple[int, int]
    box: tuple[int, int, int, int] | None
    explained: np.ndarray = field(repr=False)
    hidden: np.ndarray = field(repr=False)

    def _full(self, crop: np.ndarray) -> np.ndarray:
        out = np.zeros((self.size[1], self.size[0]), bool)
        if self.box is not None:
            x0, y0, x1, y1 = self.box
            out[y0:y1, x0:x1] = crop
        return out

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: :attr:`explained` in the whole image."""
        return self._full(self.explained)

    @property
    def occluded(self) -> np.ndarray:
        """(H, W) bool: :attr:`hidden` in the whole image."""
        return self._full(self.hidden)


@dataclass(frozen=True)
class PersonObservation:
    """One person of one frame (:func:`observe_persons`).

    Attributes
    ----------
    position : (2,) float
        Floor-plane centroid (x, y) of the person's voxels, metres (world frame).
    height : float
        Top of the person's highest voxel above the floor, metres (the hull is a
        little taller than the body: about a voxel).
    voxels : int
        The person's voxels.
    views : tuple of PersonView, length C
        Per camera, the pixels the person explains and those occluded.
    id : int or None
        Track identity (:class:`PersonTracker`); None before tracking.
    """

    position: np.ndarray
    height: float
    voxels: int
    views: tuple[PersonView, ...] = field(default=(), repr=False)
    id: int | None = None


@dataclass(frozen=True)
class PersonTrack:
    """One person across the kept frames (:func:`track_persons`).

    Attributes
    ----------
    id : int
        Identity, 0, 1, ... in order of first appearance.
    frames : tuple of int
        Indices (into the frames given to :func:`track_persons`) where the person
        is observed, increasing.
    observations : tuple of PersonObservation
        The person's observation in each of those frames (``id`` set).
    """

    id: int
    frames: tuple[int, ...]
    observations: tuple[PersonObservation, ...] = field(repr=False)


def _neighbour_graph(occupied: np.ndarray, cell: float) -> sparse.csr_matrix:
    """The 26-connected voxels of ``occupied`` (X, Y, Z) bool as a graph: node i is the
    i-th occupied voxel in C order, edge weights the centre distances in metres."""
    node = np.full(occupied.shape, -1, np.int64)
    node[occupied] = np.arange(int(occupied.sum()))
    rows, cols, weights = [], [], []
    # Half of the 26 offsets (the lexicographically positive ones): each edge once.
    offsets = [np.array(d) - 1 for d in np.ndindex(3, 3, 3)]
    for d in (d for d in offsets if tuple(d) > (0, 0, 0)):
        src = tuple(
            slice(max(-k, 0), n - max(k, 0)) for k, n in zip(d, occupied.shape, strict=True)
        )
        dst = tuple(slice(max(k, 0), n + min(k, 0)) for k, n in zip(d, occupied.shape, strict=True))
        a, b = node[src], node[dst]
        ok = (a >= 0) & (b >= 0)
        rows.append(a[ok])
        cols.append(b[ok])
        weights.append(np.full(int(ok.sum()), cell * float(np.linalg.norm(d))))
    n = int(occupied.sum())
    return sparse.csr_matrix(
        (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
    )


def side_by_side(person: np.ndarray, support: np.ndarray) -> bool:
    """Whether a view shows two people standing side by side where the hull holds one
    body: two blobs of ``person`` (H, W) bool (background subtraction's person pixels
    within the hull's projection), each as tall as :data:`STANDING_SHARE` of the
    projection ``support`` (H, W) bool, whose columns overlap by at most
    :data:`SIDE_OVERLAP` of the narrower one's width.

    Two people half a metre apart whose reaching arms touch merge into one hull body
    with one top (the dip between their heads is under the split's prominence), and
    the segmenter's mask can hold both of them; a view that sees the gap between
    them still shows two whole, upright blobs. One person's blobs are not both that
    tall beside each other: a lost trunk leaves legs under half the projection's
    height, and a detached arm is short or stands above the body, not beside it.
    """
    rows = np.flatnonzero(support.any(axis=1))
    if rows.size == 0:
        return False
    tall = STANDING_SHARE * (rows[-1] - rows[0] + 1)
    n, _, stats, _ = cv2.connectedComponentsWithStats(person.astype(np.uint8), connectivity=8)
    spans = [
        (x, x + w) for x, _, w, h, _ in stats[1:n] if h >= tall
    ]  # columns [x0, x1) of the blobs as tall as a person
    for i, (a0, a1) in enumerate(spans):
        for b0, b1 in spans[i + 1 :]:
            overlap = max(0, min(a1, b1) - max(a0, b0))
            if overlap <= SIDE_OVERLAP * min(a1 - a0, b1 - b0):
                return True
    return False


def raised_hands(tops: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """Which of a hull's tops are one person's raised hands.

    The hull counts people by their tops (:func:`~bodymetry.capture.consistency.person_tops`).
    Hands held straight up stand above the head, 0.4-0.5 m apart, on arms that
    stand on the shoulders: two tops as prominent and as solid as two heads, and
    the hull's cross-section below them is no narrower than a neck (head, arms
    and shoulders merge at 4 cm voxels). The segmenter's skeleton tells them
    apart: its triangulated hands lie at those tops.

    Only hands held above the person's own head count (above the highest of
    their triangulated face landmarks, :data:`_FACE`): a hand resting on a
    second, shorter person's head (a parent steadying a child) lies at that
    head's top too, but below the hand's owner's face. With both hands up, the
    hull (three views of four agreeing) can put its tops between the cameras'
    cones rather than over the two thin columns of the arms; a top within half
    the hands' spacing plus :data:`HAND_REACH` of their midpoint, at their
    height, is theirs as well, within
    :data:`~bodymetry.capture.consistency.PERSON_SPACING` at most (two heads
    stand no closer).

    Parameters
    ----------
    tops : (K, 3) float
        The tops as world points, metres (:attr:`HullBodies.tops`).
    landmarks : (33, 3) float
        One person's triangulated landmarks, metres, NaN where not triangulated
        (:func:`~bodymetry.capture.landmarks.triangulate_landmarks`).

    Returns
    -------
    (K,) bool
        True where a raised hand landmark lies within :data:`HAND_REACH` on the
        floor, and from :data:`HAND_BELOW` above to :data:`HAND_ABOVE` below the
        top, or, with both hands raised, where their midpoint does within half
        their spacing plus :data:`HAND_REACH`. All False where no face landmark
        was triangulated.
    """
    tops = np.asarray(tops, float).reshape(-1, 3)
    landmarks = np.asarray(landmarks, float)
    face = landmarks[_FACE, 2]
    hands = landmarks[_HANDS]
    raised = np.isfinite(hands).all(axis=1) & np.isfinite(face).any()
    if raised.any():
        raised &= hands[:, 2] > np.nanmax(face)
    if not raised.any() or len(tops) == 0:
        return np.zeros(len(tops), bool)

    def at(points: np.ndarray, reach: float) -> np.ndarray:
        floor = np.linalg.norm(tops[:, None, :2] - points[None, :, :2], axis=2)
        rise = tops[:, None, 2] - points[None, :, 2]
        return ((floor <= reach) & (rise <= HAND_ABOVE) & (rise >= -HAND_BELOW)).any(axis=1)

    out = at(hands[raised], HAND_REACH)
    left, right = raised & _LEFT, raised & ~_LEFT
    if left.any() and right.any():
        # Both hands up: the hull of two thin columns, three views of four
        # agreeing, can put its tops between the cameras' cones instead of over
        # the hands; a top within half the hands' spacing (plus the reach) of
        # their midpoint, at their height, is theirs too.
        pair = np.stack([hands[left].mean(axis=0), hands[right].mean(axis=0)])
        half = 0.5 * np.linalg.norm(pair[0, :2] - pair[1, :2])
        out |= at(pair.mean(axis=0, keepdims=True), min(half + HAND_REACH, PERSON_SPACING))
    return out


def split_hull(occupied: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Split the person-sized bodies of a voxel grid into persons (module docstring, 1).

    Parameters
    ----------
    occupied : (X, Y, Z) bool
        The voxels of person-sized hull bodies; level k spans heights
        ``[k cell, (k + 1) cell)`` above the floor.
    cell : float
        Voxel side, metres.

    Returns
    -------
    labels : (X, Y, Z) int
        Per voxel its person, 1..K (0: not occupied, or a part too short or too
        small to be a person). Persons are numbered by their top, highest
        first, then the bodies seeded under their highest voxel.
    axes : (K, 2) float
        Each person's axis: the floor position of their seed (top or highest
        voxel), in grid cells (fractional (x, y) indices).
    """
    occupied = np.asarray(occupied, bool)
    if occupied.ndim != 3:
        raise InputError(f"split_hull: expected an (X, Y, Z) grid, got shape {occupied.shape}")
    out = np.zeros(occupied.shape, np.int32)
    if not occupied.any():
        return out, np.zeros((0, 2))
    cells = np.argwhere(occupied)  # (M, 3), C order: node i of the graph
    centres, heights = person_tops(occupied, cell)
    reach2 = max(round(PERSON_REACH / cell), 1) ** 2
    owner = np.full(len(cells), -1)
    for k, ((cx, cy), h) in enumerate(zip(centres, heights, strict=True)):
        # The column under the top (the person's axis), up to the top's level.
        column = ((cells[:, 0] - cx) ** 2 + (cells[:, 1] - cy) ** 2 <= reach2) & (
            cells[:, 2] < round(h / cell)
        )
        owner[column & (owner < 0)] = k
    # A body that holds no seed (no top stands out on it) is a person of its own.
    bodies, n_bodies = ndimage.label(occupied, structure=np.ones((3, 3, 3)))
    body = bodies[occupied]
    seeded = np.zeros(n_bodies + 1, bool)
    seeded[body[owner >= 0]] = True
    k = len(centres)
    axes = [np.asarray(c, float) for c in centres]
    for b in range(1, n_bodies + 1):
        if seeded[b]:
            continue
        members = np.flatnonzero(body == b)
        x, y, _ = cells[members[np.argmax(cells[members, 2])]]
        near = (cells[members, 0] - x) ** 2 + (cells[members, 1] - y) ** 2 <= reach2
        owner[members[near]] = k
        axes.append(np.array([x, y], float))
        k += 1
    seeds = np.flatnonzero(owner >= 0)
    graph = _neighbour_graph(occupied, cell)
    _, _, source = dijkstra(
        graph, directed=False, indices=seeds, min_only=True, return_predecessors=True
    )
    person = np.where(source >= 0, owner[np.maximum(source, 0)], -1)
    # Only the parts that could be a person are persons (phantom tops over a small
    # hull bump grow a sliver).
    labels = np.zeros(len(cells), np.int32)
    kept: list[np.ndarray] = []
    for p in range(k):
        mine = person == p
        if not mine.any():
            continue
        z = cells[mine, 2]
        tall = (z.max() - z.min() + 1) * cell >= PERSON_MIN_HEIGHT
        if tall and mine.sum() * cell**3 >= PERSON_MIN_VOLUME:
            kept.append(axes[p])
            labels[mine] = len(kept)
    out[occupied] = labels
    return out, np.array(kept, float).reshape(-1, 2)


def person_views(
    cameras: CameraGroup,
    people: Sequence[np.ndarray],
    masks: Sequence[np.ndarray],
    splat: Sequence[int],
) -> list[tuple[PersonView, ...]]:
    """Per person and camera, the silhouette pixels they explain and those occluded.

    Parameters
    ----------
    cameras : CameraGroup
        The rig, C cameras.
    people : sequence of (M_k, 3) float
        Each person's voxel centres, world frame, metres.
    masks : sequence of (H_c, W_c) bool, length C
        The views' silhouettes (every person's pixels).
    splat : sequence of int, length C
        Half the projected voxel side per camera, pixels
        (:attr:`~bodymetry.capture.consistency.VisualHull.splat`).

    Returns
    -------
    list of tuple of PersonView
        ``out[k][c]``: person k in camera c.
    """
    if len(masks) != len(cameras) or len(splat) != len(cameras):
        raise InputError(
            f"person_views: {len(cameras)} cameras, {len(masks)} masks, {len(splat)} splat sizes"
        )
    out: list[list[PersonView]] = [[] for _ in people]
    for cam, mask, r in zip(cameras, masks, splat, strict=True):
        w, h = cam.size
        mask = np.asarray(mask, bool)
        if mask.shape != (h, w):
            raise InputError(f"camera {cam.name!r}: mask is {mask.shape[::-1]}, camera {w}x{h}")
        kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * int(r) + 1, 2 * int(r) + 1))
        depths = []
        for points in people:
            depth = np.full((h, w), _NOTHING, np.float32)
            if len(points):
                z = cam.to_camera(points)[:, 2]
                px = np.floor(cam.project(points)).astype(np.int64)
                ok = (z > 0) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
                np.minimum.at(depth, (px[ok, 1], px[ok, 0]), z[ok].astype(np.float32))
                # The voxel's footprint: nearest depth over the splat (a min filter).
                depth = cv2.erode(depth, kernel)
            depths.append(depth)
        stack = np.stack(depths) if depths else np.zeros((0, h, w), np.float32)
        for k, depth in enumerate(depths):
            covers = depth < _NOTHING
            if not covers.any():
                empty = np.zeros((0, 0), bool)
                out[k].append(PersonView((w, h), None, empty, empty))
                continue
            ys, xs = np.nonzero(covers)
            x0, y0, x1, y1 = int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1
            crop = stack[:, y0:y1, x0:x1]
            others = np.delete(crop, k, axis=0)
            nearer = (
                (others < crop[k]).any(axis=0)
                if len(others)
                else np.zeros_like(covers[y0:y1, x0:x1])
            )
            inside = covers[y0:y1, x0:x1] & mask[y0:y1, x0:x1]
            out[k].append(PersonView((w, h), (x0, y0, x1, y1), inside & ~nearer, inside & nearer))
    return [tuple(v) for v in out]


def everyone_silhouettes(
    hull: VisualHull,
    bodies: HullBodies,
    masks: Sequence[np.ndarray],
    candidates: Sequence[np.ndarray | None],
) -> list[np.ndarray]:
    """Every person's pixels per view: the subject's silhouette, and a label that sees
    everyone where the hull's person-sized bodies project.

    The capture's silhouettes hold one person (the segmenter finds one per image and
    the multi-view check keeps the largest body); background subtraction sees
    everyone, and the hull of the frame's candidates (every pixel some source calls
    person) says where people are.

    Parameters
    ----------
    hull : VisualHull
    bodies : HullBodies
        The hull's bodies of the frame's candidates.
    masks : sequence of (H_c, W_c) bool
        The subject's silhouettes.
    candidates : sequence of ((H_c, W_c) bool or None)
        Per view a person label that sees everyone (the capture passes background
        subtraction's label with the segmenter's person; None: no background or
        unreadable, the view keeps the subject's silhouette).

    Returns
    -------
    list of (H_c, W_c) bool
    """
    people = (bodies.labels > 0) & bodies.person_sized[bodies.labels]
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    out = []
    for c, (mask, candidate) in enumerate(zip(masks, candidates, strict=True)):
        mask = np.asarray(mask, bool)
        if candidate is None or not people.any():
            out.append(mask)
            continue
        # An opening drops the sensor noise's single pixels.
        candidate = cv2.morphologyEx(np.asarray(candidate, np.uint8), cv2.MORPH_OPEN, kernel) > 0
        out.append(mask | (candidate & hull.support(people, c)))
    return out


def observe_persons(
    hull: VisualHull, masks: Sequence[np.ndarray], bodies: HullBodies | None = None
) -> tuple[PersonObservation, ...]:
    """The persons of one frame: the hull of ``masks`` split into people, with their views.

    Parameters
    ----------
    hull : VisualHull
        The rig's capture volume.
    masks : sequence of (H_c, W_c) bool, camera order
        Every person's silhouettes per view (:func:`everyone_silhouettes`).
    bodies : HullBodies, optional
        The hull's bodies to split (default ``hull.bodies(masks)``; the capture
        passes those of the candidates, which counted the persons).

    Returns
    -------
    tuple of PersonObservation
        In :func:`split_hull`'s order, ``id`` None (see :class:`PersonTracker`).
    """
    bodies = bodies if bodies is not None else hull.bodies(masks)
    people = (bodies.labels > 0) & bodies.person_sized[bodies.labels]
    if not people.any():
        return ()
    grid, axes = split_hull(hull.grid(people), hull.voxel)
    labels = grid[tuple(hull.cells.T)]
    points = [hull.points[labels == p] for p in range(1, len(axes) + 1)]
    real = _explaining(person_views(hull.cameras, points, masks, hull.splat))
    if len(real) < len(points):
        log.debug("%d of %d hull persons are phantoms", len(points) - len(real), len(points))
    points, axes = [points[k] for k in real], axes[real]
    views = person_views(hull.cameras, points, masks, hull.splat)
    out = []
    for pts, axis, v in zip(points, hull.origin[:2] + axes * hull.voxel, views, strict=True):
        # The floor centroid of the body around the axis: the hull's phantoms (where
        # one person's cones cross another's) and an outstretched arm lie farther out.
        near = np.linalg.norm(pts[:, :2] - axis, axis=1) <= PERSON_AXIS_RADIUS
        out.append(
            PersonObservation(
                position=pts[near, :2].mean(axis=0) if near.any() else axis,
                height=float(pts[:, 2].max() + hull.voxel / 2),
                voxels=len(pts),
                views=v,
            )
        )
    return tuple(out)


def _explaining(views: Sequence[Sequence[PersonView]]) -> list[int]:
    """The persons (indices, increasing) that explain the silhouettes, phantoms left out.

    With two people and cameras around them the visual hull has phantoms: bodies
    where one person's cone from some cameras crosses the other's from the others,
    person-sized and as tall as the shorter person. A phantom's projection lies in
    the real persons' silhouettes, half in one's and half in the other's. So,
    greedily (a set cover), the person who explains the most silhouette pixels not
    yet explained is kept, while one explains at least :data:`PERSON_OWN_SHARE` of
    their projection's silhouette pixels anew.
    """
    mine = [[v.mask | v.occluded for v in person] for person in views]
    own = [sum(int(np.count_nonzero(m)) for m in person) for person in mine]
    if not mine:
        return []
    covered = [np.zeros_like(m) for m in mine[0]]
    kept: list[int] = []
    while True:
        best, gain = -1, 0
        for k, person in enumerate(mine):
            if k in kept or not own[k]:
                continue
            new = sum(int(np.count_nonzero(m & ~c)) for m, c in zip(person, covered, strict=True))
            if new >= PERSON_OWN_SHARE * own[k] and new > gain:
                best, gain = k, new
        if best < 0:
            return sorted(kept)
        kept.append(best)
        covered = [c | m for c, m in zip(covered, mine[best], strict=True)]


class PersonTracker:
    """Gives the persons of successive kept frames their identities (module docstring, 3).

    Parameters
    ----------
    gate : float
        :data:`TRACK_GATE`, metres.
    height_gate : float
        :data:`TRACK_HEIGHT_GATE`, metres.
    """

    def __init__(self, gate: float = TRACK_GATE, height_gate: float = TRACK_HEIGHT_GATE) -> None:
        if gate <= 0 or height_gate <= 0:
            raise InputError(f"tracking gates must be > 0, got {gate} m and {height_gate} m")
        self.gate = gate
        self.height_gate = height_gate
        self._position: list[np.ndarray] = []  # per track id: last floor position
        self._height: list[float] = []
        self._step: list[np.ndarray] = []  # last move between consecutive updates
        self._last: list[int] = []  # the update that last saw the track
        self._updates = 0

    def update(self, observations: Sequence[PersonObservation]) -> tuple[PersonObservation, ...]:
        """The next kept frame's observations, each with its ``id`` set (same order)."""
        t = self._updates
        self._updates += 1
        n = len(self._position)
        ids = [-1] * len(observations)
        if n and observations:
            cost = np.full((n, len(observations)), _FORBIDDEN)
            for i in range(n):
                # A track seen in the previous update moves on by its last step (or
                # stops: a wrong step, from a frame with a phantom, must not lose it);
                # one lost longer is looked for where it was last.
                last = self._position[i]
                step = self._step[i] if self._last[i] == t - 1 else np.zeros(2)
                for j, obs in enumerate(observations):
                    d = float(
                        min(
                            np.linalg.norm(np.asarray(obs.position) - last - step),
                            np.linalg.norm(np.asarray(obs.position) - last),
                        )
                    )
                    # An unknown height (NaN: from the segmenter's skeletons, where a
                    # lunge lowers the head) is not compared.
                    dh = abs(obs.height - self._height[i])
                    dh = 0.0 if not np.isfinite(dh) else dh
                    if np.isfinite(d) and d <= self.gate and dh <= self.height_gate:
                        cost[i, j] = d + dh
            for i, j in zip(*linear_sum_assignment(cost), strict=True):
                if cost[i, j] < _FORBIDDEN:
                    ids[j] = int(i)
        out = []
        for j, obs in enumerate(observations):
            position = np.asarray(obs.position, float)
            i = ids[j]
            if i < 0:
                i = len(self._position)
                self._position.append(position)
                self._height.append(obs.height)
                self._step.append(np.zeros(2))
                self._last.append(t)
            else:
                consecutive = self._last[i] == t - 1
                self._step[i] = position - self._position[i] if consecutive else np.zeros(2)
                self._position[i] = position
                self._height[i] = obs.height
                self._last[i] = t
            out.append(replace(obs, id=i))
        return tuple(out)


def track_ids(
    frames: Sequence[Sequence[object]],
    gate: float = TRACK_GATE,
    height_gate: float = TRACK_HEIGHT_GATE,
) -> list[list[int]]:
    """Per kept frame (in time order), the identity of each of its people.

    Parameters
    ----------
    frames : sequence of (sequence of people)
        Anything with a ``position`` (world, metres; its first two coordinates
        are the floor position) and a ``height`` (metres, NaN: unknown), e.g.
        :class:`bodymetry.capture.people.Sighting`.
    gate, height_gate : float
        Metres (:data:`TRACK_GATE`, :data:`TRACK_HEIGHT_GATE`).

    Returns
    -------
    list of list of int
        Same shape as ``frames``; identities from 0 in order of first appearance.
    """
    tracker = PersonTracker(gate, height_gate)
    return [
        [
            int(o.id)
            for o in tracker.update(
                [
                    PersonObservation(np.asarray(p.position, float)[:2], float(p.height), 0)
                    for p in people
                ]
            )
        ]
        for people in frames
    ]


def track_persons(
    frames: Sequence[Sequence[PersonObservation]],
    gate: float = TRACK_GATE,
    height_gate: float = TRACK_HEIGHT_GATE,
) -> tuple[PersonTrack, ...]:
    """Tracks of the persons of successive kept frames (:class:`PersonTracker`).

    Parameters
    ----------
    frames : sequence of (sequence of PersonObservation)
        Per kept frame, in time order, its persons (an empty frame: nobody).
    gate, height_gate : float
        Metres (:data:`TRACK_GATE`, :data:`TRACK_HEIGHT_GATE`).

    Returns
    -------
    tuple of PersonTrack
        By id. Deterministic: the same input gives the same tracks.
    """
    tracker = PersonTracker(gate, height_gate)
    members: dict[int, list[tuple[int, PersonObservation]]] = {}
    for f, observations in enumerate(frames):
        for obs in tracker.update(observations):
            members.setdefault(int(obs.id), []).append((f, obs))
    return tuple(
        PersonTrack(i, tuple(f for f, _ in m), tuple(o for _, o in m))
        for i, m in sorted(members.items())
    )
