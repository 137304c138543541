"""The outline check: offsets of the observed outline from the fitted body, per region."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from bodymetry.errors import InputError
from bodymetry.estimation.body_model.model import DEFAULT_SHAPE_DOFS, BodyModel, BodyState
from bodymetry.estimation.body_model.skeleton import PARTS
from bodymetry.estimation.contours import prepare_contours
from bodymetry.estimation.outline_check import (
    REGIONS,
    OutlineConfig,
    check_outline,
    crown_vertices,
    frame_offsets,
)
from bodymetry.estimation.projection import project_silhouettes
from bodymetry.estimation.records import OutlineCheck, SessionShape
from bodymetry.estimation.refinement import Alignment, ContourCost, RefineConfig
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import RunResults, SessionInfo
from bodymetry.studio.rig import studio_rig

NU = np.pad([0.5, -0.3, 0.2, 0.0, 0.3, 0.0, -0.2, 0.0, 0.1], (0, DEFAULT_SHAPE_DOFS - 9))
#: The tolerance on a region's offset (mm) when the silhouettes are the body's
#: own: rasterization puts the outline within half a pixel, here about 3 mm.
EXACT_MM = 1.5


@pytest.fixture(scope="module")
def scene():
    """A known body in 3 headings seen by 4 studio cameras (640x480)."""
    model = BodyModel.load()
    cameras = studio_rig(4, (640, 480), seed=4)
    states = []
    for heading in (-2.0, 0.3, 2.2):
        theta = model.poses["apose"].copy()
        theta[2] = heading
        states.append(np.r_[0.05, -0.05, 0.93, theta, NU])
    return model, cameras, states


def _masks(model, cameras, state, faces=None):
    body = model.pose(BodyState.from_vector(state[None])).vertices[0]
    return list(project_silhouettes(body, model.faces() if faces is None else faces, cameras))


def _grown(masks, px):
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * px + 1, 2 * px + 1))
    return [cv2.dilate(m.astype(np.uint8), kernel).astype(bool) for m in masks]


def _with_grown_region(model, cameras, states, faces, px):
    """Frames whose silhouettes are the body's own plus ``faces`` grown by ``px``."""
    frames = []
    for s in states:
        own = _masks(model, cameras, s)
        extra = _grown(_masks(model, cameras, s, faces), px)
        frames.append(([a | b for a, b in zip(own, extra, strict=True)], s))
    return frames


def _faces_but(model, names):
    """The mesh's faces outside the parts ``names``."""
    parts = model.full.arrays.parts
    return model.faces()[~np.isin(parts, [PARTS.index(n) for n in names])]


def _with_thinned_parts(model, cameras, states, names):
    """Frames whose silhouettes are the body's own with the parts ``names`` 1 px thinner
    (their captured outline inside their own, or a body fitted too big for them)."""
    kernel = np.ones((3, 3), np.uint8)
    thin_faces, rest = _region_faces(model, names), _faces_but(model, names)
    frames = []
    for s in states:
        thin = _masks(model, cameras, s, thin_faces)
        thin = [cv2.erode(m.astype(np.uint8), kernel).astype(bool) for m in thin]
        own = _masks(model, cameras, s, rest)
        frames.append(([a | b for a, b in zip(own, thin, strict=True)], s))
    return frames


def _region_faces(model, names):
    parts = model.full.arrays.parts
    return model.faces()[np.isin(parts, [PARTS.index(n) for n in names])]


def _mm_per_px(cameras, state) -> float:
    """Millimetres per pixel at the body's depth, averaged over the views."""
    return float(np.mean([np.linalg.norm(c.center - state[:3]) / c.K[0, 0] for c in cameras]) * 1e3)


def test_own_silhouettes_give_no_offset_and_no_warning(scene):
    model, cameras, states = scene
    frames = [(_masks(model, cameras, s), s) for s in states]
    check = check_outline(model, cameras, frames)
    assert check.frames == 3 and check.status == "ok"
    assert check.mm_per_px == pytest.approx(2 * _mm_per_px(cameras, states[0]), rel=0.15)
    for region in ("trunk", "upper limbs", "lower limbs", "head"):
        assert abs(check.offsets_mm[region]) < EXACT_MM, (region, check.offsets_mm)
    assert abs(check.trunk_excess_mm) < EXACT_MM
    assert check.warnings == ()


