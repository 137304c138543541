"""Generative refinement (paper §5): chamfer likelihood and annealed particle filter."""

from __future__ import annotations

import importlib.util

import cv2
import numpy as np
import pytest

from bodymetry.estimation import generative
from bodymetry.estimation.body_model import scape
from bodymetry.estimation.body_model.model import DEFAULT_SHAPE_DOFS, THETA, BodyModel, BodyState
from bodymetry.estimation.generative import (
    AnnealingConfig,
    _temperature,
    anneal,
    chamfer_costs,
    prepare_observation,
)
from bodymetry.estimation.projection import fill_silhouette, project_silhouettes
from bodymetry.studio.rig import studio_rig

LIKELIHOOD_BACKENDS = ["numpy"] + (["numba"] if importlib.util.find_spec("numba") else [])

#: Chamfer cost (pixels) of a body against its own silhouette: only resampling.
SELF_COST = 0.05


@pytest.fixture(scope="module")
def setup():
    model = BodyModel.load()
    cameras = studio_rig(3, (160, 120), seed=4)
    truth = BodyState([0.1, -0.2, 0.93], model.poses["apose"], np.zeros(model.n_shape))
    verts = model.pose(truth, lod=True).vertices[0]
    masks = project_silhouettes(verts, model.faces(lod=True), cameras)
    return model, cameras, truth, verts, masks


def test_chamfer_cost_is_zero_for_the_true_body_and_grows_with_error(setup):
    model, cameras, _, verts, masks = setup
    obs = prepare_observation(cameras, masks, 1.0)
    faces = model.faces(lod=True)
    assert chamfer_costs(obs, verts, faces).sum() < SELF_COST
    costs = []
    for dx in (0.02, 0.05, 0.1):
        costs.append(chamfer_costs(obs, verts + [dx, 0, 0], faces).sum())
    assert costs[0] > SELF_COST and np.all(np.diff(costs) > 0)


def _reference_costs(obs, verts, faces) -> np.ndarray:
    """The chamfer cost written out on whole images (no crops, one body at a time)."""
    out = np.zeros(len(obs.cameras))
    for c, cam in enumerate(obs.cameras):
        model = fill_silhouette(cam.project(verts), faces, cam.size)
        observed = obs.masks[c]
        d_model = cv2.distanceTransform((~model).astype(np.uint8), cv2.DIST_L2, 3)
        cost = obs.dist_outside[c][model & ~observed].sum()
        cost += d_model[observed & ~model].sum() / obs.scale
        out[c] = cost / obs.scale**2 / obs.area[c]
    return out


#: The compiled likelihood sums distances in float64, the reference (numpy's float32
#: pairwise sums) rounds each sum to about 1e-7 relative.
RTOL_BACKEND = {"numpy": 1e-12, "numba": 1e-6}


@pytest.mark.parametrize("backend", LIKELIHOOD_BACKENDS)
def test_batched_cropped_chamfer_equals_the_whole_image_cost(setup, backend, monkeypatch):
    """A batch of bodies, some far off or partly outside the images: the batched cost
    (distance transforms on crops) is the whole-image cost, exactly for the numpy
    path and to float32 rounding of the sums for the compiled one."""
    monkeypatch.setattr(generative, "BACKEND", backend)
    model, cameras, truth, _, masks = setup
    obs = prepare_observation(cameras, masks, 0.5)
    faces = model.faces(lod=True)
    rng = np.random.default_rng(4)
    Y = np.repeat(truth.vector(), 6, axis=0)
    Y[:, :3] += rng.normal(0.0, [0.05, 0.05, 0.02], (6, 3))
    Y[4, :3] += [1.5, 0.0, 0.0]  # far to one side: partly outside some images
    Y[5, THETA] += rng.normal(0.0, 0.3, 37)
    verts = model.pose(BodyState.from_vector(Y), lod=True).vertices
    batched = chamfer_costs(obs, verts, faces)
    assert batched.shape == (6, 3)
    for b in range(6):
        np.testing.assert_allclose(
            batched[b], _reference_costs(obs, verts[b], faces), rtol=RTOL_BACKEND[backend]
        )


def test_views_without_silhouette_are_left_out(setup):
    model, cameras, _, verts, masks = setup
    masks = masks.copy()
    masks[1] = False
    obs = prepare_observation(cameras, masks, 1.0)
    assert list(obs.valid) == [True, False, True]
    assert chamfer_costs(obs, verts + [0.05, 0, 0], model.faces(lod=True))[1] == 0.0


