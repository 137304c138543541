"""Camera registration from the fitted bodies (beyond the paper).

A calibration can be a few pixels off a recording (a camera knocked after the
calibration, a principal point the solver placed badly). The landmark check
(:func:`bodymetry.capture.landmarks.principal_point_offsets`) finds offsets of
2 % of the image height and more from the segmenter's landmarks; smaller ones
stay. Once every frame is fitted, the model's silhouettes say more: where a
camera is off, its model silhouettes sit shifted from its observed ones by
the same image offset in every frame, while the other cameras' agree (the
body's 3D pose takes up what all cameras share). On Pose2Sim's real
recordings the fitted bodies sit 1-3 px (at the working resolution) off the
observed silhouettes in the same direction in all ten frames of some cameras,
and a studio session with exact calibrations reads 0 px in every camera
(docs/generative.md, "Camera registration").

:func:`camera_shifts` measures each camera's offset: the overlap (IoU) of
observed and model silhouettes, pooled over the frames (intersections and
unions summed), as a function of an integer image shift of the model
silhouettes within ``search_px``; its peak, refined to sub-pixel by a parabola
through the neighbours on each axis. The fitted body moves to meet a camera that is off halfway, so
the others see part of its offset; the body's common motion that makes the
offsets sparsest is taken out (most cameras of a rig are right), as the
landmark check does. With three cameras or more, a camera whose own offset is
at least ``min_shift_px`` long, on at least ``min_frames`` frames, where the
shift seen raises the pooled IoU by at least ``min_gain``, and where most
frames' own best shifts point the same way (``min_agreement``), is off; the run shifts its
principal point by the offset (scaled to the camera's own resolution) and fits
the frames again (:func:`bodymetry.pipeline.register_cameras`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from bodymetry.calibration.camera import CameraGroup
from bodymetry.capture.landmarks import sparsest_offsets
from bodymetry.errors import InputError
from bodymetry.fileio import read_json_object, write_json_atomic
from bodymetry.settings import from_jsonable

__all__ = [
    "REGISTRATION_FORMAT",
    "CameraShift",
    "RegistrationConfig",
    "camera_shifts",
    "pooled_iou",
    "read_registration",
    "shift_mask",
    "write_registration",
]

#: The farthest the search goes when the peak lies on the edge of ``search_px``.
MAX_SEARCH_PX = 16

#: ``registration.json``'s format.
REGISTRATION_FORMAT = 1


@dataclass(frozen=True)
class RegistrationConfig:
    """When the fitted bodies shift a camera (:func:`camera_shifts`).

    Attributes
    ----------
    enabled : bool
        Off: the cameras stay as the calibration (and the landmark check) left them.
    search_px : int
        Largest shift tried per axis first, working-resolution pixels (doubled,
        up to :data:`MAX_SEARCH_PX`, while the peak lies on the grid's edge).
    min_shift_px : float
        A shorter own offset is left alone. The peak's own uncertainty is about
        a quarter of a pixel on exact silhouettes, but rough fits read more: on
        the tiny 240x180 test session, whose fits reach IoU 0.77, the right
        cameras read up to 1.2 px (render seeds 2-9, one camera 5 px off); on
        Pose2Sim's recordings the right cameras read at most 0.6 px.
    min_frames : int
        Fewest frames with both silhouettes in the camera.
    min_gain : float
        Smallest rise of the pooled IoU that the shift must bring.
    min_agreement : float
        Share of the frames whose own best integer shift lies within one pixel
        of the pooled one on both axes.
    """

    enabled: bool = True
    search_px: int = 4
    min_shift_px: float = 1.5
    min_frames: int = 3
    min_gain: float = 0.005
    min_agreement: float = 0.6

    def __post_init__(self) -> None:
        if not 1 <= self.search_px <= MAX_SEARCH_PX:
            raise InputError(
                f"registration.search_px: expected 1..{MAX_SEARCH_PX}, got {self.search_px}"
            )
        if not self.min_shift_px > 0:
            raise InputError(f"registration.min_shift_px: expected > 0, got {self.min_shift_px}")
        if self.min_frames < 1:
            raise InputError(f"registration.min_frames: expected >= 1, got {self.min_frames}")
        if not 0.0 <= self.min_agreement <= 1.0:
            raise InputError(f"registration.min_agreement: expected 0..1, got {self.min_agreement}")


@dataclass(frozen=True)
class CameraShift:
    """One camera's registration offset.

    Attributes
    ----------
    camera : str
    dx, dy : float
        The camera's own offset, working-resolution pixels (x right, y down):
        the principal point moves by as much. The offsets seen, less the common
        motion of the body that makes them sparsest (most cameras are right).
    seen_dx, seen_dy : float
        The offset seen: by how much the model silhouettes move onto the
        observed ones at the pooled IoU's peak.
    frames : int
        Frames it rests on.
    iou_before, iou_after : float
        Pooled IoU unshifted and at the integer peak.
    agreement : float
        Share of frames whose own best shift agrees (within 1 px).
    applied : bool
    """

    camera: str
    dx: float
    dy: float
    seen_dx: float
    seen_dy: float
    frames: int
    iou_before: float
    iou_after: float
    agreement: float
    applied: bool

    def describe(self) -> str:
        return (
            f"camera {self.camera!r}: the fitted bodies sit {self.seen_dx:+.1f} px in x and "
            f"{self.seen_dy:+.1f} px in y (working resolution) off the observed silhouettes in "
            f"{self.agreement:.0%} of {self.frames} frames (pooled IoU {self.iou_before:.3f}, "
            f"{self.iou_after:.3f} shifted); the camera's own offset, the body's common "
            f"motion taken out: {self.dx:+.1f}, {self.dy:+.1f} px"
        )


def shift_mask(mask: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """``mask`` (H, W) moved by (dx, dy) whole pixels, zeros shifted in (no wrap)."""
    h, w = mask.shape
    out = np.zeros_like(mask)
    ys, yd = (slice(0, h - dy), slice(dy, h)) if dy >= 0 else (slice(-dy, h), slice(0, h + dy))
    xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w), slice(0, w + dx))
    out[yd, xd] = mask[ys, xs]
    return out


def pooled_iou(
    pairs: Sequence[tuple[np.ndarray, np.ndarray]], search_px: int
) -> tuple[np.ndarray, np.ndarray]:
    """Pooled IoU of the model silhouettes shifted over a grid, and each frame's best shift.

    Parameters
    ----------
    pairs : sequence of ((H, W) bool, (H, W) bool)
        Per frame, the observed and the model silhouette of one camera.
    search_px : int
        s: shifts -s..s on each axis.

    Returns
    -------
    surface : (2s+1, 2s+1) float
        ``[dy + s, dx + s]``: summed intersections over summed unions.
    best : (F, 2) int
        Each frame's own best (dx, dy).
    """
    s = search_px
    n = 2 * s + 1
    inter = np.zeros((n, n))
    union = np.zeros((n, n))
    best = np.zeros((len(pairs), 2), int)
    for f, (observed, model) in enumerate(pairs):
        observed = np.asarray(observed, bool)
        model = np.asarray(model, bool)
        # Crop to both silhouettes with the search margin: the shifts only move pixels there.
        ys, xs = np.nonzero(observed | model)
        y0, y1 = max(ys.min() - s, 0), min(ys.max() + s + 1, observed.shape[0])
        x0, x1 = max(xs.min() - s, 0), min(xs.max() + s + 1, observed.shape[1])
        o, m = observed[y0:y1, x0:x1], model[y0:y1, x0:x1]
        n_o, n_m = o.sum(), m.sum()
        frame = np.zeros((n, n))
        for iy, dy in enumerate(range(-s, s + 1)):
            for ix, dx in enumerate(range(-s, s + 1)):
                both = np.count_nonzero(o & shift_mask(m, dx, dy))
                inter[iy, ix] += both
                union[iy, ix] += n_o + n_m - both
                frame[iy, ix] = both / max(n_o + n_m - both, 1)
        iy, ix = np.unravel_index(np.argmax(frame), frame.shape)
        best[f] = (ix - s, iy - s)
    return inter / np.maximum(union, 1), best


def _parabola_peak(left: float, centre: float, right: float) -> float:
    """Offset (-0.5..0.5) of the vertex of the parabola through three equally spaced samples."""
    curvature = left - 2.0 * centre + right
    if curvature >= 0:  # not a maximum (flat or at the grid's edge)
        return 0.0
    return float(np.clip(0.5 * (left - right) / curvature, -0.5, 0.5))


def camera_shifts(
    cameras: CameraGroup,
    pairs: Sequence[Sequence[tuple[np.ndarray, np.ndarray]]],
    centre: np.ndarray,
    config: RegistrationConfig | None = None,
) -> list[CameraShift]:
    """Each camera's offset between its model and observed silhouettes over the frames.

    The offsets seen are what the fit left: where one camera is off, the fitted
    body moves to meet it halfway, and the others see part of its offset. The
    body's common motion that makes the offsets sparsest is taken out
    (:func:`bodymetry.capture.landmarks.sparsest_offsets`), which puts the
    offset back on the camera that is off.

    Parameters
    ----------
    cameras : CameraGroup
        The C working cameras (the silhouettes' pixels).
    pairs : sequence of C sequences of ((H, W) bool, (H, W) bool)
        Per camera, per frame, the observed and the model silhouette (pairs
        with an empty silhouette are left out).
    centre : (3,) float
        Where the subject stood, world metres (e.g. the median of the fitted τ).
    config : RegistrationConfig, optional

    Returns
    -------
    list of CameraShift
        Per camera, applied or not (a camera with no frames: 0, not applied).
    """
    cfg = config or RegistrationConfig()
    if len(cameras) != len(pairs):
        raise InputError(f"registration: {len(cameras)} cameras but {len(pairs)} mask lists")
    seen = np.zeros((len(cameras), 2))
    stats = []
    for c, cam_pairs in enumerate(pairs):
        cam_pairs = [(o, m) for o, m in cam_pairs if np.any(o) and np.any(m)]
        if not cam_pairs:
            stats.append((0, 0.0, 0.0, 0.0))
            continue
        s = cfg.search_px
        while True:
            surface, best = pooled_iou(cam_pairs, s)
            iy, ix = np.unravel_index(np.argmax(surface), surface.shape)
            # A peak on the grid's edge may lie beyond it: search twice as far.
            if (0 < ix < 2 * s and 0 < iy < 2 * s) or s >= MAX_SEARCH_PX:
                break
            s = min(2 * s, MAX_SEARCH_PX)
        seen[c] = (ix - s, iy - s)
        if 0 < ix < 2 * s:
            seen[c, 0] += _parabola_peak(surface[iy, ix - 1], surface[iy, ix], surface[iy, ix + 1])
        if 0 < iy < 2 * s:
            seen[c, 1] += _parabola_peak(surface[iy - 1, ix], surface[iy, ix], surface[iy + 1, ix])
        agree = float(np.mean(np.all(np.abs(best - (ix - s, iy - s)) <= 1, axis=1)))
        stats.append((len(cam_pairs), float(surface[s, s]), float(surface[iy, ix]), agree))
    counted = np.array([n > 0 for n, *_ in stats])
    own = np.zeros_like(seen)
    if counted.sum() >= 3:  # two cameras cannot say which of them is off
        sub = CameraGroup([cam for cam, k in zip(cameras, counted, strict=True) if k])
        own[counted] = sparsest_offsets(sub, seen[counted], np.asarray(centre, float))
    out = []
    for c, cam in enumerate(cameras):
        n, before, after, agree = stats[c]
        applied = (
            counted.sum() >= 3
            and np.hypot(*own[c]) >= cfg.min_shift_px
            and n >= cfg.min_frames
            and after - before >= cfg.min_gain
            and agree >= cfg.min_agreement
        )
        dx, dy = own[c].tolist()
        sx, sy = seen[c].tolist()
        out.append(CameraShift(cam.name, dx, dy, sx, sy, n, before, after, agree, bool(applied)))
    return out


def write_registration(path: Path, shifts: Sequence[CameraShift]) -> None:
    """Write ``registration.json`` (atomically): every camera's measured offset."""
    write_json_atomic(path, {"format": REGISTRATION_FORMAT, "cameras": [asdict(s) for s in shifts]})


def read_registration(path: Path) -> list[CameraShift]:
    """Read ``registration.json``; InputError naming the file and the problem."""
    data = read_json_object(path, what="registration file")
    if data.get("format") != REGISTRATION_FORMAT:
        raise InputError(f"{path}: format {data.get('format')!r}, expected {REGISTRATION_FORMAT}")
    cameras = data.get("cameras")
    if not isinstance(cameras, list):
        raise InputError(f"{path}: 'cameras' must be a list")
    out = []
    for i, entry in enumerate(cameras):
        where = f"{path}: cameras[{i}]"
        if not isinstance(entry, dict):
            raise InputError(f"{where}: expected an object, got {entry!r}")
        shift = from_jsonable(CameraShift, entry, where)
        if not (np.isfinite(shift.dx) and np.isfinite(shift.dy)):
            raise InputError(f"{where}: offsets must be finite")
        out.append(shift)
    return out
