"""End-to-end `process` on a tiny studio session: schema, failures, resume, evaluate."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh
from tiny_run import TINY_TRAIN, tiny_process_config, tiny_session

import bodymetry.cameras as cameras_module
import bodymetry.frame_jobs as frame_jobs
import bodymetry.pipeline as pipeline
import bodymetry.process as process_module
from bodymetry.calibration.camera import CameraGroup
from bodymetry.calibration.io import load_calibration
from bodymetry.calibration.solve import CalibrationResult
from bodymetry.capture.people import Sighting
from bodymetry.capture.segmentation import segment_session
from bodymetry.capture.session import load_session
from bodymetry.capture.video import H264Writer
from bodymetry.errors import InputError
from bodymetry.estimation.fit import FitConfig, FrameFit, fit_frame
from bodymetry.estimation.records import (
    CORE_MEASUREMENTS,
    STAGES,
    FrameArrays,
    FrameRecord,
    Stat,
    summarize,
)
from bodymetry.estimation.registration import read_registration
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import (
    EVALUATION_FORMAT,
    SUMMARY_VERSION,
    Evaluation,
    RunLayout,
    RunResults,
)
from bodymetry.estimation.session_shape import session_frame
from bodymetry.estimation.studio_accuracy import LOW_CONTRAST, VALIDATED_MM_PER_PX
from bodymetry.estimation.training import DiscriminativeModels
from bodymetry.frame_jobs import RESCUE_FILE, rescue_poor_frames
from bodymetry.review.evaluation import evaluate_persons, evaluate_run


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    base = tmp_path_factory.mktemp("pipeline")
    session = tiny_session(base / "session", seed=2)
    out = base / "run"
    return session, out, _process(session, out, base), base


def _config(base) -> ProcessConfig:
    return tiny_process_config(base / "cache")


def _process(session, out, base) -> RunResults:
    return process_module.process_session(session.folder, out, _config(base))


def _models(base) -> DiscriminativeModels:
    return DiscriminativeModels.load(next((base / "cache" / "discriminative").glob("*.npz")))


def test_results_schema(run):
    _, out, results, _ = run
    on_disk = json.loads((out / "results.json").read_text())
    assert on_disk == results.to_json()
    assert RunResults.from_json(on_disk).to_json() == on_disk  # round trip
    assert on_disk["format"] == 3
    (person,) = on_disk["persons"]
    assert person["id"] == 0 and not person["told_apart"] and "frames" not in on_disk
    # A results.json of format 2 (one subject at the top level) still reads.
    old = {k: v for k, v in on_disk.items() if k != "persons"}
    old |= {k: v for k, v in person.items() if k not in ("id", "told_apart", "warnings")}
    old |= {"format": 2, "warnings": on_disk["warnings"] + person["warnings"]}
    back = RunResults.from_json(old)
    assert back.to_json() == on_disk | {"warnings": old["warnings"]} | {
        "persons": [person | {"warnings": []}]
    }
    assert [f.frame for f in results.frames] == [0, 2, 4]
    # Capture's outline contrast, per frame and for the run (the saturated studio colours).
    contrasts = [f.outline_contrast for f in results.frames]
    assert all(c is not None and LOW_CONTRAST < c <= 2.0 for c in contrasts), contrasts
    assert person["outline_contrast"] == pytest.approx(np.median(contrasts), abs=1e-3)
    for f in results.frames:
        assert f.status == "ok", f.status
        for stage in STAGES:
            est = f.estimates[stage]
            for key in CORE_MEASUREMENTS:
                assert np.isfinite(est.biometrics[key])
            assert est.state.theta.shape == (1, 37)
        assert set(f.silhouette_iou) <= {"cam_00", "cam_01"}
    for stage in STAGES:
        assert results.summary[stage]["height_mm"].n == 3
    assert 1300 < results.ground_truth.get("height_mm") < 2200
    # The recorded config is the one that ran, and reads back as a config.
    again = ProcessConfig.from_json(on_disk["config"])
    assert again.fit.annealing.n_particles == 60 and again.training == TINY_TRAIN


def test_frame_artifacts(run):
    """Every fitted frame leaves its mesh (PLY), silhouettes and last particles (npz)."""
    _, out, results, _ = run
    for f in results.frames:
        mesh = trimesh.load(out / "meshes" / f"{f.frame:06d}.ply", process=False)
        assert mesh.is_watertight
        assert 1.0 < np.ptp(mesh.vertices[:, 2]) < 2.3
        arrays = FrameArrays.load(out / "frames" / f"{f.frame:06d}.npz")
        assert arrays.particles.shape[0] == arrays.weights.shape[0]
        assert abs(float(arrays.weights.sum()) - 1.0) < 1e-4
        assert set(arrays.observed) == set(arrays.model) == {"cam_00", "cam_01"}
        for name, iou in f.silhouette_iou.items():
            obs, model = arrays.observed[name], arrays.model[name]
            assert obs.shape == model.shape == (180, 240)
            recomputed = (obs & model).sum() / (obs | model).sum()
            assert recomputed == pytest.approx(iou, abs=5e-5)  # the record keeps 4 decimals


def test_a_finished_run_is_returned_as_recorded(run, monkeypatch):
    """Nothing runs again: no training, no fit, no session stage, no review."""
    session, out, results, base = run
    for step in ("train", "fit", "finish", "review", "segment"):
        monkeypatch.setattr(pipeline, step, lambda *a, step=step: pytest.fail(f"{step} ran"))
    again = _process(session, out, base)
    assert again.to_json() == results.to_json()


def test_resume_does_not_refit(run, monkeypatch, tmp_path):
    session, out, results, base = run
    # A run killed after its last frame, before results.json: the frames are kept.
    resumed = tmp_path / "run"
    shutil.copytree(out, resumed)
    (resumed / "results.json").unlink()

    def boom(*args, **kwargs):
        raise AssertionError("a finished frame was fitted again")

    monkeypatch.setattr(pipeline, "run_fit_job", boom)
    again = _process(session, resumed, base)
    out = resumed
    assert again.summary == results.summary
    assert again.models_reused
    # The session stage is redone from the recorded frames, to the same shape;
    # the frame records on disk stay the per-frame fits'.
    assert results.session_shape.ok and again.session_shape.nu == results.session_shape.nu
    for f in results.frames:
        on_disk = json.loads((out / "frames" / f"{f.frame:06d}.json").read_text())
        assert "session" not in on_disk and "generative" in on_disk


def test_a_summary_of_an_earlier_bodymetry_is_made_again(run, monkeypatch, tmp_path, caplog):
    """A finished run whose summary an earlier version made (another or no
    ``summary_version``) gets its summary made again from the recorded frames,
    without fitting a frame; one of this version is returned as recorded."""
    session, out, results, base = run
    assert results.summary_version == SUMMARY_VERSION
    assert json.loads((out / "results.json").read_text())["summary_version"] == SUMMARY_VERSION
    old = tmp_path / "run"
    shutil.copytree(out, old)
    data = json.loads((old / "results.json").read_text())
    del data["summary_version"]  # a file from before the version was recorded
    data["persons"][0]["session_shape"]["biometrics"]["weight_kg"] = 1.0  # an old number
    (old / "results.json").write_text(json.dumps(data))
    assert RunResults.read(old / "results.json").summary_version == 0

    def boom(*args, **kwargs):
        raise AssertionError("a finished frame was fitted again")

    monkeypatch.setattr(pipeline, "run_fit_job", boom)
    with caplog.at_level("INFO"):
        again = _process(session, old, base)
    assert "summary made by an earlier bodymetry (summary version 0" in caplog.text
    assert again.summary_version == SUMMARY_VERSION
    assert again.session_shape.biometrics["weight_kg"] == pytest.approx(
        results.session_shape.biometrics["weight_kg"]
    )
    # Now current: returned as recorded (nothing made again).
    monkeypatch.setattr(pipeline, "finish", boom)
    assert _process(session, old, base).summary == again.summary


def test_frame_without_silhouette_is_marked_and_excluded(run):
    session, _, results, base = run
    cams = session.calibration()
    empty = np.zeros((2, 180, 240), bool)
    fit = fit_frame(7, empty, [["empty"], ["empty"]], cams, _models(base), FitConfig.preset("fast"))
    assert fit.record.status == "no silhouette in any camera"
    assert fit.state is None and set(fit.arrays.observed) == {"cam_00", "cam_01"}
    assert FrameRecord.from_json(fit.record.to_json()) == fit.record
    summary = summarize([*results.frames, fit.record])
    assert summary["generative"]["height_mm"].n == 3


def test_poor_fit_is_marked_kept_and_excluded(run):
    """Below the IoU gate a frame keeps its numbers but leaves the summary."""
    session, _, results, base = run
    sil = next(iter(segment_session(session, keep_images=False)))
    cams = session.calibration()
    flags = [list(f) for f in sil.flags]
    strict = fit_frame(
        sil.frame, sil.stack(), flags, cams, _models(base), FitConfig.preset("fast", min_iou=1.0)
    ).record
    assert strict.status.startswith("poor fit: mean silhouette IoU")
    assert strict.fitted and not strict.ok
    assert np.isfinite(strict.estimates["generative"].biometrics["height_mm"])
    assert 0.5 < strict.mean_iou < 1.0
    summary = summarize([*results.frames[1:], strict])
    assert summary["generative"]["height_mm"].n == 2


def test_refinement_improves_on_the_annealing(run):
    """The contour refinement lowers its cost from where the annealing left off."""
    _, _, results, _ = run
    for f in results.frames:
        r = f.refinement
        assert r.cost_px2 <= r.initial_cost_px2
        # The starts fit_frame refines from (the landmark pose when the session has
        # landmarks, as the tiny studio session does).
        assert r.start in ("annealing mean", "best particle", "landmarks") or r.start.startswith(
            "discriminative cam_"
        )


def test_unknown_quality_is_refused():
    with pytest.raises(InputError, match="quality"):
        ProcessConfig(quality="ultra")
    with pytest.raises(ValueError, match="quality"):
        FitConfig.preset("ultra")


def test_session_calibration_is_recorded_in_the_run(run):
    session, out, results, _ = run
    assert (out / "calibration.yaml").read_bytes() == session.calibration_path.read_bytes()
    assert results.calibration_source == str(session.calibration_path)


def test_session_without_calibration_is_calibrated_from_its_clips(run, tmp_path, monkeypatch):
    session = run[0]
    truth = session.calibration()
    uncalibrated = dataclasses.replace(session, calibration_file=None)
    calls = []

    solved = CalibrationResult(
        cameras=truth,
        rms_px=0.2,
        per_camera={},
        frames_used=12,
        observations=480,
        outliers=0,
        world={"frame": "floor board"},
    )

    def fake_calibrate(sess, **kwargs):
        calls.append(sess.folder)
        return solved, []

    monkeypatch.setattr(cameras_module, "calibrate_session", fake_calibrate)
    resolved = cameras_module.resolve_cameras(uncalibrated, tmp_path)
    cams = resolved.cameras
    assert list(cams.names) == list(session.camera_names) and len(calls) == 1
    assert resolved.source == cameras_module.SOLVED
    assert (tmp_path / "calibration.yaml").is_file()
    assert (tmp_path / "calibration-report.json").is_file()
    # A resumed run reuses the solved file instead of solving again.
    again = cameras_module.resolve_cameras(uncalibrated, tmp_path).cameras
    assert len(calls) == 1
    np.testing.assert_allclose(again[0].K, cams[0].K)


def test_evaluate_writes_the_figure_3_table(run):
    _, out, results, _ = run
    ev = evaluate_run(out, workers=1)
    assert Evaluation.read(out / "evaluation.json") == ev
    ev = json.loads((out / "evaluation.json").read_text())
    assert ev["format"] == EVALUATION_FORMAT
    assert ev["frames"] == 3 and ev["frames_failed"] == 0
    for key in CORE_MEASUREMENTS:
        row = ev["table"][key]
        assert row["actual"] == results.ground_truth.get(key)
        assert row["generative"]["mean"] == pytest.approx(results.summary["generative"][key].mean)
        assert row["gt_generative"]["n"] == 3
        assert row["session"]["mean"] == results.summary["session"][key].mean
    assert np.isfinite(ev["mpjpe_mm"]["session"])
    # Started from the true pose, the fit's joints are closer to the truth than the
    # discriminative guess.
    assert ev["mpjpe_mm"]["gt_generative"] < ev["mpjpe_mm"]["discriminative"]


def _as_two_persons(out, folder, shift_m=0.0):
    """A copy of run ``out`` as a run of two persons told apart: person 0 the run's
    own frames, person 1 the same frames with each fit moved ``shift_m`` metres in x."""
    shutil.copytree(out, folder)
    results = RunResults.read(folder / "results.json")
    layout = RunLayout(folder)
    for ident in (0, 1):
        dest = layout.for_person(ident)
        shutil.copytree(folder / "frames", dest.frames_dir)
    moved = []
    for r in results.frames:
        estimates = {
            k: dataclasses.replace(
                e, state=dataclasses.replace(e.state, tau=e.state.tau + [shift_m, 0.0, 0.0])
            )
            for k, e in r.estimates.items()
        }
        moved.append(dataclasses.replace(r, estimates=estimates))
    zero = dataclasses.replace(results.person, told_apart=True)
    one = dataclasses.replace(zero, id=1, frames=tuple(moved))
    dataclasses.replace(results, persons=(zero, one)).write(layout)
    return folder


def test_evaluate_scores_each_person_against_the_studio_person_where_they_stood(run, tmp_path):
    _, out, _, _ = run
    alone = (
        Evaluation.read(out / "evaluation.json")
        if (out / "evaluation.json").is_file()
        else (evaluate_run(out, workers=1))
    )
    two = _as_two_persons(out, tmp_path / "two")
    first, second = evaluate_persons(two, workers=1)
    assert (first.person, second.person) == (0, 1)
    assert first.truth_person == second.truth_person == 0  # the studio has its subject only
    for ev, ident in ((first, 0), (second, 1)):
        assert Evaluation.read(two / "persons" / str(ident) / "evaluation.json") == ev
        assert ev.actual == alone.actual and ev.frames == alone.frames
        for key in CORE_MEASUREMENTS:
            assert ev.table[key]["generative"] == alone.table[key]["generative"]
    assert not (two / "evaluation.json").is_file() or (
        Evaluation.read(two / "evaluation.json").person is None  # the copied one-person file
    )
    # A person who stood where no studio person was has no truth: a clear error.
    far = _as_two_persons(out, tmp_path / "far", shift_m=5.0)
    assert evaluate_run(far, workers=1, person=0).person == 0
    with pytest.raises(InputError, match="person 1 is matched to none of the studio's people"):
        evaluate_run(far, workers=1, person=1)
    with pytest.raises(InputError, match=r"has no person 7"):
        evaluate_run(far, workers=1, person=7)


def test_evaluate_needs_a_run(tmp_path):
    with pytest.raises(InputError, match=r"results\.json"):
        evaluate_run(tmp_path)


def test_old_results_get_a_clear_error(run, tmp_path):
    _, out, _, _ = run
    old = json.loads((out / "results.json").read_text())
    del old["format"]
    with pytest.raises(InputError, match="older bodymetry"):
        RunResults.from_json(old, "results.json")


def test_a_black_camera_is_named_and_the_results_stay_strict_json(run, tmp_path):
    """A covered lens: the camera is named in a warning and results.json has no NaN."""
    session, _, _, base = run
    folder = tmp_path / "session"
    shutil.copytree(session.folder, folder)
    black = load_session(folder)
    with H264Writer(black.video_path("cam_01"), black.fps, (240, 180)) as writer:
        for _ in range(5):
            writer.write(np.zeros((180, 240, 3), np.uint8))
    results = process_module.process_session(folder, tmp_path / "run", _config(base))
    assert results.camera_frames == {"cam_00": 3, "cam_01": 0}
    assert any("camera 'cam_01' saw no person" in w for w in results.for_person(0).warnings)
    text = (tmp_path / "run" / "results.json").read_text()
    json.loads(text, parse_constant=lambda c: 1 / 0)  # strict JSON: no NaN or Infinity


def test_frame_step_override_is_used_and_recorded(run, tmp_path):
    session, _, _, base = run
    config = dataclasses.replace(_config(base), frame_step=4)
    results = process_module.process_session(session.folder, tmp_path / "run", config)
    assert [r.frame for r in results.frames] == [0, 4]
    assert results.session.frame_step == 4 and results.config.frame_step == 4
    with pytest.raises(InputError, match="other settings"):  # a resume must use the same step
        process_module.process_session(session.folder, tmp_path / "run", _config(base))


def _poor_copy(run, tmp_path, *frames: int):
    """A copy of the run folder whose ``frames`` read as poor fits (IoU 0.3 everywhere)."""
    _, out, _, _ = run
    copy = tmp_path / "run"
    shutil.copytree(out, copy)
    layout = RunLayout(copy)
    for frame in frames:
        record = FrameRecord.read(layout.frame_record(frame))
        poor = dataclasses.replace(
            record,
            status="poor fit: mean silhouette IoU 0.30 < 0.50",
            silhouette_iou={k: 0.3 for k in record.silhouette_iou},
        )
        layout.frame_record(frame).write_text(json.dumps(poor.to_json()))
    return layout, {f: FrameRecord.read(layout.frame_record(f)) for f in layout.recorded_frames()}


def _rescue_inputs(run) -> tuple[CameraGroup, Path, FitConfig]:
    """The working cameras, the models and the fit settings of the tiny run."""
    session, _, _, base = run
    model_path = next((base / "cache" / "discriminative").glob("*.npz"))
    return session.calibration(), model_path, _config(base).fit


def test_rescue_refines_a_poor_frame_again_from_its_neighbours(run, tmp_path, monkeypatch):
    layout, records = _poor_copy(run, tmp_path, 2)
    cams, model_path, config = _rescue_inputs(run)
    seen = {}
    real_refit = frame_jobs.refit_frame

    def spy(previous, cameras, fit_config, proposals):
        seen[previous.record.frame] = proposals
        return real_refit(previous, cameras, fit_config, proposals)

    monkeypatch.setattr(frame_jobs, "refit_frame", spy)
    # The refinement is enough here (the frame's own fit is good; only its record
    # was made poor): no whole fit.
    monkeypatch.setattr(frame_jobs, "fit_frame", lambda *a: pytest.fail("refitted whole"))
    out = rescue_poor_frames(layout, records, cams, model_path, config)
    assert list(seen) == [2]  # only the poor frame, from both neighbours
    assert set(seen[2]) == {"frame 0", "frame 4"}
    assert out[2].mean_iou > 0.5 and out[2].status == "ok"
    # The refit keeps the first fit's discriminative estimate and annealing trace.
    before, after = records[2].to_json(), out[2].to_json()
    assert after["discriminative"] == before["discriminative"]
    assert after["annealing"] == before["annealing"]
    # The records keep seconds to 0.01 s, each rounded on its own: the total may
    # read up to one unit below the sum of its rounded parts.
    spent = records[2].seconds["total"] + out[2].seconds["rescue"]
    assert out[2].seconds["total"] >= spent - 0.01
    assert FrameRecord.read(layout.frame_record(2)).to_json() == out[2].to_json()  # written
    assert all(out[f] is records[f] for f in (0, 4))
    tried = json.loads((layout.frames_dir / RESCUE_FILE).read_text())
    assert tried["2"]["kept"] and tried["2"]["neighbours"] == [0, 4]
    assert tried["2"]["iou_before"] == pytest.approx(0.3)
    assert tried["2"]["method"] == "refinement"

    # Tried once: a resumed run does not try it again.
    monkeypatch.setattr(frame_jobs, "refit_frame", lambda *a: pytest.fail("refined twice"))
    poor_again = {**out, 2: records[2]}
    assert rescue_poor_frames(layout, poor_again, cams, model_path, config) is poor_again


def test_rescue_fits_whole_when_the_refinement_stays_below_the_gate(run, tmp_path, monkeypatch):
    layout, records = _poor_copy(run, tmp_path, 2)
    cams, model_path, config = _rescue_inputs(run)
    monkeypatch.setattr(frame_jobs, "refit_frame", lambda previous, *a: previous)  # no better
    seen = {}
    real_fit = frame_jobs.fit_frame

    def spy(frame, *args, **kwargs):
        seen[frame] = args[-1]  # the proposals
        return real_fit(frame, *args, **kwargs)

    monkeypatch.setattr(frame_jobs, "fit_frame", spy)
    # Capture's verdicts on the views travel with the frame into its new record.
    records[2] = dataclasses.replace(records[2], view_agreement={"cam_00": 0.97, "cam_01": 0.9})
    out = rescue_poor_frames(layout, records, cams, model_path, config)
    assert set(seen[2]) == {"frame 0", "frame 4"}
    assert out[2].mean_iou > 0.5 and out[2].status == "ok"
    assert out[2].view_agreement == {"cam_00": 0.97, "cam_01": 0.9}
    tried = json.loads((layout.frames_dir / RESCUE_FILE).read_text())
    assert tried["2"]["kept"] and tried["2"]["method"] == "annealing"


def test_rescue_rounds_run_together_and_a_rescued_frame_proposes_next(run, tmp_path, monkeypatch):
    """Frames 2 and 4 poor, frame 0 accepted: round one fits both at once from frame 0;
    frame 2 is rescued there and so proposes for frame 4, which round two fits again."""
    session, _, _, base = run
    layout, records = _poor_copy(run, tmp_path, 2, 4)
    good = {f: dataclasses.replace(records[f], status="ok", silhouette_iou={
        k: 0.95 for k in records[f].silhouette_iou}) for f in (2, 4)}  # fmt: skip
    calls = []

    def fake(frame, *args, **kwargs):
        calls.append((frame, sorted(args[-1])))
        fails = frame == 4 and "frame 2" not in args[-1]  # frame 4 needs frame 2's fit
        return FrameFit(records[frame] if fails else good[frame], FrameArrays())

    monkeypatch.setattr(frame_jobs, "fit_frame", fake)
    monkeypatch.setattr(frame_jobs, "refit_frame", lambda previous, *a: previous)  # never enough
    rounds = []

    def run_jobs(jobs):
        rounds.append([j.frame for j in jobs])
        return frame_jobs.run_serially(jobs)

    model_path = next((base / "cache" / "discriminative").glob("*.npz"))
    cams = session.calibration()
    out = rescue_poor_frames(
        layout, records, cams, model_path, _config(base).fit, run_jobs=run_jobs
    )
    assert rounds == [[2, 4], [2, 4], [4], [4]]  # each round: refinements, then whole fits
    assert calls == [(2, ["frame 0"]), (4, ["frame 0"]), (4, ["frame 0", "frame 2"])]
    assert out[2].ok and out[4].ok
    tried = json.loads((layout.frames_dir / RESCUE_FILE).read_text())
    assert tried["4"]["neighbours"] == [2, 0] and tried["4"]["kept"]
    assert tried["2"]["neighbours"] == [0]


def test_rescue_keeps_the_first_fit_when_the_second_is_no_better(run, tmp_path, monkeypatch):
    session, _, _, base = run
    layout, records = _poor_copy(run, tmp_path, 4)
    worse = dataclasses.replace(
        records[4], silhouette_iou={k: 0.1 for k in records[4].silhouette_iou}
    )
    monkeypatch.setattr(frame_jobs, "fit_frame", lambda *a, **k: FrameFit(worse, FrameArrays()))
    monkeypatch.setattr(frame_jobs, "refit_frame", lambda *a: FrameFit(worse, FrameArrays()))
    model_path = next((base / "cache" / "discriminative").glob("*.npz"))
    cams = session.calibration()
    out = rescue_poor_frames(layout, records, cams, model_path, _config(base).fit)
    assert all(out[f] is records[f] for f in records)
    assert FrameRecord.read(layout.frame_record(4)).to_json() == records[4].to_json()
    tried = json.loads((layout.frames_dir / RESCUE_FILE).read_text())
    assert tried == {
        "4": {
            "neighbours": [2, 0],
            "iou_before": 0.3,
            "iou_after": 0.1,
            "kept": False,
            "method": "refinement",
        }
    }


def test_rescue_off_and_nothing_to_rescue(run, tmp_path, monkeypatch):
    session, out, results, base = run
    monkeypatch.setattr(frame_jobs, "fit_frame", lambda *a: pytest.fail("nothing to rescue"))
    monkeypatch.setattr(frame_jobs, "refit_frame", lambda *a: pytest.fail("nothing to rescue"))
    cams = session.calibration()
    model_path = next((base / "cache" / "discriminative").glob("*.npz"))
    records = {r.frame: r for r in results.frames}
    config = _config(base).fit
    assert rescue_poor_frames(RunLayout(out), records, cams, model_path, config) is records
    layout, poor = _poor_copy(run, tmp_path, 2)
    assert rescue_poor_frames(layout, poor, cams, model_path, config, neighbours=0) is poor
    assert not (layout.frames_dir / RESCUE_FILE).exists()


def _first_frame_as_captured(run, tmp_path, monkeypatch, verdict):
    """A copy of the run whose capture stage passes every silhouette frame through
    ``verdict`` (SilhouetteFrame -> SilhouetteFrame); its first kept frame segmented
    and fitted again. Returns the prepared and planned run, that frame's segment, its
    written record, the run's models and the settings without the session stage."""
    session, out, results, base = run
    copy = tmp_path / "run"
    shutil.copytree(out, copy)
    config = _config(base)
    real_segment = pipeline.segment_session

    def judged(*args, **kwargs):
        yield from map(verdict, real_segment(*args, **kwargs))

    monkeypatch.setattr(pipeline, "segment_session", judged)
    prepared = pipeline.prepare(session.folder, copy, config)
    planned = pipeline.plan(prepared, config)
    models = pipeline.backgrounds(prepared, planned, config, "seek")
    (seg,) = pipeline.segment(prepared, planned, models, [planned.kept[0]], config, "seek")
    rig = pipeline.RigModels(results.models, _rescue_inputs(run)[1], True, 0.0)
    record = pipeline.fit(prepared, rig, seg, config)
    no_stage = dataclasses.replace(
        config, session_shape=dataclasses.replace(config.session_shape, enabled=False)
    )
    return prepared, planned, seg, record, rig, no_stage


