"""The posing comparison's distances (``benchmarks/bench_posing.py``)."""

import numpy as np
import pytest

from benchmarks.bench_posing import _region_distances
from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.body_model.skeleton import PARTS


@pytest.fixture(scope="module")
def mesh():
    model = BodyModel.load()
    return model.canonical_vertices(np.zeros((1, model.n_shape))), model.vertex_parts


def test_the_same_body_anywhere_is_no_distance(mesh):
    vertices, parts = mesh
    moved = vertices + np.array([0.3, -0.2, 0.1])  # the trunks are aligned first
    distances, spacing = _region_distances(moved, vertices, parts)
    for name, d in distances.items():
        assert d[0] == pytest.approx(0.0, abs=1e-9), name
    assert spacing[0] == pytest.approx(0.0, abs=1e-9)


def test_an_upper_arm_moved_out_is_seen_there_and_in_the_spacing(mesh):
    vertices, parts = mesh
    left = parts == PARTS.index("upper_arm_l")
    right = parts == PARTS.index("upper_arm_r")
    # Outward along the line between the two upper arms' centroids, 5 mm.
    out = vertices[0, left].mean(axis=0) - vertices[0, right].mean(axis=0)
    out /= np.linalg.norm(out)
    wider = vertices.copy()
    wider[0, left] += 0.005 * out
    distances, spacing = _region_distances(wider, vertices, parts)
    arms = left | right
    assert distances["upper_arms"][0] == pytest.approx(0.005 * left.sum() / arms.sum(), rel=1e-9)
    assert spacing[0] == pytest.approx(0.005, abs=1e-9)
    for name in ("trunk", "forearms_hands", "thighs"):
        assert distances[name][0] == pytest.approx(0.0, abs=1e-9), name
