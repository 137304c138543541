"""Caveats of a run (estimation/caveats.py): thin or ambiguous evidence is named."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pytest

from benchmarks.bench_studio_accuracy import TWO_PERSON_SETS
from bodymetry.errors import InputError
from bodymetry.estimation.arm_evidence import MIN_RAISED_FRAMES
from bodymetry.estimation.caveats import (
    CAVEAT_CODES,
    MIN_MEASURED_FRAMES,
    VALIDATED,
    arms_down_studio,
    persons_studio,
    run_caveats,
)
from bodymetry.estimation.records import FrameRecord
from bodymetry.estimation.studio_accuracy import StudioSession, studio_sessions

NAMES = ("cam_00", "cam_01", "cam_02")


def _records(n: int, ok: int, **kwargs) -> list[FrameRecord]:
    """``n`` kept frames (0, 25, ...), the first ``ok`` measured."""
    return [
        FrameRecord(25 * k, "ok" if k < ok else "poor fit: mean silhouette IoU 0.41 < 0.90",
                    **kwargs)
        for k in range(n)
    ]  # fmt: skip


def test_a_clean_run_has_no_caveat_and_an_unmeasured_one_none_either():
    assert run_caveats(_records(9, 9, persons=1), NAMES) == ()
    assert run_caveats(_records(9, 9), NAMES) == ()  # persons not counted: no claim
    assert run_caveats(_records(9, 0, persons=3), NAMES) == ()  # exit 3's business


def test_pixels_coarser_than_the_studio_s_are_a_caveat():
    """A 320x240 rig's 11.1 mm pixels at the body: the studio's accuracy, measured at
    5.4-5.7 mm, does not apply; the demo rig's pixels, or none known, say nothing."""
    (coarse,) = run_caveats(_records(9, 9, persons=1), NAMES, mm_per_px=11.1)
    assert coarse.code == "coarse_pixels" and "11.1 mm at the body" in coarse.message
    assert "no 95 % interval is stated" in coarse.message
    for size in (5.5, None, math.nan):
        assert run_caveats(_records(9, 9, persons=1), NAMES, mm_per_px=size) == ()


def test_a_second_person_in_some_frames_is_named_with_the_frames():
    records = _records(9, 9, persons=1)
    for k in (2, 5):
        records[k] = dataclasses.replace(records[k], persons=2)
    (caveat,) = run_caveats(records, NAMES)
    assert caveat.code == "several_persons" and caveat.frames == (50, 125)
    assert caveat.message.startswith(
        "more than one person in the capture volume in 2 of 9 kept frames"
    )
    assert "frames 50, 125" in caveat.message
    assert caveat.to_json() == {"code": caveat.code, "message": caveat.message, "frames": [50, 125]}


def test_thin_evidence_counts_frames_and_share():
    # One of nine measured: thin. Five of nine: enough. Two of two: fewer than the minimum.
    (caveat,) = run_caveats(_records(9, 1), NAMES)
    assert caveat.code == "thin_evidence" and caveat.frames == (0,)
    assert caveat.message.startswith("only 1 of 9 kept frames measured (frame 0)")
    assert run_caveats(_records(9, 5), NAMES) == ()
    assert run_caveats(_records(9, 4), NAMES)[0].code == "thin_evidence"
    assert run_caveats(_records(2, 2), NAMES)[0].code == "thin_evidence"
    assert run_caveats(_records(MIN_MEASURED_FRAMES, MIN_MEASURED_FRAMES), NAMES) == ()


def test_a_view_left_out_of_half_the_frames_and_clothing_are_caveats_in_order():
    records = _records(6, 6, persons=2)
    for k in range(3):
        flags = {"cam_01": ("unreliable",)}
        records[k] = dataclasses.replace(records[k], flags=flags, view_agreement={"cam_01": 0.6})
    hair = "hair or headwear likely: ...; the height is probably overstated"
    caveats = run_caveats(records, NAMES, outline_warnings=(hair,))
    assert [c.code for c in caveats] == ["several_persons", "view_left_out", "clothing"]
    assert [c.code for c in caveats] == [c for c in CAVEAT_CODES if c in {x.code for x in caveats}]
    assert caveats[1].message.startswith("cam_01: silhouette unreliable in 3 of 6 kept frames")
    assert caveats[2].message == hair
    # Left out of 2 of 6: named in the warnings, not a caveat.
    records[2] = dataclasses.replace(records[2], flags={})
    assert "view_left_out" not in [c.code for c in run_caveats(records, NAMES)]


def test_the_person_count_round_trips_and_old_records_read_without_it():
    record = FrameRecord(10, "ok", persons=2)
    data = record.to_json()
    assert data["persons"] == 2
    assert FrameRecord.from_json(data).persons == 2
    del data["persons"]
    assert FrameRecord.from_json(data).persons is None
    assert "persons" not in FrameRecord(10, "ok").to_json()


