"""Pose proposals: the particles drawn around given poses (landmarks, neighbours)."""

from __future__ import annotations

import numpy as np

from bodymetry.estimation.body_model.model import NU, TAU, THETA
from bodymetry.estimation.fit import _draws_around, shared_body_model


def test_draws_are_shared_among_centres_and_keep_their_shape():
    body = shared_body_model()
    rng = np.random.default_rng(3)
    n, d = 200, 40 + body.n_shape
    particles = np.zeros((n, d))
    particles[:, NU] = rng.normal(size=(n, body.n_shape))
    centres = np.zeros((2, d))
    centres[0, TAU] = [1.0, 0.0, 0.9]
    centres[1, TAU] = [-1.0, 2.0, 1.0]
    out = _draws_around(body, centres, particles, 0.5, np.random.default_rng(0))
    assert out.shape == particles.shape
    drawn = out[n // 2 :]
    # Half of the draws around each centre, within a few spreads (0.03 m) of it.
    near = [np.linalg.norm(drawn[:, TAU] - c[TAU], axis=1) < 0.2 for c in centres]
    assert near[0].sum() == near[1].sum() == n // 4
    assert np.all(near[0] | near[1])
    # Every draw kept the shape of a particle it replaced: the shapes are a permutation.
    assert np.allclose(np.sort(out[:, NU], axis=0), np.sort(particles[:, NU], axis=0))
    assert np.all(body.limits.clip(drawn[:, THETA]) == drawn[:, THETA])


def test_no_share_leaves_the_particles():
    body = shared_body_model()
    particles = np.random.default_rng(1).normal(size=(10, 40 + body.n_shape))
    out = _draws_around(body, particles[:1], particles, 0.0, np.random.default_rng(0))
    assert np.allclose(np.sort(out, axis=0), np.sort(particles, axis=0))