def test_an_unreliable_view_is_left_out_of_the_fit_and_named(run, tmp_path, monkeypatch):
    """Capture flags cam_01 ``unreliable`` in the first kept frame: cam_00 alone is left
    in that frame of the 2-camera session, too few views to measure (one silhouette says
    nothing of depth), so the frame is not fitted and says why; the session stage sees
    cam_01 blank, camera_frames does not count it, a warning names it, and capture's
    agreement survives the record's round trip."""

    def unreliable(sil):
        flags = (sil.flags[0], (*sil.flags[1], "unreliable"))
        return dataclasses.replace(sil, flags=flags, agreement=(0.97, 0.58))

    prepared, planned, seg, record, rig, config = _first_frame_as_captured(
        run, tmp_path, monkeypatch, unreliable
    )
    first = planned.kept[0]
    assert seg.agreement == {"cam_00": 0.97, "cam_01": 0.58}
    assert not record.fitted and record.status.startswith(
        "too few views: only cam_00 of 2 cameras shows the person usably"
    )
    assert record.view_agreement == {"cam_00": 0.97, "cam_01": 0.58}
    assert record.person_pixels["cam_01"] > 400  # left out for its flag, not its size
    layout = prepared.layout
    done = frame_jobs.read_done_frames(layout)
    assert done[first].to_json() == record.to_json()  # a resumed run reads the same verdict
    arrays = FrameArrays.load(layout.frame_arrays(first))
    assert arrays.observed["cam_01"].any()  # kept for review, as capture found it
    # The session stage blanks a view its record leaves out (here on the record given
    # another frame's fit: a 2-camera frame with one view left is not fitted).
    fitted = dataclasses.replace(record, estimates=done[planned.kept[1]].estimates)
    sf = session_frame(fitted, arrays, prepared.cameras)
    assert sf.masks[0].any() and not sf.masks[1].any()
    finished = _finished(prepared, config, rig, done)
    n = len(planned.kept)
    assert finished.camera_frames == {"cam_00": n, "cam_01": n - 1}
    assert (
        f"cam_01: silhouette unreliable in 1 of {n} kept frames (agreement 0.58 < 0.80), "
        "left out of those frames' fits"
    ) in finished.for_person(0).warnings
    assert RunResults.read(layout.results).frames[0].view_agreement == record.view_agreement


