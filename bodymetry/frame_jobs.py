"""One kept frame's fit as a job: what a worker needs, and the files it leaves.

A :class:`FitJob` carries one frame's silhouettes at the working resolution
and everything the fit needs without access to the session, so that
``process`` (a process pool) and ``batch`` (Dask tasks) run the same work.
:func:`write_frame` writes a fitted frame atomically (arrays and mesh first,
then the record that marks it done) and :func:`read_done_frames` reads back
the frames an interrupted run finished.

:func:`rescue_poor_frames` is the second look at the frames the quality gate
left out: each is refined again from its nearest accepted neighbours' fits (a
person moves little between kept frames), and fitted again with them as pose
proposals when that is not enough; the best fit is kept. The observed
silhouettes come from the frame's own arrays, so nothing is segmented twice.
"""

from __future__ import annotations

import bisect
import functools
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bodymetry.calibration.camera import CameraGroup
from bodymetry.errors import InputError
from bodymetry.estimation.fit import (
    FitConfig,
    FrameFit,
    fit_frame,
    refit_frame,
    session_gate,
    shared_body_model,
)
from bodymetry.estimation.records import FrameArrays, FrameRecord, SessionGate
from bodymetry.estimation.run_files import RunLayout
from bodymetry.estimation.training import DiscriminativeModels
from bodymetry.fileio import read_json_object, save_npz, write_json_atomic
from bodymetry.log import Progress
from bodymetry.review.meshes import write_mesh

log = logging.getLogger(__name__)

__all__ = [
    "RESCUE_FILE",
    "FitJob",
    "read_done_frames",
    "read_rescue",
    "rescue_poor_frames",
    "run_fit_job",
    "write_frame",
]

#: The record of the frames a rescue has tried (so a resumed run does not try
#: them again), in the run's ``frames/`` folder (a restart removes it with the
#: frames).
RESCUE_FILE = "rescue.json"


@functools.lru_cache(maxsize=2)
def _discriminative(path: Path) -> DiscriminativeModels:
    # Loaded once per worker process (a worker fits many frames).
    return DiscriminativeModels.load(path)


@dataclass(frozen=True)
class FitJob:
    """One kept frame to fit: what a worker needs (no session access).

    Attributes
    ----------
    frame : int
    masks : list of (h_c, w_c) bool
        Observed silhouettes at the working resolution, camera order.
    flags : list of list of str
        Capture's flags per camera (``unreadable`` and ``unreliable`` views are
        left out of the fit).
    cameras : CameraGroup
        The working rig.
    models_path : Path
        The rig's cached discriminative models.
    fit : FitConfig
    landmarks : (33, 3) float or None
        The subject's body landmarks in the world frame, from capture.
    proposals : dict of str to (40 + n_shape,) float, optional
        More poses to search around (the rescue's neighbouring fits; see
        :func:`~bodymetry.estimation.fit.fit_frame`).
    previous : FrameFit, optional
        The frame's fit so far: the job then only refines it and the proposals
        (:func:`~bodymetry.estimation.fit.refit_frame`, the rescue's first try).
    agreement : dict of str to float
        Capture's agreement of each judged view with the frame's other evidence,
        by camera name (the record's ``view_agreement``).
    persons : int or None
        Person-sized bodies capture counted (the record's ``persons``).
    unknown : list of ((h_c, w_c) bool or None)
        Per camera at the working resolution, the person's pixels someone
        nearer covers (neither person nor background to the fit); empty: none.
    clothing : list of ((h_c, w_c) bool or None)
        Per camera at the working resolution, the silhouettes' pixels that are
        not skin (capture's; kept in the frame's arrays); empty: not told.
    contrast : float or None
        Capture's outline contrast (the record's ``outline_contrast``).
    """

    frame: int
    masks: list[np.ndarray]
    flags: list[list[str]]
    cameras: CameraGroup
    models_path: Path
    fit: FitConfig
    landmarks: np.ndarray | None = None
    proposals: dict[str, np.ndarray] | None = None
    previous: FrameFit | None = None
    agreement: dict[str, float] = field(default_factory=dict)
    persons: int | None = None
    unknown: list[np.ndarray | None] = field(default_factory=list)
    clothing: list[np.ndarray | None] = field(default_factory=list)
    contrast: float | None = None


