"""Persons in capture (issue 29, items 1-2 of the capture): split, masks, occlusion, tracks.

Renders two-person studio sessions (``bodymetry synth OUT --people 2 --seed S
--rig-seed 5``, seeds :data:`SEEDS`, 200 frames, a kept frame every 25: 8 per
session; the other person walks past the subject and crosses it in some
cameras), segments them as ``bodymetry process`` does (the default capture with
the true calibration) and scores the persons of :attr:`SilhouetteFrame.sightings`
(identities by :func:`bodymetry.capture.persons.track_ids` over the kept frames,
as ``process --person N`` gives them) against each person's truth (``ground_truth/persons/<k>/``):

- per frame, observed persons are matched to true persons by the Hungarian
  assignment on their mask IoU summed over the cameras; a true person with no
  observation scores IoU 0 in that frame;
- **mask IoU** per (frame, camera, person) of the pixels the person explains
  against their true visible pixels (views where the person shows at least
  :data:`MIN_VISIBLE` pixels), also over the frames where the person was
  observed (``mask_iou_observed``) and over the views where another person
  hides under :data:`CLEAR_SHARE` of them (``mask_iou_unoccluded``);
- **identity swaps**: per true person, the times their track id changes
  between consecutive kept frames (target 0), and the ids used;
- **occlusion**: of the true occluded pixels (a person's projection another
  hides), the share marked ``occluded`` for that person (recall), the share
  wrongly given to that person's mask, and of the pixels marked occluded the
  share truly occluded (precision).

Sessions are rendered once into ``BODYMETRY_BENCH_PERSONS_DIR`` (default a
temporary folder; about 2 minutes each on 2 cores).
"""

from __future__ import annotations

import itertools
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from bodymetry.calibration.io import load_calibration
from bodymetry.capture.persons import track_ids
from bodymetry.capture.segmentation import segment_session
from bodymetry.capture.session import load_session
from bodymetry.studio.evaluate import GroundTruth
from bodymetry.studio.looks import Look
from bodymetry.studio.synth import SynthConfig, synthesize

SEEDS = (7, 8, 9)
#: A view is "unoccluded" for a person when another person hides under this share of them.
CLEAR_SHARE = 0.1
RIG_SEED = 5
#: Frames each session records (a kept frame every 25: 8 kept).
FRAMES = 200
#: A view scores a person's mask where the person shows at least this many true pixels.
MIN_VISIBLE = 200


def session(folder: Path, seed: int, frames: int = FRAMES, look: str | None = None) -> Path:
    """Render (once) the two-person session of ``seed`` (``frames`` long, a kept frame
    every 25) into ``folder/tracks_people2_seed<seed>`` (``..._<frames>f`` when not
    :data:`FRAMES`, ``..._<look>`` for a ``look`` (``synth --look``: the subject's
    clothing, the room and the light); not ``people2_seed<seed>``: ``python -m
    benchmarks persons`` renders other subjects and motions under that name, and a
    shared folder must not hand one the other's)."""
    name = f"tracks_people2_seed{seed}" + ("" if frames == FRAMES else f"_{frames}f")
    if look:
        name += "_" + look.replace("=", "-").replace(",", "_")
    out = folder / name
    if not (out / "session.yaml").is_file():
        synthesize(
            out,
            SynthConfig(
                frames=frames,
                frame_step=25,
                seed=seed,
                rig_seed=RIG_SEED,
                people=2,
                look=Look.parse(look),
            ),
            workers=1,
            overwrite=True,
        )
    return out


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.count_nonzero(a | b)
    return float(np.count_nonzero(a & b) / union) if union else 1.0


