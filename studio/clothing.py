"""A loose shirt, shorts and a hair volume as a displaced copy of the body mesh.

The studio renders a clothed subject as the body mesh itself (same topology)
with each covered vertex displaced outwards; the ground truth stays on the
nude body. The displacement is not a uniform offset:

1. *ease*: every covered vertex moves 1.5 cm out along its rest-pose normal,
   then an outward-only smoothing over the mesh graph fills local hollows
   (where the neighbours' mean lies further out, the cloth follows it);
2. *hang*: below the chest the shirt hangs. In cylindrical coordinates about
   the vertical axis through the root joint, the cloth at a trunk vertex lies
   at least as far out as the cloth above it on the same side, less a drape
   taper (1.5 mm per cm of drop): so it falls from the chest over the hollow
   under it and bridges the waist between chest and hips, and falls from the
   shoulder blades over the small of the back;
3. smooth fold noise (a few millimetres), a light smoothing, a 6 cm cap on
   the gap and a short taper at the hems (sleeves to 80 % of the upper arm,
   shorts to 85 % of the thigh, the collar).

The smoothing follows the mesh graph, not 3D space, and the hang uses trunk
vertices only, so arms and legs are never joined to the trunk.

A skirt (``clothing=skirt``: a tight top and a knee-length A-line skirt, the shins
bare) is no displaced copy of each part: it is one envelope about both legs
(:func:`skirt_offsets`). Below a waistband a little above the hip joints, each
1 cm slab of the skirt reaches, per direction from the root's vertical axis
(left, right, front, back), at least as far out as the body anywhere above it
in the skirt plus a flare (cloth falls from the hips and widens as it drops),
plus the ease. Trunk vertices move out to that envelope along their direction
from the axis. A thigh's outer half (and a long skirt's shin's) maps onto its own
side's half of the envelope and its inner half onto a wall at the midline, so that
the two halves close between the legs. The skirt is posed by skin weights that follow the
pelvis halfway (:func:`garment_skin_weights`): cloth between the knees does not
swing with one leg.

Hair is a cap over the scalp (above the hairline that
:meth:`bodymetry.studio.scene.Appearance.vertex_modulation` paints), up to
2.5 cm thick at the crown, thinning to nothing at the hairline.

Everything is computed once on the rest body (standing, θ = 0) and posed with
it by the same skinning.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np

from bodymetry.estimation.body_model import geometry
from bodymetry.estimation.body_model.skeleton import JOINTS, PARTS

#: Clothing a subject can wear: ``tight`` (no layer: the body's own outline, as a
#: tight suit would show), ``shorts`` (no layer either, with the shins bare: a tight
#: shirt and shorts, as a gait lab's sports kit), ``loose`` (shirt with short sleeves
#: and shorts), ``draped`` (the same garments resting on the body where it faces
#: up: the shoulders and the top of the chest, as worn cloth does), ``skirt`` (a
#: tight top and a knee-length A-line skirt over both legs, the shins bare),
#: ``dress`` (the loose shirt, without shorts, over the skirt) or ``long_skirt`` (a
#: tight top and the skirt down to mid-calf, over tights: no bare shin).
CLOTHING = ("tight", "shorts", "loose", "draped", "skirt", "dress", "long_skirt")
#: The loose shirt and shorts (``tight`` and ``shorts`` are the body's own outline).
GARMENTS = ("loose", "draped")
#: The outfits with a skirt.
SKIRTS = ("skirt", "dress", "long_skirt")
#: ``layer.skirt_length`` of the ``long_skirt``: the thigh and 60 % of the shin.
LONG_SKIRT_LENGTH = 1.6
#: The outfits that stand off the skin (``ease=`` applies to them).
EASED = (*GARMENTS, *SKIRTS)
#: The outfits that leave the shins bare (shorts, tight or loose, and the knee-length
#: skirt and dress).
BARE_SHIN_OUTFITS = ("shorts", *GARMENTS, "skirt", "dress")


@dataclass(frozen=True)
class ClothingLayer:
    """Settings of the loose garments and the hair.

    Attributes
    ----------
    ease : float
        Smallest gap between cloth and skin, metres.
    max_gap : float
        Largest gap (the envelope is capped here), metres.
    smoothing_steps : int
        Iterations of the outward-only smoothing (its reach grows with them).
    fold_amplitude : float
        Standard deviation of the smooth fold noise, metres.
    hem : float
        Length over which the garments taper to the skin at their hems, metres.
    sleeve, leg : float
        Where the sleeves and the shorts end, as a fraction of the upper arm
        (shoulder to elbow) and of the thigh (hip to knee).
    hang_from : float
        Where the shirt starts to hang, metres below the shoulder joints (the chest).
    drape : float
        How fast hanging cloth may come inwards, metres per metre of drop.
    hang_sector : float
        Half-width of the angular sector (radians) a trunk vertex hangs from.
    hair_thickness : float
        Hair volume at the crown, metres.
    seed : int
        Seed of the fold noise.
    rest_on : (2,) float
        ``draped``: where the garments rest on the body. The gap is scaled by
        ``1 - s``, with ``s`` rising from 0 to 1 as the rest-pose normal's
        upward component rises from ``rest_on[0]`` to ``rest_on[1]``: gravity
        lays cloth on the surfaces that face up.
    skirt_top : float
        Where the skirt starts, metres above the hip joints (the waistband).
    skirt_length : float
        Where it ends: from 0 to 1 the fraction of the thigh (hip to knee) it
        covers, from 1 to 2 the thigh and that fraction of the shin (knee to ankle)
        as well (``long_skirt``: :data:`LONG_SKIRT_LENGTH`).
    flare : float
        How fast it widens as it drops, metres per metre (an A-line).
    skirt_follows : float
        Share of the pelvis in the skirt's skin weights (the rest its own thigh's).
    """

    ease: float = 0.015
    max_gap: float = 0.06
    smoothing_steps: int = 200
    fold_amplitude: float = 0.003
    hem: float = 0.02
    sleeve: float = 0.8
    leg: float = 0.85
    hang_from: float = 0.12
    drape: float = 0.15
    hang_sector: float = 0.14
    hair_thickness: float = 0.025
    seed: int = 11
    rest_on: tuple[float, float] = (0.2, 0.6)
    skirt_top: float = 0.08
    skirt_length: float = 0.95
    flare: float = 0.25
    skirt_follows: float = 0.5


def _along(points: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Fraction (N,) of the way from ``start`` to ``end`` of each point's projection."""
    axis = end - start
    return (points - start) @ axis / float(axis @ axis)