def test_uniformly_larger_silhouettes_are_not_loose_clothing(scene):
    """Grown by 2 px everywhere: every region moves out alike, the trunk excess stays ~0."""
    model, cameras, states = scene
    frames = [(_grown(_masks(model, cameras, s), 2), s) for s in states]
    check = check_outline(model, cameras, frames)
    px = _mm_per_px(cameras, states[0])
    for region in ("trunk", "upper limbs", "lower limbs"):
        assert check.offsets_mm[region] == pytest.approx(2 * px, abs=0.6 * px), region
    assert abs(check.trunk_excess_mm) < 0.5 * px
    assert not any("loose" in w for w in check.warnings)


def test_a_wider_trunk_warns_of_loose_clothing(scene):
    """A shirt: the trunk's outline grown by 3 px, the limbs as they are."""
    model, cameras, states = scene
    trunk = _region_faces(model, ("torso", "pelvis"))
    frames = _with_grown_region(model, cameras, states, trunk, 3)
    check = check_outline(model, cameras, frames)
    px = _mm_per_px(cameras, states[0])
    assert check.trunk_excess_mm > 1.5 * px
    assert abs(check.offsets_mm["lower limbs"]) < EXACT_MM
    assert any(w.startswith("loose clothing likely") for w in check.warnings)
    # A threshold above the excess silences it.
    quiet = check_outline(
        model, cameras, frames, config=OutlineConfig(loose_mm=check.trunk_excess_mm + 1)
    )
    assert not any("loose" in w for w in quiet.warnings)


def test_in_low_contrast_a_body_too_big_for_its_bare_limbs_warns(scene):
    """Forearms and shins 1 px inside the fitted body (the fit inflated by a loose
    shirt): in low contrast the trunk's excess is held to ``loose_mm`` again, however
    lenient ``loose_mm_low_contrast``; with the limbs' bound beyond their offset, not."""
    model, cameras, states = scene
    frames = _with_thinned_parts(model, cameras, states, REGIONS["lower limbs"])
    # Everything but the limbs is clothing.
    rest = _faces_but(model, REGIONS["lower limbs"])
    shirt = [_masks(model, cameras, s, rest) for s in states]

    def loose(check):
        return [w for w in check.warnings if w.startswith("loose clothing")]

    def sure(check):  # low contrast alone says "possible" above loose_mm
        return [w for w in check.warnings if w.startswith("loose clothing likely")]

    # (A pixel here is about 5 mm: limbs a pixel thinner than the body would also
    # read as legs hidden by a skirt, which is not what this test is about.)
    lenient = OutlineConfig(loose_mm_low_contrast=50.0, legs_hidden_mm=60.0)
    kw = {"config": lenient, "low_contrast": True}
    check = check_outline(model, cameras, frames, clothing=shirt, **kw)
    assert check.offsets_mm["bare shins"] < -lenient.shins_inside_mm
    assert check.offsets_mm["bare lower limbs"] < -lenient.shins_inside_mm
    # Not where capture did not tell the limbs bare, nor where it called them clothing:
    # in low contrast a clothed limb's captured outline lies inside its own.
    assert not sure(check_outline(model, cameras, frames, **kw))
    suit = [masks for masks, _ in frames]
    assert not sure(check_outline(model, cameras, frames, clothing=suit, **kw))
    (likely,) = loose(check)
    assert likely.startswith("loose clothing likely") and "inside the fitted body" in likely
    # Limbs inside a body fitted too big are not hair at its (bare) crown.
    assert abs(check.crown_excess_mm) < EXACT_MM
    assert not [w for w in check.warnings if w.startswith("hair")]
    # The limbs' bound past their offset: the lenient low-contrast threshold holds.
    far = OutlineConfig(loose_mm_low_contrast=50.0, shins_inside_mm=50.0, legs_hidden_mm=60.0)
    assert not sure(
        check_outline(model, cameras, frames, config=far, low_contrast=True, clothing=shirt)
    )
    # In full contrast the threshold is loose_mm whatever the limbs say.
    assert loose(check_outline(model, cameras, frames, config=far, clothing=shirt))


