"""The capture stage: a session in, one silhouette per camera per kept frame out.

Segmentation (:func:`segment_session`, :class:`CaptureConfig`): where a camera
has an empty-scene clip, background subtraction with shadow suppression gives
the silhouette's pixels, and the learned person segmenter
(:mod:`bodymetry.capture.person`) decides which blobs are the person (a
bystander or a moved chair is dropped). Where there is no clip, the segmenter's
mask is the silhouette. Then the multi-view check
(:mod:`bodymetry.capture.consistency`) removes what the calibrated cameras do
not agree on, and a view whose segmenter picked someone else is segmented again
in the box where the other views put the subject.

Each view's raw mask is cleaned and flagged by :mod:`bodymetry.capture.masks`.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import NamedTuple

import cv2
import numpy as np

from bodymetry.calibration.camera import CameraGroup
from bodymetry.capture.background import BackgroundModel, SubtractionConfig, Subtractor, read_clip
from bodymetry.capture.consistency import HullBodies, HullConfig, visual_hull
from bodymetry.capture.fusion import (
    FEATURES,
    LIT_CHANGE,
    SURE_LOGIT,
    THIN_REACH,
    FusionConfig,
    GeometryTerms,
    change_evidence,
    confirmed_change,
    fuse,
    outline_contrast,
    segmenter_evidence,
    view_agreement,
    view_features,
)
from bodymetry.capture.ingest import SyncReport, check_sync, read_frame_sets
from bodymetry.capture.landmarks import LandmarkConfig, triangulate_landmarks
from bodymetry.capture.masks import CleanupConfig, clean_mask, grown_mask, parts_off, thin_parts
from bodymetry.capture.people import (
    Sighting,
    people_boxes,
    sighting_of,
    sightings,
    within_hulls,
)
from bodymetry.capture.person import (
    LANDMARKS,
    SEGMENTER_REQUIREMENT,
    Person,
    PersonConfig,
    PersonSegmenter,
    segmenter_available,
)
from bodymetry.capture.persons import (
    everyone_silhouettes,
    observe_persons,
    raised_hands,
    side_by_side,
)
from bodymetry.capture.session import Session
from bodymetry.capture.shadows import FloorShadow, at_feet, floor_shadows
from bodymetry.capture.skin import SkinConfig, clothing_masks, facing, hand_skin
from bodymetry.errors import InputError

log = logging.getLogger(__name__)

#: Height above the floor (metres) from which the hull's voxels give the body's footprint.
KNEE_HEIGHT = 0.5
#: With a clip and one body in the hull, the segmenter is asked for everyone where, in
#: two views or more, the changed pixels outside its person (grown by ``hide_margin``)
#: are more than this share of its person: someone else stands where the hull does.
SECOND_PERSON_SHARE = 0.3

#: With a clip and one body in the hull, the segmenter is also asked for everyone where,
#: in two views or more, one connected blob of every pixel that changed at all (shadow
#: label included) on the hull's body and outside the segmenter's person (grown by
#: ``hide_margin``) is at least this share of its person: someone in clothes of the
#: room's colours, whom subtraction took for shadow and the segmenter passed over for
#: the more prominent person. The skeletons then decide (a second person two views
#: agree on counts). On 124 single-person studio frames the second view's largest
#: such blob was at most 0.28 of the person; beside a person in light grey, 0.69-1.24.
SOMEONE_ELSE_SHARE = 0.5

__all__ = [
    "CAPTURE_METHODS",
    "CaptureConfig",
    "FrameSegmenter",
    "SilhouetteFrame",
    "ViewEvidence",
    "background_models",
    "segment_session",
]

#: :attr:`CaptureConfig.method` values.
CAPTURE_METHODS = ("auto", "background", "person")

_warned_no_segmenter = False


@dataclass(frozen=True)
class CaptureConfig:
    """How the capture stage makes silhouettes.

    Attributes
    ----------
    method : {"auto", "background", "person"}
        ``auto``: background subtraction where the camera has an empty-scene
        clip, its blobs kept only where the learned segmenter sees the person;
        the segmenter alone where there is no clip. Without the segmenter
        installed, background subtraction alone (the session's temporal median
        where there is no clip), with a warning. ``background``: background
        subtraction only. ``person``: the learned segmenter only.
    consistency : bool
        The multi-view check (:mod:`bodymetry.capture.consistency`), when the
        calibrated cameras are given.
    person : PersonConfig
    hull : HullConfig
    landmarks : LandmarkConfig
        Triangulation of the segmenter's body landmarks.
    fusion : FusionConfig
        How background change, shadow label, segmenter and hull are fused per
        pixel (:mod:`bodymetry.capture.fusion`), and the agreement below which a
        view is ``unreliable``.
    skin : SkinConfig
        How the silhouettes' skin is told from clothing and hair
        (:mod:`bodymetry.capture.skin`; needs the segmenter's landmarks).
    """

    method: str = "auto"
    consistency: bool = True
    person: PersonConfig = field(default_factory=PersonConfig)
    hull: HullConfig = field(default_factory=HullConfig)
    landmarks: LandmarkConfig = field(default_factory=LandmarkConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    skin: SkinConfig = field(default_factory=SkinConfig)

    def __post_init__(self) -> None:
        if self.method not in CAPTURE_METHODS:
            raise InputError(
                f"capture.method: expected one of {', '.join(CAPTURE_METHODS)}, got {self.method!r}"
            )

    @property
    def uses_segmenter(self) -> bool:
        """Whether silhouettes use the learned segmenter here.

        Raises
        ------
        InputError
            For ``method="person"`` where the segmenter is not installed.
        """
        global _warned_no_segmenter
        if self.method == "background":
            return False
        if segmenter_available():
            return True
        if self.method == "person":
            raise InputError(
                "capture.method 'person': the person segmenter is not installed "
                f"(pip install --no-deps {SEGMENTER_REQUIREMENT})"
            )
        if not _warned_no_segmenter:
            _warned_no_segmenter = True
            log.warning(
                "the person segmenter is not installed (pip install --no-deps %s): "
                "silhouettes from background subtraction alone",
                SEGMENTER_REQUIREMENT,
            )
        return False


@dataclass(frozen=True)
class SilhouetteFrame:
    """The silhouettes of one kept session frame.

    Attributes
    ----------
    frame : int
        Session frame.
    cameras : tuple of str
        Camera names (session order).
    masks : tuple of (H, W) bool, length C
        Cleaned person mask per camera (all False when empty or unreadable).
    flags : tuple of tuple of str, length C
        Flags per camera (:data:`bodymetry.capture.masks.FLAGS`).
    images : tuple of ((H, W, 3) uint8 or None), length C
        The decoded images (None when unreadable), for overlays.
    shadows : tuple of (H, W) bool, length C
        Pixels suppressed as cast shadow (before clean-up).
    landmarks : (33, 3) float or None
        The subject's body landmarks in the world frame, metres
        (:mod:`bodymetry.capture.landmarks`; NaN rows where too few views saw
        one); None without the segmenter or the cameras.
    view_landmarks : tuple of ((33, 3) float or None), length C
        Per camera the segmenter's landmarks (pixel x, pixel y, visibility);
        None where the view found nobody or was inconsistent (empty tuple
        without the segmenter).
    agreement : tuple of (float or None), length C
        Per camera, how well the view's silhouette agrees with the other
        evidence of the frame, in [0, 1]: the better of the share the other
        views' hull confirms and the IoU with the view's segmenter
        (:func:`bodymetry.capture.fusion.view_agreement`); None where it could
        not be judged (empty tuple when nothing was judged). A view below the
        bound is flagged ``unreliable`` and left out of the fit for that frame.
    persons : int or None
        People in the capture volume
        (:attr:`bodymetry.capture.consistency.HullBodies.persons`, from every
        pixel some source calls person; without an empty-scene clip, from the
        skeletons of every person the segmenter finds in each view,
        :func:`bodymetry.capture.headcount.count_people`); None where it cannot
        be counted (no calibrated rig, or neither a background nor the
        segmenter). More than one: the frame's silhouettes are the largest
        body's, and the run says that other people were in view.
    sightings : tuple of Sighting
        Where people are told apart, each person with their pixels per camera
        (:class:`~bodymetry.capture.people.Sighting`, masks at the camera's
        size), for measuring a chosen person (``process --person N``; their
        identities across frames are given later, over all kept frames:
        :func:`bodymetry.capture.persons.track_ids`): without an empty-scene
        clip from the segmenter's detections (:mod:`bodymetry.capture.people`),
        with one from the split of the hull where more than one person is
        counted (:mod:`bodymetry.capture.persons`); empty otherwise.
    clothing : tuple of ((H, W) bool or None), length C
        Per camera, the silhouette's pixels that are not skin
        (:mod:`bodymetry.capture.skin`); empty where it could not be told.
    contrast : float or None
        How plainly the silhouettes stand out from the empty scene along their
        outline (:func:`bodymetry.capture.fusion.outline_contrast`); None
        without an empty-scene clip.
    """

    frame: int
    cameras: tuple[str, ...]
    masks: tuple[np.ndarray, ...]
    flags: tuple[tuple[str, ...], ...]
    images: tuple[np.ndarray | None, ...] = field(default=(), repr=False)
    shadows: tuple[np.ndarray, ...] = field(default=(), repr=False)
    landmarks: np.ndarray | None = field(default=None, repr=False)
    view_landmarks: tuple[np.ndarray | None, ...] = field(default=(), repr=False)
    agreement: tuple[float | None, ...] = ()
    persons: int | None = None
    sightings: tuple[Sighting, ...] = field(default=(), repr=False)
    clothing: tuple[np.ndarray | None, ...] = field(default=(), repr=False)
    contrast: float | None = None

    def stack(self) -> np.ndarray:
        """(C, H, W) bool masks, for rigs whose cameras all have one image size.

        Rigs that mix image sizes use :attr:`masks` (one (H_c, W_c) mask per
        camera), which every estimation stage accepts.

        Raises
        ------
        ValueError
            If the cameras' masks differ in size (the message names each
            camera with its size).
        """
        shapes = [np.shape(m) for m in self.masks]
        if len(set(shapes)) > 1:
            sizes = ", ".join(
                f"{name} {s[1]}x{s[0]}" for name, s in zip(self.cameras, shapes, strict=True)
            )
            raise ValueError(
                f"frame {self.frame}: the cameras' masks differ in size (width x height: "
                f"{sizes}); use .masks, one mask per camera"
            )
        return np.stack(self.masks)


def background_models(
    session: Session,
    report: SyncReport | None = None,
    *,
    max_frames: int = 60,
    method: str = "sequential",
    median: bool = True,
) -> list[BackgroundModel | None]:
    """A :class:`BackgroundModel` per camera (session order).

    From the camera's empty-scene clip when the session names one. Otherwise,
    with ``median``, the temporal median of the session's kept frames (at most
    ``max_frames``, evenly spread), with a warning naming the camera; without
    it, None (the learned segmenter works without a background).
    """
    report = report or check_sync(session)
    models: list[BackgroundModel | None] = []
    missing = []
    for c, cam in enumerate(session.cameras):
        path = session.background_path(cam.name)
        if path is None:
            models.append(None)
            missing.append(c)
            continue
        frames = read_clip(path, cam.name, max_frames)
        size = report.videos[c].size
        if (frames.shape[2], frames.shape[1]) != size:
            raise InputError(
                f"camera {cam.name!r}: background clip {path} is "
                f"{frames.shape[2]}x{frames.shape[1]}, its video {size[0]}x{size[1]}"
            )
        models.append(BackgroundModel.from_frames(cam.name, frames, "clip"))
    if missing and median:
        names = [session.cameras[c].name for c in missing]
        log.warning(
            "no background clip for camera(s) %s and no person segmenter: using the temporal "
            "median of the session's kept frames (a person who stands still in many of them "
            "becomes background; install the segmenter: pip install --no-deps %s)",
            ", ".join(names),
            SEGMENTER_REQUIREMENT,
        )
        kept = report.kept
        if len(kept) > max_frames:
            kept = kept[np.linspace(0, len(kept) - 1, max_frames).round().astype(int)]
        stacks: dict[int, list[np.ndarray]] = {c: [] for c in missing}
        for fs in read_frame_sets(session, report, frames=kept, method=method):
            for c in missing:
                if fs.images[c] is not None:
                    stacks[c].append(fs.images[c])
        for c in missing:
            name = session.cameras[c].name
            if not stacks[c]:
                raise InputError(f"camera {name!r}: no frame decodes; cannot model its background")
            models[c] = BackgroundModel.from_frames(name, np.stack(stacks[c]), "session")
    return models


def _prefetch(items: Iterator, depth: int = 2) -> Iterator:
    """Iterate ``items`` in a background thread, ``depth`` ahead (decoding overlaps
    segmentation; both release the GIL). Exceptions are re-raised here."""

    q: queue.Queue = queue.Queue(maxsize=depth)
    done = object()
    stop = threading.Event()

    def put(entry: tuple) -> bool:
        while not stop.is_set():
            try:
                q.put(entry, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def work() -> None:
        try:
            for item in items:
                if not put(("item", item)):
                    break
            else:
                put(("item", done))
        except BaseException as exc:  # re-raised in the consumer
            put(("error", exc))
        finally:
            close = getattr(items, "close", None)
            if close is not None:
                close()

    thread = threading.Thread(target=work, daemon=True)
    thread.start()
    try:
        while True:
            kind, item = q.get()
            if kind == "error":
                raise item
            if item is done:
                return
            yield item
    finally:
        stop.set()
        thread.join()


#: A part the segmenter's mask lost is confirmed only where it reaches near where its
#: own skeleton puts a hand or a foot: within this share of the person's height (the
#: mask's box) of a visible wrist, finger, ankle, heel or toe landmark. The hull's
#: projection alone also covers a hard cast shadow beside the feet.
LIMB_END_REACH = 0.12
_LIMB_ENDS = [
    LANDMARKS.index(f"{side}_{part}")
    for side in ("left", "right")
    for part in ("wrist", "pinky", "index", "thumb", "ankle", "heel", "foot_index")
]


def _near_ends(landmarks: np.ndarray, person: np.ndarray, reach: float) -> np.ndarray:
    """(H, W) bool: pixels within ``reach`` of the person's height (rows of ``person``
    (H, W) bool) of a visible hand or foot landmark of ``landmarks`` (33, 3)."""
    out = np.zeros(person.shape, np.uint8)
    if not person.any():
        return out.astype(bool)
    rows = np.flatnonzero(person.any(axis=1))
    radius = max(round(float(reach * (rows[-1] - rows[0] + 1))), 1)
    for x, y, visibility in landmarks[_LIMB_ENDS]:
        if np.isfinite(visibility) and visibility >= 0.5:
            cv2.circle(out, (round(float(x)), round(float(y))), radius, 1, -1)
    return out.astype(bool)


@dataclass
class _View:
    """One camera's silhouette of one frame, while the frame is segmented."""

    mask: np.ndarray
    flags: tuple[str, ...]
    shadow: np.ndarray
    landmarks: np.ndarray | None = None
    #: The mask holds a part the segmenter's person does not touch (kept because the
    #: hull confirms it): the segmenter lost what joins it to the body.
    lost_part: bool = False