def test_temperature_keeps_the_target_effective_sample_size():
    ll = np.random.default_rng(0).normal(0, 50, 200)
    beta = _temperature(ll, 0.5)
    w = np.exp(beta * (ll - ll.max()))
    ess = w.sum() ** 2 / (w**2).sum() / len(w)
    assert 0 < beta < 1 and ess == pytest.approx(0.5, abs=0.01)
    assert _temperature(np.zeros(10), 0.5) == 1.0


def test_annealing_moves_towards_the_truth(setup):
    model, cameras, truth, _, masks = setup
    rng = np.random.default_rng(1)
    y0 = truth.vector()[0]
    spread = np.r_[np.full(3, 0.06), np.full(37, 0.05), np.full(model.n_shape, 0.5)]
    init = y0 + rng.normal(0, 1, (60, len(y0))) * spread
    obs = prepare_observation(cameras, masks, 1.0)
    config = AnnealingConfig(n_particles=40, n_layers=4, image_scale=1.0)
    result = anneal(model, obs, init, config, rng)
    start = np.linalg.norm(init[:, :3] - y0[:3], axis=1).mean()
    end = np.linalg.norm(result.state.tau[0] - y0[:3])
    assert end < 0.5 * start
    assert (
        np.all(np.diff(result.layer_log_likelihood) > -1e-9)
        or result.layer_log_likelihood[-1] > result.layer_log_likelihood[0]
    )
    assert model.limits.contains(result.particles[:, THETA]).all()
    np.testing.assert_allclose(result.weights.sum(), 1.0)


def test_annealing_needs_a_silhouette(setup):
    model, cameras, truth, _, masks = setup
    obs = prepare_observation(cameras, np.zeros_like(masks), 1.0)
    with pytest.raises(ValueError, match="no view"):
        anneal(
            model,
            obs,
            truth.vector(),
            AnnealingConfig(n_particles=4, n_layers=1),
            np.random.default_rng(0),
        )


def test_annealing_config_validates_its_fields():
    with pytest.raises(ValueError, match="n_particles"):
        AnnealingConfig(n_particles=0)
    with pytest.raises(ValueError, match="target_ess"):
        AnnealingConfig(target_ess=1.5)


@pytest.mark.skipif("numba" not in LIKELIHOOD_BACKENDS, reason="numba is not installed")
def test_likelihood_batches_do_not_change_the_vertices(setup, monkeypatch):
    """The compiled path poses up to 256 states per call, the numpy path 64: with the
    compiled Eq. (1) the level of detail's vertices are the same bits either way
    (each state's edges on their own; the solve's columns are independent). (The
    numpy Eq. (1)'s matrix products may round differently by batch size.)"""
    monkeypatch.setattr(scape, "EDGES_BACKEND", "numba")
    model, _, truth, _, _ = setup
    rng = np.random.default_rng(2)
    Y = np.repeat(truth.vector(), 150, axis=0)
    Y[:, THETA] += rng.normal(0.0, 0.1, (150, 37))
    Y[:, 40:] += rng.normal(0.0, 0.5, (150, model.n_shape))
    states = BodyState.from_vector(Y)
    whole = model.pose(states, lod=True).vertices
    parts = [model.pose(states[s : s + 64], lod=True).vertices for s in range(0, 150, 64)]
    assert np.array_equal(whole, np.concatenate(parts))


def test_the_weighted_estimate_takes_the_heading_around_the_circle():
    """Two states facing almost backwards, one each side of ±π: their mean faces
    backwards (not forwards, as a plain mean of -3.13 and +3.13 would); every
    other value is the plain weighted mean."""
    from bodymetry.estimation.body_model.skeleton import YAW

    Y = np.zeros((2, 40 + DEFAULT_SHAPE_DOFS))
    Y[:, 0] = [1.0, 3.0]
    Y[0, THETA.start + YAW], Y[1, THETA.start + YAW] = 3.13, -3.13
    est = generative.weighted_estimate(Y, np.array([0.5, 0.5]))
    assert abs(abs(est[THETA.start + YAW]) - np.pi) < 1e-9
    assert est[0] == pytest.approx(2.0)
