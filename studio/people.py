"""More people in the studio: persons who move through the capture volume with the subject.

``bodymetry synth --people N`` records the subject (person 0) and ``N - 1`` other
persons. Each other person is a body of the independent bank
(:mod:`bodymetry.studio.independent`; a body other than the subject's and the
other persons'), wears its own shirt and trousers (from the bystanders' palette,
:data:`~bodymetry.studio.bystanders.SHIRTS` / :data:`~.bystanders.TROUSERS`,
away from the subject's colours), performs its own library motion (another seed)
standing on the floor, and walks a straight line past the subject while doing
it: the line runs ``side_m`` = 0.55-0.85 m beside the subject's mean root
position, so that in one or two cameras one person passes in front of the other
for part of the clip (a *crossing*). The studio's cameras frame a standing
person at the volume centre with little room to spare, so a body a metre
towards a camera leaves its image: the pair is centred on the volume instead,
the subject's motion moved (a constant floor offset) to half the side distance
on the other side of the centre.

A path is kept only when (:func:`draw_people`)

- every camera sees every person (at least :data:`MIN_IN_VIEW` of the
  subject's and person 1's posed vertices inside the image, every frame, and
  :data:`MIN_IN_VIEW_THIRD` of a third person's),
- it never comes closer than :data:`MIN_GAP_M` to an earlier person (the
  subject included; nearest posed vertices, every frame), and
- at least one camera sees it cross the subject (their image extents overlap by
  half the narrower one's width in some frame);

otherwise the path is drawn again, then the motion. Every draw comes from the
session seed.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from bodymetry.calibration.camera import CameraGroup
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.body_model.motion.library import Motion, make_motion
from bodymetry.estimation.body_model.motion.seeds import SEED_RANGES, seed_for
from bodymetry.estimation.body_model.skeleton import PARTS
from bodymetry.studio.bystanders import SHIRTS, TROUSERS
from bodymetry.studio.independent import IndependentSpec, IndependentSubject, committed_bank
from bodymetry.studio.scene import Appearance

log = logging.getLogger(__name__)

#: The most people a session may hold (the subject included).
MAX_PEOPLE = 3
#: Closest two persons' posed vertices may come (every 7th vertex, so the surfaces keep
#: a few centimetres more), metres.
MIN_GAP_M = 0.08
#: Sideways distance of a person's path from the subject, metres.
SIDE_RANGE_M = (0.55, 0.85)
#: Length of a person's path over the clip, metres.
LENGTH_RANGE_M = (0.6, 1.0)
#: Colours closer than this (BGR albedo distance) to the subject's or another
#: person's are not worn.
MIN_COLOUR_DISTANCE = 0.25
#: Fraction of a person's posed vertices every camera must see, every frame (a hand may
#: leave the image, or the toes for a moment, not a head or a leg): the subject and person 1.
MIN_IN_VIEW = 0.95
#: The same for a third person: the rig's framing leaves no room for three bodies that
#: keep clear of each other, so its head or feet may leave an image for a while.
MIN_IN_VIEW_THIRD = 0.85
#: Every how many vertices the placement checks use.
VERTEX_STRIDE = 7
_SHIRT_PARTS = tuple(PARTS.index(p) for p in ("torso", "upper_arm_l", "upper_arm_r"))
_TROUSER_PARTS = tuple(PARTS.index(p) for p in ("pelvis", "thigh_l", "shin_l", "thigh_r", "shin_r"))
_MOTION_DRAWS = 4
_PATH_DRAWS = 40


@dataclass(frozen=True)
class PersonPath:
    """The straight line a person's root follows over the clip (on top of its motion's
    own small drift), world metres.

    Attributes
    ----------
    start, end : (float, float)
        Floor position at the first and the last frame.
    side_m : float
        Distance of the line from the subject's mean root position.
    """

    start: tuple[float, float]
    end: tuple[float, float]
    side_m: float

    def positions(self, frames: int) -> np.ndarray:
        """(F, 2) float floor positions, evenly along the line."""
        t = np.linspace(0.0, 1.0, frames) if frames > 1 else np.zeros(1)
        a, b = np.asarray(self.start), np.asarray(self.end)
        return a[None] + t[:, None] * (b - a)[None]

    def to_json(self) -> dict:
        return {
            "start_m": [round(v, 4) for v in self.start],
            "end_m": [round(v, 4) for v in self.end],
            "side_m": round(self.side_m, 4),
        }


@dataclass(frozen=True, eq=False)
class Person:
    """One person besides the subject.

    Attributes
    ----------
    index : int
        1.. (the subject is person 0).
    subject : IndependentSubject
        The body (nude truth, tight clothing rendered).
    motion : Motion
        τ (F, 3) on the path, lowest point on the floor; θ (F, 37).
    motion_seed : int
    shirt, trousers : str
        Keys of :data:`SHIRTS` and :data:`TROUSERS`.
    path : PersonPath
    crossings : dict of str to (int, int)
        Per camera that sees this person and the subject overlap: the first and
        the last frame they do.
    """

    index: int
    subject: IndependentSubject
    motion: Motion
    motion_seed: int
    shirt: str
    trousers: str
    path: PersonPath
    crossings: dict[str, tuple[int, int]]

    def shifted(self, offset: np.ndarray, crossings: dict[str, tuple[int, int]]) -> Person:
        """The person moved by a floor offset (2,), with its crossings there."""
        tau = self.motion.tau + np.r_[offset, 0.0]
        p = self.path
        path = PersonPath(
            (float(p.start[0] + offset[0]), float(p.start[1] + offset[1])),
            (float(p.end[0] + offset[0]), float(p.end[1] + offset[1])),
            p.side_m,
        )
        motion = Motion(self.motion.theta, tau, self.motion.fps, self.motion.name)
        return dataclasses.replace(self, motion=motion, path=path, crossings=crossings)

    @property
    def spec(self) -> IndependentSpec:
        return self.subject.spec

    def truth(self, batch: int = 32) -> tuple[dict, np.ndarray, np.ndarray]:
        """The person's true biometrics, joints (F, 15, 3) and every
        :data:`VERTEX_STRIDE`-th posed vertex (F, N, 3) of the rendered surface."""
        tau, theta = self.motion.tau, self.motion.theta
        joints, sparse = [], []
        for s in range(0, len(tau), batch):
            v, j = self.subject.pose(tau[s : s + batch], theta[s : s + batch])
            joints.append(j)
            sparse.append(v[:, ::VERTEX_STRIDE])
        bio = self.subject.biometrics().to_dict()
        return bio, np.concatenate(joints), np.concatenate(sparse)

    def appearance(self, base: Appearance | None = None) -> Appearance:
        """``base`` (default :class:`Appearance`) in this person's shirt and trousers."""
        return dressed(self.shirt, self.trousers, base)

    def to_json(self) -> dict:
        """What ``ground_truth/studio.json`` records about the person."""
        return {
            "index": self.index,
            "body": self.subject.index,
            "subject": self.spec.to_text(),
            "shirt": self.shirt,
            "trousers": self.trousers,
            "motion": self.motion.name,
            "motion_seed": self.motion_seed,
            "path": self.path.to_json(),
            "crossings": {cam: list(span) for cam, span in self.crossings.items()},
        }


