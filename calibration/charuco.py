"""ChArUco board detection in calibration clips (OpenCV 5 ``cv2.aruco`` API).

A board of ``sx x sy`` squares has ``(sx - 1) * (sy - 1)`` inner (ChArUco)
corners; corner ``id`` sits at board coordinates
``((id % (sx - 1) + 1) * square, (id // (sx - 1) + 1) * square, 0)`` (OpenCV's
board frame: origin at the pattern's outer corner, x along the columns, y along
the rows, printed side facing -z).

Detections are stored densely: for every camera an array ``(F, N, 2)`` of pixel
positions of the N board corners in F sampled frames, NaN where a corner was
not found. Boards are small (a 5x4 board has 12 corners), so dense arrays are
simpler and faster than ragged lists.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bodymetry.errors import InputError

__all__ = [
    "BoardGeometry",
    "CameraDetections",
    "board_geometry",
    "detect_clip",
    "detect_image",
    "make_detector",
]

#: Upscale factor before detection: small markers far from the camera are found
#: about twice as often on a 2x (bicubic) image.
DEFAULT_UPSCALE = 2


@dataclass(frozen=True)
class BoardGeometry:
    """Object points of a ChArUco board's inner corners.

    Attributes
    ----------
    squares : (int, int)
        ``(sx, sy)`` squares.
    square_m : float
        Square side, metres.
    points : (N, 3) float
        Corner ``id`` -> board coordinates, metres (float64, exact multiples of
        the square size; OpenCV stores them as float32).
    """

    squares: tuple[int, int]
    square_m: float
    points: np.ndarray

    @property
    def n_corners(self) -> int:
        return len(self.points)


def board_geometry(board: cv2.aruco.CharucoBoard, square_m: float | None = None) -> BoardGeometry:
    """The corner geometry of an OpenCV ``CharucoBoard`` (lengths as the board's)."""
    sx, sy = board.getChessboardSize()
    sq = float(board.getSquareLength()) if square_m is None else float(square_m)
    ids = np.arange((sx - 1) * (sy - 1))
    pts = np.stack(
        [(ids % (sx - 1) + 1) * sq, (ids // (sx - 1) + 1) * sq, np.zeros(len(ids))], axis=1
    )
    ref = np.asarray(board.getChessboardCorners(), dtype=float).reshape(-1, 3)
    if ref.shape != pts.shape or not np.allclose(ref, pts, rtol=1e-5, atol=1e-6 * sq):
        raise ValueError("unexpected ChArUco corner layout in this OpenCV version")
    return BoardGeometry((int(sx), int(sy)), sq, pts)


@dataclass
class CameraDetections:
    """The board corners found in one camera's calibration clip.

    Attributes
    ----------
    name : str
        Camera name.
    size : (int, int)
        Image ``(width, height)``.
    frames_read : int
        Frames decoded (sampled ones).
    frames : (F,) int
        Clip frame index of every sampled frame (all sampled frames, board found
        or not, so cameras can be matched frame by frame).
    corners : (F, N, 2) float
        Pixel position of every board corner; NaN where not detected.
    source : str
        Clip path (for messages).
    """

    name: str
    size: tuple[int, int]
    frames_read: int
    frames: np.ndarray
    corners: np.ndarray
    source: str = ""

    @property
    def found(self) -> np.ndarray:
        """(F, N) bool: corner detected."""
        return np.all(np.isfinite(self.corners), axis=-1)

    @property
    def boards_detected(self) -> int:
        """Frames where at least one corner was found."""
        return int(np.any(self.found, axis=1).sum())

    @property
    def corners_detected(self) -> int:
        return int(self.found.sum())


def make_detector(
    board: cv2.aruco.CharucoBoard, min_marker_perimeter_rate: float = 0.01
) -> cv2.aruco.CharucoDetector:
    """A ``CharucoDetector`` tuned for small boards in wide views."""
    params = cv2.aruco.DetectorParameters()
    params.minMarkerPerimeterRate = min_marker_perimeter_rate
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    charuco = cv2.aruco.CharucoParameters()
    charuco.tryRefineMarkers = True
    return cv2.aruco.CharucoDetector(board, charuco, params, cv2.aruco.RefineParameters())


def detect_image(
    detector: cv2.aruco.CharucoDetector,
    image: np.ndarray,
    n_corners: int,
    upscale: int = DEFAULT_UPSCALE,
) -> np.ndarray:
    """Board corners in one image.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8
    upscale : int
        Detect on an image enlarged by this factor (bicubic), then map back.

    Returns
    -------
    (N, 2) float
        Pixels (original image, OpenCV pixel-centre convention); NaN where absent.
    """
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if upscale > 1:
        big = cv2.resize(gray, None, fx=upscale, fy=upscale, interpolation=cv2.INTER_CUBIC)
    else:
        big = gray
    corners, ids, _, _ = detector.detectBoard(big)
    out = np.full((n_corners, 2), np.nan)
    if ids is None or corners is None or len(ids) == 0:
        return out
    ids = np.asarray(ids).reshape(-1)
    c = np.asarray(corners, dtype=float).reshape(-1, 2)
    if upscale > 1:
        # Pixel centres: x_big = s * x + (s - 1) / 2.
        c = (c - (upscale - 1) / 2.0) / upscale
        # (A second cornerSubPix at the native resolution was measured: no better.)
    keep = (ids >= 0) & (ids < n_corners)
    out[ids[keep]] = c[keep]
    return out


def _open(path: Path, camera: str) -> cv2.VideoCapture:
    if not path.is_file():
        raise InputError(f"camera {camera!r}: calibration clip {path} does not exist")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputError(f"camera {camera!r}: cannot open calibration clip {path} as a video")
    return cap


def detect_clip(
    path: str | Path,
    board: cv2.aruco.CharucoBoard,
    camera: str,
    *,
    step: int = 1,
    upscale: int = DEFAULT_UPSCALE,
    max_frames: int | None = None,
    on_frame: Callable[[int, int], None] | None = None,
) -> CameraDetections:
    """Detect the board in every ``step``-th frame of a clip.

    Parameters
    ----------
    path : path of the clip
    board : the board (lengths in metres)
    camera : camera name (messages, result)
    step : sample every ``step``-th frame (frame indices ``0, step, 2 step, ...``)
    max_frames : stop after this many clip frames (None: the whole clip)
    on_frame : called as ``on_frame(frames_done, frames_total)`` after each sample

    Raises
    ------
    InputError
        The clip is missing, unreadable or has no frames.
    """
    if step < 1:
        raise InputError(f"detection step must be >= 1, got {step}")
    path = Path(path)
    geom = board_geometry(board)
    detector = make_detector(board)
    cap = _open(path, camera)
    try:
        total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        if max_frames is not None:
            total = min(total, max_frames) if total > 0 else max_frames
        n_samples = (total + step - 1) // step if total > 0 else 0
        frames: list[int] = []
        corners: list[np.ndarray] = []
        size: tuple[int, int] | None = None
        index = 0
        while max_frames is None or index < max_frames:
            if index % step == 0:
                ok, image = cap.read()
                if not ok:
                    break
                if size is None:
                    size = (image.shape[1], image.shape[0])
                corners.append(detect_image(detector, image, geom.n_corners, upscale))
                frames.append(index)
                if on_frame is not None:
                    on_frame(len(frames), max(n_samples, len(frames)))
            elif not cap.grab():
                break
            index += 1
    finally:
        cap.release()
    if not frames or size is None:
        raise InputError(f"camera {camera!r}: calibration clip {path} has no readable frames")
    return CameraDetections(
        name=camera,
        size=size,
        frames_read=len(frames),
        frames=np.asarray(frames, dtype=int),
        corners=np.stack(corners),
        source=str(path),
    )
