"""The studio's accuracy by body: ``python -m benchmarks studio_accuracy``.

Reads the committed end-to-end results (no rendering, no fitting) of every set of
tight-clothed studio sessions scored on the current pipeline (:data:`SETS`: issue 15's
eleven evaluated again, the edge, looks, unseen edge, arms, weight and children sets
of issue 33, and the low-contrast set of issue 32) and writes one row per session (the
subject's true height, weight and age, whether an arm was raised in enough measured
frames, whether capture saw the subject in low contrast (the run's outline contrast
below ``LOW_CONTRAST``; sessions whose results predate the figure wore the studio's
saturated colours), and the session stage's signed error per core measurement) to the
package's ``estimation/data/studio_sessions.json``, which
:mod:`bodymetry.estimation.studio_accuracy` holds each run against.

Its result says how well that rule would have told a session's error from the
others (leave one out): per core measurement, the sessions whose own error was
beyond the target, those the ``body_accuracy`` rule (:meth:`MeasuredAccuracy.beyond`)
would have named from the other sessions alone, and for each session the like
bodies' RMS and mean computed without it. And whether the 95 % interval a run
states (:mod:`bodymetry.estimation.uncertainty`) holds the truth: per
measurement, how many of the intervals stated from the other sessions alone held
it (``coverage``), their median half-width, the sessions outside, and the silent
misses (beyond the target, outside the interval, named by no caveat).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from benchmarks.bench_arm_evidence import RESULTS, committed_sessions
from benchmarks.bench_pipeline import _outfit
from bodymetry.estimation.arm_evidence import arms_raised
from bodymetry.estimation.studio_accuracy import (
    ADULT_AGE,
    CORE,
    DATA,
    LIKE_HEIGHT,
    LIKE_WEIGHT,
    MIN_LIKE,
    TARGETS,
    MeasuredAccuracy,
    StudioSession,
    is_low_contrast,
    like_accuracy,
    target_for,
)
from bodymetry.estimation.uncertainty import stated_interval

#: The committed results scored with the current pipeline (the height read from the
#: floor and the weight from the posed bodies), tight clothing only.
SETS = (
    "pipeline_recheck.json",
    "pipeline_edge.json",
    "pipeline_looks.json",
    "pipeline_edge_unseen.json",
    "pipeline_arms.json",
    "pipeline_weight.json",
    "pipeline_children.json",
    "pipeline_contrast.json",
    "pipeline_edge_fresh.json",
    "pipeline_edge_fourth.json",
    "pipeline_children_fresh.json",
    "pipeline_contrast_fresh.json",
    "pipeline_contrast_clothing.json",
    "pipeline_loose_gaps.json",
    "pipeline_tight_night.json",
    "pipeline_shorts.json",
)


def scored_sessions(names: tuple[str, ...] = SETS) -> list[StudioSession]:
    """One :class:`StudioSession` per tight-clothed session with a session-stage value
    of every core measurement in the committed results ``names``."""
    out = []
    for name in names:
        for s in committed_sessions((name,)):
            f3 = s["figure3"]
            folder = Path(s["session"]).name
            if _outfit(s.get("subject") or folder) != "tight":
                continue
            if not all("session" in f3[k] for k in CORE):
                continue
            out.append(
                StudioSession(
                    name=f"{Path(name).stem}:{folder}",
                    height_mm=float(f3["height_mm"]["actual"]),
                    weight_kg=float(f3["weight_kg"]["actual"]),
                    age_years=float(s.get("age_years") or s["edge"]["age_years"]),
                    arms_raised=bool(arms_raised(s["arm_raised_frames"])),
                    errors={k: float(f3[k]["session"]["mean"] - f3[k]["actual"]) for k in CORE},
                    low_contrast=bool(is_low_contrast(s.get("outline_contrast"))),
                    standard_errors={k: float(f3[k]["session"]["std"]) for k in CORE},
                    frames=int(f3[CORE[0]]["session"]["n"]),
                )
            )
    return out


#: The committed two-person results (``python -m benchmarks two_persons``, ``--long``,
#: ``--fresh``, ``--neutral`` and ``--neutral-fresh``): each person scored against their
#: own truth.
TWO_PERSON_SETS = (
    "two_persons.json",
    "two_persons_long.json",
    "two_persons_fresh.json",
    "two_persons_neutral.json",
    "two_persons_neutral_fresh.json",
)


def crowded_sessions(names: tuple[str, ...] = TWO_PERSON_SETS) -> list[StudioSession]:
    """One :class:`StudioSession` per person of the committed two-person results
    ``names`` (the age is not recorded; an arm counts as raised where the run did not
    say ``arms_down``; a person whose session stage the run rejected has no errors)."""
    out = []
    for name in names:
        for folder, session in committed_two_person(name).items():
            for p in session["persons"]:
                errors = {k: float(v) for k, v in p["session_error"].items() if v is not None}
                se = p.get("session_standard_error") or {}
                out.append(
                    StudioSession(
                        name=f"{Path(name).stem}:{folder}/{p['person']}",
                        height_mm=float(p["actual"]["height_mm"]),
                        weight_kg=float(p["actual"]["weight_kg"]),
                        age_years=float("nan"),
                        arms_raised="arms_down" not in p["caveats"],
                        errors=errors,
                        standard_errors={k: float(v) for k, v in se.items() if v is not None},
                        frames=int(p["frames_measured"]),
                    )
                )
    return out


def committed_two_person(name: str) -> dict:
    """The sessions of one committed two-person results file (none where absent)."""
    path = RESULTS / name
    return json.loads(path.read_text())["sessions"] if path.is_file() else {}


def leave_one_out(sessions: list[StudioSession]) -> dict:
    """Per session, the like bodies' accuracy without it, beside its own error."""
    rows = []
    for i, s in enumerate(sessions):
        others = sessions[:i] + sessions[i + 1 :]
        measured = {"height_mm": s.height_mm, "weight_kg": s.weight_kg}
        like = like_accuracy(measured, s.arms_raised, others, low_contrast=s.low_contrast)
        row = {
            "session": s.name,
            "low_contrast": s.low_contrast,
            "errors": {k: round(v, 2) for k, v in s.errors.items()},
        }
        for key in CORE:
            acc = like.get(key)
            target = target_for(key, s.weight_kg, s.age_years < ADULT_AGE)
            # The interval the run would have stated, centred on the error (the value
            # less the truth): does it hold zero, the truth?
            interval = (
                None
                if acc is None or key not in s.standard_errors
                else stated_interval(s.errors[key], s.standard_errors[key], s.frames, acc)
            )
            row[key] = {
                "beyond_target": bool(abs(s.errors[key]) > target),
                "like_sessions": 0 if acc is None else acc.sessions,
                "like_rms": None if acc is None else round(acc.rms, 2),
                "like_bias": None if acc is None else round(acc.bias, 2),
                # Would a caveat have named it before it was scored? The arm span of arms
                # that stayed down is arms_down's, every measurement of a session seen in
                # low contrast low_contrast's; the rest body_accuracy's.
                "flagged": (key == "arm_span_mm" and not s.arms_raised)
                or s.low_contrast
                or (acc is not None and acc.beyond(target)),
                "half_width": None if interval is None else round(interval.half_width, 2),
                "inside": None if interval is None else interval.contains(0.0),
            }
        rows.append(row)
    return {
        "sessions": rows,
        **{
            key: {
                "beyond_target": [r["session"] for r in rows if r[key]["beyond_target"]],
                "flagged": [r["session"] for r in rows if r[key]["flagged"]],
                "beyond_and_flagged": sum(
                    r[key]["beyond_target"] and r[key]["flagged"] for r in rows
                ),
                **_coverage(rows, key),
            }
            for key in CORE
        },
    }


