"""Where the session stage's error comes from: the stage again, from truer starts and data.

``python -m benchmarks session_bias`` processes each studio session (the demo by
default; ``BODYMETRY_BENCH_SESSIONS=a:b:c`` for others, rendered beforehand, e.g. by
``bodymetry synth``) into ``$BODYMETRY_BENCH_RUN_DIR/<name>`` (a temporary folder by
default; an existing finished run there is reused) with the user's model cache, then
runs the session stage (:func:`~bodymetry.estimation.session_shape.fit_session_shape`,
the run's own settings) four times over the same accepted frames:

==========================  =============================  ==========================
condition                   starts                         silhouettes
==========================  =============================  ==========================
``stage``                   the per-frame fits             segmented (the run's)
``true_silhouettes``        the per-frame fits             rendered truth
``true_states``             true τ, θ and ν                segmented
``true_states_silhouettes`` true τ, θ and ν                rendered truth
==========================  =============================  ==========================

Each gives the error of height, arm span and weight against the subject's truth,
the fitted body's lowest point over the frames (``lowest_point_mm``, median; the
studio stands its subjects on the floor, z = 0, so a negative figure is soles sunk
into it, read as that much more height), the session cost before and after, and
the steps taken; ``arms_subsets`` repeats
``stage`` and ``true_states_silhouettes`` on the frames whose true pose has a wrist
above its shoulder and on the others (each when it has 3 frames or more). Reading the table: the
gap between ``stage`` and ``true_states`` is what the per-frame fits' poses (local
minima) cost; between ``true_states`` and ``true_states_silhouettes`` what the
segmentation costs; and ``true_states_silhouettes`` itself is the floor of the
cost (its correspondences and the body model). For a subject the model was not
built from (``--subject independent:...``) there is no true ν: the "true states"
then have the true pose and the per-frame fits' median ν (the stage's own start).

``python -m benchmarks session_bias --parts`` (``session_bias_parts.json``) adds
``part_swaps``: the ``stage`` condition again with the pixels of one group of body
parts (:data:`PART_GROUPS`) taken from the rendered truth, one group at a time, and
with every pixel but the hands' and the forearms' taken from it: which part's
segmentation moves which measurement. A pixel belongs to the part of its nearest
projected vertex within :data:`benchmarks.bench_capture.PART_RADIUS_PX` (the subject
posed by its true state, an independent subject with its shape projected onto the
model's space).

For an independent subject the report also gives ``posing_offsets_mm``: at each
frame's true pose and the subject's own shape (its rest body projected onto the
model's shape space), how far the rendered true outline lies outside the model's
contour, per body region (median over frames of
:func:`~bodymetry.estimation.outline_check.frame_offsets`; + outside). It is the
difference between our posed body model and the rig's skinning that poses the
subject, which no fit of ν can remove.

Only sessions with ground truth (``ground_truth/states.npz``,
``ground_truth/silhouettes``, ``ground_truth/subject.json``) can be used.
"""

from __future__ import annotations

import functools
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from benchmarks.bench_capture import frame_part_labels
from bodymetry.capture.ground_truth import SubjectTruth
from bodymetry.capture.session import Session, load_session
from bodymetry.cli import DEMO_SESSION
from bodymetry.estimation.body_model.model import NU, BodyState
from bodymetry.estimation.body_model.skeleton import PARTS
from bodymetry.estimation.fit import shared_body_model
from bodymetry.estimation.outline_check import REGIONS, frame_offsets
from bodymetry.estimation.records import FrameArrays
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import RunLayout
from bodymetry.estimation.session_shape import SessionFrame, fit_session_shape, session_frame
from bodymetry.estimation.standing_height import lowest_points
from bodymetry.fileio import load_npz
from bodymetry.process import process_session
from bodymetry.review.run_data import RunData, load_run
from bodymetry.studio.independent import IndependentSubject
from bodymetry.studio.synth import SubjectSpec

#: The biometrics compared (results.json keys).
KEYS = ("height_mm", "arm_span_mm", "weight_kg")
CONDITIONS = ("stage", "true_silhouettes", "true_states", "true_states_silhouettes")
#: The arm subsets are reported when each has at least this many frames.
MIN_SUBSET = 3
#: The groups of body parts whose pixels ``part_swaps`` takes from the truth in turn.
PART_GROUPS = {
    "hands": ("hand_l", "hand_r"),
    "forearms": ("lower_arm_l", "lower_arm_r"),
    "upper_arms": ("upper_arm_l", "upper_arm_r"),
    "trunk_head": ("pelvis", "torso", "head"),
    "legs": ("thigh_l", "shin_l", "foot_l", "thigh_r", "shin_r", "foot_r"),
}
#: ``part_swaps``'s last condition: every pixel from the truth but these groups'.
ALL_BUT = ("hands", "forearms")