def dressed(shirt: str, trousers: str, base: Appearance | None = None) -> Appearance:
    """``base`` (default :class:`Appearance`) in a shirt and trousers of the palette."""
    if shirt not in SHIRTS or trousers not in TROUSERS:
        raise InputError(
            f"clothes {shirt!r}/{trousers!r}: expected a shirt of {', '.join(SHIRTS)} and "
            f"trousers of {', '.join(TROUSERS)}"
        )
    base = base or Appearance()
    colors = np.array(base.part_colors, dtype=float, copy=True)
    colors[list(_SHIRT_PARTS)] = SHIRTS[shirt]
    colors[list(_TROUSER_PARTS)] = TROUSERS[trousers]
    return dataclasses.replace(base, part_colors=colors)


def draw_people(
    model: BodyModel,
    cameras: CameraGroup,
    subject_tau: np.ndarray,
    subject_vertices: np.ndarray,
    subject_appearance: Appearance,
    n: int,
    seed: int,
    *,
    motion: str,
    fps: float,
    exclude_bodies: tuple[int, ...] = (),
) -> tuple[list[Person], np.ndarray]:
    """Draw and place ``n`` persons besides the subject (see the module docstring).

    Parameters
    ----------
    model : BodyModel
    cameras : CameraGroup
        The rig.
    subject_tau : (F, 3) float
        The subject's root positions over the clip.
    subject_vertices : (F, N, 3) float
        The subject's posed vertices (every :data:`VERTEX_STRIDE`-th) over the clip.
    subject_appearance : Appearance
        The subject's clothes (the persons wear other colours).
    n : int
        Persons to add (0 .. ``MAX_PEOPLE - 1``).
    seed : int
        Seeds every draw.
    motion : str
        The library motion each person performs (with its own seed).
    fps : float
    exclude_bodies : tuple of int
        Bank bodies not to use (the subject's, when it is an independent one).

    Returns
    -------
    list of Person
        Persons 1 .. n, on their final paths.
    (2,) float
        The floor offset to add to the subject's motion (zero when ``n`` is 0).

    Raises
    ------
    InputError
        ``n`` out of range, or no path satisfies the constraints.
    """
    if not 0 <= n <= MAX_PEOPLE - 1:
        raise InputError(f"--people: expected 1..{MAX_PEOPLE} people, got {n + 1}")
    group = _Group(cameras, np.asarray(subject_tau, float), np.asarray(subject_vertices, float))
    used_bodies = set(exclude_bodies)
    shirts = [np.asarray(subject_appearance.part_colors)[_SHIRT_PARTS[0]]]
    trousers = [np.asarray(subject_appearance.part_colors)[_TROUSER_PARTS[1]]]
    people = []
    for k in range(1, n + 1):
        rng = np.random.default_rng([seed, 0x9E0, k])
        free = [b for b in range(len(committed_bank())) if b not in used_bodies]
        body = int(rng.choice(free))
        used_bodies.add(body)
        subject = IndependentSubject(IndependentSpec(seed=seed, body=body), model=model)
        shirt = _pick_colour(SHIRTS, shirts, rng)
        trouser = _pick_colour(TROUSERS, trousers, rng)
        shirts.append(np.asarray(SHIRTS[shirt]))
        trousers.append(np.asarray(TROUSERS[trouser]))
        people.append(group.place(k, subject, (shirt, trouser), rng, motion, fps))
    # Everyone moves by the group's final offset (it centres the group on the volume).
    shift = group.offset
    people = [p.shifted(shift, group.crossings[i]) for i, p in enumerate(people)]
    for p in people:
        log.info(
            "person %d: body %d, path %s, crosses the subject in %s",
            p.index,
            p.subject.index,
            p.path.to_json(),
            ", ".join(p.crossings) or "no camera",
        )
    return people, shift