@dataclass
class ViewEvidence:
    """What each source says about one view (:mod:`bodymetry.capture.fusion`).

    Attributes
    ----------
    raw : (H, W) bool or None
        Background subtraction's person label (None without a background).
    shadow : (H, W) bool
        Its cast-shadow label (all False without a background).
    change : (H, W) float32 or None
        The change term (:func:`~bodymetry.capture.fusion.change_evidence`) of the
        colour distance with its chroma weighed down
        (:meth:`~bodymetry.capture.background.Subtractor.labels`' ``video2``).
    colour_change : (H, W) float32 or None
        The same of the colour distance with every channel alike, which
        :func:`~bodymetry.capture.fusion.outline_contrast` reads (its classes were
        measured on it).
    brightness : (H, W) float32 or None
        The log brightness ratio to the empty scene (for the floor-shadow test).
    person : Person or None
        The segmenter's person (None without the segmenter, or nobody found).
    threshold : float
        The segmenter's probability threshold (:attr:`PersonConfig.threshold`).
    """

    raw: np.ndarray | None
    shadow: np.ndarray
    change: np.ndarray | None
    brightness: np.ndarray | None
    person: Person | None
    threshold: float = 0.5
    colour_change: np.ndarray | None = None

    @cached_property
    def found(self) -> np.ndarray | None:
        """(H, W) bool: the segmenter's person mask, or None (computed once: the hull's
        candidates, the silhouette and the agreement all use it)."""
        return None if self.person is None else self.person.mask(self.threshold)

    def candidate(self) -> np.ndarray:
        """(H, W) bool: every pixel some source may call person (for the hull)."""
        out = self.shadow.copy()
        for part in (self.raw, self.found):
            if part is not None:
                out |= part
        return out


