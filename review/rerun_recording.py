"""``RUN/recording.rrd``: the run as a Rerun recording (layout in docs/review.md).

Entity paths (world z up, metres; every per-frame value on the ``frame``
timeline, a sequence of session frame numbers, and on ``time``, seconds from
the start of the recording):

``/world``
    view coordinates (right-handed, z up), static.
``/world/rig/cam_NN``
    Transform3D (camera to world) and Pinhole, static;
    ``image`` (JPEG), ``observed`` (the observed silhouette) and ``model``
    (the fitted model's silhouette) per frame, as segmentation images over the
    image (class 1: observed, light blue; class 2: model, dark red; the colours
    of the paper's Figure 4).
``/world/body/mesh``
    the fitted body: triangles and colours once (static), vertex positions per frame.
``/world/session/mesh``
    the session stage's body (the session's one shape in the frame's refined
    pose; its level of detail), translucent green, per frame that has it.
``/world/body/skeleton``, ``/world/body/keypoints``
    bones and keypoints per frame.
``/world/body/particles``
    the root positions τ of the last annealing layer's particles (the cloud's
    spread), coloured by weight.
``/world/landmarks``
    the subject's body landmarks that capture triangulated from the person
    segmenter's detections (what the landmark pose proposals aimed at), per frame.
``/metrics/biometrics/<name>/{discriminative,generative,session,actual}``
    every measurement per stage (the session's one value on every frame it
    used), and the ground truth when known.
``/metrics/likelihood/layer_NN``
    log-likelihood of the estimate after each annealing layer.
``/metrics/silhouette_iou/cam_NN``, ``/metrics/particle_std/tau_{x,y,z}_mm``
    fit quality and the particle cloud's spread.
``/metrics/views/cam_NN/agreement``
    capture's agreement of the view's silhouette with the frame's other
    evidence (the record's ``view_agreement``), per judged view and frame; a
    view flagged ``unreliable`` was left out of that frame's fit.
``/metrics/views/outline_contrast``
    capture's outline contrast of the frame (the record's ``outline_contrast``:
    how plainly the person stood out from the empty scene; below 1.4, low
    contrast), in the same tab.

A run of several persons (``results.json`` with more than one person) keeps
the camera images, ``/metrics/persons`` and the rig once and puts each person's
entities under their id K: ``/world/person/K/{body,session,landmarks}/...``
(the paths above, below ``/world/person/K``), ``/world/rig/cam_NN/person/K/
{observed,model}`` (their silhouettes stay under the camera: a 2D view shows
only what lies under its pinhole; their model class is ``2 + index`` in the
person's colour, :mod:`bodymetry.review.person_colors`) and
``/metrics/person/K/...`` (the series above, below ``/metrics/person/K``). A
run of one person keeps the paths without ``person/K``.

The blueprint opens with the 3D view beside the camera grid and the plots below
(each plot with every person's series in a run of several).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from bodymetry.calibration.camera import Camera
from bodymetry.estimation.body_model.biometrics import MEASUREMENTS
from bodymetry.estimation.body_model.model import TAU, BodyModel
from bodymetry.estimation.records import STAGES, FrameRecord
from bodymetry.review.meshes import PART_COLORS
from bodymetry.review.person_colors import person_rgb
from bodymetry.review.run_data import FrameView, RunData, skeleton_segments

log = logging.getLogger(__name__)

#: Segmentation classes and colours (paper Figure 4: light blue observed, dark red model).
OBSERVED_CLASS, MODEL_CLASS = 1, 2
OBSERVED_RGB = (120, 190, 255)
MODEL_RGB = (170, 20, 30)
#: The observed silhouette's pixels that are not skin (clothing, hair, shoes): a
#: class far above the persons' model classes (2 + a person's index).
CLOTHING_CLASS, CLOTHING_RGB = 200, (150, 60, 200)
#: Series colours per stage.
STAGE_RGB = {
    "discriminative": (70, 130, 230),
    "generative": (220, 80, 40),
    "session": (40, 160, 90),
    "actual": (90, 200, 90),
}
#: The session body's colour (RGBA: translucent over the generative body).
SESSION_RGBA = (40, 160, 90, 110)
#: Biometrics shown in their own plot below the views (the others are in tabs).
MAIN_PLOTS = ("height_mm", "arm_span_mm", "weight_kg")
#: JPEG quality of the camera images.
JPEG_QUALITY = 80


def camera_to_world(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) taking camera coordinates to the world.

    Raises
    ------
    ValueError
        If the rotation is not proper (det != +1): the viewer would reject it.
    """
    rot = cam.R.T
    det = float(np.linalg.det(rot))
    if not np.isclose(det, 1.0, atol=1e-6):
        raise ValueError(f"camera {cam.name!r}: rotation has det {det:.6f}, expected +1")
    return rot, cam.center