def test_the_outline_contrast_round_trips_and_old_records_read_without_it():
    data = FrameRecord(10, "ok", outline_contrast=1.23456).to_json()
    assert data["outline_contrast"] == 1.235
    assert FrameRecord.from_json(data).outline_contrast == 1.235
    del data["outline_contrast"]
    assert FrameRecord.from_json(data).outline_contrast is None
    assert "outline_contrast" not in FrameRecord(10, "ok").to_json()


def test_the_validated_range_is_the_edge_benchmarks_subjects():
    # The range the report states and the caveat holds runs against is what
    # `python -m benchmarks pipeline --edge` measured, not a number typed in.
    results = Path(__file__).resolve().parents[2] / "benchmarks" / "results"
    subjects = json.loads((results / "pipeline_edge.json").read_text())["edge_summary"]["subjects"]
    assert VALIDATED.subjects == len(subjects)
    for key in ("height_mm", "weight_kg", "age_years"):
        values = [s[key] for s in subjects]
        assert getattr(VALIDATED, key) == pytest.approx((min(values), max(values)), abs=0.05)
    assert "1145-1939 mm" in VALIDATED.describe() and "ages 6-80 years" in VALIDATED.describe()


@pytest.mark.parametrize(
    ("headline", "outside"),
    [
        ({"height_mm": 2011.0}, ["height 2011 mm"]),
        ({"weight_kg": 140.0, "arm_span_mm": 5000.0}, ["weight 140 kg"]),
        ({"height_mm": VALIDATED.height_mm[0]}, []),
        ({"height_mm": math.nan, "weight_kg": math.inf}, []),
        ({}, []),
    ],
)
def test_a_height_or_weight_alone_outside_the_validated_range_is_a_caveat(headline, outside):
    # Without both a height and a weight there is no body to compare: the span holds.
    assert VALIDATED.outside(headline) == outside
    caveats = run_caveats(_records(9, 9, persons=1), NAMES, headline=headline)
    if not outside:
        assert caveats == ()
        return
    (caveat,) = caveats
    assert caveat.code == "outside_validated" and caveat.frames == ()
    verb = "lie" if len(outside) > 1 else "lies"
    assert caveat.message.startswith(f"the measured {' and '.join(outside)} {verb} outside")
    assert VALIDATED.describe() in caveat.message
    # Nothing measured: no caveat about the numbers (exit 3 says it).
    assert run_caveats(_records(9, 0), NAMES, headline=headline) == ()


@pytest.mark.parametrize(
    ("height", "weight", "unlike"),
    [
        (1700.0, 70.0, False),
        # The 6-year-olds' bodies set the span's lower ends; one measured a little under
        # both is still like them (no caveat that flips on a tenth of a kilogram).
        (VALIDATED.height_mm[0] - 2.0, VALIDATED.weight_kg[0] - 0.2, False),
        # Inside the span in each value, like no body in both: 1.15 m and 111 kg.
        (VALIDATED.height_mm[0], VALIDATED.weight_kg[1], True),
        (1052.0, 17.0, True),
        (2100.0, 95.0, True),
    ],
)
def test_a_body_unlike_the_studio_s_is_outside_the_validated_bodies(height, weight, unlike):
    headline = {"height_mm": height, "weight_kg": weight}
    caveats = run_caveats(_records(9, 9, persons=1), NAMES, headline=headline)
    outside = [c for c in caveats if c.code == "outside_validated"]
    assert bool(outside) == unlike
    if unlike:
        assert outside[0].message.startswith(
            f"the measured height {height:.0f} mm and weight {weight:.0f} kg are unlike"
        )
        assert VALIDATED.describe() in outside[0].message
        # Unlike any studio body: no accuracy is quoted for it, only the extrapolation.
        assert not any(c.code == "body_accuracy" for c in caveats)


def test_arms_down_is_a_caveat_below_the_minimum_of_raised_frames():
    records = _records(9, 9, persons=1)
    assert run_caveats(records, NAMES) == ()  # not judged
    assert run_caveats(records, NAMES, raised=(0, 25, 50)[:MIN_RAISED_FRAMES]) == ()
    for raised in ((), (25,), (25, 75)):
        (caveat,) = run_caveats(records, NAMES, raised=raised)
        assert caveat.code == "arms_down" and caveat.frames == ()  # the whole run's arm span
        assert caveat.message.startswith(
            f"an arm was raised (at least 45 degrees from hanging) in {len(raised)} of 9 "
            "measured frames"
        )
        assert (" 25" in caveat.message) == bool(raised)
        studio = arms_down_studio()
        assert f"{studio.low:+.1f} to {studio.high:+.1f} mm off" in caveat.message
    # Nothing measured: no caveat about the numbers.
    assert run_caveats(_records(9, 0), NAMES, raised=()) == ()


