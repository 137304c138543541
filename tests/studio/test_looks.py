"""Studio looks: parsing, garment colours, the plain room and the soft light."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from bodymetry.calibration.camera import Camera
from bodymetry.capture.ground_truth import StudioRecord
from bodymetry.cli import main
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.skeleton import PARTS
from bodymetry.studio.independent import IndependentSpec, IndependentSubject
from bodymetry.studio.looks import (
    CLOTHING_CHOICES,
    GARMENT_PARTS,
    LIGHT_CHOICES,
    NEUTRAL_ALBEDO,
    PLAIN_ROOM,
    ROOM_CHOICES,
    Look,
    recorded_look,
)
from bodymetry.studio.render import Studio
from bodymetry.studio.scene import FLOOR, WALL_YMIN, Appearance, Light, Room

SKIN_PARTS = tuple(
    PARTS.index(p) for p in ("head", "lower_arm_l", "hand_l", "lower_arm_r", "hand_r")
)
SHOES = tuple(PARTS.index(p) for p in ("foot_l", "foot_r"))


# --- text and records ---------------------------------------------------------------


@pytest.mark.parametrize("clothing", CLOTHING_CHOICES)
@pytest.mark.parametrize("room", ROOM_CHOICES)
@pytest.mark.parametrize("light", LIGHT_CHOICES)
def test_parse_round_trip(clothing, room, light):
    look = Look(clothing, room, light)
    assert Look.parse(look.to_text()) == look
    assert Look.from_json(json.loads(json.dumps(look.to_json()))) == look
    assert look.label == f"{clothing}/{room}/{light}"


def test_parse_subsets_default_the_rest():
    assert Look.parse(None) == Look.parse("") == Look() == Look("saturated", "textured", "hard")
    assert Look.parse(" light = soft , clothing=white") == Look("white", "textured", "soft")
    assert Look.parse("room=plain") == Look(room="plain")
    assert Look().is_default and not Look(light="soft").is_default


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("clothing=pink", "clothing='pink', expected one of saturated, white, light_grey"),
        ("colour=white", "unknown option 'colour=white', expected clothing=saturated|white"),
        ("white", "unknown option 'white'"),
        ("room=plain,room=textured", "room is given twice"),
        ("light=diffuse", "light='diffuse', expected one of hard, soft"),
        ("clothing=white,", "unknown option ''"),
    ],
)
def test_parse_errors_name_the_text_and_the_choices(text, message):
    with pytest.raises(InputError, match="--look") as info:
        Look.parse(text)
    assert repr(text) in str(info.value) and message in str(info.value)


def test_bad_values_and_records_are_refused():
    with pytest.raises(InputError, match="room='lab', expected one of textured, plain"):
        Look(room="lab")
    with pytest.raises(InputError, match="unknown keys"):
        Look.from_json({"clothes": "white"})
    assert Look.from_json(None) == Look.from_json({}) == Look()


def test_appearance_classes():
    classes = {c: Look(clothing=c).appearance_class for c in CLOTHING_CHOICES}
    assert classes == {
        "saturated": "saturated",
        "white": "neutral",
        "light_grey": "neutral",
        "black": "neutral",
        "wall": "wall-coloured",
    }


def test_recorded_look_reads_studio_json_and_old_records(tmp_path):
    assert recorded_look(tmp_path) == Look()  # no studio.json at all
    StudioRecord(config={"frames": 3}).write(tmp_path)  # rendered before looks existed
    assert StudioRecord.read(tmp_path).look == {} and recorded_look(tmp_path) == Look()
    look = Look("black", "plain", "soft")
    StudioRecord(config={"frames": 3, "look": look.to_json()}).write(tmp_path)
    assert recorded_look(tmp_path) == look
    StudioRecord(config={"look": "white"}).write(tmp_path)
    with pytest.raises(InputError, match=r"config\.look must be an object"):
        recorded_look(tmp_path)


# --- the default look is today's studio ------------------------------------------------


def test_default_look_is_todays_studio():
    look = Look()
    room, light = look.build_room(), look.build_light()
    assert room == Room()
    today = Light(direction=Light.direction_from_angles(azimuth_deg=0.0, elevation_deg=50.0))
    for name in ("direction", "color"):
        np.testing.assert_array_equal(getattr(light, name), getattr(today, name))
    for name in ("key", "ambient", "sky_falloff", "penumbra"):
        assert getattr(light, name) == getattr(today, name)
    base = Appearance()
    assert look.appearance(base) is base


# --- clothing -------------------------------------------------------------------------


@pytest.mark.parametrize("clothing", ["white", "light_grey", "black", "wall"])
def test_garments_recoloured_skin_hair_and_shoes_kept(clothing):
    look = Look(clothing=clothing, room="plain")
    base = Appearance()
    dressed = look.appearance(base)
    colors = np.asarray(dressed.part_colors)
    want = np.asarray(
        PLAIN_ROOM.wall_color if clothing == "wall" else NEUTRAL_ALBEDO[clothing], float
    )
    np.testing.assert_array_equal(colors[list(GARMENT_PARTS)], np.tile(want, (8, 1)))
    for part in SKIN_PARTS + SHOES:
        np.testing.assert_array_equal(colors[part], np.asarray(base.part_colors)[part])
    np.testing.assert_array_equal(dressed.hair_color, base.hair_color)
    assert (dressed.variation, dressed.seed) == (base.variation, base.seed)
    # Neutral: the three channels within 10 % of each other.
    assert np.ptp(want) <= 0.1 * want.mean()


def test_wall_clothing_takes_the_rooms_wall_albedo():
    textured = Look(clothing="wall").appearance(Appearance())
    torso = PARTS.index("torso")
    np.testing.assert_array_equal(textured.part_colors[torso], Room().wall_color)
    plain = Look(clothing="wall", room="plain").appearance(Appearance())
    np.testing.assert_array_equal(plain.part_colors[torso], PLAIN_ROOM.wall_color)


def test_independent_subject_keeps_its_bare_shins():
    subject = IndependentSubject(IndependentSpec(seed=0, clothing="loose"))
    base = subject.appearance()
    dressed = Look(clothing="black").appearance(base)
    colors, before = np.asarray(dressed.part_colors), np.asarray(base.part_colors)
    shins = [PARTS.index("shin_l"), PARTS.index("shin_r")]
    np.testing.assert_array_equal(colors[shins], before[[PARTS.index("head")] * 2])
    covered = [p for p in GARMENT_PARTS if p not in shins]
    np.testing.assert_array_equal(colors[covered], np.tile(NEUTRAL_ALBEDO["black"], (6, 1)))
    for part in SKIN_PARTS + SHOES:
        np.testing.assert_array_equal(colors[part], before[part])


# --- the plain room ---------------------------------------------------------------------


def _relative_std(room: Room, surface: int) -> tuple[float, np.ndarray]:
    """Relative spatial std of a room surface's albedo (luma) over a 2 x 2 m patch
    sampled every 7 mm at a 2 mm footprint, and its mean BGR albedo."""
    u, v = np.meshgrid(np.arange(-1.0, 1.0, 0.007), np.arange(0.0, 2.0, 0.007))
    if surface == FLOOR:
        points = np.stack([u, v - 1.0, np.zeros_like(u)], axis=-1)
    else:  # the wall at y = ymin, from the floor up
        points = np.stack([u, np.full_like(u, room.bounds[0, 1]), v + 0.01], axis=-1)
    albedo = room.albedo(points, np.full(u.shape, surface, np.int8), np.full(u.shape, 0.002))
    luma = albedo.mean(axis=-1)
    return float(luma.std() / luma.mean()), albedo.reshape(-1, 3).mean(axis=0)


def test_plain_room_has_no_tiles_grout_or_panels():
    floor_plain, floor_mean = _relative_std(PLAIN_ROOM, FLOOR)
    wall_plain, wall_mean = _relative_std(PLAIN_ROOM, WALL_YMIN)
    floor_tiled, _ = _relative_std(Room(), FLOOR)
    wall_panels, _ = _relative_std(Room(), WALL_YMIN)  # the bench and a baseboard here
    # Faint noise only (painted wall, linoleum) against tiles and grout, panels.
    assert floor_plain < 0.012 and wall_plain < 0.012, (floor_plain, wall_plain)
    assert floor_tiled > 0.04 and wall_panels > 0.1, (floor_tiled, wall_panels)
    # Neutral grey, the floor of a similar grey as the walls.
    for mean in (floor_mean, wall_mean):
        assert np.ptp(mean) < 0.01 * mean.mean()
    assert 0.7 < floor_mean.mean() / wall_mean.mean() < 1.0


# --- the soft light -----------------------------------------------------------------------


def _box_scene():
    """A 0.3 x 0.3 x 0.6 m box on the floor and a 160 x 120 camera 3 m above the
    floor looking straight down at the box's shadow (about 9 mm per pixel)."""
    c = np.array([[x, y, z] for x in (-0.15, 0.15) for y in (-0.15, 0.15) for z in (0.0, 0.6)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = np.array([t for a, b, cc, d in quads for t in ((a, b, cc), (a, cc, d))])
    R = np.diag([1.0, -1.0, -1.0])  # camera x along world x, looking down (-z)
    center = np.array([-0.4, 0.0, 3.0])
    K = np.array([[300.0, 0, 80.0], [0, 300.0, 60.0], [0, 0, 1.0]])
    camera = Camera("down", (160, 120), K, np.zeros(5), R, -R @ center)
    return c, faces, camera


def _shadow_profile(light: Light) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fraction of the floor's light a box's cast shadow removes per pixel (H, W),
    and the frame and the empty floor (H, W, 3) float, rendered without noise."""
    verts, faces, camera = _box_scene()
    # Flat albedo: the fabric noise field is meaningless on a mesh of 8 vertices.
    studio = Studio(
        faces,
        np.zeros(len(faces), int),
        light=light,
        room=PLAIN_ROOM,
        vertex_modulation=np.ones((len(verts), 3)),
    )
    frame = studio.render_frame(camera, verts, effects=False)
    empty = studio.render_background(camera, effects=False).astype(float)
    image = frame.image.astype(float)
    removed = 1.0 - image.mean(-1) / empty.mean(-1)
    removed[frame.person_mask] = np.nan
    return removed, image, empty


def test_soft_light_gives_a_weaker_wider_shadow_at_the_same_brightness():
    hard, _, empty_hard = _shadow_profile(Look(light="hard").build_light())
    soft, _, empty_soft = _shadow_profile(Look(light="soft").build_light())
    # The full shadow removes the key light's share of the floor's light:
    # about half under the hard light, about a quarter under the soft one.
    assert 0.42 < np.nanmax(hard) < 0.55 and 0.18 < np.nanmax(soft) < 0.30
    # Penumbra: pixels between 10 % and 90 % of the full shadow, at least 3x as many.
    band_hard = np.count_nonzero((hard > 0.1 * 0.487) & (hard < 0.9 * 0.487))
    band_soft = np.count_nonzero((soft > 0.1 * 0.237) & (soft < 0.9 * 0.237))
    assert band_soft > 3 * band_hard > 0, (band_hard, band_soft)
    # Roughly the same overall brightness of the lit floor (within 2 %).
    ratio = empty_soft.mean() / empty_hard.mean()
    assert abs(ratio - 1.0) < 0.02, ratio


# --- the command line ---------------------------------------------------------------------


def test_cli_lists_the_choices_and_refuses_a_bad_look(tmp_path):
    runner = CliRunner()
    assert "clothing=saturated|white|light_grey|black|wall" in " ".join(
        runner.invoke(main, ["synth", "--help"], terminal_width=200).output.split()
    )
    out = tmp_path / "s"
    result = runner.invoke(main, ["synth", str(out), "--look", "clothing=white,light=dim"])
    assert result.exit_code == 2, result.output
    assert "light='dim', expected one of hard, soft" in result.stderr
    assert not out.exists()
