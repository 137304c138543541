"""Tests for bodymetry.estimation.body_model.motion.seeds: disjoint seed ranges."""

from __future__ import annotations

import itertools

import pytest

from bodymetry.estimation.body_model.motion.seeds import SEED_RANGES, seed_for, seed_purpose


def test_seed_ranges_are_disjoint() -> None:
    for (pa, a), (pb, b) in itertools.combinations(SEED_RANGES.items(), 2):
        assert a.stop <= b.start or b.stop <= a.start, (pa, pb)
    for purpose, span in SEED_RANGES.items():
        first, last = seed_for(purpose, 0), seed_for(purpose, len(span) - 1)
        assert (first, last) == (span.start, span.stop - 1)
        assert seed_purpose(first) == purpose and seed_purpose(last) == purpose
    assert seed_purpose(42) is None


@pytest.mark.parametrize(
    ("purpose", "index"), [("train", -1), ("train", 10**9), ("validation", 0), ("test", 1.5)]
)
def test_seed_for_rejects_bad_arguments(purpose: str, index: object) -> None:
    with pytest.raises(ValueError, match="seed_for"):
        seed_for(purpose, index)  # type: ignore[arg-type]