def garment_weight(
    rest: np.ndarray,
    vertex_parts: np.ndarray,
    joints: np.ndarray,
    layer: ClothingLayer = ClothingLayer(),
) -> np.ndarray:
    """How much each vertex is covered by the shirt or the shorts, (V,) in [0, 1].

    1 inside the garments, 0 outside (head, neck, forearms, hands, lower legs,
    feet), a linear taper over ``layer.hem`` at the sleeve and leg hems and the collar.

    Parameters
    ----------
    rest : (V, 3) float
        The standing body.
    vertex_parts : (V,) int
        Part of each vertex (``BodyModel.vertex_parts``).
    joints : (15, 3) float
        Its joint centres.
    """
    w = np.zeros(len(rest))
    trunk = np.isin(vertex_parts, [PARTS.index("torso"), PARTS.index("pelvis")])
    # Collar: the shirt stops a few centimetres below the neck joint, around the neck.
    neck = joints[JOINTS.index("neck")]
    below = (neck[2] - 0.05 - rest[:, 2]) / layer.hem
    around = (np.linalg.norm(rest[:, :2] - neck[:2], axis=1) - 0.09) / layer.hem
    w[trunk] = np.clip(np.maximum(below, around), 0.0, 1.0)[trunk]
    limbs = (("upper_arm", "shoulder", "elbow", layer.sleeve), ("thigh", "hip", "knee", layer.leg))
    _cover_limbs(w, rest, vertex_parts, joints, limbs, layer.hem)
    return w