def test_capture_s_outline_contrast_reaches_the_record_and_the_run(run, tmp_path, monkeypatch):
    """Capture's outline contrast travels through the fit into the record, survives a
    resume, and a run seen in low contrast is held against the studio's low-contrast
    sessions (the scope of its studio accuracy says so)."""
    prepared, planned, seg, record, rig, config = _first_frame_as_captured(
        run, tmp_path, monkeypatch, lambda sil: dataclasses.replace(sil, contrast=1.1)
    )
    first = planned.kept[0]
    assert seg.contrast == 1.1 and record.outline_contrast == 1.1
    done = frame_jobs.read_done_frames(prepared.layout)
    assert done[first].outline_contrast == 1.1
    low = {f: dataclasses.replace(r, outline_contrast=1.1) for f, r in done.items()}
    finished = _finished(prepared, config, rig, low)
    assert finished.outline_contrast == 1.1
    assert finished.studio_accuracy
    assert all("low-contrast clothing" in a.scope for a in finished.studio_accuracy.values())
    # The session stage's outline check holds a run seen in low contrast to its own
    # threshold (OutlineConfig.loose_mm_low_contrast).
    asked = []
    check = pipeline.check_outline
    monkeypatch.setattr(
        pipeline, "check_outline", lambda *a, **k: asked.append(k["low_contrast"]) or check(*a, **k)
    )
    staged = dataclasses.replace(
        config, session_shape=dataclasses.replace(config.session_shape, enabled=True, iterations=0)
    )
    plain = {f: dataclasses.replace(r, outline_contrast=1.8) for f, r in done.items()}
    for records in (low, plain):
        pipeline.session_stage(prepared, staged, list(records.values()))
    assert asked == [True, False]


