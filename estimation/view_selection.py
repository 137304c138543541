"""Which views of a frame the fit uses, and the views left out (unreliable, occluded, mixed).

One decision, made here for every consumer of a frame's per-view silhouettes
(the per-frame fit and its rescue, the session stage and its outline check,
``camera_frames`` in ``results.json``, the evaluation's fits): a view is
usable when its silhouette has at least :data:`MIN_PIXELS` person pixels and
capture did not flag it with one of :data:`LEAVE_OUT_FLAGS`.

``unreliable`` is capture's verdict that a view's silhouette disagrees with
the frame's other evidence (the other views' hull and the learned segmenter;
:attr:`bodymetry.capture.segmentation.SilhouetteFrame.agreement`). Capture
keeps such a mask as it found it, for review; the fit leaves the view out of
that frame. ``occluded`` is capture's verdict that someone else hides most of a
person in a view (or a camera missed them where someone covers them), and
``mixed`` that the camera's detection of a person is partly someone else's
(:data:`bodymetry.capture.people.MIXED_SHARE`), or that a camera which did not
detect them has masks there that follow someone else
(:data:`bodymetry.capture.people.BACKGROUND_BONES`). :func:`left_out_views`
gathers these kinds of view over a run, and
:meth:`LeftOutView.describe` is the run's warning about each camera (the
report lists the same).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bodymetry.estimation.records import FrameRecord

__all__ = [
    "ABSENT",
    "LEAVE_OUT_FLAGS",
    "LEFT_OUT_REASONS",
    "MIN_PIXELS",
    "MIN_VIEWS",
    "LeftOutView",
    "blank_unusable",
    "left_out_views",
    "usable_camera_frames",
    "usable_view",
    "usable_views",
]

#: Views with fewer person pixels than this are treated as having no silhouette.
MIN_PIXELS = 400

#: The fewest usable views a frame of a rig of that many cameras or more is
#: measured from. One silhouette says nothing of the body's depth: a studio
#: session (seed 7, 8 kept frames) with three of its four cameras showing the
#: empty room measured 7 frames, and the session stage read the weight
#: +5.2 kg, the arm span +37 mm and the waist +55 mm off, with standard errors
#: of 2.0 kg, 19 mm and 9 mm (2026-12-06; the four cameras: +0.9 kg, +7.9 mm).
MIN_VIEWS = 2

#: Capture's view flags that leave a view out of the frame's fit: no image
#: (``unreadable``), a silhouette the frame's other evidence contradicts
#: (``unreliable``), or a chosen person whom someone nearer may hide in part
#: (``occluded``: hidden pixels are unknown, not background) or whose detection
#: there is partly someone else's (``mixed``: its mask follows both).
LEAVE_OUT_FLAGS = ("unreadable", "unreliable", "occluded", "mixed")
#: Why :func:`left_out_views` reports a camera: capture's flag, and the words for it.
LEFT_OUT_REASONS = {
    "unreliable": "silhouette unreliable",
    "occluded": "hidden behind another person",
    "mixed": "detected mixed with another person",
}
#: The flag of every view of a frame in which a person told apart from others was
#: not found (their fit records why instead of "no silhouette").
ABSENT = "absent"


def usable_view(pixels: int, flags: Sequence[str]) -> bool:
    """Whether one view has a person silhouette to fit: enough pixels, not left out by a flag."""
    return pixels >= MIN_PIXELS and not any(f in LEAVE_OUT_FLAGS for f in flags)


def usable_views(
    names: Sequence[str], pixels: Mapping[str, int], flags: Mapping[str, Sequence[str]]
) -> np.ndarray:
    """(C,) bool: per camera of ``names``, :func:`usable_view` of its pixels and flags
    (a camera missing from ``pixels`` has none)."""
    return np.array([usable_view(pixels.get(n, 0), flags.get(n, ())) for n in names], bool)


def blank_unusable(masks: Sequence[np.ndarray], usable: Sequence[bool]) -> list[np.ndarray]:
    """The (H_c, W_c) ``masks`` with the views not ``usable`` (:func:`usable_views`)
    emptied, each at its own size: an empty view is left out downstream."""
    return [m if ok else np.zeros_like(m) for m, ok in zip(masks, usable, strict=True)]


def usable_camera_frames(records: Sequence[FrameRecord], names: Sequence[str]) -> dict[str, int]:
    """Per camera, the frames of ``records`` in which its view was usable
    (``camera_frames`` of ``results.json``)."""
    return {
        n: sum(usable_view(r.person_pixels.get(n, 0), r.flags.get(n, ())) for r in records)
        for n in names
    }


@dataclass(frozen=True)
class LeftOutView:
    """A camera whose view was left out (``unreliable``, ``occluded`` or ``mixed``) in some kept
    frames.

    Attributes
    ----------
    camera : str
    frames : tuple of int
        The kept frames in which it was left out, in order.
    agreement : tuple of float
        Capture's agreement (IoU with the frame's other evidence) in those of
        ``frames`` that recorded one, in frame order.
    kept : int
        The run's kept frames.
    reason : {"unreliable", "occluded", "mixed"}
        Capture's flag (:data:`LEFT_OUT_REASONS`).
    """

    camera: str
    frames: tuple[int, ...]
    agreement: tuple[float, ...]
    kept: int
    reason: str = "unreliable"

    @property
    def agreement_text(self) -> str:
        """``"0.61"`` or ``"0.61-0.74"`` (empty when no frame recorded one)."""
        if not self.agreement:
            return ""
        lo, hi = min(self.agreement), max(self.agreement)
        return f"{lo:.2f}" if f"{lo:.2f}" == f"{hi:.2f}" else f"{lo:.2f}-{hi:.2f}"

    def describe(self, bound: float | None = None) -> str:
        """The run's warning about this camera, e.g. ``"cam02: silhouette unreliable in 3
        of 9 kept frames (agreement 0.61-0.74 < 0.80), left out of those frames' fits"``.

        ``bound`` is the agreement below which capture flags a view (quoted when given).
        """
        detail = ""
        if self.agreement:
            below = f" < {bound:.2f}" if bound is not None else ""
            detail = f" (agreement {self.agreement_text}{below})"
        return (
            f"{self.camera}: {LEFT_OUT_REASONS[self.reason]} in {len(self.frames)} of "
            f"{self.kept} kept frames{detail}, left out of those frames' fits"
        )


def left_out_views(records: Sequence[FrameRecord], names: Sequence[str]) -> list[LeftOutView]:
    """The cameras of ``names`` flagged ``unreliable``, ``occluded`` or ``mixed`` in
    any of ``records`` (the run's kept frames), in camera order (per camera in the
    order of :data:`LEFT_OUT_REASONS`); empty when no view was left out so.

    An ``occluded`` view is one in which someone nearer hides most of the
    person, or a camera whose segmenter did not detect them where someone else
    covers their skeleton (:func:`bodymetry.capture.people.sightings`): a camera
    that never saw a person leaves their measurements to the other views as
    surely as an unreliable one does (studio two-person session of seed 31:
    cam_03 left out of 15 of 16 frames of the person the detector missed there,
    whose arm span read 36 mm short where the same body alone read 10 mm).
    """
    out = []
    ordered = sorted(records, key=lambda r: r.frame)
    for name in names:
        for reason in LEFT_OUT_REASONS:
            hit = [r for r in ordered if reason in r.flags.get(name, ())]
            if not hit:
                continue
            values = [r.view_agreement.get(name) for r in hit]
            agreement = tuple(float(v) for v in values if v is not None and math.isfinite(v))
            frames = tuple(r.frame for r in hit)
            out.append(LeftOutView(name, frames, agreement, len(records), reason))
    return out