def score_session(folder: Path) -> dict:
    """The persons of one session's kept frames against each person's truth."""
    s = load_session(folder)
    gt = GroundTruth(s)
    n_true = gt.persons()
    cameras = load_calibration(folder / "calibration.yaml")
    ious: list[float] = []
    clear: list[float] = []  # views where another person hides under 10 % of the person
    observed: list[float] = []  # views of frames where the person was observed
    occ = {"true": 0, "marked": 0, "marked_true": 0, "explained_true": 0}
    matched: list[list[int | None]] = [[] for _ in range(n_true)]
    frame_people: list = []
    counted, frames = [], 0
    t0 = time.perf_counter()
    for sf in segment_session(s, cameras=cameras, keep_images=False):
        frames += 1
        counted.append(sf.persons)
        truth = [
            [gt.person(c, sf.frame, k) for c in sf.cameras] for k in range(n_true)
        ]  # fmt: skip
        hidden = [[gt.occluded(c, sf.frame, k) for c in sf.cameras] for k in range(n_true)]
        people = sf.sightings
        frame_people.append(people)

        def mask(seen, c: int, shape=tuple(t.shape for t in truth[0])) -> np.ndarray:
            m = seen.masks[c]
            return np.zeros(shape[c], bool) if m is None else m

        # Observations to true persons: the pixels they share over the cameras.
        score = np.zeros((n_true, len(people)))
        for k in range(n_true):
            for j, seen in enumerate(people):
                inter = sum(np.count_nonzero(mask(seen, c) & t) for c, t in enumerate(truth[k]))
                union = sum(np.count_nonzero(mask(seen, c) | t) for c, t in enumerate(truth[k]))
                score[k, j] = inter / max(union, 1)
        match = dict(zip(*linear_sum_assignment(-score), strict=True)) if people else {}
        for k in range(n_true):
            j = match.get(k)
            seen = None if j is None else people[j]
            matched[k].append(j)
            for c in range(len(sf.cameras)):
                t = truth[k][c]
                if np.count_nonzero(t) >= MIN_VISIBLE:
                    ious.append(0.0 if seen is None else _iou(mask(seen, c), t))
                    if seen is not None:
                        observed.append(ious[-1])
                    hid = np.count_nonzero(hidden[k][c])
                    if hid < CLEAR_SHARE * (hid + np.count_nonzero(t)):
                        clear.append(ious[-1])
                occ["true"] += int(np.count_nonzero(hidden[k][c]))
                if seen is None:
                    continue
                marked = seen.hidden[c] if seen.hidden and seen.hidden[c] is not None else None
                if marked is not None:
                    occ["marked"] += int(np.count_nonzero(marked))
                    occ["marked_true"] += int(np.count_nonzero(marked & hidden[k][c]))
                occ["explained_true"] += int(np.count_nonzero(mask(seen, c) & hidden[k][c]))
    # Identities over the whole session, as the run gives them.
    tracked = track_ids(frame_people)
    ids = [
        [None if j is None else tracked[f][j] for f, j in enumerate(matched[k])]
        for k in range(n_true)
    ]
    seconds = time.perf_counter() - t0
    swaps = [
        sum(1 for a, b in itertools.pairwise(seq) if a is not None and b is not None and a != b)
        for seq in ids
    ]
    iou = np.array(ious)
    return {
        "kept_frames": frames,
        "persons_counted": counted,
        "frames_with_persons": sum(
            1 for k in range(frames) if all(ids[p][k] is not None for p in range(n_true))
        ),
        "track_ids_per_person": ids,
        "identity_swaps": int(sum(swaps)),
        "mask_iou": {
            "views": len(iou),
            "mean": round(float(iou.mean()), 4) if len(iou) else None,
            "median": round(float(np.median(iou)), 4) if len(iou) else None,
            "min": round(float(iou.min()), 4) if len(iou) else None,
        },
        "mask_iou_observed": {
            "views": len(observed),
            "mean": round(float(np.mean(observed)), 4) if observed else None,
            "median": round(float(np.median(observed)), 4) if observed else None,
        },
        "mask_iou_unoccluded": {
            "views": len(clear),
            "mean": round(float(np.mean(clear)), 4) if clear else None,
            "min": round(float(np.min(clear)), 4) if clear else None,
        },
        "occluded_pixels": occ["true"],
        "occluded_marked_recall": round(occ["marked_true"] / max(occ["true"], 1), 4),
        "occluded_marked_precision": round(occ["marked_true"] / max(occ["marked"], 1), 4),
        "occluded_given_to_mask": round(occ["explained_true"] / max(occ["true"], 1), 4),
        "capture_seconds": round(seconds, 1),
    }


def run(**_: bool) -> dict:
    base = os.environ.get("BODYMETRY_BENCH_PERSONS_DIR")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(base) if base else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        sessions = {f"seed{seed}": score_session(session(folder, seed)) for seed in SEEDS}
    iou = [s["mask_iou"]["mean"] for s in sessions.values() if s["mask_iou"]["mean"] is not None]
    true = sum(s["occluded_pixels"] for s in sessions.values())
    return {
        "sessions": sessions,
        "summary": {
            "identity_swaps": sum(s["identity_swaps"] for s in sessions.values()),
            "mask_iou_mean_of_sessions": round(float(np.mean(iou)), 4) if iou else None,
            "mask_iou_unoccluded_mean_of_sessions": round(
                float(
                    np.mean(
                        [
                            s["mask_iou_unoccluded"]["mean"]
                            for s in sessions.values()
                            if s["mask_iou_unoccluded"]["mean"] is not None
                        ]
                    )
                ),
                4,
            ),
            "mask_iou_worst_view": min(
                (
                    s["mask_iou"]["min"]
                    for s in sessions.values()
                    if s["mask_iou"]["min"] is not None
                ),
                default=None,
            ),
            "occluded_marked_recall": round(
                sum(s["occluded_marked_recall"] * s["occluded_pixels"] for s in sessions.values())
                / max(true, 1),
                4,
            ),
        },
        "command": "python -m benchmarks person_tracks",
    }
