"""Silhouettes written for inspection: mask PNGs and overlay images.

:func:`overlay` tints the person green with its outline and the pixels
suppressed as shadow blue, and writes the view's flags
(:data:`bodymetry.capture.masks.FLAGS`) in the corner;
:func:`save_silhouette_frame` writes one :class:`SilhouetteFrame`'s masks and
overlays.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from bodymetry.capture.segmentation import SilhouetteFrame
from bodymetry.fileio import write_bytes_atomic

__all__ = ["overlay", "save_silhouette_frame"]

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
