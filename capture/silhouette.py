"""Silhouettes: clean-up of the raw background-subtraction mask, per-frame flags,
and the whole capture stage (session -> one silhouette per camera per kept frame).

Clean-up (:func:`clean_mask`), on the raw person mask of one image:

1. opening with a small disc (isolated noise pixels), then closing (joins parts
   split by thin misclassified seams);
2. connected components: the person is the largest blob plus the blobs near it
   (within ``join_distance`` of the person's bounding box, grown by a fraction
   of its height) that are not tiny: hands and feet cut off by a shadow-like seam;
3. holes smaller than ``max_hole_fraction`` of the person's area are filled
   when most of their pixels differ from the background (clothing taken for
   shadow); holes showing the unchanged background (the gap between an arm and
   the torso) stay open, as do large ones;
4. edge refinement (when the image and background are given): optical blur and
   4:2:0 chroma subsampling spread the person's colour 1-2 pixels into the
   background, so a noise-level threshold labels a band around the person too
   wide, and the darker mix of person and floor at the feet passes for shadow.
   Within ``edge_radius`` of the outline each pixel goes to whichever is nearer
   in colour: the background, or the person's local colour (the mean of the
   person's interior pixels in an ``edge_window`` square). That is the
   half-coverage point of a blurred edge; it raised the mean IoU on the demo
   recording from 0.93 to 0.96.

Flags per camera and frame (:data:`FLAGS`):

``empty``
    no blob of at least ``min_person_fraction`` of the image: nobody in view
    (the mask is then all False).
``border``
    the person touches the image border (cut off: its silhouette is incomplete).
``multiple``
    another large blob (at least ``other_blob_fraction`` of the person's area)
    away from the person: a second person or a moved object. Only the
    person's blob is kept.
``unreadable``
    the camera's video did not decode at that frame (mask all False).
``scene_change``
    the changed region covers more than ``max_person_fraction`` of the image:
    not a person but a lighting change, a moved camera, a covered or black lens
    (mask all False, so the view is left out of the fit).
``inconsistent``
    the multi-view check found that most of this view's silhouette is not
    where the other calibrated cameras see the subject (or the view found
    nobody where they do), even after looking again in the subject's box; only
    the part the other views confirm is kept.

Segmentation (:func:`segment_session`, :class:`CaptureConfig`): where a camera
has an empty-scene clip, background subtraction with shadow suppression gives
the silhouette's pixels, and the learned person segmenter
(:mod:`bodymetry.capture.person`) decides which blobs are the person (a
bystander or a moved chair is dropped). Where there is no clip, the segmenter's
mask is the silhouette. Then the multi-view check
(:mod:`bodymetry.capture.consistency`) removes what the calibrated cameras do
not agree on, and a view whose segmenter picked someone else is segmented again
in the box where the other views put the subject.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from bodymetry.calibration.camera import Camera
from bodymetry.capture.background import BackgroundModel, SubtractionConfig, Subtractor, read_clip
from bodymetry.capture.consistency import HullConfig, visual_hull
from bodymetry.capture.ingest import SyncReport, check_sync, read_frame_sets
from bodymetry.capture.landmarks import LandmarkConfig, triangulate_landmarks
from bodymetry.capture.person import (
    SEGMENTER_REQUIREMENT,
    PersonConfig,
    PersonSegmenter,
    segmenter_available,
)
from bodymetry.capture.session import Session
from bodymetry.errors import InputError
from bodymetry.fileio import write_bytes_atomic

log = logging.getLogger(__name__)

__all__ = [
    "CAPTURE_METHODS",
    "FLAGS",
    "CaptureConfig",
    "CleanupConfig",
    "SilhouetteFrame",
    "background_models",
    "clean_mask",
    "overlay",
    "refine_edges",
    "save_silhouette_frame",
    "segment_session",
]

FLAGS = ("empty", "border", "multiple", "unreadable", "scene_change", "inconsistent")

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
    """

    method: str = "auto"
    consistency: bool = True
    person: PersonConfig = field(default_factory=PersonConfig)
    hull: HullConfig = field(default_factory=HullConfig)
    landmarks: LandmarkConfig = field(default_factory=LandmarkConfig)

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
class CleanupConfig:
    """Parameters of :func:`clean_mask` (lengths in pixels at 640x480; they scale
    with the image diagonal).

    Attributes
    ----------
    open_radius, close_radius : int
        Disc radii of the opening and closing (0 = skip).
    min_person_fraction : float
        Smallest person, as a fraction of the image area (smaller: ``empty``).
    max_person_fraction : float
        Largest changed region that can be a person, as a fraction of the image
        area (larger: ``scene_change``). A person filling a portrait frame from
        head to foot covers about a third of it.
    join_distance : float
        Blobs within this fraction of the person's height of its bounding box join it.
    min_part_pixels : int
        Smaller blobs never join (noise).
    other_blob_fraction : float
        A blob away from the person with at least this fraction of its area
        raises ``multiple``.
    max_hole_fraction : float
        Holes smaller than this fraction of the person's area are filled.
    edge_radius : int
        Half-width of the band around the outline that edge refinement decides
        (0 = no refinement).
    edge_window : int
        Side of the square over which the person's local colour is averaged.
    """

    open_radius: int = 1
    close_radius: int = 1
    min_person_fraction: float = 0.002
    max_person_fraction: float = 0.6
    join_distance: float = 0.08
    min_part_pixels: int = 12
    other_blob_fraction: float = 0.25
    max_hole_fraction: float = 0.02
    edge_radius: int = 2
    edge_window: int = 7

    def __post_init__(self) -> None:
        if self.open_radius < 0 or self.close_radius < 0:
            raise InputError("open_radius and close_radius must be >= 0")
        if not 0 < self.min_person_fraction < self.max_person_fraction <= 1:
            raise InputError(
                "min_person_fraction, max_person_fraction: expected 0 < min < max <= 1, got "
                f"{self.min_person_fraction}, {self.max_person_fraction}"
            )


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
        Flags per camera (:data:`FLAGS`).
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
    """

    frame: int
    cameras: tuple[str, ...]
    masks: tuple[np.ndarray, ...]
    flags: tuple[tuple[str, ...], ...]
    images: tuple[np.ndarray | None, ...] = field(default=(), repr=False)
    shadows: tuple[np.ndarray, ...] = field(default=(), repr=False)
    landmarks: np.ndarray | None = field(default=None, repr=False)
    view_landmarks: tuple[np.ndarray | None, ...] = field(default=(), repr=False)

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


def _disc(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def _scaled(value: float, shape: tuple[int, ...]) -> int:
    return round(value * np.hypot(shape[0], shape[1]) / 800.0)


def clean_mask(
    raw: np.ndarray,
    config: CleanupConfig | None = None,
    image: np.ndarray | None = None,
    background: np.ndarray | None = None,
    shadow: np.ndarray | None = None,
    person: np.ndarray | None = None,
) -> tuple[np.ndarray, tuple[str, ...]]:
    """Clean a raw person mask and flag it.

    Parameters
    ----------
    raw : (H, W) bool
    config : CleanupConfig
    image : (H, W, 3) uint8, optional
        The image, for edge refinement.
    background : (H, W, 3) float, optional
        Its background colour (:attr:`BackgroundModel.median`), for edge refinement.
    shadow : (H, W) bool, optional
        Pixels the subtraction labelled cast shadow: edge refinement does not add
        them, and holes are filled only when mostly shadow-labelled (without it,
        every hole up to ``max_hole_fraction`` is filled).
    person : (H, W) bool, optional
        Where a learned segmenter sees the person: blobs that do not touch it
        (a bystander, a moved object) are dropped before the person is chosen.

    Returns
    -------
    mask : (H, W) bool
        The person's blob(s), holes filled.
    flags : tuple of str
        Subset of ``("empty", "border", "multiple", "scene_change")``.
    """
    cfg = config or CleanupConfig()
    raw = np.asarray(raw)
    if raw.ndim != 2:
        raise InputError(f"mask: expected (H, W), got {raw.shape}")
    h, w = raw.shape
    m = raw.astype(np.uint8)
    r_open = _scaled(cfg.open_radius, raw.shape) if cfg.open_radius else 0
    r_close = max(_scaled(cfg.close_radius, raw.shape), 1) if cfg.close_radius else 0
    if r_open:
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, _disc(r_open))
    if r_close:
        m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, _disc(r_close))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    empty = np.zeros((h, w), bool)
    if n <= 1:
        return empty, ("empty",)
    areas = stats[1:, cv2.CC_STAT_AREA].copy()
    if person is not None:
        touches = np.zeros(n, bool)
        touches[np.unique(labels[person & (m > 0)])] = True
        areas[~touches[1:]] = 0  # never the person, never "multiple"
        if not areas.any():
            return empty, ("empty",)
    order = np.argsort(-areas)
    main = int(order[0]) + 1
    if stats[main, cv2.CC_STAT_AREA] < cfg.min_person_fraction * h * w:
        return empty, ("empty",)
    if m.sum() > cfg.max_person_fraction * h * w:
        return empty, ("scene_change",)
    x0, y0, bw, bh = (int(v) for v in stats[main, :4])
    grow = cfg.join_distance * bh
    keep = [main]
    flags: list[str] = []
    for idx in order[1:]:
        lab = int(idx) + 1
        area = int(areas[idx])
        if area < cfg.min_part_pixels:
            break
        bx, by, bbw, bbh = (int(v) for v in stats[lab, :4])
        gap_x = max(x0 - (bx + bbw), bx - (x0 + bw), 0)
        gap_y = max(y0 - (by + bbh), by - (y0 + bh), 0)
        near = max(gap_x, gap_y) <= grow
        large = area >= cfg.other_blob_fraction * stats[main, cv2.CC_STAT_AREA]
        if (
            large
            and area >= cfg.min_person_fraction * h * w
            and not _overlaps(stats[main], stats[lab])
        ):
            flags.append("multiple")
            continue
        if near:
            keep.append(lab)
    mask = np.isin(labels, keep)
    changed = None if shadow is None else (raw | shadow)
    mask = _fill_holes(mask, cfg.max_hole_fraction * mask.sum(), changed, cfg.min_part_pixels)
    if image is not None and background is not None and cfg.edge_radius > 0:
        mask = refine_edges(
            image,
            background,
            mask,
            max(_scaled(cfg.edge_radius, raw.shape), 1),
            max(_scaled(cfg.edge_window, raw.shape) | 1, 3),
            shadow,
        )
    if mask[0, :].any() or mask[-1, :].any() or mask[:, 0].any() or mask[:, -1].any():
        flags.append("border")
    return mask, tuple(dict.fromkeys(flags))


def refine_edges(
    image: np.ndarray,
    background: np.ndarray,
    mask: np.ndarray,
    radius: int = 2,
    window: int = 7,
    shadow: np.ndarray | None = None,
) -> np.ndarray:
    """Re-decide the pixels within ``radius`` of the outline of ``mask`` by colour.

    A pixel of the band is person when its colour is nearer the person's local
    colour (mean over the interior in a ``window`` square) than the
    background's. The band is decided twice: first with the interior of
    ``mask``, then with the interior of that first answer. The change threshold
    makes ``mask`` too wide (about 0.9 px on the demo), so the first interior
    still holds edge pixels mixed with the background by the optical blur; that
    pulls the person's colour towards the background and moves the decision
    outwards (a person pixel needs less than half the pixel). The second pass
    takes the colour from pixels a pixel inside the refined outline (where that
    leaves none in the window, as on a hand, the first answer stands): on the
    demo the torso's outline moves from +0.18 to +0.10 px outside the true one,
    the hands' from -0.39 and -0.24 to -0.45 and -0.31 px, with the same IoU
    (``docs/capture.md``, "Edge refinement"). Pixels labelled shadow outside the
    mask stay out (the feet touch their shadow: adding them measurably raised
    the shadow false positives, 0.2 % -> 2 % on the demo recording). Works on
    the bounding box of the band only.

    Parameters
    ----------
    image : (H, W, 3) uint8
    background : (H, W, 3) float
    mask : (H, W) bool
    radius, window : int
        Band half-width and averaging window, pixels.
    shadow : (H, W) bool, optional
        Shadow-labelled pixels (never added).

    Returns
    -------
    (H, W) bool
    """
    ys, xs = np.nonzero(mask)
    if ys.size == 0:
        return mask
    h, w = mask.shape
    pad = radius + window
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, h)
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, w)
    inside = mask[y0:y1, x0:x1]
    m = inside.astype(np.uint8)
    img = image[y0:y1, x0:x1].astype(np.float32)
    d_background = ((img - background[y0:y1, x0:x1]) ** 2).sum(axis=2)
    disc = _disc(radius)
    band = (cv2.dilate(m, disc) > 0) & ~(cv2.erode(m, disc) > 0)
    allowed = True if shadow is None else ~(shadow[y0:y1, x0:x1] & ~inside)
    first, has_interior = _nearer_person(img, d_background, inside, window)
    first &= has_interior & allowed
    second, has_interior = _nearer_person(img, d_background, np.where(band, first, inside), window)
    # Where the refined interior leaves no pixel in the window (a hand, a wrist),
    # the first answer stands.
    second = np.where(has_interior, second & allowed, first)
    out = mask.copy()
    out[y0:y1, x0:x1] = np.where(band, second, inside)
    return out


def _nearer_person(
    img: np.ndarray, d_background: np.ndarray, person: np.ndarray, window: int
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels whose colour is nearer the mean of ``person``'s interior (its pixels a
    pixel from its outline or deeper) in a ``window`` square than the background.

    Parameters
    ----------
    img : (h, w, 3) float32
    d_background : (h, w) float
        Squared colour distance of each pixel to the background.
    person : (h, w) bool
    window : int

    Returns
    -------
    nearer : (h, w) bool
    has_interior : (h, w) bool
        The window holds an interior pixel (``nearer`` means nothing elsewhere).
    """
    inner = cv2.erode(person.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(np.float32)
    weight = cv2.boxFilter(inner, -1, (window, window), normalize=False)
    local = cv2.boxFilter(img * inner[..., None], -1, (window, window), normalize=False)
    local /= np.maximum(weight, 1e-6)[..., None]
    d_person = ((img - local) ** 2).sum(axis=2)
    return d_person < d_background, weight > 0


def _overlaps(a: np.ndarray, b: np.ndarray) -> bool:
    """Bounding boxes (x, y, w, h, ...) overlap."""
    return not (
        a[0] + a[2] <= b[0] or b[0] + b[2] <= a[0] or a[1] + a[3] <= b[1] or b[1] + b[3] <= a[1]
    )


def _fill_holes(
    mask: np.ndarray,
    max_area: float,
    changed: np.ndarray | None = None,
    always_area: int = 0,
) -> np.ndarray:
    """Fill background regions enclosed by ``mask`` of at most ``max_area`` pixels.

    With ``changed`` (pixels that differ from the background: raw person or
    shadow), a hole larger than ``always_area`` is filled only when most of its
    pixels changed: a gap between arm and torso shows the unchanged background
    and stays open; a patch of clothing taken for shadow is filled.
    """
    ys, xs = np.nonzero(mask)
    if ys.size == 0:
        return mask
    # Work on the bounding box grown by a pixel: its border is outside the mask.
    h, w = mask.shape
    y0, y1 = max(ys.min() - 1, 0), min(ys.max() + 2, h)
    x0, x1 = max(xs.min() - 1, 0), min(xs.max() + 2, w)
    crop = mask[y0:y1, x0:x1]
    padded = np.pad(~crop, 1, constant_values=True).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(padded, connectivity=4)
    area = stats[:, cv2.CC_STAT_AREA]
    holes = area <= max_area
    holes[0] = False  # the mask itself (label 0 = zeros of ``padded``)
    holes[labels[0, 0]] = False  # the outside
    if changed is not None and holes.any():
        inside = labels[1:-1, 1:-1]
        hits = np.bincount(inside[changed[y0:y1, x0:x1]], minlength=n)
        holes &= (area <= always_area) | (2 * hits >= area)
    if not holes.any():
        return mask
    out = mask.copy()
    out[y0:y1, x0:x1] |= holes[labels[1:-1, 1:-1]]
    return out


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


@dataclass
class _View:
    """One camera's silhouette of one frame, while the frame is segmented."""

    mask: np.ndarray
    flags: tuple[str, ...]
    shadow: np.ndarray
    landmarks: np.ndarray | None = None


class _Views:
    """Segments the views of one frame: the per-camera silhouette, then the
    multi-view check and the landmarks in 3D (module docstring, "Segmentation")."""

    def __init__(
        self,
        models: Sequence[BackgroundModel | None],
        sizes: Sequence[tuple[int, int]],
        config: CaptureConfig,
        subtraction: SubtractionConfig | None,
        cleanup: CleanupConfig | None,
        cameras: Sequence[Camera] | None,
    ) -> None:
        self.models = list(models)
        self.sizes = list(sizes)
        self.cleanup = cleanup
        self.config = config
        self.cameras = None if cameras is None else list(cameras)
        self.subtractors = [None if m is None else Subtractor(m, subtraction) for m in models]
        self.segmenter = PersonSegmenter(config.person) if config.uses_segmenter else None
        self.hull = None
        if cameras is not None and config.consistency and len(cameras) >= config.hull.min_views:
            try:
                self.hull = visual_hull(cameras, config.hull)
            except InputError as exc:
                log.warning("%s; silhouettes are not checked across views", exc)

    def _one(
        self, c: int, image: np.ndarray | None, roi: tuple[int, int, int, int] | None = None
    ) -> _View:
        w, h = self.sizes[c]
        none = np.zeros((h, w), bool)
        if image is None:
            return _View(none, ("unreadable",), none)
        person = None if self.segmenter is None else self.segmenter.detect(image, roi)
        found = None if person is None else person.mask(self.config.person.threshold)
        landmarks = None if person is None else person.landmarks
        model = self.models[c]
        if model is None:  # no background: the segmenter's person is the silhouette
            if found is None:
                return _View(none, ("empty",), none)
            mask, flags = clean_mask(found, self.cleanup)
            return _View(mask, flags, none, landmarks)
        raw, shadow = self.subtractors[c].labels(image)
        mask, flags = clean_mask(raw, self.cleanup, image, model.median, shadow, found)
        return _View(mask, flags, shadow, landmarks)

    def __call__(
        self, images: Sequence[np.ndarray | None]
    ) -> tuple[list[_View], np.ndarray | None]:
        """Per camera the view, and the (33, 3) world landmarks (None without a segmenter
        or cameras)."""
        views = [self._one(c, image) for c, image in enumerate(images)]
        if self.hull is not None:
            check = self.hull.check([v.mask for v in views])
            if self.segmenter is not None and any(check.inconsistent):
                # Ask again where the other views put the subject (the segmenter
                # returns the most prominent person, maybe a bystander).
                retry = [
                    c for c, bad in enumerate(check.inconsistent)
                    if bad and check.rois[c] is not None and images[c] is not None
                ]  # fmt: skip
                for c in retry:
                    views[c] = self._one(c, images[c], check.rois[c])
                if retry:
                    check = self.hull.check([v.mask for v in views])
            for view, mask, bad in zip(views, check.masks, check.inconsistent, strict=True):
                view.mask = mask
                if bad:
                    view.flags = (*view.flags, "inconsistent")
                    view.landmarks = None
        landmarks = None
        if self.cameras is not None and sum(v.landmarks is not None for v in views) >= 2:
            landmarks = triangulate_landmarks(
                self.cameras, [v.landmarks for v in views], self.config.landmarks
            )
        return views, landmarks

    def close(self) -> None:
        if self.segmenter is not None:
            self.segmenter.close()


def segment_session(
    session: Session,
    *,
    config: CaptureConfig | None = None,
    cameras: Sequence[Camera] | None = None,
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
    cameras : sequence of Camera, optional
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
    views = _Views(models, [v.size for v in report.videos], config, subtraction, cleanup, cameras)
    try:
        for fs in _prefetch(read_frame_sets(session, report, frames=frames, method=read_method)):
            per_view, landmarks = views(fs.images)
            out = SilhouetteFrame(
                frame=fs.frame,
                cameras=fs.cameras,
                masks=tuple(v.mask for v in per_view),
                flags=tuple(v.flags for v in per_view),
                images=fs.images if keep_images else (),
                shadows=tuple(v.shadow for v in per_view),
                landmarks=landmarks,
                view_landmarks=tuple(v.landmarks for v in per_view)
                if views.segmenter is not None
                else (),
            )
            if on_frame is not None:
                on_frame(out)
            yield out
    finally:
        views.close()


# --------------------------------------------------------------------------
# Output for inspection
# --------------------------------------------------------------------------
#: Overlay colours (BGR): person tint and outline, suppressed shadow tint.
_PERSON_BGR = np.array([60, 200, 60], np.float32)
_SHADOW_BGR = np.array([220, 120, 0], np.float32)


def overlay(
    image: np.ndarray | None,
    mask: np.ndarray,
    shadow: np.ndarray | None = None,
    flags: Sequence[str] = (),
) -> np.ndarray:
    """An inspection image: the person tinted green with its outline, pixels
    suppressed as shadow tinted blue, flags written in the corner.

    Parameters
    ----------
    image : (H, W, 3) uint8 or None (unreadable: a grey image)
    mask, shadow : (H, W) bool
    flags : sequence of str

    Returns
    -------
    (H, W, 3) uint8 BGR
    """
    h, w = mask.shape
    out = np.full((h, w, 3), 64, np.uint8) if image is None else image.copy()
    if shadow is not None and shadow.any():
        s = shadow & ~mask
        out[s] = (0.55 * out[s] + 0.45 * _SHADOW_BGR).astype(np.uint8)
    if mask.any():
        out[mask] = (0.6 * out[mask] + 0.4 * _PERSON_BGR).astype(np.uint8)
        contours, _ = cv2.findContours(
            mask.astype(np.uint8), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE
        )
        cv2.drawContours(out, contours, -1, (0, 255, 0), 1, cv2.LINE_AA)
    if flags:
        text = ", ".join(flags)
        scale = max(h / 960.0, 0.4)
        # A dark outline under the text keeps it readable on any background.
        for color, thickness in (((0, 0, 0), 3), ((0, 220, 255), 1)):
            cv2.putText(
                out,
                text,
                (6, int(44 * scale)),
                cv2.FONT_HERSHEY_SIMPLEX,
                scale,
                color,
                thickness,
                cv2.LINE_AA,
            )
    return out


def save_silhouette_frame(out: str | Path, sf: SilhouetteFrame, overlays: bool = True) -> None:
    """Write ``masks/<camera>/<frame:06d>.png`` (0 / 255) and, with ``overlays``,
    ``overlays/<camera>/<frame:06d>.jpg`` under ``out`` (atomically per file)."""

    out = Path(out)
    for c, name in enumerate(sf.cameras):
        ok, png = cv2.imencode(".png", sf.masks[c].astype(np.uint8) * 255)
        if not ok:  # pragma: no cover - OpenCV failure
            raise RuntimeError("PNG encoding failed")
        write_bytes_atomic(out / "masks" / name / f"{sf.frame:06d}.png", png.tobytes())
        if overlays:
            image = sf.images[c] if sf.images else None
            shadow = sf.shadows[c] if sf.shadows else None
            ok, jpg = cv2.imencode(
                ".jpg",
                overlay(image, sf.masks[c], shadow, sf.flags[c]),
                [cv2.IMWRITE_JPEG_QUALITY, 90],
            )
            if not ok:  # pragma: no cover
                raise RuntimeError("JPEG encoding failed")
            write_bytes_atomic(out / "overlays" / name / f"{sf.frame:06d}.jpg", jpg.tobytes())
