"""Colour differences as 4:2:0 video records them.

Video is recorded in 4:2:0 (H.264 and HEVC from nearly every camera, and the
studio's renders): luma at every pixel, chroma at half the resolution in each
direction. A saturated garment's chroma therefore spreads a pixel or two past
its outline, into the wall or floor beside it and into every narrow gap between
an arm and the trunk or between the legs, while the luma there is the
background's. Colour differences that decide whether a pixel is the person
(background subtraction's change term in the fusion, the edge refinement's
nearer-colour test) weigh the chroma part of a difference down against its
luma part.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "CHANGE_CHROMA_WEIGHT",
    "CHROMA_WEIGHT",
    "LUMA",
    "VIDEO_METRIC",
    "video_distance2",
    "video_metric",
]

#: Weight of the chroma part of a colour difference (squared) against its luma part
#: where the edge refinement decides which colour a pixel is nearer. With chroma at full
#: weight it put the outline of a saturated shirt further out (studio session 363: torso
#: +0.20 px outside the true outline, upper arms +0.07 and +0.12 px; at 0.25: +0.15,
#: +0.04 and +0.05 px) and weights read heavy (docs/capture.md, "Edge refinement").
CHROMA_WEIGHT = 0.25

#: The same for background subtraction's change term in the evidence fusion
#: (``video`` of :meth:`bodymetry.capture.background.Subtractor.labels`), where a pixel's
#: difference from the empty scene is held against the camera noise: in a 3-pixel gap
#: beside a red garment the bled chroma is a few times the noise and the luma at it
#: (docs/capture.md, "Chroma in the gaps": on the studio's unseen edge set the session
#: weights of the thin bodies walking read 0.7-0.9 kg lighter at 0.0625 than at full
#: chroma, 0.4-0.6 kg at 0.25).
CHANGE_CHROMA_WEIGHT = 0.0625

#: The luma axis of a BGR colour (BT.601, as encoders convert RGB to YCbCr), unit length.
LUMA = np.array([0.114, 0.587, 0.299]) / np.linalg.norm([0.114, 0.587, 0.299])


def video_metric(chroma_weight: float) -> np.ndarray:
    """(3, 3) float32: a BGR difference ``d`` maps to ``d @ M``, whose squared length is
    its luma part squared plus ``chroma_weight`` times its chroma part squared."""
    luma = np.outer(LUMA, LUMA)
    return (luma + np.sqrt(chroma_weight) * (np.eye(3) - luma)).astype(np.float32)


#: :func:`video_metric` at :data:`CHROMA_WEIGHT`.
VIDEO_METRIC = video_metric(CHROMA_WEIGHT)


def video_distance2(diff: np.ndarray, metric: np.ndarray = VIDEO_METRIC) -> np.ndarray:
    """Squared length of BGR differences with their chroma weighed down.

    Parameters
    ----------
    diff : (..., 3) float
        BGR differences (in any units: grey levels, or noise units per channel).
    metric : (3, 3) float
        :func:`video_metric` of the chroma weight (default :data:`VIDEO_METRIC`; the
        identity: every channel alike).

    Returns
    -------
    (...) float32
        The luma part squared plus the chroma weight times the chroma part squared.
    """
    return ((np.asarray(diff, np.float32) @ metric) ** 2).sum(axis=-1)
