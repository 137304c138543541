"""Per-rig training of the discriminative models on a tiny rig and training set."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from bodymetry.errors import InputError
from bodymetry.estimation import training
from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.projection import project_silhouettes
from bodymetry.estimation.training import (
    HEADLINE_METRICS,
    MODEL_NAMES,
    DiscriminativeModels,
    TrainConfig,
    _training_bodies,
    load_or_train,
    rig_key,
    sample_states,
    targets_to_theta,
    theta_to_targets,
    train,
)
from bodymetry.estimation.uncalibrated import compare_photos, estimate_photo, read_mask
from bodymetry.studio.rig import studio_rig
from bodymetry.warmup import TINY_TRAIN

TINY = dataclasses.replace(TINY_TRAIN, n_test=12, experts=(1, 2), max_iter=10)
#: Feet on the floor after grounding on the LOD mesh, metres.
FLOOR_TOL = 1e-6


@pytest.fixture(scope="module")
def cameras():
    return studio_rig(2, (160, 120), seed=1)


@pytest.fixture(scope="module")
def trained(cameras, tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    models, reused = load_or_train(cameras, TINY, cache, workers=1)
    return models, cache, reused


def test_heading_targets_round_trip():
    rng = np.random.default_rng(0)
    theta = rng.uniform(-1, 1, (20, 37))
    theta[:, 2] = rng.uniform(-np.pi, np.pi, 20)
    y = theta_to_targets(theta)
    assert y.shape == (20, 38)
    np.testing.assert_allclose(targets_to_theta(y), theta, atol=1e-12)


def test_rig_key_tracks_cameras_and_settings(cameras):
    base = rig_key(cameras, TINY)
    assert base == rig_key(list(cameras), TINY)
    assert base != rig_key(studio_rig(2, (160, 120), seed=2), TINY)
    assert base != rig_key(cameras, TrainConfig(n_train=61, n_test=12))


def test_rig_key_tracks_how_bodies_are_posed(cameras, monkeypatch):
    """The same model file posed another way renders other training silhouettes."""
    base = rig_key(cameras, TINY)
    monkeypatch.setattr(training, "ANCHOR_WEIGHT", training.ANCHOR_WEIGHT * 2)
    assert rig_key(cameras, TINY) != base


def test_rig_key_tracks_the_number_of_shape_components(cameras, monkeypatch):
    """Models trained for 12 shape components cannot serve a 20-component body model."""
    base = rig_key(cameras, TINY)
    monkeypatch.setattr(training, "DEFAULT_SHAPE_DOFS", training.DEFAULT_SHAPE_DOFS + 8)
    assert rig_key(cameras, TINY) != base


def test_sampled_states_stand_on_the_floor_and_split_shapes():
    model = BodyModel.load()
    train = sample_states(model, 30, "train", 0, 1.0)
    test = sample_states(model, 30, "test", 0, 1.0)
    for states in (train, test):
        lowest = model.pose(states, lod=True).vertices[..., 2].min(axis=1)
        np.testing.assert_allclose(lowest, 0.0, atol=FLOOR_TOL)
        assert np.all(np.abs(states.tau[:, :2]) < 1.6)
        assert model.limits.contains(states.theta).all()
    # Test shapes are held-out bodies of the prior, exactly.
    heldout = model.prior_shapes("heldout")
    assert all(np.any(np.all(np.isclose(heldout, nu), axis=1)) for nu in test.nu)


def test_training_produces_finite_figures(trained, cameras):
    models, _, reused = trained
    assert not reused
    assert models.camera_names == cameras.names
    m = models.metrics
    for key in HEADLINE_METRICS:
        assert np.isfinite(m[key]), key
    assert set(m["chosen"]) == set(MODEL_NAMES)
    assert m["position_error_mm"] < 1000  # metres-scale nonsense would show here


def test_cache_is_reused_and_round_trips(trained, cameras, tmp_path):
    models, cache, _ = trained
    again, reused = load_or_train(cameras, TINY, cache, workers=1)
    assert reused
    x = np.random.default_rng(0).uniform(0, 100, (3, 102))
    for name in ("nu_rdf", "tau_rdf"):
        np.testing.assert_array_equal(
            again.models["cam_00"][name].predict(x), models.models["cam_00"][name].predict(x)
        )
    models.save(tmp_path / "m.npz")
    back = DiscriminativeModels.load(tmp_path / "m.npz")
    assert back.key == models.key and back.metrics["n_train"] == 60


#: A body posed at the lowered root vs the posed body lowered, metres (round-off).
MESH_TOL = 1e-12


def test_training_bodies_are_posed_once_and_the_same_on_two_workers():
    model = BodyModel.load()
    states, meshes = _training_bodies(model.n_shape, 70, "train", 0, 1.0, 1)
    _, meshes2 = _training_bodies(model.n_shape, 70, "train", 0, 1.0, 2)
    np.testing.assert_array_equal(meshes, meshes2)
    np.testing.assert_array_equal(states.tau, sample_states(model, 70, "train", 0, 1.0).tau)
    posed = model.pose(states, lod=True).vertices
    np.testing.assert_allclose(meshes, posed, rtol=0, atol=MESH_TOL)
    assert np.abs(meshes[..., 2].min(axis=1)).max() < FLOOR_TOL
    assert not meshes.flags.writeable


def test_two_workers_train_the_same_models(trained, cameras):
    """The fits run as parallel jobs; each is seeded, so scheduling changes nothing."""
    models, _, _ = trained
    parallel = train(cameras, TINY, workers=2)
    assert parallel.metrics["chosen"] == models.metrics["chosen"]
    for cam in models.camera_names:
        for name in MODEL_NAMES:
            a, b = models.models[cam][name], parallel.models[cam][name]
            np.testing.assert_array_equal(a.betas, b.betas)
            np.testing.assert_array_equal(a.covs, b.covs)
    np.testing.assert_array_equal(models.codebook.centers, parallel.codebook.centers)


def test_codebook_examples_may_be_the_whole_training_set(cameras):
    """No body left after the codebook's: the rest of the training set is empty, not an error."""
    config = dataclasses.replace(TINY, n_train=50, codebook_examples=50)
    models = train(cameras, config, workers=2)
    assert models.metrics["n_train"] == 50
    assert np.isfinite(models.metrics["shape_rdf_improvement_over_mean"])