def run_fit_job(job: FitJob) -> FrameFit:
    """Fit one frame (in a worker: the rig's models are loaded once per process)."""
    if job.previous is not None:
        return refit_frame(job.previous, job.cameras, job.fit, job.proposals or {})
    models = _discriminative(job.models_path)
    return fit_frame(
        job.frame,
        job.masks,
        job.flags,
        job.cameras,
        models,
        job.fit,
        job.landmarks,
        job.proposals,
        agreement=job.agreement,
        persons=job.persons,
        unknown=job.unknown,
        clothing=job.clothing,
        contrast=job.contrast,
    )


def run_serially(jobs: Sequence[FitJob]) -> list[FrameFit]:
    """:func:`run_fit_job` of each job in this process, in order."""
    return [run_fit_job(job) for job in jobs]


def write_frame(layout: RunLayout, fit: FrameFit) -> FrameRecord:
    """Write a fitted frame: arrays and mesh first, then the record that marks it done.

    Returns the record as written (rounded as in the file), so that a fresh run
    and a resumed one summarize exactly the same numbers.
    """
    frame = fit.record.frame
    save_npz(layout.frame_arrays(frame), fit.arrays.to_arrays())
    if fit.state is not None:
        body = shared_body_model()
        vertices = body.pose(fit.state).vertices[0]
        write_mesh(layout.frame_mesh(frame), vertices, body.faces(), body.full.arrays.parts)
    record = fit.record.to_json()
    write_json_atomic(layout.frame_record(frame), record)
    return FrameRecord.from_json(record)


def read_done_frames(layout: RunLayout) -> dict[int, FrameRecord]:
    """The frames a previous run of this folder finished: record, arrays and mesh whole.

    A frame whose record is unreadable (a truncated file) or whose arrays or mesh
    are missing is fitted again, with a warning.
    """
    done = {}
    for frame in layout.recorded_frames():
        path = layout.frame_record(frame)
        try:
            record = FrameRecord.read(path)
        except InputError as exc:
            log.warning("%s; fitting the frame again", exc)
            path.unlink()
            continue
        missing = [
            p.name
            for p in (layout.frame_arrays(frame), layout.frame_mesh(frame))
            if not p.is_file() and (p.suffix == ".npz" or record.fitted)
        ]
        if missing:
            log.warning(
                "%s: frame %d lacks %s; fitting it again", layout.folder, frame, ", ".join(missing)
            )
            path.unlink()
            continue
        done[frame] = record
    return done


def _neighbours(frame: int, accepted: list[int], n: int) -> list[int]:
    """The ``n`` accepted frames nearest to ``frame``: the nearest before and after first."""
    before = [f for f in accepted if f < frame][::-1]
    after = [f for f in accepted if f > frame]
    order = [f for pair in zip(before, after, strict=False) for f in pair]
    longer = before if len(before) > len(after) else after
    order += longer[min(len(before), len(after)) :]
    return order[:n]