def _finished(prepared, config, rig, done):
    """The run of one subject finished from its recorded frames (the graph's last steps)."""
    person = pipeline.finish_person(prepared, config, done, pipeline.PersonPlan(), 0)
    return pipeline.finish(prepared, config, rig, [person], {})


def test_a_second_person_in_view_is_recorded_and_becomes_a_caveat(run, tmp_path, monkeypatch):
    """Capture counts two people in the first kept frame: the count travels through the
    fit into the record, survives a resume, and the finished run carries the caveat
    (in results.json too)."""
    prepared, planned, seg, record, rig, config = _first_frame_as_captured(
        run, tmp_path, monkeypatch, lambda sil: dataclasses.replace(sil, persons=2)
    )
    first = planned.kept[0]
    assert seg.persons == 2 and record.persons == 2
    layout = prepared.layout
    done = frame_jobs.read_done_frames(layout)
    assert done[first].persons == 2
    finished = _finished(prepared, config, rig, done)
    codes = [c.code for c in finished.caveats]
    assert record.ok and "several_persons" in codes
    (crowd,) = [c for c in finished.caveats if c.code == "several_persons"]
    assert crowd.frames == (first,)
    written = json.loads(layout.results.read_text())
    assert [c["code"] for c in written["persons"][0]["caveats"]] == codes
    assert RunResults.read(layout.results).caveats == finished.caveats