def jpeg(image_bgr: np.ndarray, quality: int = JPEG_QUALITY) -> bytes:
    """JPEG bytes of a BGR image (H, W, 3) uint8."""
    ok, buf = cv2.imencode(".jpg", image_bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - OpenCV failure
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def vertex_colors(body: BodyModel) -> np.ndarray:
    """(V, 3) uint8 per-vertex colours of the full mesh from its per-face part colours."""
    faces = body.faces()
    rgb = PART_COLORS[np.asarray(body.full.arrays.parts)]
    out = np.zeros((body.full.n_vertices, 3), np.uint8)
    # Later faces overwrite earlier ones; every vertex gets one of its faces' colours.
    for k in range(3):
        out[faces[:, k]] = rgb
    return out


def metrics_root(person: int | None) -> str:
    """Where a person's series lie: ``/metrics`` for a run of one person (None),
    ``/metrics/person/K`` for person K of a run of several."""
    return "/metrics" if person is None else f"/metrics/person/{person}"


def world_root(person: int | None) -> str:
    """Where a person's bodies lie: ``/world`` for a run of one person (None),
    ``/world/person/K`` for person K of a run of several."""
    return "/world" if person is None else f"/world/person/{person}"


def _series_view(sub: str, name: str, persons: list[int] | None) -> Any:
    """A time series view of ``/metrics/<sub>`` (one person), or of every person's
    ``/metrics/person/K/<sub>`` in one plot (``persons``: a run of several)."""
    if persons is None:
        return rrb.TimeSeriesView(origin=f"/metrics/{sub}", name=name)
    return rrb.TimeSeriesView(
        origin="/metrics/person",
        contents=[f"{metrics_root(k)}/{sub}/**" for k in persons],
        name=name,
    )


def blueprint(
    camera_names: list[str],
    biometrics: list[str],
    eye: tuple[np.ndarray, np.ndarray] | None = None,
    agreement: bool = False,
    persons: bool = False,
    person_ids: list[int] | None = None,
) -> Any:
    """3D view beside the camera grid, the time series below.

    Parameters
    ----------
    camera_names : list of str
    biometrics : list of str
        Measurement keys with series under ``/metrics/biometrics``.
    eye : ((3,) float, (3,) float), optional
        Initial 3D eye position and look target (world, metres).
    agreement : bool
        Whether the run recorded capture's view agreement or outline contrast (a
        tab of its ``/metrics/views`` series).
    persons : bool
        Whether capture saw more than one person in some frame (a tab of the
        ``/metrics/persons`` series: people in the capture volume per frame).
    person_ids : list of int, optional
        The persons of a run of several: each plot shows every person's series
        (``/metrics/person/K/...``); None for a run of one person.
    """
    cams = [rrb.Spatial2DView(origin=f"/world/rig/{name}", name=name) for name in camera_names]
    plots = [
        _series_view(f"biometrics/{key}", key, person_ids)
        for key in MAIN_PLOTS
        if key in biometrics
    ]
    views = [_series_view("views", "view agreement and outline contrast", person_ids)]
    people = [rrb.TimeSeriesView(origin="/metrics/persons", name="people in view")]
    more = [
        *(people if persons else []),
        _series_view("likelihood", "log-likelihood per layer", person_ids),
        _series_view("silhouette_iou", "silhouette IoU", person_ids),
        *(views if agreement else []),
        _series_view("particle_std", "particle spread (mm)", person_ids),
        *(
            _series_view(f"biometrics/{key}", key, person_ids)
            for key in biometrics
            if key not in MAIN_PLOTS
        ),
    ]
    eye_controls = None
    if eye is not None:
        eye_controls = rrb.EyeControls3D(
            position=eye[0].tolist(), look_target=eye[1].tolist(), eye_up=[0.0, 0.0, 1.0]
        )
    top = rrb.Horizontal(
        rrb.Spatial3DView(origin="/world", name="3D", eye_controls=eye_controls),
        rrb.Grid(*cams, name="cameras") if cams else rrb.TextDocumentView(origin="/notes"),
        column_shares=[1, 1],
    )
    bottom = rrb.Horizontal(*plots, rrb.Tabs(*more), column_shares=[1] * len(plots) + [1.5])
    return rrb.Blueprint(
        rrb.Vertical(top, bottom, row_shares=[3, 2]),
        rrb.TimePanel(state="expanded", timeline="frame"),
        collapse_panels=True,
    )


class RerunWriter:
    """Writes a run's recording to ``path``, one frame at a time.

    Uses its own :class:`rerun.RecordingStream`, never the global one. The
    caller makes the write atomic (:func:`bodymetry.fileio.atomic_path`). In a
    run of several persons each person's entities lie under ``/world/person/K``,
    ``/world/rig/cam_NN/person/K`` and ``/metrics/person/K`` (docs/review.md);
    a run of one person keeps the paths without ``person/K``.

    Parameters
    ----------
    path : path
        The file to write (a temporary name is fine: Rerun ignores the suffix).
    run : RunData
    body : BodyModel
    """

    def __init__(self, path: str | Path, run: RunData, body: BodyModel) -> None:
        self.path = Path(path)
        self.run = run
        self._persons = run.person_runs()
        self._several = run.several
        self._rec = rr.RecordingStream("bodymetry", recording_id=f"bodymetry-{run.name}")
        names = [] if run.cameras is None else list(run.cameras.names)
        fitted = [r for p in self._persons for r in p.fitted_frames]
        present = fitted[0].estimates["generative"].biometrics if fitted else {}
        self.biometrics = [k for k in MEASUREMENTS if k in present]
        eye = None
        if run.cameras:
            # Between the first two cameras, a little farther out and higher than
            # they are, looking at the middle of the rig at hip height.
            centres = run.cameras.centers
            target = np.r_[centres[:, :2].mean(axis=0), 0.9]
            side = centres[:2, :2].mean(axis=0) - target[:2]
            if np.linalg.norm(side) < 1e-6:
                side = centres[0, :2] - target[:2] + [1e-3, 0.0]
            radius = np.linalg.norm(centres[:, :2] - target[:2], axis=1).mean()
            horizontal = side / np.linalg.norm(side) * radius * 1.1
            eye = (target + np.r_[horizontal, centres[:, 2].mean() + 0.6], target)
        records = [r for p in self._persons for r in p.frames]
        agreement = any(r.view_agreement or r.outline_contrast is not None for r in records)
        crowded = any((r.persons or 0) > 1 for r in records)
        self._rec.save(
            self.path,
            default_blueprint=blueprint(
                names,
                self.biometrics,
                eye,
                agreement,
                crowded,
                list(run.person_ids) if self._several else None,
            ),
        )
        self._frames = 0
        self._last_frame: int | None = None
        self._truth: dict[int, dict[str, float]] = {}
        self._log_static(body)

    def _key(self, person: int) -> int | None:
        """The person part of the entity paths: None (no ``person/K``) in a run of one."""
        return person if self._several else None

    def _model_class(self, person: int) -> int:
        """The segmentation class of a person's model silhouette (person 0: MODEL_CLASS)."""
        return MODEL_CLASS + (self.run.person_ids.index(person) if self._several else 0)

    # -- static content --------------------------------------------------------------
    def _log_static(self, body: BodyModel) -> None:
        rec = self._rec
        rec.log("/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        models = (
            [
                (self._model_class(k), f"model silhouette, person {k}", person_rgb(k))
                for k in self.run.person_ids
            ]
            if self._several
            else [(MODEL_CLASS, "model silhouette", MODEL_RGB)]
        )
        rec.log(
            "/world/rig",
            rr.AnnotationContext(
                [
                    # Class 0 must be transparent, else the viewer colours it.
                    (0, "background", (0, 0, 0, 0)),
                    (OBSERVED_CLASS, "observed silhouette", OBSERVED_RGB),
                    *models,
                    (CLOTHING_CLASS, "clothing or hair (not skin)", CLOTHING_RGB),
                ]
            ),
            static=True,
        )
        for cam in self.run.cameras or ():
            rot, centre = camera_to_world(cam)
            base = f"/world/rig/{cam.name}"
            rec.log(base, rr.Transform3D(translation=centre, mat3x3=rot), static=True)
            rec.log(
                base,
                rr.Pinhole(
                    image_from_camera=cam.K,
                    resolution=list(cam.size),
                    camera_xyz=rr.ViewCoordinates.RDF,
                    image_plane_distance=0.5,
                ),
                static=True,
            )
        colors = vertex_colors(body)
        for person in self._persons:
            key = self._key(person.person_id)
            world, metrics = world_root(key), metrics_root(key)
            rec.log(
                f"{world}/body/mesh",
                rr.Mesh3D.from_fields(
                    triangle_indices=body.faces().astype(np.uint32), vertex_colors=colors
                ),
                static=True,
            )
            shape = person.results.session_shape
            if shape is not None and shape.ok:
                rec.log(
                    f"{world}/session/mesh",
                    rr.Mesh3D.from_fields(
                        triangle_indices=body.faces(lod=True).astype(np.uint32),
                        albedo_factor=SESSION_RGBA,
                    ),
                    static=True,
                )
            who = "" if key is None else f"person {key} "
            for name in self.biometrics:
                for stage in (*STAGES, "actual"):
                    rec.log(
                        f"{metrics}/biometrics/{name}/{stage}",
                        rr.SeriesLines(colors=[STAGE_RGB[stage]], names=[f"{who}{stage}"]),
                        static=True,
                    )
            truth = person.ground_truth.measurements if person.ground_truth else {}
            self._truth[person.person_id] = {
                k: float(truth[k]) for k in self.biometrics if k in truth
            }
        summary = "\n\n".join(_summary_text(p, self._several) for p in self._persons)
        rec.log("/notes", rr.TextDocument(summary, media_type="text/markdown"), static=True)

    # -- per frame ---------------------------------------------------------------------
    def add(self, view: FrameView) -> None:
        """Log one person's view of a frame (the camera images once per frame)."""
        rec = self._rec
        frame = view.frame
        rec.set_time("frame", sequence=frame)
        rec.set_time("time", duration=self.run.time_seconds(frame))
        first = frame != self._last_frame
        if first:
            self._frames += 1
            self._last_frame = frame
        key = self._key(view.person)
        world = world_root(key)
        for c, cam in enumerate(self.run.cameras):
            base = f"/world/rig/{cam.name}"
            mine = base if key is None else f"{base}/person/{key}"
            if first and c < len(view.images) and view.images[c] is not None:
                rec.log(
                    f"{base}/image",
                    rr.EncodedImage(contents=jpeg(view.images[c]), media_type="image/jpeg"),
                )
            if c < len(view.observed) and view.observed[c] is not None:
                rec.log(
                    f"{mine}/observed",
                    rr.SegmentationImage(
                        view.observed[c].astype(np.uint8) * OBSERVED_CLASS, opacity=0.45
                    ),
                )
            if c < len(view.clothing) and view.clothing[c] is not None:
                rec.log(
                    f"{mine}/clothing",
                    rr.SegmentationImage(
                        view.clothing[c].astype(np.uint8) * CLOTHING_CLASS, opacity=0.45
                    ),
                )
            if view.model is not None:
                rec.log(
                    f"{mine}/model",
                    rr.SegmentationImage(
                        view.model[c].astype(np.uint8) * self._model_class(view.person),
                        opacity=0.45,
                    ),
                )
        if view.vertices is not None:
            rec.log(f"{world}/body/mesh", rr.Mesh3D.from_fields(vertex_positions=view.vertices))
        if view.session_vertices is not None:
            rec.log(
                f"{world}/session/mesh",
                rr.Mesh3D.from_fields(vertex_positions=view.session_vertices),
            )
        if view.keypoints is not None:
            rec.log(
                f"{world}/body/skeleton",
                rr.LineStrips3D(
                    skeleton_segments(view.keypoints),
                    radii=0.012,
                    colors=[person_rgb(view.person) if key is not None else (30, 30, 30)],
                ),
            )
            rec.log(
                f"{world}/body/keypoints",
                rr.Points3D(view.keypoints, radii=0.02, colors=[(250, 200, 0)]),
            )
        if view.landmarks is not None:
            seen = np.all(np.isfinite(view.landmarks), axis=1)
            rec.log(
                f"{world}/landmarks",
                rr.Points3D(view.landmarks[seen], radii=0.015, colors=[(0, 200, 255)]),
            )
        if view.particles is not None and view.weights is not None:
            w = view.weights / max(float(view.weights.max()), 1e-12)
            colors = np.stack([255 * w, 80 + 0 * w, 255 * (1 - w)], axis=1).astype(np.uint8)
            rec.log(
                f"{world}/body/particles",
                rr.Points3D(view.particles[:, TAU], radii=0.008, colors=colors),
            )
        if first and view.record.persons is not None:
            # Capture's count of people in view is the frame's, not a person's.
            rec.log("/metrics/persons", rr.Scalars(float(view.record.persons)))
        self._log_metrics(view.record, view.person)

    def _log_metrics(self, record: FrameRecord, person: int = 0) -> None:
        rec = self._rec
        root = metrics_root(self._key(person))
        # Capture's verdict on each view stands whether or not the frame was fitted.
        for name, value in record.view_agreement.items():
            if np.isfinite(value):
                rec.log(f"{root}/views/{name}/agreement", rr.Scalars(float(value)))
        if record.outline_contrast is not None:
            rec.log(f"{root}/views/outline_contrast", rr.Scalars(float(record.outline_contrast)))
        if record.estimate() is None:  # no fit: nothing else to plot
            return
        truth = self._truth.get(person, {})
        for key in self.biometrics:
            for stage in STAGES:
                est = record.estimates.get(stage)
                value = est.biometrics.get(key) if est is not None else None
                # NaN stands for a value the record does not have: no point.
                if value is not None and np.isfinite(value):
                    rec.log(f"{root}/biometrics/{key}/{stage}", rr.Scalars(float(value)))
            if key in truth:
                rec.log(f"{root}/biometrics/{key}/actual", rr.Scalars(truth[key]))
        for name, iou in record.silhouette_iou.items():
            if np.isfinite(iou):
                rec.log(f"{root}/silhouette_iou/{name}", rr.Scalars(float(iou)))
        if record.annealing is None:
            return
        for i, value in enumerate(record.annealing.layer_log_likelihood):
            rec.log(f"{root}/likelihood/layer_{i:02d}", rr.Scalars(float(value)))
        for axis, value in zip("xyz", record.annealing.tau_std_m, strict=False):
            rec.log(f"{root}/particle_std/tau_{axis}_mm", rr.Scalars(1000.0 * float(value)))

    @property
    def frames(self) -> int:
        """Frames logged so far."""
        return self._frames

    def close(self) -> None:
        """Flush the recording and close the file (footer included)."""
        self._rec.flush()
        self._rec.disconnect()


def _summary_text(run: RunData, several: bool = False) -> str:
    """The notes of one person's view of the run (with a "Person K" heading when
    the run has several)."""
    lines = [f"# {run.name}" + (f": person {run.person_id}" if several else ""), ""]
    ok = len(run.ok_frames)
    lines.append(
        f"{ok} of {len(run.frames)} kept frames fitted; cameras: {run.calibration_source}."
    )
    shape = run.results.session_shape
    if shape is not None:
        lines += ["", "## Session shape", ""]
        if shape.ok:
            lines.append(
                f"One shape from {len(shape.frames)} frames (mean silhouette IoU "
                f"{shape.mean_iou:.3f}; per-frame fits {shape.reference_iou:.3f}):"
            )
            lines.append("")
            for key in ("height_mm", "arm_span_mm", "weight_kg"):
                if key in shape.biometrics:
                    lines.append(
                        f"- {key}: {shape.biometrics[key]:.1f} ± "
                        f"{shape.standard_errors.get(key, float('nan')):.1f} (s.e.)"
                    )
        else:
            lines.append(shape.status)
    return "\n".join(lines)