def _cover_limbs(
    w: np.ndarray,
    rest: np.ndarray,
    vertex_parts: np.ndarray,
    joints: np.ndarray,
    limbs,
    hem: float,
) -> None:
    """Set ``w`` (V,) on the limbs' vertices, both sides: 1 down to ``reach`` of the way
    from the upper joint to the lower one, tapering to 0 over ``hem`` metres.

    ``limbs``: (part, upper joint, lower joint, reach) per limb segment."""
    for part, proximal, distal, reach in limbs:
        for side in "lr":
            on = vertex_parts == PARTS.index(f"{part}_{side}")
            a = joints[JOINTS.index(f"{proximal}_{side}")]
            b = joints[JOINTS.index(f"{distal}_{side}")]
            t = _along(rest[on], a, b)
            w[on] = np.clip((reach - t) * np.linalg.norm(b - a) / hem, 0.0, 1.0)


def skirt_weight(
    rest: np.ndarray,
    vertex_parts: np.ndarray,
    joints: np.ndarray,
    layer: ClothingLayer = ClothingLayer(),
) -> np.ndarray:
    """How much each vertex is covered by the skirt, (V,) in [0, 1].

    1 on the trunk below the waistband (``layer.skirt_top`` above the hip joints) and
    on the legs above the hem (``layer.skirt_length``: of the way to the knee, and past
    1 down the shin), a linear taper over ``layer.hem`` at both ends, 0 elsewhere.

    Parameters
    ----------
    rest : (V, 3) float
        The standing body.
    vertex_parts : (V,) int
    joints : (15, 3) float
    """
    w = np.zeros(len(rest))
    top = _skirt_top(joints, layer)
    trunk = np.isin(vertex_parts, [PARTS.index("torso"), PARTS.index("pelvis")])
    w[trunk] = np.clip((top - rest[trunk, 2]) / layer.hem, 0.0, 1.0)
    # Each leg segment's share of the skirt's length (the shin's past the knee).
    legs = [(*seg, layer.skirt_length - k) for k, seg in enumerate(_LEG_SEGMENTS)]
    _cover_limbs(w, rest, vertex_parts, joints, legs, layer.hem)
    return w


#: The leg's segments a skirt may cover, from the hip down: (part, upper joint, lower joint).
_LEG_SEGMENTS = (("thigh", "hip", "knee"), ("shin", "knee", "ankle"))


def _skirt_top(joints: np.ndarray, layer: ClothingLayer) -> float:
    hips = joints[[JOINTS.index("hip_l"), JOINTS.index("hip_r")], 2]
    return float(hips.mean() + layer.skirt_top)


#: Height of the slabs the skirt's envelope is measured in, metres.
SKIRT_SLAB = 0.01


def skirt_envelope(
    rest: np.ndarray,
    vertex_parts: np.ndarray,
    joints: np.ndarray,
    layer: ClothingLayer = ClothingLayer(),
) -> tuple[np.ndarray, np.ndarray]:
    """The skirt's reach from the root's vertical axis, slab by slab.

    Returns
    -------
    tops : (S,) float
        Top of each slab, metres (descending, :data:`SKIRT_SLAB` apart, from the waistband).
    reach : (S, 4) float
        How far out the skirt stands in each slab towards +x, -x, +y and -y, metres: the
        body's furthest trunk or thigh vertex at or above the slab (within the skirt),
        plus ``layer.flare`` per metre of drop below it, plus ``layer.ease``.
    """
    top = _skirt_top(joints, layer)
    axis = joints[JOINTS.index("root"), :2]
    legs = [f"{part}_{side}" for part, _, _ in _LEG_SEGMENTS for side in "lr"]
    lower = np.isin(vertex_parts, [PARTS.index(p) for p in ("torso", "pelvis", *legs)])
    # Down to the lower joint of the last segment it reaches (the knees or the ankles).
    last = _LEG_SEGMENTS[min(int(np.ceil(layer.skirt_length)), len(_LEG_SEGMENTS)) - 1][2]
    bottom = joints[[JOINTS.index(f"{last}_l"), JOINTS.index(f"{last}_r")], 2].max()
    tops = np.arange(top, bottom - SKIRT_SLAB, -SKIRT_SLAB)
    pts = rest[lower & (rest[:, 2] <= top)]
    rel = pts[:, :2] - axis
    # Per slab and direction, the body's own reach there.
    slab = np.clip(((top - pts[:, 2]) / SKIRT_SLAB).astype(int), 0, len(tops) - 1)
    own = np.zeros((len(tops), 4))
    for k, v in enumerate((rel[:, 0], -rel[:, 0], rel[:, 1], -rel[:, 1])):
        np.maximum.at(own[:, k], slab, np.maximum(v, 0.0))
    # Cloth hangs: each slab reaches as far as any slab above it, widening by the flare.
    drop = tops[None, :] - tops[:, None]  # (below, above): how far slab i lies under j
    hang = np.where(drop[..., None] >= 0.0, own[None] + layer.flare * drop[..., None], 0.0)
    return tops, hang.max(axis=1) + layer.ease


