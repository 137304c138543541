"""Multi-view consistency: keep what the calibrated cameras agree is the subject.

A per-camera silhouette can hold things that are not the subject: a bystander,
a moved chair, floor mats, or (for a learned segmenter, which returns the most
prominent person of its image) the wrong person altogether. The subject is the
one thing every camera sees at one place in the room. So:

1. the **capture volume** is the part of the room, floor to ``height``, that at
   least ``min_views`` cameras see; it is cut into voxels once per rig and each
   voxel's pixel in every camera is precomputed (:class:`VisualHull`);
2. per frame, a voxel is **occupied** when it falls inside the silhouette in
   every camera that sees it, allowing ``misses`` cameras to disagree (a view
   whose segmenter picked a bystander, a limb lost in one view): the visual
   hull of the views' agreement;
3. in each camera, the silhouette's connected regions that the hull's
   projection does not touch are removed (bystanders, objects seen by one or
   two cameras only), and a view that lost most of its silhouette that way is
   ``inconsistent``: :func:`bodymetry.capture.segmentation.segment_session` then
   asks its segmenter again in the box where the hull projects (:attr:`HullCheck.rois`).

A region that all cameras see at one place is kept: the check rejects what is
inconsistent, not a second person standing in the capture volume in full view.
People in the capture volume are counted (:meth:`VisualHull.bodies`,
:attr:`HullBodies.persons`, :func:`count_persons`): the tops of the hull's
person-sized bodies, seen from above, that stand out as separate heads.
bodymetry measures one subject, the largest body, and a frame with a second
person in full view says so (docs/capture.md, "Several people in the capture
volume").
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from scipy import ndimage

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.errors import InputError

log = logging.getLogger(__name__)

__all__ = [
    "PERSON_MIN_HEIGHT",
    "PERSON_MIN_TOP",
    "PERSON_MIN_VOLUME",
    "PERSON_PROMINENCE",
    "PERSON_REACH",
    "PERSON_SOLIDITY",
    "PERSON_SPACING",
    "TOP_DEPTH",
    "HullBodies",
    "HullCheck",
    "HullConfig",
    "VisualHull",
    "count_persons",
    "person_tops",
    "visual_hull",
]

#: A hull body counts as a person when it is at least this tall (metres): a child of
#: five stands about 1.1 m, a crouching adult about 0.9 m; the hull's ghosts over cast
#: shadows and floor marks are a few voxels high.
PERSON_MIN_HEIGHT = 0.8
#: ... and at least this large (cubic metres; the hull is larger than the body, a child
#: of 20 kg has a volume of 0.02 m^3).
PERSON_MIN_VOLUME = 0.02
#: A person's top (the head, seen from above) is at least this high (metres): a child
#: of five stands 1.1 m; the hull's low bumps next to a person (a ghost over the cast
#: shadow, a bag) are not people. A crouching second person is not counted.
PERSON_MIN_TOP = 1.0
#: ... and stands at least this much (metres)
#: above the lowest pass to any higher top: two people side by side, even when their
#: hulls touch, have the gap between them; a head between raised arms, or a hand held
#: out at shoulder height, does not stand out that much.
PERSON_PROMINENCE = 0.25
#: ... and lies at least this far (metres, on the floor) from a higher one: raised
#: hands stay within it of their own head.
PERSON_SPACING = 0.45
#: ... and stands on a body: over at least this share of the height below it, the
#: hull is occupied within :data:`PERSON_REACH` of the top's floor position (a hand
#: raised in a wide V has nothing under it from the shoulder down).
PERSON_SOLIDITY = 0.7
#: Metres: the legs of a standing person lie within this of the head's floor position.
PERSON_REACH = 0.12
#: How far below a hull top (metres) its voxels are looked at for one held by
#: every camera that sees it (:attr:`HullBodies.held`): three 4 cm voxels, a
#: head's crown.
TOP_DEPTH = 0.12


@dataclass(frozen=True)
class HullConfig:
    """Parameters of the multi-view consistency check.

    Attributes
    ----------
    min_views : int
        A point belongs to the capture volume when at least this many cameras see it.
    misses : int
        Cameras that may disagree about an occupied voxel.
    height : float
        Top of the capture volume above the floor, metres.
    max_voxels : int
        The voxel size is chosen so that the capture volume has about this many.
    keep_fraction : float
        A view whose silhouette keeps less than this fraction of its pixels is
        ``inconsistent``.
    """

    min_views: int = 3
    misses: int = 1
    height: float = 2.4
    max_voxels: int = 250_000
    keep_fraction: float = 0.5

    def __post_init__(self) -> None:
        if self.min_views < 2:
            raise InputError(f"hull.min_views: expected >= 2, got {self.min_views}")
        if not 0 <= self.misses < self.min_views - 1:
            raise InputError(
                f"hull.misses: expected 0 <= misses < min_views - 1, got {self.misses} "
                f"(min_views {self.min_views})"
            )
        if self.height <= 0 or self.max_voxels < 1000:
            raise InputError("hull.height must be > 0 and hull.max_voxels >= 1000")
        if not 0 < self.keep_fraction <= 1:
            raise InputError(f"hull.keep_fraction: expected (0, 1], got {self.keep_fraction}")


@dataclass(frozen=True)
class HullCheck:
    """The outcome of :meth:`VisualHull.check` for one frame.

    Attributes
    ----------
    masks : tuple of (H_c, W_c) bool
        The silhouettes with the regions the hull does not support removed.
    inconsistent : tuple of bool
        Per camera: the view lost most of its silhouette (or had none where the
        other views agree there is a person).
    rois : tuple of ((x0, y0, x1, y1) or None)
        Per camera: the box in which the hull projects (None: no hull).
    voxels : int
        Occupied voxels.
    """

    masks: tuple[np.ndarray, ...]
    inconsistent: tuple[bool, ...]
    rois: tuple[tuple[int, int, int, int] | None, ...]
    voxels: int


@dataclass(frozen=True)
class HullBodies:
    """The connected bodies of one frame's hull (:meth:`VisualHull.bodies`).

    Attributes
    ----------
    labels : (N,) int
        Per capture-volume voxel its body (0: not occupied; 1..K).
    voxels : (K + 1,) int
        Voxels per body (index 0 unused, 0).
    heights : (K + 1,) float
        Vertical extent of each body, metres (voxel centres plus one voxel).
    voxel : float
        Voxel side, metres.
    persons : int
        People among the bodies (:func:`count_persons` of the person-sized ones:
        at least :data:`PERSON_MIN_HEIGHT` tall and :data:`PERSON_MIN_VOLUME`
        large; a stool, a bag or a cast shadow's ghost is none).
    tops : (T, 3) float
        The tops :func:`count_persons` counted (:func:`person_tops`) as world
        points, metres (floor position and the top of the highest voxel), highest
        first; (0, 3) when there is no person-sized body.
    held : (T,) bool
        Per top, whether the cameras that see it hold it: some voxel of its crown
        (within :data:`TOP_DEPTH` below the top and :data:`PERSON_REACH` of its
        floor position) lies inside the silhouette of every camera that sees it.
        A head lies in every view's silhouette (studio heads: 2 to 16 such
        voxels, the fewest where two people's hulls merge and the top sits off
        the head); a top that the ``misses`` allowed let through where a few
        views' cones cross (a sliver between two opposite views, which the
        others' silhouettes leave out) has none.
    confirmed : (K + 1,) bool
        Per body, whether some voxel of it lies inside the silhouette of every
        camera that sees it (a person's does; a ghost where a few views' cones
        cross, which the ``misses`` allowed let through, has none); empty where not
        computed (read as confirmed).
    """

    labels: np.ndarray
    voxels: np.ndarray
    heights: np.ndarray
    voxel: float
    persons: int = 0
    tops: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False)
    held: np.ndarray = field(default_factory=lambda: np.zeros(0, bool), repr=False)
    confirmed: np.ndarray = field(default_factory=lambda: np.zeros(0, bool), repr=False)

    @property
    def largest_body(self) -> int:
        """The label of the largest body (0 when none)."""
        return int(np.argmax(self.voxels)) if len(self.voxels) > 1 else 0

    @property
    def largest(self) -> np.ndarray:
        """(N,) bool: the voxels of the largest body (all False when none)."""
        if len(self.voxels) <= 1:
            return np.zeros(len(self.labels), bool)
        return self.labels == self.largest_body

    @property
    def person_sized(self) -> np.ndarray:
        """(K + 1,) bool: the bodies tall and large enough to be a person."""
        sized = (self.heights >= PERSON_MIN_HEIGHT) & (
            self.voxels * self.voxel**3 >= PERSON_MIN_VOLUME
        )
        sized[:1] = False
        return sized


def count_persons(occupied: np.ndarray, cell: float) -> int:
    """People standing in a voxel grid (floor cells by height levels).

    Each separate top counts: a local maximum of the top heights (seen from
    above) at least :data:`PERSON_MIN_TOP` high, whose dynamic (its height
    above the highest pass to a higher top) is at least
    :data:`PERSON_PROMINENCE`, which stands on a body (:data:`PERSON_SOLIDITY`)
    and lies :data:`PERSON_SPACING` or more from every higher counted top. Two
    people whose hulls merge still have two heads; the visual hull's phantoms
    (where one person's cone in some views crosses the other's in others) can
    add a top of their own, so a count above one is "more than one", not exact.

    Parameters
    ----------
    occupied : (X, Y, Z) bool
        The voxels of person-sized bodies; level k spans heights
        ``[k cell, (k + 1) cell)`` above the floor.
    cell : float
        Voxel side, metres.
    """
    return len(person_tops(occupied, cell)[1])


def person_tops(occupied: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """The people's tops (heads) of a voxel grid, as :func:`count_persons` counts them.

    Parameters
    ----------
    occupied : (X, Y, Z) bool
        As for :func:`count_persons`.
    cell : float
        Voxel side, metres.

    Returns
    -------
    centres : (K, 2) float
        Each top's floor position in grid cells (fractional (x, y) indices),
        highest top first.
    heights : (K,) float
        Each top's height above the floor, metres (the top of its highest voxel).
    """
    occupied = np.asarray(occupied, bool)
    none = np.zeros((0, 2)), np.zeros(0)
    levels = (np.arange(occupied.shape[2], dtype=np.float32) + 1) * np.float32(cell)
    top = np.where(occupied, levels, np.float32(0)).max(axis=2)
    if not (top >= PERSON_MIN_TOP).any():
        return none
    # Morphological reconstruction by dilation of (top - h) under top: a top whose
    # dynamic is at least h keeps a gap of h there (the h-maxima transform).
    h = np.float32(PERSON_PROMINENCE)
    rec = np.maximum(top - h, 0)
    kernel = np.ones((3, 3), np.uint8)
    while True:
        grown = np.minimum(cv2.dilate(rec, kernel), top)
        if np.array_equal(grown, rec):
            break
        rec = grown
    peaks = (top - rec >= h - 1e-4) & (top >= PERSON_MIN_TOP)
    labels, n = ndimage.label(peaks, structure=np.ones((3, 3)))
    if n == 0:
        return none
    index = np.arange(1, n + 1)
    centres = np.array(ndimage.center_of_mass(peaks, labels, index))
    heights = np.asarray(ndimage.maximum(top, labels, index))
    # What stands under each top: any voxel within reach, per height level.
    reach = max(round(PERSON_REACH / cell), 1)
    near = ndimage.maximum_filter(occupied, size=(2 * reach + 1, 2 * reach + 1, 1))
    kept: list[int] = []
    for i in np.argsort(-heights, kind="stable"):
        x, y = np.clip(np.round(centres[i]).astype(int), 0, np.array(top.shape) - 1)
        below = levels <= heights[i]
        if near[x, y, below].mean() < PERSON_SOLIDITY:
            continue
        if all(np.linalg.norm(centres[i] - centres[j]) * cell >= PERSON_SPACING for j in kept):
            kept.append(int(i))
    return centres[kept].reshape(-1, 2), heights[kept].astype(float)


def _in_view(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) int of ``points`` (N, 3) and whether they fall in the image (N,).

    A point must lie in the image both with and without lens distortion: far
    outside the calibrated field of view a distortion polynomial folds points
    back into the image.
    """
    w, h = camera.size
    ideal = camera.project(points, distort=False)
    real = camera.project(points)
    ok = np.ones(len(points), bool)
    for px in (ideal, real):
        with np.errstate(invalid="ignore"):
            ok &= (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    pix = np.zeros((len(points), 2), np.int32)
    pix[ok] = np.floor(real[ok]).astype(np.int32)
    return pix, ok


def _rig_key(cameras: CameraGroup) -> tuple:
    """A hashable fingerprint of a rig (every parameter that moves a pixel)."""
    return tuple(
        (c.name, c.size, c.K.tobytes(), c.dist.tobytes(), c.R.tobytes(), c.t.tobytes())
        for c in cameras
    )


_hulls: dict[tuple, VisualHull] = {}


def visual_hull(cameras: CameraGroup, config: HullConfig | None = None) -> VisualHull:
    """The :class:`VisualHull` of a rig, built once per process, rig and config (a
    batch segments frame by frame, every task asking for the same rig's hull)."""
    config = config or HullConfig()
    key = (_rig_key(cameras), config)
    if key not in _hulls:
        if len(_hulls) >= 4:  # a process sees few rigs; keep the memory bounded
            _hulls.pop(next(iter(_hulls)))
        _hulls[key] = VisualHull(cameras, config)
    return _hulls[key]


class VisualHull:
    """The capture volume of a rig as voxels, with each voxel's pixel per camera.

    Parameters
    ----------
    cameras : CameraGroup
        The rig (at least ``config.min_views`` cameras).
    config : HullConfig, optional

    Raises
    ------
    InputError
        When fewer cameras than ``min_views``, or no part of the floor is seen
        by ``min_views`` cameras (the check cannot run; the message says so).
    """

    def __init__(self, cameras: CameraGroup, config: HullConfig | None = None) -> None:
        self.config = cfg = config or HullConfig()
        self.cameras = cameras
        if len(self.cameras) < cfg.min_views:
            raise InputError(
                f"multi-view check: needs at least {cfg.min_views} cameras, got {len(cameras)}"
            )
        lo, hi = self._floor_extent()
        #: The capture volume's floor (x, y) box.
        self.floor_box = (lo, hi)
        size = float(np.cbrt(np.prod(hi - lo) * cfg.height / cfg.max_voxels))
        self.voxel = size
        axes = [np.arange(a + size / 2, b, size) for a, b in zip(lo, hi, strict=True)]
        axes.append(np.arange(size / 2, cfg.height, size))
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        pix, seen = zip(*(_in_view(c, grid) for c in self.cameras), strict=True)
        seen = np.stack(seen)  # (C, N)
        keep = seen.sum(axis=0) >= cfg.min_views
        self._shape = tuple(len(a) for a in axes)
        #: World position (3,) of the grid's first voxel centre (grid cell (0, 0, 0)).
        self.origin = np.array([a[0] for a in axes])
        self._index = np.flatnonzero(keep)  # (N,) into the full grid
        self.points = grid[keep]  # (N, 3)
        self.seen = seen[:, keep]  # (C, N)
        self.pixels = np.stack([p[keep] for p in pix])  # (C, N, 2)
        # Half the projected voxel side per camera (pixels), to splat the hull back.
        depth = np.array([np.median(c.to_camera(self.points)[:, 2]) for c in self.cameras])
        focal = np.array([c.K[0, 0] for c in self.cameras])
        self.splat = np.maximum(np.ceil(focal * size / depth / 2).astype(int), 1)
        log.debug(
            "capture volume: x %.2f..%.2f, y %.2f..%.2f m, %d voxels of %.1f cm",
            lo[0], hi[0], lo[1], hi[1], len(self.points), 100 * size,
        )  # fmt: skip

    def _floor_extent(self) -> tuple[np.ndarray, np.ndarray]:
        """The (x, y) box of the floor region that ``min_views`` cameras see at waist height."""
        centers = self.cameras.centers
        mid = centers[:, :2].mean(axis=0)
        reach = np.linalg.norm(centers[:, :2] - mid, axis=1).max() + 1.0
        step = reach / 100
        xs = np.arange(mid[0] - reach, mid[0] + reach, step)
        ys = np.arange(mid[1] - reach, mid[1] + reach, step)
        plane = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
        count = np.zeros(len(plane), int)
        for z in (0.05, 1.0, 1.8):
            pts = np.column_stack([plane, np.full(len(plane), z)])
            count = np.maximum(count, sum(_in_view(c, pts)[1].astype(int) for c in self.cameras))
        inside = plane[count >= self.config.min_views]
        if len(inside) == 0:
            raise InputError(
                f"multi-view check: no part of the room is seen by {self.config.min_views} "
                "cameras (are the cameras calibrated in one world frame, z up?)"
            )
        return inside.min(axis=0) - step, inside.max(axis=0) + step

    def grid(self, voxels: np.ndarray) -> np.ndarray:
        """(X, Y, Z) bool: capture-volume voxels ``voxels`` (N,) bool on the full grid
        (cell ``(i, j, k)`` centred at ``origin + (i, j, k) * voxel``; level k spans
        heights ``[k voxel, (k + 1) voxel)``)."""
        grid = np.zeros(int(np.prod(self._shape)), bool)
        grid[self._index[np.asarray(voxels, bool)]] = True
        return grid.reshape(self._shape)

    @property
    def cells(self) -> np.ndarray:
        """(N, 3) int: each capture-volume voxel's grid cell (see :meth:`grid`)."""
        return np.column_stack(np.unravel_index(self._index, self._shape))

    def occupied(self, masks: Sequence[np.ndarray]) -> np.ndarray:
        """The subject's voxels: the largest connected body of :meth:`bodies`.

        Parameters
        ----------
        masks : sequence of (H_c, W_c) bool, camera order

        Returns
        -------
        (N,) bool
        """
        return self.bodies(masks).largest

    def bodies(self, masks: Sequence[np.ndarray]) -> HullBodies:
        """Voxels inside the silhouettes of their cameras, ``misses`` disagreements allowed,
        as connected bodies.

        Cameras with an empty silhouette abstain (a view with nobody found, or
        unreadable, cannot vote against the others). At least ``min_views``
        cameras must agree on a voxel.

        Parameters
        ----------
        masks : sequence of (H_c, W_c) bool, camera order

        Returns
        -------
        HullBodies
            The subject is the largest body; smaller ones are ghosts (a blob in
            one view whose cone crosses the subject's cones in others) or other
            people (:attr:`HullBodies.persons`).
        """
        hits, votes = self._votes(masks)
        # Never fewer than min_views agreeing cameras: the silhouette cones of two
        # cameras always meet somewhere, far from the subject too.
        need = np.maximum(votes - self.config.misses, self.config.min_views)
        occupied = hits >= need
        if not occupied.any():
            none = np.zeros(1)
            return HullBodies(
                np.zeros(len(self.points), np.int32), none.astype(int), none, self.voxel
            )
        labels, n = ndimage.label(self.grid(occupied), structure=np.ones((3, 3, 3)))
        labels = labels.reshape(-1)[self._index]
        voxels = np.bincount(labels[occupied], minlength=n + 1)
        voxels[0] = 0
        z = self.points[occupied, 2]
        top = np.full(n + 1, -np.inf)
        bottom = np.full(n + 1, np.inf)
        np.maximum.at(top, labels[occupied], z)
        np.minimum.at(bottom, labels[occupied], z)
        heights = np.where(voxels > 0, top - bottom + self.voxel, 0.0)
        bodies = HullBodies(labels, voxels, heights, self.voxel)
        people = occupied & bodies.person_sized[labels]
        if not people.any():
            return bodies
        # Separate bodies are separate people whatever their tops say (a raised hand
        # can be a body's only top, and it stands on nothing).
        centres, heights = person_tops(self.grid(people), self.voxel)
        tops = np.column_stack([self.origin[:2] + centres * self.voxel, heights])
        persons = max(len(tops), int(bodies.person_sized.sum()))
        agreed = people & (hits >= votes)
        held = np.array([self._crown(top, agreed).any() for top in tops], bool)
        confirmed = np.bincount(labels[agreed], minlength=n + 1) > 0
        return replace(bodies, persons=persons, tops=tops, held=held, confirmed=confirmed)

    def top_bodies(self, bodies: HullBodies) -> np.ndarray:
        """(T,) int: the body (:attr:`HullBodies.labels`) each of ``bodies``' tops stands
        on (the label of most of its crown's voxels: within :data:`PERSON_REACH` of its
        floor position and :data:`TOP_DEPTH` below it)."""
        out = np.zeros(len(bodies.tops), int)
        for k, top in enumerate(bodies.tops):
            labels = bodies.labels[self._crown(top, bodies.labels > 0)]
            if labels.size:
                out[k] = np.bincount(labels).argmax()
        return out

    def _crown(self, top: np.ndarray, voxels: np.ndarray) -> np.ndarray:
        """(N,) bool: ``voxels`` (N,) bool within :data:`PERSON_REACH` of ``top``'s (3,)
        floor position and :data:`TOP_DEPTH` below it."""
        beside = np.linalg.norm(self.points[:, :2] - top[:2], axis=1) <= PERSON_REACH
        return voxels & beside & (self.points[:, 2] >= top[2] - TOP_DEPTH)

    def _votes(self, masks: Sequence[np.ndarray | None]) -> tuple[np.ndarray, np.ndarray]:
        """Per voxel (N,) int16: the cameras whose silhouette holds it, and the cameras
        that see it and have a silhouette (an empty or None mask abstains)."""
        if len(masks) != len(self.cameras):
            raise InputError(f"expected {len(self.cameras)} masks, got {len(masks)}")
        hits = np.zeros(len(self.points), np.int16)
        votes = np.zeros(len(self.points), np.int16)
        for c, (cam, mask) in enumerate(zip(self.cameras, masks, strict=True)):
            if mask is None:
                continue
            if np.shape(mask) != (cam.size[1], cam.size[0]):
                raise InputError(
                    f"camera {cam.name!r}: mask is {np.shape(mask)[1]}x{np.shape(mask)[0]}, "
                    f"the camera {cam.size[0]}x{cam.size[1]}"
                )
            if not mask.any():
                continue
            seen = self.seen[c]
            inside = np.zeros(len(self.points), bool)
            u, v = self.pixels[c, seen, 0], self.pixels[c, seen, 1]
            inside[seen] = mask[v, u]
            hits += inside
            votes += seen
        return hits, votes

    def carved(self, masks: Sequence[np.ndarray | None], min_views: int = 2) -> np.ndarray:
        """(N,) bool: the largest connected body of the voxels that every given
        silhouette seeing them holds, seen by at least ``min_views`` of them.

        One person's hull from their own silhouettes (None or empty: the camera
        abstains), with no disagreement allowed: unlike :meth:`bodies` (the frame's
        hull, which forgives a camera that lost part of someone), a person's
        silhouettes were chosen to hold all of them.
        """
        hits, votes = self._votes(masks)
        occupied = (hits == votes) & (votes >= min_views)
        if not occupied.any():
            return occupied
        labels, _ = ndimage.label(self.grid(occupied), structure=np.ones((3, 3, 3)))
        labels = labels.reshape(-1)[self._index]
        largest = np.argmax(np.bincount(labels[occupied])[1:]) + 1
        return occupied & (labels == largest)

    def support(self, occupied: np.ndarray, c: int, reach: float = 0.5) -> np.ndarray:
        """(H, W) bool: where the occupied voxels project in camera ``c``, each as a
        square of ``reach`` voxel sides about its centre's pixel (0.5: the voxel's
        own footprint; more reaches the parts thinner than a voxel that the
        centre-sampled hull cannot hold, e.g. fingers)."""
        cam = self.cameras[c]
        out = np.zeros((cam.size[1], cam.size[0]), np.uint8)
        sel = occupied & self.seen[c]
        px = self.pixels[c, sel]
        out[px[:, 1], px[:, 0]] = 1
        r = max(int(np.ceil(self.splat[c] * reach / 0.5)), 1)
        out = cv2.dilate(out, cv2.getStructuringElement(cv2.MORPH_RECT, (2 * r + 1, 2 * r + 1)))
        return out.astype(bool)

    def leave_one_out(self, masks: Sequence[np.ndarray], c: int) -> np.ndarray | None:
        """(H, W) bool: where the hull of every view but ``c`` projects in camera ``c``
        (None when the other views agree on nothing).

        Parameters
        ----------
        masks : sequence of (H_c, W_c) bool, camera order
        c : int
        """
        others = [np.zeros_like(m) if k == c else m for k, m in enumerate(masks)]
        occupied = self.occupied(others)
        return self.support(occupied, c) if occupied.any() else None

    def check(self, masks: Sequence[np.ndarray]) -> HullCheck:
        """Remove from each silhouette what the other views do not confirm.

        Parameters
        ----------
        masks : sequence of (H_c, W_c) bool, camera order

        Returns
        -------
        HullCheck
            With fewer than ``min_views`` non-empty views there is nothing to
            check: the masks are returned unchanged. When the views agree on
            nothing (no occupied voxel), the masks are returned unchanged and
            every non-empty view is ``inconsistent``.
        """
        occ = self.occupied(masks)
        n_views = sum(bool(np.any(m)) for m in masks)
        if not occ.any():
            judged = n_views >= self.config.min_views
            return HullCheck(
                tuple(np.asarray(m, bool) for m in masks),
                tuple(bool(np.any(m)) and judged for m in masks),
                (None,) * len(masks),
                0,
            )
        out, bad, rois = [], [], []
        for c, mask in enumerate(masks):
            sup = self.support(occ, c)
            ys, xs = np.nonzero(sup)
            rois.append((int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1))
            kept = _touching(np.asarray(mask, bool), sup)
            total = int(np.count_nonzero(mask))
            out.append(kept)
            bad.append(total == 0 or np.count_nonzero(kept) < self.config.keep_fraction * total)
        return HullCheck(tuple(out), tuple(bad), tuple(rois), int(occ.sum()))


def _touching(mask: np.ndarray, support: np.ndarray) -> np.ndarray:
    """The connected regions of ``mask`` (8-connected) that overlap ``support``."""
    if not mask.any():
        return mask
    n, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    hit = np.zeros(n, bool)
    hit[np.unique(labels[mask & support])] = True
    hit[0] = False
    return hit[labels]
