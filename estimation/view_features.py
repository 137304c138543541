"""The features of one view's silhouette, as the discriminative stage uses them.

:func:`silhouette_features` traces the contour once for the radial distance
function and the shape contexts (training computes both for every rendered
view; fitting for every observed one); :func:`sc_features` encodes a
silhouette's shape contexts with a codebook into ``X_sc``. See
``docs/features.md``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bodymetry.estimation.codebook import Codebook
from bodymetry.estimation.features import RngLike, largest_blob, positive_int
from bodymetry.estimation.rdf import rdf_of_blob
from bodymetry.estimation.shape_context import (
    ShapeContextConfig,
    contour_descriptors,
    sc_descriptors,
)

__all__ = ["sc_features", "silhouette_features"]


def silhouette_features(
    mask: ArrayLike, rng: RngLike, config: ShapeContextConfig, n: int = 100
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`rdf` and :func:`sc_descriptors` of one silhouette, its contour traced once.

    The same values as the two calls (``rng`` drawn from as by
    :func:`sc_descriptors`); training computes both for every rendered view.

    Returns
    -------
    x_rdf : (n + 2,) float64
    descriptors : (S, config.n_points, config.n_bins) float64
    """
    if not isinstance(config, ShapeContextConfig):
        raise ValueError(f"config: expected a ShapeContextConfig, got {type(config).__name__}")
    blob = largest_blob(mask)
    descriptors = contour_descriptors(blob[3], rng, config)
    return rdf_of_blob(*blob, positive_int(n, "n")), descriptors


def sc_features(mask: ArrayLike, codebook: Codebook, rng: RngLike) -> NDArray[np.float64]:
    """Codebook shape-context feature ``X_sc`` of a silhouette.

    Samples ``codebook.config.n_points`` contour points, computes their
    multi-scale shape contexts and encodes them with ``codebook``.

    Parameters
    ----------
    mask : (H, W) bool
        Silhouette.
    codebook : Codebook
        From :func:`fit_codebook`.
    rng : numpy.random.Generator or int
        Sampling randomness.

    Returns
    -------
    x_sc : (S * K,) float64
        Non-negative, unit length.
    """
    if not isinstance(codebook, Codebook):
        raise ValueError(f"codebook: expected a Codebook, got {type(codebook).__name__}")
    return codebook.encode(sc_descriptors(mask, rng, codebook.config))
