"""End-to-end `process` on a tiny studio session: schema, failures, resume."""

from __future__ import annotations

import json

import numpy as np
import pytest
from tiny_run import TINY_TRAIN, tiny_session

from bodymetry.estimation.pipeline import ProcessConfig, fit_frame, process_session, summarize
from bodymetry.estimation.training import DiscriminativeModels


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    base = tmp_path_factory.mktemp("pipeline")
    session = tiny_session(base / "session", seed=2)
    out = base / "run"
    return session, out, _process(session, out, base), base


def _process(session, out, base) -> dict:
    return process_session(
        session.folder,
        out,
        # The tiny models and 240x180 images fit less tightly than the real
        # setting; the quality gate has its own test.
        ProcessConfig(quality="fast", min_iou=0.5),
        workers=1,
        cache_dir=base / "cache",
        train_config=TINY_TRAIN,
    )


def test_results_schema(run):
    _, out, results, _ = run
    on_disk = json.loads((out / "results.json").read_text())
    assert on_disk["summary"] == results["summary"]
    for key in ("session", "config", "frames", "summary", "ground_truth", "timing_seconds"):
        assert key in results
    assert [f["frame"] for f in results["frames"]] == [0, 2, 4]
    for f in results["frames"]:
        assert f["status"] == "ok", f["status"]
        for stage in ("discriminative", "generative"):
            for key in ("height_mm", "arm_span_mm", "weight_kg"):
                assert np.isfinite(f[stage][key])
            assert len(f[stage]["state"]["theta"]) == 37
        assert set(f["silhouette_iou"]) <= {"cam_00", "cam_01"}
    for stage in ("discriminative", "generative"):
        assert results["summary"][stage]["height_mm"]["n"] == 3
    assert 1300 < results["ground_truth"]["height_mm"] < 2200


def test_frame_artifacts(run):
    """Every fitted frame leaves its mesh (PLY) and its last particles (npz)."""
    import trimesh

    from bodymetry.fileio import load_npz

    _, out, results, _ = run
    for f in results["frames"]:
        mesh = trimesh.load(out / "meshes" / f"{f['frame']:06d}.ply", process=False)
        assert mesh.is_watertight
        assert 1.0 < np.ptp(mesh.vertices[:, 2]) < 2.3
        arrays = load_npz(out / "frames" / f"{f['frame']:06d}.npz")
        assert arrays["particles"].shape[0] == arrays["weights"].shape[0]
        assert abs(float(arrays["weights"].sum()) - 1.0) < 1e-4
        state = np.r_[f["generative"]["state"]["tau"], f["generative"]["state"]["theta"]]
        np.testing.assert_allclose(arrays["state"][:40], state, atol=1e-9)


def test_resume_does_not_refit(run, monkeypatch):
    session, out, results, base = run
    import bodymetry.estimation.pipeline as pipeline

    def boom(*args, **kwargs):
        raise AssertionError("a finished frame was fitted again")

    monkeypatch.setattr(pipeline, "_fit_worker", boom)
    again = _process(session, out, base)
    assert again["summary"] == results["summary"]
    assert again["config"]["models_reused"]


def test_frame_without_silhouette_is_marked_and_excluded(run):
    session, _, results, base = run
    models = DiscriminativeModels.load(next((base / "cache" / "discriminative").glob("*.npz")))
    cams = list(session.calibration())
    empty = np.zeros((2, 180, 240), bool)
    record = fit_frame(
        7, empty, [["empty"], ["empty"]], cams, models, ProcessConfig(quality="fast")
    )
    assert record["status"] == "no silhouette in any camera"
    summary = summarize([*results["frames"], record])
    assert summary["generative"]["height_mm"]["n"] == 3


def test_poor_fit_is_marked_kept_and_excluded(run):
    """Below the IoU gate a frame keeps its numbers but leaves the summary."""
    from bodymetry.capture.silhouette import segment_session

    session, _, results, base = run
    models = DiscriminativeModels.load(next((base / "cache" / "discriminative").glob("*.npz")))
    sil = next(iter(segment_session(session, keep_images=False)))
    cams = list(session.calibration())
    flags = [list(f) for f in sil.flags]
    strict = fit_frame(
        sil.frame, sil.stack(), flags, cams, models, ProcessConfig("fast", min_iou=1.0)
    )
    assert strict["status"].startswith("poor fit: mean silhouette IoU")
    assert np.isfinite(strict["generative"]["height_mm"])
    mean_iou = np.mean(list(strict["silhouette_iou"].values()))
    assert 0.5 < mean_iou < 1.0
    summary = summarize([*results["frames"][1:], strict])
    assert summary["generative"]["height_mm"]["n"] == 2


def test_refinement_improves_on_the_annealing(run):
    """The contour refinement lowers its cost from where the annealing left off."""
    _, _, results, _ = run
    for f in results["frames"]:
        r = f["refinement"]
        assert r["cost_px2"] <= r["initial_cost_px2"]
        assert r["start"] in ("annealing mean", "best particle") or r["start"].startswith(
            "discriminative cam_"
        )


def test_unknown_quality_is_refused(run):
    session, out, _, _ = run
    with pytest.raises(ValueError, match="quality"):
        process_session(session.folder, out, ProcessConfig(quality="ultra"))


def test_session_without_calibration_is_calibrated_from_its_clips(run, tmp_path, monkeypatch):
    import dataclasses

    import bodymetry.calibration.session_calibration as sc
    from bodymetry.estimation.pipeline import _session_cameras

    session = run[0]
    truth = session.calibration()
    uncalibrated = dataclasses.replace(session, calibration_file=None)
    calls = []

    class Solved:
        cameras = truth

        def __init__(self):
            self.world = {"frame": "floor board"}

        def report(self):
            return {"rms_px": 0.2}

        def quality(self):
            return {}

    def fake_calibrate(sess, **kwargs):
        calls.append(sess.folder)
        return Solved(), []

    monkeypatch.setattr(sc, "calibrate_session", fake_calibrate)
    cams = _session_cameras(uncalibrated, tmp_path)
    assert [c.name for c in cams] == list(session.camera_names) and len(calls) == 1
    assert (tmp_path / "calibration.yaml").is_file()
    assert (tmp_path / "calibration-report.json").is_file()
    # A resumed run reuses the solved file instead of solving again.
    again = _session_cameras(uncalibrated, tmp_path)
    assert len(calls) == 1
    np.testing.assert_allclose(again[0].K, cams[0].K)


def test_evaluate_writes_the_figure_3_table(run):
    from bodymetry.estimation.evaluation import evaluate_run

    _, out, results, _ = run
    ev = evaluate_run(out, workers=1)
    assert json.loads((out / "evaluation.json").read_text()) == ev
    assert ev["frames"] == 3 and ev["frames_failed"] == 0
    for key in ("height_mm", "arm_span_mm", "weight_kg"):
        row = ev["table"][key]
        assert row["actual"] == results["ground_truth"][key]
        assert row["disc_generative"]["mean"] == pytest.approx(
            results["summary"]["generative"][key]["mean"]
        )
        assert row["gt_generative"]["n"] == 3
    # Started from the true pose, the fit's joints are closer to the truth than the
    # discriminative guess.
    assert ev["mpjpe_mm"]["gt_generative"] < ev["mpjpe_mm"]["discriminative"]


def test_evaluate_needs_a_run(tmp_path):
    from bodymetry.errors import InputError
    from bodymetry.estimation.evaluation import evaluate_run

    with pytest.raises(InputError, match=r"results\.json"):
        evaluate_run(tmp_path)
