"""Fit the evidence-fusion weights of the capture stage (:mod:`bodymetry.capture.fusion`).

``python -m benchmarks fusion_fit`` renders (or reuses, with
``BODYMETRY_BENCH_CAPTURE_DIR``) the training sessions below, collects per-pixel
evidence around the person in every kept frame and camera, labels it with the
true silhouette, and fits one logistic regression per combination of sources.
It prints the table to paste into ``capture/fusion.py`` (``WEIGHTS``) and writes
it with the fit's figures to ``benchmarks/results/fusion_fit.json``.

The training sessions use their own seeds (201-206): the capture benchmark's
sessions (``bench_capture``) are rendered from other seeds and never seen by
the fit. Pixels within a pixel of the true outline are left out (their label
is a matter of coverage, which the edge refinement decides, not the fusion).

The segmenter-only combinations are not fitted: without a background the
segmenter's own mask at 0.5 is kept (the real footage it was validated on has no
empty-scene clip, and the studio's renders are not a basis to retune it).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import minimize

from benchmarks.bench_capture import studio_session
from bodymetry.calibration.io import load_calibration
from bodymetry.capture.fusion import FEATURES, sources_key
from bodymetry.capture.ingest import check_sync, read_frame_sets
from bodymetry.capture.person import segmenter_available
from bodymetry.capture.segmentation import CaptureConfig, FrameSegmenter, background_models
from bodymetry.capture.session import load_session
from bodymetry.studio.evaluate import GroundTruth

#: (seed, look) of the training sessions: every clothing class, both rooms, both lights.
TRAINING = (
    (201, "clothing=saturated,room=textured,light=hard"),
    (202, "clothing=white,room=plain,light=soft"),
    (203, "clothing=light_grey,room=plain,light=hard"),
    (204, "clothing=black,room=textured,light=soft"),
    (205, "clothing=wall,room=plain,light=hard"),
    (206, "clothing=light_grey,room=textured,light=soft"),
)
#: Every ``STRIDE``-th pixel of the region around the person is sampled.
STRIDE = 3
#: The region: the true silhouette's box grown by this fraction of its height.
MARGIN = 0.25
#: Sample weight of the true cast-shadow pixels (shadow false positives are what the
#: fusion must not trade for recall).
SHADOW_WEIGHT = 4.0
#: L2 penalty on the weights (keeps them finite where two terms say the same).
RIDGE = 1e-3
#: Combinations fitted: (background, segmenter, hull).
COMBINATIONS = ((True, True, True), (True, True, False), (True, False, True), (True, False, False))


def _samples(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel indices (rows, cols) to sample around the true ``mask`` (H, W) bool,
    leaving out the pixels within one of its outline."""
    h, w = mask.shape
    ys, xs = np.nonzero(mask)
    pad = int(MARGIN * (ys.max() - ys.min() + 1))
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, h)
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, w)
    m = mask.astype(np.uint8)
    edge = cv2.dilate(m, np.ones((3, 3), np.uint8)) != cv2.erode(m, np.ones((3, 3), np.uint8))
    rows, cols = np.mgrid[y0:y1:STRIDE, x0:x1:STRIDE]
    keep = ~edge[rows, cols]
    return rows[keep], cols[keep]