def _changed(ev: ViewEvidence) -> np.ndarray:
    """(H, W) bool: background subtraction's person label, with the segmenter's person
    (where the change is shadow-like: a grey shirt reads as the wall's shadow)."""
    return ev.raw if ev.found is None else ev.raw | ev.found


def _second_beside(ev: ViewEvidence, term: GeometryTerms, found: np.ndarray) -> bool:
    """One view of :meth:`FrameSegmenter._more_than_one`: background subtraction's
    person pixels where the hull stands, off ``found`` (the segmenter's person grown),
    hold more than :data:`SECOND_PERSON_SHARE` of that person, or form two whole
    people side by side."""
    changed = ev.raw & term.hull_any
    rest = np.count_nonzero(changed & ~found)
    return rest > SECOND_PERSON_SHARE * np.count_nonzero(ev.found) or side_by_side(
        changed, term.hull_any
    )


def _unseen_beside(ev: ViewEvidence, term: GeometryTerms, found: np.ndarray) -> bool:
    """One view of :meth:`FrameSegmenter._someone_unseen`: one connected blob of the
    hull's candidates on its body and off ``found`` (the segmenter's person grown) is
    at least :data:`SOMEONE_ELSE_SHARE` of that person."""
    rest = (ev.candidate() & term.hull_body & ~found).astype(np.uint8)
    n, _, stats, _ = cv2.connectedComponentsWithStats(rest, connectivity=8)
    largest = stats[1:, cv2.CC_STAT_AREA].max() if n > 1 else 0
    return bool(largest >= SOMEONE_ELSE_SHARE * np.count_nonzero(ev.found))