def test_in_low_contrast_the_trunk_is_compared_with_the_bare_limbs(scene):
    """Shins in trousers whose captured outline lies 1 px inside (a low-contrast rim
    lost), forearms bare and exact: in low contrast the trunk's excess is taken over
    the bare forearms alone, in full contrast over both, as calibrated."""
    model, cameras, states = scene
    frames = _with_thinned_parts(model, cameras, states, ("shin_l", "shin_r"))
    bare = _faces_but(model, ("lower_arm_l", "lower_arm_r", "hand_l", "hand_r"))
    worn = [_masks(model, cameras, s, bare) for s in states]
    low = check_outline(model, cameras, frames, clothing=worn, low_contrast=True)
    full = check_outline(model, cameras, frames, clothing=worn)
    assert abs(low.offsets_mm["bare lower limbs"]) < EXACT_MM
    assert abs(low.trunk_excess_mm) < EXACT_MM
    assert full.trunk_excess_mm > low.trunk_excess_mm + 0.5


def test_in_low_contrast_a_limb_outside_its_outline_is_not_the_reference(scene):
    """A forearm whose observed outline lies 3 px outside the fitted one (a limb the
    fit misplaced) is not the limb the fit meets best: in low contrast the trunk is
    compared with the limb group nearest zero (here the exact shins), not the larger."""
    model, cameras, states = scene
    forearms = _region_faces(model, ("lower_arm_l", "lower_arm_r"))
    frames = _with_grown_region(model, cameras, states, forearms, 3)
    low = check_outline(model, cameras, frames, low_contrast=True)
    assert low.offsets_mm["forearms"] > _mm_per_px(cameras, states[0])
    assert abs(low.offsets_mm["shins"]) < EXACT_MM
    assert abs(low.trunk_excess_mm) < EXACT_MM


def test_hair_at_the_crown_warns(scene):
    model, cameras, states = scene
    crown = crown_vertices(model, lod=False)
    faces = model.faces()[crown[model.faces()].all(axis=1)]
    frames = _with_grown_region(model, cameras, states, faces, 3)
    check = check_outline(model, cameras, frames)
    assert check.offsets_mm["crown"] > 1.5 * _mm_per_px(cameras, states[0])
    assert any(w.startswith("hair or headwear likely") for w in check.warnings)
    assert not any("loose" in w for w in check.warnings)


def test_coarse_pixels_decide_nothing(scene):
    """At 160x120 a working pixel is ~50 mm: the same wider trunk gives no verdict."""
    model, _, states = scene
    cameras = studio_rig(4, (160, 120), seed=4)
    trunk = _region_faces(model, ("torso", "pelvis"))
    frames = _with_grown_region(model, cameras, states, trunk, 1)
    check = check_outline(model, cameras, frames)
    assert check.mm_per_px > OutlineConfig().max_mm_per_px
    assert check.status.startswith("undecided") and check.warnings == ()
    assert np.isfinite(check.trunk_excess_mm)  # the figures are kept


def test_regions_are_parts_of_the_mesh():
    model = BodyModel.load()
    for lod in (False, True):
        parts = model.parts_of_vertices(lod)
        assert len(parts) == model.pose(BodyState.rest(model.n_shape), lod=lod).vertices.shape[1]
        crown = crown_vertices(model, lod)
        assert crown.any() and np.all(parts[crown] == PARTS.index("head"))
    # the crown is the top of the head, a small share of it
    parts = model.parts_of_vertices(False)
    assert crown_vertices(model, False).sum() < 0.5 * (parts == PARTS.index("head")).sum()


def test_lod_refinement_gives_the_same_verdict(scene):
    model, cameras, states = scene
    frames = [(_masks(model, cameras, s), s) for s in states]
    check = check_outline(model, cameras, frames, RefineConfig(full_mesh=False))
    assert abs(check.trunk_excess_mm) < 2 * EXACT_MM and check.warnings == ()


def test_no_frames_gives_nan_and_no_warning():
    model = BodyModel.load()
    check = check_outline(model, studio_rig(4, (64, 48), seed=4), [])
    assert check.frames == 0 and np.isnan(check.trunk_excess_mm) and check.warnings == ()
    assert check.status == "no contour"


def test_config_is_validated():
    with pytest.raises(ValueError, match="loose_mm"):
        OutlineConfig(loose_mm=0)
    with pytest.raises(ValueError, match="min_points"):
        OutlineConfig(min_points=0)
    with pytest.raises(ValueError, match="max_mm_per_px"):
        OutlineConfig(max_mm_per_px=0)


