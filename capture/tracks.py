"""Identities of the people of a capture across its kept frames.

Each kept frame's people (:class:`bodymetry.capture.people.Sighting`) are found
on their own; a person keeps one identity across frames by where they stand.
Every known person's last floor position is a candidate for each frame's
people (an optimal assignment, :func:`scipy.optimize.linear_sum_assignment`,
on the floor distance); a pair further apart than :data:`TRACK_GATE` is no
match, and a person matched by nobody is new. So a person who leaves the
capture volume and comes back where they left keeps their identity, and one
who comes back elsewhere gets a new one.

Identities are numbered in the order people are first seen (in a frame, in
the order of :func:`bodymetry.capture.headcount.group_people`: most cameras
first, then along the world x axis), so the same recording gives the same
numbers every time.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from bodymetry.errors import InputError

__all__ = ["TRACK_GATE", "track"]

#: Largest distance (metres, on the floor) between a person's positions in two
#: kept frames that are one person: walking at 1.4 m/s, a person moves 0.6 m
#: in 25 frames at 60 fps; two people stand at least 0.45 m apart.
TRACK_GATE = 1.0


def track(positions: Sequence[Sequence[np.ndarray]], gate: float = TRACK_GATE) -> list[list[int]]:
    """Per kept frame, the identity of each of its people.

    Parameters
    ----------
    positions : sequence of sequences of (3,) float
        Per kept frame (in order), the world position of each person found
        (metres; NaN where unknown: that person is new).
    gate : float
        :data:`TRACK_GATE`.

    Returns
    -------
    list of list of int
        Same shape as ``positions``; identities from 0, one per person per frame.
    """
    if not gate > 0:
        raise InputError(f"track: gate must be > 0 m, got {gate}")
    last: list[np.ndarray] = []  # per identity, the last floor position seen
    out: list[list[int]] = []
    for frame in positions:
        floor = np.array([np.asarray(p, float)[:2] for p in frame]).reshape(-1, 2)
        ids = [-1] * len(floor)
        if len(floor) and last:
            cost = np.linalg.norm(floor[:, None, :] - np.array(last)[None, :, :], axis=2)
            cost = np.where(np.isfinite(cost), cost, np.inf)
            big = 1e6  # linear_sum_assignment needs finite costs
            rows, cols = linear_sum_assignment(np.minimum(cost, big))
            for r, c in zip(rows, cols, strict=True):
                if cost[r, c] <= gate:
                    ids[r] = int(c)
        for r, pos in enumerate(floor):
            if ids[r] < 0:
                ids[r] = len(last)
                last.append(pos)
            elif np.isfinite(pos).all():
                last[ids[r]] = pos
        out.append(ids)
    return out