class _FrameViews(NamedTuple):
    """One frame as :class:`FrameSegmenter` segments it.

    Attributes
    ----------
    views : list of _View
        Per camera.
    landmarks : (33, 3) float or None
        World landmarks (None without a segmenter or cameras).
    agreement : list of (float or None)
        Per camera (None where not judged).
    persons : int or None
        :attr:`SilhouetteFrame.persons`.
    sightings : tuple of Sighting
        :attr:`SilhouetteFrame.sightings`.
    contrast : float or None
        :attr:`SilhouetteFrame.contrast`.
    """

    views: list[_View]
    landmarks: np.ndarray | None
    agreement: list[float | None]
    persons: int | None
    sightings: tuple[Sighting, ...] = ()
    contrast: float | None = None


class FrameSegmenter:
    """Segments the views of one frame: the evidence per camera, its fusion with
    the multi-view hull, then the multi-view check, each view's agreement and the
    landmarks in 3D (module docstring, "Segmentation").

    Parameters
    ----------
    models : sequence of (BackgroundModel or None)
        Per camera (None: no background, the segmenter alone).
    sizes : sequence of (width, height)
    config : CaptureConfig
    subtraction : SubtractionConfig or None
    cleanup : CleanupConfig or None
    cameras : CameraGroup or None
        The calibrated rig (no hull without it).
    """

    def __init__(
        self,
        models: Sequence[BackgroundModel | None],
        sizes: Sequence[tuple[int, int]],
        config: CaptureConfig,
        subtraction: SubtractionConfig | None,
        cleanup: CleanupConfig | None,
        cameras: CameraGroup | None,
    ) -> None:
        self.models = list(models)
        self.sizes = list(sizes)
        self.cleanup = cleanup
        self.config = config
        self.cameras = cameras
        self.subtractors = [None if m is None else Subtractor(m, subtraction) for m in models]
        self.segmenter = PersonSegmenter(config.person) if config.uses_segmenter else None
        self.hull = None
        if cameras is not None and config.consistency and len(cameras) >= config.hull.min_views:
            try:
                self.hull = visual_hull(cameras, config.hull)
            except InputError as exc:
                log.warning("%s; silhouettes are not checked across views", exc)

    def evidence(
        self, c: int, image: np.ndarray, roi: tuple[int, int, int, int] | None = None
    ) -> ViewEvidence:
        """Every source's evidence of camera ``c``'s image (the segmenter in ``roi``)."""
        w, h = self.sizes[c]
        person = None if self.segmenter is None else self.segmenter.detect(image, roi)
        sub = self.subtractors[c]
        threshold = self.config.person.threshold
        if sub is None:
            return ViewEvidence(None, np.zeros((h, w), bool), None, None, person, threshold)
        raw, shadow, dist2, video2, brightness = sub.labels(
            image, distances=True, brightness=True, video=True
        )
        # The fusion's change term leaves out the chroma that 4:2:0 video spreads past a
        # garment's outline into the narrow gaps beside it (docs/capture.md, "Chroma in
        # the gaps"), except at the hands, whose skin differs from a beige floor more in
        # chroma than in lightness ("Hands before the floor"); the outline contrast keeps
        # the full colour distance.
        if person is not None and person.landmarks is not None:
            hands = hand_skin(image, person.landmarks)
            video2[hands] = dist2[hands]
        change = change_evidence(video2, sub.config.fg_sigma)
        colour_change = change_evidence(dist2, sub.config.fg_sigma)
        return ViewEvidence(raw, shadow, change, brightness, person, threshold, colour_change)

    def _asked_again(
        self, images: Sequence[np.ndarray | None], evidence: list[ViewEvidence | None]
    ) -> list[ViewEvidence | None]:
        """``evidence`` with each camera whose segmenter found nobody, while two
        other cameras agree on someone, asked again in the box where they put
        each such person (:func:`~bodymetry.capture.people.people_boxes`), until
        one is found.

        The detector can miss everyone in a whole image and find them in a crop:
        Demo_MultiPerson, frame 90, cam02, both people in plain view, nobody found
        even at detection confidence 0.1, each found in a crop of their own. A
        camera that did find someone is not asked again here (someone hidden behind
        another is their skeleton's business, :func:`~bodymetry.capture.people.sightings`).
        """
        if self.segmenter is None or self.hull is None:
            return evidence
        missed = [
            c for c, ev in enumerate(evidence)
            if ev is not None and ev.person is None and images[c] is not None
        ]  # fmt: skip
        if not missed:
            return evidence
        landmarks = [
            [] if ev is None or ev.person is None else [ev.person.landmarks] for ev in evidence
        ]
        for c in missed:
            for roi in people_boxes(self.hull.cameras, landmarks, c, self.hull.floor_box):
                # Only the segmenter is asked again: background subtraction's labels
                # do not depend on where it looks.
                person = self.segmenter.detect(images[c], roi)
                if person is not None:
                    log.debug("camera %s: nobody found in the image, someone in %s", c, roi)
                    evidence[c] = replace(evidence[c], person=person)
                    break
        return evidence

    def bodies(self, evidence: Sequence[ViewEvidence | None]) -> HullBodies | None:
        """The hull's bodies of every pixel some source calls person (the fusion's
        candidates); None without a hull."""
        if self.hull is None:
            return None
        candidates = [
            np.zeros((h, w), bool) if ev is None else ev.candidate()
            for ev, (w, h) in zip(evidence, self.sizes, strict=True)
        ]
        return self.hull.bodies(candidates)

    def people(
        self,
        images: Sequence[np.ndarray | None],
        evidence: Sequence[ViewEvidence | None],
        expected: int = 0,
        bodies: HullBodies | None = None,
        floor: Sequence[FloorShadow | None] | None = None,
    ) -> list[Sighting] | None:
        """Every person in the capture volume, with their pixels in each camera
        (:func:`bodymetry.capture.people.sightings`); None without a hull (a
        calibrated rig) or the segmenter.

        Background subtraction sees everyone; the segmenter returns one person
        per call, so each view is asked again with the people found hidden
        (:meth:`~bodymetry.capture.person.PersonSegmenter.detect_others`).
        ``expected`` and ``bodies``: the hull's count of people and the hull's
        bodies, where the session has a background: each person's pixels are
        then their part of everyone's fused silhouette (:meth:`everyone`), not
        of the detections' masks, and those on someone else's hull and off
        their own are unknown to them
        (:func:`~bodymetry.capture.people.within_hulls`). ``floor``: :meth:`floor`
        of the same evidence, when already computed.
        """
        if self.hull is None or self.segmenter is None:
            return None
        detections: list[list[Person]] = []
        for ev, image in zip(evidence, images, strict=True):
            found = [] if ev is None or ev.person is None or image is None else [ev.person]
            if found:
                found += self.segmenter.detect_others(image, ev.person)
            detections.append(found)
        foreground = None
        if bodies is not None:
            foreground = self.everyone(images, evidence, detections, bodies, floor)
        cfg = self.config.person
        found = sightings(
            self.hull.cameras,
            detections,
            cfg.threshold,
            self.hull.floor_box,
            self.hull.config.min_views,
            expected,
            foreground,
        )
        return found if foreground is None else within_hulls(found, self.hull, foreground)

    def everyone(
        self,
        images: Sequence[np.ndarray | None],
        evidence: Sequence[ViewEvidence | None],
        detections: Sequence[Sequence[Person]],
        bodies: HullBodies,
        floor: Sequence[FloorShadow | None] | None = None,
    ) -> list[np.ndarray | None]:
        """Per camera everyone's silhouette: the evidence fused as for one subject
        (:meth:`_fused`), with every detection's segmenter probability and every
        person-sized body of the hull, then cleaned and edge-refined around each
        detection (:func:`~bodymetry.capture.masks.clean_mask` keeps the blob
        that holds its person); None where the view has no background, or
        nobody was detected in it.

        The frame's silhouettes are the subject's: the segmenter's most prominent
        person, the hull's largest body, and the cleaning's one blob. Each person
        of several gets their pixels snapped to this instead of the detections'
        masks, which are upsampled from the segmenter's 256 px input
        (:func:`~bodymetry.capture.people.partition`; docs/capture.md, "Each
        person's pixels from everyone's fused silhouette").
        """
        out: list[np.ndarray | None] = [None] * len(evidence)
        if self.hull is None:
            return out
        occupied = (bodies.labels > 0) & bodies.person_sized[bodies.labels]
        terms = self.geometry(evidence, bodies, occupied, floor)
        for c, (image, ev, found) in enumerate(zip(images, evidence, detections, strict=True)):
            if image is None or ev is None or ev.raw is None or not found:
                continue
            everyone = Person(np.maximum.reduce([p.probability for p in found]), found[0].landmarks)
            raw, shadow = self._fused(c, replace(ev, person=everyone), terms[c])
            mask = np.zeros_like(raw)
            for person in found:
                mine, _ = clean_mask(raw, self.cleanup, image, self.models[c].median, shadow,
                                     person.mask(ev.threshold))  # fmt: skip
                mask |= mine
            out[c] = mask
        return out

    def geometry(
        self,
        evidence: Sequence[ViewEvidence | None],
        bodies: HullBodies | None = None,
        occupied: np.ndarray | None = None,
        floor: Sequence[FloorShadow | None] | None = None,
    ) -> list[GeometryTerms | None]:
        """Per camera what the rig says (:class:`~bodymetry.capture.fusion.GeometryTerms`):
        the hull's support above the floor band and anywhere, and the floor-shadow
        test; None without a hull or fusion, or where the candidates agree on nothing.
        ``bodies``: :meth:`bodies` of the same evidence, when already computed;
        ``occupied`` (N,) bool: the voxels of the people to support (default the
        largest body's: the subject's); ``floor``: :meth:`floor` of the same
        evidence, when already computed (it does not depend on who is supported)."""
        none: list[GeometryTerms | None] = [None] * len(evidence)
        if self.hull is None or not self.config.fusion.enabled:
            return none
        bodies = bodies or self.bodies(evidence)
        occupied = bodies.largest if occupied is None else occupied
        if not occupied.any():
            return none
        body = occupied & (self.hull.points[:, 2] >= self.config.fusion.floor_band)
        floor = self.floor(evidence) if floor is None else floor
        # The body's footprint from its voxels above the knees: lower down the hull
        # also holds ghosts over the cast shadow (every view sees it dark there).
        legs = occupied & (self.hull.points[:, 2] >= KNEE_HEIGHT)
        feet = at_feet(floor, self.hull.points[legs, :2], self.config.fusion.feet_reach)
        return [
            GeometryTerms(
                self.hull.support(body, c),
                self.hull.support(occupied, c),
                None if floor[c] is None else floor[c].mask,
                feet[c],
                self.hull.support(occupied, c, reach=THIN_REACH),
            )
            for c in range(len(evidence))
        ]

    def floor(self, evidence: Sequence[ViewEvidence | None]) -> list[FloorShadow | None]:
        """Per camera the shadow labels the other views confirm on the floor
        (:func:`~bodymetry.capture.shadows.floor_shadows`); needs the hull's cameras."""
        return floor_shadows(
            self.hull.cameras,
            [None if ev is None or ev.raw is None else ev.shadow for ev in evidence],
            [
                None if ev is None or ev.change is None else ev.change < LIT_CHANGE
                for ev in evidence
            ],
            brightness=[None if ev is None else ev.brightness for ev in evidence],
        )

    def _one_person(self, bodies: HullBodies, person: Sighting) -> bool:
        """Whether the hull's count of more than one is the one person the
        segmenter's detections agree on (``person``): all the hull's tops but one
        are that person's raised hands (:func:`~bodymetry.capture.persons.raised_hands`;
        both arms held straight up give two tops as solid and as far apart as two
        heads) or are not held by every camera that sees them (:attr:`HullBodies.held`:
        a sliver where two opposite views' cones cross, which the 3-of-4 vote lets
        through; a second person's head lies in every view's silhouette), the one
        left stands on the largest body (the subject's), and every person-sized
        body holds a top or is not :attr:`HullBodies.confirmed` (no voxel of it in
        every seeing camera's silhouette). A separate body whose tops are all
        unheld, or that has no top and no confirmed voxel, is a ghost: a bystander
        whom one or two cameras see, whose cones cross the subject's in a third
        (the skeletons, which need three cameras, count nobody there either); the
        subject's silhouettes are the largest body's, which it does not touch. A
        confirmed body without a top (someone bent below the tops' height) counts."""
        if self.hull is None:
            return False
        tops = bodies.tops
        landmarks = triangulate_landmarks(
            self.hull.cameras, person.landmarks, self.config.landmarks
        )
        hands = raised_hands(tops, landmarks)
        crossing = ~bodies.held
        explained = hands | crossing
        if int((~explained).sum()) > 1:
            return False
        under = self.hull.top_bodies(bodies)
        topless = [k for k in np.flatnonzero(bodies.person_sized) if k not in under]
        confirmed = [k >= len(bodies.confirmed) or bodies.confirmed[k] for k in topless]
        if any(confirmed) or not set(under[~explained].tolist()) <= {bodies.largest_body}:
            return False
        if not (explained.any() or topless):
            return False  # nothing the hull counted is explained
        log.debug(
            "hull tops %s m: one person's raised hands, %s m: cones crossing",
            tops[hands].round(2).tolist(),
            tops[crossing & ~hands].round(2).tolist(),
        )
        return True

    def _more_than_one(
        self, evidence: Sequence[ViewEvidence | None], terms: Sequence[GeometryTerms | None]
    ) -> bool:
        """Whether the hull's one body may be two people standing close: in at least
        two views, background subtraction's person pixels where the hull stands hold
        more than :data:`SECOND_PERSON_SHARE` of the segmenter's person again outside
        it, or form two whole people side by side
        (:func:`~bodymetry.capture.persons.side_by_side`: the segmenter's mask can
        hold both). Two people half a metre apart merge into one hull body, and its
        split looks for two heads 0.45 m apart."""
        return self._views_showing(evidence, terms, _second_beside) >= 2

    def _someone_unseen(
        self, evidence: Sequence[ViewEvidence | None], terms: Sequence[GeometryTerms | None]
    ) -> bool:
        """Whether the hull's one body may hold someone neither subtraction nor the
        segmenter found: in at least two views, a connected blob of the hull's
        candidates (every pixel that changed at all, shadow label included) on its
        body and outside the segmenter's person is at least :data:`SOMEONE_ELSE_SHARE`
        of that person. A person in light grey in a grey room reads as the wall's
        shadow to subtraction, and the segmenter returns the more prominent person
        beside them (``docs/capture.md``, "Someone the segmenter passed over")."""
        return self._views_showing(evidence, terms, _unseen_beside) >= 2

    def _views_showing(
        self,
        evidence: Sequence[ViewEvidence | None],
        terms: Sequence[GeometryTerms | None],
        shows: Callable[[ViewEvidence, GeometryTerms, np.ndarray], bool],
    ) -> int:
        """The views with a background, the segmenter's person and the rig's terms
        where ``shows(ev, term, found)`` holds, ``found`` (H, W) bool the segmenter's
        person grown by ``hide_margin``; none without the segmenter."""
        if self.segmenter is None:
            return 0
        views = 0
        for ev, term in zip(evidence, terms, strict=True):
            if ev is None or ev.raw is None or ev.found is None or term is None:
                continue
            views += bool(shows(ev, term, grown_mask(ev.found, self.config.person.hide_margin)))
        return views

    def features(
        self, c: int, ev: ViewEvidence, terms: GeometryTerms | None
    ) -> tuple[np.ndarray, str]:
        """Camera ``c``'s fusion features (H, W, F) float32 and their sources key
        (:func:`bodymetry.capture.fusion.view_features`)."""
        w, h = self.sizes[c]
        return view_features(
            (h, w),
            ev.change,
            None if ev.raw is None else ev.shadow,
            None if ev.person is None else segmenter_evidence(ev.person.probability),
            terms,
        )

    def _view(
        self,
        c: int,
        image: np.ndarray | None,
        ev: ViewEvidence | None,
        terms: GeometryTerms | None,
    ) -> _View:
        """Camera ``c``'s cleaned silhouette from its evidence (fused when enabled)."""
        w, h = self.sizes[c]
        none = np.zeros((h, w), bool)
        if image is None or ev is None:
            return _View(none, ("unreadable",), none)
        landmarks = None if ev.person is None else ev.person.landmarks
        found = ev.found
        if ev.raw is None:
            # No background: the segmenter's person is the silhouette (nothing to fuse
            # it with but the hull, which the multi-view check applies below).
            if found is None:
                return _View(none, ("empty",), none)
            mask, flags = clean_mask(found, self.cleanup)
            return _View(mask, flags, none, landmarks)
        raw, shadow = self._fused(c, ev, terms)
        # Where the hull puts the subject, a blob the segmenter did not touch may still
        # be theirs (a shoe below a shin it lost; docs/capture.md, "Parts the
        # segmenter lost").
        confirmed = ends = None
        if terms is not None and landmarks is not None and found is not None:
            confirmed = terms.hull_any
            ends = _near_ends(landmarks, found, LIMB_END_REACH)
        mask, flags = clean_mask(
            raw, self.cleanup, image, self.models[c].median, shadow, found, confirmed, ends
        )
        lost = confirmed is not None and parts_off(mask, found, self.cleanup)
        return _View(mask, flags, shadow, landmarks, lost)

    def _fused(
        self, c: int, ev: ViewEvidence, terms: GeometryTerms | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Camera ``c``'s person label (H, W) bool before cleaning, and its shadow
        label (H, W) bool: background subtraction's, or (fusion enabled) the fused
        evidence's (``ev`` has a background)."""
        raw, shadow = ev.raw, ev.shadow
        if self.config.fusion.enabled:
            features, key = self.features(c, ev, terms)
            raw = fuse(features, self.config.fusion.weights_for(key)) > 0
            if terms is not None and terms.shadow_at_feet is not None:
                # A shadow the other views confirm on the floor at the feet is not
                # person where the segmenter is unsure (its soft outline spreads over
                # the shadow there; a shoe or a trouser hem it is sure of stays).
                seg = features[..., FEATURES.index("segmenter")]
                raw &= ~(terms.shadow_at_feet & (seg < SURE_LOGIT))
            if terms is not None:
                raw = confirmed_change(
                    raw,
                    ev.raw,
                    ev.change,
                    terms.hull_any,
                    thin_parts(raw, self.cleanup),
                    terms.hull_reach,
                )
            # Shadow labels the fusion overruled (a grey shirt's shaded side) are person.
            shadow = shadow & ~raw
        return raw, shadow

    def __call__(self, images: Sequence[np.ndarray | None]) -> _FrameViews:
        """Segment one frame's images (None: unreadable): :class:`_FrameViews`."""
        evidence = [None if im is None else self.evidence(c, im) for c, im in enumerate(images)]
        evidence = self._asked_again(images, evidence)
        # Background subtraction sees everyone; without a background clip the
        # segmenter is asked for everyone (to count them and tell them apart: the
        # frame's silhouettes stay the most prominent person's, checked across
        # views as before).
        sees_all = any(ev is not None and ev.raw is not None for ev in evidence)
        bodies = self.bodies(evidence) if sees_all else None
        # The floor-shadow test depends on the evidence alone: once per frame, for the
        # subject's geometry and, with several people, everyone's (:meth:`everyone`).
        floor = None
        if sees_all and self.hull is not None and self.config.fusion.enabled:
            floor = self.floor(evidence)
        terms = self.geometry(evidence, bodies, floor=floor)
        views = [self._view(c, im, evidence[c], terms[c]) for c, im in enumerate(images)]
        people = None
        if sees_all:
            persons = None if bodies is None else bodies.persons
            close = persons == 1 and self._more_than_one(evidence, terms)
            unseen = persons == 1 and not close and self._someone_unseen(evidence, terms)
            if persons is not None and (persons > 1 or close or unseen):
                # Background subtraction sees everyone but cannot tell apart people who
                # touch or cross; the segmenter's detections, matched across cameras by
                # their skeletons, can (as without a clip). The hull's split stays the
                # answer where they find fewer than two people, unless the hull's extra
                # tops are the one person's raised hands or crossing cones
                # (:meth:`_one_person`).
                # Someone unseen is looked for as a second person: two views that agree
                # on them are enough (the hull holds them within the one body).
                expected = 2 if unseen else persons
                found = self.people(images, evidence, expected, bodies, floor)
                if found is not None and len(found) > 1:
                    people, persons = found, len(found)
                elif (
                    persons > 1
                    and found is not None
                    and len(found) == 1
                    and self._one_person(bodies, found[0])
                ):
                    bodies = replace(bodies, persons=1)
                    persons = 1
                elif close:
                    # Two views show a second person-sized blob beside the one the
                    # skeletons found (two people close, the second apart in too few
                    # views to match): more than one, though not told apart. Never
                    # seen in a single-person studio frame (docs/capture.md).
                    log.debug("a second person beside the one found: more than one")
                    persons = 2
        else:
            people = self.people(images, evidence)
            persons = None if people is None else len(people)
        agreement: list[float | None] = [None] * len(views)
        if self.hull is not None:
            check = self.hull.check([v.mask for v in views])
            # Ask again where the other views put the subject: the segmenter returns
            # the most prominent person, maybe a bystander; and it can lose a whole
            # shin in trousers of the floor's colour, which it finds when it sees the
            # person larger (docs/capture.md, "Parts the segmenter lost").
            retry = [
                c for c, (bad, v) in enumerate(zip(check.inconsistent, views, strict=True))
                if (bad or v.lost_part) and check.rois[c] is not None and images[c] is not None
            ]  # fmt: skip
            if self.segmenter is not None and retry:
                for c in retry:
                    person = self.segmenter.detect(images[c], check.rois[c])
                    again = replace(evidence[c], person=person)
                    view = self._view(c, images[c], again, terms[c])
                    if check.inconsistent[c] or view.mask.sum() >= views[c].mask.sum():
                        # A view that kept a lost part takes the second answer only
                        # where it keeps as much: the segmenter may lose it again.
                        evidence[c], views[c] = again, view
                check = self.hull.check([v.mask for v in views])
            for view, mask, bad in zip(views, check.masks, check.inconsistent, strict=True):
                view.mask = mask
                if bad:
                    view.flags = (*view.flags, "inconsistent")
                    view.landmarks = None
            agreement = self._agreement(views, evidence)
            if people is None and bodies is not None and bodies.persons > 1:
                everyone = everyone_silhouettes(
                    self.hull,
                    bodies,
                    [v.mask for v in views],
                    [None if ev is None or ev.raw is None else _changed(ev) for ev in evidence],
                )
                # The hull of every person's silhouettes is tighter than the
                # candidates' (no shadows, no segmenter halo); where it holds fewer
                # persons than the candidates' (a head lost in two views), the
                # candidates' hull is split, the pixels still from the silhouettes.
                observed = observe_persons(self.hull, everyone)
                if len(observed) < bodies.persons:
                    looser = observe_persons(self.hull, everyone, bodies)
                    if len(looser) > len(observed):
                        observed = looser
                people = [sighting_of(o) for o in observed]
        landmarks = None
        if self.cameras is not None and sum(v.landmarks is not None for v in views) >= 2:
            landmarks = triangulate_landmarks(
                self.cameras, [v.landmarks for v in views], self.config.landmarks
            )
        changes = [None if ev is None else ev.colour_change for ev in evidence]
        contrast = outline_contrast([v.mask for v in views], changes)
        people = _with_contrast(people or (), [v.mask for v in views], changes)
        return _FrameViews(views, landmarks, agreement, persons, people, contrast)

    def _agreement(
        self, views: list[_View], evidence: Sequence[ViewEvidence | None]
    ) -> list[float | None]:
        """Each view's agreement with the other views' hull and its segmenter; a view
        below ``fusion.min_agreement`` is flagged ``unreliable`` (in place)."""
        masks = [v.mask for v in views]
        others = [self.hull.leave_one_out(masks, c) for c in range(len(views))]
        segmenter = [None if ev is None else ev.found for ev in evidence]
        agreement = view_agreement(masks, others, segmenter)
        for view, score in zip(views, agreement, strict=True):
            if score is not None and score < self.config.fusion.min_agreement:
                view.flags = (*view.flags, "unreliable")
        return agreement

    def close(self) -> None:
        if self.segmenter is not None:
            self.segmenter.close()


def frame_clothing(
    images: Sequence[np.ndarray | None],
    masks: Sequence[np.ndarray],
    landmarks: np.ndarray | None,
    view_landmarks: Sequence[np.ndarray | None],
    people: Sequence[Sighting],
    cameras: CameraGroup | None,
    config: CaptureConfig,
) -> tuple[np.ndarray | None, ...]:
    """Per camera, the silhouettes' pixels that are not skin (:attr:`SilhouetteFrame.clothing`).

    The seeds of the skin colour are the subject's landmarks in each view and
    every sighting's (a person's face seeds only in the views that see it,
    judged from their triangulated landmarks; without the cameras, their hands
    alone); the pixels classified are those of the frame's silhouettes and of
    every sighting's masks.
    """
    n = len(masks)
    found = []  # (per-view 2D landmarks, world landmarks or None), one per person
    if any(v is not None for v in view_landmarks):
        found.append((tuple(view_landmarks), landmarks))
    for seen in people:
        views = tuple(seen.landmarks)
        world = (
            triangulate_landmarks(cameras, list(views), config.landmarks)
            if cameras is not None and sum(v is not None for v in views) >= 2
            else None
        )
        found.append((views, world))
    silhouettes = []
    for c, mask in enumerate(masks):
        union = np.asarray(mask, bool).copy()
        for seen in people:
            if seen.masks[c] is not None:
                union |= seen.masks[c]
        silhouettes.append(union)
    seeds = [
        [
            (views[c], world is not None and facing(world, cameras[c].center))
            for views, world in found
            if views[c] is not None
        ]
        for c in range(n)
    ]
    return tuple(clothing_masks(list(images), silhouettes, seeds, config.skin))


def _with_contrast(
    people: Sequence[Sighting],
    masks: Sequence[np.ndarray],
    changes: Sequence[np.ndarray | None],
) -> tuple[Sighting, ...]:
    """``people`` each with their own outline contrast (:attr:`Sighting.contrast`):
    their pixels' rim where it borders the empty scene, not someone else's pixels nor
    someone nearer who hides them. ``masks``: the frame's silhouettes (for the shape of
    a view that shows nothing of a person)."""
    out = []
    for k, person in enumerate(people):
        mine = [
            np.zeros_like(m) if p is None else p for p, m in zip(person.masks, masks, strict=True)
        ]
        beside = []
        for c, m in enumerate(mine):
            other = np.zeros_like(m)
            for j, someone in enumerate(people):
                if j != k and someone.masks[c] is not None:
                    other |= someone.masks[c]
            if person.hidden and person.hidden[c] is not None:
                other |= person.hidden[c]
            beside.append(other)
        out.append(replace(person, contrast=outline_contrast(mine, changes, beside)))
    return tuple(out)


def segment_session(
    session: Session,
    *,
    config: CaptureConfig | None = None,
    cameras: CameraGroup | None = None,
    subtraction: SubtractionConfig | None = None,
    cleanup: CleanupConfig | None = None,
    report: SyncReport | None = None,
    models: Sequence[BackgroundModel | None] | None = None,
    frames: Sequence[int] | None = None,
    read_method: str = "sequential",
    keep_images: bool = True,
    on_frame: Callable[[SilhouetteFrame], None] | None = None,
) -> Iterator[SilhouetteFrame]:
    """The capture stage: yield a :class:`SilhouetteFrame` for every kept frame.

    Parameters
    ----------
    session : Session
    config : CaptureConfig, optional
        Which segmentation (background subtraction, the learned segmenter or
        both) and the multi-view check.
    cameras : CameraGroup, optional
        The calibrated rig (session order), for the multi-view check (skipped
        without it).
    subtraction, cleanup : configs (defaults: Horprasert shadow suppression)
    report : SyncReport, optional
        From :func:`capture.ingest.check_sync` (computed when not given).
    models : sequence of (BackgroundModel or None), optional
        Per camera (computed by :func:`background_models` when not given).
    frames : sequence of int, optional
        Session frames (default: the kept frames).
    read_method : {"sequential", "seek"}
    keep_images : bool
        Keep the decoded images in the frames (for overlays).
    """
    config = config or CaptureConfig()
    report = report or check_sync(session)
    if config.method == "person":
        models = [None] * len(session.cameras)
    if models is None:
        models = background_models(
            session, report, method=read_method, median=not config.uses_segmenter
        )
    if len(models) != len(session.cameras):
        raise InputError(f"expected {len(session.cameras)} background models, got {len(models)}")
    if config.method == "background" and any(m is None for m in models):
        raise InputError("capture.method 'background' needs a background model for every camera")
    views = FrameSegmenter(
        models, [v.size for v in report.videos], config, subtraction, cleanup, cameras
    )
    try:
        for fs in _prefetch(read_frame_sets(session, report, frames=frames, method=read_method)):
            per_view, landmarks, agreement, persons, people, contrast = views(fs.images)
            masks = tuple(v.mask for v in per_view)
            view_landmarks = (
                tuple(v.landmarks for v in per_view) if views.segmenter is not None else ()
            )
            out = SilhouetteFrame(
                frame=fs.frame,
                cameras=fs.cameras,
                masks=masks,
                flags=tuple(v.flags for v in per_view),
                images=fs.images if keep_images else (),
                shadows=tuple(v.shadow for v in per_view),
                landmarks=landmarks,
                view_landmarks=view_landmarks,
                agreement=tuple(agreement) if any(a is not None for a in agreement) else (),
                persons=persons,
                sightings=people,
                contrast=contrast,
                clothing=frame_clothing(
                    fs.images, masks, landmarks, view_landmarks, people, cameras, config
                )
                if view_landmarks
                else (),
            )
            if on_frame is not None:
                on_frame(out)
            yield out
    finally:
        views.close()