def test_a_kept_alignment_gives_the_same_offsets(scene):
    """The session stage's contour cost and correspondences, reused: the same offsets
    at its state, and at another state the ones computed afresh."""
    model, cameras, states = scene
    trunk = _region_faces(model, ("torso", "pelvis"))
    masks, state = _with_grown_region(model, cameras, states[:1], trunk, 3)[0]
    config = RefineConfig()
    cost = ContourCost(model, prepare_contours(cameras, masks, config.image_scale), config)
    alignment = Alignment(cost, state.copy(), cost.evaluate(state)[1])
    fresh = frame_offsets(model, cameras, masks, state, config)
    for got, want in zip(
        frame_offsets(model, cameras, masks, state, config, alignment), fresh, strict=True
    ):
        np.testing.assert_array_equal(got, want)
    moved = state.copy()
    moved[0] += 0.01
    for got, want in zip(
        frame_offsets(model, cameras, masks, moved, config, alignment),
        frame_offsets(model, cameras, masks, moved, config),
        strict=True,
    ):
        np.testing.assert_array_equal(got, want)
    check = check_outline(model, cameras, [(masks, state)], config, alignments=[alignment])
    again = check_outline(model, cameras, [(masks, state)], config)
    assert check.to_json() == again.to_json() and check.warnings  # one frame: s.e. NaN
    with pytest.raises(ValueError, match="alignments: expected 1, got 2"):
        check_outline(model, cameras, [(masks, state)], config, alignments=[None, None])


def test_json_round_trip_inside_the_session_block():
    check = OutlineCheck(
        status="ok",
        mm_per_px=9.8,
        frames=4,
        offsets_mm={"trunk": 2.5, "lower limbs": -1.0, "crown": float("nan")},
        trunk_excess_mm=3.5,
        trunk_excess_se_mm=0.4,
        warnings=("loose clothing likely: ...",),
    )
    shape = SessionShape(status="ok", outline=check)
    back = SessionShape.from_json(shape.to_json())
    assert back.outline.offsets_mm["trunk"] == 2.5 and np.isnan(back.outline.offsets_mm["crown"])
    assert back.outline == OutlineCheck.from_json(check.to_json())
    assert back.outline.warnings == check.warnings and back.outline.trunk_excess_mm == 3.5
    assert back.outline.mm_per_px == 9.8 and back.outline.status == "ok"
    assert SessionShape.from_json(SessionShape(status="ok").to_json()).outline is None
    info = SessionInfo("/s", "s", ("cam_00",), 25.0, 10)
    assert RunResults.of_subject(info, ProcessConfig(), session_shape=shape).outline == check
    assert RunResults.of_subject(info, ProcessConfig()).outline is None
    ok = SessionShape(status="ok")
    assert RunResults.of_subject(info, ProcessConfig(), session_shape=ok).outline is None
    with pytest.raises(InputError, match=r"session_shape\.outline"):
        SessionShape.from_json({"status": "ok", "outline": [1, 2]})
    with pytest.raises(InputError, match="malformed outline"):
        OutlineCheck.from_json({"frames": "many"})


def test_one_frame_warns_without_a_standard_error(scene):
    model, cameras, states = scene
    trunk = _region_faces(model, ("torso", "pelvis"))
    check = check_outline(model, cameras, _with_grown_region(model, cameras, states[:1], trunk, 3))
    assert np.isnan(check.trunk_excess_se_mm)
    (warning,) = [w for w in check.warnings if w.startswith("loose clothing likely")]
    assert "nan" not in warning and f"{check.trunk_excess_mm:.1f} mm further" in warning


def test_a_warning_within_one_standard_error_of_its_threshold_says_so():
    """A figure above its threshold by less than its standard error: the warning
    stands, and says the frames do not settle it."""
    from bodymetry.estimation.outline_check import _borderline

    assert _borderline(3.3, 1.3, 3.2).startswith("; borderline")
    assert _borderline(5.0, 1.3, 3.2) == ""
    assert _borderline(3.3, float("nan"), 3.2) == ""  # one frame: no standard error


