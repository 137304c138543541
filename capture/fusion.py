"""Evidence fusion: one person probability per pixel from every source the frame has.

Background subtraction, its shadow label, the learned segmenter and the
multi-view hull each see the person differently, and each fails differently: a
grey shirt in front of a grey wall barely changes the image, and its shaded
side has the wall's chromaticity (the colour test calls it cast shadow); the
segmenter finds the shirt but blurs the outline and sometimes picks a
bystander; the hull knows where the cameras agree in 3D but is coarse. So
instead of choosing one, every pixel gets the sum of their log-odds
(naive-Bayes fusion, i.e. a logistic model over the per-pixel evidence):

.. math::

    \\log\\frac{p}{1-p} = b + w_c\\,c + w_s\\,s + w_p\\,\\ell + w_h\\,h_{body} + w_a\\,h_{any}

with

``c`` (*change*)
    ``clip(log(d / fg_sigma), -2, 2)``: the colour distance ``d`` to the
    background in noise units, relative to the change threshold (0 at the
    threshold, positive above).
``s`` (*shadow*)
    1 where the colour test labels the pixel cast shadow (darker, same
    chromaticity: :mod:`bodymetry.capture.background`), else 0.
``f`` (*floor shadow*)
    1 where the colour test says shadow and the geometry agrees it can be a
    shadow on the floor: another camera sees the pixel's floor point as dark,
    and as dim relative to the empty scene, and none sees it as lit background
    (:mod:`bodymetry.capture.shadows`). A shadow label the geometry
    refutes (``s`` without ``f``) is an achromatic garment's shaded side.
``l`` (*segmenter*)
    ``clip(logit(p), -4, 4)`` of the segmenter's probability ``p``.
``h_body`` (*hull above the floor*)
    1 where the hull's voxels higher than ``floor_band`` above the floor
    project. A cast shadow lies on the floor: the cameras' cones through it
    meet at floor level only, so this term is what tells an achromatic
    garment's shaded side (which stands in the room) from a shadow (which lies
    on the floor) without colour.
``h_any`` (*any hull*)
    1 where any occupied voxel projects (the feet and their floor band too);
    a pixel outside every projection is claimed by this view alone.

The hull here is built from generous candidates (every changed pixel, shadow
included, and the segmenter's person), so a part one source lost in a view is
still in 3D when the other sources or views see it.

A source a frame lacks (no segmenter, no calibrated rig, or the segmenter
found nobody in a view) is left out, and the weights fitted without it are
used: :data:`WEIGHTS` holds one set per combination of sources,
fitted by logistic regression on studio sessions whose appearance spans
saturated, white, grey, black and wall-coloured clothing in textured and plain
rooms under hard and soft light (``python -m benchmarks fusion_fit``, which
prints this table; docs/capture.md, "Evidence fusion"). A camera without a
background clip has no change or shadow evidence: its silhouette is the
segmenter's mask (checked against the hull by the multi-view check), as it was
validated on real footage without empty-scene clips.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from bodymetry.errors import InputError

__all__ = [
    "FEATURES",
    "WEIGHTS",
    "FusionConfig",
    "FusionWeights",
    "GeometryTerms",
    "change_evidence",
    "confirmed_change",
    "fuse",
    "mask_iou",
    "outline_contrast",
    "segmenter_evidence",
    "sources_key",
    "view_agreement",
    "view_features",
]

#: The evidence terms, in the order of :attr:`FusionWeights.weights` and :func:`view_features`.
FEATURES = ("change", "shadow", "floor_shadow", "segmenter", "hull_body", "hull_any")

#: Clip of the change term (log units).
CHANGE_CLIP = 2.0
#: Clip of the segmenter's logit (a confident segmenter must not overrule a hull and a
#: background that both disagree).
LOGIT_CLIP = 4.0


#: A strong change: the change term at or above this (a colour distance of e = 2.7 times
#: the change threshold).
STRONG_CHANGE = 1.0

#: How far (voxel sides about each occupied voxel's centre) the hull confirms a
#: thin part: the hull holds a voxel only where every view's mask covers its centre,
#: so fingers and a hand seen edge-on (thinner than the 4 cm voxels) lie up to about
#: a voxel outside its footprint (half a side) even where each view sees them.
THIN_REACH = 1.5

#: The segmenter is sure of a pixel above this logit (p > 0.9).
SURE_LOGIT = float(np.log(9.0))

#: Width (pixels) of the silhouette's inner rim that :func:`outline_contrast` reads ...
RIM_PX = 2
#: ... and the share of it whose change :func:`outline_contrast` reports (its lower
#: quartile: the change three quarters of the outline reach).
RIM_SHARE = 0.75

#: A pixel plainly shows the unchanged background (for the floor-shadow test) when its
#: change term is below this: a colour distance under half the change threshold.
LIT_CHANGE = float(np.log(0.5))


@dataclass(frozen=True)
class GeometryTerms:
    """What the calibrated rig says about one view (:meth:`FrameSegmenter.geometry`).

    Attributes
    ----------
    hull_body : (H, W) bool
        Where the hull's voxels above the floor band project.
    hull_any : (H, W) bool
        Where any occupied voxel projects.
    floor_shadow : (H, W) bool or None
        Shadow labels the other views confirm on the floor
        (:func:`bodymetry.capture.shadows.floor_shadows`; None without a background).
    shadow_at_feet : (H, W) bool or None
        The floor shadows that touch the feet
        (:func:`bodymetry.capture.shadows.at_feet`): never person.
    hull_reach : (H, W) bool or None
        ``hull_any`` widened by :data:`THIN_REACH` voxels: the hull samples voxel
        centres, so a part thinner than a voxel (fingers) falls outside it even
        where every view sees it; the thin-part rule of :func:`confirmed_change`
        confirms against this (None: ``hull_any``).
    """

    hull_body: np.ndarray
    hull_any: np.ndarray
    floor_shadow: np.ndarray | None = None
    shadow_at_feet: np.ndarray | None = None
    hull_reach: np.ndarray | None = None


@dataclass(frozen=True)
class FusionWeights:
    """The log-odds weights of one combination of sources.

    Attributes
    ----------
    bias : float
    weights : tuple of float
        One per :data:`FEATURES` (0 for a source the combination lacks).
    """

    bias: float
    weights: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.weights) != len(FEATURES):
            raise InputError(
                f"fusion weights: expected {len(FEATURES)} ({', '.join(FEATURES)}), "
                f"got {len(self.weights)}"
            )


def sources_key(background: bool, segmenter: bool, hull: bool) -> str:
    """The :data:`WEIGHTS` key of a combination of sources, e.g. ``"background+segmenter+hull"``."""
    names = [n for n, on in (("background", background), ("segmenter", segmenter),
                             ("hull", hull)) if on]  # fmt: skip
    return "+".join(names) or "none"


#: Fitted weights per combination of sources (``python -m benchmarks fusion_fit``).
WEIGHTS: dict[str, FusionWeights] = {
    "background+segmenter+hull": FusionWeights(
        -0.696, (0.431, -0.248, -0.481, 1.953, 0.178, 0.081)
    ),
    "background+segmenter": FusionWeights(-0.52, (0.368, -0.306, 0.0, 2.011, 0.0, 0.0)),
    "background+hull": FusionWeights(-2.956, (1.974, -1.344, -4.809, 0.0, 1.961, 1.189)),
    "background": FusionWeights(-1.096, (2.216, -4.325, 0.0, 0.0, 0.0, 0.0)),
}


@dataclass(frozen=True)
class FusionConfig:
    """How the capture stage fuses its evidence.

    Attributes
    ----------
    enabled : bool
        Off: today's choice instead of a fusion (background subtraction's
        mask, the segmenter only choosing among its blobs).
    floor_band : float
        Hull voxels lower than this (metres above the floor) may be cast
        shadow; only higher ones give ``h_body``.
    min_agreement : float
        A view whose silhouette agrees with neither the other views' hull nor
        its segmenter better than this (:func:`view_agreement`) is ``unreliable``.
    feet_reach : float
        A confirmed floor shadow whose floor point lies within this (metres) of
        the body's footprint touches the feet and is never person.
    """

    enabled: bool = True
    floor_band: float = 0.15
    min_agreement: float = 0.8
    feet_reach: float = 0.3

    def __post_init__(self) -> None:
        if not 0.0 <= self.floor_band < 1.0:
            raise InputError(f"fusion.floor_band: expected 0 <= band < 1 m, got {self.floor_band}")
        if not self.feet_reach >= 0.0:
            raise InputError(f"fusion.feet_reach: expected >= 0 m, got {self.feet_reach}")
        if not 0.0 <= self.min_agreement < 1.0:
            raise InputError(f"fusion.min_agreement: expected 0 <= a < 1, got {self.min_agreement}")

    def weights_for(self, key: str) -> FusionWeights:
        """The weights of the sources ``key`` (:func:`sources_key`)."""
        if key not in WEIGHTS:
            raise InputError(f"fusion: no weights for the sources {key!r}")
        return WEIGHTS[key]


def change_evidence(dist2: np.ndarray, fg_sigma: float) -> np.ndarray:
    """(H, W) float32 change term ``clip(log(d / fg_sigma), ±CHANGE_CLIP)`` from the
    squared colour distance ``dist2`` (H, W), noise units squared."""
    ratio = np.maximum(np.asarray(dist2, np.float32), 1e-6) / np.float32(fg_sigma**2)
    return np.clip(0.5 * np.log(ratio), -CHANGE_CLIP, CHANGE_CLIP).astype(np.float32)


def segmenter_evidence(probability: np.ndarray) -> np.ndarray:
    """(H, W) float32 ``clip(logit(p), ±LOGIT_CLIP)`` of a probability map (H, W)."""
    p = np.clip(np.asarray(probability, np.float32), 1e-4, 1 - 1e-4)
    return np.clip(np.log(p / (1 - p)), -LOGIT_CLIP, LOGIT_CLIP).astype(np.float32)


def view_features(
    shape: tuple[int, int],
    change: np.ndarray | None = None,
    shadow: np.ndarray | None = None,
    segmenter: np.ndarray | None = None,
    geometry: GeometryTerms | None = None,
) -> tuple[np.ndarray, str]:
    """The evidence of one view as a (H, W, F) float32 stack and its sources key.

    Parameters
    ----------
    shape : (H, W)
    change : (H, W) float32, optional
        :func:`change_evidence` (with ``shadow``: both or neither).
    shadow : (H, W) bool, optional
    segmenter : (H, W) float32, optional
        :func:`segmenter_evidence`.
    geometry : GeometryTerms, optional
        The hull's support and the floor-shadow test.

    Returns
    -------
    features : (H, W, F) float32
        Per :data:`FEATURES` (F = 6); 0 where a source is absent.
    key : str
        :func:`sources_key` of the sources present.
    """
    if (change is None) != (shadow is None):
        raise InputError("view_features: change and shadow come in pairs")
    out = np.zeros((*shape, len(FEATURES)), np.float32)
    hull_body = hull_any = floor_shadow = None
    if geometry is not None:
        hull_body, hull_any = geometry.hull_body, geometry.hull_any
        floor_shadow = None if shadow is None else geometry.floor_shadow
    for k, term in enumerate((change, shadow, floor_shadow, segmenter, hull_body, hull_any)):
        if term is not None:
            if np.shape(term) != tuple(shape):
                raise InputError(
                    f"view_features: {FEATURES[k]} is {np.shape(term)}, expected {tuple(shape)}"
                )
            out[..., k] = term
    key = sources_key(change is not None, segmenter is not None, geometry is not None)
    return out, key


def confirmed_change(
    fused: np.ndarray,
    subtracted: np.ndarray,
    change: np.ndarray,
    hull_any: np.ndarray,
    thin: np.ndarray,
    hull_reach: np.ndarray | None = None,
) -> np.ndarray:
    """The fused mask with the plain changes the other views confirm given back.

    * A strong change of colour (:data:`STRONG_CHANGE`, not shadow-like) that the
      hull confirms is person whatever the segmenter says: it misses shoes and
      soft-edged parts that subtraction sees plainly.
    * On a thin part (a hand, a wrist: ``thin``) any change that subtraction labels
      person (above its threshold, not shadow) and the hull confirms is person: the
      segmenter's coarse mask says background there, and the weights were fitted
      away from the outline (:mod:`benchmarks.fusion_fit`), so they never saw a
      finger. On the studio's hands the fusion alone lost a third of a pixel of
      outline (fingertips of 1-2 px; docs/capture.md, "Thin parts").

    Parameters
    ----------
    fused : (H, W) bool
        The fused mask (:func:`fuse` > 0).
    subtracted : (H, W) bool
        Background subtraction's person label.
    change : (H, W) float32
        :func:`change_evidence`.
    hull_any : (H, W) bool
        :attr:`GeometryTerms.hull_any`.
    thin : (H, W) bool
        Thin parts of ``fused`` (:func:`bodymetry.capture.masks.thin_parts`).
    hull_reach : (H, W) bool, optional
        :attr:`GeometryTerms.hull_reach`: what confirms a thin part (the hull's
        voxels are as wide as a hand; ``hull_any`` when not given).

    Returns
    -------
    (H, W) bool
    """
    changed = subtracted & (change >= 0.0)
    reach = hull_any if hull_reach is None else hull_reach | hull_any
    strong = changed & hull_any & (change >= STRONG_CHANGE)
    return fused | strong | (changed & reach & thin)


def fuse(features: np.ndarray, weights: FusionWeights) -> np.ndarray:
    """(H, W) float32 log-odds that each pixel shows the person.

    Parameters
    ----------
    features : (H, W, F) float32
        :func:`view_features`.
    weights : FusionWeights
    """
    w = np.asarray(weights.weights, np.float32)
    return (features.reshape(-1, len(FEATURES)) @ w).reshape(features.shape[:2]) + np.float32(
        weights.bias
    )


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two (H, W) bool masks (0 when both are empty)."""
    union = np.count_nonzero(a | b)
    return float(np.count_nonzero(a & b) / union) if union else 0.0