def skirt_offsets(
    rest: np.ndarray,
    vertex_parts: np.ndarray,
    joints: np.ndarray,
    layer: ClothingLayer = ClothingLayer(),
) -> np.ndarray:
    """Horizontal offsets (V, 3) that put the covered vertices on the skirt.

    Trunk vertices move out along their direction from the root's vertical axis to
    the envelope (:func:`skirt_envelope`; never inwards). A thigh vertex maps by
    its angle about the thigh's axis: its outer half onto the envelope's half on its
    side (straight out to the outermost point, front and back to the midline), its
    inner half onto a wall 5 mm past the midline (from front to back), so that the
    two legs' halves overlap between the legs and the skirt is closed. Scaled by
    :func:`skirt_weight` (the hems taper).
    """
    w = skirt_weight(rest, vertex_parts, joints, layer)
    out = np.zeros_like(rest)
    on = np.flatnonzero(w > 0)
    if on.size == 0:
        return out
    tops, reach = skirt_envelope(rest, vertex_parts, joints, layer)
    axis = joints[JOINTS.index("root"), :2]
    p = rest[on]
    slab = np.clip(((tops[0] - p[:, 2]) / SKIRT_SLAB).astype(int), 0, len(tops) - 1)
    xp, xn, yp, yn = reach[slab].T
    rel = p[:, :2] - axis
    target = p[:, :2].copy()
    parts = vertex_parts[on]
    trunk = np.isin(parts, [PARTS.index("torso"), PARTS.index("pelvis")])
    # Trunk: along the direction from the axis, onto the quarter-ellipses of the reach.
    c, s = rel[trunk].T / np.maximum(np.linalg.norm(rel[trunk], axis=1), 1e-9)
    a = np.where(c >= 0.0, xp[trunk], xn[trunk])
    b = np.where(s >= 0.0, yp[trunk], yn[trunk])
    r = 1.0 / np.sqrt((c / a) ** 2 + (s / b) ** 2)
    r = np.maximum(r, np.linalg.norm(rel[trunk], axis=1))
    target[trunk] = axis + r[:, None] * np.stack([c, s], axis=1)
    for (part, proximal, distal), side in itertools.product(_LEG_SEGMENTS, "lr"):
        leg = parts == PARTS.index(f"{part}_{side}")
        hip = joints[JOINTS.index(f"{proximal}_{side}")]
        knee = joints[JOINTS.index(f"{distal}_{side}")]
        t = (p[leg, 2] - hip[2]) / (knee[2] - hip[2])
        centre = hip[:2] + t[:, None] * (knee[:2] - hip[:2])
        out_sign = 1.0 if hip[0] >= axis[0] else -1.0
        d = p[leg, :2] - centre
        alpha = np.arctan2(d[:, 1], out_sign * d[:, 0])  # 0 outwards, ±π inwards
        half = np.where(out_sign > 0.0, xp[leg], xn[leg])
        depth = np.where(d[:, 1] >= 0.0, yp[leg], yn[leg])
        outer = np.abs(alpha) <= 0.5 * np.pi
        x = np.where(outer, out_sign * half * np.cos(alpha), -out_sign * 0.005)
        frac = np.where(outer, np.abs(np.sin(alpha)), (np.pi - np.abs(alpha)) / (0.5 * np.pi))
        y = np.sign(d[:, 1]) * depth * frac
        target[leg] = axis + np.stack([x, y], axis=1)
    out[on, :2] = w[on, None] * (target - p[:, :2])
    return out