def among_others_out(alone: list[StudioSession], crowded: list[StudioSession]) -> dict:
    """Per person of the two-person sessions, the interval a run measuring them among
    others would state (every single-person session, and the other two-person persons
    alone), and whether it held the truth. Where the benchmark recorded no standard
    error the statistical part is left out, which can only narrow the interval."""
    rows = []
    for i, s in enumerate(crowded):
        others = crowded[:i] + crowded[i + 1 :]
        measured = {"height_mm": s.height_mm, "weight_kg": s.weight_kg}
        like = like_accuracy(measured, s.arms_raised, alone, among_others=True, crowded=others)
        row: dict = {"session": s.name, "errors": {k: round(v, 2) for k, v in s.errors.items()}}
        for key in CORE:
            acc = like.get(key)
            interval = (
                None
                if acc is None or key not in s.errors
                else stated_interval(s.errors[key], s.standard_errors.get(key, 0.0), s.frames, acc)
            )
            row[key] = {
                "beyond_target": key in s.errors and abs(s.errors[key]) > TARGETS[key],
                "scope": None if acc is None else acc.scope,
                # Every person here carries among_persons, which names the condition.
                "flagged": True,
                "half_width": None if interval is None else round(interval.half_width, 2),
                "inside": None if interval is None else interval.contains(0.0),
            }
        rows.append(row)
    return {"persons": rows, **{key: _coverage(rows, key) for key in CORE}}


