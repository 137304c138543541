"""The studio's edge bodies (issue 33): the committed bank, ``edge=KEY`` and its errors."""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.errors import InputError
from bodymetry.estimation.body_model import geometry
from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.body_model.skeleton import JOINTS
from bodymetry.studio.independent import (
    EDGE_BODIES_PATH,
    EDGE_KEYS,
    IndependentSpec,
    IndependentSubject,
    committed_bank,
    committed_edge_bank,
)
from bodymetry.studio.synth import SubjectSpec


@pytest.fixture(scope="module")
def bank():
    return committed_edge_bank()


@pytest.fixture(scope="module")
def model():
    return BodyModel.load()


def _record(bank, key: str) -> dict:
    return bank.edge[bank.keys.index(key)]


def test_edge_bank_is_compact_and_holds_every_key(bank, model):
    assert EDGE_BODIES_PATH.stat().st_size < 2_000_000
    assert bank.keys == EDGE_KEYS and len(bank) == len(EDGE_KEYS) >= 10
    assert bank.vertices.shape[1:] == (model.full.n_vertices, 3)
    np.testing.assert_array_equal(bank.faces, model.faces())
    np.testing.assert_allclose(bank.vertices[..., 2].min(axis=1), 0.0, atol=1e-3)
    for record, female, age in zip(bank.edge, bank.is_female, bank.age_years, strict=True):
        assert (record["sex"] == "female") == female
        assert record["age_years"] == pytest.approx(age, abs=0.05)


def test_records_describe_the_stored_bodies(bank):
    height_mm = np.ptp(bank.vertices[..., 2], axis=1) * 1000.0
    weight_kg = geometry.mesh_volume(bank.vertices, bank.faces) * 1000.0
    for i, record in enumerate(bank.edge):
        # float16 offsets move vertices by < 0.1 mm: height within 0.2 mm, weight 0.05 kg.
        assert record["height_mm"] == pytest.approx(height_mm[i], abs=0.2)
        assert record["weight_kg"] == pytest.approx(weight_kg[i], abs=0.05)
        if record["target"] == "median":
            assert abs(record["height_percentile"] - 50.0) < 5.0
            assert abs(record["weight_percentile"] - 50.0) < 5.0
        else:
            measure, p = record["target"].split(" p")
            other = "weight" if measure == "height" else "height"
            # Extreme in its measure (within the bake's ±0.5 point band), ordinary in the other.
            assert abs(record[f"{measure}_percentile"] - float(p)) <= 0.5
            assert 25.0 < record[f"{other}_percentile"] < 75.0


def test_percentiles_order_the_bodies(bank):
    for sex in ("female", "male"):
        for measure, unit in (("height", "height_mm"), ("weight", "weight_kg")):
            low, mid, high = (
                _record(bank, k)[unit]
                for k in (f"{sex}_{measure}_p01", f"{sex}_p50", f"{sex}_{measure}_p99")
            )
            assert low < mid < high
    # Women's p99 height is above men's p01; children grow with age (medians).
    assert _record(bank, "female_height_p99")["height_mm"] > 1800.0
    assert _record(bank, "male_height_p01")["height_mm"] < 1650.0
    for child in ("girl", "boy"):
        heights = [_record(bank, f"{child}_age{a}")["height_mm"] for a in (6, 10, 14)]
        assert 1000.0 < heights[0] < heights[1] < heights[2] < 1700.0


def test_edge_subjects_parse_round_trip_and_select_the_edge_bank(model):
    spec = SubjectSpec.parse("independent:7,edge=girl_age6,clothing=loose", 0).independent
    assert spec == IndependentSpec(7, clothing="loose", edge="girl_age6")
    assert IndependentSpec.parse(spec.to_text().partition(":")[2]) == spec
    subject = IndependentSubject(IndependentSpec(7, edge="girl_age6"), model=model)
    assert subject.bank is committed_edge_bank()
    assert subject.index == EDGE_KEYS.index("girl_age6")
    described = subject.describe()
    assert described["edge"]["key"] == "girl_age6" and described["age_years"] == 6.0
    assert subject.biometrics().height_mm == pytest.approx(described["edge"]["height_mm"], abs=0.2)
    # Without edge=, the drawn bank (no edge records in what the subject describes).
    plain = IndependentSubject(IndependentSpec(7), model=model)
    assert plain.bank is committed_bank() and "edge" not in plain.describe()


def test_child_tpose_puts_the_arms_level(model):
    subject = IndependentSubject(IndependentSpec(0, edge="boy_age6"), model=model)
    _, joints, keypoints = subject.skin(np.zeros(3), subject.bank.tpose[subject.index][None])
    names = subject.bank.keypoint_names
    height = np.ptp(subject.rest[:, 2])
    for side in "lr":
        knuckle = keypoints[0, names.index(f"knuckle_{side}")]
        wrist = joints[0, JOINTS.index(f"wrist_{side}")]
        shoulder = joints[0, JOINTS.index(f"shoulder_{side}")]
        # Arms straight out: wrist and knuckles within 2 cm of the shoulder's height.
        assert abs(wrist[2] - shoulder[2]) < 0.02 and abs(knuckle[2] - shoulder[2]) < 0.02
    # A 6-year-old's span is about 0.9 of the stature in MakeHuman (0.91 here).
    assert 0.85 * height < subject.arm_span() < 0.97 * height


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("independent:1,edge=female_height_p50", "expected one of .*female_height_p01"),
        ("independent:1,edge=child", "girl_age6"),
        ("independent:1,body=3,edge=girl_age6", "both given"),
        ("independent:1,edge=girl_age6,edge=boy_age6", "given twice"),
    ],
)
def test_bad_edge_texts_say_what_is_expected(text, match):
    with pytest.raises(InputError, match=match):
        SubjectSpec.parse(text, 0)


def test_edge_key_needs_a_bank_with_edge_bodies():
    with pytest.raises(InputError, match="not in this bank"):
        IndependentSpec(1, edge="girl_age6").index(48, ())