def view_agreement(
    masks: Sequence[np.ndarray],
    others_support: Sequence[np.ndarray | None],
    segmenter_masks: Sequence[np.ndarray | None],
) -> list[float | None]:
    """Per view, how well its silhouette agrees with the frame's other evidence.

    The better of two scores, each in [0, 1]: the share of the silhouette that
    the *other* views' hull confirms (the hull is larger than the body, so a
    right silhouette lies inside its projection, while a region this view adds
    alone, or a view that looks elsewhere, does not), and the IoU with the
    view's own segmenter. A view scores low only when both disagree.

    Parameters
    ----------
    masks : sequence of (H_c, W_c) bool
    others_support : sequence of ((H_c, W_c) bool or None)
        Where the hull of the other views projects in this view.
    segmenter_masks : sequence of ((H_c, W_c) bool or None)

    Returns
    -------
    list of (float or None)
        None where neither can judge or the view is empty.
    """
    out: list[float | None] = []
    for mask, support, seg in zip(masks, others_support, segmenter_masks, strict=True):
        area = np.count_nonzero(mask)
        scores = []
        if support is not None and support.any() and area:
            scores.append(np.count_nonzero(mask & support) / area)
        if seg is not None and seg.any() and area:
            scores.append(mask_iou(mask, seg))
        out.append(float(max(scores)) if scores else None)
    return out


