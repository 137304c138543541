"""Skeletons of standing people seen by a camera: the segmenter's landmarks as a
known answer, for the tests of counting and telling people apart."""

from __future__ import annotations

import numpy as np

from bodymetry.capture.person import LANDMARKS

#: A standing person's body landmarks, metres: (name, x offset, height).
SKELETON = {
    "left_shoulder": (0.2, 1.45), "right_shoulder": (-0.2, 1.45),
    "left_elbow": (0.27, 1.15), "right_elbow": (-0.27, 1.15),
    "left_wrist": (0.3, 0.85), "right_wrist": (-0.3, 0.85),
    "left_hip": (0.1, 0.95), "right_hip": (-0.1, 0.95),
    "left_knee": (0.1, 0.5), "right_knee": (-0.1, 0.5),
    "left_ankle": (0.1, 0.08), "right_ankle": (-0.1, 0.08),
}  # fmt: skip


def detection(camera, at, noise: float = 0.0, rng=None) -> np.ndarray:
    """(33, 3) landmarks of a person standing at floor point ``at`` as ``camera`` sees
    them (x, y, visibility 1; NaN for the landmarks the skeleton lacks)."""
    out = np.full((len(LANDMARKS), 3), np.nan)
    names = list(SKELETON)
    points = np.array([[at[0] + SKELETON[n][0], at[1], SKELETON[n][1]] for n in names])
    pixels = camera.project(points)
    if noise:
        pixels = pixels + rng.normal(0.0, noise, pixels.shape)
    for name, px in zip(names, pixels, strict=True):
        out[LANDMARKS.index(name)] = (*px, 1.0)
    return out
