"""The session-bias harness's part swaps (``benchmarks/bench_session_bias.py``)."""

from pathlib import Path

import cv2
import numpy as np

from benchmarks.bench_capture import PART_RADIUS_PX, frame_part_labels
from benchmarks.bench_session_bias import ALL_BUT, PART_GROUPS, swapped_masks
from bodymetry.calibration.io import load_calibration
from bodymetry.estimation.body_model.model import N_POSE, BodyModel, BodyState
from bodymetry.estimation.body_model.skeleton import PARTS


def test_the_part_groups_cover_every_part_once():
    grouped = [p for group in PART_GROUPS.values() for p in group]
    assert sorted(grouped) == sorted(PARTS)
    assert set(ALL_BUT) <= set(PART_GROUPS)


def test_a_swap_takes_the_groups_pixels_from_the_truth_and_nothing_else():
    rng = np.random.default_rng(3)
    observed = rng.random((6, 8)) > 0.5
    true = rng.random((6, 8)) > 0.5
    labels = rng.integers(-1, 4, (6, 8))  # -1: near no part
    hands = swapped_masks(observed, true, labels, [1, 2], keep=False)
    near = (labels == 1) | (labels == 2)
    np.testing.assert_array_equal(hands[near], true[near])
    np.testing.assert_array_equal(hands[~near], observed[~near])
    # Keeping the group: everything else (the unlabelled pixels too) from the truth.
    rest = swapped_masks(observed, true, labels, [1, 2], keep=True)
    np.testing.assert_array_equal(rest[near], observed[near])
    np.testing.assert_array_equal(rest[~near], true[~near])
    # Swapping every label and the unlabelled pixels gives the truth back.
    everything = swapped_masks(observed, true, labels, [-1, 0, 1, 2, 3], keep=False)
    np.testing.assert_array_equal(everything, true)


def test_part_labels_put_each_vertex_pixel_in_its_part_and_far_pixels_in_none():
    root = Path(__file__).resolve().parents[2]
    cameras = load_calibration(root / "recordings" / "demo" / "calibration.yaml")
    body = BodyModel.load()
    nu = np.zeros(body.n_shape)
    state = np.r_[np.array([0.0, 0.0, 1.0]), np.zeros(N_POSE), nu]
    labels = frame_part_labels(body, cameras, state, nu)
    parts = body.parts_of_vertices(False)
    vertices = body.pose(BodyState.from_vector(state[None])).vertices[0]
    for camera, lab in zip(cameras, labels, strict=True):
        w, h = camera.size
        assert lab.shape == (h, w)
        xy = np.round(camera.project(vertices)).astype(int)
        inside = (xy[:, 0] >= 0) & (xy[:, 0] < w) & (xy[:, 1] >= 0) & (xy[:, 1] < h)
        seen = lab[xy[inside, 1], xy[inside, 0]]
        # A vertex's own pixel carries the part of a vertex that projects there: its
        # own part for all but the few pixels where parts meet.
        assert np.mean(seen == parts[inside]) > 0.95
        assert set(np.unique(lab)) <= set(range(-1, len(PARTS)))
        # Beyond the radius of every projected vertex: no part.
        far = np.ones((h, w), bool)
        far[np.clip(xy[inside, 1], 0, h - 1), np.clip(xy[inside, 0], 0, w - 1)] = False
        dist = cv2.distanceTransform(far.astype(np.uint8), cv2.DIST_L2, 5)
        assert (lab[dist > PART_RADIUS_PX + 1] == -1).all()