def outline_contrast(
    masks: Sequence[np.ndarray],
    changes: Sequence[np.ndarray | None],
    beside: Sequence[np.ndarray | None] | None = None,
) -> float | None:
    """How plainly the person stands out from the empty scene along their outline.

    The median, over the views, of the change term (:func:`change_evidence`: the
    log colour distance to the empty scene relative to the change threshold,
    clipped at ±:data:`CHANGE_CLIP`) that :data:`RIM_SHARE` of each view's
    silhouette's inner rim (the pixels within :data:`RIM_PX` of the outside)
    reaches: its lower quartile. A person in saturated or black clothing stands
    out nearly all round (1.55-2.0 on the studio's runs); one in white, light
    grey or wall-coloured clothing, or light grey in the textured lab, only on
    the lit side or nowhere (0.3-1.26): there the silhouettes rest on the
    segmenter and the hull more than on the colour, and the outline is less sure
    (docs/capture.md, "Outline contrast"). The lower quartile, not the median:
    in hard light a white shirt's lit side stands out as plainly as a saturated
    one, and its shaded side not at all.

    Parameters
    ----------
    masks : sequence of (H_c, W_c) bool
        The final silhouettes.
    changes : sequence of ((H_c, W_c) float32 or None)
        Each view's change term (None: no empty-scene clip for that camera).
    beside : sequence of ((H_c, W_c) bool or None), optional
        Per view, pixels that are not the empty scene though not the person's
        (someone else, someone nearer who hides them): the rim within
        :data:`RIM_PX` of them borders another person, not the background, and is
        left out.

    Returns
    -------
    float or None
        None where no view has both a silhouette and a change term.
    """
    per_view = []
    kernel = np.ones((2 * RIM_PX + 1, 2 * RIM_PX + 1), np.uint8)
    beside = beside or (None,) * len(masks)
    for mask, change, other in zip(masks, changes, beside, strict=True):
        if change is None or not np.any(mask):
            continue
        m = np.asarray(mask, np.uint8)
        rim = (m > 0) & ~(cv2.erode(m, kernel, borderValue=1) > 0)
        if other is not None:
            rim &= ~(cv2.dilate(np.asarray(other, np.uint8), kernel) > 0)
        if rim.any():
            per_view.append(float(np.quantile(change[rim], 1.0 - RIM_SHARE)))
    return float(np.median(per_view)) if per_view else None
