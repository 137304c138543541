"""Fixtures shared by the estimation tests."""

from __future__ import annotations

import numpy as np
import pytest
from silhouette_shapes import figure_mask

from bodymetry.estimation.codebook import fit_codebook
from bodymetry.estimation.shape_context import ShapeContextConfig, sc_descriptors


@pytest.fixture(scope="session")
def codebook():
    """A K = 100 codebook of 18 stick-figure poses (the feature tests' own)."""
    cfg = ShapeContextConfig()
    masks = [
        figure_mask(300, (320, 60), arm=a, leg=g)
        for a in np.linspace(0.2, 2.8, 6)
        for g in (0.1, 0.3, 0.5)
    ]
    desc = np.concatenate([sc_descriptors(m, i, cfg) for i, m in enumerate(masks)], axis=1)
    return fit_codebook(desc, k=100, rng=0, config=cfg)