def test_a_run_measures_each_person_capture_tells_apart(run, tmp_path, monkeypatch):
    """Capture tells two people apart in every kept frame (here both standing in the
    subject's pixels, one at x = 0 and one 1.5 m away): the run fits each of them on
    their own, writes each one's frames under persons/K/, records both in results.json
    without the several_persons caveat, and a second call finds the run finished."""
    session, _, alone, base = run
    real_segment = pipeline.segment_session

    last = alone.frames[-1].frame

    def two_people(*args, **kwargs):
        for sil in real_segment(*args, **kwargs):
            n = len(sil.masks)
            people = tuple(
                Sighting(np.array([x, 0.0, 1.0]), sil.masks, (None,) * n, (False,) * n)
                for x in ((0.0,) if sil.frame == last else (0.0, 1.5))
            )
            yield dataclasses.replace(sil, persons=len(people), sightings=people)

    monkeypatch.setattr(pipeline, "segment_session", two_people)
    monkeypatch.setattr(pipeline, "needs_every_frame", lambda config: True)
    out = tmp_path / "two"
    results = process_module.process_session(session.folder, out, _config(base))
    assert results.several and [p.id for p in results.persons] == [0, 1]
    layout = RunLayout(out)
    kept = [f.frame for f in alone.frames]
    for person in results.persons:
        assert person.told_apart and [f.frame for f in person.frames] == kept
        assert sorted(layout.for_person(person.id).recorded_frames()) == kept
        assert [f.persons for f in person.frames] == [2] * (len(kept) - 1) + [1]
        codes = [c.code for c in results.for_person(person.id).caveats]
        assert "several_persons" not in codes
    assert layout.recorded_frames() == []  # a run of several keeps no subject's frames
    # The same pixels and the same seed: both persons' fits are the run of one subject's.
    for person in results.persons:
        for mine, theirs in zip(person.frames, alone.frames, strict=True):
            if person.id == 1 and mine.frame == last:
                # Person 1 is not in the last frame: the record says so.
                assert mine.status.startswith("person not found in this frame")
                assert all("absent" in f for f in mine.flags.values())
            else:
                assert mine.status.split(":")[0] == theirs.status.split(":")[0]
    assert RunResults.read(out / "results.json").to_json() == results.to_json()

    def no_fit(*args, **kwargs):
        raise AssertionError("a finished run fits nothing")

    monkeypatch.setattr(pipeline, "fit", no_fit)
    again = process_module.process_session(session.folder, out, _config(base))
    assert again.to_json() == results.to_json()