def _true_masks(session, cameras, frame: int) -> list[np.ndarray]:
    """The rendered true silhouettes of one frame at the working cameras' sizes."""
    out = []
    for cam in cameras:
        path = session.ground_truth_silhouette_path(cam.name, frame)
        mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if mask is None:
            raise FileNotFoundError(f"{path}: no true silhouette")
        w, h = cam.size
        if mask.shape != (h, w):
            mask = cv2.resize(mask, (w, h), interpolation=cv2.INTER_AREA)
        out.append(mask > 127)
    return out


def _true_states(session, frames: list[SessionFrame]) -> tuple[list[np.ndarray], bool]:
    """Each frame's true ``[τ, θ, ν]`` (ν the per-frame fits' median without a true
    one), and whether the session has a true ν.

    A recorded ν with fewer components than the model's predates its shape space
    (the bundled demo, recorded on 2026-11-22 with 9, before the re-bake of 2026-12-04): its
    components are another basis's, so it is no true ν here. A longer one is
    the same space's (the studio records every stored component) and is cut."""
    folder = session.path(session.ground_truth)
    states = load_npz(folder / "states.npz")
    start_nu = np.median(np.stack([f.start[NU] for f in frames]), axis=0)
    known = "nu" in states and len(states["nu"]) >= len(start_nu)
    nu = states["nu"][: len(start_nu)] if known else start_nu
    out = []
    for f in frames:
        row = np.nonzero(states["frame"] == f.frame)[0]
        if len(row) == 0:
            raise ValueError(f"{folder}/states.npz: no state for frame {f.frame}")
        i = int(row[0])
        out.append(np.r_[states["tau"][i], states["theta"][i], nu])
    return out, known


def _arms_up(body, states: list[np.ndarray]) -> np.ndarray:
    """(F,) bool: frames whose true pose has either wrist above its shoulder."""
    names = body.keypoint_names
    kp = body.pose(BodyState.from_vector(np.stack(states))).keypoints
    return np.array(
        [
            max(k[names.index(f"wrist_{s}"), 2] - k[names.index(f"shoulder_{s}"), 2] for s in "lr")
            > 0
            for k in kp
        ]
    )


def _lowest_point_mm(body, estimates) -> float | None:
    """Median over frames of the fitted body's lowest point (full mesh), mm above the
    floor (z = 0; the studio stands its subjects on it, so below 0 the fit sank the
    soles into the floor and reads the body taller by about as much)."""
    states = [e.vector() for e in estimates]
    if not states:
        return None
    return round(float(np.median(lowest_points(body.pose_states(np.stack(states))))) * 1000.0, 2)


def _projected_nu(body, subject: str) -> np.ndarray:
    """An independent subject's rest body projected onto the model's shape space."""
    spec = SubjectSpec.parse(subject, 0).independent
    return body.shape_from_vertices(IndependentSubject(spec).rest[None])[0]


def swapped_masks(
    observed: np.ndarray, true: np.ndarray, labels: np.ndarray, parts: list[int], keep: bool
) -> np.ndarray:
    """(H, W) bool: ``observed`` with the pixels whose part ``labels`` (H, W) int (-1:
    none) is one of ``parts`` taken from ``true`` (``keep`` False), or every pixel but
    those (``keep`` True)."""
    near = np.isin(labels, parts)
    return np.where(near != keep, true, observed)


def posing_offsets(body, cameras, nu: np.ndarray, states, masks, refinement) -> dict:
    """Median outline offset per region (mm) of an independent subject's rendered
    truth against the model at the true pose and the subject's projected shape
    ``nu`` (:func:`_projected_nu`)."""
    parts = body.parts_of_vertices(not refinement.full_mesh)
    per_region: dict[str, list[float]] = {name: [] for name in REGIONS if REGIONS[name]}
    for state, frame_masks in zip(states, masks, strict=True):
        y = np.r_[state[: len(state) - len(nu)], nu]
        verts, mm, _ = frame_offsets(body, cameras, frame_masks, y, refinement)
        for name, values in per_region.items():
            sel = np.isin(parts[verts], [PARTS.index(p) for p in REGIONS[name]])
            if sel.any():
                values.append(float(np.median(mm[sel])))
    return {k: round(float(np.median(v)), 2) for k, v in per_region.items() if v}


@dataclass(frozen=True)
class ProcessedSession:
    """A processed studio session, as the session stage sees it, with its truth."""

    run: RunData
    session: Session
    truth: dict
    recorded: ProcessConfig
    frames: list[SessionFrame]


def processed_session(session_dir: Path, run_dir: Path) -> ProcessedSession:
    """Process one session into ``run_dir`` (or reuse its finished run there) and load
    its accepted frames and its ground truth."""
    config = ProcessConfig(workers=os.cpu_count() or 1, review=False)
    process_session(session_dir, run_dir, config)
    run = load_run(run_dir)
    session = load_session(session_dir)
    truth = SubjectTruth.read(session.ground_truth_path).measurements
    layout = RunLayout(run_dir)
    frames = [
        session_frame(r, FrameArrays.load(layout.frame_arrays(r.frame)), run.cameras)
        for r in run.results.frames
        if r.ok
    ]
    return ProcessedSession(run, session, truth, run.results.config, frames)