@dataclass(frozen=True)
class RescueOutcome:
    """What the rescue did to one frame (``rescue.json``).

    Attributes
    ----------
    frame : int
    neighbours : tuple of int
        The accepted frames whose fits were the proposals.
    iou_before, iou_after : float
        Mean silhouette IoU of the first fit and of the rescue's best.
    kept : bool
        Whether the rescue's fit replaced the first (it fits better).
    method : str
        How the rescue's best fit was found: ``"refinement"`` (contour
        refinement from the neighbours' fits and the first fit) or
        ``"annealing"`` (a whole fit with the neighbours' fits as proposals,
        tried when the refinement stays below the gate).
    """

    frame: int
    neighbours: tuple[int, ...]
    iou_before: float
    iou_after: float
    kept: bool
    method: str

    def to_json(self) -> dict:
        return {
            "neighbours": list(self.neighbours),
            "iou_before": round(self.iou_before, 4) if math.isfinite(self.iou_before) else None,
            "iou_after": round(self.iou_after, 4) if math.isfinite(self.iou_after) else None,
            "kept": self.kept,
            "method": self.method,
        }

    @classmethod
    def from_json(cls, frame: int, data: Any, where: str = RESCUE_FILE) -> RescueOutcome:
        try:
            return cls(
                frame,
                tuple(int(n) for n in data["neighbours"]),
                _nan_if_none(data["iou_before"]),
                _nan_if_none(data["iou_after"]),
                bool(data["kept"]),
                str(data["method"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: frame {frame}: malformed rescue entry ({exc})") from exc


def _nan_if_none(v: Any) -> float:
    return math.nan if v is None else float(v)


def read_rescue(layout: RunLayout) -> dict[int, RescueOutcome]:
    """The rescue's log of a run (``frames/rescue.json``): what it tried, per frame.

    A torn or malformed file reads as empty (with a warning): its frames are
    tried again, nothing is lost.
    """
    path = layout.frames_dir / RESCUE_FILE
    if not path.is_file():
        return {}
    try:
        return {
            int(k): RescueOutcome.from_json(int(k), v, str(path))
            for k, v in read_json_object(path).items()
        }
    except (InputError, ValueError) as exc:
        log.warning("%s; the rescue tries its frames again", exc)
        return {}


def write_rescue(layout: RunLayout, tried: dict[int, RescueOutcome]) -> None:
    """Write the rescue's log (atomically; keyed by frame)."""
    write_json_atomic(
        layout.frames_dir / RESCUE_FILE, {str(f): o.to_json() for f, o in sorted(tried.items())}
    )


def rescue_poor_frames(
    layout: RunLayout,
    records: dict[int, FrameRecord],
    cameras: CameraGroup,
    models_path: Path,
    config: FitConfig,
    neighbours: int = 2,
    progress: Progress | None = None,
    run_jobs: Callable[[Sequence[FitJob]], list[FrameFit]] = run_serially,
) -> dict[int, FrameRecord]:
    """Fit the frames the session's quality gate leaves out again, from their neighbours.

    Each fitted frame below the session gate (:func:`session_gate`) is first
    refined again from the generative fits of its ``neighbours`` nearest
    accepted frames and from its own (:func:`refit_frame`: contour refinement
    only, a fraction of a fit's time). A frame still below the gate is then
    fitted again with those fits as pose proposals (half the initial particles
    are drawn around them, and each is a refinement start; see
    :func:`fit_frame`). The frames are fitted in rounds, all of a round at once
    (``run_jobs``, e.g. on the run's worker pool): a frame rescued in one round
    (passing the gate) becomes a neighbour for the next, and a frame still
    below the gate is tried again only when its nearest accepted frames have
    changed. The rescue's best fit replaces the first when its mean silhouette
    IoU is higher; either way the last attempt is recorded in
    ``frames/rescue.json``, so a resumed run does not repeat it.

    Parameters
    ----------
    layout : RunLayout
        The run folder; the frames' observed silhouettes are read from their
        arrays (``frames/FFFFFF.npz``), at the working resolution.
    records : dict of int to FrameRecord
        Every kept frame's record (:func:`read_done_frames` after the first pass).
    cameras : CameraGroup
        The working rig the frames were fitted with.
    models_path : Path
        The rig's discriminative models.
    config : FitConfig
    neighbours : int
        Proposals per frame.
    progress : callable, optional
        ``progress("rescue", done, total)``.
    run_jobs : callable
        Fits a round's jobs and returns their fits in the same order (default:
        one after the other in this process).

    Returns
    -------
    dict of int to FrameRecord
        ``records`` with the rescued frames' new records.
    """
    gate, gated = session_gate([records[f] for f in sorted(records)], config)
    accepted = [r.frame for r in gated if r.ok]
    tried = read_rescue(layout)
    poor = [r.frame for r in gated if r.fitted and not r.ok and r.frame not in tried]
    if not poor or not accepted or neighbours < 1:
        return records
    msg = "%s: %d frame(s) below the quality gate %.2f; fitting them again from their neighbours"
    log.info(msg, layout.folder, len(poor), gate.threshold)
    out = dict(records)
    proposed: dict[int, tuple[int, ...]] = {}
    if progress:
        progress("rescue", 0, len(poor))
    while todo := _this_round(poor, out, accepted, neighbours, gate, proposed):
        best = _best_fits(
            todo,
            lambda frame, near, refine: _rescue_job(
                layout, out, frame, near, cameras, models_path, config, refine
            ),
            run_jobs,
            gate,
        )
        for frame, near in todo:
            proposed[frame] = near
            tried[frame] = _keep_better(layout, out, frame, near, *best[frame], gate, accepted)
            write_rescue(layout, tried)
        if progress:
            progress("rescue", len(proposed), len(poor))
    return out


def _this_round(
    poor: Sequence[int],
    records: dict[int, FrameRecord],
    accepted: list[int],
    neighbours: int,
    gate: SessionGate,
    proposed: dict[int, tuple[int, ...]],
) -> list[tuple[int, tuple[int, ...]]]:
    """A rescue round's frames with their neighbours: every frame still below the gate
    whose nearest accepted frames are not the ones it was last tried from (none
    rescued in a round: no neighbour changes, and the next round is empty)."""
    near_of = {
        frame: tuple(_neighbours(frame, accepted, neighbours))
        for frame in poor
        if records[frame].mean_iou < gate.threshold
    }
    return [(frame, near) for frame, near in near_of.items() if proposed.get(frame) != near]


def _best_fits(
    todo: Sequence[tuple[int, tuple[int, ...]]],
    make_job: Callable[[int, tuple[int, ...], bool], FitJob],
    run_jobs: Callable[[Sequence[FitJob]], list[FrameFit]],
    gate: SessionGate,
) -> dict[int, tuple[str, FrameFit]]:
    """A round's best fit of each frame and how it was found: refinement from the
    neighbours first, a whole fit for what that leaves below the gate."""
    refined = run_jobs([make_job(frame, near, True) for frame, near in todo])
    best = {frame: ("refinement", fit) for (frame, _), fit in zip(todo, refined, strict=True)}
    again = [(frame, near) for frame, near in todo if not _passes(best[frame][1], gate)]
    jobs = [make_job(frame, near, False) for frame, near in again]
    for (frame, _), fit in zip(again, run_jobs(jobs) if jobs else [], strict=True):
        first = best[frame][1].record
        if fit.record.fitted and (not first.fitted or fit.record.mean_iou > first.mean_iou):
            best[frame] = ("annealing", fit)
    return best


def _keep_better(
    layout: RunLayout,
    records: dict[int, FrameRecord],
    frame: int,
    near: tuple[int, ...],
    method: str,
    fit: FrameFit,
    gate: SessionGate,
    accepted: list[int],
) -> RescueOutcome:
    """Write the rescue's fit of ``frame`` over its first when it fits better (updating
    ``records``, and ``accepted`` when it now passes the gate); the outcome, logged."""
    old = records[frame]
    kept = fit.record.fitted and fit.record.mean_iou > old.mean_iou
    if kept:
        records[frame] = write_frame(layout, fit)
        if records[frame].mean_iou >= gate.threshold:  # it proposes in the next round
            bisect.insort(accepted, frame)
    outcome = RescueOutcome(frame, near, old.mean_iou, fit.record.mean_iou, kept, method)
    log.info(
        "%s: frame %d: IoU %.3f -> %.3f by %s from frames %s (%s)",
        layout.folder,
        frame,
        outcome.iou_before,
        outcome.iou_after,
        method,
        ", ".join(map(str, near)),
        "kept" if kept else "first fit kept",
    )
    return outcome


def _passes(fit: FrameFit, gate: SessionGate) -> bool:
    """Whether a fit passes the session's gate."""
    return fit.record.fitted and fit.record.mean_iou >= gate.threshold


def _rescue_job(
    layout: RunLayout,
    records: dict[int, FrameRecord],
    frame: int,
    near: tuple[int, ...],
    cameras: CameraGroup,
    models_path: Path,
    config: FitConfig,
    refine: bool,
) -> FitJob:
    """The rescue's job for one frame: its recorded silhouettes and its neighbours' fits;
    with ``refine``, only a refinement of its current fit and theirs.

    Raises
    ------
    InputError
        When the frame's arrays lack a camera's silhouette.
    """
    arrays = FrameArrays.load(layout.frame_arrays(frame))
    try:
        masks = [arrays.observed[n] for n in cameras.names]
    except KeyError as exc:
        raise InputError(
            f"{layout.frame_arrays(frame)}: no observed silhouette of camera {exc}"
        ) from exc
    old = records[frame]
    return FitJob(
        frame,
        masks,
        [list(old.flags.get(n, ())) for n in cameras.names],
        cameras,
        models_path,
        config,
        arrays.landmarks,
        {f"frame {n}": records[n].estimate().vector() for n in near},
        FrameFit(old, arrays) if refine else None,
        # A whole fit again writes a new record: it keeps capture's verdicts.
        dict(old.view_agreement),
        old.persons,
        arrays.unknown_of(cameras.names) if arrays.unknown else [],
        arrays.clothing_of(cameras.names) if arrays.clothing else [],
        old.outline_contrast,
    )