def test_a_figure_within_one_standard_error_below_the_threshold_says_it_cannot_tell():
    from bodymetry.estimation.outline_check import _clothing_warnings

    config = OutlineConfig()
    t = config.loose_mm
    (possible,) = _clothing_warnings(t - 0.2, 0.3, 0.0, 0.1, config)
    assert possible.startswith("loose clothing possible") and "do not settle" in possible
    assert _clothing_warnings(t - 0.5, 0.3, 0.0, 0.1, config) == []  # over one s.e. below
    assert _clothing_warnings(t - 0.2, float("nan"), 0.0, 0.1, config) == []  # one frame
    (likely,) = _clothing_warnings(t + 0.3, 0.4, 0.0, 0.1, config)
    assert likely.startswith("loose clothing likely")


def test_a_run_seen_in_low_contrast_is_held_to_its_own_threshold():
    """In low contrast the captured outline itself errs by part: the studio's tight
    subjects read up to +1.56 +- 0.74 mm there, so loose clothing needs more."""
    from bodymetry.estimation.outline_check import _clothing_warnings

    config = OutlineConfig()
    low = config.loose_mm_low_contrast
    assert low > config.loose_mm
    # A tight low-contrast session of the studio: "likely" in full contrast; in low
    # contrast, between the thresholds, "possible": the check cannot tell there.
    (full,) = _clothing_warnings(1.56, 0.74, 0.0, 0.1, config)
    assert full.startswith("loose clothing likely")
    (low_one,) = _clothing_warnings(1.56, 0.74, 0.0, 0.1, config, low_contrast=True)
    assert low_one.startswith("loose clothing possible") and "cannot tell" in low_one
    assert _clothing_warnings(1.2, 0.5, 0.0, 0.1, config, low_contrast=True) == []
    (likely,) = _clothing_warnings(low + 0.5, 0.3, 0.0, 0.1, config, low_contrast=True)
    assert likely.startswith("loose clothing likely")
    assert f"tight clothing in low contrast: under {low:g} mm" in likely
    (possible,) = _clothing_warnings(low - 0.2, 0.3, 0.0, 0.1, config, low_contrast=True)
    assert possible.startswith("loose clothing possible")
    # Hair is judged as before, and a bare trunk wears no loose shirt in any contrast.
    (hair,) = _clothing_warnings(0.0, 0.1, 12.0, 0.5, config, low_contrast=True)
    assert hair.startswith("hair or headwear likely")
    assert _clothing_warnings(5.0, 0.3, 0.0, 0.1, config, 0.2, low_contrast=True) == []
    with pytest.raises(ValueError, match="loose_mm_low_contrast"):
        OutlineConfig(loose_mm_low_contrast=0.0)


def test_in_low_contrast_bare_shins_inside_the_body_restore_the_full_contrast_threshold():
    """The studio's loose shirt with a 10 mm gap in low contrast (seed 801): trunk
    excess 2.16 +- 0.20 mm, the bare shins 2.24 mm inside the fitted body, 9 kg
    heavy; seven tight subjects' bare shins (in shorts) at most 0.57 mm inside in full
    contrast, 1.27 mm in low contrast (seed 877: warned "possible", and why)."""
    from bodymetry.estimation.outline_check import _clothing_warnings

    config = OutlineConfig()
    (likely,) = _clothing_warnings(2.16, 0.2, 0.0, 0.1, config, low_contrast=True, shins=-2.24)
    assert likely.startswith("loose clothing likely")
    assert (
        f"under {config.loose_mm:g} mm, in low contrast too" in likely and "here 2.2 mm" in likely
    )
    for shins in (-0.76, 0.0, float("nan")):  # tight, or no bare shins: the lenient bound
        (which,) = _clothing_warnings(2.16, 0.2, 0.0, 0.1, config, low_contrast=True, shins=shins)
        assert which.startswith("loose clothing possible") and "cannot tell" in which
    (possible,) = _clothing_warnings(1.2, 0.2, 0.0, 0.1, config, low_contrast=True, shins=-2.0)
    assert possible.startswith("loose clothing possible")
    # Shins inside and nothing at the trunk, in low contrast: said, with why it may be tight.
    (shins,) = _clothing_warnings(0.13, 0.46, 0.0, 0.1, config, low_contrast=True, shins=-1.27)
    assert shins.startswith("loose clothing possible: the bare shins lie 1.3")
    assert "cannot tell them apart" in shins
    # In any contrast, shins that far inside warn "possible" on their own: the
    # studio's loose shirt with a 7 mm gap (seed 831, +5.0 kg) read 1.23 +- 0.24 mm
    # of trunk excess and its bare shins 1.15 mm inside.
    (possible,) = _clothing_warnings(0.98, 0.23, 0.0, 0.1, config, shins=-1.15)
    assert possible.startswith("loose clothing possible: the bare shins lie 1.1")
    assert "cannot tell" not in possible  # in full contrast skin keeps its outline
    assert _clothing_warnings(0.98, 0.23, 0.0, 0.1, config, shins=-0.76) == []
    # Nothing for a bare trunk.
    assert _clothing_warnings(2.16, 0.2, 0.0, 0.1, config, 0.2, True, -2.24) == []
    with pytest.raises(ValueError, match="shins_inside_mm"):
        OutlineConfig(shins_inside_mm=0.0)


