"""Body measurements on the canonical (unposed, standing) body of a shape ν.

Every definition is written out in ``docs/biometrics.md``. In short, for the
canonical body (rest pose, lowest point on the floor z = 0):

* height: floor to the top of the head (highest vertex);
* arm span: knuckle to knuckle (middle-finger knuckles) with the body posed in a
  T-pose (paper footnote 3);
* weight: enclosed volume times density (1000 kg/m^3 by default, as the paper);
* chest, waist, hip circumference: tape-measure girths (convex hull of a
  horizontal section) of the torso / torso + pelvis / pelvis + thighs, at the
  level where each is largest (chest, hip) or smallest (waist);
* shoulder breadth: between the two acromion landmarks (biacromial);
* inseam: floor to crotch;
* arm length: acromion to elbow plus elbow to wrist, mean of both sides.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from bodymetry.estimation.body_model import geometry
from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.body_model.skeleton import JOINTS, PARTS

#: Density of the body, kg/m^3 (paper: water).
DEFAULT_DENSITY = 1000.0
#: Vertical step of the girth searches, metres.
GIRTH_STEP = 0.005


@dataclass(frozen=True)
class Biometrics:
    """Measurements of one body (reports use millimetres and kilograms).

    Attributes
    ----------
    height_mm, arm_span_mm : float
    weight_kg : float
        ``volume_l`` times density.
    volume_l : float
        Enclosed volume, litres.
    chest_mm, waist_mm, hip_mm : float
        Circumferences.
    shoulder_breadth_mm, inseam_mm, arm_length_mm : float
    bmi : float
        weight / height², kg/m².
    """

    height_mm: float
    arm_span_mm: float
    weight_kg: float
    volume_l: float
    chest_mm: float
    waist_mm: float
    hip_mm: float
    shoulder_breadth_mm: float
    inseam_mm: float
    arm_length_mm: float
    bmi: float

    def to_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}


#: Names and units of the measurements, in report order.
MEASUREMENTS: dict[str, str] = {
    "height_mm": "mm",
    "arm_span_mm": "mm",
    "weight_kg": "kg",
    "volume_l": "l",
    "chest_mm": "mm",
    "waist_mm": "mm",
    "hip_mm": "mm",
    "shoulder_breadth_mm": "mm",
    "inseam_mm": "mm",
    "arm_length_mm": "mm",
    "bmi": "kg/m²",
}


def _girth_extreme(
    vertices: np.ndarray,
    faces: np.ndarray,
    mask: np.ndarray,
    z_lo: float,
    z_hi: float,
    largest: bool,
) -> float:
    levels = np.arange(z_lo, z_hi + 1e-9, GIRTH_STEP)
    if len(levels) == 0:
        return float("nan")
    # Only faces reaching into the band can be cut at one of its levels (a face
    # is cut at z when min z < z <= max z, geometry.plane_section): the same
    # sections, in the same order, from a fraction of the faces.
    selected = faces[mask]
    corners = vertices[selected, 2]
    selected = selected[(corners.max(axis=1) >= levels[0]) & (corners.min(axis=1) < levels[-1])]
    girths = np.array([geometry.girth(vertices, selected, level) for level in levels])
    girths = girths[girths > 0]
    if len(girths) == 0:
        return float("nan")
    return float(girths.max() if largest else girths.min())


def body_mass_index(weight_kg: float, height_mm: float) -> float:
    """Weight over height squared, kg/m² (the ``bmi`` of :class:`Biometrics`)."""
    return weight_kg / (height_mm / 1000.0) ** 2


def measure(model: BodyModel, nu: np.ndarray, density: float = DEFAULT_DENSITY) -> list[Biometrics]:
    """Measure the canonical bodies of a batch of shapes.

    Parameters
    ----------
    model : BodyModel
    nu : (B, n_shape) or (n_shape,) float
    density : float
        kg/m^3; must be positive.

    Returns
    -------
    list of Biometrics, one per shape.

    Raises
    ------
    ValueError
        For a density that is not positive (:func:`measure_canonical` checks it).
    """
    nu = np.atleast_2d(np.asarray(nu, dtype=float))
    # Arm span in a T-pose; the root's height does not matter for a distance.
    tpose = BodyState(np.zeros(3), model.poses["tpose"][None], nu)
    tposed = model.pose(tpose).keypoints
    names = model.keypoint_names
    span = np.linalg.norm(
        tposed[:, names.index("knuckle_l")] - tposed[:, names.index("knuckle_r")], axis=-1
    )
    return measure_canonical(
        model, model.canonical_vertices(nu), model.rest_keypoints(nu), span, density
    )


def measure_canonical(
    model: BodyModel,
    vertices: np.ndarray,
    keypoints: np.ndarray,
    arm_span: np.ndarray,
    density: float = DEFAULT_DENSITY,
) -> list[Biometrics]:
    """Measure canonical bodies given as full meshes (the definitions of :func:`measure`).

    Any body in correspondence with the model's full mesh can be measured, e.g.
    the studio's independent bodies, which are not of the model's shape space.

    Parameters
    ----------
    model : BodyModel
        Gives the triangles, their parts and the landmark vertices.
    vertices : (B, V, 3) float
        Rest-pose bodies, lowest point on z = 0, metres.
    keypoints : (B, K, 3) float
        Their joint centres (order of ``model.keypoint_names``; only the joints are used).
    arm_span : (B,) float
        Knuckle-to-knuckle distance in the T-pose, metres (the pose is the caller's).
    density : float
        kg/m^3; must be positive.

    Returns
    -------
    list of Biometrics, one per body.
    """
    if not density > 0:
        raise ValueError(f"density: expected a positive value in kg/m^3, got {density}")
    verts = np.asarray(vertices, dtype=float)
    kp = np.asarray(keypoints, dtype=float)
    if verts.ndim == 2:
        verts, kp = verts[None], kp[None]
    span = np.atleast_1d(np.asarray(arm_span, dtype=float))
    if verts.shape[1:] != (model.full.n_vertices, 3) or len(kp) != len(verts):
        raise ValueError(
            f"vertices: expected (B, {model.full.n_vertices}, 3) with B keypoint sets, "
            f"got {verts.shape} and {kp.shape}"
        )
    faces = model.faces()
    regions = _girth_regions(model)
    volume = np.atleast_1d(geometry.mesh_volume(verts, faces))
    return [
        _measure_one(model, faces, regions, verts[b], kp[b], span[b], volume[b], density)
        for b in range(len(verts))
    ]


def _girth_regions(model: BodyModel) -> dict[str, np.ndarray]:
    """The triangles (T,) bool of the full mesh each girth is searched on: the
    chest on the torso, the waist on the trunk (torso and pelvis), the hips on
    the pelvis and thighs."""
    parts = model.full.arrays.parts
    torso = parts == PARTS.index("torso")
    return {
        "chest": torso,
        "waist": torso | (parts == PARTS.index("pelvis")),
        "hip": np.isin(parts, [PARTS.index(p) for p in ("pelvis", "thigh_l", "thigh_r")]),
    }


def _measure_one(
    model: BodyModel,
    faces: np.ndarray,
    regions: dict[str, np.ndarray],
    v: np.ndarray,
    k: np.ndarray,
    span: float,
    volume: float,
    density: float,
) -> Biometrics:
    """:func:`measure_canonical` of one body: vertices ``v`` (V, 3), joint centres
    ``k`` (K, 3), arm span and volume (m, m^3)."""
    lm = model.landmarks
    z = {j: k[JOINTS.index(j), 2] for j in ("hip_l", "spine", "shoulder_l")}
    crotch = v[lm["crotch"], 2]
    chest = _girth_extreme(
        v, faces, regions["chest"], z["shoulder_l"] - 0.25, z["shoulder_l"] - 0.08, True
    )
    waist = _girth_extreme(
        v, faces, regions["waist"], z["hip_l"] + 0.08, z["shoulder_l"] - 0.2, False
    )
    hip = _girth_extreme(v, faces, regions["hip"], crotch + 0.02, z["hip_l"] + 0.1, True)
    arm = np.mean(
        [
            np.linalg.norm(v[lm[f"acromion_{s}"]] - k[JOINTS.index(f"elbow_{s}")])
            + np.linalg.norm(k[JOINTS.index(f"elbow_{s}")] - k[JOINTS.index(f"wrist_{s}")])
            for s in "lr"
        ]
    )
    height = v[:, 2].max()
    weight = volume * density
    return Biometrics(
        height_mm=1000.0 * height,
        arm_span_mm=1000.0 * span,
        weight_kg=weight,
        volume_l=1000.0 * volume,
        chest_mm=1000.0 * chest,
        waist_mm=1000.0 * waist,
        hip_mm=1000.0 * hip,
        shoulder_breadth_mm=1000.0 * np.linalg.norm(v[lm["acromion_l"]] - v[lm["acromion_r"]]),
        inseam_mm=1000.0 * crotch,
        arm_length_mm=1000.0 * arm,
        bmi=body_mass_index(weight, 1000.0 * height),
    )
