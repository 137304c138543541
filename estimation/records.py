"""The fit's records: what the steps record of each frame and of the session's shape.

One typed schema (docs/outputs.md): the per-frame records
(``frames/FFFFFF.json``), the arrays a fit leaves for review
(``frames/FFFFFF.npz``: observed and model silhouettes, the last annealing
layer), the per-stage summary, the session stage's shape and the quality gate.
The files of a whole run (``results.json``, ``run.json``, ``evaluation.json``,
``study.json``) are :mod:`bodymetry.estimation.run_files`, built from these.
JSON keeps the layout of earlier versions (a stage's measurements beside its
``state``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bodymetry.errors import InputError
from bodymetry.estimation.body_model.model import BodyState
from bodymetry.fileio import load_npz, read_json_object

__all__ = [
    "CORE_MEASUREMENTS",
    "FRAME_STAGES",
    "STAGES",
    "AnnealingTrace",
    "FrameArrays",
    "FrameRecord",
    "OutlineCheck",
    "RefinementTrace",
    "SessionGate",
    "SessionShape",
    "StageEstimate",
    "Stat",
    "summarize",
]

#: The fitting stages, in pipeline order, as keyed in the records: two per frame,
#: then the session's one shape (:mod:`bodymetry.estimation.session_shape`), which
#: only frames with status ``ok`` of a run whose session stage was accepted carry.
STAGES: tuple[str, ...] = ("discriminative", "generative", "session")
#: The stages every fitted frame has.
FRAME_STAGES: tuple[str, ...] = STAGES[:2]
#: The three measurements of the paper's Figure 3.
CORE_MEASUREMENTS: tuple[str, ...] = ("height_mm", "arm_span_mm", "weight_kg")
#: Status of a frame that counts in the summary.
OK = "ok"
#: The largest per-frame record (``frames/FFFFFF.json``) read.
FRAME_RECORD_MAX_BYTES = 4_000_000


def _finite_or_none(x: float | None, digits: int) -> float | None:
    # Strict JSON has no NaN: a non-finite value is written as null.
    if x is None or not math.isfinite(x):
        return None
    return round(float(x), digits)


def _nan_if_none(v: Any) -> float:
    """The reverse of :func:`_finite_or_none`: a JSON null reads as NaN."""
    return math.nan if v is None else float(v)


def _state_to_json(state: BodyState) -> dict[str, list[float]]:
    return {
        "tau": state.tau[0].tolist(),
        "theta": state.theta[0].tolist(),
        "nu": state.nu[0].tolist(),
    }


def _state_from_json(data: Mapping[str, Any], where: str) -> BodyState:
    try:
        return BodyState(
            np.asarray(data["tau"], float)[None],
            np.asarray(data["theta"], float)[None],
            np.asarray(data["nu"], float)[None],
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{where}: not a body state ({exc})") from exc


@dataclass(frozen=True)
class StageEstimate:
    """One stage's estimate for one frame.

    Attributes
    ----------
    state : BodyState
        Batch of one: τ (1, 3) m, θ (1, 37) rad, ν (1, n_shape).
    biometrics : dict of str to float
        Measurements of the canonical body (``MEASUREMENTS`` keys: mm, kg, l).
    silhouette_iou : dict of str to float
        IoU of this estimate's silhouette with the observed one per view, when
        it differs from the frame's (the session stage's; empty otherwise).
    """

    state: BodyState
    biometrics: dict[str, float]
    silhouette_iou: dict[str, float] = field(default_factory=dict)

    def vector(self) -> np.ndarray:
        """``[τ, θ, ν]`` (40 + n_shape,) float."""
        return self.state.vector()[0]

    @property
    def finite(self) -> bool:
        return bool(np.all(np.isfinite(self.vector())))

    @property
    def mean_iou(self) -> float:
        values = [v for v in self.silhouette_iou.values() if math.isfinite(v)]
        return float(np.mean(values)) if values else float("nan")

    def to_json(self) -> dict[str, Any]:
        out = {
            **{k: _finite_or_none(v, 3) for k, v in self.biometrics.items()},
            "state": _state_to_json(self.state),
        }
        if self.silhouette_iou:
            out["silhouette_iou"] = {
                k: _finite_or_none(v, 4) for k, v in self.silhouette_iou.items()
            }
        return out

    @classmethod
    def from_json(cls, data: Mapping[str, Any], where: str = "estimate") -> StageEstimate:
        if not isinstance(data, Mapping) or "state" not in data:
            raise InputError(f"{where}: expected measurements and a 'state'")
        extra = ("state", "silhouette_iou")
        bio = {
            k: float("nan") if v is None else float(v) for k, v in data.items() if k not in extra
        }
        iou = {
            k: float("nan") if v is None else float(v)
            for k, v in (data.get("silhouette_iou") or {}).items()
        }
        return cls(_state_from_json(data["state"], f"{where}.state"), bio, iou)


@dataclass(frozen=True)
class AnnealingTrace:
    """What the annealed particle filter did on one frame.

    Attributes
    ----------
    layer_log_likelihood : tuple of float
        Weighted mean log-likelihood per layer.
    layer_beta : tuple of float
        Temperature per layer.
    tau_std_m : (3,) tuple of float
        Spread of the last layer's τ (m).
    nu_std : tuple of float
        Spread of the last layer's ν.
    """

    layer_log_likelihood: tuple[float, ...] = ()
    layer_beta: tuple[float, ...] = ()
    tau_std_m: tuple[float, ...] = ()
    nu_std: tuple[float, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {
            "layer_log_likelihood": [_finite_or_none(v, 4) for v in self.layer_log_likelihood],
            "layer_beta": [_finite_or_none(v, 6) for v in self.layer_beta],
            "particle_std": {
                "tau_m": [_finite_or_none(v, 4) for v in self.tau_std_m],
                "nu": [_finite_or_none(v, 4) for v in self.nu_std],
            },
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> AnnealingTrace:
        std = data.get("particle_std", {})

        def floats(values: Sequence[Any]) -> tuple[float, ...]:
            return tuple(float("nan") if v is None else float(v) for v in values)

        return cls(
            floats(data.get("layer_log_likelihood", [])),
            floats(data.get("layer_beta", [])),
            floats(std.get("tau_m", [])),
            floats(std.get("nu", [])),
        )


@dataclass(frozen=True)
class RefinementTrace:
    """What the contour refinement did on one frame.

    Attributes
    ----------
    start : str
        The candidate the refinement started from.
    initial_cost_px2, cost_px2 : float
        Contour cost (mean squared working pixels) before and after.
    iterations : int
    """

    start: str
    initial_cost_px2: float
    cost_px2: float
    iterations: int

    def to_json(self) -> dict[str, Any]:
        return {
            "start": self.start,
            "initial_cost_px2": _finite_or_none(self.initial_cost_px2, 4),
            "cost_px2": _finite_or_none(self.cost_px2, 4),
            "iterations": int(self.iterations),
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> RefinementTrace:
        return cls(
            str(data.get("start", "")),
            _nan_if_none(data.get("initial_cost_px2")),
            _nan_if_none(data.get("cost_px2")),
            int(data.get("iterations", 0)),
        )


@dataclass(frozen=True)
class FrameRecord:
    """One kept frame's outcome (``frames/FFFFFF.json``, an entry of ``results.json``).

    Attributes
    ----------
    frame : int
        Session frame.
    status : str
        ``"ok"`` (counts in the summary), ``"poor fit: ..."`` (fitted, numbers
        kept, left out of the summary), or why there is no fit.
    flags : dict of str to tuple of str
        Silhouette flags per camera.
    estimates : dict of str to StageEstimate
        Per stage (:data:`STAGES`); empty when there is no fit.
    silhouette_iou : dict of str to float
        IoU of the fitted body's silhouette with the observed one, per camera.
    person_pixels : dict of str to int
        Pixels of the observed silhouette per camera (0: the camera saw no one).
    view_agreement : dict of str to float
        Capture's agreement of each judged view's silhouette with the frame's
        other evidence (in [0, 1], :func:`bodymetry.capture.fusion.view_agreement`;
        views not judged are absent). A view flagged ``unreliable`` was left out of the fit
        (:mod:`bodymetry.estimation.view_selection`).
    persons : int or None
        People capture counted in the capture volume
        (:attr:`bodymetry.capture.segmentation.SilhouetteFrame.persons`); more than
        one (a count above one means "more than one", not an exact number): the
        silhouettes are the largest body's and may be another person's.
        None: not counted (no empty-scene clip, no calibrated rig, or a run
        before the count).
    outline_contrast : float or None
        How plainly the silhouettes stood out from the empty scene along their
        outline (:func:`bodymetry.capture.fusion.outline_contrast`: the change
        term that three quarters of the silhouettes' inner rim reach, 2.0 at
        most); below
        :data:`~bodymetry.estimation.studio_accuracy.LOW_CONTRAST` the frame was
        seen in low contrast (white, grey or wall-coloured clothing in a plain
        room); a person told apart from others, on the rim that borders the empty
        scene. None: no empty-scene clip, or a run before the figure.
    annealing : AnnealingTrace or None
    refinement : RefinementTrace or None
    seconds : dict of str to float
        Time per step.
    """

    frame: int
    status: str
    flags: dict[str, tuple[str, ...]] = field(default_factory=dict)
    estimates: dict[str, StageEstimate] = field(default_factory=dict)
    silhouette_iou: dict[str, float] = field(default_factory=dict)
    person_pixels: dict[str, int] = field(default_factory=dict)
    view_agreement: dict[str, float] = field(default_factory=dict)
    persons: int | None = None
    outline_contrast: float | None = None
    annealing: AnnealingTrace | None = None
    refinement: RefinementTrace | None = None
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """Whether the frame counts in the summary."""
        return self.status == OK

    @property
    def crowded(self) -> bool:
        """Whether capture counted someone besides the measured person in this frame (a
        count above one is "more than one": the hull's phantoms can add to it)."""
        return self.persons is not None and self.persons > 1

    def estimate(self, stage: str = "generative") -> StageEstimate | None:
        """A stage's estimate, or None when the frame has none (or a non-finite one)."""
        est = self.estimates.get(stage)
        return est if est is not None and est.finite else None

    @property
    def status_kind(self) -> str:
        """The status's kind, the text before any ``:`` ("poor fit" for "poor fit: mean
        silhouette IoU 0.41 < 0.90"); ``"unknown"`` for an empty status."""
        return self.status.split(":", 1)[0].strip() or "unknown"

    @property
    def fitted(self) -> bool:
        """Whether the frame carries a fit (``ok`` or left out by a quality gate)."""
        return self.estimate() is not None

    @property
    def mean_iou(self) -> float:
        values = [v for v in self.silhouette_iou.values() if math.isfinite(v)]
        return float(np.mean(values)) if values else float("nan")

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "frame": int(self.frame),
            "status": self.status,
            "flags": {k: list(v) for k, v in self.flags.items()},
        }
        for stage, est in self.estimates.items():
            out[stage] = est.to_json()
        if self.silhouette_iou:
            out["silhouette_iou"] = {
                k: _finite_or_none(v, 4) for k, v in self.silhouette_iou.items()
            }
        if self.person_pixels:
            out["person_pixels"] = {k: int(v) for k, v in self.person_pixels.items()}
        if self.view_agreement:
            out["view_agreement"] = {
                k: _finite_or_none(v, 4) for k, v in self.view_agreement.items()
            }
        if self.persons is not None:
            out["persons"] = int(self.persons)
        if self.outline_contrast is not None:
            out["outline_contrast"] = round(float(self.outline_contrast), 3)
        if self.annealing is not None:
            out["annealing"] = self.annealing.to_json()
        if self.refinement is not None:
            out["refinement"] = self.refinement.to_json()
        if self.seconds:
            out["seconds"] = {k: round(float(v), 2) for k, v in self.seconds.items()}
        return out

    @classmethod
    def from_json(cls, data: Any, where: str = "frame record") -> FrameRecord:
        """Read a record; InputError naming ``where`` when it is not one."""
        if not isinstance(data, Mapping) or "frame" not in data or "status" not in data:
            raise InputError(f"{where}: not a frame record of `bodymetry process`")
        try:
            frame = int(data["frame"])
            return cls(
                frame=frame,
                status=str(data["status"]),
                flags={k: tuple(v) for k, v in data.get("flags", {}).items()},
                estimates={
                    s: StageEstimate.from_json(data[s], f"{where}: {s}")
                    for s in STAGES
                    if s in data
                },
                silhouette_iou={
                    k: float("nan") if v is None else float(v)
                    for k, v in data.get("silhouette_iou", {}).items()
                },
                person_pixels={k: int(v) for k, v in data.get("person_pixels", {}).items()},
                # Runs before issue 32 recorded no agreement: none judged.
                view_agreement={
                    k: float("nan") if v is None else float(v)
                    for k, v in data.get("view_agreement", {}).items()
                },
                persons=None if data.get("persons") is None else int(data["persons"]),
                outline_contrast=None
                if data.get("outline_contrast") is None
                else float(data["outline_contrast"]),
                annealing=AnnealingTrace.from_json(data["annealing"])
                if "annealing" in data
                else None,
                refinement=RefinementTrace.from_json(data["refinement"])
                if "refinement" in data
                else None,
                seconds={k: float(v) for k, v in data.get("seconds", {}).items()},
            )
        except (TypeError, ValueError, AttributeError) as exc:
            raise InputError(f"{where}: malformed frame record ({exc})") from exc

    @classmethod
    def read(cls, path: Path) -> FrameRecord:
        """Read ``frames/FFFFFF.json``; InputError naming the file when it is unreadable."""
        data = read_json_object(path, FRAME_RECORD_MAX_BYTES, "frame record")
        return cls.from_json(data, str(path))


