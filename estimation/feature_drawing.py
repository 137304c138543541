"""Drawings of the silhouette features on an image (the docs figure, review overlays).

:func:`draw_rdf` draws a radial distance function's rays;
:func:`draw_shape_context_grid` the log-polar grid of one shape context.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from bodymetry.estimation.shape_context import DEFAULT_R_IN_FRACTION

__all__ = ["draw_rdf", "draw_shape_context_grid"]


def draw_rdf(
    image: NDArray[np.uint8],
    x_rdf: ArrayLike,
    color: tuple[int, int, int] = (0, 90, 255),
    thickness: int = 1,
) -> NDArray[np.uint8]:
    """Draw an RDF (rays from the centroid to the extents) on a BGR image, in place.

    Parameters
    ----------
    image : (H, W, 3) uint8
        BGR image (modified and returned).
    x_rdf : (n + 2,) float
        From :func:`rdf`.
    """
    x = np.asarray(x_rdf, dtype=np.float64)
    if x.ndim != 1 or x.size < 3:
        raise ValueError(f"x_rdf: expected an (n + 2,) vector, got shape {x.shape}")
    c, r = x[:2], x[2:]
    ang = np.arange(r.size) * (2.0 * np.pi / r.size)
    ends = c + r[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    s = 1 << 4
    c_i = tuple(int(v) for v in np.round(c * s))
    for e in np.round(ends * s).astype(np.int64):
        cv2.line(image, c_i, (int(e[0]), int(e[1])), color, thickness, cv2.LINE_AA, 4)
        cv2.circle(image, (int(e[0]), int(e[1])), 2 * s, color, -1, cv2.LINE_AA, 4)
    cv2.circle(image, c_i, 4 * s, (0, 0, 0), -1, cv2.LINE_AA, 4)
    return image


def draw_shape_context_grid(
    image: NDArray[np.uint8],
    point: ArrayLike,
    r_out: float,
    n_theta: int = 12,
    n_r: int = 5,
    r_in_fraction: float = DEFAULT_R_IN_FRACTION,
    color: tuple[int, int, int] = (200, 120, 0),
    thickness: int = 1,
) -> NDArray[np.uint8]:
    """Draw the log-polar shape-context grid around ``point`` on a BGR image, in place.

    Circles at the radial bin edges ``r_in g^k`` (``k = 0 .. n_r``) and the
    orientation bin edges (``(k + 1/2) 2 pi / n_theta``, bins centred on the
    image axes) between ``r_in`` and ``r_out``.
    """
    p = np.asarray(point, dtype=np.float64).reshape(2)
    r_in = r_in_fraction * r_out
    radii = r_in * (r_out / r_in) ** (np.arange(n_r + 1) / n_r)
    s = 1 << 4
    c_i = tuple(int(v) for v in np.round(p * s))
    for r in radii:
        cv2.circle(image, c_i, round(r * s), color, thickness, cv2.LINE_AA, 4)
    for k in range(n_theta):
        a = (k + 0.5) * 2.0 * np.pi / n_theta
        d = np.array([np.cos(a), np.sin(a)])
        p0, p1 = np.round((p + r_in * d) * s), np.round((p + r_out * d) * s)
        cv2.line(
            image,
            (int(p0[0]), int(p0[1])),
            (int(p1[0]), int(p1[1])),
            color,
            thickness,
            cv2.LINE_AA,
            4,
        )
    return image
