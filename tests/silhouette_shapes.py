"""Synthetic silhouettes drawn with OpenCV, for the feature tests."""

from __future__ import annotations

import cv2
import numpy as np

SHIFT = 4  # sub-pixel bits for cv2.fillPoly


def _limb(p, q, width):
    p, q = np.asarray(p, float), np.asarray(q, float)
    d = q - p
    n = np.array([-d[1], d[0]]) / np.hypot(*d) * width / 2
    return np.array([p + n, q + n, q - n, p - n])


def _disk(center, radius, k=40):
    a = np.linspace(0, 2 * np.pi, k, endpoint=False)
    return np.stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)], 1)


def figure_mask(scale, offset, shape=(480, 640), arm=1.0, leg=0.3):
    """A stick figure ``scale`` pixels tall with the top of its head at ``offset``."""
    polys = [_disk((0, 0.07), 0.07), _limb((0, 0.16), (0, 0.52), 0.2)]
    for side in (-1, 1):
        shoulder = np.array([0.09 * side, 0.18])
        polys.append(
            _limb(shoulder, shoulder + 0.33 * np.array([np.sin(arm) * side, np.cos(arm)]), 0.06)
        )
        hip = np.array([0.06 * side, 0.5])
        polys.append(_limb(hip, hip + 0.5 * np.array([np.sin(leg) * side, np.cos(leg)]), 0.08))
    mask = np.zeros(shape, np.uint8)
    pts = [np.round((p * scale + offset) * (1 << SHIFT)).astype(np.int32) for p in polys]
    cv2.fillPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=SHIFT)
    return mask.astype(bool)


def ellipse_mask(center, axes, angle_deg=20.0, shape=(480, 640)):
    mask = np.zeros(shape, np.uint8)
    c = tuple(round(v * (1 << SHIFT)) for v in center)
    a = tuple(round(v * (1 << SHIFT)) for v in axes)
    cv2.ellipse(mask, c, a, angle_deg, 0, 360, 1, -1, cv2.LINE_8, SHIFT)
    return mask.astype(bool)


def shifted(mask, dx, dy):
    """The mask translated by whole pixels (content must stay inside)."""
    out = np.zeros_like(mask)
    h, w = mask.shape
    out[max(dy, 0) : h + min(dy, 0), max(dx, 0) : w + min(dx, 0)] = mask[
        max(-dy, 0) : h - max(dy, 0), max(-dx, 0) : w - max(dx, 0)
    ]
    assert out.sum() == mask.sum()
    return out


def cylinder_mask(camera, center=(0.0, 0.0), radius: float = 0.2, height: float = 1.7):
    """(H, W) bool: the filled projection of an upright cylinder standing on the floor
    at ``center`` (x, y) metres (a stand-in person for the multi-view tests)."""
    a = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    ring = np.column_stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)])
    pts = np.vstack([np.column_stack([ring, np.full(len(a), z)]) for z in (0.0, height)])
    px = camera.project(pts).astype(np.float32)
    mask = np.zeros((camera.size[1], camera.size[0]), np.uint8)
    cv2.fillConvexPoly(mask, cv2.convexHull(px).astype(np.int32), 1)
    return mask.astype(bool)
