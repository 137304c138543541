"""Looks: what the subject wears, which room it stands in and which light falls on it.

A :class:`Look` has three independent axes, so that the capture stage can be
measured per appearance class (issue 32: silhouettes that do not depend on
colour contrast):

- ``clothing``: ``saturated`` (the studio's part colours, ``PART_COLORS``: red
  shirt, blue trousers), ``white``, ``light_grey``, ``black`` or ``wall`` (the
  room's own wall albedo). Only the garments change: the shirt (torso and upper
  arms, i.e. short sleeves) and the trousers (pelvis, thighs and shins). Skin
  (head, forearms, hands, and any garment part the base appearance dresses in
  skin, such as the bare shins below an independent subject's loose shorts),
  the hair, the dark shoes and the per-vertex fabric variation stay as they are.
- ``room``: ``textured`` (the tiled lab with panels, :class:`~.scene.Room`) or
  ``plain`` (:data:`PLAIN_ROOM`: grey paint and a grey linoleum floor with only
  faint noise; no tiles, grout, panels or baseboard).
- ``light``: ``hard`` (the studio's key light: 1.2 cm penumbra, key-to-ambient
  1.24) or ``soft`` (an extended source: 6 cm penumbra, key-to-ambient 0.41, the
  same brightness on the floor and on walls facing the light within 1 %).

``Look.parse("clothing=white,room=plain,light=soft")`` reads the ``--look``
text of ``bodymetry synth``; ``Look()`` is today's studio, pixel for pixel.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bodymetry.capture.ground_truth import StudioRecord
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.skeleton import PARTS
from bodymetry.studio.scene import Appearance, Light, Room

#: Clothing choices, the default first.
CLOTHING_CHOICES: tuple[str, ...] = ("saturated", "white", "light_grey", "black", "wall")
#: Room choices, the default first.
ROOM_CHOICES: tuple[str, ...] = ("textured", "plain")
#: Light choices, the default first.
LIGHT_CHOICES: tuple[str, ...] = ("hard", "soft")
_CHOICES: dict[str, tuple[str, ...]] = {
    "clothing": CLOTHING_CHOICES,
    "room": ROOM_CHOICES,
    "light": LIGHT_CHOICES,
}

#: Garment albedos (BGR, 0..1) of the neutral clothing choices: white cotton,
#: light grey jersey, black fabric (real black cloth reflects 4-8 %).
NEUTRAL_ALBEDO: dict[str, tuple[float, float, float]] = {
    "white": (0.85, 0.85, 0.85),
    "light_grey": (0.60, 0.60, 0.60),
    "black": (0.06, 0.06, 0.065),
}
#: Parts (indices into ``skeleton.PARTS``) a garment covers: the shirt with short
#: sleeves and the long trousers. Feet (shoes), head, forearms and hands are not.
SHIRT_PARTS: tuple[int, ...] = tuple(
    PARTS.index(p) for p in ("torso", "upper_arm_l", "upper_arm_r")
)
TROUSER_PARTS: tuple[int, ...] = tuple(
    PARTS.index(p) for p in ("pelvis", "thigh_l", "shin_l", "thigh_r", "shin_r")
)
GARMENT_PARTS: tuple[int, ...] = SHIRT_PARTS + TROUSER_PARTS
_SKIN_PART = PARTS.index("head")

#: The plain room: the textured lab's geometry, ceiling and light fixtures, with
#: neutral grey paint (albedo 0.66) and a slightly darker grey linoleum floor
#: (0.55); only faint noise (1-3 %), no tiles, grout, panels or baseboard.
PLAIN_ROOM = Room(
    floor_color=(0.55, 0.55, 0.55),
    wall_color=(0.66, 0.66, 0.66),
    panels=(),
    tile_tone=0.0,
    tile_hue=0.0,
    grout_depth=0.0,
    floor_cloud=0.03,
    floor_speckle=0.03,
    wall_mottle=0.02,
    baseboard_height=0.0,
)


def studio_light_direction() -> np.ndarray:
    """(3,) travel direction of the studio's key light: azimuth 0°, elevation 50°,
    between two cameras of the rig, so that every camera sees the cast shadow."""
    return Light.direction_from_angles(azimuth_deg=0.0, elevation_deg=50.0)


def _hard_light() -> Light:
    """The studio's key light (the default ``Light`` from the studio's direction)."""
    return Light(direction=studio_light_direction())


def _soft_light() -> Light:
    """An extended, diffuse source (a large window, a bounced light).

    The key is halved and the ambient raised so that a floor and a wall facing the
    light keep their brightness (within 1 % of :func:`_hard_light`) while a cast
    shadow removes a quarter of the floor's light instead of half, with a penumbra
    five times wider.
    """
    return Light(direction=studio_light_direction(), key=0.30, ambient=0.74, penumbra=0.06)


@dataclass(frozen=True)
class Look:
    """How a studio session looks: the subject's clothing, the room and the light.

    Attributes
    ----------
    clothing : str
        One of :data:`CLOTHING_CHOICES`.
    room : str
        One of :data:`ROOM_CHOICES`.
    light : str
        One of :data:`LIGHT_CHOICES`.
    """

    clothing: str = "saturated"
    room: str = "textured"
    light: str = "hard"

    def __post_init__(self) -> None:
        for key, choices in _CHOICES.items():
            value = getattr(self, key)
            if value not in choices:
                raise InputError(f"look: {key}={value!r}, expected one of {', '.join(choices)}")

    # --- text and records ---------------------------------------------------------
    @classmethod
    def parse(cls, text: str | None) -> Look:
        """Read ``"clothing=C,room=R,light=L"`` (any subset in any order; the rest
        default; None or an empty text is the default look).

        Raises
        ------
        InputError
            An unknown key, a repeated key, a missing ``=`` or an unknown value; the
            message names the text and the choices.
        """
        if text is None or not text.strip():
            return cls()
        fields: dict[str, str] = {}
        for item in text.split(","):
            key, sep, value = (p.strip() for p in item.partition("="))
            if not sep or key not in _CHOICES:
                raise InputError(
                    f"--look {text!r}: unknown option {item.strip()!r}, expected {look_usage()}"
                )
            if key in fields:
                raise InputError(f"--look {text!r}: {key} is given twice")
            if value not in _CHOICES[key]:
                raise InputError(
                    f"--look {text!r}: {key}={value!r}, expected one of {', '.join(_CHOICES[key])}"
                )
            fields[key] = value
        return cls(**fields)

    def to_text(self) -> str:
        """The ``--look`` text of this look (all three keys; ``parse`` gives it back)."""
        return f"clothing={self.clothing},room={self.room},light={self.light}"

    @classmethod
    def from_json(cls, data: dict[str, Any] | None) -> Look:
        """The look recorded in ``ground_truth/studio.json`` (``config.look``);
        None or missing keys (sessions rendered before looks existed) are the defaults."""
        if data is None:
            return cls()
        unknown = sorted(set(data) - set(_CHOICES))
        if unknown:
            raise InputError(f"look {data!r}: unknown keys {unknown}, expected {look_usage()}")
        return cls(**{k: str(v) for k, v in data.items()})

    def to_json(self) -> dict[str, str]:
        """The look as ``studio.json`` records it."""
        return dataclasses.asdict(self)

    @property
    def label(self) -> str:
        """Short name for tables and plots, e.g. ``"white/plain/soft"``."""
        return f"{self.clothing}/{self.room}/{self.light}"

    @property
    def appearance_class(self) -> str:
        """The class benchmarks group sessions by: ``"saturated"`` (the studio's
        coloured clothes), ``"neutral"`` (white, light grey, black) or
        ``"wall-coloured"`` (the room's wall albedo)."""
        if self.clothing == "saturated":
            return "saturated"
        if self.clothing == "wall":
            return "wall-coloured"
        return "neutral"

    @property
    def is_default(self) -> bool:
        """Whether this is today's studio (saturated/textured/hard)."""
        return self == Look()

    # --- what the renderer needs ---------------------------------------------------
    def build_room(self) -> Room:
        """The :class:`Room` of this look (a new default ``Room`` for ``textured``)."""
        return Room() if self.room == "textured" else PLAIN_ROOM

    def build_light(self) -> Light:
        """The key and ambient :class:`Light` of this look."""
        return _hard_light() if self.light == "hard" else _soft_light()

    def garment_albedo(self) -> np.ndarray | None:
        """(3,) BGR albedo of shirt and trousers, or None for ``saturated`` (the
        base appearance's own colours)."""
        if self.clothing == "saturated":
            return None
        if self.clothing == "wall":
            return np.asarray(self.build_room().wall_color, dtype=float)
        return np.asarray(NEUTRAL_ALBEDO[self.clothing], dtype=float)

    def appearance(self, base: Appearance) -> Appearance:
        """``base`` with its garments recoloured (``base`` itself for ``saturated``).

        A garment part (:data:`GARMENT_PARTS`) that ``base`` dresses in skin (the
        head's colour, e.g. the bare shins of an independent subject in loose
        shorts) stays skin; the hair colour, the variation and its seed are kept.
        """
        albedo = self.garment_albedo()
        if albedo is None:
            return base
        colors = np.array(base.part_colors, dtype=float, copy=True)
        skin = colors[_SKIN_PART]
        for part in GARMENT_PARTS:
            if not np.array_equal(colors[part], skin):
                colors[part] = albedo
        return dataclasses.replace(base, part_colors=colors)


def look_usage() -> str:
    """The keys and choices of a look, for messages and help texts:
    ``clothing=saturated|white|...; room=textured|plain; light=hard|soft``."""
    return "; ".join(f"{key}={'|'.join(choices)}" for key, choices in _CHOICES.items())


def recorded_look(ground_truth: str | Path) -> Look:
    """The look a studio session was rendered with, from its ``ground_truth/studio.json``
    (the default look when the session has no record or the record names none).

    Parameters
    ----------
    ground_truth : path
        The session's ground-truth folder.
    """
    record = StudioRecord.read(Path(ground_truth))
    return Look() if record is None else Look.from_json(record.look)
