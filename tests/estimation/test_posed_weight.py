"""Weight read from the posed bodies (estimation.posed_weight)."""

from __future__ import annotations

import numpy as np
import pytest

from bodymetry.estimation.body_model.biometrics import measure
from bodymetry.estimation.body_model.model import POSE_DIM, BodyState, shipped_model
from bodymetry.estimation.posed_weight import posed_volumes, weight_from_posed

#: Relative tolerance of a mesh volume moved rigidly (float rounding of the sum).
RIGID_RTOL = 1e-9


def test_weight_from_posed_known_answers():
    bios = {
        "height_mm": 1800.0,
        "weight_kg": 81.0,
        "volume_l": 81.0,
        "bmi": 25.0,
        "arm_span_mm": 1790.0,
    }
    se = {"height_mm": 0.5, "weight_kg": 0.2, "volume_l": 0.2, "bmi": 0.1, "arm_span_mm": 1.0}
    volumes = np.array([0.0795, 0.0800, 0.0790, 0.0700, 0.0805])  # one pose loses 10 l
    out, out_se = weight_from_posed(bios, se, volumes, 1000.0)
    assert out["volume_l"] == pytest.approx(79.5) and out["weight_kg"] == pytest.approx(79.5)
    assert out["bmi"] == pytest.approx(79.5 / 1.8**2)
    median_se = 1.2533 * np.std(volumes, ddof=1) / np.sqrt(5)
    assert out_se["weight_kg"] == pytest.approx(np.hypot(0.2, 1000.0 * median_se))
    assert out_se["volume_l"] == pytest.approx(np.hypot(0.2, 1000.0 * median_se))
    assert out_se["bmi"] == pytest.approx(
        out["bmi"] * np.hypot(out_se["weight_kg"] / 79.5, 2 * 0.5 / 1800.0)
    )
    # Only the volume, the weight and the BMI change; the inputs are not touched.
    assert out["height_mm"] == 1800.0 and out["arm_span_mm"] == 1790.0 and bios["weight_kg"] == 81.0
    assert out_se["arm_span_mm"] == 1.0
    # The density scales the weight, not the volume.
    dense, _ = weight_from_posed(bios, se, volumes, 1050.0)
    assert dense["weight_kg"] == pytest.approx(79.5 * 1.05) and dense["volume_l"] == pytest.approx(
        79.5
    )
    # One frame: no spread to add.
    one, one_se = weight_from_posed(bios, se, volumes[:1], 1000.0)
    assert one["weight_kg"] == pytest.approx(79.5) and one_se["weight_kg"] == pytest.approx(0.2)
    for bad in (np.array([]), np.array([0.08, np.nan]), np.zeros((2, 2))):
        with pytest.raises(ValueError, match="posed volumes"):
            weight_from_posed(bios, se, bad, 1000.0)
    with pytest.raises(ValueError, match="density"):
        weight_from_posed(bios, se, volumes, 0.0)


def test_posed_volume_at_rest_is_the_canonical_volume_and_rigid_motion_keeps_it():
    body = shipped_model()
    rng = np.random.default_rng(3)
    nu = rng.normal(0.0, 0.7, body.n_shape)
    rest = np.concatenate([[0.0, 0.0, 1.0], np.zeros(POSE_DIM - 3), nu])
    moved = rest.copy()
    moved[:3] = (1.2, -0.4, 1.1)
    moved[3:6] = (0.0, 0.0, 2.1)  # turned about the vertical
    tpose = rest.copy()
    tpose[3:POSE_DIM] = body.poses["tpose"]
    volumes = posed_volumes(body.pose_states(np.stack([rest, moved, tpose])))
    canonical = measure(body, nu[None])[0].volume_l / 1000.0
    # The rest pose is the canonical body; moving it rigidly keeps its volume.
    assert volumes[0] == pytest.approx(canonical, rel=1e-6)
    assert volumes[1] == pytest.approx(volumes[0], rel=RIGID_RTOL)
    # Posing changes the model's volume (what the module corrects), by little.
    assert volumes[2] != pytest.approx(volumes[0], rel=1e-6)
    assert volumes[2] == pytest.approx(volumes[0], rel=0.05)
    with pytest.raises(ValueError, match="states"):
        posed_volumes(body.pose_states(np.zeros((1, POSE_DIM + body.n_shape + 2))))
    assert BodyState.from_vector(rest[None]).nu.shape == (1, body.n_shape)