@dataclass(frozen=True)
class FrameArrays:
    """The arrays a fitted frame leaves for review (``frames/FFFFFF.npz``).

    Every camera keeps its own image size, so masks are stored per camera.

    Attributes
    ----------
    observed : dict of str to (H, W) bool
        The silhouettes the fit saw, per camera.
    model : dict of str to (H, W) bool
        The fitted body's level of detail projected in each camera (the IoU's
        model side); empty when there is no fit.
    particles : (N, 40 + n_shape) float or None
        The last annealing layer ``[τ, θ, ν]``.
    weights : (N,) float or None
    landmarks : (33, 3) float or None
        The subject's body landmarks in the world frame, metres (NaN rows: not
        triangulated), when capture found them.
    unknown : dict of str to (H, W) bool
        Per camera where the person is partly hidden by someone nearer, the
        pixels that are neither theirs nor background (the fit's "unknown";
        ``unknown/<camera>`` in the file, absent from files of runs without).
    clothing : dict of str to (H, W) bool
        Per camera where capture told skin from clothing, the observed
        silhouette's pixels that are not skin: clothing, hair, shoes
        (:mod:`bodymetry.capture.skin`; ``clothing/<camera>`` in the file,
        absent from files of runs without).
    """

    observed: dict[str, np.ndarray] = field(default_factory=dict)
    model: dict[str, np.ndarray] = field(default_factory=dict)
    particles: np.ndarray | None = None
    weights: np.ndarray | None = None
    landmarks: np.ndarray | None = None
    unknown: dict[str, np.ndarray] = field(default_factory=dict)
    clothing: dict[str, np.ndarray] = field(default_factory=dict)

    def unknown_of(self, names: Sequence[str]) -> list[np.ndarray | None]:
        """The unknown masks in camera order of ``names`` (None where a camera has none)."""
        return [self.unknown.get(n) for n in names]

    def clothing_of(self, names: Sequence[str]) -> list[np.ndarray | None]:
        """The clothing masks in camera order of ``names`` (None where a camera has none)."""
        return [self.clothing.get(n) for n in names]

    def clothing_pixels(self) -> tuple[int, int]:
        """(clothing, silhouette) pixel counts over the cameras with a clothing mask."""
        worn = seen = 0
        for name, mask in self.clothing.items():
            if name in self.observed:
                worn += int(np.count_nonzero(mask))
                seen += int(np.count_nonzero(self.observed[name]))
        return worn, seen

    def to_arrays(self) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        for kind, masks in (
            ("observed", self.observed),
            ("model", self.model),
            ("unknown", self.unknown),
            ("clothing", self.clothing),
        ):
            for name, mask in masks.items():
                out[f"{kind}/{name}"] = np.asarray(mask, bool)
        if self.particles is not None and self.weights is not None:
            out["particles"] = np.asarray(self.particles, np.float32)
            out["weights"] = np.asarray(self.weights, np.float32)
        if self.landmarks is not None:
            out["landmarks"] = np.asarray(self.landmarks, np.float32)
        return out

    @classmethod
    def load(cls, path: Path) -> FrameArrays:
        """Read ``frames/FFFFFF.npz``; InputError naming the file when it is unreadable."""
        arrays = load_npz(path)

        def masks(kind: str) -> dict[str, np.ndarray]:
            return {
                k.split("/", 1)[1]: v.astype(bool)
                for k, v in arrays.items()
                if k.startswith(f"{kind}/")
            }

        particles = arrays.get("particles")
        weights = arrays.get("weights")
        landmarks = arrays.get("landmarks")
        return cls(
            masks("observed"),
            masks("model"),
            None if particles is None else np.asarray(particles, float),
            None if weights is None else np.asarray(weights, float),
            None if landmarks is None or landmarks.shape != (33, 3) else landmarks.astype(float),
            masks("unknown"),
            masks("clothing"),
        )