def skirt_layer(clothing: str, layer: ClothingLayer = ClothingLayer()) -> ClothingLayer:
    """``layer`` with the skirt's length of the outfit (the long skirt's down the shins)."""
    return replace(layer, skirt_length=LONG_SKIRT_LENGTH) if clothing == "long_skirt" else layer


def garment_skin_weights(
    weights,
    rest: np.ndarray,
    vertex_parts: np.ndarray,
    joints: np.ndarray,
    clothing: str,
    layer: ClothingLayer = ClothingLayer(),
):
    """Skin weights (V, 15) of the rendered surface: the body's, and for a skirt
    moved ``layer.skirt_follows`` of the way towards the pelvis where it covers.

    Parameters
    ----------
    weights : (V, 15) float or sparse matrix
        The body's skin weights (rows sum to 1).
    rest, vertex_parts, joints, clothing
        As :func:`dress`.
    """
    if clothing not in SKIRTS:
        return weights
    skirt = skirt_layer(clothing, layer)
    share = skirt.skirt_follows * skirt_weight(rest, vertex_parts, joints, skirt)
    dense = weights.toarray() if hasattr(weights, "toarray") else np.array(weights, dtype=float)
    dense *= (1.0 - share)[:, None]
    dense[:, PARTS.index("pelvis")] += share
    return dense


def hair_weight(rest: np.ndarray, vertex_parts: np.ndarray) -> np.ndarray:
    """Hair thickness profile (V,) in [0, 1]: 1 at the crown, 0 below the hairline.

    The hairline is the one :meth:`Appearance.vertex_modulation` paints: 7.5 cm
    below the top of the head at the forehead, 17.5 cm at the back.
    """
    head = np.flatnonzero(vertex_parts == PARTS.index("head"))
    h = rest[head]
    top = h[:, 2].max()
    front = h[:, 1].min()  # the body faces -y
    depth = max(h[:, 1].max() - front, 1e-6)
    below_top = top - h[:, 2]
    back = np.clip(((h[:, 1] - front) / depth - 0.35) / 0.5, 0.0, 1.0)
    hairline = 0.075 + 0.10 * back
    s = np.clip(1.0 - below_top / hairline, 0.0, 1.0)
    out = np.zeros(len(rest))
    out[head] = s * s * (3.0 - 2.0 * s)  # thick on top, thinning to the hairline
    return out


def hang_offsets(
    shell: np.ndarray,
    trunk: np.ndarray,
    joints: np.ndarray,
    layer: ClothingLayer = ClothingLayer(),
) -> np.ndarray:
    """Horizontal push (V, 3) that makes the cloth of the trunk hang below the chest.

    Parameters
    ----------
    shell : (V, 3) float
        The cloth surface so far (the body plus its ease).
    trunk : (V,) bool
        Covered vertices of the torso and pelvis.
    joints : (15, 3) float
    """
    out = np.zeros_like(shell)
    idx = np.flatnonzero(trunk)
    if idx.size == 0:
        return out
    axis = joints[JOINTS.index("root"), :2]
    rel = shell[idx, :2] - axis
    r = np.linalg.norm(rel, axis=1)
    phi = np.arctan2(rel[:, 1], rel[:, 0])
    z = shell[idx, 2]
    top = 0.5 * (joints[JOINTS.index("shoulder_l"), 2] + joints[JOINTS.index("shoulder_r"), 2])
    start = top - layer.hang_from
    # Each vertex hangs from the trunk vertices above it (up to the chest) in its sector.
    dphi = np.abs((phi[:, None] - phi[None, :] + np.pi) % (2.0 * np.pi) - np.pi)
    drop = z[None, :] - z[:, None]
    above = (dphi <= layer.hang_sector) & (drop >= 0.0) & (z[None, :] <= start)
    reach = np.where(above, r[None, :] - layer.drape * drop, -np.inf).max(axis=1)
    push = np.clip(reach - r, 0.0, layer.max_gap)
    push[z > start] = 0.0
    out[idx, :2] = push[:, None] * rel / np.maximum(r, 1e-9)[:, None]
    return out