def _pick_colour(palette: dict, worn: list[np.ndarray], rng: np.random.Generator) -> str:
    """A palette colour away from every worn one (the farthest when none is)."""
    names = list(palette)
    gap = np.array(
        [min(float(np.linalg.norm(np.asarray(palette[c]) - w)) for w in worn) for c in names]
    )
    ok = [c for c, g in zip(names, gap, strict=True) if g >= MIN_COLOUR_DISTANCE]
    return str(rng.choice(ok)) if ok else names[int(np.argmax(gap))]


def _grounded_motion(
    subject: IndependentSubject, name: str, frames: int, fps: float, seed: int
) -> Motion:
    """The library motion on the floor, its root drift centred on the origin."""
    motion = make_motion(
        name, frames, fps, seed, limits=subject.model.limits, rest=subject.rest_pose_info()
    )
    tau = motion.tau.copy()
    tau[:, :2] -= tau[:, :2].mean(axis=0)
    tau[:, 2] -= subject.lowest_point(tau, motion.theta)
    return Motion(motion.theta, tau, motion.fps, motion.name)


def _sparse_vertices(subject: IndependentSubject, motion: Motion, batch: int = 32) -> np.ndarray:
    """(F, V / stride, 3) the rendered surface's posed vertices, every stride-th."""
    out = []
    for s in range(0, len(motion), batch):
        v, _ = subject.pose(motion.tau[s : s + batch], motion.theta[s : s + batch])
        out.append(v[:, ::VERTEX_STRIDE])
    return np.concatenate(out)


class _Group:
    """The persons placed so far, in the subject's frame, and the floor offset that
    centres the subject and person 1 on the volume (the world origin).

    Parameters
    ----------
    cameras : CameraGroup
    subject_tau : (F, 3) float
    subject_vertices : (F, N, 3) float
        Sparse posed vertices of the subject.
    """

    def __init__(
        self, cameras: CameraGroup, subject_tau: np.ndarray, subject_vertices: np.ndarray
    ) -> None:
        self.cameras = cameras
        self.centre = subject_tau[:, :2].mean(axis=0)
        self.frames = len(subject_tau)
        self.vertices = [subject_vertices]  # sparse posed vertices, subject first
        self.middles = [self.centre]  # each person's mean floor position
        self.offset = np.zeros(2)
        self.crossings: list[dict[str, tuple[int, int]]] = []

    def place(
        self,
        index: int,
        subject: IndependentSubject,
        clothes: tuple[str, str],
        rng: np.random.Generator,
        motion_name: str,
        fps: float,
    ) -> Person:
        """Draw a motion and a path until person ``index`` fits (module docstring) and
        add it; the person as placed in the subject's frame (before the offset)."""
        span = len(SEED_RANGES["test"])
        for _ in range(_MOTION_DRAWS):
            motion_seed = seed_for("test", int(rng.integers(span)))
            motion = _grounded_motion(subject, motion_name, self.frames, fps, motion_seed)
            here = _sparse_vertices(subject, motion)
            for _ in range(_PATH_DRAWS):
                path = _draw_path(self.centre, rng)
                walk = np.zeros((self.frames, 3))
                walk[:, :2] = path.positions(self.frames)
                moved = here + walk[:, None]
                if not _clear_of(moved, self.vertices):
                    continue
                middles = [*self.middles, walk[:, :2].mean(axis=0)]
                # The subject and person 1 are centred on the volume; a third person
                # keeps clear of them where it can.
                offset = -np.mean(middles[:2], axis=0)
                shift = np.r_[offset, 0.0]
                bodies = [v + shift for v in (*self.vertices, moved)]
                needs = [MIN_IN_VIEW if i < 2 else MIN_IN_VIEW_THIRD for i in range(len(bodies))]
                if not all(_seen(self.cameras, v, f) for v, f in zip(bodies, needs, strict=True)):
                    continue
                crossings = [_crossings(self.cameras, v, bodies[0]) for v in bodies[1:]]
                if not crossings[-1]:
                    continue
                self.vertices.append(moved)
                self.middles = middles
                self.offset = offset
                self.crossings = crossings
                tau = motion.tau + walk
                return Person(
                    index,
                    subject,
                    Motion(motion.theta, tau, motion.fps, motion.name),
                    motion_seed,
                    *clothes,
                    path,
                    {},
                )
        raise InputError(
            f"--people: could not place person {index} (seen by every camera with everyone "
            f"else, clear of the others and crossing the subject in a camera) in "
            f"{_MOTION_DRAWS * _PATH_DRAWS} draws; try another --seed, fewer --people or a "
            "calmer --motion"
        )