@dataclass(frozen=True)
class Stat:
    """Mean, sample standard deviation and count of a measurement over frames.

    For the ``session`` stage (one value for the session) ``mean`` is that
    value, ``std`` its standard error and ``n`` the frames it was fitted to.
    """

    mean: float | None
    std: float | None
    n: int

    @classmethod
    def of(cls, values: Sequence[float]) -> Stat:
        v = np.asarray([x for x in values if math.isfinite(x)], float)
        if len(v) == 0:
            return cls(None, None, 0)
        return cls(float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else 0.0, len(v))

    def to_json(self) -> dict[str, Any]:
        return {"mean": self.mean, "std": self.std, "n": self.n}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Stat:
        mean, std = data.get("mean"), data.get("std")
        return cls(
            None if mean is None else float(mean),
            None if std is None else float(std),
            int(data.get("n", 0)),
        )


def summarize(
    records: Sequence[FrameRecord], session_shape: SessionShape | None = None
) -> dict[str, dict[str, Stat]]:
    """Per stage and measurement: mean, std and n over the frames with status ``ok``.

    The ``session`` stage is there when ``session_shape`` was accepted: its one
    value with its standard error (see :class:`Stat`).
    """
    ok = [r for r in records if r.ok]
    out: dict[str, dict[str, Stat]] = {}
    for stage in FRAME_STAGES:
        keys = list(ok[0].estimates[stage].biometrics) if ok else list(CORE_MEASUREMENTS)
        out[stage] = {k: Stat.of([r.estimates[stage].biometrics[k] for r in ok]) for k in keys}
    if session_shape is not None and session_shape.ok:
        n = len(session_shape.frames)
        out["session"] = {
            k: Stat(
                _finite_or_none(v, 6),
                _finite_or_none(session_shape.standard_errors.get(k, math.nan), 6),
                n,
            )
            for k, v in session_shape.biometrics.items()
        }
    return out


