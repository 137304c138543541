"""Silhouette features for discriminative estimation (paper §3).

Two descriptors of one view's silhouette:

* **Radial distance function** (RDF, :func:`rdf`): the silhouette centroid
  followed by the maximal extent of the outer contour in ``n`` equally spaced
  directions from it, in pixels. Deliberately *not* translation or scale
  invariant: with a calibrated, fixed camera, position and size carry the
  body's location and height.
* **Histograms of shape context** (SC, :func:`sc_features`): log-polar
  histograms (``n_theta = 12`` orientations x ``n_r = 5`` radii, outer radius
  ``r_out = kappa * h`` with ``h`` the silhouette height) at randomly sampled
  contour points, vector-quantized into a K-centre k-means :class:`Codebook`
  with soft voting and normalized to unit length. Translation and scale
  invariant by construction, but not rotation invariant (orientation is
  measured against the image axes, because the pose matters).

Conventions
-----------
* Masks are 2-D arrays ``(H, W)``; ``bool`` or any integer/float array whose
  non-zero pixels are the foreground. Only the largest blob (by enclosed area) is
  used (the capture stage cleans masks to one person blob anyway).
* Image points are ``(x, y)`` pixel-centre coordinates: ``x`` = column
  (right), ``y`` = row (down), as OpenCV.
* Angles are measured in the image frame from ``+x`` towards ``+y`` (that is
  clockwise on screen), starting at ``0``.
* Every random choice takes ``rng``: a :class:`numpy.random.Generator` or an
  integer seed. The same inputs and seed give the same output.

The modules, one job each:

* :mod:`~bodymetry.estimation.features` (this one): what the others share: the
  implementation they run (:data:`BACKEND`), the checks of their arguments,
  and the largest blob of a mask with its outer contour;
* :mod:`~bodymetry.estimation.rdf`: the radial distance function;
* :mod:`~bodymetry.estimation.shape_context`: the log-polar histograms;
* :mod:`~bodymetry.estimation.codebook`: the k-means codebook and its encoding;
* :mod:`~bodymetry.estimation.view_features`: one view's features, its contour
  traced once (what training and fitting compute);
* :mod:`~bodymetry.estimation.feature_drawing`: drawings for figures and overlays.

See ``docs/features.md`` for the definitions, the design choices and timings.
"""

from __future__ import annotations

import numbers
import os
from types import ModuleType

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from bodymetry.estimation.backends import default_backend, module_kernels

__all__ = [
    "BACKEND",
    "RngLike",
    "as_rng",
    "compiled_kernels",
    "largest_blob",
    "positive_float",
    "positive_int",
    "silhouette_contour",
]

#: A random generator or an integer seed.
RngLike = np.random.Generator | int | np.integer

_BACKENDS = ("numba", "numpy")

#: The implementation of the shape-context histograms, the codebook encoding and
#: the RDF's ray casting: ``"numba"`` (``feature_kernels.py``: the same
#: histograms, encodings equal to about 1e-15, extents to about 1e-12 px) or
#: ``"numpy"`` (the reference). From ``$BODYMETRY_FEATURES``; by
#: default numba when installed. Read at every call, so tests and benchmarks may
#: set it.
BACKEND: str = default_backend(
    "BODYMETRY_FEATURES", os.environ.get("BODYMETRY_FEATURES"), _BACKENDS, "numba"
)


def compiled_kernels() -> ModuleType | None:
    """The compiled feature kernels for :data:`BACKEND`.

    Returns
    -------
    module or None
        ``bodymetry.estimation.feature_kernels`` (imported on first use, with
        numba), or None for the numpy path: when :data:`BACKEND` is
        ``"numpy"``, or numba fails to import and was not asked for (then
        :data:`BACKEND` becomes ``"numpy"``).

    Raises
    ------
    ValueError
        When :data:`BACKEND` is neither ``"numba"`` nor ``"numpy"``.
    """
    return module_kernels(
        globals(),
        "BACKEND",
        "bodymetry.estimation.feature_kernels",
        "BODYMETRY_FEATURES",
        "shape-context features",
    )


# --------------------------------------------------------------------------
# argument checks
# --------------------------------------------------------------------------


def as_rng(rng: RngLike, name: str = "rng") -> np.random.Generator:
    """A random generator from a generator (returned as is) or an integer seed.

    Raises
    ------
    ValueError
        For anything else (the message names ``name``).
    """
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, numbers.Integral) and not isinstance(rng, bool):
        return np.random.default_rng(int(rng))
    raise ValueError(f"{name}: expected a numpy.random.Generator or an int seed, got {rng!r}")


