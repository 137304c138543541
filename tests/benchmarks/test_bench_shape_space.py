"""The shape-space reach benchmark's errors (``benchmarks/bench_shape_space.py``)."""

import numpy as np
import pytest

from benchmarks.bench_shape_space import projection_errors
from bodymetry.estimation.body_model import geometry
from bodymetry.estimation.body_model.model import BodyModel


@pytest.fixture(scope="module")
def model():
    return BodyModel.load()


def test_bodies_of_the_space_project_onto_themselves(model):
    bodies = model.canonical_vertices(model.prior_shapes("heldout")[:3])
    errors = projection_errors(model, bodies)
    for key, tol in (("rms_mm", 0.01), ("max_mm", 0.05), ("height_mm", 0.05), ("weight_kg", 1e-3)):
        assert np.abs(errors[key]).max() < tol, key


def test_a_body_outside_the_space_shows_its_distance_height_and_weight(model):
    body = model.canonical_vertices(model.prior_shapes("heldout")[:1])
    # Scale the body by 1.1 about its soles: no component of the space is a pure
    # scaling, so some of it is left, with its stature and volume.
    grown = body * np.array([1.0, 1.0, 1.1])
    errors = projection_errors(model, grown)
    true_height = 1000.0 * np.ptp(grown[0, :, 2])
    assert errors["rms_mm"][0] > 5.0 and errors["max_mm"][0] >= errors["rms_mm"][0]
    # The projection stays near the body: within a tenth of its stature and weight.
    assert abs(errors["height_mm"][0]) < 0.1 * true_height
    faces = model.faces()
    true_weight = geometry.mesh_volume(grown[0], faces) * 1000.0
    assert abs(errors["weight_kg"][0]) < 0.1 * true_weight