#: How the outline check's warnings begin (:mod:`bodymetry.estimation.outline_check`).
LOOSE_CLOTHING = "loose clothing"
HAIR = "hair or headwear"
LEGS_HIDDEN = "legs hidden"
#: Why every core measurement's interval is withheld where the run's working pixels
#: were coarser than the studio's (``RunResults.intervals_withheld``).
COARSE_PIXELS = "coarse pixels"
#: Per warning, the core measurements the silhouette overstates when it is not the
#: body's own outline: loose clothing the weight and the arm span (the studio's loose
#: shirt and shorts read +12 to +17 kg and +5 to +40 mm), hair the height (+14 to
#: +15 mm), a skirt over the thighs all three (the legs are shaped and posed to the
#: skirt: the height up to 52 mm high, the weight 5-47 kg heavy, the arm span 18-46 mm
#: short). Their 95 % interval, made from
#: tight-clothed, bare-headed sessions, does not apply, and none is stated
#: (:attr:`OutlineCheck.overstated`).
OVERSTATED: dict[str, tuple[str, ...]] = {
    LOOSE_CLOTHING: ("arm_span_mm", "weight_kg"),
    HAIR: ("height_mm",),
    LEGS_HIDDEN: ("height_mm", "arm_span_mm", "weight_kg"),
}


