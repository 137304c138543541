"""report.html (self-contained), measurements.csv, report.pdf, and graceful degradation."""

from __future__ import annotations

import base64
import csv
import dataclasses
import html as html_text
import json
import re
import shutil
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from bodymetry.errors import InputError
from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.outline_check import OutlineConfig
from bodymetry.estimation.records import FrameRecord, SessionShape
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import EVALUATION_FORMAT, RunLayout, RunResults, SessionInfo
from bodymetry.estimation.studio_accuracy import LOW_CONTRAST, VALIDATED_MM_PER_PX
from bodymetry.estimation.uncertainty import MEASURED_AMONG
from bodymetry.review import plots
from bodymetry.review import report as report_module
from bodymetry.review.accuracy import SESSION_ACCURACY
from bodymetry.review.accuracy import SOURCE as ACCURACY_SOURCE
from bodymetry.review.build import build_review
from bodymetry.review.report import (
    _headline_lines,
    _left_out_lines,
    body_renders,
    breakable,
    build_report,
    csv_columns,
    figure3_rows,
    headline_cards,
    left_out_rows,
    measurement_rows,
    ordinal,
    prior_pull_text,
    select_overlay_frames,
)
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
    n_cams = len(review_run.results.session.cameras)
    n_overlays = len(select_overlay_frames(load_run(review_run.folder)))
    # plots (measurements, fit quality, body) + one overlay tile per camera per frame
    assert len(images) == 3 + n_overlays * n_cams
    truth = review_run.results.ground_truth
    assert f"{truth.get('height_mm'):,.1f}".replace(",", " ") in html
    # What the numbers assume and what a frame needed to count.
    assert "assume tight clothing" in html
    # The report shows the gate as results.json records it (rounded to 4 places: a
    # threshold of 0.8749999... in memory is 0.875 there, and "0.88" in the report).
    gate = load_run(review_run.folder).results.quality_gate.threshold
    assert f"mean IoU of at least {gate:.2f}" in html