def session_bias(session_dir: Path, run_dir: Path, parts: bool = False) -> dict:
    """Process one session (or reuse its finished run) and run the four conditions
    (and, with ``parts``, the part swaps)."""
    processed = processed_session(session_dir, run_dir)
    run, session, truth = processed.run, processed.session, processed.truth
    recorded, frames = processed.recorded, processed.frames
    true_masks = [_true_masks(session, run.cameras, f.frame) for f in frames]
    true_states, true_nu = _true_states(session, frames)
    body = shared_body_model()
    out = {
        "session": str(session_dir),
        "frames": len(frames),
        "truth": {k: truth[k] for k in KEYS},
        "true_nu": true_nu,
    }

    def condition(name: str, use: np.ndarray, masks: list | None = None) -> dict:
        """The stage under one condition, on the frames where ``use`` is True
        (``masks``: per frame the silhouettes to use instead of the condition's)."""
        use_truth = name.startswith("true_states")
        use_masks = name.endswith("silhouettes")
        chosen = masks or [
            t if use_masks else f.masks for f, t in zip(frames, true_masks, strict=True)
        ]
        inputs = [
            replace(f, start=s if use_truth else f.start, masks=m)
            for f, s, m, u in zip(frames, true_states, chosen, use, strict=True)
            if u
        ]
        fit = fit_session_shape(
            body,
            run.cameras,
            inputs,
            recorded.fit.refinement,
            # The stage's verdict on the IoU is beside the point here.
            replace(recorded.session_shape, max_iou_drop=1.0),
            recorded.fit.density,
        )
        s = fit.summary
        return {
            "status": s.status,
            "frames": len(inputs),
            "errors": {k: round(s.biometrics[k] - truth[k], 2) for k in KEYS},
            "lowest_point_mm": _lowest_point_mm(body, fit.estimates.values()),
            "standard_errors": {k: round(s.standard_errors[k], 2) for k in KEYS},
            "cost": [round(s.initial_cost, 2), round(s.cost, 2)],
            "steps": s.iterations,
        }

    every = np.ones(len(frames), bool)
    for name in CONDITIONS:
        out[name] = condition(name, every)
    # The same on the frames with either wrist above its shoulder (true pose) and on
    # the others: whether the floor comes from the arms-overhead frames.
    up = _arms_up(body, true_states)
    out["arms_subsets"] = {
        label: {name: condition(name, use) for name in ("stage", "true_states_silhouettes")}
        for label, use in (("arms_up", up), ("arms_down", ~up))
        if use.sum() >= MIN_SUBSET
    }
    # The subject's spec is a detail of ground_truth/subject.json, not a measurement.
    subject = str(SubjectTruth.read(session.ground_truth_path).details.get("subject", ""))
    # An independent subject's shape in the model's space (once: a projection of its
    # full body), for the part labels and the posing offsets.
    nu = _projected_nu(body, subject) if subject.startswith("independent:") else None
    if parts:
        # The part labels need the subject's shape: its own ν, or its body projected.
        if nu is None and not true_nu:
            out["part_swaps"] = {"skipped": "the subject's shape in this model's space is unknown"}
        else:
            labels = [
                frame_part_labels(body, run.cameras, s, s[NU] if nu is None else nu)
                for s in true_states
            ]
            swaps = {g: (PART_GROUPS[g], False) for g in PART_GROUPS}
            swaps["all_but_" + "_".join(ALL_BUT)] = (
                tuple(p for g in ALL_BUT for p in PART_GROUPS[g]),
                True,
            )
            out["part_swaps"] = {}
            for label, (group, keep) in swaps.items():
                ids = [PARTS.index(p) for p in group]
                masks = [
                    [
                        swapped_masks(o, t, lab, ids, keep)
                        for o, t, lab in zip(f.masks, tm, fl, strict=True)
                    ]
                    for f, tm, fl in zip(frames, true_masks, labels, strict=True)
                ]
                out["part_swaps"][label] = condition("stage", every, masks)
    if nu is not None:
        out["posing_offsets_mm"] = posing_offsets(
            body, run.cameras, nu, true_states, true_masks, recorded.fit.refinement
        )
    return out


def per_session(report: Callable[[Path, Path], dict]) -> dict:
    """``report(session_dir, run_dir)`` for each session of ``BODYMETRY_BENCH_SESSIONS``
    (the demo by default), its run in ``$BODYMETRY_BENCH_RUN_DIR/<name>`` (a temporary
    folder by default)."""
    sessions = os.environ.get("BODYMETRY_BENCH_SESSIONS")
    folders = [Path(p) for p in sessions.split(":")] if sessions else [Path(DEMO_SESSION)]
    keep = os.environ.get("BODYMETRY_BENCH_RUN_DIR")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(keep) if keep else Path(tmp)
        return {"sessions": [report(f, root / f.name) for f in folders]}


def run(parts: bool = False) -> dict:
    return per_session(functools.partial(session_bias, parts=parts))
