"""Identities across kept frames of people without a known height (capture/persons.py,
``track_ids``, as ``process --person N`` uses it): known tracks through crossings,
absences and re-entries."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bodymetry.capture.persons import TRACK_GATE, track_ids
from bodymetry.errors import InputError


def _p(x: float, y: float = 0.0, height: float = float("nan")) -> SimpleNamespace:
    return SimpleNamespace(position=np.array([x, y, 1.0]), height=height)


def track(frames, **kw):
    return track_ids(frames, **kw)


def test_two_people_walking_past_each_other_keep_their_numbers():
    # A walks from x=-1 to +1, B from +1 to -1, 0.6 m apart in y; the order in which
    # capture lists them changes from frame to frame.
    frames = []
    for k, t in enumerate(np.linspace(-1.0, 1.0, 6)):
        a, b = _p(t, -0.3), _p(-t, 0.3)
        frames.append([a, b] if k % 2 == 0 else [b, a])
    ids = track(frames)
    assert ids == [[0, 1], [1, 0], [0, 1], [1, 0], [0, 1], [1, 0]]


def test_a_person_who_leaves_and_comes_back_keeps_a_number_where_they_left():
    frames = [[_p(0.0), _p(1.5)], [_p(0.1)], [_p(0.1)], [_p(0.2), _p(1.4)]]
    assert track(frames) == [[0, 1], [0], [0], [0, 1]]
    # Back elsewhere (further than the gate from where they left): someone new.
    frames[3] = [_p(0.2), _p(1.5 + 1.5 * TRACK_GATE)]
    assert track(frames)[3] == [0, 2]


def test_new_people_and_unknown_positions_get_new_numbers():
    nan = SimpleNamespace(position=np.full(3, np.nan), height=float("nan"))
    assert track([[], [_p(0.0)], [_p(0.0), nan]]) == [[], [0], [0, 1]]
    assert track([]) == []
    with pytest.raises(InputError, match="gate"):
        track([[_p(0.0)]], gate=0.0)


def test_a_known_height_tells_two_people_at_one_place_apart():
    # A child comes where an adult stood: someone new.
    assert track([[_p(0.0, height=1.8)], [_p(0.1, height=1.2)]]) == [[0], [1]]