def test_measurements_csv_has_one_row_per_kept_frame(review_run):
    run = load_run(review_run.folder)
    with open(review_run.folder / "measurements.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == csv_columns(run)
    records = review_run.results.frames
    assert [int(r["frame"]) for r in rows] == [f.frame for f in records]
    for row, record in zip(rows, records, strict=True):
        assert row["status"] == record.status
        # results.json keeps 3 decimals of a measurement and 4 of an IoU.
        assert float(row["generative_height_mm"]) == pytest.approx(
            record.estimates["generative"].biometrics["height_mm"], rel=1e-5
        )
        for cam, iou in record.silhouette_iou.items():
            assert float(row[f"iou_{cam}"]) == pytest.approx(iou, abs=1e-4)
        ll = record.annealing.layer_log_likelihood[-1]
        assert float(row["final_log_likelihood"]) == pytest.approx(ll, rel=1e-4, abs=1e-3)


def test_pdf_has_the_report_pages(review_run):
    data = (review_run.folder / "report.pdf").read_bytes()
    assert data.startswith(b"%PDF")
    pages = len(re.findall(rb"/Type\s*/Page(?!s)", data))
    # summary, per-frame plots, fit quality, overlays, body and calibration
    assert pages == 5
    assert b"bodymetry report" in data  # the document title (metadata)


@pytest.fixture
def bare_run(review_run, tmp_path):
    """A copy of the run with results.json only (no cameras, no frame records)."""
    folder = tmp_path / "bare"
    folder.mkdir()
    shutil.copy(review_run.folder / "results.json", folder / "results.json")
    return folder


def test_figure_3_gets_the_gt_generative_column_from_evaluation_json(review_run, bare_run):
    table = {
        key: {
            "actual": review_run.results.ground_truth.get(key),
            "discriminative": {"mean": 1.0, "std": 0.1, "n": 3},
            "generative": {"mean": 2.0, "std": 0.2, "n": 3},
            "gt_generative": {"mean": 4321.5, "std": 12.25, "n": 3},
        }
        for key in ("height_mm", "arm_span_mm", "weight_kg")
    }
    evaluation = {
        "format": EVALUATION_FORMAT,
        "run": str(bare_run),
        "session": "bare",
        "frames": 3,
        "frames_failed": 0,
        "table": table,
        "mpjpe_mm": {"discriminative": 90.0, "generative": 40.0, "gt_generative": 20.0},
        "silhouette_iou_mean": 0.9,
    }
    (bare_run / "evaluation.json").write_text(json.dumps(evaluation))
    files = build_report(bare_run)
    html = files.html.read_text()
    assert "GT + Generative" in html and "4 321.5" in html
    assert files.pdf is None and files.csv.is_file()


def test_review_of_a_run_without_frame_arrays_or_session(review_run, tmp_path, caplog):
    # The run's records without its frames/*.npz, and the session moved away:
    # no silhouettes, particles or images, yet every output is written.
    folder = tmp_path / "old"
    shutil.copytree(
        review_run.folder,
        folder,
        ignore=shutil.ignore_patterns("*.npz", "recording.*", "report.*", "measurements.csv"),
    )
    assert list((folder / "frames").glob("*.json")) and not list(folder.glob("frames/*.npz"))
    results = json.loads((folder / "results.json").read_text())
    results["session"]["path"] = str(folder / "gone")
    (folder / "results.json").write_text(json.dumps(results))
    summary = build_review(folder)
    assert not summary.errors, summary.errors
    assert set(summary.files) == {"rrd", "mcap", "html", "csv"}
    html = (folder / "report.html").read_text()
    assert "which were not found" in html
    assert len(_decode_images(html)) == 3  # the plots, no overlay tiles
    assert "session folder" in caplog.text and "not found" in caplog.text


def test_the_recorded_silhouettes_make_overlays_without_the_session(review_run, tmp_path):
    folder = tmp_path / "moved"
    shutil.copytree(
        review_run.folder, folder, ignore=shutil.ignore_patterns("recording.*", "report.*")
    )
    results = json.loads((folder / "results.json").read_text())
    results["session"]["path"] = str(folder / "gone")
    (folder / "results.json").write_text(json.dumps(results))
    run = load_run(folder)
    assert run.session_folder is None
    files = build_report(run)
    n_overlays = len(select_overlay_frames(run))
    n_cams = len(run.cameras)
    assert n_overlays and n_cams
    assert len(_decode_images(files.html.read_text())) == 3 + n_overlays * n_cams


def test_report_needs_results_json(tmp_path):
    with pytest.raises(InputError, match=r"results\.json: not found"):
        build_report(tmp_path)
    (tmp_path / "results.json").write_text("{not json")
    with pytest.raises(InputError, match="not a readable JSON"):
        load_run(tmp_path)


def test_results_of_an_older_version_are_refused_naming_the_file(review_run, tmp_path):
    results = json.loads((review_run.folder / "results.json").read_text())
    del results["format"]  # as written before the typed schema
    path = tmp_path / "results.json"
    path.write_text(json.dumps(results))
    for build in (build_review, build_report):
        with pytest.raises(InputError) as info:
            build(tmp_path)
        message = str(info.value)
        assert message.startswith(str(path)) and "older bodymetry" in message
        assert "\n" not in message


# --- runs where nothing was measured: no numpy warnings (pytest turns them into errors) ----------
def _run_without_measured_frames(review_run, tmp_path, status: str):
    """A copy of the review run's results.json whose every frame failed with ``status``."""
    results = json.loads((review_run.folder / "results.json").read_text())
    fitted = status.startswith("poor fit")
    for frame in results["persons"][0]["frames"]:
        frame["status"] = status
        if not fitted:
            for key in ("estimates", "silhouette_iou", "annealing", "refinement"):
                frame.pop(key, None)
    for stage in results["persons"][0]["summary"].values():
        for stat in stage.values():
            stat.update(mean=None, std=None, n=0)
    (tmp_path / "results.json").write_text(json.dumps(results))
    return tmp_path


@pytest.mark.parametrize(
    "status", ["no silhouette in any camera", "poor fit: mean silhouette IoU 0.41 < 0.90"]
)
def test_review_of_a_run_with_no_measured_frame(review_run, tmp_path, status):
    folder = _run_without_measured_frames(review_run, tmp_path, status)
    summary = build_review(folder, recordings=False, pdf=True)
    assert summary.errors == {}, summary.errors
    html = (folder / "report.html").read_text()
    assert status.split(":")[0] in html
    with open(folder / "measurements.csv", newline="") as fh:
        assert len(list(csv.DictReader(fh))) == len(review_run.results.frames)


def _empty_run():
    """A run-like object with two frames, neither fitted."""
    frames = (FrameRecord(0, "no silhouette in any camera"), FrameRecord(10, "fit failed: x"))
    results = RunResults.of_subject(
        SessionInfo("/s", "s", ("cam_00",), 25.0, 10), ProcessConfig(), frames=frames
    )
    return SimpleNamespace(
        fitted_frames=[],
        ok_frames=[],
        frames=list(frames),
        ground_truth=None,
        camera_names=["cam_00"],
        results=results,
        evaluation=None,
    )


def test_report_parts_of_a_run_without_fitted_frames():
    run = _empty_run()
    assert select_overlay_frames(run) == []
    assert [row["generative"] for row in figure3_rows(run)] == [None, None, None]
    assert measurement_rows(run) == []
    assert body_renders(run, BodyModel.load()) == {}
    plots.measurement_plots(run)
    plots.fit_quality_plots(run)


def test_render_body_of_an_empty_mesh_is_blank():
    image = plots.render_body(
        np.zeros((0, 3)), np.zeros((0, 3), int), np.zeros((0, 3), np.uint8), np.array([1.0, 0, 0])
    )
    assert image.shape == (480, 240, 3) and (image == 255).all()


def test_render_body_refuses_a_zero_view():
    with pytest.raises(ValueError, match="non-zero direction"):
        plots.render_body(
            np.zeros((3, 3)), np.array([[0, 1, 2]]), np.zeros((1, 3), np.uint8), np.zeros(3)
        )


def test_front_direction_of_a_body_without_feet():
    pelvis_only = SimpleNamespace(
        faces=lambda: np.array([[0, 1, 2]]),
        full=SimpleNamespace(arrays=SimpleNamespace(parts=np.array([0]))),
    )
    np.testing.assert_array_equal(plots.front_direction(pelvis_only, np.eye(3)), [0.0, -1.0, 0.0])


def test_body_figure_needs_a_render():
    with pytest.raises(ValueError, match="no render"):
        plots.body_figure({})


def _at_studio_pixels(review_run, tmp_path):
    """A copy of the review run as if seen at the studio's pixels: the tiny run's 240x180
    cameras (about 15 mm at the body) are coarser than every scored session's, so it
    states no interval (the ``coarse_pixels`` caveat); at the studio's it does. Its
    results.json is written again (with the intervals derived from it) and its review
    built again. Returns the folder and its results."""
    folder = tmp_path / "studio_pixels"
    shutil.copytree(review_run.folder, folder)
    results = RunResults.read(folder / "results.json")
    shape = results.session_shape
    outline = dataclasses.replace(shape.outline, mm_per_px=VALIDATED_MM_PER_PX)
    results = results.with_person(session_shape=dataclasses.replace(shape, outline=outline))
    results.write(RunLayout(folder))
    build_review(folder, recordings=False, pdf=False)
    return folder, RunResults.read(folder / "results.json")


def test_the_session_stage_is_beside_the_per_frame_stages(review_run, tmp_path):
    """The session's one shape: its value ± standard error in the Figure 3 table and
    the measurements, a column per measurement in the CSV."""
    folder, results = _at_studio_pixels(review_run, tmp_path)
    shape = results.session_shape
    assert shape is not None and shape.ok, shape
    html = (folder / "report.html").read_text()
    assert "Session (one shape)" in html and "S.e." in html
    height = results.summary["session"]["height_mm"]
    assert f"{height.mean:,.1f}".replace(",", " ") in html
    assert f"{height.std:.1f}" in html
    # Beside each core session value, the accuracy the benchmarks measured on bodies like
    # this one (else on the mid-population subjects), and whence.
    like = results.studio_accuracy
    for key, accuracy in SESSION_ACCURACY.items():
        quoted = like.get(key, accuracy)
        assert f"RMS error {quoted.rms:.1f}" in html, key
        assert f"(studio, {quoted.sessions} {quoted.scope})" in html, key
    assert ACCURACY_SOURCE in html and "bodies like this one" in html
    # Beside it, the 95 % interval combining the two (estimation/uncertainty.py).
    intervals = results.stated_intervals
    assert intervals, "the review run's body is like the studio's: intervals are stated"
    for interval in intervals.values():
        low, high = (f"{v:,.1f}".replace(",", " ") for v in (interval.low, interval.high))
        assert f'95 % interval <span class="nw">{low} – {high}' in html
    assert "Welch–Satterthwaite" in html
    written = json.loads((folder / "results.json").read_text())["persons"][0]
    assert written["intervals"] == {k: i.to_json() for k, i in intervals.items()}
    assert written["intervals_withheld"] == {}  # no loose clothing, no hair
    # At its own pixels the tiny run states none, and says why.
    assert review_run.results.stated_intervals == {}
    assert "coarse_pixels" in [c.code for c in review_run.results.caveats]
    # The PDF's summary page says them in one line.
    lines = _headline_lines({"headline": headline_cards(load_run(folder))})
    (stated,) = [line for line in lines if line.startswith("95 % interval")]
    height = intervals["height_mm"]
    assert f"height {height.low:,.1f} to {height.high:,.1f} mm".replace(",", " ") in stated
    with open(folder / "measurements.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    used = {str(f) for f in shape.frames}
    for row in rows:
        value = row["session_height_mm"]
        if row["frame"] in used:
            assert float(value) == pytest.approx(shape.biometrics["height_mm"], abs=1e-2)
            assert 0 < float(row["session_iou_mean"]) <= 1
        else:
            assert value == ""


def test_the_report_says_how_plainly_the_person_stood_out(review_run, tmp_path):
    """The fit's settings quote the run's outline contrast; seen in low contrast, the
    report says so and quotes the studio's low-contrast sessions."""
    html = (review_run.folder / "report.html").read_text()
    contrast = review_run.results.outline_contrast
    assert contrast is not None and contrast >= LOW_CONTRAST  # the studio's saturated colours
    assert f"outline contrast {contrast:.2f}" in html and "stood out plainly" in html
    folder = tmp_path / "run"
    shutil.copytree(review_run.folder, folder)
    results = json.loads((folder / "results.json").read_text())
    for frame in results["persons"][0]["frames"]:
        frame["outline_contrast"] = 1.1
    (folder / "results.json").write_text(json.dumps(results))
    build_review(folder, recordings=False, pdf=False)
    low = (folder / "report.html").read_text()
    assert "outline contrast 1.10" in low and "seen in low contrast" in low
    stated = RunResults.read(folder / "results.json").studio_accuracy
    assert stated  # the studio's low-contrast sessions, of like bodies or of every body
    for accuracy in stated.values():
        assert f"(studio, {accuracy.sessions} {accuracy.scope})" in low
        assert "low-contrast clothing" in accuracy.scope


def _with_outline(review_run, tmp_path, warnings, offsets=None, mm_per_px=None):
    """A copy of the review run whose outline check warned ``warnings`` (and read the
    ``offsets`` mm and working pixel given): its folder, its results.json as a dict, and
    read back."""
    folder = tmp_path / "run"
    shutil.copytree(review_run.folder, folder)
    results = json.loads((folder / "results.json").read_text())
    outline = results["persons"][0]["session_shape"]["outline"]
    outline["warnings"] = list(warnings)
    outline["offsets_mm"].update(offsets or {})
    # The studio's pixels unless given (the tiny run's are coarser than any scored one's).
    outline["mm_per_px"] = mm_per_px or VALIDATED_MM_PER_PX
    (folder / "results.json").write_text(json.dumps(results))
    return folder, results, RunResults.read(folder / "results.json")


def test_no_interval_where_the_outline_check_finds_loose_clothing_or_hair(review_run, tmp_path):
    """The studio's accuracy is of tight clothing and bare heads: where the outline check
    warns of loose clothing no weight or arm span interval is stated, of hair no height
    interval, and the card says why."""
    warnings = [
        "loose clothing likely: the silhouettes lie 4.8 ± 0.8 mm further outside ...",
        "hair or headwear likely: the silhouettes lie 12.0 ± 0.5 mm further outside ...",
    ]
    folder, results, read = _with_outline(review_run, tmp_path, warnings)
    outline = results["persons"][0]["session_shape"]["outline"]
    assert read.intervals_withheld == {
        "arm_span_mm": "loose clothing",
        "weight_kg": "loose clothing",
        "height_mm": "hair or headwear",
    }
    assert read.stated_intervals == {}
    _, _, clean = _with_outline(review_run, tmp_path / "clean", [])
    assert set(clean.stated_intervals) == {"height_mm", "arm_span_mm", "weight_kg"}
    build_review(folder, recordings=False, pdf=False)
    html = (folder / "report.html").read_text()
    assert "95 % interval <span" not in html
    assert html.count("no 95 % interval: loose clothing (see the caveats)") == 2
    assert html.count("no 95 % interval: hair or headwear (see the caveats)") == 1
    assert "nor where the outline check found loose clothing" in html
    # Hair alone leaves the weight's and the arm span's intervals.
    outline["warnings"] = outline["warnings"][1:]
    (folder / "results.json").write_text(json.dumps(results))
    assert set(RunResults.read(folder / "results.json").stated_intervals) == {
        "arm_span_mm",
        "weight_kg",
    }


def test_legs_hidden_by_a_skirt_withhold_every_interval(review_run, tmp_path):
    """A skirt shapes and poses the fitted legs (the studio's read the height up to 52 mm
    high): "legs hidden" withholds the height's interval too, the card says so, and the
    clothing note reads the bare shins against the bound that decides it."""
    warnings = [
        "loose clothing likely: the silhouettes lie 2.9 ± 1.2 mm further outside ...",
        "legs hidden likely: the bare shins lie 9.0 mm inside the fitted body ...",
    ]
    folder, _, read = _with_outline(review_run, tmp_path, warnings, {"bare shins": -9.0})
    assert read.intervals_withheld == {
        "arm_span_mm": "loose clothing",
        "weight_kg": "loose clothing",
        "height_mm": "legs hidden",
    }
    assert read.stated_intervals == {}
    build_review(folder, recordings=False, pdf=False)
    html = (folder / "report.html").read_text()
    assert html.count("no 95 % interval: legs hidden (see the caveats)") == 1
    assert "the bare shins lie -9.0 mm outside it" in html
    assert f"{OutlineConfig().legs_hidden_mm:.1f} mm or more inside, as when a skirt" in html
    assert "legs hidden by a skirt (all three)" in html


def test_pixels_coarser_than_the_studio_s_withhold_every_interval(review_run, tmp_path):
    """A run whose working pixels at the body are twice the studio's (a 320x240 rig): no
    interval, the card and the caveat say why; an outline finding keeps its own name."""
    folder, _, read = _with_outline(review_run, tmp_path, [], mm_per_px=11.1)
    assert read.intervals_withheld == dict.fromkeys(
        ("height_mm", "arm_span_mm", "weight_kg"), "coarse pixels"
    )
    assert read.stated_intervals == {}
    assert "coarse_pixels" in [c.code for c in read.caveats]
    build_review(folder, recordings=False, pdf=False)
    html = (folder / "report.html").read_text()
    assert html.count("no 95 % interval: coarse pixels (see the caveats)") == 3
    hair = ["hair or headwear likely: the silhouettes lie 12.0 ± 0.5 mm further outside ..."]
    _, _, both = _with_outline(review_run, tmp_path / "b", hair, mm_per_px=11.1)
    assert both.intervals_withheld["height_mm"] == "hair or headwear"
    assert both.intervals_withheld["weight_kg"] == "coarse pixels"


def test_a_person_among_others_is_told_how_their_interval_was_held(review_run, tmp_path):
    """A person measured among others is held to the larger of the single-person and
    the two-person sessions' errors: the interval's footnote says so, with how often
    that held the truth; a person alone is not told."""
    folder = tmp_path / "run"
    shutil.copytree(review_run.folder, folder)
    build_review(folder, recordings=False, pdf=False)
    alone = (folder / "report.html").read_text()
    assert "Measured among others" not in alone
    results = json.loads((folder / "results.json").read_text())
    for frame in results["persons"][0]["frames"]:
        frame["persons"] = 2
    (folder / "results.json").write_text(json.dumps(results))
    read = RunResults.read(folder / "results.json")
    assert read.among_others and not review_run.results.among_others
    build_review(folder, recordings=False, pdf=False)
    html = (folder / "report.html").read_text()
    inside, stated = MEASURED_AMONG["weight_kg"]
    assert "Measured among others, this person is held to the larger" in html
    assert f"{inside} of {stated} weights" in html


def test_a_run_without_the_session_stage_has_no_session_column(review_run, bare_run):
    data = json.loads((bare_run / "results.json").read_text())
    data["persons"][0].pop("session_shape")
    data["persons"][0]["summary"].pop("session")
    for frame in data["persons"][0]["frames"]:
        frame.pop("session", None)
    (bare_run / "results.json").write_text(json.dumps(data))
    html = build_report(bare_run).html.read_text()
    assert "Session (one shape)" not in html and "Disc. + Generative" in html
    # The measured accuracy is that of the session values: none without them.
    assert "measured accuracy" not in html.lower()


def test_the_outline_check_and_the_run_warnings_are_in_the_report(review_run, bare_run):
    """The process run recorded the outline check; a run with a loose-clothing
    warning shows it in a warnings box and the check's figures by the clothing note."""
    outline = review_run.results.session_shape.outline
    assert outline is not None and outline.frames == len(review_run.results.session_shape.frames)
    assert np.isfinite(outline.trunk_excess_mm) and np.isfinite(outline.offsets_mm["trunk"])
    # The tiny session's 240x180 cameras lie about at the check's bound (about 15 mm per
    # working pixel at the body): the status follows the rule either way, with no warning.
    coarse = outline.mm_per_px > OutlineConfig().max_mm_per_px
    assert outline.status.startswith("undecided") == coarse and outline.warnings == ()
    html = (review_run.folder / "report.html").read_text()
    assert "Outline check" in html and 'class="warnings"' not in html
    if coarse:
        assert "undecided: working pixels of" in html
    else:
        assert f"working pixels of {outline.mm_per_px:.1f} mm at the body" in html
    data = json.loads((bare_run / "results.json").read_text())
    warning = "loose clothing likely: the silhouettes lie 4.2 ± 0.3 mm further outside"
    data["persons"][0]["session_shape"]["outline"] = {
        "status": "ok",
        "mm_per_px": 9.5,
        "frames": 3,
        "offsets_mm": {"trunk": 2.0, "lower limbs": -2.2},
        "trunk_excess_mm": 4.2,
        "trunk_excess_se_mm": 0.3,
        "crown_excess_mm": 1.0,
        "crown_excess_se_mm": 0.2,
        "warnings": [warning],
    }
    data["warnings"] = [*data.get("warnings", []), warning]
    (bare_run / "results.json").write_text(json.dumps(data))
    html = build_report(bare_run).html.read_text()
    box = html[html.index('class="warnings"') :]
    assert warning in box[: box.index("</div>")]
    assert "4.2 ± 0.3 mm further outside the fitted body at the trunk" in html
    # A silent check says what it cannot see: garments a few millimetres off the skin.
    limit = "less than about 8 mm off the skin leaves no trace this check can see"
    assert limit not in html
    data["persons"][0]["session_shape"]["outline"]["warnings"] = []
    data["warnings"] = [w for w in data["warnings"] if w != warning]
    (bare_run / "results.json").write_text(json.dumps(data))
    assert limit in build_report(bare_run).html.read_text()


# --- the headline: the session estimate first --------------------------------------------------
def _card(html: str, key: str) -> dict[str, str]:
    """The text of a headline card's parts: ``k`` (its title), ``v`` (the big
    number), ``f`` (the per-frame mean) and ``u`` (why no session estimate)."""
    start = html.index(f'id="headline-{key}"')
    card = re.split(r'id="headline-|</section>', html[start + 1 :])[0]
    parts = {}
    for part in ("k", "v", "f", "u"):
        found = re.search(rf'<div class="{part}">(.*?)</div>', card, re.S)
        if found:
            parts[part] = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", "", found.group(1))).strip()
    return parts


def _fmt(value: float) -> str:
    return f"{value:,.1f}".replace(",", " ")


def test_the_headline_is_the_session_estimate_with_its_standard_error(review_run):
    html = (review_run.folder / "report.html").read_text()
    summary = review_run.results.summary
    for key in ("height_mm", "arm_span_mm", "weight_kg"):
        card = _card(html, key)
        session, frames = summary["session"][key], summary["generative"][key]
        assert "session estimate ± standard error" in card["k"], card
        assert card["v"].startswith(f"{_fmt(session.mean)} ± {_fmt(session.std)}"), card
        assert card["v"].endswith("(s.e.)"), card
        assert card["f"].startswith(f"per-frame mean {_fmt(frames.mean)} ± {_fmt(frames.std)}")
        assert f"std over {frames.n} frames" in card["f"]
        assert "u" not in card


@pytest.mark.parametrize("stage", ["rejected", "not run"])
def test_without_the_session_estimate_the_headline_is_the_per_frame_mean(
    review_run, bare_run, stage
):
    data = json.loads((bare_run / "results.json").read_text())
    data["persons"][0]["summary"].pop("session")
    for frame in data["persons"][0]["frames"]:
        frame.pop("session", None)
    status = "rejected: the shared shape lowers the frames' mean silhouette IoU"
    if stage == "rejected":
        data["persons"][0]["session_shape"]["status"] = status
    else:
        data["persons"][0].pop("session_shape")
        status = "the session stage was not run"
    (bare_run / "results.json").write_text(json.dumps(data))
    html = build_report(bare_run).html.read_text()
    generative = review_run.results.summary["generative"]["height_mm"]
    card = _card(html, "height_mm")
    assert "per-frame mean ± std" in card["k"], card
    assert card["v"].startswith(f"{_fmt(generative.mean)} ± {_fmt(generative.std)}"), card
    assert card["v"].endswith("(std)"), card
    assert html_text.unescape(card["u"]) == f"Session estimate unavailable ({status})"


def test_filters_of_the_report_pages():
    assert str(breakable("/a/b-c/d_e<")) == (
        '/<wbr>a/<wbr><span class="nw">b-c/</span><wbr>d_<wbr>e&lt;'
    )
    assert [ordinal(n) for n in (1, 2, 3, 4, 11, 12, 13, 21, 25, 112)] == [
        "1st", "2nd", "3rd", "4th", "11th", "12th", "13th", "21st", "25th", "112th",
    ]  # fmt: skip
    assert ordinal(2.5) == "2.5"
    assert headline_cards(_empty_run()) == []


def test_the_views_left_out_as_unreliable_are_listed_only_when_there_are_any(
    review_run, bare_run, monkeypatch
):
    # The plots are another test's: without them the report renders in a fraction of the time.
    monkeypatch.setattr(report_module, "_figures", lambda run, body: ({}, {}))
    html = (review_run.folder / "report.html").read_text()
    assert "Views left out" not in html  # capture left no view out of this run
    data = json.loads((bare_run / "results.json").read_text())
    frames = data["persons"][0]["frames"]
    for frame, value in ((frames[0], 0.61), (frames[2], 0.7449)):
        frame["flags"]["cam_01"] = ["unreliable"]
        frame["view_agreement"] = {"cam_00": 0.97, "cam_01": value}
    (bare_run / "results.json").write_text(json.dumps(data))
    html = build_report(bare_run).html.read_text()
    section = html[html.index('id="views-left-out"') :]
    items = re.findall(r"<li>(.*?)</li>", section[: section.index("</ul>")])
    kept = len(frames)
    listed = f"{frames[0]['frame']}, {frames[2]['frame']}"
    assert items == [
        f"cam_01 (unreliable): 2 of {kept} kept frames ({listed}), agreement 0.61-0.74"
    ]
    # The frames table still lists the flag per frame; the PDF's summary says it in a line.
    assert "cam_01: unreliable" in html[html.index('id="frames"') :]
    (line,) = _left_out_lines({"left_out": left_out_rows(load_run(bare_run))})
    assert line.endswith(
        f"cam_01 (unreliable) in 2 of {kept} kept frames ({listed}), agreement 0.61-0.74."
    )
    # A view another person hides (occluded) is listed too, with no agreement.
    frames[1]["flags"]["cam_00"] = ["occluded"]
    (bare_run / "results.json").write_text(json.dumps(data))
    rows = left_out_rows(load_run(bare_run))
    assert [(r["camera"], r["reason"], r["agreement"]) for r in rows] == [
        ("cam_00", "occluded", ""),
        ("cam_01", "unreliable", "0.61-0.74"),
    ]
    assert rows[0]["frames"] == f"1 of {kept} kept frames ({frames[1]['frame']})"
    # So is a view whose detection mixed the person with another.
    frames[2]["flags"]["cam_00"] = ["mixed"]
    (bare_run / "results.json").write_text(json.dumps(data))
    rows = left_out_rows(load_run(bare_run))
    assert [(r["camera"], r["reason"]) for r in rows] == [
        ("cam_00", "occluded"),
        ("cam_00", "mixed"),
        ("cam_01", "unreliable"),
    ]
    html = build_report(bare_run).html.read_text()
    assert f"cam_00 (mixed): 1 of {kept} kept frames ({frames[2]['frame']})" in html


def test_caveats_head_the_report_only_when_there_are_any(bare_run, monkeypatch):
    monkeypatch.setattr(report_module, "_figures", lambda run, body: ({}, {}))
    # No caveat: no box. (Stated here rather than read from the tiny run, whose rough
    # fits may or may not sink the soles past the floor bound or keep the arms down.)
    with monkeypatch.context() as m:
        m.setattr(RunResults, "caveats", property(lambda self: ()))
        assert 'id="caveats"' not in build_report(bare_run).html.read_text()
    data = json.loads((bare_run / "results.json").read_text())
    frames = data["persons"][0]["frames"]
    frames[0]["persons"] = 2
    (bare_run / "results.json").write_text(json.dumps(data))
    html = build_report(bare_run).html.read_text()
    box = html[html.index('id="caveats"') :]
    box = box[: box.index("</div>")]
    # Above the headline cards, naming the code and the frame.
    assert html.index('id="caveats"') < html.index('class="cards"')
    assert "several_persons" in box and f"frame {frames[0]['frame']}" in box
    # The frames table says it on that frame's row.
    assert "2 people in view" in html[html.index('id="frames"') :]


def test_the_prior_pull_is_stated_for_an_accepted_session_stage_only():
    pulled = SessionShape(
        "ok", prior_pull={"height_mm": -0.43, "arm_span_mm": 1.25, "weight_kg": 0.051}
    )
    assert prior_pull_text(pulled) == "height -0.4 mm, arm span +1.2 mm, weight +0.05 kg"
    # Recorded before the pull existed, rejected, not run: nothing is claimed.
    assert prior_pull_text(SessionShape("ok")) == ""
    assert prior_pull_text(dataclasses.replace(pulled, status="rejected: worse IoU")) == ""
    assert prior_pull_text(None) == ""
    partial = SessionShape("ok", prior_pull={"weight_kg": float("nan"), "height_mm": 2.0})
    assert prior_pull_text(partial) == "height +2.0 mm"
