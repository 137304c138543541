"""Which studio person a tracked person is (capture/ground_truth.py, match_person)."""

from __future__ import annotations

import numpy as np

from bodymetry.capture.ground_truth import (
    GROUND_TRUTH_STATES,
    MATCH_DISTANCE,
    match_person,
    person_folder,
)


def _studio(tmp_path, paths):
    """A ground_truth folder whose people walk along ``paths`` (per person, (F, 2))."""
    for k, path in enumerate(paths):
        folder = person_folder(tmp_path, k)
        folder.mkdir(parents=True, exist_ok=True)
        frames = np.arange(0, 25 * len(path), 25)
        tau = np.column_stack([path, np.full(len(path), 0.9)])
        np.savez(folder / GROUND_TRUTH_STATES, frame=frames, tau=tau)
    return tmp_path


def test_a_tracked_person_is_the_studio_person_they_walk_with(tmp_path):
    t = np.linspace(0.0, 1.0, 5)[:, None]
    a = np.hstack([-1.0 + 2.0 * t, np.zeros_like(t)])  # walks along x
    b = np.hstack([np.full_like(t, 0.5), -1.0 + 2.0 * t])  # walks along y
    gt = _studio(tmp_path, [a, b])
    rng = np.random.default_rng(0)
    near_b = {25 * k: b[k] + rng.normal(0, 0.05, 2) for k in range(5)}
    index, distance = match_person(gt, near_b)
    assert index == 1 and distance < 0.15
    assert match_person(gt, {25 * k: a[k] for k in range(5)})[0] == 0
    # Nobody near: no match (and the distance says how far).
    far = {25 * k: a[k] + [0.0, 2.0] for k in range(5)}
    index, distance = match_person(gt, far)
    assert index is None and distance > MATCH_DISTANCE
    # Between the two, about as near to each: no match rather than a guess.
    both = _studio(tmp_path / "close", [np.zeros((5, 2)), np.full((5, 2), 0.2)])
    assert match_person(both, {25 * k: np.array([0.1, 0.1]) for k in range(5)})[0] is None
    assert match_person(tmp_path / "nothing", near_b) == (None, np.inf)
