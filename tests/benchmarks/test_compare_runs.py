"""Whether two runs measured the same (benchmarks/compare_runs.py), per person."""

from __future__ import annotations

import dataclasses

from benchmarks.compare_runs import differences
from bodymetry.estimation.records import FrameRecord
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import PersonResults, RunResults, SessionInfo

INFO = SessionInfo("/s", "s", ("cam_00", "cam_01"), 25.0, 10)


def _person(ident: int, statuses: dict[int, str], seconds: float = 1.0) -> PersonResults:
    frames = tuple(
        dataclasses.replace(FrameRecord(f, s), seconds={"total": seconds})
        for f, s in statuses.items()
    )
    return PersonResults(ident, frames, {}, told_apart=True)


def _run(*persons: PersonResults, warnings: tuple[str, ...] = ()) -> RunResults:
    return RunResults(INFO, ProcessConfig(), persons, warnings=warnings)


def test_runs_that_measured_the_same_are_equal_whatever_they_took():
    a = _run(_person(0, {0: "ok", 10: "ok"}), _person(1, {0: "ok"}))
    b = _run(_person(0, {0: "ok", 10: "ok"}, seconds=9.0), _person(1, {0: "ok"}, seconds=5.0))
    assert differences(a, b) == []
    # One subject's run (the persons' list of one) reads the same way.
    assert differences(_run(_person(0, {0: "ok"})), _run(_person(0, {0: "ok"}, 3.0))) == []


def test_each_difference_is_named_with_its_person():
    a = _run(_person(0, {0: "ok", 10: "ok"}), _person(1, {0: "ok"}))
    b = _run(_person(0, {0: "ok", 10: "poor fit: mean silhouette IoU 0.80 < 0.84"}),
             _person(1, {0: "ok"}), warnings=("cam_01: moved",))  # fmt: skip
    assert differences(a, b) == ["person 0: frame 10: status differs", "warnings differs"]
    assert differences(a, _run(_person(0, {0: "ok", 10: "ok"}))) == [
        "persons differ: [0, 1] against [0]"
    ]
    alone = _run(_person(0, {0: "ok"}))
    assert differences(alone, _run(_person(0, {0: "ok", 10: "ok"}))) == ["kept frames differ"]