def test_the_headline_values_prefer_the_session_stage_and_are_held_to_the_validated_range(run):
    """The values a run states (the session stage's, else the frames' mean) are what
    the validated-bodies caveat judges; a body the benchmarks never measured is named."""
    alone = run[2]
    inside = alone.with_person(
        summary={
            "generative": {"height_mm": Stat(1700.0, 5.0, 3), "weight_kg": Stat(70.0, 1.0, 3)},
            "session": {"height_mm": Stat(1705.0, 1.0, 3), "weight_kg": Stat(None, None, 0)},
        }
    )
    assert inside.headline_values == {"height_mm": 1705.0, "weight_kg": 70.0}
    assert "outside_validated" not in [c.code for c in inside.caveats]
    small = inside.with_person(
        summary={**inside.summary, "session": {"height_mm": Stat(1052.0, 1.0, 3)}}
    )
    (caveat,) = [c for c in small.caveats if c.code == "outside_validated"]
    # Height from the session stage, weight from the frames: a body like none scored.
    assert caveat.message.startswith("the measured height 1052 mm and weight 70 kg are unlike")


def test_a_camera_off_its_video_is_registered_and_the_frames_fitted_again(
    moved_camera, tmp_path, monkeypatch
):
    """Camera 1's calibration moved 5 px down (its principal point) in a 4-camera
    session: the fitted bodies sit off its silhouettes in every frame (and, meeting
    it halfway, a little off the others'), so the run shifts camera 1 alone back,
    fits every frame again and says so; a resumed run fits nothing again."""
    registered, out = moved_camera.results, moved_camera.out
    shifts = {s.camera: s for s in read_registration(out / "registration.json")}
    assert shifts["cam_01"].applied and -6.5 < shifts["cam_01"].dy < -3.0, shifts["cam_01"]
    assert [n for n, s in shifts.items() if s.applied] == ["cam_01"], shifts
    run_calib = load_calibration(out / "calibration.yaml")
    rendered = moved_camera.calibration[1].K[1, 2]
    # About where it belongs: on this tiny session the registration recovers 64-94 %
    # of the 5 px (render seeds 2-9 of the same session: 0.32-1.78 px left, 1.61 at
    # seed 2); the fitted bodies meet the camera that is off partly by posing, which
    # the body's common motion does not take out.
    assert abs(run_calib[1].K[1, 2] - rendered) < 2.0
    assert any("'cam_01'" in w and "fitted again" in w for w in registered.warnings)
    assert [f.frame for f in registered.frames] == [0, 2, 4]
    # Resumed after its last frame (in a copy: the run is shared): the registered
    # cameras again, nothing refitted.
    resumed = shutil.copytree(out, tmp_path / "run")
    (resumed / "results.json").unlink()
    monkeypatch.setattr(pipeline, "run_fit_job", lambda *a, **k: pytest.fail("refitted"))
    folder = moved_camera.session.folder
    again = process_module.process_session(folder, resumed, moved_camera.config)
    assert again.summary == registered.summary
    assert again.warnings == registered.warnings


