"""Radial distance function of a silhouette (paper §3, :func:`rdf`).

The silhouette centroid followed by the maximal extent of the outer contour in
``n`` equally spaced directions from it, in pixels. Deliberately *not*
translation or scale invariant: with a calibrated, fixed camera, position and
size carry the body's location and height. Conventions (masks, image points,
angles) are :mod:`bodymetry.estimation.features`'; see ``docs/features.md``.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from bodymetry.estimation.features import compiled_kernels, largest_blob, positive_int

__all__ = ["rdf", "rdf_batch", "rdf_of_blob"]


def _simplify(contour: NDArray[np.float64]) -> NDArray[np.float64]:
    """Drop points whose incoming and outgoing steps are equal (collinear runs).

    Same polygon as the input, like ``CHAIN_APPROX_SIMPLE``; ``(P', 2)``.
    """
    if contour.shape[0] < 3:
        return contour
    d_in = contour - np.roll(contour, 1, axis=0)
    d_out = np.roll(contour, -1, axis=0) - contour
    keep = np.any(d_in != d_out, axis=1)
    return contour[keep] if keep.any() else contour[:1]


def _ray_extents(
    polygon: NDArray[np.float64], center: NDArray[np.float64], n: int
) -> NDArray[np.float64]:
    """Farthest intersection of ``n`` rays from ``center`` with a closed polygon.

    ``polygon`` is ``(P, 2)``, implicitly closed. Returns ``(n,)`` distances;
    a ray that meets no edge (possible only if ``center`` lies outside the
    polygon) gets 0.

    O(P + n * winding): each edge is intersected only with the rays inside the
    angle it subtends at the centre (an edge never subtends pi or more unless
    it passes through the centre, which is then handled as a zero distance).
    """
    step = 2.0 * np.pi / n
    a = polygon - center  # (P, 2) vertices relative to the centre
    if a.shape[0] == 1:
        return np.full(n, float(np.hypot(a[0, 0], a[0, 1])))
    b = np.roll(a, -1, axis=0)
    e = b - a  # edge vectors
    phi = np.arctan2(a[:, 1], a[:, 0])  # vertex angles in (-pi, pi]
    dphi = np.roll(phi, -1) - phi
    dphi -= 2.0 * np.pi * np.round(dphi / (2.0 * np.pi))  # signed, in [-pi, pi]
    lo = np.minimum(phi, phi + dphi) - 1e-9  # widened: no ray slips between edges
    hi = np.maximum(phi, phi + dphi) + 1e-9
    k_lo = np.ceil(lo / step).astype(np.int64)
    k_hi = np.floor(hi / step).astype(np.int64)
    count = np.maximum(k_hi - k_lo + 1, 0)
    edge = np.repeat(np.arange(a.shape[0]), count)  # one (edge, ray) pair per row
    first = np.repeat(np.cumsum(count) - count, count)
    k = np.repeat(k_lo, count) + (np.arange(edge.size) - first)
    ang = k * step
    d = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    ae, ee = a[edge], e[edge]
    denom = d[:, 0] * ee[:, 1] - d[:, 1] * ee[:, 0]  # d x e
    a_x_d = ae[:, 0] * d[:, 1] - ae[:, 1] * d[:, 0]  # a x d
    radial = np.abs(denom) <= 1e-12 * (1.0 + np.hypot(ee[:, 0], ee[:, 1]))
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.clip(np.where(radial, 0.0, a_x_d / denom), 0.0, 1.0)
    p = ae + u[:, None] * ee
    dist = np.hypot(p[:, 0], p[:, 1])
    # an edge along the ray: its farther end
    far = np.maximum(np.hypot(ae[:, 0], ae[:, 1]), np.hypot(*b[edge].T))
    dist = np.where(radial, far, dist)
    ext = np.zeros(n)
    np.maximum.at(ext, k % n, dist)
    return ext


def rdf(mask: ArrayLike, n: int = 100) -> NDArray[np.float64]:
    """Radial distance function of a silhouette (paper §3).

    ``X_rdf = (p_c, ||p_1 - p_c||, ..., ||p_n - p_c||)``: the centroid ``p_c`` of
    the largest blob, followed by the maximal extent of its outer contour in
    ``n`` equally spaced directions from the centroid.

    The extent in direction ``i`` (angle ``2 pi i / n`` from ``+x`` towards
    ``+y``) is found by ray casting: the distance from ``p_c`` to the farthest
    intersection of the ray with the outer-contour polygon (through boundary
    pixel centres, with collinear points dropped as ``CHAIN_APPROX_SIMPLE``
    does, which leaves the polygon unchanged). Unlike the farthest contour point
    in an angular bin, this is continuous in the shape, defined in every
    direction (no empty bins) and exact for thin limbs. If the centroid lies
    outside the silhouette (possible for strongly bent shapes), a direction
    whose ray misses the contour gets extent 0.

    Parameters
    ----------
    mask : (H, W) bool
        Silhouette (non-zero = foreground).
    n : int, default 100
        Number of directions.

    Returns
    -------
    x_rdf : (n + 2,) float64
        ``[cx, cy, r_0, ..., r_{n-1}]`` in pixels: the centroid (mean of the
        blob's pixel centres, holes excluded) then the extents. Not translation
        or scale invariant, as the paper says: a translation moves ``p_c`` by
        the same amount and leaves the extents unchanged; scaling the
        silhouette by ``s`` scales the extents by ``s``. Extents are measured
        to boundary pixel centres, i.e. about half a pixel inside the edge of
        the silhouette's pixel area.

    Raises
    ------
    ValueError
        If ``mask`` is not a 2-D numeric array, is empty, or ``n < 1``.
    """
    n = positive_int(n, "n")
    return rdf_of_blob(*largest_blob(mask), n)


def rdf_of_blob(
    roi: NDArray[np.uint8], x0: int, y0: int, contour: NDArray[np.float64], n: int
) -> NDArray[np.float64]:
    """:func:`rdf` of a blob already found by :func:`~bodymetry.estimation.features.largest_blob`.

    Parameters
    ----------
    roi : (h, w) uint8
        0/1 pixels of the blob inside its bounding box.
    x0, y0 : int
        Image coordinates of ``roi[0, 0]``.
    contour : (P, 2) float64
        The blob's outer contour.
    n : int
        Number of directions (checked by the caller).

    Returns
    -------
    x_rdf : (n + 2,) float64
        As :func:`rdf`.
    """
    mom = cv2.moments(roi, binaryImage=True)
    center = np.array([mom["m10"] / mom["m00"] + x0, mom["m01"] / mom["m00"] + y0])
    out = np.empty(n + 2)
    out[:2] = center
    kernels = compiled_kernels()
    if kernels is None:
        out[2:] = _ray_extents(_simplify(contour), center, n)
    else:
        kernels.ray_extents_kernel(contour, float(center[0]), float(center[1]), n, out[2:])
    return out


def rdf_batch(masks: ArrayLike | Sequence[ArrayLike], n: int = 100) -> NDArray[np.float64]:
    """:func:`rdf` of several masks, e.g. one per camera.

    Parameters
    ----------
    masks : (B, H, W) bool, or sequence of B (H_b, W_b) bool
        Silhouettes; as a sequence they may differ in size (cameras of a rig
        with different image sizes). Each RDF is in its own mask's pixels.
    n : int, default 100
        Number of directions.

    Returns
    -------
    x_rdf : (B, n + 2) float64
        One RDF per mask. Contours differ in length, so this is a loop over
        masks (each :func:`rdf` is already vectorized over directions).

    Raises
    ------
    ValueError
        If ``masks`` is neither a 3-D stack nor a sequence of 2-D masks, or any
        mask is empty (the message names the index).
    """
    if isinstance(masks, np.ndarray) or not isinstance(masks, Sequence):
        arr = np.asarray(masks)
        if arr.ndim != 3:
            raise ValueError(f"masks: expected a 3-D (B, H, W) stack, got shape {arr.shape}")
        items: Sequence[ArrayLike] = list(arr)
    else:
        items = masks
        for i, m in enumerate(items):
            if np.ndim(m) != 2:
                raise ValueError(f"masks[{i}]: expected a 2-D (H, W) mask, got shape {np.shape(m)}")
    n = positive_int(n, "n")
    out = np.empty((len(items), n + 2))
    for i, mask in enumerate(items):
        try:
            out[i] = rdf(mask, n)
        except ValueError as exc:
            raise ValueError(f"masks[{i}]: {exc}") from None
    return out