def collect(folder: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per sources key, the (N, F) features, (N,) labels and (N,) sample weights of
    one session (true cast-shadow pixels weigh :data:`SHADOW_WEIGHT`)."""
    session = load_session(folder)
    report = check_sync(session)
    models = background_models(session, report)
    cameras = load_calibration(folder / "calibration.yaml")
    truth = GroundTruth(session)
    sizes = [v.size for v in report.videos]
    segmenters = {
        on: FrameSegmenter(models, sizes, CaptureConfig(method=method), None, None, cameras)
        for on, method in ((True, "auto"), (False, "background"))
    }
    out: dict[str, list] = {}
    try:
        for fs in read_frame_sets(session, report):
            true_masks = [truth.person(cam.name, fs.frame) for cam in session.cameras]
            shadows = [truth.shadow(cam.name, fs.frame) for cam in session.cameras]
            for with_segmenter, seg in segmenters.items():
                evidence = [seg.evidence(c, im) for c, im in enumerate(fs.images)]
                terms = seg.geometry(evidence)
                for c, ev in enumerate(evidence):
                    if true_masks[c] is None or not true_masks[c].any():
                        continue
                    rows, cols = _samples(true_masks[c])
                    for hull in (True, False):
                        features, key = seg.features(c, ev, terms[c] if hull else None)
                        if key != sources_key(True, with_segmenter, hull):
                            continue  # the segmenter found nobody in this view
                        x = features[rows, cols]
                        y = true_masks[c][rows, cols]
                        w = np.where(shadows[c][rows, cols], SHADOW_WEIGHT, 1.0)
                        out.setdefault(key, []).append((x, y, w))
    finally:
        for seg in segmenters.values():
            seg.close()
    return {k: tuple(np.concatenate(part) for part in zip(*v, strict=True)) for k, v in out.items()}


def fit_logistic(
    x: np.ndarray, y: np.ndarray, sample_weight: np.ndarray, columns: list[int]
) -> tuple[float, np.ndarray]:
    """Bias and weights (F,) of a weighted logistic regression of ``y`` (N,) bool on
    the ``columns`` of ``x`` (N, F) (the others' weights are 0)."""
    a = np.column_stack([np.ones(len(x)), x[:, columns]]).astype(np.float64)
    t = y.astype(np.float64)
    sw = sample_weight / sample_weight.mean()

    def loss(w: np.ndarray) -> tuple[float, np.ndarray]:
        z = a @ w
        # log(1 + e^z) - t z, stably; its gradient is (sigmoid(z) - t) a.
        value = sw * (np.logaddexp(0.0, z) - t * z)
        p = 0.5 * (1.0 + np.tanh(0.5 * z))
        grad = a.T @ (sw * (p - t)) / len(t) + RIDGE * np.r_[0.0, w[1:]]
        return float(value.mean() + 0.5 * RIDGE * w[1:] @ w[1:]), grad

    res = minimize(loss, np.zeros(a.shape[1]), jac=True, method="L-BFGS-B")
    weights = np.zeros(len(FEATURES))
    weights[columns] = res.x[1:]
    return float(res.x[0]), weights


def run() -> dict:
    if not segmenter_available():
        raise SystemExit("fusion_fit needs the person segmenter (make install)")
    keep = os.environ.get("BODYMETRY_BENCH_CAPTURE_DIR")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(keep) if keep else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        data: dict[str, list] = {}
        for seed, look in TRAINING:
            session = studio_session(folder, seed, look, f"fusion_seed{seed}")
            for key, xy in collect(session).items():
                data.setdefault(key, []).append(xy)
    result: dict = {"sessions": [f"seed {s}: {look}" for s, look in TRAINING], "weights": {}}
    for background, segmenter, hull in COMBINATIONS:
        key = sources_key(background, segmenter, hull)
        x, y, sw = (np.concatenate(part) for part in zip(*data[key], strict=True))
        names = ["change", "shadow"] + (["segmenter"] if segmenter else [])
        names += ["floor_shadow", "hull_body", "hull_any"] if hull else []
        bias, weights = fit_logistic(x, y, sw, [FEATURES.index(n) for n in names])
        z = x @ weights + bias
        result["weights"][key] = {
            "bias": round(bias, 3),
            "weights": dict(zip(FEATURES, np.round(weights, 3).tolist(), strict=True)),
            "pixels": len(y),
            "person_share": round(float(y.mean()), 3),
            "pixel_error": round(float(np.mean((z > 0) != y)), 4),
        }
    result["table"] = "\n".join(
        f'    "{k}": FusionWeights({v["bias"]}, ({", ".join(map(str, v["weights"].values()))})),'
        for k, v in result["weights"].items()
    )
    return result
