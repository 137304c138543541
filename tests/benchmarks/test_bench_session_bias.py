"""The session-bias harness's part swaps (``benchmarks/bench_session_bias.py``)."""

import numpy as np

from benchmarks.bench_session_bias import ALL_BUT, PART_GROUPS, swapped_masks
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
