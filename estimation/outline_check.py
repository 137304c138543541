"""Does the observed outline lie outside the fitted body? A check for loose clothing and hair.

The measurements assume the silhouette is the body's own outline (tight
clothing). Loose clothes break that silently: the fit explains the larger
silhouettes with a larger body at an IoU as good as a tight subject's (a
loose shirt and shorts added 13-16 kg in the studio, docs/session-shape.md).
No single number of the fit separates the two (the IoU, the size of ν, the
overall excess of silhouette over model all overlap); the *pattern* of the
misfit does:

* a shirt and shorts (or a dress, a jacket) cover the trunk and leave the
  forearms and shins bare. One body cannot be wide at the trunk and slim at
  the forearms beyond what the shape space allows, so the fit settles in
  between: the observed outline lies **outside** the fitted body at the trunk
  and **inside** it at the bare limbs, the shins below shorts most. With tight
  clothing the offset is about the same everywhere, but at a forearm thinner
  than the shape space makes it;
* hair or headwear puts the outline outside the fitted head, most at the
  crown, which is what the height is measured to.

For every frame and view, at the given states, each model contour edge is
paired with the nearest observed outline point (the contour cost's
model-to-observed correspondences, :mod:`bodymetry.estimation.refinement`), and
its offset along the observed outline's outward normal is converted from
pixels to millimetres at the edge's depth: positive where the observed outline
lies outside the body. Offsets are pooled per body region and frame (median),
and the session's figure is the median over frames, with the frames' spread
as its standard error.

The thresholds and the sessions they were set on are in docs/session-shape.md
("Outline check"); the margins are a millimetre or so.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bodymetry.calibration.camera import CameraGroup
from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.body_model.skeleton import PARTS
from bodymetry.estimation.contours import near_region, prepare_contours
from bodymetry.estimation.records import HAIR, LEGS_HIDDEN, LOOSE_CLOTHING, OutlineCheck
from bodymetry.estimation.refinement import Alignment, ContourCost, RefineConfig

#: Body regions the offsets are pooled over, by part name.
REGIONS: dict[str, tuple[str, ...]] = {
    "trunk": ("torso", "pelvis"),
    "upper limbs": ("upper_arm_l", "upper_arm_r", "thigh_l", "thigh_r"),
    "lower limbs": ("lower_arm_l", "lower_arm_r", "shin_l", "shin_r"),
    "head": ("head",),
    "crown": (),  # the head within CROWN_DEPTH of its top (see crown_vertices)
}

#: The offsets' key of the forearms' and shins' outline points on skin, where
#: capture told skin from clothing (:func:`check_outline`).
BARE_LIMBS = "bare lower limbs"
#: The lower limbs apart, by part name: in low contrast the trunk is compared with
#: whichever of them the fit meets best (:func:`check_outline`).
LIMB_GROUPS: dict[str, tuple[str, ...]] = {
    "forearms": ("lower_arm_l", "lower_arm_r"),
    "shins": ("shin_l", "shin_r"),
}
#: The offsets' key of the shins' outline points on skin (below shorts, loose or tight).
BARE_SHINS = "bare shins"
#: The least share of a frame's shin outline points on skin for its shins to count as
#: bare (trousers left up to 13 of 400-850 points on skin, at the shoes; shorts 70-85 %).
BARE_SHARE = 0.5

#: The regions whose median offset in a frame the crown's is compared with. Not
#: the forearms and shins alone: a loose shirt fits the body too big for them
#: (they lie 2-6 mm inside it), and against them alone a bare crown read as hair
#: (a draped shirt with a 40 mm gap: 5.9 mm, where hair reads 6.6 mm and more);
#: the trunk and head are fitted where they are seen, and a median of three
#: ignores the one that clothing or hair moves (docs/session-shape.md).
CROWN_REFERENCE = ("trunk", "head", "lower limbs")

#: Depth below the top of the standing body's head that counts as its crown, metres.
CROWN_DEPTH = 0.06


@dataclass(frozen=True)
class OutlineConfig:
    """Thresholds of the outline check.

    Attributes
    ----------
    loose_mm : float
        Warn of loose clothing when the trunk's offset exceeds the lower
        limbs' by more than this. Set on 2026-12-07 for the session stage at
        full resolution: the studio's tight subjects (issue 15's eleven, the
        edge, unseen edge and weight sets) at most +0.45 ± 0.45 mm, the loose
        shirt and shorts (seeds 45, 46, 56, 73, 74) +1.4 to +4.6 mm (at half
        resolution before: tight -1.2 to +2.8 mm, loose +3.4 to +5.0 mm, 3.2 mm;
        docs/session-shape.md).
    crown_mm : float
        Warn of hair or headwear when the crown's offset exceeds the median
        of the trunk's, head's and lower limbs' (:data:`CROWN_REFERENCE`) by
        more than this (studio at full resolution: bare head at most
        +0.1 mm, hair up to 2.5 cm thick +6.8 to +10.8 mm; the real Pose2Sim
        subject's cap +6.6 mm. At half resolution before: 2 mm, 11.9 mm and
        5.8 mm, 7 mm).
    min_points : int
        Fewest contour points a region needs in a frame to count there.
    max_mm_per_px : float
        Coarsest working pixel (millimetres at the body) the check decides
        at: the signatures are a few millimetres, a fifth to a whole pixel of
        the demo's 5.5 mm pixels at the session stage's full resolution; at
        25 mm (a 240x180 camera) they are lost in the outline's quantization.
    loose_mm_low_contrast : float
        ``loose_mm`` for "likely" in a run seen in low contrast (white, grey or
        wall-coloured clothing before a wall of about its colour: the run's
        outline contrast under
        :data:`~bodymetry.estimation.studio_accuracy.LOW_CONTRAST`). There the
        captured outline itself errs by part: the limbs a few tenths of a pixel
        inside, the trunk less (docs/capture.md), and the studio's tight
        subjects in such clothing read up to +1.68 ± 0.49 mm (27 sessions),
        while a shirt draped 6 mm off the skin read +1.72 ± 0.60 mm and +7.7 kg
        (docs/session-shape.md, "Outline check"). Between ``loose_mm`` and this
        the check cannot tell them apart and says "loose clothing possible".
    shins_inside_mm : float
        The bare shins (their outline points on skin, where capture told skin
        from clothing: ``offsets_mm["bare shins"]``, in half the frames or more)
        lying at least this far *inside* the fitted body (median over frames,
        at most ``-shins_inside_mm``) says the body was fitted too big for
        them, which is what loose clothing over the thighs does to the fit: it
        warns "loose clothing possible" whatever the trunk's excess, and in low
        contrast it holds the trunk's excess to ``loose_mm`` again. Clothed
        shins do not count: in low contrast their captured outline lies inside
        their own (a tight wall-coloured suit's forearms and shins read 1.33 mm
        inside). Nor do the forearms: their girth is where the shape space
        reaches least, and a tight-clothed woman of 76 with thin forearms,
        measured within 0.1 kg, read hers 2.5 mm inside the fitted body (seed 42;
        loose subjects' forearms 0.0 to 2.2 mm). Studio, 2026-12-08: the bare
        shins of seven tight subjects in shorts (``clothing=shorts``) at most
        0.57 mm inside in full contrast and 1.27 mm in low contrast (skin before
        a beige floor; warned "possible", saying the check cannot tell); of ten
        loose ones 1.15 to 3.43 mm for five, 0.0 to 0.4 mm for the two draped,
        the heaviest man (his trunk warns) and the gaps of 5-6 mm
        (docs/session-shape.md, "Forearms are not the clothing's signature").
    legs_hidden_mm : float
        Bare shins lying at least this far inside the fitted body say the thighs
        were hidden by something that stands well off them (a skirt, a dress, a
        long coat): the fit shapes the legs to the garment and poses them to fill
        it (the hips turned 20-40 degrees in a walk), so the height is off too. It
        warns "legs hidden likely", and no interval is stated for the height, the
        arm span or the weight (:data:`~bodymetry.estimation.records.OVERSTATED`).
        Studio, 2026-12-08: the loose shorts' bare shins 0.0 to 3.43 mm inside, the
        tight shorts' at most 1.27 mm; knee-length skirts and dresses
        (``clothing=skirt``, ``dress``) 5.44 to 13.73 mm in 11 of 13, and 3.33 and
        3.44 mm for a skirt only 5 mm off the hips and one in light grey in low
        contrast, whose heights held (docs/session-shape.md, "Skirts").
    bare_trunk : float
        Where capture told skin from clothing (:mod:`bodymetry.capture.skin`),
        a trunk whose outline lies on clothing in less than this share is
        bare: it wears no loose shirt, and no loose-clothing warning is given
        (the real Pose2Sim subject, shirtless, reads +2.7 ± 1.3 mm).
    """

    loose_mm: float = 1.3
    loose_mm_low_contrast: float = 2.5
    shins_inside_mm: float = 0.9
    legs_hidden_mm: float = 4.5
    crown_mm: float = 4.0
    min_points: int = 10
    max_mm_per_px: float = 15.0
    bare_trunk: float = 0.5

    def __post_init__(self) -> None:
        if not (self.loose_mm > 0 and self.loose_mm_low_contrast > 0 and self.crown_mm > 0):
            raise ValueError(
                "loose_mm, loose_mm_low_contrast, crown_mm: expected > 0, got "
                f"{self.loose_mm}, {self.loose_mm_low_contrast}, {self.crown_mm}"
            )
        if not self.shins_inside_mm > 0:
            raise ValueError(f"shins_inside_mm: expected > 0, got {self.shins_inside_mm}")
        if not self.legs_hidden_mm > self.shins_inside_mm:
            raise ValueError(
                f"legs_hidden_mm: expected > shins_inside_mm ({self.shins_inside_mm}), "
                f"got {self.legs_hidden_mm}"
            )
        if self.min_points < 1:
            raise ValueError(f"min_points: expected >= 1, got {self.min_points}")
        if not self.max_mm_per_px > 0:
            raise ValueError(f"max_mm_per_px: expected > 0, got {self.max_mm_per_px}")
        if not 0 <= self.bare_trunk <= 1:
            raise ValueError(f"bare_trunk: expected in [0, 1], got {self.bare_trunk}")


def crown_vertices(body: BodyModel, lod: bool) -> np.ndarray:
    """(V,) bool: head vertices within :data:`CROWN_DEPTH` of the rest body's top.

    Taken on the mean shape standing (θ = 0); the set then moves with the head.
    """
    parts = body.parts_of_vertices(lod)
    rest = body.pose(BodyState.rest(body.n_shape), lod=lod).vertices[0]
    head = parts == PARTS.index("head")
    return head & (rest[:, 2] >= rest[head, 2].max() - CROWN_DEPTH)


def frame_offsets(
    body: BodyModel,
    cameras: CameraGroup,
    masks: Sequence[np.ndarray],
    state: np.ndarray,
    refinement: RefineConfig,
    alignment: Alignment | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signed outline offsets of one frame's model contour, every usable view.

    Parameters
    ----------
    cameras : CameraGroup
        The working cameras.
    masks : sequence of C (H_c, W_c) bool
        Observed silhouettes (all-False: view left out).
    state : (40 + n_shape,) float
        ``[τ, θ, ν]`` of the frame.
    refinement : RefineConfig
        The contour cost's settings (mesh, scale, points).
    alignment : Alignment, optional
        The frame's contour cost on these masks with these settings (the
        session stage's): its prepared outline is used, and its
        correspondences when ``state`` is its state. The same offsets.

    Returns
    -------
    vertices : (N,) int
        The first vertex of each contour edge (indices into the cost's mesh).
    offsets_mm : (N,) float
        Observed outline minus model contour along the outline's outward
        normal, millimetres at the edge's depth (+: the outline lies outside).
    mm_per_px : (N,) float
        The size of a working pixel at each edge's depth, millimetres.
    """
    verts, offsets, sizes, _, _ = _frame_pairs(body, cameras, masks, state, refinement, alignment)
    return verts, offsets, sizes


def _frame_pairs(
    body: BodyModel,
    cameras: CameraGroup,
    masks: Sequence[np.ndarray],
    state: np.ndarray,
    refinement: RefineConfig,
    alignment: Alignment | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`frame_offsets`, and where each offset's observed outline point lies:
    (N, 2) working pixels (``x``, ``y`` of the masks) and (N,) the view index."""
    y = np.asarray(state, float)
    if alignment is None:
        obs = prepare_contours(cameras, masks, refinement.image_scale, refinement.max_points)
        cost = ContourCost(body, obs, refinement)
        _, pairs = cost.evaluate(y)
    else:
        cost, obs, pairs = alignment.cost, alignment.cost.obs, alignment.pairs_at(y)
    V = cost.vertices(y)[0]
    verts, offsets, sizes, where, views = [], [], [], [], []
    for p in pairs:
        if p.source is not None:  # the observed-to-model direction repeats edges
            continue
        cam = obs.cameras[p.camera]
        mid = 0.5 * (V[p.edges[:, 0]] + V[p.edges[:, 1]])
        px = np.einsum("ij,ij->i", p.targets - cam.project(mid), p.normals)
        depth = (mid @ cam.R.T + cam.t)[:, 2]
        verts.append(p.edges[:, 0])
        sizes.append(depth / cam.K[0, 0] * 1000.0)
        offsets.append(px * sizes[-1])
        # The outline's points are at the contour scale (Camera.scaled: x' = (x + 0.5) s - 0.5),
        # the alignment's own where one is given (the session stage's may differ).
        where.append((p.targets + 0.5) / obs.scale - 0.5)
        views.append(np.full(len(p.edges), p.camera))
    if not verts:
        empty = np.zeros(0)
        return np.zeros(0, np.int64), empty, empty, np.zeros((0, 2)), np.zeros(0, np.int64)
    return (
        np.concatenate(verts),
        np.concatenate(offsets),
        np.concatenate(sizes),
        np.concatenate(where),
        np.concatenate(views),
    )


def _on_clothing(
    clothing: Sequence[np.ndarray | None], where: np.ndarray, views: np.ndarray
) -> np.ndarray:
    """(N,) float: 1 where an outline point (``where`` (N, 2) working pixels, in view
    ``views`` (N,)) lies within a pixel of its view's clothing mask, 0 where not, NaN
    where the view has none."""
    out = np.full(len(where), np.nan)
    for c, mask in enumerate(clothing):
        sel = views == c
        if mask is None or not sel.any():
            continue
        out[sel] = near_region(np.asarray(mask, bool), where[sel], 1)
    return out


def check_outline(
    body: BodyModel,
    cameras: CameraGroup,
    frames: Sequence[tuple[Sequence[np.ndarray], np.ndarray]],
    refinement: RefineConfig | None = None,
    config: OutlineConfig | None = None,
    alignments: Sequence[Alignment | None] | None = None,
    clothing: Sequence[Sequence[np.ndarray | None]] | None = None,
    low_contrast: bool = False,
) -> OutlineCheck:
    """The session's outline offsets per region, and its warnings.

    Parameters
    ----------
    body : BodyModel
    cameras : CameraGroup
        The working cameras.
    frames : sequence of (masks, state)
        Each accepted frame's observed silhouettes and fitted state (see
        :func:`frame_offsets`).
    refinement : RefineConfig, optional
    config : OutlineConfig, optional
    alignments : sequence of (Alignment or None), optional
        Per frame, its contour cost from the session stage (see
        :func:`frame_offsets`); saves preparing the outlines again.
    clothing : sequence of (sequence of C ((H_c, W_c) bool or None)), optional
        Per frame, capture's clothing masks per view (empty or None: not
        told): the share of the trunk's outline on clothing
        (``trunk_clothing_share``) tells a bare trunk, which wears no loose
        shirt (``OutlineConfig.bare_trunk``).
    low_contrast : bool
        Capture saw the person in low contrast: loose clothing is judged against
        ``OutlineConfig.loose_mm_low_contrast``.

    Returns
    -------
    OutlineCheck
    """
    refinement = refinement or RefineConfig()
    config = config or OutlineConfig()
    members = _region_members(body, lod=not refinement.full_mesh)
    per_frame: dict[str, list[float]] = {name: [] for name in REGIONS}
    # Per frame, the trunk's offset relative to the forearms and shins and the
    # crown's relative to the median of the trunk, head and those limbs: a uniformly
    # larger silhouette (a blurred or dilated segmentation) moves every region alike
    # and is neither clothing nor hair.
    excess: dict[str, list[float]] = {"trunk": [], "crown": []}
    # The trunk's excess over the forearms or the shins, whichever the fit meets best.
    best_excess: list[float] = []
    pixel = []
    aligned = [None] * len(frames) if alignments is None else list(alignments)
    if len(aligned) != len(frames):
        raise ValueError(f"alignments: expected {len(frames)}, got {len(aligned)}")
    worn = [None] * len(frames) if clothing is None else list(clothing)
    if len(worn) != len(frames):
        raise ValueError(f"clothing: expected {len(frames)}, got {len(worn)}")
    trunk_worn = []
    for (masks, state), alignment, cloth in zip(frames, aligned, worn, strict=True):
        verts, mm, size, where, views = _frame_pairs(
            body, cameras, masks, state, refinement, alignment
        )
        selections = {name: member[verts] for name, member in members.items()}
        if cloth:
            on = _on_clothing(cloth, where, views)
            trunk_worn.append(on[selections["trunk"]])
            # Where capture told skin from clothing: the forearms and shins on skin.
            selections[BARE_LIMBS] = selections["lower limbs"] & (on == 0)
            bare_shins = selections["shins"] & (on == 0)
            # Shins mostly on skin (below shorts), not a few points at a trouser's
            # hem or a shoe's edge.
            if bare_shins.sum() >= BARE_SHARE * selections["shins"].sum():
                selections[BARE_SHINS] = bare_shins
        pixel.append(size)
        med = {}
        for name, sel in selections.items():
            med[name] = float(np.median(mm[sel])) if sel.sum() >= config.min_points else np.nan
            if np.isfinite(med[name]):
                per_frame.setdefault(name, []).append(med[name])
        limbs = [med[name] for name in LIMB_GROUPS if np.isfinite(med[name])]
        if np.isfinite(med["trunk"]) and limbs:
            # Nearest zero, not the largest: a limb misplaced by the fit (a forearm's
            # outline 24 mm outside it in one frame) is not one the fit meets best.
            best_excess.append(med["trunk"] - min(limbs, key=abs))
        if not np.isfinite(med["lower limbs"]):
            continue
        if np.isfinite(med["trunk"]):
            excess["trunk"].append(med["trunk"] - med["lower limbs"])
        if np.isfinite(med["crown"]):
            reference = [med[n] for n in CROWN_REFERENCE if np.isfinite(med[n])]
            excess["crown"].append(med["crown"] - float(np.median(reference)))
    # In low contrast a clothed limb's captured outline lies inside its own (the
    # garment's shaded rim is lost), and a bare forearm can be thinner than the shape
    # space makes it: the trunk is compared with the forearms or the shins, whichever
    # the fit meets best (a tight wall-coloured suit's bare forearms, not its shins).
    if low_contrast and best_excess:
        excess["trunk"] = best_excess
    trunk, trunk_se = _median(excess["trunk"]), median_standard_error(excess["trunk"])
    crown, crown_se = _median(excess["crown"]), median_standard_error(excess["crown"])
    mm_per_px = float(np.median(np.concatenate(pixel))) if any(len(p) for p in pixel) else np.nan
    coarse = not mm_per_px <= config.max_mm_per_px
    # Coarse pixels: the figures are kept, but they decide nothing.
    on_cloth = np.concatenate(trunk_worn) if trunk_worn else np.zeros(0)
    on_cloth = on_cloth[np.isfinite(on_cloth)]
    trunk_share = float(on_cloth.mean()) if len(on_cloth) else float("nan")
    # Bare shins seen in a frame or two (a label's slip at a hem) say nothing.
    if len(per_frame.get(BARE_SHINS, [])) < max(2, len(frames) // 2):
        per_frame.pop(BARE_SHINS, None)
    shins_offset = _median(per_frame.get(BARE_SHINS, []))
    warnings = (
        []
        if coarse
        else _clothing_warnings(
            trunk, trunk_se, crown, crown_se, config, trunk_share, low_contrast, shins_offset
        )
    )
    status = _status(mm_per_px, coarse, config)
    return OutlineCheck(
        status=status,
        frames=len(frames),
        mm_per_px=mm_per_px,
        offsets_mm={k: _median(v) for k, v in per_frame.items()},
        trunk_excess_mm=trunk,
        trunk_excess_se_mm=trunk_se,
        crown_excess_mm=crown,
        crown_excess_se_mm=crown_se,
        warnings=tuple(warnings),
        trunk_clothing_share=trunk_share,
    )


def _region_members(body: BodyModel, lod: bool) -> dict[str, np.ndarray]:
    """Per region of :data:`REGIONS` and :data:`LIMB_GROUPS`, which vertices (V,) bool of the mesh
    (level of detail or full) belong to it."""
    parts = body.parts_of_vertices(lod)
    crown = crown_vertices(body, lod)
    return {
        name: crown if name == "crown" else np.isin(parts, [PARTS.index(p) for p in names])
        for name, names in {**REGIONS, **LIMB_GROUPS}.items()
    }


def _clothing_warnings(
    trunk: float,
    trunk_se: float,
    crown: float,
    crown_se: float,
    config: OutlineConfig,
    trunk_share: float = float("nan"),
    low_contrast: bool = False,
    shins: float = float("nan"),
) -> list[str]:
    """The warnings for loose clothing (the trunk's excess offset, mm) and for hair
    or headwear (the crown's), each with its standard error.

    Loose clothing is warned of above ``loose_mm`` (``loose_mm_low_contrast`` for a
    run seen in low contrast, unless the bare shins lie inside the fitted body by
    ``shins_inside_mm`` or more: ``shins``, their offset in mm, + outside, NaN
    where capture did not tell them bare), and also within one standard error
    below it, where the frames do not settle the verdict either way, or wherever
    the bare shins lie that far inside; not where the trunk's
    outline is bare skin (``trunk_share``, the share of it on clothing, under
    ``bare_trunk``). Legs hidden by a skirt are warned of where the bare shins
    lie ``legs_hidden_mm`` or more inside, whatever the trunk."""
    warnings = []
    bare = np.isfinite(trunk_share) and trunk_share < config.bare_trunk
    # A body fitted too big for its bare limbs is the clothing's signature, which
    # the low-contrast outline (the trunk's a little out) does not leave.
    inside = bool(np.isfinite(shins) and shins <= -config.shins_inside_mm)
    # Far inside: the thighs were hidden (a skirt), and the legs fitted to the garment.
    hidden = bool(np.isfinite(shins) and shins <= -config.legs_hidden_mm)
    relaxed = low_contrast and not inside
    limit = config.loose_mm_low_contrast if relaxed else config.loose_mm
    if relaxed:
        bound = f"tight clothing in low contrast: under {limit:g} mm"
    elif low_contrast:
        bound = (
            f"tight clothing: under {limit:g} mm, in low contrast too where the bare "
            f"shins lie {config.shins_inside_mm:g} mm or more inside the fitted body, "
            f"here {-shins:.1f} mm"
        )
    else:
        bound = f"tight clothing: under {limit:g} mm"
    if np.isfinite(trunk) and trunk > limit and not bare:
        note = _borderline(trunk, trunk_se, limit)
        warnings.append(
            f"{LOOSE_CLOTHING} likely: the silhouettes lie {_mm(trunk, trunk_se)} "
            "further outside the fitted body at the trunk than at the forearms and shins "
            f"({bound}{note}); the weight, arm span, "
            "circumferences and widths are probably overstated"
        )
    elif not bare and np.isfinite(trunk_se) and trunk + trunk_se >= limit:
        warnings.append(
            f"{LOOSE_CLOTHING} possible: the silhouettes lie {_mm(trunk, trunk_se)} "
            "further outside the fitted body at the trunk than at the forearms and "
            f"shins ({bound}; within one standard "
            "error below it, the frames do not settle it); the weight, arm span, "
            "circumferences and widths may be overstated"
        )
    elif not bare and inside and not hidden:
        warnings.append(
            f"{LOOSE_CLOTHING} possible: the bare shins lie {-shins:.1f} mm inside "
            f"the fitted body (tight clothing: under {config.shins_inside_mm:g} mm), as when "
            "loose clothing makes the body fitted too big for its bare legs"
            # Skin before a floor of like colour loses its rim as a grey garment does
            # (a tight subject in shorts in the textured lab, seed 877: 1.27 mm).
            + (
                " (or as the captured outline of skin before a floor of about its colour "
                "does in low contrast: the check cannot tell them apart)"
                if low_contrast
                else ""
            )
            + f"; the trunk's outline lies {_mm(trunk, trunk_se)} further outside than "
            f"the limbs' ({bound}); the weight, arm span, circumferences and widths may be "
            "overstated"
        )
    elif not bare and relaxed and np.isfinite(trunk) and trunk > config.loose_mm:
        # Between the two thresholds low contrast cannot tell: a tight garment's
        # lost rim and a loose one a few millimetres off the skin read alike.
        warnings.append(
            f"{LOOSE_CLOTHING} possible: the silhouettes lie {_mm(trunk, trunk_se)} "
            "further outside the fitted body at the trunk than at the forearms and "
            f"shins (tight clothing: under {config.loose_mm:g} mm; in low contrast the "
            f"captured outline alone reads up to {limit:g} mm, so the check cannot tell "
            "tight clothing from loose); the weight, arm span, circumferences and "
            "widths may be overstated (or, as in low contrast, understated)"
        )
    if hidden:
        warnings.append(
            f"{LEGS_HIDDEN} likely: the bare shins lie {-shins:.1f} mm inside the fitted "
            f"body (bare legs below shorts, loose or tight: under {config.legs_hidden_mm:g} "
            "mm), as when a skirt, a dress or a long coat hides the thighs and the fit "
            "shapes and poses the legs to fill it; the height, weight, arm span, "
            "circumferences and widths are the garment's, not the body's (the studio's "
            "skirts and dresses read the height up to 52 mm high, the weight 5-47 kg "
            "heavy and the arm span 18-46 mm short)"
        )
    if np.isfinite(crown) and crown > config.crown_mm:
        note = _borderline(crown, crown_se, config.crown_mm)
        warnings.append(
            f"{HAIR} likely: the silhouettes lie {_mm(crown, crown_se)} "
            "further outside the fitted body at the crown than elsewhere (the median of "
            "the trunk, the head and the forearms and shins) "
            f"(bare head: under {config.crown_mm:g} mm{note}); the height is probably "
            "overstated"
        )
    return warnings


def _status(mm_per_px: float, coarse: bool, config: OutlineConfig) -> str:
    """The check's status: ``"ok"``, ``"no contour"`` or ``"undecided: ..."`` when
    the working pixels are too coarse at the body."""
    if not np.isfinite(mm_per_px):
        return "no contour"
    if coarse:
        return (
            f"undecided: working pixels of {mm_per_px:.0f} mm at the body are coarser "
            f"than the {config.max_mm_per_px:g} mm the check needs"
        )
    return "ok"


def _mm(value: float, se: float) -> str:
    """``"3.4 ± 0.6 mm"``; without the ± when one frame gives no standard error."""
    return f"{value:.1f} ± {se:.1f} mm" if np.isfinite(se) else f"{value:.1f} mm"


def _borderline(value: float, se: float, threshold: float) -> str:
    """A note for a warning whose figure lies within one standard error above its
    threshold: the frames do not settle the verdict (empty otherwise)."""
    if np.isfinite(se) and value - se <= threshold:
        return "; borderline: within one standard error of it"
    return ""


def _median(values: Sequence[float]) -> float:
    return float(np.median(values)) if len(values) else float("nan")


def median_standard_error(values: Sequence[float]) -> float:
    """Standard error of the median of ``values`` over frames (1.2533 σ/√n, the
    median's efficiency under a normal spread); NaN for fewer than two."""
    if len(values) < 2:
        return float("nan")
    return float(1.2533 * np.std(values, ddof=1) / np.sqrt(len(values)))