def test_bare_shins_far_inside_say_the_legs_were_hidden():
    """Knee-length skirts (``clothing=skirt``): the fit shapes the thighs to the skirt
    and turns the hips to fill it, the bare shins below lie 5.44-13.73 mm inside the
    fitted body and the height reads up to 52 mm high; loose shorts' bare shins lie
    at most 3.43 mm inside, tight shorts' 1.27 mm (docs/session-shape.md, "Skirts")."""
    from bodymetry.estimation.outline_check import _clothing_warnings

    config = OutlineConfig()
    # A skirt on a heavy woman (seed 901): the trunk warns, and the legs on their own.
    loose, hidden = _clothing_warnings(2.88, 1.18, 2.06, 0.74, config, 0.95, shins=-9.0)
    assert loose.startswith("loose clothing likely")
    assert hidden.startswith("legs hidden likely: the bare shins lie 9.0 mm inside")
    check = OutlineCheck(warnings=(loose, hidden))
    assert set(check.overstated) == {"height_mm", "arm_span_mm", "weight_kg"}
    assert check.overstated["height_mm"] == "legs hidden"
    # Whatever the trunk (bare, or nothing outside), in any contrast.
    for kwargs in ({"trunk_share": 0.1}, {"low_contrast": True}, {}):
        warnings = _clothing_warnings(0.1, 0.3, 0.0, 0.1, config, shins=-5.9, **kwargs)
        assert [w for w in warnings if w.startswith("legs hidden likely")], kwargs
        # ... and the shins' "possible" is not said twice.
        assert not [w for w in warnings if w.startswith("loose clothing possible: the bare")]
    # Loose shorts (seed 833's 3.43 mm, a 20 mm gap): loose clothing possible, the legs not hidden.
    (possible,) = _clothing_warnings(0.5, 0.3, 0.0, 0.1, config, shins=-3.43)
    assert possible.startswith("loose clothing possible: the bare shins lie 3.4")
    assert OutlineCheck(warnings=(possible,)).overstated == {
        "arm_span_mm": "loose clothing",
        "weight_kg": "loose clothing",
    }
    with pytest.raises(ValueError, match="legs_hidden_mm"):
        OutlineConfig(legs_hidden_mm=0.5)


def test_bare_shins_a_pixel_inside_the_body_read_as_hidden_legs(scene):
    """The whole check on silhouettes whose bare shins are a pixel (about 5 mm) thinner
    than the fitted body, the rest its own outline: "legs hidden", in full contrast
    and in low; with the shins called clothing, nothing of the kind."""
    model, cameras, states = scene
    shins = ("shin_l", "shin_r")
    frames = _with_thinned_parts(model, cameras, states, shins)
    clothed = [_masks(model, cameras, s, _faces_but(model, shins)) for s in states]
    for low in (False, True):
        check = check_outline(model, cameras, frames, clothing=clothed, low_contrast=low)
        assert check.offsets_mm["bare shins"] <= -OutlineConfig().legs_hidden_mm
        assert [w for w in check.warnings if w.startswith("legs hidden likely")], low
        assert set(check.overstated) == {"height_mm", "arm_span_mm", "weight_kg"}
    suit = [masks for masks, _ in frames]
    covered = check_outline(model, cameras, frames, clothing=suit)
    assert not [w for w in covered.warnings if w.startswith("legs hidden")]


