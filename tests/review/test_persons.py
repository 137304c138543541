"""The review outputs of a run of two persons: the tiny review run copied as a format-3
run with two persons (tests/review/conftest.py, ``two_person_copy``), person 1 taller
by PERSON1_HEIGHT_SHIFT_MM, each person's frame files in ``persons/K/``."""

from __future__ import annotations

import csv
import json
import re
import shutil

import numpy as np
import pytest
import rerun.chunk as rc
from mcap.reader import make_reader
from two_persons import PERSON1_HEIGHT_SHIFT_MM, two_person_copy

from bodymetry.estimation.run_files import StudyResults, StudySession
from bodymetry.fileio import write_json_atomic
from bodymetry.review import cohort
from bodymetry.review.build import build_review
from bodymetry.review.cohort import write_cohort
from bodymetry.review.mcap_recording import overlay_silhouettes
from bodymetry.review.person_colors import person_rgb
from bodymetry.review.report import _num, build_report, headline_cards
from bodymetry.review.run_data import load_frame_arrays, load_run

RUN_WARNING = "a warning about the whole run (test)"


@pytest.fixture(scope="module")
def reviewed(two_person_run, tmp_path_factory):
    """The two-person run with a run-level warning, its review outputs written."""
    folder = tmp_path_factory.mktemp("reviewed") / "run"
    shutil.copytree(two_person_run, folder)
    data = json.loads((folder / "results.json").read_text())
    data["warnings"] = [RUN_WARNING]
    (folder / "results.json").write_text(json.dumps(data))
    summary = build_review(folder)
    assert summary.errors == {}
    return folder


def _person_block(html: str, person: int) -> str:
    """The HTML of one person's section (up to the next person's or the calibration)."""
    start = html.index(f'id="person-{person}"')
    ends = [html.find(m, start + 1) for m in ('id="person-', '<section id="calibration"')]
    return html[start : min(e for e in ends if e > 0)]


def test_run_data_serves_each_person_from_their_own_files(two_person_run):
    run = load_run(two_person_run)
    assert run.several and run.person_ids == (0, 1)
    second = run.for_person(1)
    assert not second.several and second.person_id == 1
    assert second.layout.frames_dir == two_person_run / "persons" / "1" / "frames"
    assert second.results.warnings[-1].startswith("person 1 was hidden")
    frame = second.frames[0].frame
    assert load_frame_arrays(second.layout, frame) is not None
    # The run's own frames/ is gone: only the persons' layouts hold the arrays.
    assert load_frame_arrays(run.folder, frame) is None
    with pytest.raises(KeyError, match="no person 7"):
        run.for_person(7)


def test_report_has_a_section_per_person_with_their_numbers(reviewed):
    html = (reviewed / "report.html").read_text()
    run = load_run(reviewed)
    assert html.count(RUN_WARNING) == 1  # the run's warnings once, above the persons
    heights = []
    for person in (0, 1):
        block = _person_block(html, person)
        assert f"Person {person}" in block
        card = next(c for c in headline_cards(run.for_person(person)) if c["key"] == "height_mm")
        value = card["session"][0] if card["session"] else card["mean"]
        heights.append(value)
        headline = re.search(
            rf'id="headline-height_mm-p{person}">(.*?)</div>\s*</div>', block, re.S
        )
        assert headline is not None and _num(value) in headline.group(1)
        # Their overlays, measurement plots and frames table are in their section.
        assert block.count("data:image/jpeg;base64,") >= 1
        assert f'id="frames-p{person}"' in block and f'id="overlays-p{person}"' in block
        assert ("hidden behind person 0" in block) == (person == 1)  # their own warning
    assert heights[1] - heights[0] == pytest.approx(PERSON1_HEIGHT_SHIFT_MM, abs=0.05)
    assert 'id="summary"' not in html  # ids are per person: no clash


def test_overlays_draw_each_person_in_their_colour():
    observed = np.zeros((20, 20), bool)
    model = np.zeros((20, 20), bool)
    model[5:10, 5:10] = True  # model only: the person's colour over grey
    colours = [overlay_silhouettes(None, observed, model, k)[7, 7] for k in (0, 1)]
    for k, bgr in enumerate(colours):
        expected = 0.35 * 90 + 0.65 * np.array(person_rgb(k)[::-1])
        np.testing.assert_allclose(bgr, expected, atol=1.0)
    assert not np.array_equal(colours[0], colours[1])


def _scalars(store, path):
    """The values of a series, in the order logged (the static style chunk has none)."""
    batches = [c.to_record_batch() for c in store.stream().to_chunks() if c.entity_path == path]
    return [
        v
        for batch in batches
        if "Scalars:scalars" in batch.schema.names
        for v in np.ravel(batch.column("Scalars:scalars").to_pylist())
    ]


