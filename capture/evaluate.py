"""Silhouette quality against a studio session's ground truth.

- ``iou``: intersection over union of the computed and the true person mask
  (``ground_truth/silhouettes/<camera>/<frame:06d>.png``);
- ``shadow_false_positive``: the fraction of true cast-shadow pixels labelled
  person. The studio does not store shadow masks, so they are recomputed: the
  session's state (``ground_truth/states.npz``) is posed and rendered again
  through the true cameras with the studio's key light, without noise (the
  shadow geometry does not depend on the noise).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import cv2
import numpy as np

from bodymetry.capture.session import GROUND_TRUTH_STATES, Session
from bodymetry.errors import InputError

__all__ = ["GroundTruth", "SilhouetteScores", "iou", "load_ground_truth"]


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two (H, W) bool masks (1.0 when both are empty)."""
    union = np.count_nonzero(a | b)
    return float(np.count_nonzero(a & b) / union) if union else 1.0


@dataclass
class GroundTruth:
    """Lazy access to a studio session's true person and shadow masks."""

    session: Session
    with_shadows: bool = True

    def __post_init__(self) -> None:
        self._studio = None
        self._states = None
        self._model = None
        self._cameras = None
        self._shadow_cache: dict[tuple[str, int], np.ndarray | None] = {}

    def has_silhouettes(self) -> bool:
        gt = self.session.ground_truth_path
        return gt is not None and (gt / "silhouettes").is_dir()

    def has_states(self) -> bool:
        gt = self.session.ground_truth_path
        return gt is not None and (gt / GROUND_TRUTH_STATES).is_file()

    def person(self, camera: str, frame: int) -> np.ndarray | None:
        """(H, W) bool true silhouette, or None when the session has none for that frame."""
        if self.session.ground_truth is None:
            return None
        path = self.session.ground_truth_silhouette_path(camera, frame)
        if not path.is_file():
            return None
        mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if mask is None:
            raise InputError(f"{path}: not a readable PNG mask")
        return mask > 0

    def _setup(self) -> None:
        from bodymetry.estimation.body_model.model import BodyModel
        from bodymetry.fileio import load_npz
        from bodymetry.studio.render import Studio
        from bodymetry.studio.scene import Light

        gt = self.session.ground_truth_path
        self._states = load_npz(gt / GROUND_TRUTH_STATES)
        shadows = True
        studio_json = gt / "studio.json"
        if studio_json.is_file():
            shadows = bool(json.loads(studio_json.read_text())["config"].get("shadows", True))
        self._model = BodyModel.load(n_shape=len(self._states["nu"]))
        # The light of capture/studio/synth.py (_render_camera).
        self._studio = Studio.from_model(
            self._model,
            shadows=shadows,
            light=Light(direction=Light.direction_from_angles(azimuth_deg=0.0, elevation_deg=50.0)),
        )
        self._cameras = {cam.name: cam for cam in self.session.calibration()}

    def shadow(self, camera: str, frame: int) -> np.ndarray | None:
        """(H, W) bool true cast-shadow pixels (not person), or None without states."""
        key = (camera, int(frame))
        if key not in self._shadow_cache:
            self._shadow_cache[key] = self._render_shadow(camera, int(frame))
        return self._shadow_cache[key]

    def _render_shadow(self, camera: str, frame: int) -> np.ndarray | None:
        if not self.has_states():
            return None
        if self._studio is None:
            self._setup()
        from bodymetry.estimation.body_model.model import BodyState

        s = self._states
        rows = np.flatnonzero(s["frame"] == frame)
        if rows.size == 0:
            return None
        r = int(rows[0])
        state = BodyState(s["tau"][r], s["theta"][r], s["nu"][None])
        vertices = self._model.pose(state).vertices[0]
        out = self._studio.render_frame(self._cameras[camera], vertices, effects=False)
        return out.shadow_mask & ~out.person_mask


def load_ground_truth(session: Session) -> GroundTruth | None:
    """The session's ground truth, or None when it has no silhouettes."""
    gt = GroundTruth(session)
    return gt if gt.has_silhouettes() else None


class SilhouetteScores:
    """Accumulates IoU and shadow false positives over :class:`SilhouetteFrame` s.

    Parameters
    ----------
    ground_truth : GroundTruth
    shadows : bool
        Also score cast shadows (re-renders each frame; slower).
    """

    def __init__(self, ground_truth: GroundTruth, shadows: bool = True) -> None:
        self.gt = ground_truth
        self.shadows = shadows and ground_truth.has_states()
        self.ious: dict[str, list[float]] = {}
        self.shadow_hits: dict[str, int] = {}
        self.shadow_total: dict[str, int] = {}
        self.shadow_fractions: dict[str, list[float]] = {}

    def update(self, sf) -> None:
        """Score one ``capture.silhouette.SilhouetteFrame``."""
        for name, mask in zip(sf.cameras, sf.masks, strict=True):
            truth = self.gt.person(name, sf.frame)
            if truth is None:
                continue
            if truth.shape != mask.shape:
                raise InputError(
                    f"camera {name!r}: ground-truth silhouette of frame {sf.frame} is "
                    f"{truth.shape[1]}x{truth.shape[0]}, the video {mask.shape[1]}x{mask.shape[0]}"
                )
            self.ious.setdefault(name, []).append(iou(mask, truth))
            if self.shadows:
                shadow = self.gt.shadow(name, sf.frame)
                if shadow is not None:
                    hits = int(np.count_nonzero(mask & shadow))
                    total = int(np.count_nonzero(shadow))
                    self.shadow_hits[name] = self.shadow_hits.get(name, 0) + hits
                    self.shadow_total[name] = self.shadow_total.get(name, 0) + total
                    if total:
                        self.shadow_fractions.setdefault(name, []).append(hits / total)

    def summary(self) -> dict[str, dict]:
        """Per camera: ``iou_mean``, ``iou_min``, ``shadow_false_positive`` (pooled
        over frames: true shadow pixels labelled person / true shadow pixels;
        None when not scored), ``shadow_false_positive_max`` (worst frame), ``frames``."""
        out = {}
        for name, values in self.ious.items():
            total = self.shadow_total.get(name, 0)
            fractions = self.shadow_fractions.get(name, [])
            out[name] = {
                "iou_mean": round(float(np.mean(values)), 4),
                "iou_min": round(float(np.min(values)), 4),
                "shadow_false_positive": (
                    round(self.shadow_hits[name] / total, 4) if total else None
                ),
                "shadow_false_positive_max": round(max(fractions), 4) if fractions else None,
                "frames": len(values),
            }
        return out
