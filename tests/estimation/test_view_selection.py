"""Which views a frame's fit uses, and the views left out as unreliable
(estimation/view_selection.py), with the record's ``view_agreement``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bodymetry.errors import InputError
from bodymetry.estimation.records import FrameRecord
from bodymetry.estimation.view_selection import (
    MIN_PIXELS,
    LeftOutView,
    left_out_views,
    usable_camera_frames,
    usable_view,
    usable_views,
)

NAMES = ("cam_00", "cam_01", "cam_02", "cam_03")


def test_a_view_is_usable_with_enough_pixels_and_no_leave_out_flag():
    pixels = {"cam_00": 5000, "cam_01": 5000, "cam_02": MIN_PIXELS - 1, "cam_03": 5000}
    flags = {"cam_00": ("border",), "cam_01": ("unreliable",), "cam_03": ("unreadable",)}
    assert usable_views(NAMES, pixels, flags).tolist() == [True, False, False, False]
    # A camera the record does not know has no silhouette.
    assert usable_views(("cam_09",), pixels, flags).tolist() == [False]
    assert usable_view(MIN_PIXELS, ("inconsistent",)) and not usable_view(MIN_PIXELS - 1, ())
    assert usable_views((), pixels, flags).dtype == bool


def _record(frame: int, unreliable: dict[str, float | None], pixels: int = 5000) -> FrameRecord:
    """A fitted-looking record whose ``unreliable`` views carry their agreement (None:
    flagged without a recorded agreement); every view has ``pixels``."""
    return FrameRecord(
        frame,
        "ok",
        flags={n: ("unreliable",) if n in unreliable else () for n in NAMES},
        person_pixels={n: pixels for n in NAMES},
        view_agreement={n: a for n in NAMES if (a := unreliable.get(n, 0.93)) is not None},
        silhouette_iou={n: 0.9 for n in NAMES if n not in unreliable},
    )


def test_left_out_views_name_each_camera_once_with_its_frames_and_agreement():
    records = [
        _record(50, {"cam_02": 0.74}),
        _record(0, {"cam_02": 0.61, "cam_00": None}),
        _record(25, {}),
        _record(75, {"cam_02": 0.7449}),
    ]
    views = left_out_views(records, NAMES)
    assert [v.camera for v in views] == ["cam_00", "cam_02"]  # camera order
    cam0, cam2 = views
    assert cam2.frames == (0, 50, 75) and cam2.agreement == (0.61, 0.74, 0.7449)
    assert cam2.kept == 4 and cam2.agreement_text == "0.61-0.74"
    assert cam2.describe() == (
        "cam_02: silhouette unreliable in 3 of 4 kept frames (agreement 0.61-0.74), "
        "left out of those frames' fits"
    )
    assert "(agreement 0.61-0.74 < 0.80)" in cam2.describe(bound=0.8)
    # Flagged without a recorded agreement: the warning says so without numbers.
    assert cam0.agreement == () and cam0.describe(0.8) == (
        "cam_00: silhouette unreliable in 1 of 4 kept frames, left out of those frames' fits"
    )
    assert LeftOutView("c", (3,), (0.5, 0.504), 9).agreement_text == "0.50"
    assert left_out_views([_record(0, {})], NAMES) == []


def test_views_left_out_for_each_reason_are_named_for_it():
    def flagged(frame: int, flag: str) -> FrameRecord:
        return FrameRecord(
            frame, "ok", flags={n: (flag,) if n == "cam_01" else () for n in NAMES},
            person_pixels={n: 5000 for n in NAMES},
        )  # fmt: skip

    records = [flagged(0, "mixed"), flagged(25, "occluded"), flagged(50, "mixed")]
    assert not usable_view(5000, ("mixed",))
    occluded, mixed = left_out_views(records, NAMES)
    assert (occluded.reason, occluded.frames) == ("occluded", (25,))
    assert (mixed.reason, mixed.frames) == ("mixed", (0, 50))
    assert mixed.describe() == (
        "cam_01: detected mixed with another person in 2 of 3 kept frames, "
        "left out of those frames' fits"
    )


def test_camera_frames_count_only_the_usable_views():
    records = [_record(0, {"cam_01": 0.5}), _record(25, {}), _record(50, {"cam_01": 0.6}, 10)]
    assert usable_camera_frames(records, NAMES) == {
        "cam_00": 2,
        "cam_01": 1,
        "cam_02": 2,
        "cam_03": 2,
    }


def test_view_agreement_round_trips_and_old_records_read_without_it():
    record = _record(25, {"cam_01": 0.61234})
    data = json.loads(json.dumps(record.to_json(), allow_nan=False))
    assert data["view_agreement"]["cam_01"] == 0.6123  # rounded as silhouette_iou is
    back = FrameRecord.from_json(data)
    assert back.view_agreement == {**record.view_agreement, "cam_01": 0.6123}
    assert back.flags["cam_01"] == ("unreliable",)
    # Nothing judged: no key written; a record of an older run (no key) reads as none.
    plain = FrameRecord(7, "no silhouette in any camera", person_pixels={"cam_00": 0})
    assert "view_agreement" not in plain.to_json()
    assert FrameRecord.from_json(plain.to_json()) == plain
    old = {k: v for k, v in data.items() if k != "view_agreement"}
    assert FrameRecord.from_json(old).view_agreement == {}
    # Strict JSON: a non-finite agreement is written as null and read back as NaN.
    nan = FrameRecord(3, "ok", view_agreement={"cam_00": math.nan}).to_json()
    assert nan["view_agreement"] == {"cam_00": None}
    assert np.isnan(FrameRecord.from_json(nan).view_agreement["cam_00"])
    with pytest.raises(InputError, match="malformed frame record"):
        FrameRecord.from_json({**data, "view_agreement": {"cam_00": "high"}}, "f.json")