def test_rerun_recording_has_entities_per_person(reviewed):
    store = rc.RrdReader(reviewed / "recording.rrd").store()
    paths = set(store.schema().entity_paths())
    cam = load_run(reviewed).camera_names[0]
    for k in (0, 1):
        expected = {
            f"/world/person/{k}/body/mesh",
            f"/world/person/{k}/body/skeleton",
            f"/world/rig/{cam}/person/{k}/model",
            f"/metrics/person/{k}/biometrics/height_mm/generative",
        }
        assert expected <= paths, sorted(expected - paths)
    assert "/world/body/mesh" not in paths
    assert f"/world/rig/{cam}/image" in paths
    first, second = (
        _scalars(store, f"/metrics/person/{k}/biometrics/height_mm/generative") for k in (0, 1)
    )
    assert len(first) == len(second) > 0
    np.testing.assert_allclose(np.subtract(second, first), PERSON1_HEIGHT_SHIFT_MM, atol=0.01)


def test_mcap_has_a_topic_set_per_person(reviewed):
    run = load_run(reviewed)
    with open(reviewed / "recording.mcap", "rb") as fh:
        reader = make_reader(fh)
        msgs = [(channel.topic, message) for _, channel, message in reader.iter_messages()]
    topics = {t for t, _ in msgs}
    cam = run.camera_names[0]
    for k in (0, 1):
        assert {f"/person/{k}/body", f"/person/{k}/measurements"} <= topics
        assert f"/person/{k}/cameras/{cam}/overlay" in topics
    assert "/body" not in topics
    # The camera images are the frame's: once per frame, not once per person.
    n_frames = len(run.frames)
    assert sum(t == f"/cameras/{cam}/image" for t, _ in msgs) == n_frames
    heights = {
        k: [
            json.loads(m.data)["generative"]["height_mm"]
            for t, m in msgs
            if t == f"/person/{k}/measurements" and "generative" in json.loads(m.data)
        ]
        for k in (0, 1)
    }
    assert len(heights[0]) == len(heights[1]) > 0
    np.testing.assert_allclose(
        np.subtract(heights[1], heights[0]), PERSON1_HEIGHT_SHIFT_MM, atol=0.01
    )


def _csv(path):
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def test_measurements_csv_has_a_row_per_person_and_frame(reviewed):
    rows = _csv(reviewed / "measurements.csv")
    run = load_run(reviewed)
    assert [r["person"] for r in rows] == ["0"] * len(run.frames) + ["1"] * len(run.frames)
    by = {(r["person"], r["frame"]): r for r in rows}
    for r in run.fitted_frames:
        a = float(by["0", str(r.frame)]["generative_height_mm"])
        b = float(by["1", str(r.frame)]["generative_height_mm"])
        assert b - a == pytest.approx(PERSON1_HEIGHT_SHIFT_MM, abs=0.01)


def test_one_person_csv_has_person_zero(review_run):
    rows = _csv(review_run.folder / "measurements.csv")
    assert rows and {r["person"] for r in rows} == {"0"}


def test_cohort_has_a_row_per_person(review_run, two_person_run, tmp_path, monkeypatch):
    study = tmp_path / "study"
    study.mkdir()
    two_person_copy(review_run, study / "pair")
    shutil.copytree(review_run.folder, study / "solo", ignore=shutil.ignore_patterns("recording.*"))
    write_json_atomic(
        study / "study.json",
        StudyResults(
            (StudySession("pair", "/data/pair", "done"), StudySession("solo", "/data/solo", "done"))
        ).to_json(),
    )
    monkeypatch.setattr(cohort, "_pyarrow_available", lambda: False)
    files = write_cohort(study)
    rows = _csv(files.csv)
    assert [(r["session"], r["person"]) for r in rows] == [
        ("pair", "0"),
        ("pair", "1"),
        ("solo", "0"),
    ]
    pair = {r["person"]: r for r in rows if r["session"] == "pair"}
    diff = float(pair["1"]["generative_height_mm_mean"]) - float(
        pair["0"]["generative_height_mm_mean"]
    )
    assert diff == pytest.approx(PERSON1_HEIGHT_SHIFT_MM, abs=0.1)  # the CSV rounds to 0.1 mm
    html = files.html.read_text()
    assert "pair, person 1" in html and "3 persons measured" in html
    assert re.search(r"sessions done</div><div class=\"v\">2 <small>of 2", html)


def _pdf_pages(path) -> int:
    return len(re.findall(rb"/Type\s*/Page(?![s\w])", path.read_bytes()))


def test_pdf_has_the_pages_of_each_person(reviewed, review_run):
    files = build_report(reviewed, pdf=True)
    one = _pdf_pages(review_run.folder / "report.pdf")
    assert one >= 3
    assert _pdf_pages(files.pdf) == 2 * one


def test_one_person_report_shows_the_persons_own_warnings(review_run, tmp_path):
    """A run of one person (format 3) has its person's warnings in results.json's
    person entry: the report shows them with the run's, each once."""
    folder = tmp_path / "run"
    shutil.copytree(review_run.folder, folder, ignore=shutil.ignore_patterns("recording.*"))
    data = json.loads((folder / "results.json").read_text())
    data["warnings"] = [RUN_WARNING]
    data["persons"][0]["warnings"] = ["own warning of the subject (test)"]
    (folder / "results.json").write_text(json.dumps(data))
    html = build_report(folder).html.read_text()
    assert html.count(RUN_WARNING) == 1
    assert html.count("own warning of the subject (test)") == 1
    assert 'id="person-0"' not in html and "<h2>Subject</h2>" in html