def test_the_arms_down_figures_are_the_shipped_studio_sessions():
    # What the caveat quotes is what the scored studio sessions measured (the
    # shipped file, itself recomputed from the committed results by
    # tests/estimation/test_studio_accuracy.py), not a number typed in.
    def session(name: str, raised: bool, span: float | None) -> StudioSession:
        errors = {"height_mm": 1.0} if span is None else {"arm_span_mm": span}
        return StudioSession(name, 1700.0, 70.0, 30.0, raised, errors)

    pool = [
        session("a", False, 4.04),
        session("b", False, -2.0),
        session("c", False, 21.26),
        session("d", True, -40.0),  # arms raised: not this caveat's
        session("e", False, None),  # no arm span scored
    ]
    figures = arms_down_studio(pool)
    assert (figures.low, figures.high, figures.mean, figures.sessions) == (-2.0, 21.3, 7.8, 3)
    with pytest.raises(InputError, match="no arm span with the arms down"):
        arms_down_studio(pool[3:])
    shipped = [
        s.errors["arm_span_mm"]
        for s in studio_sessions()
        if not s.arms_raised and "arm_span_mm" in s.errors
    ]
    assert arms_down_studio().sessions == len(shipped) >= 8
    assert arms_down_studio().high == round(max(shipped), 1)
    (caveat,) = run_caveats(_records(9, 9, persons=1), NAMES, raised=())
    assert f"mean {arms_down_studio().mean:+.1f} mm, {len(shipped)} sessions" in caveat.message


def test_soles_far_below_the_floor_are_a_caveat():
    """The session stage's soles 32 mm below z = 0 (Demo_MultiPerson's woman, beside
    the treadmill) are more than shadow explains: the run says so; the studio's
    deepest (8.4 mm), soles above the floor and no session stage are not."""
    records = _records(9, 9, persons=1)
    for depth in (None, 0.0, -8.4, -15.0):
        assert run_caveats(records, NAMES, sole_depth_mm=depth) == ()
    (caveat,) = run_caveats(records, NAMES, sole_depth_mm=-31.8)
    assert caveat.code == "floor" and caveat.frames == ()
    assert caveat.message.startswith("the fitted soles stood 32 mm below the calibration's floor")
    assert "not read from the floor (32 mm less)" in caveat.message


def test_a_camera_that_another_person_hides_in_most_frames_is_a_caveat():
    # Studio two-person session of seed 31: the detector missed one person in cam_03 in
    # 15 of 16 frames, the view was left out as occluded, and their arm span read 36 mm
    # short (10 mm alone) with nothing said.
    records = _records(6, 6)
    for k in range(4):
        records[k] = dataclasses.replace(records[k], flags={"cam_02": ("occluded",)})
    (caveat,) = run_caveats(records, NAMES, told_apart=True)
    assert caveat.code == "view_left_out" and caveat.frames == (0, 25, 50, 75)
    assert caveat.message.startswith("cam_02: hidden behind another person in 4 of 6 kept frames")
    assert caveat.message.endswith("the measurements rest on the other views")
    # Hidden in 2 of 6: a warning, not a caveat.
    for k in (2, 3):
        records[k] = dataclasses.replace(records[k], flags={})
    assert run_caveats(records, NAMES, told_apart=True) == ()


def test_a_person_measured_among_others_says_so_with_the_studio_s_figures():
    records = _records(6, 6, persons=2)
    records[5] = dataclasses.replace(records[5], persons=1)  # alone in the last frame
    (caveat,) = run_caveats(records, NAMES, told_apart=True)
    assert caveat.code == "among_persons" and caveat.frames == (0, 25, 50, 75, 100)
    assert caveat.message.startswith(
        "measured among 2 people (someone else in the capture volume in 5 of 6 kept frames)"
    )
    lo, hi = persons_studio().weight_kg
    assert f"{lo:+.1f} to {hi:+.1f} kg in weight" in caveat.message
    # Not told apart (one subject per frame): the several_persons caveat instead.
    assert [c.code for c in run_caveats(records, NAMES)] == ["several_persons"]
    # Told apart and alone in every frame, or not counted: nothing to say.
    assert run_caveats(_records(6, 6, persons=1), NAMES, told_apart=True) == ()
    assert run_caveats(_records(6, 6), NAMES, told_apart=True) == ()


def test_the_two_person_figures_are_the_benchmarks():
    # What the caveat quotes is what the committed two-person results measured (python
    # -m benchmarks two_persons [--long | --fresh | --neutral | --neutral-fresh]), not a
    # number typed in.
    results = Path(__file__).resolve().parents[2] / "benchmarks" / "results"
    rows = [
        person
        for name in TWO_PERSON_SETS
        for session in json.loads((results / name).read_text())["sessions"].values()
        for person in session["persons"]
    ]
    studio = persons_studio()
    assert studio.persons == len(rows) == 30
    assert studio.within == sum(all(p["within"].values()) for p in rows)
    for key, (lo, hi) in (
        ("height_mm", studio.height_mm),
        ("arm_span_mm", studio.arm_span_mm),
        ("weight_kg", studio.weight_kg),
    ):
        # A person whose session stage the run rejected has no session error.
        errors = [p["session_error"][key] for p in rows if p["session_error"][key] is not None]
        assert (lo, hi) == (round(min(errors), 1), round(max(errors), 1)), key
