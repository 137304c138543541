"""``RUN/recording.mcap``: the run as MCAP with Foxglove schemas (docs/review.md).

Written with ``foxglove-sdk`` (protobuf encoding, the schemas
``foxglove.CompressedImage`` and so on), readable by Foxglove and by the Rerun
viewer (which converts images, calibrations and transforms). Message log times
are the session time of each frame (frame / fps, from 0).

Topics (one message per kept frame unless said otherwise; cameras ``cam_NN``):

``/cameras/cam_NN/image``        ``foxglove.CompressedImage``  the camera image (JPEG)
``/cameras/cam_NN/overlay``      ``foxglove.CompressedImage``  image with observed silhouette
                                 (light blue), model silhouette (dark red), overlap (orange)
``/cameras/cam_NN/calibration``  ``foxglove.CameraCalibration``  K, distortion, projection
``/tf``                          ``foxglove.FrameTransforms``  ``world`` -> ``cam_NN``
``/body``                        ``foxglove.SceneUpdate``  the fitted body (triangle lists
                                 per colour) and its skeleton, in ``world`` (fitted frames);
                                 entity ``session``: the session stage's body
                                 (level of detail, translucent green), on the
                                 frames it used
``/particles``                   ``foxglove.PointCloud``  particle root positions τ and
                                 weights (fitted frames with particles)
``/measurements``                JSON  the frame's record from ``results.json``
                                 (without the body states)

A run of several persons has one topic set per person K, ``/person/K/body``,
``/person/K/particles``, ``/person/K/measurements`` and
``/person/K/cameras/cam_NN/overlay`` (the overlay in the person's colour), and
the cameras' ``image``, ``calibration`` and ``/tf`` once per frame; a run of one
person keeps the topics above.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import cv2
import foxglove
import numpy as np
from foxglove import channels as ch
from foxglove import messages as m
from scipy.spatial.transform import Rotation

from bodymetry.estimation.body_model.model import TAU, BodyModel
from bodymetry.estimation.records import STAGES, FrameRecord
from bodymetry.review.meshes import PART_COLORS
from bodymetry.review.person_colors import person_overlap_rgb, person_rgb
from bodymetry.review.rerun_recording import camera_to_world, jpeg
from bodymetry.review.run_data import FrameView, RunData, skeleton_segments

log = logging.getLogger(__name__)

#: JSON schema of the ``/measurements`` channel.
MEASUREMENTS_SCHEMA = {
    "type": "object",
    "title": "bodymetry.FrameMeasurements",
    "properties": {
        "frame": {"type": "integer"},
        "status": {"type": "string"},
        "discriminative": {"type": "object"},
        "generative": {"type": "object"},
        "session": {"type": "object"},
        "silhouette_iou": {"type": "object"},
        "view_agreement": {"type": "object"},
        "persons": {"type": "integer"},
        "outline_contrast": {"type": "number"},
        "annealing": {"type": "object"},
    },
}


def overlay_silhouettes(
    image: np.ndarray | None,
    observed: np.ndarray | None,
    model: np.ndarray | None,
    person: int = 0,
) -> np.ndarray:
    """The paper's Figure 4 overlay: observed only light blue, model only dark red,
    both orange, blended over the camera image; another person's model and overlap
    in that person's colours (:mod:`bodymetry.review.person_colors`).

    Parameters
    ----------
    image : (H, W, 3) uint8 BGR or None (grey background)
    observed, model : (H, W) bool or None
    person : int
        Whose silhouettes these are (their colours; 0: the paper's).

    Returns
    -------
    (H, W, 3) uint8 BGR
    """
    shape = next(a.shape[:2] for a in (image, observed, model) if a is not None)
    out = np.full((*shape, 3), 90, np.uint8) if image is None else image.copy()
    obs = np.zeros(shape, bool) if observed is None else observed
    mod = np.zeros(shape, bool) if model is None else model
    for mask, bgr in (
        (obs & ~mod, (255, 190, 120)),  # light blue
        (mod & ~obs, person_rgb(person)[::-1]),  # person 0: dark red
        (obs & mod, person_overlap_rgb(person)[::-1]),  # person 0: orange
    ):
        if mask.any():
            out[mask] = (0.35 * out[mask] + 0.65 * np.array(bgr)).astype(np.uint8)
    if obs.any():
        contours, _ = cv2.findContours(obs.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(out, contours, -1, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def person_prefix(person: int | None) -> str:
    """The topic prefix of a person's channels: ``""`` for a run of one person (None),
    ``/person/K`` for person K of a run of several."""
    return "" if person is None else f"/person/{person}"


class _PersonTopics:
    """One person's channels: ``<prefix>/cameras/cam_NN/overlay``, ``<prefix>/body``,
    ``<prefix>/particles``, ``<prefix>/measurements`` (prefix: :func:`person_prefix`)."""

    def __init__(self, prefix: str, cameras: Any, context: foxglove.Context) -> None:
        self.overlay = {
            n: ch.CompressedImageChannel(f"{prefix}/cameras/{n}/overlay", context=context)
            for n in cameras
        }
        self.body = ch.SceneUpdateChannel(f"{prefix}/body", context=context)
        self.particles = ch.PointCloudChannel(f"{prefix}/particles", context=context)
        self.measurements = foxglove.Channel(
            f"{prefix}/measurements", schema=MEASUREMENTS_SCHEMA, context=context
        )


def _timestamp(seconds: float) -> m.Timestamp:
    ns = round(seconds * 1e9)
    return m.Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def _quaternion(rot: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix (3, 3)."""
    x, y, z, w = Rotation.from_matrix(rot).as_quat()
    return float(x), float(y), float(z), float(w)


class McapWriter:
    """Writes a run as MCAP to ``path``, one frame at a time (the caller makes it atomic).

    Uses its own :class:`foxglove.Context`, never the global one.

    Parameters
    ----------
    path : path
        The file to write (replaced if it exists).
    run : RunData
    body : BodyModel
    """

    def __init__(self, path: str | Path, run: RunData, body: BodyModel) -> None:
        self.path = Path(path)
        self.run = run
        self._ctx = foxglove.Context()
        self._writer = foxglove.open_mcap(self.path, allow_overwrite=True, context=self._ctx)
        names = () if run.cameras is None else run.cameras.names
        topic = "/cameras/{}/{}".format
        self._image = {
            n: ch.CompressedImageChannel(topic(n, "image"), context=self._ctx) for n in names
        }
        self._calib = {
            n: ch.CameraCalibrationChannel(topic(n, "calibration"), context=self._ctx)
            for n in names
        }
        self._tf = ch.FrameTransformsChannel("/tf", context=self._ctx)
        self._topics = {
            ident: _PersonTopics(person_prefix(ident if run.several else None), names, self._ctx)
            for ident in run.person_ids
        }
        self._frames = 0
        self._last_frame: int | None = None
        faces = body.faces()
        parts = np.asarray(body.full.arrays.parts)
        rgb = PART_COLORS[parts]
        # One triangle list per colour: solid colours need no per-vertex colour data.
        # The session body: its level of detail, one colour.
        self._session_indices = body.faces(lod=True).reshape(-1).astype(int).tolist()
        self._groups = []
        for colour in np.unique(rgb, axis=0):
            tri = faces[np.all(rgb == colour, axis=1)]
            used, local = np.unique(tri, return_inverse=True)
            self._groups.append((used, local.reshape(-1).astype(int).tolist(), colour / 255.0))

    @property
    def frames(self) -> int:
        """Frames written so far."""
        return self._frames

    def add(self, view: FrameView) -> None:
        """Write one person's view of a frame (the cameras' images, calibrations and
        transforms once per frame, on its first view)."""
        seconds = self.run.time_seconds(view.frame)
        log_time = round(seconds * 1e9)
        stamp = _timestamp(seconds)
        first = view.frame != self._last_frame
        if first:
            self._frames += 1
            self._last_frame = view.frame
            self._log_cameras(view, stamp, log_time)
        topics = self._topics[view.person]
        for c, cam in enumerate(self.run.cameras or ()):
            image = view.images[c] if c < len(view.images) else None
            observed = view.observed[c] if c < len(view.observed) else None
            model = view.model[c] if view.model is not None else None
            if image is not None or observed is not None or model is not None:
                topics.overlay[cam.name].log(
                    m.CompressedImage(
                        timestamp=stamp,
                        frame_id=cam.name,
                        data=jpeg(overlay_silhouettes(image, observed, model, view.person)),
                        format="jpeg",
                    ),
                    log_time=log_time,
                )
        if view.vertices is not None:
            topics.body.log(self._scene(view, stamp), log_time=log_time)
        if view.particles is not None and view.weights is not None:
            topics.particles.log(_point_cloud(view, stamp), log_time=log_time)
        topics.measurements.log(json.dumps(_measurement_message(view.record)), log_time=log_time)

    def _log_cameras(self, view: FrameView, stamp: m.Timestamp, log_time: int) -> None:
        """The frame's camera images, calibrations and the ``/tf`` transforms."""
        transforms = []
        for c, cam in enumerate(self.run.cameras or ()):
            rot, centre = camera_to_world(cam)
            x, y, z, w = _quaternion(rot)
            transforms.append(
                m.FrameTransform(
                    timestamp=stamp,
                    parent_frame_id="world",
                    child_frame_id=cam.name,
                    translation=m.Vector3(x=centre[0], y=centre[1], z=centre[2]),
                    rotation=m.Quaternion(x=x, y=y, z=z, w=w),
                )
            )
            K = cam.K
            P = np.hstack([K, np.zeros((3, 1))])
            dist = list(map(float, cam.dist))
            self._calib[cam.name].log(
                m.CameraCalibration(
                    timestamp=stamp,
                    frame_id=cam.name,
                    width=cam.size[0],
                    height=cam.size[1],
                    distortion_model="plumb_bob" if len(dist) <= 5 else "rational_polynomial",
                    D=(dist + [0.0] * 5)[:5] if len(dist) <= 5 else dist[:8],
                    K=K.reshape(-1).tolist(),
                    R=np.eye(3).reshape(-1).tolist(),
                    P=P.reshape(-1).tolist(),
                ),
                log_time=log_time,
            )
            image = view.images[c] if c < len(view.images) else None
            if image is not None:
                self._image[cam.name].log(
                    m.CompressedImage(
                        timestamp=stamp, frame_id=cam.name, data=jpeg(image), format="jpeg"
                    ),
                    log_time=log_time,
                )
        if transforms:
            self._tf.log(m.FrameTransforms(transforms=transforms), log_time=log_time)

    def _scene(self, view: FrameView, stamp: m.Timestamp) -> m.SceneUpdate:
        verts = np.asarray(view.vertices, float)
        triangles = []
        for used, indices, colour in self._groups:
            triangles.append(
                m.TriangleListPrimitive(
                    points=[m.Point3(x=p[0], y=p[1], z=p[2]) for p in verts[used].tolist()],
                    color=m.Color(r=colour[0], g=colour[1], b=colour[2], a=1.0),
                    indices=indices,
                )
            )
        entities = [
            m.SceneEntity(timestamp=stamp, frame_id="world", id="body", triangles=triangles)
        ]
        if view.session_vertices is not None:
            session = np.asarray(view.session_vertices, float)
            entities.append(
                m.SceneEntity(
                    timestamp=stamp,
                    frame_id="world",
                    id="session",
                    triangles=[
                        m.TriangleListPrimitive(
                            points=[m.Point3(x=p[0], y=p[1], z=p[2]) for p in session.tolist()],
                            color=m.Color(r=0.16, g=0.63, b=0.35, a=0.45),
                            indices=self._session_indices,
                        )
                    ],
                )
            )
        if view.keypoints is not None:
            segs = skeleton_segments(view.keypoints).reshape(-1, 3).tolist()
            entities.append(
                m.SceneEntity(
                    timestamp=stamp,
                    frame_id="world",
                    id="skeleton",
                    lines=[
                        m.LinePrimitive(
                            type=m.LinePrimitiveLineType.LineList,
                            thickness=0.015,
                            points=[m.Point3(x=p[0], y=p[1], z=p[2]) for p in segs],
                            color=m.Color(r=0.1, g=0.1, b=0.1, a=1.0),
                        )
                    ],
                )
            )
        return m.SceneUpdate(entities=entities)

    def close(self) -> None:
        """Finish the file (summary and index)."""
        self._writer.close()


def _point_cloud(view: FrameView, stamp: m.Timestamp) -> m.PointCloud:
    f32 = m.PackedElementFieldNumericType.Float32
    data = np.hstack(
        [
            np.asarray(view.particles, np.float32)[:, TAU],
            np.asarray(view.weights, np.float32)[:, None],
        ]
    )
    return m.PointCloud(
        timestamp=stamp,
        frame_id="world",
        pose=m.Pose(
            position=m.Vector3(x=0.0, y=0.0, z=0.0),
            orientation=m.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
        ),
        point_stride=16,
        fields=[
            m.PackedElementField(name=name, offset=4 * i, type=f32)
            for i, name in enumerate(("x", "y", "z", "weight"))
        ],
        data=np.ascontiguousarray(data).tobytes(),
    )


def _measurement_message(record: FrameRecord) -> dict[str, Any]:
    """The frame record as ``results.json`` has it, less the body states (kept small)."""
    out = record.to_json()
    for stage in STAGES:
        if stage in out:
            out[stage] = {k: v for k, v in out[stage].items() if k != "state"}
    return out
