"""A session's ground truth files, each one typed class read and written here.

A studio session (docs/session-format.md) has ``ground_truth/`` beside its
videos: ``subject.json`` (:class:`SubjectTruth`: the true measurements of the
subject, its shape ν when it is a body of our model, and how it was made),
``studio.json`` (:class:`StudioRecord`: how the studio rendered the session),
``states.npz``, the true silhouettes and the true cast shadows. The studio writes them; ``process``,
the review and the studio's evaluation read them, through these classes only.

A session with several people (``bodymetry synth --people N``) keeps the
subject's (person 0's) files where they are and adds, for each other person
``k``, the same files in ``ground_truth/persons/<k>/`` (:func:`person_folder`);
every person's folder also has ``occluded/<camera>/<frame>.png``, the pixels of
its whole projection that another person hides.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bodymetry.errors import InputError
from bodymetry.fileio import load_npz, read_json_object, write_json_atomic

__all__ = [
    "GROUND_TRUTH_OCCLUDED",
    "GROUND_TRUTH_PERSONS",
    "GROUND_TRUTH_SHADOWS",
    "GROUND_TRUTH_SILHOUETTES",
    "GROUND_TRUTH_STATES",
    "GROUND_TRUTH_STUDIO",
    "GROUND_TRUTH_SUBJECT",
    "MEASUREMENT_SUFFIXES",
    "StudioRecord",
    "SubjectTruth",
    "match_person",
    "person_folder",
]

#: The subject's true measurements and description, in ``ground_truth/``.
GROUND_TRUTH_SUBJECT = "subject.json"
#: The studio's record of a rendered session, in ``ground_truth/``.
GROUND_TRUTH_STUDIO = "studio.json"
#: The true body states per frame (``tau``, ``theta``, ``joints``, ...), in ``ground_truth/``.
GROUND_TRUTH_STATES = "states.npz"
#: The true silhouettes, ``ground_truth/silhouettes/<camera>/<frame>.png``.
GROUND_TRUTH_SILHOUETTES = "silhouettes"
#: The true cast shadows (no person pixel), ``ground_truth/shadows/<camera>/<frame>.png``.
#: Rendered with the body model of the render: re-rendering them later from the states
#: would follow whatever body model is current then.
GROUND_TRUTH_SHADOWS = "shadows"
#: Where another person hides a person, ``<person folder>/occluded/<camera>/<frame>.png``.
GROUND_TRUTH_OCCLUDED = "occluded"
#: The other persons' folders, ``ground_truth/persons/<k>/`` (k >= 1).
GROUND_TRUTH_PERSONS = "persons"
#: Keys of ``subject.json`` that are measurements (by their unit), besides ``bmi``.
MEASUREMENT_SUFFIXES = ("_mm", "_kg", "_l")


def _is_measurement(key: str, value: Any) -> bool:
    return (key == "bmi" or key.endswith(MEASUREMENT_SUFFIXES)) and isinstance(value, int | float)


def person_folder(ground_truth: Path, index: int) -> Path:
    """The folder of person ``index``'s ground truth: ``ground_truth`` itself for the
    subject (0), ``ground_truth/persons/<index>`` for the others.

    Raises
    ------
    InputError
        ``index`` is negative or not an integer.
    """
    if isinstance(index, bool) or not isinstance(index, int) or index < 0:
        raise InputError(f"person index: expected an integer >= 0, got {index!r}")
    ground_truth = Path(ground_truth)
    return ground_truth if index == 0 else ground_truth / GROUND_TRUTH_PERSONS / str(index)


@dataclass(frozen=True)
class SubjectTruth:
    """``ground_truth/subject.json``: who the studio rendered.

    Attributes
    ----------
    measurements : dict of str to float
        The true biometrics of the nude body (``height_mm``, ``weight_kg``, ...,
        in the units of their names), in the file's order.
    nu : tuple of float or None
        The shape in our model's space; None for a body made outside it (an
        independent subject).
    source : str
        How the body was drawn (``"calibrated prior, held-out body"``,
        ``"independent"``, ...).
    details : dict
        The rest of the description, as written (held-out index, the
        independent subject's spec, phenotype, clothing, ...).
    """

    measurements: dict[str, float]
    nu: tuple[float, ...] | None = None
    source: str = ""
    details: dict[str, Any] = field(default_factory=dict)

    def get(self, key: str) -> float | None:
        """The true value of a measurement, or None when the file has none."""
        return self.measurements.get(key)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = dict(self.measurements)
        if self.nu is not None:
            out["nu"] = list(self.nu)
        if self.source:
            out["source"] = self.source
        return {**out, **self.details}

    @classmethod
    def from_json(cls, data: Any, where: str = GROUND_TRUTH_SUBJECT) -> SubjectTruth:
        """Read ``subject.json`` content; InputError naming ``where`` when it is malformed."""
        if not isinstance(data, dict):
            raise InputError(f"{where}: expected a JSON object, got {type(data).__name__}")
        measurements = {k: float(v) for k, v in data.items() if _is_measurement(k, v)}
        bad = [k for k, v in measurements.items() if not math.isfinite(v)]
        if bad:
            raise InputError(f"{where}: not a finite number: {', '.join(bad)}")
        nu = data.get("nu")
        try:
            shape = None if nu is None else tuple(float(x) for x in nu)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{where}: nu: expected a list of numbers ({exc})") from exc
        details = {
            k: v for k, v in data.items() if k not in measurements and k not in ("nu", "source")
        }
        return cls(measurements, shape, str(data.get("source", "")), details)

    @classmethod
    def read(cls, ground_truth: Path) -> SubjectTruth | None:
        """The subject of a session's ``ground_truth/`` folder; None when it has no file."""
        path = Path(ground_truth) / GROUND_TRUTH_SUBJECT
        if not path.is_file():
            return None
        return cls.from_json(read_json_object(path), str(path))

    def write(self, ground_truth: Path) -> None:
        write_json_atomic(Path(ground_truth) / GROUND_TRUTH_SUBJECT, self.to_json())


@dataclass(frozen=True)
class StudioRecord:
    """``ground_truth/studio.json``: how the studio rendered a session.

    Attributes
    ----------
    config : dict
        The studio's settings (``bodymetry.studio.synth.StudioConfig`` as JSON).
    motion_seed : int
    bystanders : list of dict
        Each bystander's description (position, who saw it).
    render_seconds : float
    shadow_to_person_area_mean : dict of str to float
        Per camera, the cast shadow's area over the person's.
    persons : list of dict
        With several people, each person's description (``index``; for the
        others their body, clothes, motion, path and crossings; every person's
        ``occluded_fraction`` per camera); empty for one person.
    """

    config: dict[str, Any]
    motion_seed: int = 0
    bystanders: list[dict[str, Any]] = field(default_factory=list)
    render_seconds: float = 0.0
    shadow_to_person_area_mean: dict[str, float] = field(default_factory=dict)
    persons: list[dict[str, Any]] = field(default_factory=list)

    @property
    def people(self) -> int:
        """Persons recorded (the subject included; 1 for sessions made before people)."""
        return int(self.config.get("people", 1))

    @property
    def shadows(self) -> bool:
        """Whether the studio cast shadows (the shadow scores mean something)."""
        return bool(self.config.get("shadows", True))

    @property
    def look(self) -> dict[str, str]:
        """The studio's look as recorded (``config.look``: ``clothing``, ``room``,
        ``light``; ``bodymetry.studio.looks.Look.from_json`` reads it); empty for a
        session rendered before looks existed, which had the default look."""
        look = self.config.get("look") or {}
        if not isinstance(look, dict) or not all(isinstance(v, str) for v in look.values()):
            raise InputError(
                f"{GROUND_TRUTH_STUDIO}: config.look must be an object of strings, got {look!r}"
            )
        return {str(k): v for k, v in look.items()}

    def to_json(self) -> dict[str, Any]:
        return {
            "config": self.config,
            "motion_seed": self.motion_seed,
            "bystanders": self.bystanders,
            "render_seconds": self.render_seconds,
            "shadow_to_person_area_mean": self.shadow_to_person_area_mean,
            **({"persons": self.persons} if self.persons else {}),
        }

    @classmethod
    def read(cls, ground_truth: Path) -> StudioRecord | None:
        """The record in a session's ``ground_truth/`` folder; None when it has none."""
        path = Path(ground_truth) / GROUND_TRUTH_STUDIO
        if not path.is_file():
            return None
        data = read_json_object(path)
        try:
            return cls(
                config=dict(data["config"]),
                motion_seed=int(data.get("motion_seed", 0)),
                bystanders=list(data.get("bystanders", [])),
                render_seconds=float(data.get("render_seconds", 0.0)),
                shadow_to_person_area_mean={
                    str(k): float(v)
                    for k, v in dict(data.get("shadow_to_person_area_mean", {})).items()
                },
                persons=[dict(p) for p in data.get("persons", [])],
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: not a studio.json of `bodymetry synth` ({exc})") from exc

    def write(self, ground_truth: Path) -> None:
        write_json_atomic(Path(ground_truth) / GROUND_TRUTH_STUDIO, self.to_json())


#: A tracked person is the studio's person whose root lies within this (metres, mean
#: floor distance over the frames both have) and nearer than every other person's by
#: :data:`MATCH_MARGIN` times.
MATCH_DISTANCE = 0.3
MATCH_MARGIN = 2.0


def match_person(ground_truth: Path, positions: dict[int, np.ndarray]) -> tuple[int | None, float]:
    """Which of the studio's people a tracked person is, by where they stood.

    Parameters
    ----------
    ground_truth : Path
        A session's ``ground_truth/`` folder (the subject's ``states.npz`` there,
        the others' under ``persons/<k>/``).
    positions : dict of int to (2,) or (3,) float
        Per session frame, the tracked person's root position (world, metres;
        the floor coordinates are compared).

    Returns
    -------
    index : int or None
        The studio person (0: the subject), or None when nobody is within
        :data:`MATCH_DISTANCE` or two are about as near (:data:`MATCH_MARGIN`).
    distance : float
        The chosen (or nearest) person's mean floor distance, metres (inf
        without common frames).
    """
    ground_truth = Path(ground_truth)
    distances = []
    index = 0
    while (person_folder(ground_truth, index) / GROUND_TRUTH_STATES).is_file():
        states = load_npz(person_folder(ground_truth, index) / GROUND_TRUTH_STATES)
        rows = {int(f): k for k, f in enumerate(states["frame"])}
        d = [
            float(np.linalg.norm(np.asarray(p, float)[:2] - states["tau"][rows[f], :2]))
            for f, p in positions.items()
            if f in rows
        ]
        distances.append(float(np.mean(d)) if d else np.inf)
        index += 1
    if not distances:
        return None, np.inf
    order = np.argsort(distances)
    best = float(distances[order[0]])
    second = float(distances[order[1]]) if len(order) > 1 else np.inf
    if best > MATCH_DISTANCE or second < MATCH_MARGIN * best:
        return None, best
    return int(order[0]), best
