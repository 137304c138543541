"""Images through the codec the studio and most cameras record with (H.264, 4:2:0)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from bodymetry.capture.video import H264Writer


def through_h264(img: np.ndarray, path: Path) -> np.ndarray:
    """``img`` (H, W, 3) uint8 written to ``path`` as the studio writes video (H.264,
    4:2:0) and read back."""
    with H264Writer(path, 25, (img.shape[1], img.shape[0]), 20) as writer:
        for _ in range(2):
            writer.write(img)
    cap = cv2.VideoCapture(str(path))
    ok, out = cap.read()
    cap.release()
    assert ok
    return out
