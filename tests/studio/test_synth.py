"""The studio's session writer: a tiny session renders, loads and is self-consistent."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from tiny_run import SYNTH_SIZE, SYNTH_TINY

from bodymetry.capture.session import load_session
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.model import DEFAULT_SHAPE_DOFS
from bodymetry.fileio import load_npz
from bodymetry.studio.board_motion import board_trajectory
from bodymetry.studio.rig import studio_rig
from bodymetry.studio.synth import (
    STUDIO_BOARD,
    SubjectSpec,
    SynthConfig,
    synthesize,
)

#: Joints reprojected with calibration.yaml must fall within this many pixels of the silhouette.
JOINT_TO_MASK_PX = 2
SIZE = SYNTH_SIZE
TINY = SYNTH_TINY


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth") / "tiny"
    return synthesize(out, SynthConfig(**TINY), workers=1)


def test_session_loads_with_every_file(session):
    loaded = load_session(session.folder)
    assert loaded.camera_names == ("cam_00", "cam_01")
    assert loaded.frame_step == 2
    for cam in loaded.camera_names:
        for path in (
            loaded.video_path(cam),
            loaded.background_path(cam),
            loaded.calibration_clip_path(cam),
        ):
            assert path.is_file()
    cap = cv2.VideoCapture(str(loaded.video_path("cam_00")))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 6
    ok, frame = cap.read()
    assert ok and frame.shape == (SIZE[1], SIZE[0], 3)


def test_ground_truth_files(session):
    gt = session.folder / "ground_truth"
    subject = json.loads((gt / "subject.json").read_text())
    assert 1300 < subject["height_mm"] < 2200 and 30 < subject["weight_kg"] < 150
    with np.load(gt / "states.npz", allow_pickle=False) as states:
        assert states["theta"].shape == (6, 37) and states["joints"].shape == (6, 15, 3)
        assert states["nu"].shape == (DEFAULT_SHAPE_DOFS,)
    kept = sorted(p.name for p in (gt / "silhouettes" / "cam_01").iterdir())
    assert kept == ["000000.png", "000002.png", "000004.png"]


def test_ground_truth_joints_project_onto_the_rendered_body(session):
    cameras = session.calibration()
    with np.load(session.folder / "ground_truth" / "states.npz", allow_pickle=False) as states:
        joints = states["joints"]
    kernel = np.ones((2 * JOINT_TO_MASK_PX + 1, 2 * JOINT_TO_MASK_PX + 1), np.uint8)
    for frame in (0, 2, 4):
        for cam in cameras:
            mask = cv2.imread(
                str(session.ground_truth_silhouette_path(cam.name, frame)), cv2.IMREAD_GRAYSCALE
            )
            assert mask is not None and mask.any()
            grown = cv2.dilate(mask, kernel) > 0
            px = np.round(cam.project(joints[frame])).astype(int)
            inside = (px[:, 0] >= 0) & (px[:, 0] < SIZE[0]) & (px[:, 1] >= 0) & (px[:, 1] < SIZE[1])
            assert inside.all()
            assert grown[px[:, 1], px[:, 0]].all(), f"{cam.name} frame {frame}"


def test_same_config_same_ground_truth(session, tmp_path):
    config = json.loads((session.folder / "ground_truth" / "studio.json").read_text())["config"]
    assert config["seed"] == 3
    again = synthesize(
        tmp_path / "again",
        SynthConfig(**TINY),
        workers=1,
    )
    a = load_npz(session.folder / "ground_truth" / "states.npz")
    b = load_npz(again.folder / "ground_truth" / "states.npz")
    for key in ("tau", "theta", "joints", "nu"):
        np.testing.assert_array_equal(a[key], b[key])
    m1 = cv2.imread(str(session.ground_truth_silhouette_path("cam_00", 2)))
    m2 = cv2.imread(str(again.ground_truth_silhouette_path("cam_00", 2)))
    np.testing.assert_array_equal(m1, m2)
    # And the clips, byte for byte (libx264's mbtree once made them vary, docs/studio.md).
    clips = sorted(p.relative_to(session.folder) for p in session.folder.rglob("*.mp4"))
    assert clips == sorted(p.relative_to(again.folder) for p in again.folder.rglob("*.mp4"))
    assert clips
    for clip in clips:
        assert (session.folder / clip).read_bytes() == (again.folder / clip).read_bytes(), clip


def test_refuses_to_overwrite(session):
    with pytest.raises(InputError, match="not empty"):
        synthesize(session.folder, SynthConfig(frames=2, cameras=1, size=SIZE), workers=1)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"frames": 0}, "--frames"),
        ({"motion": "moonwalk"}, "--motion"),
        ({"size": (641, 480)}, "--size"),
        ({"cameras": 0}, "--cameras"),
        ({"frame_step": 0}, "--frame-step"),
    ],
)
def test_config_validation(kwargs, message):
    with pytest.raises(InputError, match=message):
        SynthConfig(**kwargs)


@pytest.mark.parametrize("text", ["nu:a,b", "height:3", "seed:x", "nu:"])
def test_subject_parse_errors(text):
    with pytest.raises(InputError, match="--subject"):
        SubjectSpec.parse(text, 0)


def test_subject_parse():
    assert SubjectSpec.parse(None, 4).seed == 4
    assert SubjectSpec.parse("heldout:7", 0).heldout_index == 7
    assert SubjectSpec.parse("nu:1,-0.5", 0).nu == (1.0, -0.5)


def test_board_trajectory_starts_flat_on_the_floor_then_faces_the_cameras():
    rng = np.random.default_rng(0)
    cams = studio_rig(4, (640, 480), seed=0)
    poses = board_trajectory(300, 60.0, rng, STUDIO_BOARD, cams)
    R = poses[:, :3, :3]
    np.testing.assert_allclose(
        np.einsum("nij,nkj->nik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-9
    )
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-9)
    # Floor: printed side (-z of the board) up, pattern origin at the world origin.
    np.testing.assert_allclose(poses[:60, :3, 2], [[0.0, 0.0, -1.0]] * 60, atol=1e-12)
    np.testing.assert_allclose(poses[:60, :3, 3], 0.0, atol=1e-12)
    # Afterwards the printed side faces the cameras and the board stays within reach.
    centre = poses[60:, :3, 3] + np.einsum("nij,j->ni", R[60:], [0.5, 0.4, 0.0])
    assert np.all((centre[:, 2] > 0.5) & (centre[:, 2] < 2.25))
    centers = np.stack([c.center for c in cams])
    facing = -R[60:, :, 2]
    to_cams = centers[None] - centre[:, None]
    cos = np.einsum("nd,ncd->nc", facing, to_cams) / np.linalg.norm(to_cams, axis=-1)
    # Within 60 deg of some camera almost always (turns between cameras pass further).
    assert np.mean(cos.max(axis=1) > 0.5) > 0.9 and np.all(cos.max(axis=1) > 0.0)
    # Every camera sees board corners close to each of its four image corners.
    corners = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.8, 0.0], [1.0, 0.8, 0.0]])
    for cam in cams:
        world = np.einsum("nij,kj->nki", R[60:], corners) + poses[60:, None, :3, 3]
        uv = cam.project(world.reshape(-1, 3))
        w, h = cam.size
        for cx, cy in [(0, 0), (w, 0), (0, h), (w, h)]:
            assert np.nanmin(np.linalg.norm(uv - [cx, cy], axis=1)) < 0.25 * h, (cam.name, cx, cy)


def test_rig_seed_keeps_the_cameras_and_changes_the_rest(session, tmp_path):
    """Sessions of one lab: --rig-seed fixes the cameras, --seed the subject and motion."""
    other = synthesize(
        tmp_path / "other", SynthConfig(**{**TINY, "seed": 4, "rig_seed": 3}), workers=1
    )
    assert (other.folder / "calibration.yaml").read_text() == (
        session.folder / "calibration.yaml"
    ).read_text()
    a = load_npz(session.folder / "ground_truth" / "states.npz")
    b = load_npz(other.folder / "ground_truth" / "states.npz")
    assert not np.allclose(a["theta"], b["theta"])
    config = json.loads((other.folder / "ground_truth" / "studio.json").read_text())["config"]
    assert config["rig_seed"] == 3 and config["seed"] == 4
