"""The per-frame fit: discriminative initialization, then the generative search (paper §4-5).

For one kept frame: every usable camera's mixtures of experts propose states
(§4), the annealed particle filter searches from them against all views (§5),
the contour refinement polishes the best starts, and the biometrics of the
canonical body follow. :func:`fit_frame` never raises for bad data: a frame
that cannot be fitted gets a record saying why. Orchestration (sessions,
workers, run folders) is the application's (``bodymetry.process``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from bodymetry.calibration.camera import CameraGroup
from bodymetry.estimation.body_model.biometrics import DEFAULT_DENSITY, Biometrics, measure
from bodymetry.estimation.body_model.model import (
    NU,
    TAU,
    THETA,
    BodyModel,
    BodyState,
    shipped_model,
)
from bodymetry.estimation.contours import ContourObservation, prepare_contours
from bodymetry.estimation.generative import (
    AnnealingConfig,
    AnnealingResult,
    Observation,
    anneal,
    chamfer_costs,
    prepare_observation,
)
from bodymetry.estimation.landmark_pose import pose_from_landmarks
from bodymetry.estimation.projection import project_silhouettes, view_ious
from bodymetry.estimation.records import (
    AnnealingTrace,
    FrameArrays,
    FrameRecord,
    RefinementTrace,
    SessionGate,
    StageEstimate,
)
from bodymetry.estimation.refinement import RefineConfig, RefineResult, refine
from bodymetry.estimation.shape_context import ShapeContextConfig
from bodymetry.estimation.training import DiscriminativeModels, targets_to_theta
from bodymetry.estimation.view_features import silhouette_features
from bodymetry.estimation.view_selection import (
    ABSENT,
    MIN_PIXELS,
    MIN_VIEWS,
    blank_unusable,
    usable_views,
)

__all__ = [
    "MIN_PIXELS",
    "POOR_FIT",
    "PRESETS",
    "FitConfig",
    "FrameFit",
    "GenerativeFit",
    "discriminative_particles",
    "fit_frame",
    "generative_fit",
    "polish",
    "poor_fit_hint",
    "refit_frame",
    "shared_body_model",
]

#: How a fitted frame whose silhouettes the model explains too poorly is marked (its
#: status begins so, :func:`session_gate`).
POOR_FIT = "poor fit"

#: The quality presets: the one table of what ``--quality`` means.
PRESETS: dict[str, tuple[AnnealingConfig, RefineConfig]] = {
    "fast": (
        AnnealingConfig(n_particles=60, n_layers=6, image_scale=0.25),
        RefineConfig(iterations=10, screen_iterations=3),
    ),
    "default": (AnnealingConfig(), RefineConfig()),
    "best": (
        AnnealingConfig(n_particles=200, n_layers=20, image_scale=0.5),
        RefineConfig(iterations=40, screen_iterations=8, image_scale=1.0, max_points=800),
    ),
}


@dataclass(frozen=True)
class FitConfig:
    """How one frame is fitted.

    Attributes
    ----------
    seed : int
        Seeds every draw (with the frame number).
    density : float
        kg/m³ for weight.
    initial_particles : int
        Draws from the discriminative mixtures that start the search.
    landmark_share : float
        Fraction of the initial particles drawn around the pose fitted to the
        subject's 3D landmarks (:mod:`bodymetry.estimation.landmark_pose`),
        when capture found them; that pose is also a start of the refinement.
        0 searches from the discriminative mixtures alone (the paper).
    min_iou : float
        Quality gate: a frame whose fitted body overlaps the observed
        silhouettes less than this (mean IoU over its views) is marked
        ``"poor fit: ..."`` and left out of the summary; its numbers stay in
        its record. On the demo the fits that found the person's pose score
        0.90-0.96, those stuck in a wrong pose or limb configuration 0.82-0.87
        (their height errors are 11-53 mm, weight errors up to 25 kg). The
        session may lower it (:func:`session_gate`).
    rescue_neighbours : int
        Frames the session gate leaves out are fitted again with this many
        nearest accepted frames' fits as pose proposals
        (:func:`bodymetry.frame_jobs.rescue_poor_frames`); 0 turns it off.
    gate_margin, gate_floor : float
        The session gate (:func:`session_gate`): when even the session's good
        frames cannot reach ``min_iou`` (a real person in clothes is not the
        body model), a frame passes within ``gate_margin`` of the session's
        75th-percentile IoU, never below ``gate_floor``.
    annealing : AnnealingConfig
    refinement : RefineConfig
    """

    seed: int = 0
    density: float = DEFAULT_DENSITY
    initial_particles: int = 400
    landmark_share: float = 0.5
    min_iou: float = 0.9
    gate_margin: float = 0.03
    gate_floor: float = 0.8
    rescue_neighbours: int = 2
    annealing: AnnealingConfig = field(default_factory=AnnealingConfig)
    refinement: RefineConfig = field(default_factory=RefineConfig)

    def __post_init__(self) -> None:
        if self.density <= 0:
            raise ValueError(f"density: expected > 0 kg/m³, got {self.density}")
        if self.initial_particles < 1:
            raise ValueError(f"initial_particles: expected >= 1, got {self.initial_particles}")
        if not 0 <= self.min_iou <= 1:
            raise ValueError(f"min_iou: expected in [0, 1], got {self.min_iou}")
        if not 0 <= self.gate_floor <= 1 or not 0 <= self.gate_margin < 1:
            raise ValueError(
                "gate_floor, gate_margin: expected 0 <= gate_floor <= 1 and "
                f"0 <= gate_margin < 1, got {self.gate_floor}, {self.gate_margin}"
            )
        if self.rescue_neighbours < 0:
            raise ValueError(f"rescue_neighbours: expected >= 0, got {self.rescue_neighbours}")
        if not 0 <= self.landmark_share < 1:
            raise ValueError(f"landmark_share: expected in [0, 1), got {self.landmark_share}")

    @classmethod
    def preset(cls, quality: str, **kwargs) -> FitConfig:
        """The settings of a quality preset (:data:`PRESETS`), other fields from ``kwargs``."""
        if quality not in PRESETS:
            raise ValueError(f"quality: expected one of {', '.join(PRESETS)}, got {quality!r}")
        annealing, refinement = PRESETS[quality]
        return cls(annealing=annealing, refinement=refinement, **kwargs)


def shared_body_model() -> BodyModel:
    """The shipped body model, loaded once per process (workers fit many frames;
    training uses the same one, :func:`~bodymetry.estimation.body_model.model.shipped_model`)."""
    return shipped_model()


def preload(cameras: CameraGroup, refinement: RefineConfig | None = None) -> None:
    """Load, in this process, what every frame's fit and the session stage both use.

    The body model with its factorizations and skeleton anchors at both
    resolutions, and the compiled kernels of posing, rasterizing, the
    likelihood, the silhouette features and contour alignment (numba loads
    each from its cache on first use): a worker pool forked afterwards inherits
    them instead of loading them in every worker, and the session stage, which
    runs here later, needs them anyway. Thread-safe against work that does not
    use the body model (``process`` runs it beside the silhouettes).

    Parameters
    ----------
    cameras : CameraGroup
        The working cameras.
    refinement : RefineConfig, optional
        The run's contour alignment (one step of it runs on the rest body).
    """
    body = shared_body_model()
    rest = BodyState.rest(body.n_shape)
    body.pose(rest)  # the full mesh's anchors and factorization
    lod = body.pose(rest, lod=True).vertices[0]
    faces = body.faces(lod=True)
    masks = project_silhouettes(lod, faces, cameras)
    chamfer_costs(prepare_observation(cameras, masks, AnnealingConfig().image_scale), lod, faces)
    seen = [m for m in masks if m.any()]
    if seen:
        silhouette_features(seen[0], np.random.default_rng(0), ShapeContextConfig())
    config = replace(refinement or RefineConfig(), iterations=1)
    refine(body, prepare_contours(cameras, masks, config.image_scale), rest.vector()[0], config)


def discriminative_particles(
    models: DiscriminativeModels,
    masks: Sequence[np.ndarray] | np.ndarray,
    valid: np.ndarray,
    n: int,
    rng: np.random.Generator,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Initial particles drawn from every usable camera's mixtures.

    Parameters
    ----------
    models : DiscriminativeModels
    masks : sequence of C (H_c, W_c) bool, or (C, H, W) bool
        Per camera, each at its own size.
    valid : (C,) bool
        Cameras with a usable silhouette.
    n : int
        Particles in all (split evenly between the usable cameras).
    rng : Generator

    Returns
    -------
    particles : (n', 40 + n_shape) float
        ``[τ, θ, ν]`` draws.
    points : list of (40 + n_shape,) float
        Each usable camera's point prediction.
    """
    per = max(1, n // max(1, int(np.count_nonzero(valid))))
    particles, points = [], []
    for c, name in enumerate(models.camera_names):
        if not valid[c]:
            continue
        x_rdf, x_sc = models.features(name, masks[c], rng)
        m = models.models[name]
        nu = m["nu_rdf"].sample(x_rdf, per, rng)
        theta = targets_to_theta(m["theta_sc"].sample(x_sc, per, rng))
        tau = m["tau_rdf"].sample(x_rdf, per, rng)
        particles.append(np.hstack([tau, theta, nu]))
        point = np.hstack(
            [
                m["tau_rdf"].predict(x_rdf[None])[0],
                targets_to_theta(m["theta_sc"].predict(x_sc[None], mode="gate"))[0],
                m["nu_rdf"].predict(x_rdf[None])[0],
            ]
        )
        points.append(point)
    return np.vstack(particles), points


def _clip_pose(body: BodyModel, vectors: np.ndarray) -> np.ndarray:
    """States ``(..., 40 + n_shape)`` with θ clipped to the joint limits."""
    states = BodyState.from_vector(np.atleast_2d(vectors))
    clipped = replace(states, theta=body.limits.clip(states.theta))
    return clipped.vector().reshape(np.shape(vectors))


#: Spread of the particles drawn around the landmark pose: τ (m), θ (rad).
_LANDMARK_SPREAD = (0.03, 0.08)

#: Share of the initial particles drawn around the caller's pose proposals.
PROPOSAL_SHARE = 0.5


def _draws_around(
    body: BodyModel,
    centres: np.ndarray,
    particles: np.ndarray,
    share: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Replace ``share`` of the particles by draws of τ and θ around given poses.

    Each draw keeps the shape of the particle it replaces (the shape search stays
    the mixtures'); the draws are shared evenly among the centres.

    Parameters
    ----------
    centres : (K, 40 + n_shape) float
        The poses to draw around (their ν is not used).
    particles : (N, 40 + n_shape) float

    Returns
    -------
    (N, 40 + n_shape) float
        The kept particles, then the draws.
    """
    n = len(particles)
    k = round(share * n)
    keep = rng.permutation(n)
    drawn = particles[keep[:k]].copy()
    centres = np.atleast_2d(centres)
    centre = centres[np.arange(k) % len(centres)]
    drawn[:, TAU] = centre[:, TAU] + rng.normal(0.0, _LANDMARK_SPREAD[0], (k, 3))
    drawn[:, THETA] = body.limits.clip(
        centre[:, THETA] + rng.normal(0.0, _LANDMARK_SPREAD[1], (k, 37))
    )
    return np.vstack([particles[keep[k:]], drawn])


def _with_landmark_particles(
    body: BodyModel,
    landmarks: np.ndarray,
    disc: BodyState,
    particles: np.ndarray,
    share: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Replace ``share`` of the initial particles by draws around the landmark pose.

    The pose is solved for the discriminative shape. Returns the particles and
    the landmark pose's state vector (None, and the particles unchanged, when
    the landmarks do not give a pose).
    """
    pose = pose_from_landmarks(body, landmarks, disc.nu[0])
    if pose is None:
        return particles, None
    start = np.concatenate([pose.tau, pose.theta, disc.nu[0]])
    return _draws_around(body, start[None], particles, share, rng), start


@dataclass(frozen=True)
class FrameFit:
    """One frame's fit: its record and the arrays it leaves for review.

    Attributes
    ----------
    record : FrameRecord
    arrays : FrameArrays
        Observed and model silhouettes, the last annealing layer.
    state : BodyState or None
        The generative estimate (None when there is no fit).
    """

    record: FrameRecord
    arrays: FrameArrays
    state: BodyState | None = None


def fit_frame(
    frame: int,
    masks: Sequence[np.ndarray] | np.ndarray,
    flags: list[list[str]],
    cameras: CameraGroup,
    models: DiscriminativeModels,
    config: FitConfig,
    landmarks: np.ndarray | None = None,
    proposals: dict[str, np.ndarray] | None = None,
    agreement: dict[str, float] | None = None,
    persons: int | None = None,
    unknown: Sequence[np.ndarray | None] | None = None,
    clothing: Sequence[np.ndarray | None] | None = None,
    contrast: float | None = None,
) -> FrameFit:
    """Fit one frame (never raises for bad data: the record says what went wrong).

    A frame that fewer than :data:`~bodymetry.estimation.view_selection.MIN_VIEWS`
    of a rig's cameras show usably is not fitted ("too few views"): one
    silhouette says nothing of the body's depth.

    Parameters
    ----------
    frame : int
        Session frame (seeds the draws with ``config.seed``).
    masks : sequence of C (H_c, W_c) bool, or (C, H, W) bool
        Observed silhouettes, camera order of ``cameras``, each at its camera's
        size (cameras may differ in size; a mask of the wrong size gives a
        ``"fit failed: ..."`` record naming the camera).
    flags : list of list of str
        Silhouette flags per camera; a view flagged ``unreadable`` or
        ``unreliable`` is left out (:func:`~bodymetry.estimation.view_selection.usable_views`).
    cameras : CameraGroup
    models : DiscriminativeModels
        Trained for these cameras.
    config : FitConfig
    landmarks : (33, 3) float, optional
        The subject's body landmarks in the world frame (NaN rows: not seen),
        from capture; they add pose proposals (``config.landmark_share``).
    proposals : name -> (40 + n_shape,) float, optional
        More poses to search around, e.g. the fits of neighbouring frames
        (:func:`bodymetry.frame_jobs.rescue_poor_frames`): half of the
        mixtures' particles are drawn around them, and each is a start of the
        refinement under its name.
    agreement : camera name -> float, optional
        Capture's agreement of each judged view with the frame's other
        evidence; recorded as the record's ``view_agreement``.
    persons : int, optional
        Person-sized bodies capture counted in the capture volume; recorded as the
        record's ``persons`` (None: not counted).
    unknown : sequence of C ((H_c, W_c) bool or None), optional
        Per camera, the person's pixels someone nearer covers: neither person
        nor background to the likelihood, the contour refinement and the IoU
        (:func:`~bodymetry.estimation.generative.prepare_observation`); kept
        in the frame's arrays for the session stage.
    clothing : sequence of C ((H_c, W_c) bool or None), optional
        Per camera, the pixels capture found not to be skin (clothing, hair,
        shoes); kept in the frame's arrays where they fall on the silhouette.
    contrast : float, optional
        Capture's outline contrast; recorded as the record's ``outline_contrast``.
    """
    t0 = time.perf_counter()
    body = shared_body_model()
    rng = np.random.default_rng([config.seed, frame])
    names = cameras.names
    pixels = {n: int(np.count_nonzero(m)) for n, m in zip(names, masks, strict=True)}
    flag_map = {n: tuple(f) for n, f in zip(names, flags, strict=True)}
    valid = usable_views(names, pixels, flag_map)
    views = _ViewFacts(
        flag_map, pixels, {n: float(v) for n, v in (agreement or {}).items()}, persons, contrast
    )
    observed_arrays = FrameArrays(
        observed={n: np.asarray(m, bool) for n, m in zip(names, masks, strict=True)},
        landmarks=landmarks,
        unknown={
            n: np.asarray(u, bool)
            for n, u in zip(names, unknown or [None] * len(names), strict=True)
            if u is not None and np.any(u)
        },
        clothing={
            n: np.asarray(c, bool) & np.asarray(m, bool)
            for n, c, m in zip(names, clothing or [None] * len(names), masks, strict=True)
            if c is not None and np.shape(c) == np.shape(m)
        },
    )

    def failed(status: str) -> FrameFit:
        return FrameFit(
            FrameRecord(
                int(frame),
                status,
                flag_map,
                person_pixels=pixels,
                view_agreement=views.agreement,
                persons=views.persons,
                outline_contrast=views.contrast,
            ),
            observed_arrays,
        )

    if valid.sum() == 0:
        if flag_map and all(ABSENT in f for f in flag_map.values()):
            # A person told apart from others whom capture did not find in this frame.
            return failed(
                "person not found in this frame (fewer than three cameras agreed on them)"
            )
        return failed("no silhouette in any camera")
    if valid.sum() < MIN_VIEWS <= len(names):
        seen = ", ".join(n for n, ok in zip(names, valid, strict=True) if ok)
        return failed(
            f"too few views: only {seen} of {len(names)} cameras shows the person usably, "
            f"and one view cannot tell the body's depth (at least {MIN_VIEWS} are needed)"
        )
    try:
        # Unusable views become empty masks of their own size (left out downstream).
        # Prepared first: it checks every mask against its camera's size.
        observed = blank_unusable(masks, valid)
        hidden = observed_arrays.unknown_of(names)
        obs = prepare_observation(cameras, observed, config.annealing.image_scale, hidden)
        particles, points, disc_state = _discriminative(
            body, models, masks, valid, obs, config, rng
        )
        t_disc = time.perf_counter() - t0
        particles, starts = _search_starts(
            body, cameras, valid, points, particles, disc_state, proposals, landmarks, config, rng
        )
        fit = generative_fit(body, cameras, observed, particles, config, rng, starts, obs, hidden)
        t_gen = time.perf_counter() - t0 - t_disc
    except (ValueError, np.linalg.LinAlgError) as exc:
        return failed(f"fit failed: {exc}")
    result, refined = fit.annealing, fit.refined
    if not np.all(np.isfinite(refined.vector)) or not np.isfinite(result.best_cost):
        return failed("likelihood collapse (non-finite estimate)")
    bios = measure(body, np.vstack([disc_state.nu, refined.state.nu]), density=config.density)
    record = _fitted_record(
        frame, views, StageEstimate(disc_state, bios[0].to_dict()), fit, t_disc, t_gen
    )
    arrays = replace(observed_arrays, particles=result.particles, weights=result.weights)
    return _finish(body, record, arrays, refined, bios[1], fit.start, cameras, valid, config, t0)


@dataclass(frozen=True)
class _ViewFacts:
    """What a frame's record says about its views: capture's flags, the person
    pixels and capture's agreement, by camera name, capture's person count and its
    outline contrast."""

    flags: dict[str, tuple[str, ...]]
    pixels: dict[str, int]
    agreement: dict[str, float]
    persons: int | None = None
    contrast: float | None = None


def _fitted_record(
    frame: int,
    views: _ViewFacts,
    discriminative: StageEstimate,
    fit: GenerativeFit,
    t_disc: float,
    t_gen: float,
) -> FrameRecord:
    """The record of a fitted frame before :func:`_finish`: its views' facts, the
    discriminative estimate, the annealing's trace and the stages' seconds."""
    return FrameRecord(
        frame=int(frame),
        status="",
        flags=views.flags,
        person_pixels=views.pixels,
        view_agreement=views.agreement,
        persons=views.persons,
        outline_contrast=views.contrast,
        estimates={"discriminative": discriminative},
        annealing=AnnealingTrace(
            tuple(fit.annealing.layer_log_likelihood.tolist()),
            tuple(fit.annealing.layer_beta.tolist()),
            tuple(fit.annealing.particles[:, TAU].std(axis=0).tolist()),
            tuple(fit.annealing.particles[:, NU].std(axis=0).tolist()),
        ),
        seconds={
            "discriminative": t_disc,
            "annealing": fit.seconds[0],
            "refinement": fit.seconds[1],
            "generative": t_gen,
        },
    )


def _discriminative(
    body: BodyModel,
    models: DiscriminativeModels,
    masks: Sequence[np.ndarray] | np.ndarray,
    valid: np.ndarray,
    obs: Observation,
    config: FitConfig,
    rng: np.random.Generator,
) -> tuple[np.ndarray, list[np.ndarray], BodyState]:
    """The discriminative stage of one frame.

    Returns
    -------
    particles : (N, 40 + n_shape) float
        Initial particles drawn from the mixtures, clipped to the pose limits.
    points : list of (40 + n_shape,) float
        Each usable camera's point prediction, clipped likewise.
    estimate : BodyState
        The discriminative estimate: the camera prediction whose body explains
        all views best (lowest summed chamfer cost).
    """
    particles, points = discriminative_particles(
        models, masks, valid, config.initial_particles, rng
    )
    particles = _clip_pose(body, particles)
    points = [_clip_pose(body, p) for p in points]
    faces = body.faces(lod=True)
    costs = [
        chamfer_costs(
            obs, body.pose(BodyState.from_vector(p[None]), lod=True).vertices[0], faces
        ).sum()
        for p in points
    ]
    return particles, points, BodyState.from_vector(points[int(np.argmin(costs))][None])


def _search_starts(
    body: BodyModel,
    cameras: CameraGroup,
    valid: np.ndarray,
    points: list[np.ndarray],
    particles: np.ndarray,
    disc_state: BodyState,
    proposals: dict[str, np.ndarray] | None,
    landmarks: np.ndarray | None,
    config: FitConfig,
    rng: np.random.Generator,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The annealing's initial particles and the refinement's named starts.

    The starts are each usable camera's discriminative prediction, the
    ``proposals`` (half of the mixtures' particles are redrawn around them)
    and, with ``landmarks``, the pose fitted to them (``config.landmark_share``
    of the particles drawn around it).

    Returns
    -------
    particles : (N, 40 + n_shape) float
    starts : dict of str -> (40 + n_shape,) float
    """
    starts = {
        f"discriminative {cameras[c].name}": p
        for c, p in zip(np.flatnonzero(valid), points, strict=True)
    }
    if proposals:
        particles = _draws_around(
            body, np.array(list(proposals.values())), particles, PROPOSAL_SHARE, rng
        )
        starts.update(proposals)
    if landmarks is not None and config.landmark_share > 0:
        particles, start = _with_landmark_particles(
            body, landmarks, disc_state, particles, config.landmark_share, rng
        )
        if start is not None:
            starts["landmarks"] = start
    return particles, starts


def _finish(
    body: BodyModel,
    record: FrameRecord,
    arrays: FrameArrays,
    refined: RefineResult,
    biometrics: Biometrics,
    start: str,
    cameras: CameraGroup,
    valid: np.ndarray,
    config: FitConfig,
    t0: float,
) -> FrameFit:
    """A frame's fit from its refined state: the generative estimate, the model
    silhouettes and their IoU, the gate status and the total time, added to
    ``record`` (its other fields as the caller set them) and ``arrays``."""
    state = refined.state
    names = cameras.names
    masks = [arrays.observed[n] for n in names]
    model_masks = project_silhouettes(
        body.pose(state, lod=True).vertices[0], body.faces(lod=True), cameras
    )
    iou = view_ious(cameras, model_masks, masks, valid, arrays.unknown_of(names))
    mean_iou = float(np.mean(list(iou.values())))
    record = replace(
        record,
        status=_gate_status(mean_iou, config.min_iou),
        estimates={
            **record.estimates,
            "generative": StageEstimate(state, biometrics.to_dict()),
        },
        silhouette_iou=iou,
        refinement=RefinementTrace(start, refined.initial_cost, refined.cost, refined.iterations),
        seconds={**record.seconds, "total": time.perf_counter() - t0},
    )
    arrays = replace(arrays, model={n: model_masks[c] for c, n in enumerate(names)})
    return FrameFit(record, arrays, state)


def refit_frame(
    previous: FrameFit, cameras: CameraGroup, config: FitConfig, proposals: dict[str, np.ndarray]
) -> FrameFit:
    """Fit a frame again by contour refinement alone, from other poses (a cheap rescue).

    The starts are ``proposals`` (e.g. the neighbouring frames' fits, a person
    moves little between kept frames) and the frame's own generative estimate,
    screened and polished as :func:`generative_fit` does. The discriminative
    estimate, the annealing's trace and its last layer are the previous fit's;
    ``seconds`` adds ``rescue``, and its total is both fits'.

    Parameters
    ----------
    previous : FrameFit
        The frame's fit: its record and arrays (observed silhouettes at the
        working resolution, last annealing layer).
    cameras : CameraGroup
        The working cameras it was fitted with.
    config : FitConfig
    proposals : name -> (40 + n_shape,) float

    Returns
    -------
    FrameFit
        ``previous`` itself when it has no generative estimate or the refinement
        fails.
    """
    record, body = previous.record, shared_body_model()
    # The record's total is the work behind it: the first fit's and this.
    t0 = time.perf_counter() - record.seconds.get("total", 0.0)
    t_start = time.perf_counter()
    first = record.estimate("generative")
    if first is None or not first.finite:
        return previous
    names = cameras.names
    masks = [previous.arrays.observed[n] for n in names]
    valid = usable_views(names, record.person_pixels, record.flags)
    observed = blank_unusable(masks, valid)
    try:
        contours = prepare_contours(
            cameras,
            observed,
            config.refinement.image_scale,
            config.refinement.max_points,
            previous.arrays.unknown_of(names),
        )
        starts = {**proposals, f"frame {record.frame} (first fit)": first.vector()}
        refined, start = polish(body, contours, starts, config.refinement)
    except (ValueError, np.linalg.LinAlgError):
        return previous
    if not np.all(np.isfinite(refined.vector)):
        return previous
    bios = measure(body, refined.state.nu, density=config.density)[0]
    seconds = {**record.seconds, "rescue": time.perf_counter() - t_start}
    return _finish(
        body,
        replace(record, seconds=seconds),
        previous.arrays,
        refined,
        bios,
        start,
        cameras,
        valid,
        config,
        t0,
    )


#: The silhouette width ``sqrt(volume / height)`` (m) of the bodies ``min_iou`` and
#: ``gate_margin`` were set on: the studio's mid-population adults (the mean adult,
#: ν = 0: 1689 mm and 66.7 l, gives 0.199 m).
REFERENCE_WIDTH_M = 0.199
#: The most a slim or small body relaxes the gate's IoU deficits (a 6-year-old:
#: 1.47; beyond that the gate would stop telling a wrong pose from a right one).
MAX_WIDTH_SCALE = 1.5


def width_scale(records: Sequence[FrameRecord]) -> float:
    """How much wider a session's IoU deficits are because its body is slimmer or
    smaller than the bodies the gate was set on.

    For an outline off by the same distance everywhere, ``1 - IoU`` is that distance
    times the silhouette's perimeter over its area, and the perimeter over the
    area of a body's silhouettes goes as one over its width. The width is
    ``W = sqrt(V / H)`` of the fitted frames' median generative volume and height;
    the scale is ``REFERENCE_WIDTH_M / W``, at least 1 (a broader body keeps the
    gate it was set with) and at most :data:`MAX_WIDTH_SCALE`; 1 when the records
    do not carry both measurements.
    """
    sizes = [
        (est.biometrics.get("volume_l", math.nan), est.biometrics.get("height_mm", math.nan))
        for r in records
        if r.fitted and (est := r.estimates.get("generative")) is not None
    ]
    sizes = [(v, h) for v, h in sizes if math.isfinite(v) and math.isfinite(h) and v > 0 < h]
    if not sizes:
        return 1.0
    volume_m3, height_m = np.median(np.array(sizes), axis=0) / 1000.0
    return float(np.clip(REFERENCE_WIDTH_M / math.sqrt(volume_m3 / height_m), 1.0, MAX_WIDTH_SCALE))


def session_gate(
    records: Sequence[FrameRecord], config: FitConfig
) -> tuple[SessionGate, list[FrameRecord]]:
    """Hold a session's fitted frames to one gate, relative to its own good frames.

    ``min_iou`` was set on studio sessions, whose silhouettes are the body
    model's own: a correct fit scores 0.90-0.96 there. A real person in
    clothes, seen through a learned segmenter, is not the model: on the
    Pose2Sim demo every frame's fit is in the right pose (checked on the
    overlays) and scores 0.86-0.89. So the gate is
    ``min(min_iou, max(gate_floor, p75 - gate_margin))`` with p75 the 75th
    percentile of the fitted frames' mean IoU: unchanged where the good frames
    reach ``min_iou`` (the studio sessions), and otherwise a frame passes
    when it is within ``gate_margin`` of the session's good frames. A frame
    stuck in a wrong pose scores well below them in either case. Both
    deficits, ``1 - min_iou`` and ``gate_margin``, are set for mid-population
    bodies and widen by :func:`width_scale` for a slimmer or smaller one (a
    child's right pose scores lower IoU than an adult's).

    Returns
    -------
    SessionGate
    list of FrameRecord
        The records with their status set by that gate (fitted frames only;
        the others keep theirs).
    """
    fitted = [r.mean_iou for r in records if r.fitted and math.isfinite(r.mean_iou)]
    if not fitted:
        return SessionGate(config.min_iou, config.min_iou, None), list(records)
    reference = float(np.percentile(fitted, 75))
    scale = width_scale(records)
    # A slim or small body's silhouettes lose more IoU to the same outline error:
    # both deficits (from a perfect overlap, from the good frames) widen with it.
    min_iou = SessionGate.widened(config.min_iou, scale)
    threshold = min(min_iou, max(config.gate_floor, reference - scale * config.gate_margin))
    out = []
    for r in records:
        if r.fitted and math.isfinite(r.mean_iou):
            r = replace(r, status=_gate_status(r.mean_iou, threshold))
        out.append(r)
    return SessionGate(threshold, config.min_iou, reference, scale), out


def poor_fit_hint(records: Sequence[FrameRecord]) -> str:
    """What can make every frame a poor fit, with the best frame's mean IoU; ``""``
    unless every record is one.

    Found in every view and fitted, but never well: what the cameras saw is not a
    body the model can take the shape of (the studio's long skirts: a mean IoU of
    0.60-0.70 in every frame, docs/session-shape.md, "Skirts"), or the cameras do
    not see what the calibration says.
    """
    if not records or {r.status_kind for r in records} != {POOR_FIT}:
        return ""
    means = [r.mean_iou for r in records if math.isfinite(r.mean_iou)]
    best = f" (the best frame's mean IoU {max(means):.2f})" if means else ""
    return (
        f"the body model fitted no frame's silhouettes well{best}: clothing that hides "
        "the body's shape (a long skirt or coat), something carried, or a calibration "
        "that does not fit the videos; the report's overlays show where"
    )


def _gate_status(mean_iou: float, threshold: float) -> str:
    if mean_iou >= threshold:
        return "ok"
    return f"{POOR_FIT}: mean silhouette IoU {mean_iou:.2f} < {threshold:.2f}"


@dataclass(frozen=True)
class GenerativeFit:
    """The generative stage's outcome for one frame.

    Attributes
    ----------
    annealing : AnnealingResult
        The annealed particle filter (paper §5).
    refined : RefineResult
        The contour refinement of the best start (the estimate).
    start : str
        Which start the refinement came from.
    seconds : (float, float)
        Time spent annealing and refining.
    """

    annealing: AnnealingResult
    refined: RefineResult
    start: str
    seconds: tuple[float, float]


def generative_fit(
    body: BodyModel,
    cameras: CameraGroup,
    masks: Sequence[np.ndarray] | np.ndarray,
    initial: np.ndarray,
    config: FitConfig,
    rng: np.random.Generator,
    extra_starts: dict[str, np.ndarray] | None = None,
    obs: Observation | None = None,
    unknown: Sequence[np.ndarray | None] | None = None,
) -> GenerativeFit:
    """Annealed search from initial particles, then contour refinement.

    Parameters
    ----------
    body : BodyModel
    cameras : CameraGroup
    masks : sequence of C (H_c, W_c) bool, or (C, H, W) bool
        Observed silhouettes, each at its camera's size; all-False views are
        left out.
    initial : (N0, 40 + n_shape) float
        Initial particles.
    config : FitConfig
    rng : Generator
    extra_starts : name -> (40 + n_shape,) float, optional
        More starts for the refinement (e.g. each camera's discriminative
        prediction), besides the annealing's weighted mean and best particle.
    obs : Observation, optional
        The prepared observation, if the caller has it already (with the same
        ``unknown``).
    unknown : sequence of C ((H_c, W_c) bool or None), optional
        Pixels that are neither the person's nor background (someone nearer
        covers them), per view.
    """
    t0 = time.perf_counter()
    obs = obs or prepare_observation(cameras, masks, config.annealing.image_scale, unknown)
    result = anneal(body, obs, initial, config.annealing, rng)
    t1 = time.perf_counter()
    contours = prepare_contours(
        cameras, masks, config.refinement.image_scale, config.refinement.max_points, unknown
    )
    starts = {
        "annealing mean": result.state.vector()[0],
        "best particle": result.particles[int(np.argmax(result.weights))],
        **(extra_starts or {}),
    }
    refined, chosen = polish(body, contours, starts, config.refinement)
    return GenerativeFit(result, refined, chosen, (t1 - t0, time.perf_counter() - t1))


def polish(
    body: BodyModel,
    contours: ContourObservation,
    candidates: dict[str, np.ndarray],
    config: RefineConfig,
) -> tuple[RefineResult, str]:
    """Refine several starting states briefly, then the most promising one fully.

    Parameters
    ----------
    body : BodyModel
    contours : ContourObservation
    candidates : name -> (40 + n_shape,) float
        E.g. the annealing estimate, its best particle, each camera's
        discriminative prediction (modes the annealing may have missed).
    config : RefineConfig

    Returns
    -------
    RefineResult
        The refined state (its ``initial_cost`` is the chosen start's).
    str
        The name of the candidate it started from.
    """
    # Screening is on the level of detail with a working-resolution raster and no
    # outline offsets (cheap: it only ranks the starts); the chosen one gets the
    # full config.
    screen = replace(
        config,
        iterations=config.screen_iterations,
        full_mesh=False,
        visibility_scale=config.image_scale,
        outline_offsets=False,
    )
    trials = {name: refine(body, contours, y, screen) for name, y in candidates.items()}
    name = min(trials, key=lambda k: trials[k].cost)
    first = trials[name]
    rest = refine(
        body,
        contours,
        first.vector,
        replace(config, iterations=max(0, config.iterations - first.iterations)),
    )
    return replace(
        rest, initial_cost=first.initial_cost, iterations=first.iterations + rest.iterations
    ), name
