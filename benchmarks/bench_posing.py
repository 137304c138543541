"""Our posing against the studio's skinning (issue 33): ``python -m benchmarks posing``.

The studio renders its independent bodies posed by its skinning (dual quaternions
since 2026-12-07, linear blending before; ``estimation/body_model/skinning.py``) with their
own joints (:class:`~bodymetry.studio.independent.IndependentSubject`); the fit
explains those silhouettes with our SCAPE model posed by its own rule (part
rotations, the learned pose deformation Q, the anchored vertex solve). Where the two
posings part, the fit bends the shape to make up for it, and the canonical body it
measures is off by that much (docs/biometrics.md, "Where her body and ours part").

Each edge body of the studio (``studio/data/edge_bodies.npz``, the same topology as
our mesh) is projected onto the first k shape components
(:meth:`BodyModel.shape_from_vertices`), then posed both ways at the same τ = 0 and
θ: at rest (θ = 0) and at the frames of a library motion (:data:`MOTIONS`, every
:data:`STEP`-th frame). Per region (:data:`REGIONS`), the mean distance between
corresponding vertices after aligning the trunks' centroids, at rest and the median
over the posed frames; and the spacing of the two upper arms' centroids, ours less
the studio's. The rest figure is the shape space's reach; what posing adds on top of
it is the posing's own mismatch. Volumes: our posed body's over our rest body's and
the studio's posed over its rest (medians over the frames).

The result's ``markdown`` is the table quoted in docs/biometrics.md.
"""

from __future__ import annotations

import numpy as np

from bodymetry.estimation.body_model import geometry
from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.body_model.motion.library import make_motion
from bodymetry.estimation.body_model.skeleton import PARTS
from bodymetry.studio.independent import (
    EDGE_KEYS,
    IndependentSpec,
    IndependentSubject,
    committed_edge_bank,
)

#: Numbers of shape components compared (the default and all the model file stores).
COMPONENTS = (12, 20)
#: Library motions whose frames pose the bodies: arms raised overhead and hanging
#: while walking. Seed 0, 400 frames at 60 fps, every :data:`STEP`-th frame.
MOTIONS = ("arm_raises", "walk_turn")
FRAMES = 400
STEP = 25
#: Regions compared, by body part; the trunk is also what the two are aligned by.
REGIONS = {
    "trunk": ("torso", "pelvis"),
    "upper_arms": ("upper_arm_l", "upper_arm_r"),
    "forearms_hands": ("lower_arm_l", "lower_arm_r", "hand_l", "hand_r"),
    "thighs": ("thigh_l", "thigh_r"),
}


def _region_distances(
    ours: np.ndarray, theirs: np.ndarray, vertex_parts: np.ndarray
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Mean vertex distance (B,) per region after aligning the trunks, metres, and the
    upper arms' centroid spacing ours less theirs (B,), metres.

    Parameters
    ----------
    ours, theirs : (B, V, 3) float
        The same bodies posed both ways, corresponding vertices.
    vertex_parts : (V,) int
    """
    select = {
        name: np.isin(vertex_parts, [PARTS.index(p) for p in parts])
        for name, parts in REGIONS.items()
    }
    trunk = select["trunk"]
    shift = ours[:, trunk].mean(axis=1, keepdims=True) - theirs[:, trunk].mean(
        axis=1, keepdims=True
    )
    distances = {
        name: np.linalg.norm(ours[:, sel] - shift - theirs[:, sel], axis=2).mean(axis=1)
        for name, sel in select.items()
    }
    arms = [vertex_parts == PARTS.index(p) for p in ("upper_arm_l", "upper_arm_r")]

    def spacing(v: np.ndarray) -> np.ndarray:
        return np.linalg.norm(v[:, arms[0]].mean(axis=1) - v[:, arms[1]].mean(axis=1), axis=1)

    return distances, spacing(ours) - spacing(theirs)


def compare(model: BodyModel, subject: IndependentSubject, theta: np.ndarray) -> dict:
    """One body posed by our model and by the studio's skinning at rest and at ``theta``.

    Parameters
    ----------
    model : BodyModel
    subject : IndependentSubject
    theta : (F, 37) float
        The posed frames (τ = 0).

    Returns
    -------
    dict
        Per region ``{"rest_mm", "posed_mm"}`` (the median over the frames), the
        upper arms' spacing (``arm_spacing_mm``, the same two), and the volume ratios.
    """
    thetas = np.vstack([np.zeros((1, theta.shape[1])), theta])
    tau = np.zeros((len(thetas), 3))
    nu = model.shape_from_vertices(subject.rest[None])[0]
    shapes = np.repeat(nu[None], len(thetas), axis=0)
    state = BodyState.from_vector(np.column_stack([tau, thetas, shapes]))
    posed = model.pose(state)
    skinned, _, _ = subject.skin(tau, thetas, subject.rest)
    distances, spacing = _region_distances(posed.vertices, skinned, model.vertex_parts)
    ours = geometry.mesh_volume(posed.vertices, posed.faces)
    theirs = geometry.mesh_volume(skinned, subject.bank.faces)
    return {
        **{
            name: {
                "rest_mm": round(1000 * float(d[0]), 1),
                "posed_mm": round(1000 * float(np.median(d[1:])), 1),
            }
            for name, d in distances.items()
        },
        "arm_spacing_mm": {
            "rest_mm": round(1000 * float(spacing[0]), 1),
            "posed_mm": round(1000 * float(np.median(spacing[1:])), 1),
        },
        "volume_posed_over_rest": {
            "ours": round(float(np.median(ours[1:] / ours[0])), 4),
            "studio": round(float(np.median(theirs[1:] / theirs[0])), 4),
        },
        "projection_volume_over_body": round(float(ours[0] / theirs[0]), 4),
    }


def _markdown(rows: list[dict]) -> str:
    lines = [
        "| body | k | motion | trunk | upper arms | forearms + hands | thighs "
        "| upper arms' spacing |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        cells = [
            f"{r[name]['rest_mm']} → {r[name]['posed_mm']}" for name in (*REGIONS, "arm_spacing_mm")
        ]
        head = f"| {r['body']} | {r['components']} | {r['motion']} | "
        lines.append(head + " | ".join(cells) + " |")
    return "\n".join(lines)


def run() -> dict:
    bank = committed_edge_bank()
    rows = []
    for k in COMPONENTS:
        model = BodyModel.load(n_shape=k)
        for key in EDGE_KEYS:
            subject = IndependentSubject(IndependentSpec(seed=0, edge=key), bank=bank, model=model)
            rest = subject.rest_pose_info()
            for motion in MOTIONS:
                theta = make_motion(motion, FRAMES, 60.0, 0, limits=model.limits, rest=rest).theta[
                    ::STEP
                ]
                row = {"body": key, "components": model.n_shape, "motion": motion}
                rows.append({**row, **compare(model, subject, theta)})
    return {
        "setup": (
            f"{len(EDGE_KEYS)} edge bodies projected onto k = {list(COMPONENTS)} components, "
            f"posed at rest and at every {STEP}th of {FRAMES} frames of {list(MOTIONS)} "
            "(seed 0), by our model and by the studio's skinning; mean vertex distance per "
            "region after aligning the trunks, mm (rest → median posed)"
        ),
        "rows": rows,
        "markdown": _markdown(rows),
    }