# --- uncalibrated mode (estimation/uncalibrated.py) on the tiny models -------------------
def _mask_of(nu, cameras):
    model = BodyModel.load()
    state = BodyState([0.0, 0.0, 0.93], model.poses["apose"], nu)
    verts = model.pose(state, lod=True).vertices[0]
    return project_silhouettes(verts, model.faces(lod=True), cameras[:1])[0]


def test_photo_estimate_is_scaled_to_the_reference_height(trained, cameras):
    models = trained[0]
    body = BodyModel.load()
    mask = _mask_of(np.zeros(body.n_shape), cameras)
    est = estimate_photo(mask, models, body, 1750.0)
    bio = est.biometrics
    assert bio.height_mm == pytest.approx(1750.0, rel=1e-9)
    assert bio.bmi == pytest.approx(bio.weight_kg / 1.75**2, rel=1e-9)
    # Same photo twice: no change at all.
    change = compare_photos(est, estimate_photo(mask, models, body, 1750.0))
    assert all(abs(v) < 1e-9 for v in change.values())
    # A taller reference scales weight by the cube of the height ratio.
    taller = estimate_photo(mask, models, body, 1750.0 * 1.1)
    assert taller.biometrics.weight_kg == pytest.approx(bio.weight_kg * 1.1**3, rel=1e-9)


def test_read_mask_errors(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_mask(tmp_path / "missing.png")
    (tmp_path / "junk.png").write_bytes(b"not an image")
    with pytest.raises(InputError, match="not a readable image"):
        read_mask(tmp_path / "junk.png")
    cv2.imwrite(str(tmp_path / "empty.png"), np.zeros((50, 50), np.uint8))
    with pytest.raises(InputError, match="no person"):
        read_mask(tmp_path / "empty.png")
    cv2.imwrite(str(tmp_path / "full.png"), np.full((50, 50), 255, np.uint8))
    with pytest.raises(InputError, match="inverted"):
        read_mask(tmp_path / "full.png")