def positive_int(value: object, name: str, minimum: int = 1) -> int:
    """``value`` as an ``int``, checked to be an integer (not a bool) ``>= minimum``.

    Raises
    ------
    ValueError
        Otherwise (the message names ``name``).
    """
    if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < minimum:
        raise ValueError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    return int(value)


def positive_float(value: object, name: str) -> float:
    """``value`` as a ``float``, checked to be a finite real number ``> 0`` (not a bool).

    Raises
    ------
    ValueError
        Otherwise (the message names ``name``).
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name}: expected a positive number, got {value!r}")
    v = float(value)
    if not np.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name}: expected a positive finite number, got {value!r}")
    return v


def _as_mask(mask: ArrayLike, name: str = "mask") -> NDArray[np.uint8]:
    """Validate a 2-D mask and return it as a 0/1 ``uint8`` array ``(H, W)``."""
    arr = np.asarray(mask)
    if arr.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D (H, W) mask, got shape {arr.shape}")
    if arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"{name}: expected a non-empty (H, W) mask, got shape {arr.shape}")
    if arr.dtype == np.bool_:
        return arr.view(np.uint8)
    if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise ValueError(f"{name}: expected a bool or numeric mask, got dtype {arr.dtype}")
    return (arr != 0).view(np.uint8)


def largest_blob(
    mask: ArrayLike, name: str = "mask"
) -> tuple[NDArray[np.uint8], int, int, NDArray[np.float64]]:
    """The largest blob of a mask: its pixels and its outer contour.

    Parameters
    ----------
    mask : (H, W) bool
        Silhouette; any numeric array is accepted with non-zero = foreground.
    name : str, default "mask"
        The argument's name in error messages.

    The largest blob is the external contour enclosing the largest area
    (``cv2.contourArea``; ties go to the longer contour, then the first found).

    Returns
    -------
    roi : (h, w) uint8
        0/1 pixels of the blob alone (holes kept) inside its bounding box.
    x0, y0 : int
        Image coordinates of ``roi[0, 0]``.
    contour : (P, 2) float64
        Its boundary pixel centres ``(x, y)``, ``CHAIN_APPROX_NONE``, oriented
        clockwise on screen, starting at the top-most, then left-most pixel.
    """
    m = _as_mask(mask, name)
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise ValueError(f"{name}: the mask is empty (no foreground pixel), shape {m.shape}")
    if len(contours) == 1:
        best = contours[0]
    else:
        best = max(contours, key=lambda c: (cv2.contourArea(c), len(c)))
    x0, y0, w, h = cv2.boundingRect(best)
    roi = m[y0 : y0 + h, x0 : x0 + w]
    if len(contours) > 1:  # keep only this blob's pixels (and its holes)
        fill = np.zeros((h, w), np.uint8)
        cv2.drawContours(fill, [best], -1, 1, cv2.FILLED, offset=(-x0, -y0))
        roi = roi & fill
    c = best.reshape(-1, 2).astype(np.float64)
    # consistent orientation: positive shoelace area in (x right, y down),
    # i.e. clockwise on screen (OpenCV returns outer contours the other way).
    x, y = c[:, 0], c[:, 1]
    if np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)) < 0:
        c = np.concatenate([c[:1], c[:0:-1]])  # same start point, reversed
    return roi, x0, y0, c


def silhouette_contour(mask: ArrayLike) -> NDArray[np.float64]:
    """External boundary of the largest blob of a silhouette mask.

    The largest blob is the external contour enclosing the largest area.

    Parameters
    ----------
    mask : (H, W) bool
        Silhouette; any numeric array is accepted with non-zero = foreground.

    Returns
    -------
    contour : (P, 2) float64
        Every boundary pixel centre ``(x, y)`` of the largest blob
        (``cv2.findContours``, ``RETR_EXTERNAL``, ``CHAIN_APPROX_NONE``), in
        order along the boundary, starting at the top-most (then left-most)
        pixel and oriented clockwise on screen (positive shoelace area in image
        coordinates). Consecutive points are 8-neighbours; holes are ignored.
        A single-pixel blob gives ``P = 1``.

    Raises
    ------
    ValueError
        If ``mask`` is not 2-D, not numeric, or has no foreground pixel.
    """
    return largest_blob(mask)[3]
