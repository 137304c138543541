"""``recording.rrd`` read back with Rerun's own tooling (rerun.chunk and the rerun CLI)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import rerun.chunk as rc

from bodymetry.estimation.fit import shared_body_model
from bodymetry.review.rerun_recording import RerunWriter, camera_to_world
from bodymetry.review.run_data import FrameView, load_run


@pytest.fixture(scope="module")
def store(review_run):
    return rc.RrdReader(review_run.folder / "recording.rrd").store()


@pytest.fixture(scope="module")
def chunks(store):
    return store.stream().to_chunks()


def test_entity_paths_follow_the_design_layout(review_run, store):
    paths = set(store.schema().entity_paths())
    cams = review_run.results.session.cameras
    expected = {
        "/world",
        "/world/rig",
        "/world/body/mesh",
        "/world/body/skeleton",
        "/world/body/keypoints",
        "/world/body/particles",
        "/metrics/biometrics/height_mm/discriminative",
        "/metrics/biometrics/height_mm/generative",
        "/metrics/biometrics/height_mm/session",
        "/world/session/mesh",
        "/metrics/biometrics/height_mm/actual",
        "/metrics/biometrics/weight_kg/generative",
        "/metrics/likelihood/layer_00",
        "/metrics/particle_std/tau_x_mm",
    }
    for cam in cams:
        base = f"/world/rig/{cam}"
        expected |= {base, f"{base}/image", f"{base}/observed", f"{base}/model"}
        expected.add(f"/metrics/silhouette_iou/{cam}")
    assert expected <= paths, sorted(expected - paths)


def test_every_kept_frame_is_on_the_frame_timeline(review_run, chunks):
    frames = set()
    for chunk in chunks:
        if "frame" in chunk.timeline_names:
            frames.update(chunk.to_record_batch().column("frame").to_pylist())
    assert sorted(frames) == [f.frame for f in review_run.results.frames]


def test_mesh_topology_is_static_and_positions_per_frame(review_run, chunks):
    mesh = [c for c in chunks if c.entity_path == "/world/body/mesh"]
    static = [c for c in mesh if c.is_static]
    assert len(static) == 1
    assert "Mesh3D:triangle_indices" in static[0].to_record_batch().schema.names
    rows = sum(
        c.num_rows
        for c in mesh
        if not c.is_static and "Mesh3D:vertex_positions" in c.to_record_batch().schema.names
    )
    assert rows == len(review_run.results.frames)


def test_images_are_jpeg(review_run, chunks):
    cam = review_run.results.session.cameras[0]
    images = [c for c in chunks if c.entity_path == f"/world/rig/{cam}/image"]
    batch = images[0].to_record_batch()
    media = [n for n in batch.schema.names if n.endswith("media_type")]
    assert batch.column(media[0]).to_pylist()[0] == ["image/jpeg"]


def test_camera_transform_is_camera_to_world(review_run, chunks):
    cam = review_run.session.calibration()[0]
    batches = [
        c.to_record_batch()
        for c in chunks
        if c.entity_path == f"/world/rig/{cam.name}" and c.is_static
    ]
    batch = next(b for b in batches if "Transform3D:translation" in b.schema.names)
    translation = batch.column("Transform3D:translation").to_pylist()[0][0]
    np.testing.assert_allclose(np.asarray(translation), cam.center, atol=1e-5)
    rotation = np.asarray(batch.column("Transform3D:mat3x3").to_pylist()[0][0])
    # Rerun stores 3x3 matrices column-major.
    np.testing.assert_allclose(rotation.reshape(3, 3).T, cam.R.T, atol=1e-6)
    assert any("Pinhole:image_from_camera" in b.schema.names for b in batches)


def test_the_file_has_a_blueprint(review_run):
    assert rc.RrdReader(review_run.folder / "recording.rrd").blueprints()


def test_rerun_cli_verifies_the_file(review_run):
    exe = Path(sys.executable).with_name("rerun")
    rerun = str(exe) if exe.is_file() else shutil.which("rerun")
    if rerun is None:
        pytest.skip("the rerun executable of rerun-sdk is not installed")
    done = subprocess.run(
        [rerun, "rrd", "verify", str(review_run.folder / "recording.rrd")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr


def test_improper_camera_rotation_is_refused():
    flip = np.diag([1.0, 1.0, -1.0])
    cam = SimpleNamespace(name="cam_x", R=flip, center=np.zeros(3))
    with pytest.raises(ValueError, match="det"):
        camera_to_world(cam)


def test_capture_view_agreement_is_a_metric_per_view(review_run, tmp_path):
    """Each judged view's agreement is plotted under /metrics/views/<cam>/agreement, also
    for a frame without a fit (capture's verdict does not depend on the fit)."""
    folder = tmp_path / "run"
    folder.mkdir()
    for name in ("results.json", "calibration.yaml"):
        shutil.copy(review_run.folder / name, folder / name)
    data = json.loads((folder / "results.json").read_text())
    first = data["persons"][0]["frames"][0]
    first.update(
        status="no silhouette in any camera",
        view_agreement={"cam_01": 0.58},
        persons=2,
        outline_contrast=1.25,
    )
    for stage in ("discriminative", "generative", "session"):
        first.pop(stage, None)
    (folder / "results.json").write_text(json.dumps(data))
    run = load_run(folder)
    path = tmp_path / "agreement.rrd"
    writer = RerunWriter(path, run, shared_body_model())
    writer.add(FrameView(run.frames[0]))
    writer.close()
    store = rc.RrdReader(path).store()
    paths = set(store.schema().entity_paths())
    assert "/metrics/views/cam_01/agreement" in paths
    assert "/metrics/views/cam_00/agreement" not in paths  # not judged: no point
    values = [
        v
        for chunk in store.stream().to_chunks()
        if chunk.entity_path == "/metrics/views/cam_01/agreement"
        for v in chunk.to_record_batch().column("Scalars:scalars").to_pylist()
    ]
    assert np.ravel(values).tolist() == pytest.approx([0.58])
    # Capture's person count is a series of its own.
    people = [
        v
        for chunk in store.stream().to_chunks()
        if chunk.entity_path == "/metrics/persons"
        for v in chunk.to_record_batch().column("Scalars:scalars").to_pylist()
    ]
    assert np.ravel(people).tolist() == [2.0]
    # So is its outline contrast, beside the views' agreement.
    contrast = [
        v
        for chunk in store.stream().to_chunks()
        if chunk.entity_path == "/metrics/views/outline_contrast"
        for v in chunk.to_record_batch().column("Scalars:scalars").to_pylist()
    ]
    assert np.ravel(contrast).tolist() == pytest.approx([1.25])
