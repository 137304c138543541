"""Skin and clothing per pixel (issue 31, beyond the paper).

A clothed silhouette is an upper bound of the body where it is clothing or hair
and its outline where it is skin (Balan & Black, "The Naked Truth", ECCV 2008).
This module tells the two apart in one view from the image itself: the colour
of a person's skin is learned from their own face and hands, which the
segmenter's landmarks place (:attr:`bodymetry.capture.person.Person.landmarks`),
and every pixel of their silhouette is called skin when its colour lies within
``max_distance`` standard deviations of it.

The colour model is a Gaussian over CIE L*a*b* chroma ``(a*, b*)`` with the
lightness's spread added at a lower weight: shading on skin changes its
lightness far more than its chroma, while dark hair and shoes differ from skin
mostly in lightness and saturated clothes mostly in chroma. The seeds are the
person's pixels in discs around the face landmarks (nose, eyes, ears, mouth)
and the hand landmarks (knuckles and thumb), scaled by the view's torso length
(mid-shoulder to mid-hip); hair and cuffs inside those discs are trimmed away
by keeping the ``trim`` share of seeds nearest their median colour.

What is not skin inside the silhouette is clothing (or hair, shoes, anything
worn): :func:`clothing_masks`. The colour's spread is learned from the seeds
of all views of a frame together, its centre per view where the view has
seeds enough (cameras differ in white balance and exposure); a view that sees
the back of the head seeds from the hands only (:func:`facing`). With too few
seeds anywhere there is no model and nothing is called clothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = [
    "FACE",
    "HANDS",
    "SkinConfig",
    "SkinModel",
    "clothing_masks",
    "colour_coords",
    "facing",
    "hand_skin",
    "landmark_discs",
    "seed_mask",
    "skin_models",
    "skin_toned",
]

#: BlazePose landmarks on the face (nose, eyes, ears, mouth corners).
FACE = tuple(range(11))
#: BlazePose landmarks on the hands (pinky and index knuckles, thumbs).
HANDS = (17, 18, 19, 20, 21, 22)
#: The wrists and the hand landmarks.
WRISTS_HANDS = (15, 16, *HANDS)
#: :func:`hand_skin`'s radius around each wrist and hand landmark, a share of the
#: torso length: a hand's length from the wrist, and half a hand's width beyond it
#: (studio seed 42 reaching, arm span error: 0.12: -15.5 mm, 0.2: -10.7 mm, none:
#: -21.9 mm; docs/capture.md, "Hands before the floor").
HAND_REACH = 0.2
#: A view's own skin colour is used where it lies within this many times
#: ``max_distance`` of the frame's (a camera's white balance and exposure move it
#: by more than the skin's spread within one view; seeds on cloth by far more).
RECENTRE = 2.0
#: Seed colours with less chroma (CIE a*b*) than this, or a hue angle outside
#: SKIN_HUE (degrees), are not skin (black, grey and white cloth, blue jeans).
MIN_CHROMA = 6.0
SKIN_HUE = (15.0, 95.0)
#: Shoulders and hips (the torso length that scales the seed discs).
_SHOULDERS, _HIPS = (11, 12), (23, 24)


@dataclass(frozen=True)
class SkinConfig:
    """How skin is told from clothing (:func:`clothing_masks`).

    Attributes
    ----------
    enabled : bool
        Off: no clothing masks (every outline is taken as the body's).
    face_radius, hand_radius : float
        Seed discs around each face and hand landmark, as a share of the
        view's torso length (mid-shoulder to mid-hip).
    min_visibility : float
        Landmarks the segmenter sees less surely than this seed nothing.
    min_seeds : int
        Fewer seed pixels in a view: no colour model there.
    trim : float
        Share of the seeds kept, those nearest their median colour (hair,
        eyebrows and cuffs inside the discs are the rest).
    lightness_weight : float
        Weight of the lightness in the colour distance relative to the
        chroma's (below 1: shading counts less than hue).
    max_distance : float
        A pixel within this many standard deviations of the skin colour is
        skin, if its chroma is one skin can have at all (:data:`MIN_CHROMA`,
        :data:`SKIN_HUE`): the spread within one view's seeds is narrow, and
        the same skin in shade or in a window's light lies several of them off.
    """

    enabled: bool = True
    face_radius: float = 0.12
    hand_radius: float = 0.06
    min_visibility: float = 0.5
    min_seeds: int = 40
    trim: float = 0.6
    lightness_weight: float = 0.15
    max_distance: float = 5.0

    def __post_init__(self) -> None:
        for name in ("face_radius", "hand_radius", "max_distance"):
            if getattr(self, name) <= 0:
                raise ValueError(f"skin.{name}: expected > 0, got {getattr(self, name)}")
        for name in ("min_visibility", "lightness_weight"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"skin.{name}: expected in [0, 1], got {getattr(self, name)}")
        if not 0 < self.trim <= 1:
            raise ValueError(f"skin.trim: expected in (0, 1], got {self.trim}")
        if self.min_seeds < 3:
            raise ValueError(f"skin.min_seeds: expected >= 3, got {self.min_seeds}")


@dataclass(frozen=True)
class SkinModel:
    """A person's skin colour in one view: a Gaussian over weighted L*a*b*.

    Attributes
    ----------
    mean : (3,) float
        ``(w L*, a*, b*)``, with ``w`` the config's ``lightness_weight``.
    inverse : (3, 3) float
        Inverse covariance of the same coordinates.
    """

    mean: np.ndarray
    inverse: np.ndarray

    def distance(self, coords: np.ndarray) -> np.ndarray:
        """Mahalanobis distances (...,) of colour coordinates (..., 3) (:func:`colour_coords`)."""
        x = coords - self.mean
        return np.sqrt(np.maximum(np.einsum("...i,ij,...j->...", x, self.inverse, x), 0.0))


def colour_coords(image: np.ndarray, lightness_weight: float) -> np.ndarray:
    """(H, W, 3) float32 ``(w L*, a*, b*)`` of a BGR uint8 image."""
    lab = cv2.cvtColor(image.astype(np.float32) / 255.0, cv2.COLOR_BGR2Lab)
    lab[..., 0] *= lightness_weight
    return lab


def _torso_length(landmarks: np.ndarray) -> float:
    """Mid-shoulder to mid-hip in pixels (NaN when either pair is missing)."""
    shoulders = landmarks[list(_SHOULDERS), :2].mean(axis=0)
    hips = landmarks[list(_HIPS), :2].mean(axis=0)
    return float(np.linalg.norm(shoulders - hips))


def facing(landmarks: np.ndarray, centre: np.ndarray) -> bool:
    """Whether a camera at ``centre`` (3,) sees the face of a person whose world
    landmarks are ``landmarks`` (33, 3): the nose lies on its side of the ears'
    midpoint (seen from behind, the face landmarks fall on hair). Unknown (a
    landmark missing): False."""
    nose, ears = landmarks[0], landmarks[[7, 8]].mean(axis=0)
    if not (np.isfinite(nose).all() and np.isfinite(ears).all()):
        return False
    return float(np.dot(nose - ears, np.asarray(centre, float) - ears)) > 0


def landmark_discs(
    shape: tuple[int, int],
    landmarks: np.ndarray,
    ids: Sequence[int],
    share: float,
    min_visibility: float = 0.5,
) -> np.ndarray:
    """(H, W) bool: discs around some of a person's landmarks in one view.

    Parameters
    ----------
    shape : (H, W)
    landmarks : (33, 3) float
        The person's landmarks in this view (pixel x, pixel y, visibility).
    ids : sequence of int
        Which landmarks (e.g. :data:`FACE`, :data:`HANDS`).
    share : float
        The discs' radius as a share of the view's torso length (mid-shoulder to
        mid-hip), so that it follows the person's size in the image.
    min_visibility : float
        Landmarks seen less surely than this draw nothing.

    Returns
    -------
    (H, W) bool
        All False when the torso length is unknown (a shoulder or hip missing).
    """
    marks = np.asarray(landmarks, float)
    discs = np.zeros(shape, np.uint8)
    torso = _torso_length(marks)
    if not np.isfinite(torso) or torso < 1:
        return discs > 0
    radius = max(1, round(share * torso))
    for x, y, seen in marks[list(ids)]:
        if np.isfinite(x) and np.isfinite(y) and seen >= min_visibility:
            cv2.circle(discs, (round(x), round(y)), radius, 1, -1)
    return discs > 0


def hand_skin(image: np.ndarray, landmarks: np.ndarray, reach: float = HAND_REACH) -> np.ndarray:
    """(H, W) bool: pixels near a person's hands whose colour skin can have.

    Background subtraction weighs chroma down (4:2:0 video spreads a garment's
    chroma into the gaps beside it, :mod:`bodymetry.capture.colour`), but a hand
    before a beige floor or a wooden wall differs from it more in chroma than in
    lightness: here its change keeps the full colour. Only the pixels within
    ``reach`` of the torso length of a visible wrist or hand landmark and with a
    chroma skin has (:func:`skin_toned`) are marked; a grey gap between a hand
    and the thigh has too little chroma to be one of them.

    Parameters
    ----------
    image : (H, W, 3) uint8 BGR
    landmarks : (33, 3) float
        The person's landmarks in this image (pixel x, pixel y, visibility).
    reach : float
        Radius around each landmark, a share of the torso length.
    """
    near = landmark_discs(image.shape[:2], landmarks, WRISTS_HANDS, reach)
    # Only the discs' pixels are converted (as one row): with the arms held out, the
    # box around both hands would span the whole trunk between them.
    if near.any():
        near[near] = skin_toned(colour_coords(image[near][None], 1.0)[0])
    return near


def seed_mask(
    shape: tuple[int, int],
    person: np.ndarray,
    landmarks: Sequence[tuple[np.ndarray, bool]],
    config: SkinConfig,
) -> np.ndarray:
    """The pixels of one view a skin colour is learned from.

    Parameters
    ----------
    shape : (H, W)
    person : (H, W) bool
        The people's silhouette in this view.
    landmarks : sequence of ((33, 3) float, bool)
        Each person's landmarks in this view (pixel x, pixel y, visibility),
        and whether the view sees their face (:func:`facing`): the hands seed
        either way, the face only when seen.
    config : SkinConfig

    Returns
    -------
    (H, W) bool
        Discs around the surely seen face and hand landmarks, inside the
        silhouette eroded by one pixel (its outline mixes in the background).
    """
    discs = np.zeros(shape, bool)
    for marks, face in landmarks:
        parts = ((FACE, config.face_radius),) if face else ()
        for ids, share in (*parts, (HANDS, config.hand_radius)):
            discs |= landmark_discs(shape, marks, ids, share, config.min_visibility)
    inner = cv2.erode(np.asarray(person, np.uint8), np.ones((3, 3), np.uint8))
    return discs & (inner > 0)


def skin_toned(coords: np.ndarray) -> np.ndarray:
    """(...,) bool: which colour coordinates (..., 3) have a chroma skin can have.

    Human skin of every tone lies in a narrow band of warm hues (a* and b* both
    positive, hue angle within :data:`SKIN_HUE`) with at least :data:`MIN_CHROMA`;
    black, grey and white cloth has almost none (a hand held against black
    shorts seeds them too)."""
    a, b = coords[..., 1], coords[..., 2]
    hue = np.degrees(np.arctan2(b, a))
    return (np.hypot(a, b) >= MIN_CHROMA) & (hue >= SKIN_HUE[0]) & (hue <= SKIN_HUE[1])


def _trimmed(samples: np.ndarray, trim: float) -> np.ndarray:
    """The ``trim`` share of colour samples (N, 3) nearest their median."""
    if len(samples) < 3:
        return samples
    spread = np.linalg.norm(samples - np.median(samples, axis=0), axis=1)
    return samples[spread <= np.quantile(spread, trim)]


def _gaussian(centre: np.ndarray, offsets: np.ndarray, trim: float) -> SkinModel:
    """A :class:`SkinModel` about ``centre`` with the covariance of ``offsets`` (N, 3)."""
    # The trimmed set's covariance understates the full one; a small floor on the
    # diagonal keeps a flat-coloured face (a studio render) from a singular model.
    cov = offsets.T @ offsets / max(len(offsets) - 1, 1) / trim + np.eye(3) * 1e-2
    return SkinModel(np.asarray(centre, float), np.linalg.inv(cov))


def skin_models(samples: Sequence[np.ndarray], config: SkinConfig) -> list[SkinModel | None]:
    """Per view, the skin colour of a frame from each view's seed colours.

    Parameters
    ----------
    samples : sequence of C (N_c, 3) float
        Each view's seed colours (:func:`colour_coords` at :func:`seed_mask`);
        those no skin has (:func:`skin_toned`) are dropped first.
    config : SkinConfig

    Returns
    -------
    list of C (SkinModel or None)
        All None with fewer than ``min_seeds`` seeds in all. Each view's seeds
        are trimmed to the ``trim`` share nearest their median (hair, cuffs and
        cloth inside the discs). The centre is a view's own median where it has
        ``min_seeds`` seeds lying within :data:`RECENTRE` times ``max_distance``
        of the median of all (cameras differ in white balance and exposure;
        seeds further off are mostly something else, a hand held against the
        trousers), else the median of all; the spread is that of the other
        views' seeds about their own median (so the cameras' differences do
        not widen it, nor seeds on cloth).
    """
    toned = [np.asarray(x, float).reshape(-1, 3) for x in samples]
    kept = [_trimmed(x[skin_toned(x)], config.trim) for x in toned]
    everything = np.concatenate(kept) if kept else np.empty((0, 3))
    if len(everything) < config.min_seeds:
        return [None] * len(kept)
    overall = np.median(everything, axis=0)
    own = [np.median(x, axis=0) if len(x) >= config.min_seeds else overall for x in kept]
    # The spread of skin within one view (about its own centre): the cameras'
    # differences do not widen it, and neither does a view whose seeds are all
    # something else.
    within = np.concatenate([x - c for x, c in zip(kept, own, strict=True)])
    frame = _gaussian(overall, within, config.trim)
    near = [float(frame.distance(c)) <= RECENTRE * config.max_distance for c in own]
    centres = [c if ok else overall for c, ok in zip(own, near, strict=True)]
    # A view whose seeds lie far off neither centres nor widens the colour.
    close = [x - c for x, c, ok in zip(kept, own, near, strict=True) if ok]
    offsets = np.concatenate(close) if close else everything - overall
    return [_gaussian(c, offsets, config.trim) for c in centres]


def clothing_masks(
    images: Sequence[np.ndarray | None],
    persons: Sequence[np.ndarray],
    landmarks: Sequence[Sequence[tuple[np.ndarray, bool]]],
    config: SkinConfig | None = None,
) -> list[np.ndarray | None]:
    """Per view, the silhouette's pixels that are not skin (clothing, hair, shoes).

    The skin colour's spread is learned from the seeds of every view together
    (:func:`seed_mask`); its centre from each view's own seeds where it has
    ``min_seeds`` of them (cameras differ in white balance and exposure), else
    from all of them.

    Parameters
    ----------
    images : sequence of C ((H_c, W_c, 3) uint8 or None)
        The views' images, BGR (None: unreadable).
    persons : sequence of C (H_c, W_c) bool
        The people's silhouette per view.
    landmarks : sequence of C sequences of ((33, 3) float, bool)
        Per view, each person's landmarks there and whether it sees their face.
    config : SkinConfig, optional

    Returns
    -------
    list of C ((H_c, W_c) bool or None)
        None where the view has no image or silhouette, and everywhere when no
        colour model could be learned (too few seed pixels, or
        ``config.enabled`` off). Specks of either class smaller than 3x3 px
        are given to the other.

    Raises
    ------
    ValueError
        When the inputs are not one per view, or an image and its silhouette
        differ in size.
    """
    config = config or SkinConfig()
    if not len(images) == len(persons) == len(landmarks):
        raise ValueError(
            f"clothing_masks: {len(images)} images, {len(persons)} silhouettes and "
            f"{len(landmarks)} landmark sets; expected one of each per view"
        )
    out: list[np.ndarray | None] = [None] * len(images)
    if not config.enabled:
        return out
    boxes, coords, samples = [], [], []
    for image, person, marks in zip(images, persons, landmarks, strict=True):
        person = np.asarray(person, bool)
        if image is None or not person.any():
            boxes.append(None)
            coords.append(None)
            samples.append(np.empty((0, 3)))
            continue
        if image.shape[:2] != person.shape:
            raise ValueError(
                f"image {image.shape[:2]} and silhouette {person.shape} differ in size"
            )
        # Only the silhouette's box is converted and classified (a 2-megapixel view
        # holds a person in a tenth of it).
        box = _box(person)
        boxes.append(box)
        coords.append(colour_coords(image[box], config.lightness_weight))
        samples.append(coords[-1][seed_mask(person.shape, person, marks, config)[box]])
    models = skin_models(samples, config)
    kernel = np.ones((3, 3), np.uint8)
    for c, (box, lab, person, model) in enumerate(zip(boxes, coords, persons, models, strict=True)):
        if lab is None or model is None:
            continue
        person = np.asarray(person, bool)
        inside = person[box]
        skin = (model.distance(lab) <= config.max_distance) & skin_toned(lab) & inside
        skin = cv2.morphologyEx(skin.astype(np.uint8), cv2.MORPH_OPEN, kernel) > 0
        worn = cv2.morphologyEx((inside & ~skin).astype(np.uint8), cv2.MORPH_OPEN, kernel) > 0
        out[c] = np.zeros_like(person)
        out[c][box] = worn & inside
    return out


def _box(mask: np.ndarray) -> tuple[slice, slice]:
    """The rows and columns of a non-empty mask's bounding box, a pixel wider on
    every side (the clean-up's 3x3 opening sees the border as outside)."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    h, w = mask.shape
    return (
        slice(max(rows[0] - 1, 0), min(rows[-1] + 2, h)),
        slice(max(cols[0] - 1, 0), min(cols[-1] + 2, w)),
    )