def test_soles_the_floor_reading_did_not_trust_are_a_caveat_of_the_run(run):
    """RunResults.caveats names the floor where the session stage kept the body's own
    height (soles deeper than the bound), not where it read the height from the floor."""
    alone = run[2]
    shape = alone.session_shape
    assert shape is not None and shape.ok

    def codes(**floor):
        changed = dataclasses.replace(shape, **floor)
        return [c.code for c in alone.with_person(session_shape=changed).caveats]

    assert "floor" in codes(floor_mm=-31.8, floor_height=True, floor_applied=False)
    assert "floor" not in codes(floor_mm=-8.4, floor_height=True, floor_applied=True)
    # A file made before the bound read its -31.8 mm from the floor, and says so.
    assert "floor" not in codes(floor_mm=-31.8, floor_height=True, floor_applied=True)
    assert "floor" not in codes(floor_mm=-31.8, floor_height=False, floor_applied=False)


def test_the_printed_table_gives_each_session_value_s_95_percent_interval(run, monkeypatch):
    """`bodymetry process` prints, beside each session value ± standard error, the interval
    the run states (estimation/uncertainty.py), to the table's one decimal."""
    import rich.console

    import bodymetry.cli.process as cli_process

    # The tiny run's 240x180 cameras are coarser than the studio's (no interval: the
    # coarse_pixels caveat); at the studio's pixels it states them.
    assert run[2].stated_intervals == {}
    shape = run[2].session_shape
    outline = dataclasses.replace(shape.outline, mm_per_px=VALIDATED_MM_PER_PX)
    results = run[2].with_person(session_shape=dataclasses.replace(shape, outline=outline))
    intervals = results.stated_intervals
    assert intervals, "the tiny run's body is like the studio's: intervals are stated"
    wide = rich.console.Console(width=300, record=True)
    monkeypatch.setattr(cli_process, "console", wide)
    cli_process._print_summary(results)
    text = " ".join(wide.export_text().split())
    assert "95 % interval" in text
    for interval in intervals.values():
        assert f"{interval.low:.1f} to {interval.high:.1f}" in text
    assert "no 95 % interval" not in text
    # Loose clothing found: no weight or arm span interval, and the line says why.
    shape = results.session_shape
    loose = dataclasses.replace(
        shape.outline, warnings=("loose clothing likely: the silhouettes lie ...",)
    )
    clothed = results.with_person(session_shape=dataclasses.replace(shape, outline=loose))
    wide = rich.console.Console(width=300, record=True)
    monkeypatch.setattr(cli_process, "console", wide)
    cli_process._print_summary(clothed)
    text = " ".join(wide.export_text().split())
    assert "no 95 % interval for arm_span_mm, weight_kg: loose clothing" in text
    height = clothed.stated_intervals["height_mm"]
    assert f"{height.low:.1f} to {height.high:.1f}" in text
    assert set(clothed.stated_intervals) == {"height_mm"}
