"""The working resolution of each camera: images as large as the features need.

Training renders thousands of silhouettes per camera and the fit rasterizes the
body hundreds of times per frame; both cost in proportion to the pixels, while
the features (shape contexts, radial distance function) and the chamfer
likelihood only need the person a few hundred pixels tall. A camera in which a
standing person would be much taller than that is therefore used at an
integer fraction ``1/k`` of its resolution (its *working resolution*):

- the rule looks at the calibration only (a standing 1.8 m person at the world
  origin, where training places its bodies), so it is deterministic and the
  models' cache key stays stable for a rig;
- ``k = max(1, floor(person_px / target_px))``: a camera is downscaled only
  when the person would be at least twice ``target_px`` tall, and then ends up
  between ``target_px`` and about twice that. The default target (320 px)
  keeps the 640x480 demo rig (people of 300-320 px) at full resolution and
  puts a 1080x1920 portrait camera (a person of ~960 px) at 1/3;
- integer factors make the downscaled mask a plain block average: every
  working pixel is the mean of its ``k x k`` block of camera pixels (fewer
  at the right and bottom edges of an image whose size is not a multiple of
  ``k``), thresholded at 0.5.

The working camera is :meth:`bodymetry.calibration.camera.Camera.scaled`
by ``1/k``. :class:`WorkingResolution` is the choice for a rig: it is recorded
in ``results.json`` and gives the working cameras and masks of a run
(:meth:`WorkingResolution.apply`, :meth:`WorkingResolution.downscale`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.errors import InputError

log = logging.getLogger(__name__)

__all__ = [
    "DEFAULT_WORKING_PERSON_PX",
    "PERSON_HEIGHT_M",
    "CameraScale",
    "WorkingResolution",
    "downscale_mask",
    "person_height_px",
    "working_factor",
]

#: Height of the standing person the rule projects, metres.
PERSON_HEIGHT_M = 1.8
#: Default target height of that person in a working image, pixels.
DEFAULT_WORKING_PERSON_PX = 320.0


def person_height_px(camera: Camera, height_m: float = PERSON_HEIGHT_M) -> float:
    """Image length of a standing person at the world origin.

    Parameters
    ----------
    camera : Camera
    height_m : float
        The person's height: a vertical segment from the floor at the world
        origin to ``height_m``, metres.

    Returns
    -------
    float
        Distance in pixels between the projections of its ends (with lens
        distortion); NaN when either end is behind the camera.
    """
    ends = camera.project(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, height_m]]))
    return float(np.linalg.norm(ends[1] - ends[0]))


def working_factor(person_px: float, target_px: float | None) -> int:
    """The integer downscale factor ``k`` of a camera (1: full resolution).

    Parameters
    ----------
    person_px : float
        :func:`person_height_px` of the camera (NaN: unknown, kept at 1).
    target_px : float or None
        The person's target height in the working image; None keeps every
        camera at full resolution.

    Returns
    -------
    int
        ``max(1, floor(person_px / target_px))``.
    """
    if target_px is None or not math.isfinite(person_px):
        return 1
    if not target_px > 0:
        raise ValueError(f"target_px: expected > 0 or None, got {target_px!r}")
    return max(1, math.floor(person_px / target_px))


def downscale_mask(mask: np.ndarray, factor: int, size: tuple[int, int]) -> np.ndarray:
    """Area-average a silhouette over ``factor x factor`` blocks, then threshold at 0.5.

    Parameters
    ----------
    mask : (H, W) bool
        At the camera's resolution.
    factor : int
        ``k >= 1``; 1 returns the mask unchanged (as bool).
    size : (int, int)
        The working image ``(width, height)``: ``Camera.scaled(1 / k).size``.
        Block ``(i, j)`` covers camera pixels ``[i k, i k + k)`` x ``[j k, j k + k)``;
        a partial block at the right or bottom edge averages the pixels it
        has, a block past the image (when the size rounds up) is empty.

    Returns
    -------
    (h, w) bool
        True where at least half of the block's pixels are True.

    Raises
    ------
    ValueError
        If ``factor`` is not a positive integer or ``size`` does not fit the mask.
    """
    m = np.asarray(mask, dtype=bool)
    if isinstance(factor, bool) or not isinstance(factor, (int, np.integer)) or factor < 1:
        raise ValueError(f"factor: expected an integer >= 1, got {factor!r}")
    if m.ndim != 2:
        raise ValueError(f"mask: expected a 2-D array, got shape {m.shape}")
    w, h = size
    H, W = m.shape
    if not (abs(w * factor - W) < factor and abs(h * factor - H) < factor):
        raise ValueError(
            f"mask of {W}x{H} (width x height) does not downscale by {factor} to {w}x{h}"
        )
    if factor == 1:
        return m
    k = int(factor)
    hp, wp = max(h, -(-H // k)) * k, max(w, -(-W // k)) * k
    padded = np.zeros((hp, wp), np.int32)
    padded[:H, :W] = m
    counts = np.zeros((hp, wp), np.int32)
    counts[:H, :W] = 1
    hits = padded.reshape(hp // k, k, wp // k, k).sum(axis=(1, 3))[:h, :w]
    n = counts.reshape(hp // k, k, wp // k, k).sum(axis=(1, 3))[:h, :w]
    return (n > 0) & (2 * hits >= n)


@dataclass(frozen=True)
class CameraScale:
    """One camera's working resolution.

    Attributes
    ----------
    factor : int
        ``k``: the working image is ``1/k`` of the camera's in width and height.
    calibrated_size : (int, int)
        The camera's image ``(width, height)`` (calibration, videos).
    size : (int, int)
        The working image ``(width, height)``.
    person_px : float or None
        :func:`person_height_px` at the camera's resolution (None: not known,
        as in runs recorded before working resolutions).
    """

    factor: int
    calibrated_size: tuple[int, int]
    size: tuple[int, int]
    person_px: float | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "factor": self.factor,
            "calibrated_size": list(self.calibrated_size),
            "size": list(self.size),
            "person_px": None if self.person_px is None else round(self.person_px, 1),
        }

    @classmethod
    def from_json(cls, data: Any, where: str) -> CameraScale:
        try:
            factor = data["factor"]
            full = tuple(int(v) for v in data["calibrated_size"])
            size = tuple(int(v) for v in data["size"])
            person = data.get("person_px")
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: malformed working resolution ({exc!r})") from exc
        if isinstance(factor, bool) or not isinstance(factor, int) or factor < 1:
            raise InputError(f"{where}.factor: expected an integer >= 1, got {factor!r}")
        if len(full) != 2 or len(size) != 2:
            raise InputError(f"{where}: sizes must be [width, height]")
        return cls(factor, full, size, None if person is None else float(person))  # type: ignore[arg-type]


@dataclass(frozen=True)
class WorkingResolution:
    """The working resolution of every camera of a rig.

    Attributes
    ----------
    target_px : float or None
        The target person height the factors were chosen for (None: every
        camera at full resolution).
    scales : dict of str to CameraScale
        Per camera name, in camera order.
    """

    target_px: float | None
    scales: dict[str, CameraScale]

    @classmethod
    def choose(cls, cameras: CameraGroup, target_px: float | None) -> WorkingResolution:
        """The rule (module docstring): each camera's factor from its person height.

        Logs one info line per camera that is downscaled.
        """
        scales = {}
        for cam in cameras:
            person = person_height_px(cam)
            k = working_factor(person, target_px)
            size = cam.scaled(1.0 / k).size if k > 1 else cam.size
            scales[cam.name] = CameraScale(
                k, cam.size, size, person if math.isfinite(person) else None
            )
            if k > 1:
                log.info(
                    "%s: %dx%d -> %dx%d working resolution (person ~%.0f px tall)",
                    cam.name,
                    *cam.size,
                    *size,
                    person,
                )
        return cls(target_px, scales)

    @classmethod
    def full(cls, cameras: CameraGroup) -> WorkingResolution:
        """Every camera at its own resolution (runs recorded before working resolutions)."""
        return cls(None, {c.name: CameraScale(1, c.size, c.size) for c in cameras})

    @property
    def factors(self) -> dict[str, int]:
        return {name: s.factor for name, s in self.scales.items()}

    @property
    def scaled(self) -> bool:
        """Whether any camera works below its resolution."""
        return any(s.factor > 1 for s in self.scales.values())

    def apply(self, cameras: CameraGroup) -> CameraGroup:
        """The working rig: each camera scaled by ``1/k`` (itself when k = 1).

        Raises
        ------
        InputError
            When a camera is not in this resolution or its size is not the one
            the factors were chosen for (a calibration changed since).
        """
        out = []
        for cam in cameras:
            scale = self.scales.get(cam.name)
            if scale is None:
                raise InputError(
                    f"camera {cam.name!r} has no working resolution "
                    f"(recorded for {', '.join(self.scales) or 'no camera'})"
                )
            if tuple(cam.size) != tuple(scale.calibrated_size):
                raise InputError(
                    f"camera {cam.name!r} is {cam.size[0]}x{cam.size[1]}, its working "
                    f"resolution was chosen for {scale.calibrated_size[0]}x"
                    f"{scale.calibrated_size[1]}"
                )
            working = cam if scale.factor == 1 else cam.scaled(1.0 / scale.factor)
            if working.size != tuple(scale.size):
                raise InputError(
                    f"camera {cam.name!r}: working size {working.size} differs from the "
                    f"recorded {tuple(scale.size)}"
                )
            out.append(working)
        return CameraGroup(out)

    def downscale(self, names: Sequence[str], masks: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Camera-resolution silhouettes -> working-resolution silhouettes.

        Parameters
        ----------
        names : sequence of C str
            The cameras of ``masks``, in order.
        masks : sequence of C (H_c, W_c) bool
            At each camera's resolution.

        Returns
        -------
        list of C (h_c, w_c) bool
            :func:`downscale_mask` of each (the same arrays where k = 1).
        """
        if len(names) != len(masks):
            raise ValueError(f"expected one mask per camera ({len(names)}), got {len(masks)}")
        out = []
        for name, mask in zip(names, masks, strict=True):
            scale = self.scales[name]
            try:
                out.append(downscale_mask(mask, scale.factor, scale.size))
            except ValueError as exc:
                raise ValueError(f"camera {name}: {exc}") from None
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "working_person_px": self.target_px,
            "cameras": {name: s.to_json() for name, s in self.scales.items()},
        }

    @classmethod
    def from_json(
        cls, data: Mapping[str, Any], where: str = "working_resolution"
    ) -> WorkingResolution:
        if not isinstance(data, Mapping) or not isinstance(data.get("cameras"), Mapping):
            raise InputError(f"{where}: expected an object with 'cameras'")
        target = data.get("working_person_px")
        return cls(
            None if target is None else float(target),
            {
                str(name): CameraScale.from_json(s, f"{where}.cameras.{name}")
                for name, s in data["cameras"].items()
            },
        )
