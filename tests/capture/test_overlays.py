"""Inspection overlays (capture/overlays.py)."""

from __future__ import annotations

import cv2
import numpy as np

from bodymetry.capture.overlays import overlay

H, W = 240, 320


def _person(cx: int, cy: int = 120, ax: int = 18, ay: int = 70) -> np.ndarray:
    m = np.zeros((H, W), np.uint8)
    cv2.ellipse(m, (cx, cy), (ax, ay), 0, 0, 360, 1, -1)
    return m > 0


def test_overlay_shapes() -> None:
    img = np.zeros((H, W, 3), np.uint8)
    out = overlay(img, _person(160), _person(200), ("border",))
    assert out.shape == img.shape and out.dtype == np.uint8 and out.any()
    assert overlay(None, np.zeros((H, W), bool)).shape == (H, W, 3)
