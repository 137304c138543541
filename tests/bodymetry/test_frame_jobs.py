"""The frame jobs' helpers (the rescue itself runs in test_process.py on a real run)."""

from __future__ import annotations

import pytest

from bodymetry.frame_jobs import _neighbours


@pytest.mark.parametrize(
    ("frame", "accepted", "n", "expected"),
    [
        (50, [0, 25, 75, 100], 2, [25, 75]),  # one on each side first
        (50, [0, 25, 75, 100], 4, [25, 75, 0, 100]),
        (100, [0, 25, 50, 75], 2, [75, 50]),  # at the end: the two before
        (0, [25, 50, 75], 3, [25, 50, 75]),  # at the start: the ones after
        (50, [0, 25, 75], 3, [25, 75, 0]),
        (50, [25], 2, [25]),  # fewer than asked
        (50, [], 2, []),
    ],
)
def test_neighbours_nearest_first_both_sides(frame, accepted, n, expected):
    assert _neighbours(frame, accepted, n) == expected
