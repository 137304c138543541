"""Several people in the studio: every person's masks from one z-buffer, the placement of
the others, and a two-person session's per-person ground truth."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bodymetry.calibration.camera import Camera
from bodymetry.capture.ground_truth import StudioRecord, person_folder
from bodymetry.capture.session import load_session
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.body_model.skeleton import PARTS
from bodymetry.studio.bystanders import SHIRTS, TROUSERS
from bodymetry.studio.evaluate import GroundTruth
from bodymetry.studio.independent import IndependentSpec, IndependentSubject
from bodymetry.studio.people import MAX_PEOPLE, MIN_GAP_M, draw_people, dressed
from bodymetry.studio.render import Body, Studio
from bodymetry.studio.rig import look_at, studio_rig
from bodymetry.studio.scene import Appearance
from bodymetry.studio.synth import SynthConfig, _SubjectMotion, synthesize

SIZE = (160, 120)
#: Two persons' posed surfaces never come closer than this (the placement keeps 8 cm
#: between every 7th vertex; the full meshes may come a few centimetres closer).
MIN_SURFACE_GAP_M = 0.03


def _camera(center, size=SIZE) -> Camera:
    R, t = look_at(np.asarray(center, float), np.array([0.0, 0.0, 0.9]))
    f = 0.9 * size[0]
    K = np.array([[f, 0, size[0] / 2], [0, f, size[1] / 2], [0, 0, 1.0]])
    return Camera("cam", size, K, np.zeros(5), R, t)


@pytest.fixture(scope="module")
def scene():
    """The mean body at the origin and one 0.9 m nearer the camera, 0.15 m aside
    (it hides part of the first), and a bystander behind both."""
    model = BodyModel.load()
    state = BodyState(np.zeros((1, 3)), model.poses["apose"][None], np.zeros((1, model.n_shape)))
    v = model.pose(state).vertices[0]
    v[:, 2] -= v[:, 2].min()
    cam = _camera([3.2, 0.4, 1.6])
    toward = cam.center[:2] / np.linalg.norm(cam.center[:2])
    side = np.array([-toward[1], toward[0]])
    front = v + np.r_[0.9 * toward + 0.15 * side, 0.0]
    back = v + np.r_[-1.6 * toward - 0.7 * side, 0.0]
    return model, cam, v, front, back


@pytest.mark.parametrize("supersample", [1, 2])
def test_every_person_gets_their_visible_and_whole_masks(scene, supersample):
    model, cam, v, front, back = scene
    studio = Studio.from_model(model, supersample=supersample)
    other = Body(front, dressed("navy", "khaki"))
    bystander = [Body(back)]
    out = studio.render_people(cam, v, people=[other], others=bystander, effects=False)
    alone = studio.render_frame(cam, v, others=[other, *bystander], effects=False)
    # Person 0 is the subject of render_frame, same image.
    np.testing.assert_array_equal(out.masks[0], alone.person_mask)
    np.testing.assert_array_equal(out.image, alone.image)
    assert out.masks.shape == out.full.shape == (2, SIZE[1], SIZE[0])
    # No pixel belongs to two persons; each visible mask lies in its whole projection.
    assert not np.any(out.masks[0] & out.masks[1])
    assert not np.any(out.masks & ~out.full)
    # The person in front hides part of the subject and is not hidden itself (but for
    # pixels that both cover by half on the supersampled grid: they go to the subject).
    assert out.occluded[0].sum() > 100
    assert out.occluded[1].sum() <= (0 if supersample == 1 else 0.05 * out.full[1].sum())
    if supersample == 1:
        np.testing.assert_array_equal(out.masks[1], out.full[1])
        # Whole projections are the bodies' own rasters, and nothing is lost:
        # visible plus hidden pixels are the union of the whole projections.
        np.testing.assert_array_equal(out.full[0], studio.person_raster(cam, v).mask)
        np.testing.assert_array_equal(out.full[1], studio.person_raster(cam, front).mask)
        np.testing.assert_array_equal(out.masks.any(0) | out.occluded.any(0), out.full.any(0))
        np.testing.assert_array_equal(out.occluded[0], out.full[0] & out.masks[1])


def test_render_people_needs_the_subject(scene):
    model, cam, _, front, _ = scene
    with pytest.raises(ValueError, match="subject"):
        Studio.from_model(model).render_people(cam, None, people=[Body(front)], effects=False)


def test_clothes_come_from_the_palette():
    look = dressed("green", "jeans")
    colors = np.asarray(look.part_colors)
    np.testing.assert_allclose(colors[PARTS.index("torso")], SHIRTS["green"])
    np.testing.assert_allclose(colors[PARTS.index("thigh_l")], TROUSERS["jeans"])
    np.testing.assert_allclose(
        colors[PARTS.index("head")], np.asarray(Appearance().part_colors)[PARTS.index("head")]
    )
    with pytest.raises(InputError, match="shirt"):
        dressed("pink", "jeans")


@pytest.mark.parametrize("people", [0, MAX_PEOPLE + 1, True])
def test_people_out_of_range(people):
    with pytest.raises(InputError, match="--people"):
        SynthConfig(people=people)


def test_person_folder_and_old_studio_records():
    assert str(person_folder("gt", 0)) == "gt"
    assert person_folder("gt", 2).as_posix() == "gt/persons/2"
    with pytest.raises(InputError, match="person index"):
        person_folder("gt", -1)
    assert StudioRecord(config={}).people == 1  # sessions rendered before people


# --- a two-person session -------------------------------------------------------------

CONFIG = {
    "frames": 8,
    "frame_step": 4,
    "cameras": 4,
    "size": SIZE,
    "seed": 0,
    "calibration_frames": 30,
    "background_clip": False,
    "people": 2,
}


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    out = tmp_path_factory.mktemp("people") / "two"
    session = synthesize(out, SynthConfig(**CONFIG), workers=2)
    return load_session(session.folder)


def _posed(session, index: int) -> np.ndarray:
    """(F, V, 3) the rendered vertices of person ``index`` from its ground truth."""
    truth = GroundTruth(session)
    states = truth.person_states(index)
    if index == 0:
        model = BodyModel.load(n_shape=len(states["nu"]))
        return model.pose(BodyState(states["tau"], states["theta"], states["nu"][None])).vertices
    spec = truth.person_truth(index).details["subject"]
    body = IndependentSubject(IndependentSpec.parse(spec.partition(":")[2]))
    return body.pose(states["tau"], states["theta"])[0]


def test_two_person_ground_truth_is_complete_and_consistent(two):
    truth = GroundTruth(two)
    assert truth.persons() == 2
    studio = StudioRecord.read(two.ground_truth_path)
    one = studio.persons[1]
    # Another body than the subject's, in other clothes, crossing it in some camera.
    subject = truth.person_truth(0)
    other = truth.person_truth(1)
    assert other.source == "independent" and subject.source != "independent"
    assert 1300 < other.measurements["height_mm"] < 2200
    assert one["shirt"] in SHIRTS and one["trousers"] in TROUSERS and one["crossings"]
    assert set(one["path"]) == {"start_m", "end_m", "side_m"}
    states = truth.person_states(1)
    assert states["tau"].shape == (8, 3) and states["joints"].shape == (8, 15, 3)
    # Both stand on the floor and never touch.
    posed = [_posed(two, k) for k in (0, 1)]
    for v in posed:
        np.testing.assert_allclose(v[..., 2].min(axis=1), 0.0, atol=0.02)
    for f in range(8):
        gap, _ = cKDTree(posed[0][f]).query(posed[1][f], k=1)
        assert gap.min() > MIN_SURFACE_GAP_M, f"frame {f}: {gap.min():.3f} m"
    # Same configuration, same people.
    text = json.loads((two.ground_truth_path / "studio.json").read_text())
    assert text["config"]["people"] == 2 and text["persons"][1]["body"] == one["body"]


def test_two_person_masks_are_the_visible_projections(two):
    truth = GroundTruth(two)
    cameras = two.calibration()
    studio = Studio.from_model(BodyModel.load())
    posed = [_posed(two, k) for k in (0, 1)]
    hidden = 0
    for frame in (0, 4):
        for cam in cameras:
            visible = [truth.person(cam.name, frame, index=k) for k in (0, 1)]
            occluded = [truth.occluded(cam.name, frame, index=k) for k in (0, 1)]
            whole = [studio.person_raster(cam, posed[k][frame]).mask for k in (0, 1)]
            assert not np.any(visible[0] & visible[1]), (cam.name, frame)
            for k in (0, 1):
                # Visible plus hidden is the whole projection, exactly (no bystanders).
                assert not np.any(visible[k] & occluded[k])
                np.testing.assert_array_equal(visible[k] | occluded[k], whole[k])
                assert not np.any(occluded[k] & ~visible[1 - k])
            hidden += sum(int(o.sum()) for o in occluded)
    assert hidden > 50  # they cross in some camera at a kept frame


def test_subject_reader_is_unchanged(two):
    """person(..., index=0) reads today's files, and a second person has no file in
    ground_truth/silhouettes/."""
    truth = GroundTruth(two)
    path = two.ground_truth_silhouette_path("cam_00", 4)
    assert path.is_file()
    np.testing.assert_array_equal(truth.person("cam_00", 4), truth.person("cam_00", 4, index=0))
    assert truth.person("cam_00", 5, index=1) is None  # not a kept frame
    assert truth.person("cam_00", 4, index=2) is None  # no such person


def test_three_people_keep_clear_in_view_and_cross_the_subject():
    """draw_people on a short clip: distinct bodies and clothes, everyone clear of
    everyone, the subject and person 1 centred on the volume, each crossing the
    subject in some camera; the same seed gives the same people."""
    model = BodyModel.load()
    config = SynthConfig(**{**CONFIG, "people": 3})
    subject = _SubjectMotion.draw(model, config)
    _, _, sparse = subject.truth(model, config.frames)
    cameras = studio_rig(4, SIZE, seed=0)
    args = (model, cameras, subject.motion.tau, sparse, Appearance(), 2, 0)
    people, offset = draw_people(*args, motion="mixed", fps=60.0)
    assert [p.index for p in people] == [1, 2]
    assert people[0].subject.index != people[1].subject.index
    assert (people[0].shirt, people[0].trousers) != (people[1].shirt, people[1].trousers)
    assert all(p.crossings for p in people)
    # Subject and person 1 on either side of the volume centre.
    middle = 0.5 * (
        subject.motion.tau[:, :2].mean(0) + offset + people[0].motion.tau[:, :2].mean(0)
    )
    assert np.linalg.norm(middle) < 0.15
    vertices = [sparse + np.r_[offset, 0.0]] + [p.truth()[2] for p in people]
    for a in range(3):
        for b in range(a + 1, 3):
            for f in range(config.frames):
                gap, _ = cKDTree(vertices[a][f]).query(vertices[b][f], k=1)
                assert gap.min() >= MIN_GAP_M, (a, b, f)
    again, offset_again = draw_people(*args, motion="mixed", fps=60.0)
    np.testing.assert_array_equal(offset, offset_again)
    np.testing.assert_array_equal(people[1].motion.tau, again[1].motion.tau)