def _draw_path(centre: np.ndarray, rng: np.random.Generator) -> PersonPath:
    """A straight line ``side_m`` beside the subject's mean root position ``centre``
    (2,), walked in either direction."""
    azimuth = rng.uniform(-np.pi, np.pi)
    normal = np.array([np.cos(azimuth), np.sin(azimuth)])
    along = np.array([-normal[1], normal[0]]) * rng.choice([-1.0, 1.0])
    side = rng.uniform(*SIDE_RANGE_M)
    length = rng.uniform(*LENGTH_RANGE_M)
    middle = centre + side * normal + rng.uniform(-0.1, 0.1) * along
    start, end = middle - 0.5 * length * along, middle + 0.5 * length * along
    return PersonPath(
        (float(start[0]), float(start[1])), (float(end[0]), float(end[1])), float(side)
    )


def _seen(cameras: CameraGroup, vertices: np.ndarray, fraction: float, margin: float = 2.0) -> bool:
    """Every camera sees ``fraction`` of the vertices (F, N, 3), every frame."""
    for cam in cameras:
        w, h = cam.size
        xy = cam.project(vertices.reshape(-1, 3)).reshape(*vertices.shape[:2], 2)
        inside = (
            np.isfinite(xy).all(axis=-1)
            & (xy[..., 0] >= margin)
            & (xy[..., 0] <= w - 1 - margin)
            & (xy[..., 1] >= margin)
            & (xy[..., 1] <= h - 1 - margin)
        )
        if inside.mean(axis=1).min() < fraction:
            return False
    return True


def _clear_of(vertices: np.ndarray, placed: list[np.ndarray]) -> bool:
    """The body (F, N, 3) keeps :data:`MIN_GAP_M` from every placed one, every frame."""
    for other in placed:
        # Frames where the bounding boxes are far apart need no nearest-neighbour search.
        lo = np.maximum(vertices.min(axis=1), other.min(axis=1))
        hi = np.minimum(vertices.max(axis=1), other.max(axis=1))
        near = np.flatnonzero((lo - hi < MIN_GAP_M).all(axis=1))
        for f in near:
            d, _ = cKDTree(other[f]).query(vertices[f], k=1, distance_upper_bound=MIN_GAP_M)
            if np.isfinite(d).any():
                return False
    return True


def _crossings(
    cameras: CameraGroup, vertices: np.ndarray, subject: np.ndarray, overlap: float = 0.5
) -> dict[str, tuple[int, int]]:
    """Per camera, the first and last frame the two bodies (F, N, 3) overlap in the image.

    Two bodies overlap when their horizontal image extents (10th to 90th percentile
    of the vertices' columns, so that an outstretched arm does not count) share at
    least ``overlap`` of the narrower one's width.
    """
    out = {}
    for cam in cameras:
        extents = []
        for body in (vertices, subject):
            x = cam.project(body.reshape(-1, 3))[:, 0].reshape(body.shape[:2])
            extents.append(np.nanpercentile(x, [10, 90], axis=1))  # (2, F)
        (a0, a1), (b0, b1) = extents
        shared = np.minimum(a1, b1) - np.maximum(a0, b0)
        narrow = np.minimum(a1 - a0, b1 - b0)
        frames = np.flatnonzero(shared >= overlap * narrow)
        if frames.size:
            out[cam.name] = (int(frames[0]), int(frames[-1]))
    return out