def _coverage(rows: list[dict], key: str) -> dict:
    """How often the stated 95 % interval held the truth, and the silent misses: beyond
    the target, outside the interval (or none stated) and named by no caveat."""
    stated = [r for r in rows if r[key]["inside"] is not None]
    return {
        "intervals_stated": len(stated),
        "truth_inside": sum(r[key]["inside"] for r in stated),
        "coverage": round(sum(r[key]["inside"] for r in stated) / max(len(stated), 1), 3),
        "median_half_width": (
            round(float(np.median([r[key]["half_width"] for r in stated])), 2) if stated else None
        ),
        "outside": [r["session"] for r in stated if not r[key]["inside"]],
        "silent_misses": [
            r["session"]
            for r in rows
            if r[key]["beyond_target"] and not r[key]["flagged"] and not r[key]["inside"]
        ],
    }


def run(**_: bool) -> dict:
    sessions = scored_sessions()
    crowded = crowded_sessions()
    DATA.parent.mkdir(parents=True, exist_ok=True)
    DATA.write_text(
        json.dumps(
            {
                "source": (
                    f"python -m benchmarks studio_accuracy, from {list(SETS)} and "
                    f"{list(TWO_PERSON_SETS)} (among_others)"
                ),
                "sessions": [s.to_json() for s in sessions],
                "among_others": [s.to_json() for s in crowded],
            },
            indent=1,
        )
        + "\n"
    )
    per_key = {}
    for key in CORE:
        e = np.array([s.errors[key] for s in sessions])
        per_key[key] = {
            "rms": round(float(np.sqrt(np.mean(e**2))), 2),
            "worst": round(float(np.abs(e).max()), 2),
        }
    low = [s for s in sessions if s.low_contrast]
    return {
        "setup": (
            f"{len(sessions)} tight-clothed studio sessions of {list(SETS)} (committed results "
            f"in {RESULTS.name}/); like bodies: height within {LIKE_HEIGHT} and weight within "
            f"{LIKE_WEIGHT} (log ratio), at least {MIN_LIKE} sessions; written to {DATA.name}"
        ),
        "all_sessions": per_key,
        # Issue 32: the sessions capture saw in low contrast, every body together.
        "low_contrast": {
            "sessions": [s.name for s in low],
            **{
                key: MeasuredAccuracy.of([s.errors[key] for s in low], "low contrast").to_json()
                for key in CORE
                if low
            },
        },
        "leave_one_out": leave_one_out(sessions),
        # The persons of the two-person sessions, each held against the others
        # (estimation.studio_accuracy.like_accuracy, among_others).
        "among_others": among_others_out(sessions, crowded),
    }
