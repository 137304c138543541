"""report.html (self-contained), measurements.csv, report.pdf, and graceful degradation."""

from __future__ import annotations

import base64
import csv
import json
import re
import shutil

import cv2
import numpy as np
import pytest

from bodymetry.errors import InputError
from bodymetry.review.build import build_review
from bodymetry.review.report import build_report, csv_columns, select_overlay_frames
from bodymetry.review.run_data import load_run

IMG_SRC = re.compile(r'<img[^>]*\bsrc="([^"]*)"')


def _decode_images(html: str) -> list[np.ndarray]:
    images = []
    for src in IMG_SRC.findall(html):
        assert src.startswith(("data:image/png;base64,", "data:image/jpeg;base64,")), src[:40]
        data = base64.b64decode(src.split(",", 1)[1])
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        assert image is not None and image.size > 0
        images.append(image)
    return images


def test_process_wrote_every_review_output(review_run):
    for name in ("recording.rrd", "recording.mcap", "report.html", "measurements.csv"):
        assert (review_run.folder / name).is_file(), name
    assert (review_run.folder / "report.pdf").is_file()  # the fixture asked for --pdf
    review = [c for c in review_run.progress if c[0] == "review"]
    assert review[-1] == ("review", 3, 3)
    # No temporary files left behind.
    assert not list(review_run.folder.glob(".*.tmp"))


def test_report_is_self_contained_with_every_section(review_run):
    html = (review_run.folder / "report.html").read_text()
    for section in ("summary", "session", "measurements", "plots", "overlays", "body"):
        assert f'id="{section}"' in html
    assert "calibration" in html and "Figure 3" in html
    assert not re.search(r'(src|href)="(https?:|file:|//)', html)
    images = _decode_images(html)
    n_cams = len(review_run.results["session"]["cameras"])
    n_overlays = len(select_overlay_frames(load_run(review_run.folder)))
    # plots (measurements, fit quality, body) + one overlay tile per camera per frame
    assert len(images) == 3 + n_overlays * n_cams
    truth = review_run.results["ground_truth"]
    assert f"{truth['height_mm']:,.1f}".replace(",", " ") in html


def test_measurements_csv_has_one_row_per_kept_frame(review_run):
    run = load_run(review_run.folder)
    with open(review_run.folder / "measurements.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == csv_columns(run)
    assert [int(r["frame"]) for r in rows] == [f["frame"] for f in review_run.results["frames"]]
    for row, record in zip(rows, review_run.results["frames"], strict=True):
        assert row["status"] == record["status"]
        assert float(row["generative_height_mm"]) == pytest.approx(
            record["generative"]["height_mm"], rel=1e-5
        )
        for cam, iou in record["silhouette_iou"].items():
            assert float(row[f"iou_{cam}"]) == pytest.approx(iou)


def test_pdf_has_the_report_pages(review_run):
    data = (review_run.folder / "report.pdf").read_bytes()
    assert data.startswith(b"%PDF")
    pages = len(re.findall(rb"/Type\s*/Page(?!s)", data))
    # summary, per-frame plots, fit quality, overlays, body and calibration
    assert pages == 5
    assert b"bodymetry report" in data  # the document title (metadata)


@pytest.fixture
def old_run(review_run, tmp_path):
    """A copy of the run with results.json only (like runs made before the review stage)."""
    folder = tmp_path / "old"
    folder.mkdir()
    shutil.copy(review_run.folder / "results.json", folder / "results.json")
    return folder


def test_figure_3_gets_the_gt_generative_column_from_evaluation_json(review_run, old_run):
    table = {
        key: {
            "actual": review_run.results["ground_truth"][key],
            "discriminative": {"mean": 1.0, "std": 0.1, "n": 3},
            "disc_generative": {"mean": 2.0, "std": 0.2, "n": 3},
            "gt_generative": {"mean": 4321.5, "std": 12.25, "n": 3},
        }
        for key in ("height_mm", "arm_span_mm", "weight_kg")
    }
    (old_run / "evaluation.json").write_text(json.dumps({"table": table}))
    files = build_report(old_run)
    html = files.html.read_text()
    assert "GT + Generative" in html and "4 321.5" in html
    assert files.pdf is None and files.csv.is_file()


def test_review_of_an_old_run_without_particles_or_session(review_run, old_run, caplog):
    results = json.loads((old_run / "results.json").read_text())
    results["session"]["path"] = str(old_run / "gone")
    (old_run / "results.json").write_text(json.dumps(results))
    summary = build_review(old_run)
    assert not summary.errors, summary.errors
    assert set(summary.files) == {"rrd", "mcap", "html", "csv"}
    html = (old_run / "report.html").read_text()
    assert "videos, which were not found" in html
    assert "not found" in caplog.text


def test_report_needs_results_json(tmp_path):
    with pytest.raises(InputError, match=r"results\.json: not found"):
        build_report(tmp_path)
    (tmp_path / "results.json").write_text("{not json")
    with pytest.raises(InputError, match="not a readable JSON"):
        load_run(tmp_path)