def test_thin_bare_forearms_alone_are_not_loose_clothing(scene):
    """A tight-clothed body whose bare forearms are thinner than the fitted ones (the
    shape space's reach: seed 42's 76-year-old woman, 2.5 mm inside, her weight
    within 0.1 kg), shins in trousers: the forearms alone warn of nothing, and in low
    contrast the trunk is compared with the limbs the fit meets best (here the
    shins). In full contrast the trunk's excess stays over all the lower limbs, as
    calibrated (in this scene the forearms' points outnumber the shins')."""
    model, cameras, states = scene
    forearms = ("lower_arm_l", "lower_arm_r")
    frames = _with_thinned_parts(model, cameras, states, forearms)
    bare = _faces_but(model, (*forearms, "hand_l", "hand_r"))
    worn = [_masks(model, cameras, s, bare) for s in states]
    low = check_outline(model, cameras, frames, clothing=worn, low_contrast=True)
    assert low.offsets_mm["bare lower limbs"] < -OutlineConfig().shins_inside_mm
    assert np.isnan(low.offsets_mm.get("bare shins", np.nan))
    assert abs(low.trunk_excess_mm) < EXACT_MM
    assert not [w for w in low.warnings if "loose" in w], low.warnings
    full = check_outline(model, cameras, frames, clothing=worn)
    assert not [w for w in full.warnings if "bare shins" in w]
    assert full.trunk_excess_mm > low.trunk_excess_mm + 0.5


def test_a_bare_trunk_wears_no_loose_shirt():
    from bodymetry.estimation.outline_check import _clothing_warnings

    config = OutlineConfig()
    for trunk in (3.0, 5.0):  # below and above the threshold
        assert _clothing_warnings(trunk, 0.3, 0.0, 0.1, config, trunk_share=0.2) == []
        assert _clothing_warnings(trunk, 0.3, 0.0, 0.1, config, trunk_share=0.9)
    # Hair is judged all the same.
    (hair,) = _clothing_warnings(5.0, 0.3, 12.0, 0.5, config, trunk_share=0.2)
    assert hair.startswith("hair or headwear likely")


def test_the_trunks_share_on_clothing_is_measured_where_capture_told(scene):
    model, cameras, states = scene
    frames = [(_masks(model, cameras, s), s) for s in states]
    trunk = _region_faces(model, ("torso", "pelvis"))
    shirts = [_masks(model, cameras, s, trunk) for s in states]
    told = check_outline(model, cameras, frames, clothing=shirts)
    # The trunk's outline points lie on its own silhouette (within a pixel), but
    # where an arm or the legs cover its edge they are theirs.
    assert 0.6 < told.trunk_clothing_share <= 1.0
    bare = check_outline(
        model, cameras, frames, clothing=[[np.zeros_like(m) for m in f] for f in shirts]
    )
    assert bare.trunk_clothing_share == 0.0
    assert np.isnan(check_outline(model, cameras, frames).trunk_clothing_share)
    with pytest.raises(ValueError, match="clothing"):
        check_outline(model, cameras, frames, clothing=shirts[:1])
    back = OutlineCheck.from_json(told.to_json())
    assert back.trunk_clothing_share == pytest.approx(told.trunk_clothing_share, abs=1e-3)
    assert np.isnan(OutlineCheck.from_json({"status": "ok"}).trunk_clothing_share)


def test_an_alignment_at_another_scale_finds_the_clothing_at_its_own_pixels(scene):
    """The session stage aligns at full resolution while the run's refinement works
    at half: where its outline points lie in the masks follows the alignment's
    scale, so the trunk's clothing share is what a fresh full-scale check finds."""
    model, cameras, states = scene
    state = states[0]
    masks = _masks(model, cameras, state)
    shirts = _masks(model, cameras, state, _region_faces(model, ("torso", "pelvis")))
    half, full = RefineConfig(image_scale=0.5), RefineConfig(image_scale=1.0)
    cost = ContourCost(model, prepare_contours(cameras, masks, full.image_scale), full)
    assert cost.obs.scale == 1.0
    assert prepare_contours(cameras, masks, half.image_scale).scale == 0.5
    alignment = Alignment(cost, state.copy(), cost.evaluate(state)[1])
    kept = check_outline(
        model, cameras, [(masks, state)], half, alignments=[alignment], clothing=[shirts]
    )
    fresh = check_outline(model, cameras, [(masks, state)], full, clothing=[shirts])
    assert kept.trunk_clothing_share == pytest.approx(fresh.trunk_clothing_share, abs=1e-9)
    assert kept.trunk_clothing_share > 0.6