def dress(
    rest: np.ndarray,
    faces: np.ndarray,
    vertex_parts: np.ndarray,
    joints: np.ndarray,
    *,
    clothing: str = "tight",
    hair: bool = False,
    layer: ClothingLayer = ClothingLayer(),
) -> np.ndarray:
    """The rendered surface of a subject: the rest body displaced where clothed or haired.

    Parameters
    ----------
    rest : (V, 3) float
        The nude rest body.
    faces : (T, 3) int
    vertex_parts : (V,) int
    joints : (15, 3) float
        Its joint centres.
    clothing : {"tight", "shorts", "loose", "draped", "skirt", "dress", "long_skirt"}
    hair : bool

    Returns
    -------
    (V, 3) float
        Same topology; equal to ``rest`` for tight clothing without hair.
    """
    if clothing not in CLOTHING:
        raise ValueError(f"clothing: expected one of {CLOTHING}, got {clothing!r}")
    rest = np.asarray(rest, dtype=float)
    normals = geometry.vertex_normals(rest, faces)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-12
    smooth = geometry.neighbour_mean(faces, len(rest))
    d = np.zeros(len(rest))
    if clothing in (*GARMENTS, "dress"):
        # A dress is the loose shirt without the shorts, over the skirt (below).
        shirt = replace(layer, leg=0.0) if clothing == "dress" else layer
        w = garment_weight(rest, vertex_parts, joints, shirt)
        cloth = w > 0
        d[cloth] = layer.ease
        for _ in range(layer.smoothing_steps):
            # Outward-only smoothing: where the neighbours' mean of the displaced
            # surface lies further out along the normal (a hollow), the cloth
            # follows it; over a convex part it keeps its gap.
            shell = rest + d[:, None] * normals
            out = np.einsum("vd,vd->v", smooth @ shell - rest, normals)
            d[cloth] = np.clip(np.maximum(d, out), 0.0, layer.max_gap)[cloth]
        rng = np.random.default_rng(layer.seed)
        folds = rng.standard_normal(len(rest))
        for _ in range(30):
            folds = 0.5 * folds + 0.5 * (smooth @ folds)
        folds *= layer.fold_amplitude / (folds[cloth].std() + 1e-12)
        d = np.where(cloth, np.clip(d + folds, 0.5 * layer.ease, layer.max_gap), 0.0)
        trunk = cloth & np.isin(vertex_parts, [PARTS.index("torso"), PARTS.index("pelvis")])
        offset = d[:, None] * normals
        offset += hang_offsets(rest + offset, trunk, joints, layer)
        for _ in range(3):
            offset = np.where(cloth[:, None], smooth @ offset, 0.0)
        gap = np.linalg.norm(offset, axis=1)
        offset *= (np.minimum(gap, layer.max_gap) / np.maximum(gap, 1e-12) * w)[:, None]
        if clothing == "draped":
            low, high = layer.rest_on
            lying = np.clip((normals[:, 2] - low) / (high - low), 0.0, 1.0)
            offset *= (1.0 - lying)[:, None]
    else:
        offset = np.zeros_like(rest)
    if clothing in SKIRTS:
        # The skirt falls from whatever the body wears above it (a dress's shirt).
        skirt = skirt_layer(clothing, layer)
        offset += skirt_offsets(rest + offset, vertex_parts, joints, skirt)
    if hair:
        thickness = layer.hair_thickness * hair_weight(rest, vertex_parts)
        # The head is not clothed: hair is the only layer there.
        offset = np.where((thickness > 0)[:, None], thickness[:, None] * normals, offset)
    return rest + offset
