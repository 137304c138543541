"""Seeds of motion and pose draws: training, test and demo use disjoint ranges.

Training sets use ``seed_for("train", i)``, test fixtures and benchmarks
``seed_for("test", i)``, the committed demo recording ``seed_for("demo", 0)``;
seeds below 10^9 are free for ad-hoc use. :func:`motion_rng` turns a seed into the
generator of one library motion, independent per (motion name, seed).
"""

from __future__ import annotations

import zlib
from typing import Literal

import numpy as np

Purpose = Literal["train", "test", "demo"]
_SEED_BLOCK = 1_000_000_000
#: Seed range of each purpose (disjoint; seeds below 10^9 are free for ad-hoc use).
SEED_RANGES: dict[str, range] = {
    "train": range(1 * _SEED_BLOCK, 2 * _SEED_BLOCK),
    "test": range(2 * _SEED_BLOCK, 3 * _SEED_BLOCK),
    "demo": range(3 * _SEED_BLOCK, 4 * _SEED_BLOCK),
}


def seed_for(purpose: Purpose, index: int) -> int:
    """The seed of the ``index``-th draw for ``purpose`` ("train", "test" or "demo").

    Training sets use ``seed_for("train", i)``, test fixtures and benchmarks
    ``seed_for("test", i)``, the committed demo recording ``seed_for("demo", 0)``; the
    ranges never overlap, so no test motion or pose is ever a training draw.
    """
    if purpose not in SEED_RANGES:
        raise ValueError(f"seed_for: purpose must be one of {sorted(SEED_RANGES)}, got {purpose!r}")
    span = SEED_RANGES[purpose]
    ok = isinstance(index, int | np.integer) and not isinstance(index, bool)
    if not ok or not 0 <= int(index) < len(span):
        raise ValueError(f"seed_for: index must be an integer in [0, {len(span)}), got {index!r}")
    return span.start + int(index)


def seed_purpose(seed: int) -> str | None:
    """Which purpose's range ``seed`` falls in (None for ad-hoc seeds)."""
    for purpose, span in SEED_RANGES.items():
        if int(seed) in span:
            return purpose
    return None


def motion_rng(name: str, seed: int) -> np.random.Generator:
    """The generator behind ``make_motion(name, ..., seed)``: independent per (name, seed)."""
    if int(seed) < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed}")
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(name.encode())]))
