"""Caveats: when a run's numbers stand on thin or ambiguous evidence, say so.

A run that measured something can still deserve less trust than its numbers
suggest. Each :class:`Caveat` names one such condition, found from the run's
own records (so a finished run, and an old ``results.json``, gives the same
list), and says why in a sentence a user can act on:

``several_persons``
    Capture counted more than one person-sized body in the capture volume in
    some kept frames (:attr:`FrameRecord.persons`) and did not tell the
    measured person apart from the others (``--largest``, or a hull's split
    it could not measure from): one subject is measured, the largest body of
    each frame (the most prominent person without an empty-scene clip), and
    its numbers may mix people.
``among_persons``
    The person was told apart from others in the capture volume and measured
    on their own (a run of several persons, or ``process --person N``), in
    kept frames where capture counted more than one person. Someone else
    hides parts of them, and their masks are cut from the others': the
    studio's two-person sessions read a person's session stage further off
    than one person's alone (:func:`persons_studio`), and the 95 % intervals
    hold the larger of both errors
    (:func:`~bodymetry.estimation.studio_accuracy.like_accuracy`).
``thin_evidence``
    Fewer than :data:`MIN_MEASURED_FRAMES` frames, or fewer than
    :data:`MIN_MEASURED_SHARE` of the kept frames, were measured.
``view_left_out``
    A camera's view was left out as ``unreliable``, ``occluded`` (another
    person hides them there) or ``mixed`` (the detection there is partly
    another person's) in at least :data:`MAX_LEFT_OUT_SHARE` of the kept
    frames: the measurements rest on the other views, and whatever made that
    view disagree (a reflection, a moved camera, a second person) may be in them
    too.
``clothing``
    The session stage's outline check found the observed outline wider than
    the body's around the trunk or above the head (loose clothing or hair):
    height, girths and weight may be inflated.
``floor``
    The session stage's fitted soles stood deeper below the floor (world
    z = 0) than :data:`~bodymetry.estimation.standing_height.MAX_SOLE_DEPTH`,
    more than shadow under the shoes sinks them: the person may stand on a
    floor lower than the calibration's, or the silhouettes reach below the
    feet. The height is the fitted body's own, not read from the floor.
``arms_down``
    Fewer than :data:`~bodymetry.estimation.arm_evidence.MIN_RAISED_FRAMES`
    measured frames had an arm raised (:mod:`bodymetry.estimation.arm_evidence`):
    the arm span rests on arms hanging by the body, which the studio's sessions
    read high (:func:`arms_down_studio`).
``low_contrast``
    Capture saw the person in low contrast (the run's outline contrast, the
    median of its frames' :attr:`FrameRecord.outline_contrast`, below
    :data:`~bodymetry.estimation.studio_accuracy.LOW_CONTRAST`: white, light
    grey or wall-coloured clothing before a background of about its colour).
    The silhouettes then rest on the learned segmenter and the multi-view hull
    more than on colour, and the studio's sessions seen so read the weight
    light in nearly every one and the arm span up to two centimetres off either
    way (issue 32): the message quotes their errors.
``coarse_pixels``
    The session stage's working pixels at the body
    (:attr:`~bodymetry.estimation.records.OutlineCheck.mm_per_px`) are coarser than
    :data:`~bodymetry.estimation.studio_accuracy.COARSE_FACTOR` times those of every
    studio session that measured the accuracy (640x480 cameras, a person about
    300 px tall): the studio's figures do not apply, and no 95 % interval is stated.
``outside_validated``
    Fewer than 2 of the studio's scored sessions were of a body like the
    measured one (:mod:`bodymetry.estimation.studio_accuracy`: true height within
    8 %, weight within 25 %); with only a height or a weight, it lies outside
    the span of the bodies the benchmarks validated the body model on
    (:data:`VALIDATED`, issue 33's edge set): the numbers are an extrapolation
    of the body model, with no measured accuracy.
``body_accuracy``
    On the studio's sessions of bodies like the measured one
    (:mod:`bodymetry.estimation.studio_accuracy`: height within 8 %, weight within
    25 %, the same arm evidence for the arm span; at least 2 sessions), a core
    measurement's RMS error exceeds its target (10 mm, 15 mm, 1.5 kg or 3 % of a
    child's weight), or they read it off one way by more than half the target
    (:meth:`~bodymetry.estimation.studio_accuracy.MeasuredAccuracy.beyond`): the
    arm span of a 6-year-old read short in every session.

The command line prints the caveats and exits with status 5
(:data:`bodymetry.cli.common.EXIT_CAVEATS`); the report lists them first;
``results.json`` carries them as ``caveats``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cache

from bodymetry.errors import InputError
from bodymetry.estimation.arm_evidence import MIN_RAISED_FRAMES, RAISED_DEG, arms_raised
from bodymetry.estimation.records import FrameRecord
from bodymetry.estimation.standing_height import MAX_SOLE_DEPTH
from bodymetry.estimation.studio_accuracy import (
    LIKE_HEIGHT,
    LIKE_WEIGHT,
    LOW_CONTRAST,
    MIN_LIKE,
    TARGETS,
    VALIDATED_MM_PER_PX,
    StudioSession,
    among_others_sessions,
    arms_note,
    coarse_pixels,
    contrast_accuracy,
    is_low_contrast,
    like_accuracy,
    like_children,
    like_sessions,
    run_contrast,
    studio_sessions,
    target_for,
)
from bodymetry.estimation.view_selection import left_out_views

__all__ = [
    "CAVEAT_CODES",
    "MAX_LEFT_OUT_SHARE",
    "MIN_MEASURED_FRAMES",
    "MIN_MEASURED_SHARE",
    "VALIDATED",
    "ArmsDownError",
    "Caveat",
    "PersonsError",
    "ValidatedRange",
    "arms_down_studio",
    "persons_studio",
    "run_caveats",
]

#: Fewer measured frames than this is thin evidence (a session's spread and the
#: session stage need several poses).
MIN_MEASURED_FRAMES = 3
#: ... and so is measuring less than this share of the kept frames.
MIN_MEASURED_SHARE = 0.5
#: A camera left out of at least this share of the kept frames is a caveat.
MAX_LEFT_OUT_SHARE = 0.5

#: Every caveat code, in the order they are listed.
CAVEAT_CODES = (
    "several_persons",
    "among_persons",
    "thin_evidence",
    "view_left_out",
    "clothing",
    "floor",
    "arms_down",
    "low_contrast",
    "coarse_pixels",
    "outside_validated",
    "body_accuracy",
)


@dataclass(frozen=True)
class ArmsDownError:
    """The session stage's arm span error on the studio's sessions whose arms
    stayed down (fewer than ``MIN_RAISED_FRAMES`` measured frames with an arm raised).

    Attributes
    ----------
    low, high, mean : float
        Smallest, largest and mean signed error, mm (+: reads high).
    sessions : int
    """

    low: float
    high: float
    mean: float
    sessions: int


def arms_down_studio(sessions: Sequence[StudioSession] | None = None) -> ArmsDownError:
    """The arm span error of the studio's scored sessions whose arms stayed down.

    Read from the sessions that ship with the package
    (:func:`~bodymetry.estimation.studio_accuracy.studio_sessions`, the same
    scored sessions the ``body_accuracy`` caveat holds a run against), so the
    figures the caveat quotes are what the benchmarks measured and there is one
    place to update them (``python -m benchmarks studio_accuracy``).

    Parameters
    ----------
    sessions : sequence of StudioSession, optional
        Default: the shipped ones.

    Raises
    ------
    InputError
        When no scored session kept its arms down (a broken install).
    """
    pool = studio_sessions() if sessions is None else sessions
    errors = [
        s.errors["arm_span_mm"] for s in pool if not s.arms_raised and "arm_span_mm" in s.errors
    ]
    if not errors:
        raise InputError("the studio's scored sessions hold no arm span with the arms down")
    return ArmsDownError(
        low=round(min(errors), 1),
        high=round(max(errors), 1),
        mean=round(math.fsum(errors) / len(errors), 1),
        sessions=len(errors),
    )


@dataclass(frozen=True)
class PersonsError:
    """How far the studio's two-person sessions read each person's session stage.

    Attributes
    ----------
    height_mm, arm_span_mm, weight_kg : (float, float)
        Smallest and largest signed error against the person's truth.
    persons : int
        Persons scored.
    within : int
        Of them, within issue 15's targets (10 mm, 15 mm, 1.5 kg) in all three.
    """

    height_mm: tuple[float, float]
    arm_span_mm: tuple[float, float]
    weight_kg: tuple[float, float]
    persons: int
    within: int


@cache
def persons_studio() -> PersonsError:
    """The studio's two-person sessions (``python -m benchmarks two_persons``,
    ``--long``, ``--fresh`` and ``--neutral``), each person against their own truth, as
    shipped (:func:`~bodymetry.estimation.studio_accuracy.among_others_sessions`): the
    extremes of each measurement's error (0.1 mm or kg), and how many persons were
    within every target (a person whose session stage the run rejected has no error
    and is not within). ``tests/estimation/test_caveats.py`` recomputes it from the
    committed ``benchmarks/results/two_persons*.json``."""
    rows = among_others_sessions()

    def span(key: str) -> tuple[float, float]:
        errors = [s.errors[key] for s in rows if key in s.errors]
        return round(min(errors), 1), round(max(errors), 1)

    return PersonsError(
        height_mm=span("height_mm"),
        arm_span_mm=span("arm_span_mm"),
        weight_kg=span("weight_kg"),
        persons=len(rows),
        within=sum(
            all(k in s.errors and abs(s.errors[k]) <= TARGETS[k] for k in TARGETS) for s in rows
        ),
    )


@dataclass(frozen=True)
class ValidatedRange:
    """The bodies the end-to-end benchmarks measured, edge to edge.

    Attributes
    ----------
    height_mm, weight_kg, age_years : (float, float)
        Smallest and largest true value over the subjects.
    subjects : int
        How many studio subjects (one session each) span it.
    source : str
        The command that measured them.
    """

    height_mm: tuple[float, float]
    weight_kg: tuple[float, float]
    age_years: tuple[float, float]
    subjects: int
    source: str

    def describe(self) -> str:
        """The range in words, for the report and the caveat."""
        (h0, h1), (w0, w1), (a0, a1) = self.height_mm, self.weight_kg, self.age_years
        return (
            f"heights {h0:.0f}-{h1:.0f} mm, weights {w0:.0f}-{w1:.0f} kg, ages {a0:.0f}-{a1:.0f} "
            f"years ({self.subjects} studio subjects of both sexes, {self.source})"
        )

    def outside(self, measured: Mapping[str, float]) -> list[str]:
        """``"height 1052 mm"``-style entries for the measured values outside the
        range (``height_mm`` and ``weight_kg`` of ``measured``; others ignored)."""
        out = []
        for key, label, unit, (lo, hi) in (
            ("height_mm", "height", "mm", self.height_mm),
            ("weight_kg", "weight", "kg", self.weight_kg),
        ):
            value = measured.get(key)
            if value is not None and math.isfinite(value) and not lo <= value <= hi:
                out.append(f"{label} {value:.0f} {unit}")
        return out


#: The edge set of issue 33 (``python -m benchmarks pipeline --edge``): the 1st and
#: 99th percentiles of height and weight of adult women and men, an 80-year-old and
#: children of 6, 10 and 14; the mid-population subjects of issue 15 lie inside it.
#: ``tests/estimation/test_caveats.py`` recomputes it from
#: ``benchmarks/results/pipeline_edge.json``, so it cannot drift from what was measured.
VALIDATED = ValidatedRange(
    height_mm=(1145.3, 1938.8),
    weight_kg=(21.18, 110.95),
    age_years=(6.0, 80.0),
    subjects=12,
    source="python -m benchmarks pipeline --edge",
)


@dataclass(frozen=True)
class Caveat:
    """One reason to trust a run's numbers less than they look.

    Attributes
    ----------
    code : str
        One of :data:`CAVEAT_CODES`.
    message : str
        What was found and what it means, one sentence.
    frames : tuple of int
        The kept frames it concerns (empty: the whole run).
    """

    code: str
    message: str
    frames: tuple[int, ...] = ()

    def to_json(self) -> dict:
        out: dict = {"code": self.code, "message": self.message}
        if self.frames:
            out["frames"] = list(self.frames)
        return out


def _frame_list(frames: Sequence[int], limit: int = 6) -> str:
    """``"frames 0, 25, 50"`` (the first ``limit``, then ``...``)."""
    shown = ", ".join(str(f) for f in frames[:limit])
    return f"frame{'s' if len(frames) > 1 else ''} {shown}{', ...' if len(frames) > limit else ''}"


def run_caveats(
    records: Sequence[FrameRecord],
    cameras: Sequence[str],
    outline_warnings: Sequence[str] = (),
    told_apart: bool = False,
    headline: Mapping[str, float] | None = None,
    raised: Sequence[int] | None = None,
    sole_depth_mm: float | None = None,
    mm_per_px: float | None = None,
) -> tuple[Caveat, ...]:
    """The caveats of a run (module docstring), in :data:`CAVEAT_CODES` order.

    Parameters
    ----------
    records : sequence of FrameRecord
        The run's kept frames.
    cameras : sequence of str
        The session's camera names.
    outline_warnings : sequence of str
        The session stage's outline-check warnings (loose clothing, hair).
    told_apart : bool
        Capture told the measured person apart from the others in view (a run of
        several persons, or ``process --person N``): others then do not mix into
        the numbers, and ``several_persons`` is not raised.
    headline : mapping of str to float, optional
        The run's headline ``height_mm`` and ``weight_kg`` (the session stage's,
        else the frames' mean), held against the studio's like bodies (:func:`_validity`).
    raised : sequence of int, optional
        The measured frames with an arm raised
        (:func:`bodymetry.estimation.arm_evidence.raised_frames`); None: not judged.
    sole_depth_mm : float, optional
        The session stage's soles below the floor, mm (:attr:`SessionShape.floor_mm`,
        negative below); None: not judged (no session stage, or the floor not read).
    mm_per_px : float, optional
        The session stage's working pixel at the body, mm (the outline check's); None:
        not judged.

    Returns
    -------
    tuple of Caveat
        Empty when the run measured nothing (that is an error, not a caveat) or
        nothing questions its numbers.
    """
    ordered = sorted(records, key=lambda r: r.frame)
    kept = len(ordered)
    measured = [r.frame for r in ordered if r.ok]
    if not measured:
        return ()
    out = []
    crowded = [r for r in ordered if r.crowded]
    frames = tuple(r.frame for r in crowded)
    if crowded and not told_apart:
        out.append(
            Caveat(
                "several_persons",
                f"more than one person in the capture volume in {len(crowded)} of {kept} kept "
                f"frames ({_frame_list(frames)}): bodymetry measures one "
                "subject per frame (the largest body, or the most prominent person where there "
                "is no empty-scene clip), so these measurements may mix people; each person is "
                "measured where capture tells them apart (not with --largest, nor where only "
                "the multi-view hull splits them)",
                frames,
            )
        )
    elif crowded:
        studio = persons_studio()
        (h0, h1), (a0, a1), (w0, w1) = studio.height_mm, studio.arm_span_mm, studio.weight_kg
        out.append(
            Caveat(
                "among_persons",
                f"measured among {max(r.persons for r in crowded)} people (someone else in the "
                f"capture volume in {len(crowded)} of {kept} kept frames): others hide parts of "
                "this person and their masks are cut from the others', and on the studio's "
                f"two-person sessions a person's measurements read {h0:+.1f} to {h1:+.1f} mm "
                f"in height, {a0:+.1f} to {a1:+.1f} mm in arm span and {w0:+.1f} to "
                f"{w1:+.1f} kg in weight off the truth ({studio.within} of "
                f"{studio.persons} persons within 10 mm, 15 mm and 1.5 kg): less "
                "sure than one person's alone, and the 95 % intervals are held to the "
                "larger of both errors",
                frames,
            )
        )
    need = max(MIN_MEASURED_FRAMES, math.ceil(MIN_MEASURED_SHARE * kept))
    if len(measured) < need:
        out.append(
            Caveat(
                "thin_evidence",
                f"only {len(measured)} of {kept} kept frames measured ({_frame_list(measured)}): "
                f"the measurements rest on thin evidence (at least {need} wanted; each "
                "frame's status in results.json says why it was not measured)",
                tuple(measured),
            )
        )
    for view in left_out_views(ordered, cameras):
        if len(view.frames) >= MAX_LEFT_OUT_SHARE * kept:
            out.append(
                Caveat(
                    "view_left_out",
                    f"{view.describe()}: the measurements rest on the other views",
                    view.frames,
                )
            )
    if outline_warnings:  # each already says what is likely overstated
        out.append(Caveat("clothing", "; ".join(outline_warnings)))
    if sole_depth_mm is not None and sole_depth_mm < -1000.0 * MAX_SOLE_DEPTH:
        out.append(
            Caveat(
                "floor",
                f"the fitted soles stood {-sole_depth_mm:.0f} mm below the calibration's floor "
                "(z = 0) in the median frame, deeper than the "
                f"{1000.0 * MAX_SOLE_DEPTH:.0f} mm that shadow under the shoes explains: the "
                "person may stand on a floor lower than the calibration's (beside a platform "
                "or treadmill), or the silhouettes reach below the feet; the height is the "
                f"fitted body's own, not read from the floor ({-sole_depth_mm:.0f} mm less)",
            )
        )
    if raised is not None and len(raised) < MIN_RAISED_FRAMES:
        seen = f" ({_frame_list(list(raised))})" if raised else ""
        studio = arms_down_studio()
        out.append(
            Caveat(
                "arms_down",
                f"an arm was raised (at least {RAISED_DEG:.0f} degrees from hanging) in "
                f"{len(raised)} of {len(measured)} measured frames{seen}: the arm span rests "
                "on arms by the body's sides, which the studio's sessions read "
                f"{studio.low:+.1f} to {studio.high:+.1f} mm off (mean {studio.mean:+.1f} mm, "
                f"{studio.sessions} sessions; + reads long); record a few frames with the "
                "arms held out or raised to measure it",
            )
        )
    contrast = run_contrast(ordered)
    low = is_low_contrast(contrast)
    if low:
        out.append(_low_contrast(contrast, arms_raised(raised)))
    if coarse_pixels(mm_per_px):
        out.append(
            Caveat(
                "coarse_pixels",
                f"the outline was measured with working pixels of {mm_per_px:.1f} mm at the "
                f"body, coarser than the {VALIDATED_MM_PER_PX:.1f} mm of every studio session "
                "that measured bodymetry's accuracy (640x480 cameras, a standing person about "
                "300 px tall): the studio's figures do not apply here and no 95 % interval "
                "is stated; cameras nearer the person or of higher resolution give finer pixels",
            )
        )
    out += _validity(headline or {}, raised, low)
    return tuple(out)


def _low_contrast(contrast: float, arms: bool | None) -> Caveat:
    """``low_contrast``: the run's outline ``contrast`` and the studio's errors on every
    session it saw in low contrast (the arm span's on those of the same arm
    evidence ``arms``)."""
    studio = contrast_accuracy(True, arms)
    seen = "; ".join(
        f"the {_LABELS[k][0]} {a.low:+.1f} to {a.high:+.1f} {_LABELS[k][1]} "
        f"(mean {a.bias:+.1f}, RMS {a.rms:.1f}, {a.sessions} sessions{arms_note(k, arms)})"
        for k, a in studio.items()
    )
    return Caveat(
        "low_contrast",
        f"the person stood out little from the empty scene (outline contrast {contrast:.2f}, "
        f"below {LOW_CONTRAST}: clothing of about the background's colour, such as white, grey "
        "or wall-coloured clothing before a plain wall), so the silhouettes rest on the person "
        "segmenter and the multi-view hull more than on colour"
        + (f"; on the studio's sessions seen so, {seen}" if seen else "")
        + ": these numbers are less sure than their standard error says (docs/capture.md, "
        '"Outline contrast")',
    )


_LABELS = {
    "height_mm": ("height", "mm"),
    "arm_span_mm": ("arm span", "mm"),
    "weight_kg": ("weight", "kg"),
}


def _validity(
    headline: Mapping[str, float], raised: Sequence[int] | None, low_contrast: bool | None
) -> list[Caveat]:
    """``outside_validated`` when fewer than ``MIN_LIKE`` of the studio's scored sessions
    were of a body like the measured one (or, without both a height and a weight, when
    the given one lies outside :data:`VALIDATED`), else ``body_accuracy`` where the
    studio's error on like sessions (of like bodies, seen in like contrast:
    :func:`~bodymetry.estimation.studio_accuracy.like_accuracy`) exceeds a target."""
    height, weight = (float(headline.get(k, math.nan)) for k in ("height_mm", "weight_kg"))
    if math.isfinite(height) and math.isfinite(weight):
        like = like_sessions(height, weight)
        if len(like) >= MIN_LIKE:
            return _body_accuracy(height, weight, like_children(like), raised, low_contrast)
        message = (
            f"the measured height {height:.0f} mm and weight {weight:.0f} kg are unlike the "
            f"bodies the body model was validated on ({len(like)} of the studio's scored sessions "
            f"had a true height within {100 * LIKE_HEIGHT:.0f} % and weight within "
            f"{100 * LIKE_WEIGHT:.0f} % of them, fewer than {MIN_LIKE}; the validated bodies "
            f"span {VALIDATED.describe()})"
        )
    else:
        outside = VALIDATED.outside(headline)
        if not outside:
            return []
        message = (
            f"the measured {' and '.join(outside)} {'lie' if len(outside) > 1 else 'lies'} "
            f"outside the bodies the body model was validated on ({VALIDATED.describe()})"
        )
    return [
        Caveat(
            "outside_validated",
            f"{message}: the measurements extrapolate the model and their accuracy was not "
            "measured",
        )
    ]


def _body_accuracy(
    height: float,
    weight: float,
    child: bool,
    raised: Sequence[int] | None,
    low_contrast: bool | None,
) -> list[Caveat]:
    """``body_accuracy``: the measurements whose error on the studio's like sessions (of
    a body of ``height`` mm and ``weight`` kg, a ``child``'s, seen in like contrast)
    exceeds their target (one caveat naming them all)."""
    arms = arms_raised(raised)
    accuracy = like_accuracy(
        {"height_mm": height, "weight_kg": weight}, arms, low_contrast=low_contrast
    )
    parts = []
    for key, acc in accuracy.items():
        if key == "arm_span_mm" and arms is False:
            continue  # the arms_down caveat names the arm span already
        target = target_for(key, weight, child)
        if acc.beyond(target):
            label, unit = _LABELS[key]
            seen = f"{acc.low:+.1f} to {acc.high:+.1f} {unit}, {acc.sessions} {acc.scope}"
            parts.append(
                f"the {label} read {acc.rms:.1f} {unit} RMS off ({seen}; mean "
                f"{acc.bias:+.1f} {unit}), beyond the {target:.1f} {unit} target"
                if acc.rms > target
                else f"the {label} read {'high' if acc.bias > 0 else 'low'} by "
                f"{abs(acc.bias):.1f} {unit} on average ({seen}), more than half the "
                f"{target:.1f} {unit} target"
            )
    if not parts:
        return []
    return [
        Caveat(
            "body_accuracy",
            "on the studio's scored sessions (a body is like this one when its true height "
            f"is within {100 * LIKE_HEIGHT:.0f} % and its weight within "
            f"{100 * LIKE_WEIGHT:.0f} % of the measured {height:.0f} mm and "
            f"{weight:.1f} kg), {'; '.join(parts)}: those numbers are less sure than their "
            "standard error says (python -m benchmarks studio_accuracy)",
        )
    ]
