"""Background model per camera and shadow-suppressing background subtraction.

Background model (:class:`BackgroundModel`): per pixel and channel the median of
the empty-scene clip and a robust spread (interquartile range / 1.349, floored at
``min_sigma`` DN: H.264 encodes a static scene's noise mostly away, so the clip's
spread underestimates the noise of frames with a moving person). Without a
clip, the temporal median of the session's kept frames (the person moves, so
each pixel shows the background in most of them).

Subtraction (:func:`subtract`), methods (:data:`METHODS`):

``horprasert`` (default)
    Horprasert, Harwood and Davis (1999): the pixel colour ``I`` is compared with
    the background colour ``E`` along ``E`` (brightness distortion
    ``alpha = argmin |(I - alpha E) / sigma|``) and across it (chromaticity
    distortion ``CD = |(I - alpha E) / sigma|``, in noise units). A pixel that
    differs from the background (``|(I - E) / sigma| > fg_sigma``) is
    *shadow* when it is darker (``shadow_alpha_min <= alpha < 1``) with the
    same chromaticity (``CD <= shadow_cd``), and *person* otherwise. Brighter
    with the same chromaticity (a highlight) up to ``highlight_alpha_max`` is
    background.
``mog2``
    OpenCV's MOG2 (``detectShadows=True``) trained on the background frames,
    not updated while segmenting; its shadow label (127) is background.
``none``
    The difference test alone, no shadow suppression (the baseline).

Measured on studio sessions with cast shadows (``benchmarks/bench_capture.py``,
docs/capture.md): Horprasert is the default.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bodymetry.capture.colour import CHANGE_CHROMA_WEIGHT, LUMA
from bodymetry.errors import InputError

__all__ = [
    "METHODS",
    "BackgroundModel",
    "SubtractionConfig",
    "Subtractor",
    "horprasert_distortions",
    "read_clip",
    "subtract",
]

METHODS = ("horprasert", "mog2", "none")


@dataclass(frozen=True)
class SubtractionConfig:
    """Thresholds of the background subtraction.

    Attributes
    ----------
    method : {"horprasert", "mog2", "none"}
    fg_sigma : float
        A pixel differs from the background when its colour distance, in noise
        units (``sqrt(sum_c ((I_c - E_c) / sigma_c)^2)``), exceeds this.
    min_sigma : float
        Floor of the per-pixel noise sigma, DN.
    shadow_alpha_min : float
        Darkest shadow, as a fraction of the background brightness (deeper is person:
        dark hair, shoes).
    shadow_cd : float
        Largest chromaticity distortion of a shadow, noise units.
    highlight_alpha_max : float
        Brighter than the background by up to this factor with the same chromaticity:
        background (flicker, highlights).
    mog2_var_threshold, mog2_shadow_threshold : float
        MOG2's ``varThreshold`` and ``shadowThreshold`` (``tau``).
    """

    method: str = "horprasert"
    fg_sigma: float = 6.0
    min_sigma: float = 2.0
    shadow_alpha_min: float = 0.4
    shadow_cd: float = 3.0
    highlight_alpha_max: float = 1.12
    mog2_var_threshold: float = 16.0
    mog2_shadow_threshold: float = 0.4

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise InputError(
                f"background method {self.method!r}: expected one of {', '.join(METHODS)}"
            )
        for name in ("fg_sigma", "min_sigma", "shadow_cd", "mog2_var_threshold"):
            if not getattr(self, name) > 0:
                raise InputError(f"{name}: expected > 0, got {getattr(self, name)}")
        if not 0 <= self.shadow_alpha_min < 1:
            raise InputError(f"shadow_alpha_min: expected in [0, 1), got {self.shadow_alpha_min}")
        if not 0 < self.mog2_shadow_threshold < 1:
            raise InputError(
                f"mog2_shadow_threshold: expected in (0, 1), got {self.mog2_shadow_threshold}"
            )


@dataclass(frozen=True)
class BackgroundModel:
    """Robust per-pixel statistics of one camera's empty scene.

    Attributes
    ----------
    camera : str
    median : (H, W, 3) float32
        BGR median, DN.
    sigma : (H, W, 3) float32
        Robust noise sigma, DN (not floored; 0 with fewer than 4 frames): the
        interquartile range / 1.349 for a clip, 1.4826 x the median absolute
        deviation for session frames (robust to the person covering up to half).
    source : str
        ``"clip"`` (empty-scene clip) or ``"session"`` (temporal median of frames).
    frames : int
        Frames the statistics were computed from.
    samples : (N, H, W, 3) uint8 or None
        A few of the frames (for MOG2 training).
    """

    camera: str
    median: np.ndarray
    sigma: np.ndarray
    source: str
    frames: int
    samples: np.ndarray | None = None

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)``."""
        return (self.median.shape[1], self.median.shape[0])

    @classmethod
    def from_frames(
        cls, camera: str, frames: np.ndarray | Iterable[np.ndarray], source: str = "clip"
    ) -> BackgroundModel:
        """Statistics over ``frames`` (N, H, W, 3) uint8 (N >= 1)."""
        stack = np.asarray(frames if isinstance(frames, np.ndarray) else list(frames))
        if stack.ndim != 4 or stack.shape[-1] != 3 or stack.shape[0] < 1:
            raise InputError(
                f"camera {camera!r}: background frames must be (N, H, W, 3) with N >= 1, "
                f"got {stack.shape}"
            )
        n = stack.shape[0]
        # One sort per pixel gives the median and the quartiles (uint8 sorts fast).
        values = np.sort(np.ascontiguousarray(stack.reshape(n, -1).T), axis=1)
        lo, hi = values[:, (n - 1) // 2], values[:, n // 2]
        median = (0.5 * (lo.astype(np.float32) + hi)).reshape(stack.shape[1:])
        if n >= 4 and source != "clip":
            # Frames with a person: the median absolute deviation tolerates up to half
            # of them covering a pixel (the interquartile range only a quarter).
            mad = np.abs(values.astype(np.float32) - median.reshape(-1, 1))
            mad = np.partition(mad, (n - 1) // 2, axis=1)[:, (n - 1) // 2]
            sigma = (1.4826 * mad).reshape(stack.shape[1:])
        elif n >= 4:
            q1 = values[:, (n - 1) // 4].astype(np.float32)
            q3 = values[:, (3 * (n - 1) + 3) // 4].astype(np.float32)
            sigma = ((q3 - q1) / 1.349).reshape(stack.shape[1:])
        else:
            sigma = np.zeros_like(median)
        keep = np.linspace(0, stack.shape[0] - 1, min(stack.shape[0], 10)).round().astype(int)
        return cls(
            camera,
            median,
            sigma.astype(np.float32),
            source,
            int(stack.shape[0]),
            np.ascontiguousarray(stack[keep]).astype(np.uint8),
        )


def read_clip(
    path: str | Path, camera: str, max_frames: int = 60, what: str = "background clip"
) -> np.ndarray:
    """Up to ``max_frames`` frames of a clip, evenly spread (N, H, W, 3) uint8.

    Raises InputError naming the camera and the clip (called ``what`` in the
    message: a background clip, a calibration clip, a video) when the clip is
    missing or has no frame.
    """

    path = Path(path)
    if not path.is_file():
        raise InputError(f"camera {camera!r}: {what} not found: {path}")
    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    if not cap.isOpened():
        raise InputError(f"camera {camera!r}: cannot open the {what} {path}")
    try:
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        step = max(1, n // max_frames) if n > 0 else 1
        frames = []
        i = 0
        while len(frames) < max_frames:
            if not cap.grab():
                break
            if i % step == 0:
                ok, image = cap.retrieve()
                if ok:
                    frames.append(image)
            i += 1
    finally:
        cap.release()
    if not frames:
        raise InputError(f"camera {camera!r}: no frame of the {what} {path} decodes")
    return np.stack(frames)


def horprasert_distortions(
    image: np.ndarray, background: np.ndarray, sigma: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Brightness and chromaticity distortion of ``image`` against ``background``.

    Parameters
    ----------
    image : (H, W, 3) uint8 or float
    background, sigma : (H, W, 3) float32
        Background colour and noise sigma (> 0).

    Returns
    -------
    alpha : (H, W) float32
        Brightness distortion (1 = as bright as the background, 0.5 = half).
    cd : (H, W) float32
        Chromaticity distortion, noise units.
    dist : (H, W) float32
        Colour distance ``|(I - E) / sigma|``, noise units.
    """
    img = image.astype(np.float32)
    inv = 1.0 / sigma
    e = background * inv  # E / sigma
    i = img * inv  # I / sigma
    alpha = (i * e).sum(axis=2) / np.maximum((e * e).sum(axis=2), 1e-6)
    r = i - alpha[..., None] * e
    cd = np.sqrt((r * r).sum(axis=2))
    d = i - e
    dist = np.sqrt((d * d).sum(axis=2))
    return alpha, cd, dist


class Subtractor:
    """Background subtraction for one camera (see the module notes).

    Parameters
    ----------
    model : BackgroundModel
    config : SubtractionConfig
    """

    def __init__(self, model: BackgroundModel, config: SubtractionConfig | None = None) -> None:
        self.model = model
        self.config = config or SubtractionConfig()
        self.sigma = np.maximum(model.sigma, self.config.min_sigma).astype(np.float32)
        self._mog2 = None
        self._planes = None
        if self.config.method == "mog2":
            self._mog2 = self._train_mog2()

    def _train_mog2(self):

        cfg = self.config
        mog = cv2.createBackgroundSubtractorMOG2(
            history=500, varThreshold=cfg.mog2_var_threshold, detectShadows=True
        )
        mog.setShadowThreshold(cfg.mog2_shadow_threshold)
        samples = self.model.samples
        if samples is None or len(samples) == 0:
            samples = self.model.median.round().astype(np.uint8)[None]
        # A few passes so that every Gaussian has seen the noise.
        for _ in range(max(1, 30 // len(samples))):
            for frame in samples:
                mog.apply(frame, learningRate=-1)
        return mog

    def _distortions(self, image: np.ndarray, luma: bool = False) -> tuple[np.ndarray, ...]:
        """alpha, CD^2, |(I - E) / sigma|^2 (H, W) float32, channel planes for speed;
        with ``luma`` also the squared part of ``(I - E) / sigma`` along the luma axis
        (:data:`bodymetry.capture.colour.LUMA`)."""

        if self._planes is None:
            inv = 1.0 / self.sigma
            e = [np.ascontiguousarray(self.model.median[..., k] * inv[..., k]) for k in range(3)]
            ee = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
            self._planes = (
                [np.ascontiguousarray(inv[..., k]) for k in range(3)],
                e,
                ee,
                1.0 / np.maximum(ee, 1e-6),
                sum(np.float32(LUMA[k]) * e[k] for k in range(3)),
            )
        inv, e, ee, inv_ee, le = self._planes
        planes = cv2.split(image)
        i = [cv2.multiply(planes[k], inv[k], dtype=cv2.CV_32F) for k in range(3)]
        ie = i[0] * e[0] + i[1] * e[1] + i[2] * e[2]
        ii = i[0] * i[0] + i[1] * i[1] + i[2] * i[2]
        alpha = ie * inv_ee
        cd2 = ii - alpha * ie  # |i - alpha e|^2 with alpha = (i . e) / |e|^2
        dist2 = ii - 2.0 * ie + ee
        if not luma:
            return alpha, cd2, dist2
        along = sum(np.float32(LUMA[k]) * i[k] for k in range(3)) - le
        return alpha, cd2, dist2, along * along

    def labels(
        self,
        image: np.ndarray,
        distances: bool = False,
        brightness: bool = False,
        video: bool = False,
    ) -> tuple[np.ndarray, ...]:
        """Person and shadow masks of one image.

        Parameters
        ----------
        image : (H, W, 3) uint8 BGR, the camera's size
        distances : bool
            Also return the squared colour distance to the background.
        brightness : bool
            Also return the log brightness ratio to the background.
        video : bool
            Also return the squared colour distance with its chroma part weighed by
            :data:`~bodymetry.capture.colour.CHANGE_CHROMA_WEIGHT`.

        Returns
        -------
        person, shadow : (H, W) bool
            Raw (before clean-up) person pixels and suppressed shadow pixels.
        dist2 : (H, W) float32
            With ``distances``: ``|(I - E) / sigma|^2``, noise units squared
            (for MOG2, the Horprasert distance all the same).
        video2 : (H, W) float32
            With ``video``: the same distance as
            :func:`bodymetry.capture.colour.video_distance2` measures it at
            :data:`~bodymetry.capture.colour.CHANGE_CHROMA_WEIGHT` (luma part squared
            plus the weight times the chroma part squared). 4:2:0 video carries a
            saturated garment's chroma a pixel or two into the background beside it
            and into the gaps between a hanging arm and the trunk, where the luma is
            the background's; this distance leaves that chroma nearly out.
        log_alpha : (H, W) float32
            With ``brightness``: ``log`` of the brightness distortion ``alpha``
            (clipped at ``alpha = 1e-3``), e.g. for
            :func:`bodymetry.capture.shadows.floor_shadows`.
        """
        if image.shape != self.model.median.shape:
            raise InputError(
                f"camera {self.model.camera!r}: image is {image.shape[1]}x{image.shape[0]}, "
                f"its background model {self.model.size[0]}x{self.model.size[1]}"
            )
        cfg = self.config
        alpha, cd2, dist2, *luma2 = self._distortions(image, luma=video)
        if self._mog2 is not None:
            out = self._mog2.apply(image, learningRate=0)
            labels = (out == 255, out == 127)
        elif cfg.method == "none":
            labels = (dist2 > cfg.fg_sigma**2, np.zeros(dist2.shape, bool))
        else:
            changed = dist2 > cfg.fg_sigma**2
            same_chroma = cd2 <= cfg.shadow_cd**2
            shadow = changed & same_chroma & (alpha >= cfg.shadow_alpha_min) & (alpha < 1.0)
            highlight = changed & same_chroma & (alpha >= 1.0) & (alpha <= cfg.highlight_alpha_max)
            labels = (changed & ~shadow & ~highlight, shadow)
        extra = (dist2,) if distances else ()
        if video:
            # luma^2 + w chroma^2, with chroma^2 = dist2 - luma^2.
            w = np.float32(CHANGE_CHROMA_WEIGHT)
            extra += (w * dist2 + (np.float32(1.0) - w) * luma2[0],)
        if brightness:
            extra += (np.log(np.maximum(alpha, np.float32(1e-3))),)
        return (*labels, *extra)


def subtract(
    image: np.ndarray, model: BackgroundModel, config: SubtractionConfig | None = None
) -> np.ndarray:
    """(H, W) bool raw person mask of ``image`` (see :class:`Subtractor`)."""
    return Subtractor(model, config).labels(image)[0]
