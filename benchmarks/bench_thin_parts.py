"""The hands' outline: what each capture source keeps of a thin part.

``python -m benchmarks thin_parts`` renders (or reuses, with
``BODYMETRY_BENCH_THIN_DIR``) the three independent-geometry subjects whose
session arm span read short on 2026-12-05 (seeds 43 and 91 raising their arms,
seed 42 reaching; the renders of ``python -m benchmarks pipeline
--independent`` and ``--fresh``), segments their first :data:`FRAMES` kept
frames as ``bodymetry process`` does, and scores per source, against the true
silhouette:

- the **hand zone**: the true silhouette's pixels beyond the true wrist, within
  :data:`HAND_REACH` of the projected forearm's length of it (the hand and the
  wrist, from the true joints, so it works on bodies our model did not build);
- **recall** of the hand zone's pixels and of the rest of the body;
- the outline's **net offset** in each (added less missed pixels per pixel of
  the true outline there, + outwards, in pixels), the figure the contour fit
  feels: on the studio's 640x480 renders a pixel is about 5 mm at the subject.

Sources: background subtraction's label, the segmenter's mask (p > 0.5), the
fused mask (:func:`bodymetry.capture.fusion.fuse`), the fused mask with the
changes the hull confirms given back (:func:`~bodymetry.capture.fusion.confirmed_change`,
strong changes and thin parts), and the final silhouette (after the clean-up
and the edge refinement, :func:`bodymetry.capture.masks.clean_mask`).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.bench_pipeline import _render
from bodymetry.calibration.io import load_calibration
from bodymetry.capture.fusion import confirmed_change, fuse
from bodymetry.capture.ingest import check_sync, read_frame_sets
from bodymetry.capture.masks import thin_parts
from bodymetry.capture.segmentation import CaptureConfig, FrameSegmenter, background_models
from bodymetry.capture.session import load_session
from bodymetry.estimation.body_model.skeleton import JOINTS
from bodymetry.estimation.contours import boundary_points
from bodymetry.studio.evaluate import GroundTruth

#: (seed, motion, --subject) of the sessions scored.
SESSIONS = (
    (43, "arm_raises", "independent:43"),
    (91, "arm_raises", "independent:91"),
    (42, "reach", "independent:42"),
)
#: Kept frames scored per session.
FRAMES = 6
#: The hand zone's radius, as a fraction of the projected forearm (elbow to wrist).
HAND_REACH = 0.8
#: (elbow, wrist) joint indices of each arm.
ARMS = tuple((JOINTS.index(f"elbow_{s}"), JOINTS.index(f"wrist_{s}")) for s in "lr")
SOURCES = ("subtraction", "segmenter", "fused", "fused + confirmed", "final")


def hand_zone(camera, joints: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the image region of both hands (beyond each wrist, within
    :data:`HAND_REACH` of the projected forearm of it), from the true ``joints``
    (J, 3) world positions."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w]
    zone = np.zeros(shape, bool)
    for elbow, wrist in ARMS:
        pe, pw = camera.project(joints[[elbow, wrist]])
        forearm = pw - pe
        rel = np.stack([xx - pw[0], yy - pw[1]], axis=-1)
        near = np.linalg.norm(rel, axis=-1) < HAND_REACH * np.linalg.norm(forearm)
        zone |= near & ((rel @ forearm) > 0)
    return zone


class _Tally:
    """Running sums per source and region."""

    def __init__(self) -> None:
        self.sums: dict[tuple[str, str], np.ndarray] = {}

    def add(self, source: str, region: str, *values: float) -> None:
        key = (source, region)
        self.sums[key] = self.sums.get(key, np.zeros(len(values))) + np.array(values, float)

    def table(self) -> dict[str, dict[str, dict[str, float]]]:
        out: dict[str, dict[str, dict[str, float]]] = {}
        for (source, region), (kept, true, added, outline) in self.sums.items():
            out.setdefault(source, {})[region] = {
                "recall": round(kept / max(true, 1.0), 4),
                "net_offset_px": round((added - (true - kept)) / max(outline, 1.0), 3),
            }
        return out


def score_session(folder: Path, frames: int = FRAMES) -> dict:
    """Per source, the hand zone's and the rest's recall and outline offset over the
    first ``frames`` kept frames of the session in ``folder``."""
    session = load_session(folder)
    report = check_sync(session)
    cameras = load_calibration(folder / "calibration.yaml")
    truth = GroundTruth(session)
    states = truth.person_states(0)
    segmenter = FrameSegmenter(
        background_models(session, report),
        [v.size for v in report.videos],
        CaptureConfig(),
        None,
        None,
        cameras,
    )
    tally = _Tally()
    try:
        for n, fs in enumerate(read_frame_sets(session, report)):
            if n >= frames:
                break
            joints = states["joints"][int(np.nonzero(states["frame"] == fs.frame)[0][0])]
            final = segmenter(fs.images).views
            evidence = [segmenter.evidence(c, im) for c, im in enumerate(fs.images)]
            terms = segmenter.geometry(evidence)
            for c, camera in enumerate(cameras.cameras):
                true = truth.person(camera.name, fs.frame)
                ev = evidence[c]
                features, key = segmenter.features(c, ev, terms[c])
                fused = fuse(features, segmenter.config.fusion.weights_for(key)) > 0
                confirmed = confirmed_change(
                    fused, ev.raw, ev.change, terms[c].hull_any, thin_parts(fused)
                )
                found = np.zeros_like(true) if ev.person is None else ev.person.probability > 0.5
                masks = (ev.raw, found, fused, confirmed, final[c].mask)
                zone = hand_zone(camera, joints, true.shape)
                outline = boundary_points(true).astype(int)
                on_hand = zone[outline[:, 1], outline[:, 0]]
                for source, mask in zip(SOURCES, masks, strict=True):
                    for region, where, edge in (
                        ("hands", zone, on_hand.sum()),
                        ("rest", ~zone, (~on_hand).sum()),
                    ):
                        kept = (mask & true & where).sum()
                        added = (mask & ~true & where).sum()
                        tally.add(source, region, kept, (true & where).sum(), added, edge)
    finally:
        segmenter.close()
    return tally.table()


def run(**_: bool) -> dict:
    base = os.environ.get("BODYMETRY_BENCH_THIN_DIR")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(base) if base else Path(tmp)
        scores = {}
        for seed, motion, subject in SESSIONS:
            folder = root / f"seed{seed}_{motion}"
            if not (folder / "session.yaml").is_file():
                _render(folder, seed, motion, {}, subject)
            scores[f"seed {seed}, {motion}"] = score_session(folder)
    return {
        "sessions": f"{', '.join(str(s[0]) for s in SESSIONS)} (independent geometry, "
        f"tight clothing, demo rig, 640x480), first {FRAMES} kept frames, 4 cameras",
        "hand_reach": HAND_REACH,
        "scores": scores,
    }
