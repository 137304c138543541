"""Tests for estimation.body_model.biometrics on the committed body model.

Definitions are in docs/biometrics.md; these tests check them against the
model's canonical bodies and against anthropometric plausibility.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bodymetry.estimation.body_model import geometry
from bodymetry.estimation.body_model.biometrics import (
    DEFAULT_DENSITY,
    GIRTH_STEP,
    MEASUREMENTS,
    Biometrics,
    _girth_extreme,
    measure,
)
from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.body_model.skeleton import JOINTS, PARTS

# --------------------------------------------------------------------------------------
# Tolerances and plausible ranges, all in one place.
# --------------------------------------------------------------------------------------
# Quantities that are the same arithmetic on the same arrays (relative).
RTOL_EXACT = 1e-12
# Batched vs one-by-one measurement: the same maths, different summation order.
RTOL_BATCH = 1e-9
# The mean body of an adult prior (mm, kg, kg/m²): wide adult ranges, not the prior's.
MEAN_BODY_RANGES = {
    "height_mm": (1550.0, 1850.0),
    "weight_kg": (50.0, 90.0),
    "chest_mm": (800.0, 1150.0),
    "waist_mm": (650.0, 1000.0),
    "hip_mm": (850.0, 1150.0),
    "shoulder_breadth_mm": (300.0, 420.0),
    "arm_length_mm": (450.0, 620.0),
    "bmi": (18.5, 30.0),
}
# Knuckle-to-knuckle span over height (docs: about 0.9; the paper's 0.90 and 0.91).
SPAN_OVER_HEIGHT = (0.85, 0.95)
# Inseam over height for adults.
INSEAM_OVER_HEIGHT = (0.42, 0.52)
# Symmetric landmarks of the mean body (metres).
MIRROR_LANDMARKS = 2e-3
# The crotch landmark is the lowest pelvis vertex within this distance of the midline.
CROTCH_MIDLINE = 0.01
SEED = 20240616


@pytest.fixture(scope="module")
def model() -> BodyModel:
    return BodyModel.load()


@pytest.fixture(scope="module")
def mean_body(model) -> Biometrics:
    return measure(model, np.zeros(model.n_shape))[0]


@pytest.fixture(scope="module")
def rng_nu(model) -> np.ndarray:
    return np.random.default_rng(SEED).normal(size=(3, model.n_shape))


def test_fields_and_units(mean_body):
    fields = [f.name for f in dataclasses.fields(Biometrics)]
    assert list(MEASUREMENTS) == fields
    d = mean_body.to_dict()
    assert list(d) == fields
    assert all(type(v) is float and np.isfinite(v) for v in d.values())
    assert MEASUREMENTS["height_mm"] == "mm" and MEASUREMENTS["weight_kg"] == "kg"


def test_mean_body_is_a_plausible_adult(mean_body):
    d = mean_body.to_dict()
    for key, (lo, hi) in MEAN_BODY_RANGES.items():
        assert lo < d[key] < hi, (key, d[key])
    assert SPAN_OVER_HEIGHT[0] < d["arm_span_mm"] / d["height_mm"] < SPAN_OVER_HEIGHT[1]
    assert INSEAM_OVER_HEIGHT[0] < d["inseam_mm"] / d["height_mm"] < INSEAM_OVER_HEIGHT[1]
    assert d["waist_mm"] < d["hip_mm"]
    assert d["waist_mm"] < d["chest_mm"]


def test_definitions_match_the_canonical_body(model, rng_nu):
    bios = measure(model, rng_nu)
    v = model.canonical_vertices(rng_nu)
    faces = model.faces()
    volume = geometry.mesh_volume(v, faces)
    for b, bio in enumerate(bios):
        height = v[b, :, 2].max()
        assert bio.height_mm == pytest.approx(1000.0 * height, rel=RTOL_EXACT)
        assert bio.volume_l == pytest.approx(1000.0 * volume[b], rel=RTOL_EXACT)
        assert bio.weight_kg == pytest.approx(volume[b] * DEFAULT_DENSITY, rel=RTOL_EXACT)
        assert bio.bmi == pytest.approx(bio.weight_kg / height**2, rel=RTOL_EXACT)
        crotch = v[b, model.landmarks["crotch"], 2]
        assert bio.inseam_mm == pytest.approx(1000.0 * crotch, rel=RTOL_EXACT)
        acromions = v[b, [model.landmarks["acromion_l"], model.landmarks["acromion_r"]]]
        assert bio.shoulder_breadth_mm == pytest.approx(
            1000.0 * np.linalg.norm(acromions[0] - acromions[1]), rel=RTOL_EXACT
        )


def test_batch_equals_one_by_one(model, rng_nu):
    batch = measure(model, rng_nu)
    assert len(batch) == len(rng_nu)
    for b, nu in enumerate(rng_nu):
        one = measure(model, nu)  # (n_shape,) is accepted
        assert len(one) == 1
        for key, value in one[0].to_dict().items():
            assert batch[b].to_dict()[key] == pytest.approx(value, rel=RTOL_BATCH), key


def test_weight_is_linear_in_density(model, mean_body):
    heavy = measure(model, np.zeros(model.n_shape), density=1070.0)[0]
    assert heavy.weight_kg == pytest.approx(1.07 * mean_body.weight_kg, rel=RTOL_EXACT)
    assert heavy.bmi == pytest.approx(1.07 * mean_body.bmi, rel=RTOL_EXACT)
    for key in MEASUREMENTS:
        if key not in ("weight_kg", "bmi"):
            assert heavy.to_dict()[key] == mean_body.to_dict()[key], key
    # At the paper's density of water, kilograms equal litres.
    assert mean_body.weight_kg == pytest.approx(mean_body.volume_l, rel=RTOL_EXACT)


@pytest.mark.parametrize("density", [0.0, -985.0, float("nan")])
def test_density_must_be_positive(model, density):
    with pytest.raises(ValueError, match="density"):
        measure(model, np.zeros(model.n_shape), density=density)


def test_girths_are_the_extremes_of_their_windows(model, mean_body):
    """Chest is the largest torso girth in its window, waist the smallest trunk girth."""
    v = model.canonical_vertices(np.zeros((1, model.n_shape)))[0]
    kp = model.rest_keypoints(np.zeros((1, model.n_shape)))[0]
    faces = model.faces()
    parts = model.full.arrays.parts
    torso = parts == PARTS.index("torso")
    trunk = torso | (parts == PARTS.index("pelvis"))
    z_shoulder = kp[JOINTS.index("shoulder_l"), 2]
    z_hip = kp[JOINTS.index("hip_l"), 2]
    rng = np.random.default_rng(SEED)
    chest = [geometry.girth(v, faces, z, torso) for z in rng.uniform(-0.25, -0.08, 8) + z_shoulder]
    assert max(chest) <= mean_body.chest_mm / 1000.0 + 1e-9
    assert max(chest) > 0.97 * mean_body.chest_mm / 1000.0
    waist = [
        geometry.girth(v, faces, z, trunk) for z in rng.uniform(z_hip + 0.08, z_shoulder - 0.2, 8)
    ]
    assert min(waist) >= mean_body.waist_mm / 1000.0 - 1e-9


def test_girth_windows_cut_the_same_sections_as_the_whole_mesh(model, rng_nu):
    """The window's faces alone (those reaching into it) give every level's girth
    exactly as the masked whole mesh does."""
    v = model.canonical_vertices(rng_nu[:1])[0]
    faces = model.faces()
    torso = model.full.arrays.parts == PARTS.index("torso")
    lo, hi = 1.15, 1.35
    levels = np.arange(lo, hi + 1e-9, GIRTH_STEP)
    whole = [geometry.girth(v, faces, z, torso) for z in levels]
    assert _girth_extreme(v, faces, torso, lo, hi, True) == max(whole)
    assert _girth_extreme(v, faces, torso, lo, hi, False) == min(g for g in whole if g > 0)


def test_mean_body_landmarks_are_symmetric(model):
    v = model.canonical_vertices(np.zeros((1, model.n_shape)))[0]
    left, right = v[model.landmarks["acromion_l"]], v[model.landmarks["acromion_r"]]
    np.testing.assert_allclose(left * [-1.0, 1.0, 1.0], right, atol=MIRROR_LANDMARKS)
    assert left[0] > 0.1  # left is +x
    assert abs(v[model.landmarks["crotch"], 0]) < CROTCH_MIDLINE
    assert model.landmarks["head_top"] == int(np.argmax(v[:, 2]))


def test_the_taller_direction_of_shape_space(model):
    """Along the direction of ν that raises height, the long measurements grow too."""
    n = model.n_shape
    heights = model.canonical_vertices(np.vstack([np.eye(n), -np.eye(n)]))[..., 2].max(axis=1)
    g = heights[:n] - heights[n:]
    g /= np.linalg.norm(g)
    short, tall = measure(model, np.stack([-1.5 * g, 1.5 * g]))
    assert tall.height_mm > short.height_mm + 100.0
    for key in ("arm_span_mm", "inseam_mm", "arm_length_mm", "volume_l"):
        assert tall.to_dict()[key] > short.to_dict()[key], key
    for bio in (short, tall):
        ratio = bio.arm_span_mm / bio.height_mm
        assert SPAN_OVER_HEIGHT[0] < ratio < SPAN_OVER_HEIGHT[1], ratio
