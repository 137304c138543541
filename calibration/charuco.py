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

Corner positions: OpenCV's detector places a ChArUco corner with
``cornerSubPix``, whose window on small or foreshortened squares takes in the
marker edges next to the corner (measured on studio clips: 0.18-0.49 px RMS
per camera, up to 4 px; on the floor board seen at 4 m persistent errors of
1-2 px at some corners). :class:`CornerRefiner` then aligns the printed
pattern around each corner (1.5 x 1.5 squares: the X junction and the nearby
marker edges) with the image by ECC image alignment under a homography, which
brings the error to 0.026-0.040 px RMS per camera on the same clips.
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
    "CornerRefiner",
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
    refined : (F, N) bool or None
        Corner placed by :class:`CornerRefiner` (else where OpenCV's detector
        put it); None when refinement was not run.
    """

    name: str
    size: tuple[int, int]
    frames_read: int
    frames: np.ndarray
    corners: np.ndarray
    source: str = ""
    refined: np.ndarray | None = None

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

    @property
    def corners_refined(self) -> int | None:
        """Detected corners placed by :class:`CornerRefiner` (None: refinement off)."""
        return None if self.refined is None else int((self.refined & self.found).sum())


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


class CornerRefiner:
    """Sub-pixel ChArUco corners by aligning the printed pattern with the image.

    For every detected corner, the board's own image (``board.generateImage``:
    the pattern that was printed) around the corner, ``half_squares`` squares
    on each side, is aligned with the image through a homography by ECC
    (``cv2.findTransformECC``, ``MOTION_HOMOGRAPHY``; invariant to the print's
    contrast and brightness). The corner is where the aligned warp puts
    it. The starting homography is the board's, fitted to the frame's detected
    corners, moved so that the corner starts at its detection. A patch of 1.5
    squares (at most 64 px) is small enough for lens distortion to be
    negligible within it and large enough to hold the marker edges, which the
    ECC uses as well.

    A corner keeps its detector position (``refined`` False) when the patch
    lies mostly outside the image, when ECC fails, correlates less than
    ``min_correlation``, or moves the corner by more than ``max_shift``
    squares (at least 1.5 px): the detector is off by up to ~1.7 px on small
    squares, while a wrong alignment moves by about half a square.

    Parameters
    ----------
    board : cv2.aruco.CharucoBoard
    half_squares : float
        Patch half-size, squares.
    blur_px : float
        Gaussian blur (sigma, image pixels) applied to the template, for the
        camera's optical blur.
    max_shift : float
        Largest accepted move from the detector's position, squares (but at
        least 1.5 px).
    max_half_px : float
        Patch half-size limit, image pixels (large squares: a smaller patch,
        less lens curvature within it; measured on a studio clip, squares over
        60 px: 0.067 px RMS with 32 px, 0.079 px with 48 px, 0.068 with 24 px).
    min_correlation : float
        Smallest accepted ECC correlation coefficient.
    pixels_per_square : int
        Resolution of the pattern image the templates are cut from.
    """

    def __init__(
        self,
        board: cv2.aruco.CharucoBoard,
        *,
        half_squares: float = 0.75,
        blur_px: float = 0.7,
        max_shift: float = 0.2,
        max_half_px: float = 32.0,
        min_correlation: float = 0.8,
        pixels_per_square: int = 256,
    ) -> None:
        if not 0.25 <= half_squares <= 1.0:
            raise ValueError(f"half_squares must be in [0.25, 1], got {half_squares}")
        sx, sy = board.getChessboardSize()
        self.squares = (int(sx), int(sy))
        self.half = float(half_squares)
        self.blur = float(blur_px)
        self.max_shift = float(max_shift)
        self.max_half_px = float(max_half_px)
        self.min_corr = float(min_correlation)
        self.pps = int(pixels_per_square)
        image = board.generateImage((sx * self.pps, sy * self.pps), marginSize=0)
        # A white margin of one square: windows of edge corners stay on paper.
        image = cv2.copyMakeBorder(
            image, self.pps, self.pps, self.pps, self.pps, cv2.BORDER_CONSTANT, value=255
        )
        self._pyramid = [image.astype(np.float32) / 255.0]
        while min(self._pyramid[-1].shape) > 64:
            self._pyramid.append(cv2.pyrDown(self._pyramid[-1]))
        ids = np.arange((sx - 1) * (sy - 1))
        #: (N, 2) corner positions in squares (board units / square length)
        self.corner_squares = np.stack([ids % (sx - 1) + 1, ids // (sx - 1) + 1], 1).astype(float)
        self._criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-5)

    def _template(
        self, corner: np.ndarray, scale: float, half: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pattern patch around ``corner`` (squares), ``half`` squares each side, for
        an image with ``scale`` px per square.

        The patch is an exact crop (integer pixel offsets, no resampling) of the
        pyramid level nearest to the image's resolution, blurred by ``blur_px``
        image pixels. Resampling a sharp pattern at the image's
        scale instead aliases its edges with the same phase at every corner: a
        bias of up to 0.1 px on 95 px squares (measured on exact renders).

        Returns
        -------
        T : (n, n) float32
            The patch.
        A : (3, 3) float
            Board (squares) from template pixel (pixel centres at integers).
        """
        top = len(self._pyramid) - 1
        # The level nearest in resolution: 0.7-1.4 template pixels per image pixel.
        level = int(np.clip(np.round(np.log2(self.pps / scale)), 0, top))
        k = self.pps / 2**level  # level pixels per square
        # Level-0 pixel index of board point b (squares): b * pps + pps - 0.5 (one square of
        # margin); pyrDown keeps every second pixel, so level l index = level-0 index / 2^l.
        off = (self.pps - 0.5) / 2**level
        n = int(np.ceil(2 * half * k))
        image = self._pyramid[level]
        i0, j0 = np.round((corner - half) * k + off).astype(int)  # column, row of T[0, 0]
        i0 = int(np.clip(i0, 0, image.shape[1] - n))
        j0 = int(np.clip(j0, 0, image.shape[0] - n))
        T = image[j0 : j0 + n, i0 : i0 + n]
        T = cv2.GaussianBlur(T, (0, 0), self.blur * k / scale) if self.blur > 0 else T.copy()
        A = np.array([[1 / k, 0, (i0 - off) / k], [0, 1 / k, (j0 - off) / k], [0, 0, 1]])
        return T, A

    def refine(self, gray: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Refine one frame's detected corners.

        Parameters
        ----------
        gray : (H, W) uint8 or float32
            The frame at its native resolution (grey).
        corners : (N, 2) float
            Detected corners (pixels, OpenCV pixel-centre convention), NaN
            where absent.

        Returns
        -------
        corners : (N, 2) float
            Refined where possible, else as given.
        refined : (N,) bool
        """
        img = gray.astype(np.float32) / 255.0 if gray.dtype == np.uint8 else gray
        corners = np.asarray(corners, dtype=float)
        out = corners.copy()
        refined = np.zeros(len(corners), dtype=bool)
        found = np.all(np.isfinite(corners), axis=1)
        ids = np.flatnonzero(found)
        cols = ids % (self.squares[0] - 1)
        rows = ids // (self.squares[0] - 1)
        if len(ids) < 4 or len(np.unique(cols)) < 2 or len(np.unique(rows)) < 2:
            return out, refined
        H, _ = cv2.findHomography(self.corner_squares[ids], corners[ids], 0)
        if H is None or not np.all(np.isfinite(H)):
            return out, refined
        h_img, w_img = img.shape[:2]
        for k in ids:
            c = self.corner_squares[k]
            p = cv2.perspectiveTransform(np.array([[c, c + [1e-3, 0], c + [0, 1e-3]]]), H)[0]
            scale = max(np.linalg.norm(p[1] - p[0]), np.linalg.norm(p[2] - p[0])) / 1e-3
            if not (np.isfinite(scale) and 4.0 <= scale <= self.pps):
                continue  # squares of < 4 px, or a homography gone wrong
            half = float(np.clip(self.max_half_px / scale, 0.25, self.half))
            T, A = self._template(c, scale, half)
            W = H @ A
            ct = np.linalg.solve(A, [c[0], c[1], 1.0])  # the corner in template pixels
            q = W @ ct
            shift = corners[k] - q[:2] / q[2]
            W = np.array([[1, 0, shift[0]], [0, 1, shift[1]], [0, 0, 1.0]]) @ W
            n = T.shape[0]
            box = cv2.perspectiveTransform(
                np.array([[[0, 0], [n - 1, 0], [0, n - 1], [n - 1, n - 1]]], float), W
            )[0]
            lo = np.floor(box.min(0) - 3).astype(int)
            hi = np.ceil(box.max(0) + 4).astype(int)
            full = float(np.prod(hi - lo))
            lo = np.maximum(lo, 0)
            hi = np.minimum(hi, [w_img, h_img])
            if np.any(hi - lo < 8) or np.prod(hi - lo) < 0.6 * full:
                continue  # most of the patch is outside the image
            W = np.array([[1, 0, -lo[0]], [0, 1, -lo[1]], [0, 0, 1.0]]) @ W
            roi = np.ascontiguousarray(img[lo[1] : hi[1], lo[0] : hi[0]])
            try:
                corr, W = cv2.findTransformECC(
                    T,
                    roi,
                    (W / W[2, 2]).astype(np.float32),
                    cv2.MOTION_HOMOGRAPHY,
                    self._criteria,
                    None,
                    1,
                )
            except cv2.error:
                continue  # ECC did not converge
            q = W.astype(float) @ ct
            if not (np.isfinite(corr) and corr >= self.min_corr and abs(q[2]) > 1e-12):
                continue
            pt = q[:2] / q[2] + lo
            limit = max(1.5, self.max_shift * scale)
            if np.all(np.isfinite(pt)) and np.linalg.norm(pt - corners[k]) <= limit:
                out[k] = pt
                refined[k] = True
        return out, refined


def detect_image(
    detector: cv2.aruco.CharucoDetector,
    image: np.ndarray,
    n_corners: int,
    upscale: int = DEFAULT_UPSCALE,
    refiner: CornerRefiner | None = None,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Board corners in one image.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8
    upscale : int
        Detect on an image enlarged by this factor (bicubic), then map back.
    refiner : CornerRefiner, optional
        Refine the corners at native resolution (then the refined mask is
        returned too).

    Returns
    -------
    corners : (N, 2) float
        Pixels (original image, OpenCV pixel-centre convention); NaN where absent.
    refined : (N,) bool
        Only with ``refiner``: corners the refiner placed.
    """
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if upscale > 1:
        big = cv2.resize(gray, None, fx=upscale, fy=upscale, interpolation=cv2.INTER_CUBIC)
    else:
        big = gray
    corners, ids, _, _ = detector.detectBoard(big)
    out = np.full((n_corners, 2), np.nan)
    if ids is not None and corners is not None and len(ids) > 0:
        ids = np.asarray(ids).reshape(-1)
        c = np.asarray(corners, dtype=float).reshape(-1, 2)
        if upscale > 1:
            # Pixel centres: x_big = s * x + (s - 1) / 2.
            c = (c - (upscale - 1) / 2.0) / upscale
        keep = (ids >= 0) & (ids < n_corners)
        out[ids[keep]] = c[keep]
    if refiner is None:
        return out
    return refiner.refine(gray, out)


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
    refine: bool = True,
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
    upscale : detection upscale factor (see :func:`detect_image`)
    refine : place the corners with :class:`CornerRefiner` (default)
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
    refiner = CornerRefiner(board) if refine else None
    cap = _open(path, camera)
    try:
        total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        if max_frames is not None:
            total = min(total, max_frames) if total > 0 else max_frames
        n_samples = (total + step - 1) // step if total > 0 else 0
        frames: list[int] = []
        corners: list[np.ndarray] = []
        refined: list[np.ndarray] = []
        size: tuple[int, int] | None = None
        index = 0
        while max_frames is None or index < max_frames:
            if index % step == 0:
                ok, image = cap.read()
                if not ok:
                    break
                if size is None:
                    size = (image.shape[1], image.shape[0])
                if refiner is None:
                    corners.append(detect_image(detector, image, geom.n_corners, upscale))
                else:
                    c, r = detect_image(detector, image, geom.n_corners, upscale, refiner)
                    corners.append(c)
                    refined.append(r)
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
        refined=np.stack(refined) if refiner is not None else None,
    )
