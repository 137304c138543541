"""Hidden pixels of each person without an empty-scene clip (issue 29 item 2).

Renders the two-person studio session of ``bodymetry synth OUT --people 2 --seed 7
--rig-seed 5 --no-background-clip --subject independent:72 --motion walk_turn``
(200 frames, a kept frame every 25: 8), segments it as ``bodymetry process`` does
(the default capture with the true calibration) and scores each person's
``Sighting.hidden`` (:func:`bodymetry.capture.people.sightings`) against the
studio's truth (``GroundTruth.occluded``: the pixels of a person's whole
projection another person hides), persons matched to true persons per frame by
the Hungarian assignment on their shared pixels:

- **recall**: of the truly hidden pixels, the share marked hidden;
- **precision**: of the pixels marked hidden, the share truly hidden;

for several reaches of the body region (:data:`REACHES`, fractions of the
skeleton's height; :data:`~bodymetry.capture.people.BODY_REACH` is the one used),
and per view of a person with any hidden pixels the true hidden share, whether the
view was marked and whether it was left out (``occluded``).

The session is rendered once into ``BODYMETRY_BENCH_HIDDEN_DIR`` (default a
temporary folder; about 2 minutes on 2 cores); the segmentation runs once, and
each reach partitions its recorded detections again.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from bodymetry.calibration.io import load_calibration
from bodymetry.capture import people, segmentation
from bodymetry.capture.session import load_session
from bodymetry.studio.evaluate import GroundTruth
from bodymetry.studio.synth import SubjectSpec, SynthConfig, synthesize

SEED = 7
RIG_SEED = 5
REACHES = (0.04, 0.05, 0.06, 0.08, 0.10, 0.12)


def session(folder: Path) -> Path:
    """Render (once) the benchmark's session into ``folder/hidden_people2_seed7``."""
    out = folder / f"hidden_people2_seed{SEED}"
    if not (out / "session.yaml").is_file():
        synthesize(
            out,
            SynthConfig(
                frames=200,
                frame_step=25,
                seed=SEED,
                rig_seed=RIG_SEED,
                motion="walk_turn",
                people=2,
                subject=SubjectSpec.parse("independent:72", SEED),
                background_clip=False,
            ),
            workers=1,
            overwrite=True,
        )
    return out


def recorded_detections(folder: Path) -> list[tuple[int, list[str], tuple, dict]]:
    """Per kept frame: its number, camera names and the arguments capture passed to
    :func:`~bodymetry.capture.people.sightings` (recorded while segmenting)."""
    calls: list[tuple[tuple, dict]] = []
    original = segmentation.sightings

    def recording(*args, **kwargs):
        calls.append((args, kwargs))
        return original(*args, **kwargs)

    segmentation.sightings = recording
    try:
        frames = [
            (sf.frame, list(sf.cameras))
            for sf in segmentation.segment_session(
                load_session(folder),
                cameras=load_calibration(folder / "calibration.yaml"),
                keep_images=False,
            )
        ]
    finally:
        segmentation.sightings = original
    if len(calls) != len(frames):
        raise RuntimeError(f"{len(calls)} partitions recorded for {len(frames)} kept frames")
    return [(f, names, a, k) for (f, names), (a, k) in zip(frames, calls, strict=True)]


def score(folder: Path, recorded: list, reach: float) -> dict:
    """Recall and precision of the hidden pixels with body regions of ``reach``."""
    gt = GroundTruth(load_session(folder))
    n = gt.persons()
    default = people.body_region.__defaults__
    people.body_region.__defaults__ = (reach,)
    true = marked = hit = 0
    views = []
    try:
        for frame, names, args, kwargs in recorded:
            seen = people.sightings(*args, **kwargs)
            truth = [[gt.person(c, frame, i) for c in names] for i in range(n)]
            hidden = [[gt.occluded(c, frame, i) for c in names] for i in range(n)]
            shared = np.array([
                [sum(np.count_nonzero(m & t) for m, t in zip(p.masks, truth[i], strict=True)
                     if m is not None) for p in seen]
                for i in range(n)
            ]).reshape(n, len(seen))  # fmt: skip
            for i, j in zip(*linear_sum_assignment(-shared), strict=True):
                p = seen[j]
                for c in range(len(names)):
                    h = hidden[i][c]
                    m = p.hidden[c] if p.hidden and p.hidden[c] is not None else None
                    true += int(np.count_nonzero(h))
                    if m is not None:
                        marked += int(np.count_nonzero(m))
                        hit += int(np.count_nonzero(m & h))
                    share = np.count_nonzero(h) / max(np.count_nonzero(h | truth[i][c]), 1)
                    if share > 0 or m is not None or p.occluded[c]:
                        views.append({
                            "frame": frame, "person": int(i), "camera": names[c],
                            "true_hidden_share": round(float(share), 3),
                            "marked": m is not None, "occluded": bool(p.occluded[c]),
                        })  # fmt: skip
    finally:
        people.body_region.__defaults__ = default
    return {
        "true_pixels": true,
        "marked_pixels": marked,
        "recall": round(hit / max(true, 1), 4),
        "precision": round(hit / max(marked, 1), 4),
        "views": views,
    }


def run(**_: bool) -> dict:
    base = os.environ.get("BODYMETRY_BENCH_HIDDEN_DIR")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(base) if base else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        out = session(folder)
        recorded = recorded_detections(out)
        scores = {f"{r:.2f}": score(out, recorded, r) for r in REACHES}
    used = scores[f"{people.BODY_REACH:.2f}"]
    return {
        "session": f"synth --people 2 --seed {SEED} --rig-seed {RIG_SEED} --no-background-clip "
        "--subject independent:72 --motion walk_turn",
        "body_reach": people.BODY_REACH,
        "by_reach": {r: {k: v for k, v in s.items() if k != "views"} for r, s in scores.items()},
        "views": used["views"],
    }
