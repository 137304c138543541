"""Independent studio subjects: the committed bank, the skinning, clothing and hair."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bodymetry.errors import InputError
from bodymetry.estimation.body_model import geometry
from bodymetry.estimation.body_model.bake.independent import shape_space_residual
from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.body_model.motion.library import make_motion
from bodymetry.estimation.body_model.skeleton import JOINT_SLICES, JOINTS, N_POSE
from bodymetry.studio.clothing import garment_weight, skirt_layer, skirt_weight
from bodymetry.studio.independent import (
    INDEPENDENT_BODIES_PATH,
    IndependentSpec,
    IndependentSubject,
    committed_bank,
)
from bodymetry.studio.render import Studio
from bodymetry.studio.rig import studio_rig
from bodymetry.studio.synth import SubjectSpec

#: The bank's float16 offsets round bodies to about 0.06 mm; a body of our 9-component
#: shape space would be rebuilt to that. Every bank body must lie further out than this.
NOT_IN_SPAN_MM = 0.3


@pytest.fixture(scope="module")
def model():
    return BodyModel.load()


@pytest.fixture(scope="module")
def loose(model):
    return IndependentSubject(IndependentSpec(4, clothing="loose", hair=True), model=model)


def test_bank_loads_without_pickle_and_is_compact(model):
    assert INDEPENDENT_BODIES_PATH.stat().st_size < 4_000_000
    with np.load(INDEPENDENT_BODIES_PATH, allow_pickle=False) as data:
        assert all(data[k].dtype != object for k in data.files)
        provenance = json.loads(str(data["provenance"]))
    assert provenance["wheel_sha256"] and "CC0" in provenance["licences"]["makehuman_assets"]
    bank = committed_bank()
    assert len(bank) == 48 and bank.vertices.shape[1:] == (model.full.n_vertices, 3)
    np.testing.assert_array_equal(bank.faces, model.faces())
    np.testing.assert_allclose(bank.weights.sum(axis=1), 1.0, atol=1e-6)
    # Canonical frame: lowest vertex on the floor, root joint above the origin.
    np.testing.assert_allclose(bank.vertices[..., 2].min(axis=1), 0.0, atol=1e-3)
    np.testing.assert_allclose(bank.keypoints[:, 0, :2], 0.0, atol=1e-3)


def test_skinning_at_rest_reproduces_the_rest_body(model):
    subject = IndependentSubject(IndependentSpec(0, body=7), model=model)
    tau = np.array([[0.4, -0.3, 1.2]])
    verts, joints, keypoints = subject.skin(tau, np.zeros((1, N_POSE)))
    shift = tau[0] - subject.rest_joints[0]
    np.testing.assert_allclose(verts[0], subject.rest + shift, atol=1e-9)
    np.testing.assert_allclose(joints[0], subject.rest_joints + shift, atol=1e-9)
    np.testing.assert_allclose(keypoints[0], subject.keypoints + shift, atol=1e-9)


def test_measurements_do_not_change_under_rigid_motion(model):
    subject = IndependentSubject(IndependentSpec(0, body=11), model=model)
    bio = subject.biometrics()
    faces = model.faces()
    for yaw, tau in ((0.7, (1.0, 2.0, 0.95)), (-2.5, (-0.3, 0.1, 1.4))):
        theta = np.zeros((1, N_POSE))
        theta[0, JOINT_SLICES[0].start + 2] = yaw
        verts = subject.skin(np.array([tau]), theta)[0][0]
        height = verts[:, 2].max() - verts[:, 2].min()
        # (the rest body lies on the floor to the float16 round-off of the bank)
        assert 1000.0 * height == pytest.approx(bio.height_mm, abs=1e-3)
        assert 1000.0 * geometry.mesh_volume(verts, faces) == pytest.approx(bio.volume_l, rel=1e-7)
        tpose = subject.bank.tpose[subject.index][None].copy()
        tpose[0, JOINT_SLICES[0].start + 2] = yaw
        kp = subject.skin(np.array([tau]), tpose)[2][0]
        names = subject.bank.keypoint_names
        span = np.linalg.norm(kp[names.index("knuckle_l")] - kp[names.index("knuckle_r")])
        assert 1000.0 * span == pytest.approx(bio.arm_span_mm, abs=1e-6)
    # The T-pose arm span is about 0.9 x height (docs/biometrics.md).
    assert 0.85 < bio.arm_span_mm / bio.height_mm < 0.97


def test_bank_bodies_are_outside_our_shape_space(model):
    bank = committed_bank()
    residual_mm = 1000.0 * shape_space_residual(model, bank.vertices[:12])
    assert residual_mm.min() > NOT_IN_SPAN_MM, residual_mm
    # A body of the shape space itself is rebuilt to round-off.
    own = model.canonical_vertices(model.prior_shapes("heldout")[:2])
    assert 1000.0 * shape_space_residual(model, own).max() < 0.05


def test_loose_clothing_contains_the_body_and_hides_its_outline(model, loose):
    theta = np.zeros((1, N_POSE))
    theta[0, JOINT_SLICES[JOINTS.index("shoulder_l")].start + 1] = -2.0  # left arm overhead
    theta[0, JOINT_SLICES[JOINTS.index("hip_r")].start] = -0.6
    tau = np.array([[0.0, 0.0, 0.95]])
    nude = loose.skin(tau, theta)[0][0]
    clothed = loose.pose(tau, theta)[0][0]
    studio = Studio.from_model(model)
    for camera in studio_rig(2, (320, 240), seed=5):
        a = studio.person_raster(camera, nude).mask
        b = studio.person_raster(camera, clothed).mask
        assert np.count_nonzero(a & ~b) <= 0.002 * np.count_nonzero(a)
        assert np.count_nonzero(b) > 1.04 * np.count_nonzero(a)
    # The cloth stands 1-3 cm off the covered skin for most of it, more over the waist.
    covered = garment_weight(loose.rest, model.vertex_parts, loose.rest_joints) == 1.0
    gap_mm = 1000.0 * np.linalg.norm(loose.surface - loose.rest, axis=1)[covered]
    assert 10.0 < np.median(gap_mm) < 30.0 and gap_mm.max() <= 60.0
    bare = np.isin(model.vertex_parts, [model.parts.index(p) for p in ("hand_l", "foot_r")])
    np.testing.assert_array_equal(loose.surface[bare], loose.rest[bare])


def test_draped_clothing_rests_on_the_shoulders_and_hangs_like_loose_elsewhere(model, loose):
    draped = IndependentSubject(IndependentSpec(4, clothing="draped", hair=True), model=model)
    covered = garment_weight(loose.rest, model.vertex_parts, loose.rest_joints) == 1.0
    normals = geometry.vertex_normals(loose.rest, model.faces())
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    gap = np.linalg.norm(draped.surface - draped.rest, axis=1)
    loose_gap = np.linalg.norm(loose.surface - loose.rest, axis=1)
    up, side = covered & (normals[:, 2] > 0.6), covered & (np.abs(normals[:, 2]) < 0.2)
    assert up.sum() > 50 and side.sum() > 500
    # Where the body faces up the cloth lies on it; where it faces sideways it hangs
    # as the loose garments do (the same body, the same layer).
    assert gap[up].max() < 1e-9 < loose_gap[up].min()
    np.testing.assert_allclose(gap[side], loose_gap[side], atol=1e-4)
    assert np.all(gap <= loose_gap + 1e-9)
    assert draped.biometrics() == loose.biometrics()  # the truth is the nude body


def test_ease_sets_how_far_the_garments_stand_off(model, loose):
    covered = garment_weight(loose.rest, model.vertex_parts, loose.rest_joints) == 1.0
    looser = IndependentSubject(IndependentSpec(4, clothing="loose", ease=35), model=model)
    gap = np.linalg.norm(looser.surface - looser.rest, axis=1)[covered]
    default = np.linalg.norm(loose.surface - loose.rest, axis=1)[covered]
    # 15 mm by default, 35 mm asked: the median gap grows by about the difference.
    assert 0.015 < np.median(gap) - np.median(default) < 0.025
    assert gap.max() <= 0.06 + 1e-9  # the layer's cap
    assert looser.biometrics() == loose.biometrics()


def test_shorts_are_tight_with_the_shins_bare(model, loose):
    tight = IndependentSubject(IndependentSpec(4), model=model)
    shorts = IndependentSubject(IndependentSpec(4, clothing="shorts"), model=model)
    # No garment layer: the rendered surface is the body's own, as in tight clothing.
    np.testing.assert_array_equal(shorts.surface, tight.surface)
    assert shorts.biometrics() == tight.biometrics()
    colors = np.asarray(shorts.appearance().part_colors)
    suit = np.asarray(tight.appearance().part_colors)
    skin = colors[model.parts.index("head")]
    for part in model.parts:
        expected = skin if part.startswith("shin_") else suit[model.parts.index(part)]
        np.testing.assert_array_equal(colors[model.parts.index(part)], expected, err_msg=part)
    # The loose shorts leave the same shins bare.
    np.testing.assert_array_equal(np.asarray(loose.appearance().part_colors), colors)
    spec = SubjectSpec.parse("independent:12,clothing=shorts", 0).independent
    assert IndependentSpec.parse(spec.to_text().partition(":")[2]) == spec


@pytest.mark.parametrize("outfit", ["skirt", "dress", "long_skirt"])
def test_skirt_closes_between_the_legs_and_contains_the_body(model, outfit):
    skirt = IndependentSubject(IndependentSpec(4, clothing=outfit), model=model)
    tight = IndependentSubject(IndependentSpec(4), model=model)
    assert skirt.biometrics() == tight.biometrics()  # the truth is the nude body
    studio = Studio.from_model(model)
    tau = np.array([[0.0, 0.0, 0.95]])
    for pose in ("standing", "stride"):
        theta = np.zeros((1, N_POSE))
        if pose == "stride":  # one thigh forward, the other back
            theta[0, JOINT_SLICES[JOINTS.index("hip_l")].start] = -0.4
            theta[0, JOINT_SLICES[JOINTS.index("hip_r")].start] = 0.3
        nude = skirt.skin(tau, theta)[0][0]
        clothed = skirt.pose(tau, theta)[0][0]
        # Between the thighs, 70 % of the way from the hips to the knees: the
        # segment across both thighs' axes at that height, in the world.
        posed_joints = skirt.skin(tau, theta)[1][0]
        ends = []
        for side in "lr":
            hip = posed_joints[JOINTS.index(f"hip_{side}")]
            ends.append(hip + 0.7 * (posed_joints[JOINTS.index(f"knee_{side}")] - hip))
        across = np.linspace(ends[0], ends[1], 50)
        legs_apart = 0
        for camera in studio_rig(4, (320, 240), seed=5):
            a = studio.person_raster(camera, nude).mask
            b = studio.person_raster(camera, clothed).mask
            assert np.count_nonzero(a & ~b) <= 0.003 * np.count_nonzero(a), pose
            assert np.count_nonzero(b) > 1.05 * np.count_nonzero(a), pose
            uv = np.round(camera.project(across)).astype(int)
            # The skirt is one piece across the legs in every view ...
            assert b[uv[:, 1], uv[:, 0]].all(), (pose, camera.name)
            legs_apart += not a[uv[:, 1], uv[:, 0]].all()
        assert legs_apart >= 1, pose  # ... where at least one view sees the legs apart
    layer = skirt_layer(outfit)
    covered = skirt_weight(skirt.rest, model.vertex_parts, skirt.rest_joints, layer)
    # Below the hem the legs are the body's own: the shins below a knee-length skirt
    # (bare), the ankles and feet below the long one (in tights of the skirt's colour).
    long = outfit == "long_skirt"
    shin = model.vertex_parts == model.parts.index("shin_l")
    ankle = skirt.rest_joints[JOINTS.index("ankle_l"), 2]
    knee = skirt.rest_joints[JOINTS.index("knee_l"), 2]
    low = shin & (skirt.rest[:, 2] < ankle + 0.2 * (knee - ankle))
    below = low | np.isin(model.vertex_parts, [model.parts.index("foot_r")])
    if not long:
        below |= shin
    assert covered[below].max() == 0.0
    np.testing.assert_array_equal(skirt.surface[below], skirt.rest[below])
    if long:  # half the shin under the skirt
        assert covered[shin & (skirt.rest[:, 2] > ankle + 0.7 * (knee - ankle))].min() == 1.0
    colors = np.asarray(skirt.appearance().part_colors)
    bare = colors[model.parts.index("head")] if not long else colors[model.parts.index("pelvis")]
    np.testing.assert_array_equal(colors[model.parts.index("shin_l")], bare)
    # Its skin weights follow the pelvis halfway where it covers, the body's elsewhere.
    weights = skirt.surface_weights
    body = skirt.weights.toarray() if hasattr(skirt.weights, "toarray") else skirt.weights
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=1e-9)
    thigh = (model.vertex_parts == model.parts.index("thigh_r")) & (covered == 1.0)
    pelvis = model.parts.index("pelvis")
    np.testing.assert_allclose(weights[thigh, pelvis], 0.5 + 0.5 * body[thigh, pelvis], atol=1e-9)
    np.testing.assert_array_equal(weights[below], body[below])
    spec = SubjectSpec.parse(f"independent:12,clothing={outfit},ease=25", 0).independent
    assert spec == IndependentSpec(12, clothing=outfit, ease=25)
    assert IndependentSpec.parse(spec.to_text().partition(":")[2]) == spec
    # A dress's top is the loose shirt (its trunk stands off the skin as the shirt's
    # does); a skirt's top is tight.
    torso = model.vertex_parts == model.parts.index("torso")
    chest = torso & (skirt.rest[:, 2] > skirt.rest_joints[JOINTS.index("spine"), 2])
    gap_mm = 1000.0 * np.linalg.norm(skirt.surface - skirt.rest, axis=1)[chest]
    if outfit == "dress":
        assert np.median(gap_mm) > 10.0
    else:
        assert gap_mm.max() == 0.0


def test_hair_raises_the_head_but_not_the_measured_height(model, loose):
    assert loose.surface[:, 2].max() > loose.rest[:, 2].max() + 0.015
    assert loose.biometrics().height_mm == pytest.approx(1000.0 * loose.rest[:, 2].max())


def test_subject_texts_parse_with_clear_errors():
    spec = SubjectSpec.parse("independent:12,clothing=loose,hair=1", 0).independent
    assert spec == IndependentSpec(12, clothing="loose", hair=True)
    assert IndependentSpec.parse(spec.to_text().partition(":")[2]) == spec
    draped = SubjectSpec.parse("independent:12,clothing=draped,ease=30", 0).independent
    assert draped.ease == 30
    assert IndependentSpec.parse(draped.to_text().partition(":")[2]) == draped
    assert SubjectSpec.parse("independent:3,body=40", 0).independent.index(48) == 40
    for text, match in (
        ("independent:x", "SEED"),
        ("independent:1,clothing=baggy", "clothing"),
        ("independent:1,hair=yes", "hair"),
        ("independent:1,colour=red", "unknown option"),
        ("independent:1,body=two", "body"),
        ("independent:1,ease=20", "needs clothing=loose, draped, skirt, dress or long_skirt"),
        ("independent:1,clothing=loose,ease=90", "expected 5..50"),
        ("independent:1,clothing=loose,ease=wide", "ease='wide', expected an integer"),
    ):
        with pytest.raises(InputError, match=match):
            SubjectSpec.parse(text, 0)
    with pytest.raises(InputError, match="body=99"):
        IndependentSpec(1, body=99).index(48)
    with pytest.raises(InputError, match="no shape"):
        SubjectSpec.parse("independent:1", 0).resolve(BodyModel.load())


def test_skinning_keeps_the_volume_of_a_heavy_body_with_its_arms_overhead(model):
    # Linear blend skinning took up to 3 L of the heaviest woman's 104 L in these
    # frames (the shoulders collapse); the studio's dual quaternion skinning keeps
    # her volume within half a litre (docs/studio.md).
    subject = IndependentSubject(IndependentSpec(0, edge="female_weight_p99"), model=model)
    rest = subject.rest_pose_info()
    motion = make_motion("arm_raises", 400, 25.0, 3, limits=model.limits, rest=rest)
    shoulder = JOINT_SLICES[JOINTS.index("shoulder_l")]
    raised = np.argsort(-np.linalg.norm(motion.theta[:, shoulder], axis=1))[:8]
    verts = subject.skin(motion.tau[raised], motion.theta[raised])[0]
    faces = model.faces()
    rest_l = 1000.0 * geometry.mesh_volume(subject.rest, faces)
    change_l = 1000.0 * geometry.mesh_volume(verts, faces) - rest_l
    assert np.abs(change_l).max() < 0.01 * rest_l, change_l
    assert np.linalg.norm(motion.theta[raised[0], shoulder]) > 1.5  # the arms above the shoulders


def test_the_truth_names_the_skinning_and_an_unknown_one_is_refused(model):
    subject = IndependentSubject(IndependentSpec(0, body=7), model=model)
    assert subject.describe()["skinning"] == "dual_quaternion"
    with pytest.raises(ValueError, match="skinning"):
        subject.skin(np.zeros(3), np.zeros((1, N_POSE)), skinning="spline")