@dataclass(frozen=True)
class OutlineCheck:
    """Where the observed outline lies relative to the fitted body (``session_shape.outline``).

    See :mod:`bodymetry.estimation.outline_check`.

    Attributes
    ----------
    status : str
        ``"ok"`` (the warnings are its verdict), ``"undecided: ..."`` (the
        working pixels are too coarse for a verdict; the figures are kept) or
        ``"no contour"``.
    frames : int
        Frames the offsets were measured on.
    mm_per_px : float
        A working pixel at the body, millimetres (median over the contour).
    offsets_mm : dict of str to float
        Per body region (trunk, upper limbs, lower limbs, head, crown): the
        median over frames of the outline's offset outside the fitted body,
        millimetres (negative: inside).
    trunk_excess_mm, trunk_excess_se_mm : float
        Trunk minus lower limbs (the loose-clothing signature) and its
        standard error over frames.
    crown_excess_mm, crown_excess_se_mm : float
        Crown minus the median of trunk, head and lower limbs (the hair
        signature, ``outline_check.CROWN_REFERENCE``) and its standard error.
    warnings : tuple of str
        What the offsets suggest (loose clothing, hair), in words.
    trunk_clothing_share : float
        The share of the trunk's observed outline points that lie on what
        capture called clothing (:mod:`bodymetry.capture.skin`); under
        ``OutlineConfig.bare_trunk`` the trunk is bare and no loose-clothing
        warning is given. NaN where capture did not tell (and in runs
        recorded before it).
    """

    status: str = OK
    frames: int = 0
    mm_per_px: float = math.nan
    offsets_mm: dict[str, float] = field(default_factory=dict)
    trunk_excess_mm: float = math.nan
    trunk_excess_se_mm: float = math.nan
    crown_excess_mm: float = math.nan
    crown_excess_se_mm: float = math.nan
    warnings: tuple[str, ...] = ()
    trunk_clothing_share: float = math.nan

    @property
    def overstated(self) -> dict[str, str]:
        """Per core measurement the warnings say the silhouette overstates
        (:data:`OVERSTATED`), what (:data:`LOOSE_CLOTHING`, :data:`HAIR` or
        :data:`LEGS_HIDDEN`)."""
        out: dict[str, str] = {}
        for warning in self.warnings:
            for start, keys in OVERSTATED.items():
                if warning.startswith(start):
                    out.update({key: start for key in keys if key not in out})
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "status": self.status,
            "frames": int(self.frames),
            "mm_per_px": _finite_or_none(self.mm_per_px, 2),
            "offsets_mm": {k: _finite_or_none(v, 2) for k, v in self.offsets_mm.items()},
            "trunk_excess_mm": _finite_or_none(self.trunk_excess_mm, 2),
            "trunk_excess_se_mm": _finite_or_none(self.trunk_excess_se_mm, 2),
            "crown_excess_mm": _finite_or_none(self.crown_excess_mm, 2),
            "crown_excess_se_mm": _finite_or_none(self.crown_excess_se_mm, 2),
            "warnings": list(self.warnings),
            "trunk_clothing_share": _finite_or_none(self.trunk_clothing_share, 3),
        }

    @classmethod
    def from_json(cls, data: Any, where: str = "outline") -> OutlineCheck:
        """Read the block; InputError naming ``where`` when it is not one."""
        if not isinstance(data, Mapping):
            raise InputError(f"{where}: expected an object")

        try:
            return cls(
                status=str(data.get("status", OK)),
                frames=int(data.get("frames", 0)),
                mm_per_px=_nan_if_none(data.get("mm_per_px")),
                offsets_mm={str(k): _nan_if_none(v) for k, v in data.get("offsets_mm", {}).items()},
                trunk_excess_mm=_nan_if_none(data.get("trunk_excess_mm")),
                trunk_excess_se_mm=_nan_if_none(data.get("trunk_excess_se_mm")),
                crown_excess_mm=_nan_if_none(data.get("crown_excess_mm")),
                crown_excess_se_mm=_nan_if_none(data.get("crown_excess_se_mm")),
                warnings=tuple(str(w) for w in data.get("warnings", ())),
                trunk_clothing_share=_nan_if_none(data.get("trunk_clothing_share")),
            )
        except (TypeError, ValueError, AttributeError) as exc:
            raise InputError(f"{where}: malformed outline check ({exc})") from exc


