"""Silhouette scoring against ground truth (``bodymetry.studio.evaluate``) on toy sessions."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from bodymetry.capture.segmentation import background_models, segment_session
from bodymetry.capture.session import load_session
from bodymetry.capture.toy import write_toy_session
from bodymetry.errors import InputError
from bodymetry.studio.evaluate import (
    SILHOUETTES_JSON,
    SilhouetteScores,
    iou,
    load_ground_truth,
    outline_errors,
    outline_length,
    segment_and_score,
)


@pytest.fixture(scope="module")
def toy(tmp_path_factory) -> Path:
    """2 cameras, 40 frames, every 10th kept, nobody in view at frame 20."""
    folder = tmp_path_factory.mktemp("toy") / "s"
    write_toy_session(folder, cameras=2, frames=40, frame_step=10, empty_frames=(20,), seed=1)
    return folder


def test_iou() -> None:
    a = np.zeros((4, 4), bool)
    b = np.zeros((4, 4), bool)
    assert iou(a, b) == 1.0  # both empty
    a[:2] = True
    b[1:3] = True
    assert iou(a, b) == pytest.approx(4 / 12)
    assert iou(a, a) == 1.0


def test_scores_match_the_toy_ground_truth(toy: Path) -> None:
    session = load_session(toy)
    scores = SilhouetteScores(load_ground_truth(session))
    for sf in segment_session(session):
        scores.update(sf)
    summary = scores.summary()
    for cam in ("cam_00", "cam_01"):
        assert summary[cam]["frames"] == 4
        assert summary[cam]["iou_min"] > 0.85  # MJPG at 160x120 smears the edges
        assert summary[cam]["shadow_false_positive"] is None  # toy sessions have no states


def test_scores_with_the_session_median_background(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    write_toy_session(folder, cameras=2, frames=60, frame_step=5, backgrounds=False, seed=4)
    session = load_session(folder)
    models = background_models(session)
    assert [m.source for m in models] == ["session", "session"]
    scores = SilhouetteScores(load_ground_truth(session))
    for sf in segment_session(session, models=models):
        scores.update(sf)
    for entry in scores.summary().values():
        assert entry["iou_mean"] > 0.8


def test_no_ground_truth_without_silhouettes(toy: Path, tmp_path: Path) -> None:
    folder = tmp_path / "s"
    shutil.copytree(toy, folder)
    shutil.rmtree(folder / "ground_truth" / "silhouettes")
    assert load_ground_truth(load_session(folder)) is None


def test_scores_refuse_ground_truth_of_another_size(toy: Path) -> None:
    session = load_session(toy)
    scores = SilhouetteScores(load_ground_truth(session))
    sf = next(segment_session(session, frames=[10]))
    small = type(sf)(
        frame=sf.frame,
        cameras=sf.cameras,
        masks=tuple(m[:-2] for m in sf.masks),
        flags=sf.flags,
    )
    with pytest.raises(InputError, match=r"cam_00.*frame 10"):
        scores.update(small)


def test_segment_and_score(toy: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    calls: list[tuple[str, int, int]] = []
    run = segment_and_score(
        load_session(toy), out, overlays=False, progress=lambda *a: calls.append(a)
    )
    assert calls[0] == ("background models", 0, 4) and calls[-1] == ("silhouettes", 4, 4)
    assert run.frames == 4 and run.frame_step == 10 and run.ground_truth
    assert run.method == "horprasert" and run.session == str(toy) and run.out == str(out)
    assert set(run.background.values()) == {"clip"}
    for entry in run.cameras.values():
        assert entry["frames"] == 4 and entry["iou_min"] > 0.85
        assert entry["flags"] == {"empty": [20]}
    assert [p["frame"] for p in run.per_frame] == [0, 10, 20, 30]
    assert run.per_frame[2]["flags"] == {"cam_00": ["empty"], "cam_01": ["empty"]}
    data = run.to_dict()
    assert "per_frame" not in data
    json.dumps(data)  # JSON-ready
    saved = json.loads((out / SILHOUETTES_JSON).read_text())
    assert saved == {**data, "per_frame": run.per_frame}
    assert (out / "masks" / "cam_01" / "000030.png").is_file()
    assert not (out / "overlays").exists()


def test_outline_length_counts_pixel_sides() -> None:
    m = np.zeros((8, 8), bool)
    assert outline_length(m) == 0
    m[2:5, 3:7] = True  # 3 x 4 pixels
    assert outline_length(m) == 2 * (3 + 4)
    full = np.ones((3, 5), bool)  # the image border counts as outside
    assert outline_length(full) == 2 * (3 + 5)


def test_outline_errors_known_answers() -> None:
    truth = np.zeros((40, 40), bool)
    truth[10:30, 10:30] = True  # outline 80 pixel sides
    grown = truth.copy()
    grown[30, 10:30] = True  # one row added along one side
    error, bias = outline_errors(grown, truth)
    assert error == pytest.approx(20 / 80) and bias == pytest.approx(20 / 80)
    shrunk = truth.copy()
    shrunk[10, 10:30] = False
    error, bias = outline_errors(shrunk, truth)
    assert error == pytest.approx(20 / 80) and bias == pytest.approx(-20 / 80)
    assert outline_errors(truth, truth) == (0.0, 0.0)
    assert all(np.isnan(outline_errors(truth, np.zeros_like(truth))))


def test_outline_error_does_not_depend_on_the_body_as_iou_does() -> None:
    """A one-pixel dilation of a thin and of a thick bar: IoU differs by far, the
    outline error in pixels hardly (the corners add 4 pixels to either)."""
    figures = []
    for width in (6, 30):
        truth = np.zeros((120, 80), bool)
        truth[10:110, 20 : 20 + width] = True
        grown = np.zeros_like(truth)
        grown[9:111, 19 : 21 + width] = True
        figures.append((iou(grown, truth), *outline_errors(grown, truth)))
    (iou_thin, err_thin, bias_thin), (iou_thick, err_thick, bias_thick) = figures
    assert iou_thick - iou_thin > 0.15
    assert err_thin == pytest.approx(1.0, abs=0.02) and err_thick == pytest.approx(1.0, abs=0.02)
    assert bias_thin == err_thin and bias_thick == err_thick