@dataclass(frozen=True)
class SessionShape:
    """The session stage's outcome (``results.json`` ``session_shape``).

    Attributes
    ----------
    status : str
        ``"ok"`` (accepted: the frames carry a ``session`` estimate),
        ``"rejected: ..."`` (computed, but it worsened the frames' silhouette
        fit beyond the tolerance; the numbers are kept here only),
        ``"skipped: ..."`` or ``"failed: ..."``.
    method : str
        How it was estimated and what the standard errors are.
    frames : tuple of int
        The frames it was fitted to (status ``ok``).
    nu, nu_se : tuple of float
        The one shape (n_shape,) and its standard errors.
    start_nu : tuple of float
        Where it started (the per-frame fits' median ν).
    biometrics, standard_errors : dict of str to float
        Measurements of the shape and their standard errors.
    frame_weights : dict of int to float
        Each frame's robust weight (1: full; lower: its contours disagreed).
    mean_iou, reference_iou : float
        The frames' mean silhouette IoU with the shared shape, and with their
        own per-frame fits.
    initial_cost, cost : float
        The session's contour cost before and after.
    iterations : int
        Accepted joint steps, over all descents.
    covariance : str
        Which covariance the standard errors come from.
    descents : int
        Joint descents averaged (one from the per-frame fits, the others from
        jittered copies of them).
    descent_spread : dict of str to float
        Per measurement, the standard deviation of the descents' end points
        (0 for one descent); the standard errors include it.
    prior_pull : dict of str to float
        Per measurement, how far the shape prior moved it: the value at the
        shared shape minus the value at the optimum of the data term alone
        (linearized about the shared shape; +: the prior raised it). Empty in runs
        recorded before it.
    seconds : float
    outline : OutlineCheck or None
        The loose-clothing and hair check on the session's frames (at the
        shared shape when accepted, else at the per-frame fits).
    floor_mm : float
        How far the fitted soles stood below the floor (world z = 0), mm: the
        median over the frames of each frame's lowest point when below 0
        (negative), else 0; NaN in runs recorded before it
        (:mod:`bodymetry.estimation.standing_height`).
    floor_height : bool
        Whether the height is read from the floor where the soles sink (the
        setting); False in runs recorded before it.
    floor_applied : bool
        Whether ``height_mm`` is the canonical body's height less the soles'
        depth: they sank, by at most
        :data:`~bodymetry.estimation.standing_height.MAX_SOLE_DEPTH` (runs
        recorded before the bound read every depth from the floor, and files
        without the field are read so).
    canonical_weight_kg : float
        The canonical (unposed) body's weight, kg; NaN in runs recorded before it.
    posed_weight : bool
        Whether ``weight_kg`` (and ``volume_l``, ``bmi``) were read from the
        fitted body in the frames' poses (:mod:`bodymetry.estimation.posed_weight`);
        False: the canonical body's, as in runs recorded before it.
    clothing_share : float
        The share of the stage's frames' silhouette pixels capture found not
        to be skin (clothing, hair, shoes; :mod:`bodymetry.capture.skin`),
        over the views where it told; NaN where it told nowhere (and in runs
        recorded before it). The stage does not use it yet: its measurements
        assume tight clothing.
    """

    status: str
    method: str = ""
    frames: tuple[int, ...] = ()
    nu: tuple[float, ...] = ()
    nu_se: tuple[float, ...] = ()
    start_nu: tuple[float, ...] = ()
    biometrics: dict[str, float] = field(default_factory=dict)
    standard_errors: dict[str, float] = field(default_factory=dict)
    frame_weights: dict[int, float] = field(default_factory=dict)
    mean_iou: float = math.nan
    reference_iou: float = math.nan
    initial_cost: float = math.nan
    cost: float = math.nan
    iterations: int = 0
    covariance: str = ""
    descents: int = 1
    descent_spread: dict[str, float] = field(default_factory=dict)
    prior_pull: dict[str, float] = field(default_factory=dict)
    seconds: float = 0.0
    outline: OutlineCheck | None = None
    floor_mm: float = math.nan
    floor_height: bool = False
    floor_applied: bool = False
    canonical_weight_kg: float = math.nan
    posed_weight: bool = False
    clothing_share: float = math.nan

    @property
    def ok(self) -> bool:
        return self.status == OK

    def to_json(self) -> dict[str, Any]:
        def floats(values: Sequence[float], digits: int) -> list[float | None]:
            return [_finite_or_none(v, digits) for v in values]

        return {
            "status": self.status,
            "method": self.method,
            "covariance": self.covariance,
            "frames": [int(f) for f in self.frames],
            "nu": floats(self.nu, 6),
            "nu_se": floats(self.nu_se, 6),
            "start_nu": floats(self.start_nu, 6),
            "biometrics": {k: _finite_or_none(v, 3) for k, v in self.biometrics.items()},
            "standard_errors": {k: _finite_or_none(v, 4) for k, v in self.standard_errors.items()},
            "frame_weights": {str(k): _finite_or_none(v, 4) for k, v in self.frame_weights.items()},
            "mean_iou": _finite_or_none(self.mean_iou, 4),
            "reference_iou": _finite_or_none(self.reference_iou, 4),
            "initial_cost": _finite_or_none(self.initial_cost, 4),
            "cost": _finite_or_none(self.cost, 4),
            "iterations": int(self.iterations),
            "descents": int(self.descents),
            "descent_spread": {k: _finite_or_none(v, 4) for k, v in self.descent_spread.items()},
            "prior_pull": {k: _finite_or_none(v, 4) for k, v in self.prior_pull.items()},
            "seconds": round(float(self.seconds), 2),
            "outline": None if self.outline is None else self.outline.to_json(),
            "floor_mm": _finite_or_none(self.floor_mm, 2),
            "floor_height": bool(self.floor_height),
            "floor_applied": bool(self.floor_applied),
            "canonical_weight_kg": _finite_or_none(self.canonical_weight_kg, 3),
            "posed_weight": bool(self.posed_weight),
            "clothing_share": _finite_or_none(self.clothing_share, 4),
        }

    @classmethod
    def from_json(cls, data: Any, where: str = "session_shape") -> SessionShape:
        """Read the block; InputError naming ``where`` when it is not one."""
        if not isinstance(data, Mapping) or "status" not in data:
            raise InputError(f"{where}: expected an object with a 'status'")

        try:
            return cls(
                status=str(data["status"]),
                method=str(data.get("method", "")),
                frames=tuple(int(f) for f in data.get("frames", ())),
                nu=tuple(_nan_if_none(v) for v in data.get("nu", ())),
                nu_se=tuple(_nan_if_none(v) for v in data.get("nu_se", ())),
                start_nu=tuple(_nan_if_none(v) for v in data.get("start_nu", ())),
                biometrics={k: _nan_if_none(v) for k, v in data.get("biometrics", {}).items()},
                standard_errors={
                    k: _nan_if_none(v) for k, v in data.get("standard_errors", {}).items()
                },
                frame_weights={
                    int(k): _nan_if_none(v) for k, v in data.get("frame_weights", {}).items()
                },
                mean_iou=_nan_if_none(data.get("mean_iou")),
                reference_iou=_nan_if_none(data.get("reference_iou")),
                initial_cost=_nan_if_none(data.get("initial_cost")),
                cost=_nan_if_none(data.get("cost")),
                iterations=int(data.get("iterations", 0)),
                covariance=str(data.get("covariance", "")),
                descents=int(data.get("descents", 1)),
                descent_spread={
                    k: _nan_if_none(v) for k, v in data.get("descent_spread", {}).items()
                },
                prior_pull={k: _nan_if_none(v) for k, v in data.get("prior_pull", {}).items()},
                seconds=float(data.get("seconds", 0.0)),
                outline=None
                if data.get("outline") is None
                else OutlineCheck.from_json(data["outline"], f"{where}.outline"),
                floor_mm=_nan_if_none(data.get("floor_mm")),
                floor_height=bool(data.get("floor_height", False)),
                floor_applied=bool(
                    data.get(
                        "floor_applied",
                        data.get("floor_height", False) and (data.get("floor_mm") or 0.0) < 0,
                    )
                ),
                canonical_weight_kg=_nan_if_none(data.get("canonical_weight_kg")),
                posed_weight=bool(data.get("posed_weight", False)),
                clothing_share=_nan_if_none(data.get("clothing_share")),
            )
        except (TypeError, ValueError, AttributeError) as exc:
            raise InputError(f"{where}: malformed session shape ({exc})") from exc


@dataclass(frozen=True)
class SessionGate:
    """The quality gate a session's frames were held to
    (:func:`bodymetry.estimation.fit.session_gate`; ``results.json``'s ``quality_gate``).

    Attributes
    ----------
    threshold : float
        The mean IoU a frame needed.
    min_iou : float
        The configured gate.
    reference : float or None
        The 75th percentile of the fitted frames' mean IoU (None: no fitted frame).
    width_scale : float
        How much the gate's IoU deficits were widened for a slim or small body
        (:func:`bodymetry.estimation.fit.width_scale`; 1: as configured, and in
        runs recorded before it).
    """

    threshold: float
    min_iou: float
    reference: float | None
    width_scale: float = 1.0

    @staticmethod
    def widened(min_iou: float, width_scale: float) -> float:
        """``min_iou`` with its deficit ``1 - min_iou`` widened by ``width_scale``."""
        return 1.0 - width_scale * (1.0 - min_iou)

    @property
    def follows_frames(self) -> bool:
        """Whether the session's good frames set the gate (it lies below what the
        widened ``min_iou`` alone would give), rather than ``min_iou`` itself."""
        widened = self.widened(self.min_iou, self.width_scale)
        return self.reference is not None and self.threshold < widened - 1e-6

    def to_json(self) -> dict[str, Any]:
        return {
            "threshold": round(self.threshold, 4),
            "min_iou": self.min_iou,
            "reference": None if self.reference is None else round(self.reference, 4),
            "width_scale": round(self.width_scale, 4),
        }

    @classmethod
    def from_json(cls, data: Any, where: str = "quality_gate") -> SessionGate:
        try:
            return cls(
                float(data["threshold"]),
                float(data["min_iou"]),
                None if data.get("reference") is None else float(data["reference"]),
                float(data.get("width_scale", 1.0)),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise InputError(f"{where}: malformed quality gate ({exc})") from exc
