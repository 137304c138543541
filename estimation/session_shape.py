"""One body shape per session: a joint refinement over the accepted frames (beyond the paper).

Every frame's fit (:mod:`bodymetry.estimation.fit`) estimates its own state
``Y = (τ, θ, ν)``, but the subject's shape ν is one for the whole session. This
stage refines ONE ν together with every accepted frame's pose ``(τ_f, θ_f)``
against every accepted frame's silhouettes in all views, by damped
Gauss-Newton (Levenberg-Marquardt) on the stacked contour residuals of
:mod:`bodymetry.estimation.refinement` (the same cost, correspondences and
Huber weights as each frame's own refinement):

* each frame's Jacobian ``[J_pose_f | J_ν_f]`` is one forward-difference
  linearization of its cost (:meth:`ContourCost.linearize`);
* the normal equations are block-arrow shaped (the poses are independent given
  ν), so the poses are eliminated frame by frame (Schur complement) and a
  49-dimensional solve per frame plus one ``n_shape`` solve gives the joint
  step of every pose and the shared shape;
* a Gaussian prior ν ~ N(0, I) enters once for the session (not once per frame);
* robustness: besides the per-residual Huber weights, a frame whose contour
  cost exceeds ``frame_scale`` times the session's median gets its weight
  lowered to ``frame_scale * median / cost`` (a Huber weight on the frame's
  cost), so one badly segmented frame cannot pull the shared shape.

The start is the per-frame generative fits with their shapes replaced by the
coordinate-wise median of their ν. The contour cost is piecewise constant in
which edges are on the contour and which outline point each pairs with, so
where a descent ends moves with the last digits of its start (two CPUs'
rounding is enough; docs/session-shape.md). The stage therefore runs
``descents`` descents, the first from that start and the others from copies of
it jittered by ``jitter`` (seeded), and reports their average: the states are
averaged frame by frame (the shape rows stay one shared ν), and the
correspondences, IoUs and covariance are those of the averaged state.

The result is accepted only when it keeps the frames' silhouette overlap: the
mean IoU over the frames (the level of detail, as the quality gate measures it)
may drop by at most ``max_iou_drop`` from the per-frame fits' (a shared shape
has fewer degrees of freedom than a shape per frame; a larger drop means it
does not explain the frames); otherwise the status says why and the stage's
estimate is withheld.

Uncertainty (docs/session-shape.md): the covariance of ν is the cluster-robust
(sandwich) Gauss-Newton covariance with the frames as clusters,
``H⁻¹ (n/(n-1) Σ_f (g_f - ḡ)(g_f - ḡ)ᵀ) H⁻¹``, where ``H`` is the pose-marginal
Gauss-Newton matrix and ``g_f`` each frame's pose-marginal gradient at the
solution: the linearized bootstrap over frames. The contour residuals of one
frame are strongly correlated (neighbouring points, one segmentation), so the
classical ``σ² H⁻¹`` would treat thousands of residuals as independent and
understate the error; frame-to-frame disagreement is what the sandwich
measures. Each biometric's standard error follows by propagating that
covariance through a central-difference Jacobian of the biometrics with
respect to ν. With fewer than 3 frames the classical covariance is used. The
average of K descents scatters by the covariance of their end points over K,
which is added (``descent_spread`` records each measurement's spread).
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from bodymetry.calibration.camera import CameraGroup
from bodymetry.estimation.body_model.biometrics import DEFAULT_DENSITY, measure
from bodymetry.estimation.body_model.model import NU, POSE_DIM, BodyModel, BodyState
from bodymetry.estimation.contours import prepare_contours
from bodymetry.estimation.generative import state_bounds, weighted_estimate
from bodymetry.estimation.least_squares import Damping, damped_inverse, damped_step, marquardt
from bodymetry.estimation.posed_weight import posed_volumes, weight_from_posed
from bodymetry.estimation.projection import project_silhouettes, view_ious
from bodymetry.estimation.records import FrameArrays, FrameRecord, SessionShape, StageEstimate
from bodymetry.estimation.refinement import (
    Alignment,
    ContourCost,
    RefineConfig,
    difference_steps,
)
from bodymetry.estimation.standing_height import (
    MAX_SOLE_DEPTH,
    from_the_floor,
    lowest_points,
    reads_from_floor,
    sole_depth,
)
from bodymetry.estimation.view_selection import blank_unusable, usable_views
from bodymetry.log import Progress

log = logging.getLogger(__name__)

__all__ = [
    "METHOD",
    "SessionFrame",
    "SessionShapeConfig",
    "SessionShapeFit",
    "biometric_errors",
    "fit_session_shape",
    "prior_pull",
    "session_frame",
    "silhouette_iou",
]

#: How the stage estimates and what its standard errors are (recorded in results.json).
METHOD = (
    "joint Levenberg-Marquardt of one shape and every frame's pose on the stacked "
    "contour residuals, averaged over descents from jittered starts; standard errors: "
    "cluster-robust (frames) Gauss-Newton covariance plus the descents' spread"
)

#: Most damping increases (× 4 each) tried for one joint step.
_RETRIES = 5

#: Step of the forward differences of the biometrics with respect to ν.
_BIO_STEP = 0.05


@dataclass(frozen=True)
class SessionShapeConfig:
    """Settings of the session stage.

    Attributes
    ----------
    enabled : bool
        Run the stage (``--set session_shape.enabled=false`` skips it).
    iterations : int
        Most joint Levenberg-Marquardt steps.
    frame_scale : float
        Frames whose contour cost exceeds this multiple of the session's
        median are down-weighted (``frame_scale * median / cost``).
    max_iou_drop : float
        The result is accepted when the frames' mean silhouette IoU is at most
        this much below the per-frame fits' mean IoU on the same frames.
    min_frames : int
        Fewer accepted frames than this: the stage is skipped.
    tolerance : float
        Stop when a step lowers the session cost by less than this fraction.
    descents : int
        Joint descents averaged: one from the per-frame fits, the others from
        copies of them jittered by ``jitter``.
    jitter : float
        Standard deviation of the jitter of every start value (metres, radians
        and shape standard deviations alike: far below what a fit resolves).
    floor_height : bool
        Read the height from the floor where the fitted soles sink below it
        (:mod:`bodymetry.estimation.standing_height`); false keeps the canonical
        body's height (a world whose z = 0 is not the floor).
    seed : int
        Seed of the jitter.
    image_scale : float
        Scale of the images the contours are compared at, and ...
    max_points : int
        ... the outline points per view: the stage measures, so it compares at
        the images' own resolution with twice the per-frame refinement's points
        (the ``best`` quality preset's; docs/session-shape.md, "Full resolution").
        They replace the refinement's own.
    thin_px : float
        Parts of the model narrower than about twice this many camera pixels
        give no model-to-observed residual (:attr:`RefineConfig.thin_px`; the
        fingers of a child: docs/session-shape.md, "Parts the camera does not
        resolve"). 0: every part counts.
    """

    enabled: bool = True
    iterations: int = 3
    frame_scale: float = 2.0
    max_iou_drop: float = 0.01
    min_frames: int = 2
    tolerance: float = 1e-3
    descents: int = 4
    jitter: float = 1e-3
    seed: int = 0
    floor_height: bool = True
    posed_weight: bool = True
    image_scale: float = 1.0
    max_points: int = 800
    thin_px: float = 1.2

    def __post_init__(self) -> None:
        if self.iterations < 0:
            raise ValueError(f"iterations: expected >= 0, got {self.iterations}")
        if not self.frame_scale >= 1:
            raise ValueError(f"frame_scale: expected >= 1, got {self.frame_scale}")
        if not 0 <= self.max_iou_drop <= 1:
            raise ValueError(f"max_iou_drop: expected in [0, 1], got {self.max_iou_drop}")
        if self.min_frames < 1:
            raise ValueError(f"min_frames: expected >= 1, got {self.min_frames}")
        if not self.tolerance > 0:
            raise ValueError(f"tolerance: expected > 0, got {self.tolerance}")
        if self.descents < 1:
            raise ValueError(f"descents: expected >= 1, got {self.descents}")
        if not self.jitter >= 0:
            raise ValueError(f"jitter: expected >= 0, got {self.jitter}")
        # RefineConfig checks image_scale (in (0, 1]) and thin_px (>= 0) as it checks
        # the refinement's own.
        self.refinement()
        if self.max_points < 10:
            raise ValueError(f"max_points: expected >= 10, got {self.max_points}")

    def refinement(self, refinement: RefineConfig | None = None) -> RefineConfig:
        """The contour cost's settings in this stage: ``refinement`` (the run's
        per-frame refinement) at this stage's ``image_scale``, ``max_points`` and
        ``thin_px``."""
        return replace(
            refinement or RefineConfig(),
            image_scale=self.image_scale,
            max_points=self.max_points,
            thin_px=self.thin_px,
        )


@dataclass(frozen=True)
class SessionFrame:
    """One accepted frame, as the session stage sees it.

    Attributes
    ----------
    frame : int
    start : (40 + n_shape,) float
        Its generative ``[τ, θ, ν]``.
    masks : list of (H_c, W_c) bool
        Observed silhouettes at the working cameras' sizes; the views the
        frame's fit left out are all-False.
    iou : float
        The generative fit's mean silhouette IoU (its record's).
    unknown : list of ((H_c, W_c) bool or None)
        Per view, the person's pixels someone nearer covers (neither person nor
        background; :attr:`FrameArrays.unknown`); empty: none.
    clothing : list of ((H_c, W_c) bool or None)
        Per view, the silhouette's pixels capture found not to be skin
        (:attr:`FrameArrays.clothing`), for the outline check; empty: not told.
    """

    frame: int
    start: np.ndarray
    masks: list[np.ndarray]
    iou: float
    unknown: list[np.ndarray | None] = field(default_factory=list)
    clothing: list[np.ndarray | None] = field(default_factory=list)


def session_frame(record: FrameRecord, arrays: FrameArrays, cameras: CameraGroup) -> SessionFrame:
    """A fitted frame's :class:`SessionFrame` from its record and arrays.

    The views its fit used are the usable ones of its record
    (:func:`~bodymetry.estimation.view_selection.usable_views`: enough person
    pixels, not flagged ``unreadable`` or ``unreliable``); the others are
    all-False, so the stage and its outline check leave them out too.

    Raises
    ------
    ValueError
        When the record has no generative estimate or the arrays lack a camera.
    """
    est = record.estimate("generative")
    if est is None:
        raise ValueError(f"frame {record.frame}: no generative estimate")
    missing = [n for n in cameras.names if n not in arrays.observed]
    if missing:
        raise ValueError(f"frame {record.frame}: no observed silhouette of {missing[0]!r}")
    masks = blank_unusable(
        [np.asarray(arrays.observed[n], bool) for n in cameras.names],
        usable_views(cameras.names, record.person_pixels, record.flags),
    )
    unknown = arrays.unknown_of(cameras.names) if arrays.unknown else []
    clothing = arrays.clothing_of(cameras.names) if arrays.clothing else []
    return SessionFrame(record.frame, est.vector(), masks, record.mean_iou, unknown, clothing)


def silhouette_iou(
    body: BodyModel,
    state: BodyState,
    cameras: CameraGroup,
    masks: Sequence[np.ndarray],
    unknown: Sequence[np.ndarray | None] | None = None,
) -> dict[str, float]:
    """IoU of a state's level-of-detail silhouette with the observed one, per used view.

    As the quality gate measures it (:func:`bodymetry.estimation.fit.fit_frame`);
    all-False views are left out, ``unknown`` pixels (per view, or None) too.
    """
    model = project_silhouettes(
        body.pose(state, lod=True).vertices[0], body.faces(lod=True), cameras
    )
    return view_ious(cameras, model, masks, [m.any() for m in masks], unknown)


@dataclass(frozen=True)
class SessionShapeFit:
    """The session stage's outcome.

    Attributes
    ----------
    summary : SessionShape
        The results.json block (status, ν, biometrics and standard errors).
    estimates : dict of int to StageEstimate
        Per frame: the shared ν with the frame's refined pose, the biometrics
        and the silhouette IoU (empty unless the result was accepted).
    alignments : dict of int to Alignment
        Per frame: its contour cost (the prepared outline) and the
        correspondences at its last state, for the outline check (empty when
        the stage stopped before aligning).
    """

    summary: SessionShape
    estimates: dict[int, StageEstimate] = field(default_factory=dict)
    alignments: dict[int, Alignment] = field(default_factory=dict)


@dataclass
class _Frame:
    """Mutable working state of one frame during the joint iteration."""

    cost_fn: ContourCost
    y: np.ndarray
    f: float
    pairs: list


def _frame_weights(costs: np.ndarray, scale: float) -> np.ndarray:
    """Huber weights on the frames' costs (1 up to ``scale`` × median)."""
    med = float(np.median(costs))
    if not med > 0:
        return np.ones_like(costs)
    return np.minimum(1.0, scale * med / np.maximum(costs, 1e-300))


#: One frame's Gauss-Newton blocks: ``A = J_pᵀJ_p`` (40, 40), ``B = J_pᵀJ_ν`` (40, n),
#: ``C = J_νᵀJ_ν`` (n, n), ``g_pose = J_pᵀr`` (40,), ``g_shape = J_νᵀr`` (n,), ``Σr²``
#: and the number of residuals.
_Blocks = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, int]


def _blocks(frames: Sequence[_Frame], step: np.ndarray) -> list[_Blocks]:
    """Per frame the Gauss-Newton blocks (:data:`_Blocks`) at its state."""
    out = []
    for fr in frames:
        r, J = fr.cost_fn.linearize(fr.y, fr.pairs, step)
        Jp, Jn = J[:, :POSE_DIM], J[:, POSE_DIM:]
        out.append((Jp.T @ Jp, Jp.T @ Jn, Jn.T @ Jn, Jp.T @ r, Jn.T @ r, float(r @ r), len(r)))
    return out


def _joint_step(
    work: list[_Frame],
    blocks: list[tuple],
    weights: np.ndarray,
    nu: np.ndarray,
    prior: float,
    bounds: tuple[np.ndarray, np.ndarray],
    total: Callable[[np.ndarray, np.ndarray], float],
    lam: float,
) -> tuple[float, tuple[list[np.ndarray], list[tuple]]]:
    """The stage's joint step damped by ``lam`` (the shape's Schur complement over
    every frame's pose block): its total cost, each frame's state and evaluation."""
    n_shape = len(nu)
    C_sum = sum(w * b[2] for w, b in zip(weights, blocks, strict=True))
    g_sum = sum(w * b[4] for w, b in zip(weights, blocks, strict=True))
    S = marquardt(C_sum + prior * np.eye(n_shape), lam)
    g = g_sum + prior * nu
    inverses = []
    for w, (A, B, _, gp, _, _, _) in zip(weights, blocks, strict=True):
        Ainv = damped_inverse(w * A, lam)
        inverses.append(Ainv)
        S = S - (w * B).T @ Ainv @ (w * B)
        g = g - (w * B).T @ Ainv @ (w * gp)
    dnu = -np.linalg.solve(S, g)
    candidates = []
    for w, Ainv, (_, B, _, gp, _, _, _), fr in zip(weights, inverses, blocks, work, strict=True):
        dp = -Ainv @ (w * gp + (w * B) @ dnu)
        candidates.append(np.clip(np.r_[fr.y[:POSE_DIM] + dp, nu + dnu], *bounds))
    evaluated = [fr.cost_fn.evaluate(y) for fr, y in zip(work, candidates, strict=True)]
    fs = np.array([e[0] for e in evaluated])
    f_new = total(fs, candidates[0][NU]) if np.all(np.isfinite(fs)) else np.inf
    return f_new, (candidates, evaluated)


@dataclass(frozen=True)
class _Descent:
    """One joint descent's end point: every frame's state (F, 40 + n_shape) (one
    shared ν), its weighted session cost and the steps it took."""

    states: np.ndarray
    cost: float
    steps: int


def _session_cost(weights: np.ndarray, fs: np.ndarray, nu: np.ndarray, prior: float) -> float:
    """The session's cost: the frames' contour costs ``fs`` (F,) under their robust
    weights (F,), plus the shape prior on the shared ν, once."""
    return float(weights @ fs + prior * nu @ nu)


def _descend(
    work: list[_Frame],
    prior: float,
    bounds: tuple[np.ndarray, np.ndarray],
    config: SessionShapeConfig,
    step: np.ndarray,
    tick: Callable[[], None],
) -> _Descent:
    """One joint Levenberg-Marquardt descent from ``work`` (:func:`_evaluated` at
    states whose ν rows are equal, every cost finite); updates it in place."""
    fs = np.array([w.f for w in work])
    nu = work[0].y[NU]
    weights = _frame_weights(fs, config.frame_scale)

    def total(fs: np.ndarray, shape: np.ndarray) -> float:
        return _session_cost(weights, fs, shape, prior)

    f_total = total(fs, nu)
    damping, accepted = Damping(), 0
    for it in range(config.iterations):
        tick()
        blocks = _blocks(work, step)
        propose = functools.partial(_joint_step, work, blocks, weights, nu, prior, bounds, total)
        # Each retry costs one evaluation of every frame: a step that fails at
        # λ × 4⁴ means the descent has converged (or stalled) here.
        step_taken, f_total, improved = damped_step(
            propose, f_total, damping, config.tolerance, retries=_RETRIES
        )
        if step_taken is not None:
            candidates, evaluated = step_taken
            for fr, y, (f, pairs) in zip(work, candidates, evaluated, strict=True):
                fr.y, fr.f, fr.pairs = y, f, pairs
            nu = candidates[0][NU]
            accepted += 1
        if not improved:
            break
        log.debug("session shape: step %d, cost %.4g (λ %.2g)", it + 1, f_total, damping.lam)
        # Re-weight the frames at the new state (the next step compares costs under these).
        weights = _frame_weights(np.array([w.f for w in work]), config.frame_scale)
        f_total = total(np.array([w.f for w in work]), nu)
    return _Descent(np.array([w.y for w in work]), f_total, accepted)


def _evaluated(costs: Sequence[ContourCost], states: np.ndarray) -> tuple[list[_Frame], np.ndarray]:
    """Every frame's working state at ``states`` (F, 40 + n_shape), and its costs (F,)."""
    work = []
    for cost_fn, y in zip(costs, states, strict=True):
        f, pairs = cost_fn.evaluate(y)
        work.append(_Frame(cost_fn, y, f, pairs))
    return work, np.array([w.f for w in work])


def _jittered(
    states: np.ndarray, scale: float, rng: np.random.Generator, bounds: tuple[np.ndarray, ...]
) -> np.ndarray:
    """``states`` (F, 40 + n_shape) with every pose value and the shared ν moved by
    Gaussian noise of ``scale``, within the bounds."""
    out = states.copy()
    out[:, :POSE_DIM] += rng.normal(0.0, scale, out[:, :POSE_DIM].shape)
    out[:, NU] += rng.normal(0.0, scale, out.shape[1] - POSE_DIM)
    return np.clip(out, *bounds)


def fit_session_shape(
    body: BodyModel,
    cameras: CameraGroup,
    frames: Sequence[SessionFrame],
    refinement: RefineConfig | None = None,
    config: SessionShapeConfig | None = None,
    density: float = DEFAULT_DENSITY,
    progress: Progress | None = None,
) -> SessionShapeFit:
    """Refine one shape and every frame's pose jointly (see the module docstring).

    Parameters
    ----------
    body : BodyModel
    cameras : CameraGroup
        The working cameras the frames were fitted with.
    frames : sequence of SessionFrame
        The session's accepted frames.
    refinement : RefineConfig, optional
        The contour cost's settings (the run's per-frame refinement), at the
        stage's own resolution (:meth:`SessionShapeConfig.refinement`).
    config : SessionShapeConfig, optional
    density : float
        kg/m³ for weight.
    progress : callable, optional
        ``progress("session shape", step, steps)``.

    Returns
    -------
    SessionShapeFit
        Never raises for bad data: the summary's status says what went wrong.
    """
    t0, cpu0 = time.perf_counter(), time.process_time()
    config = config or SessionShapeConfig()
    refinement = config.refinement(refinement)
    used = tuple(int(f.frame) for f in frames)
    give_up = functools.partial(_give_up, used, t0)
    if len(frames) < config.min_frames:
        return give_up(f"skipped: {len(frames)} accepted frames, need {config.min_frames}")
    n_shape = body.n_shape
    starts = np.stack([np.asarray(f.start, float) for f in frames])
    if starts.shape[1] != POSE_DIM + n_shape:
        raise ValueError(
            f"start states: expected {POSE_DIM + n_shape} values, got {starts.shape[1]}"
        )
    start_nu = np.median(starts[:, NU], axis=0)
    bounds = state_bounds(body)
    costs = _frame_costs(body, cameras, frames, refinement)
    first = np.clip(np.c_[starts[:, :POSE_DIM], np.tile(start_nu, (len(frames), 1))], *bounds)
    start, f_start = _evaluated(costs, first)
    if not np.all(np.isfinite(f_start)):
        bad = [fr.frame for fr, c in zip(frames, f_start, strict=True) if not np.isfinite(c)]
        return give_up(f"failed: no contour in frames {bad}")
    stage = _Stage(
        body=body,
        cameras=cameras,
        frames=frames,
        costs=costs,
        config=config,
        density=density,
        prior=refinement.shape_prior,
        bounds=bounds,
        step=difference_steps(refinement, n_shape),
        used=used,
        t0=t0,
        cpu0=cpu0,
    )
    f0 = _session_cost(_frame_weights(f_start, config.frame_scale), f_start, start_nu, stage.prior)
    descents = _descents(stage, start, first, progress)
    return _at_average(stage, descents, start_nu, f0)


@dataclass(frozen=True)
class _Stage:
    """What :func:`fit_session_shape`'s steps share: its inputs, each frame's
    contour cost, the session's shape prior weight, the state bounds, the
    finite-difference steps, the frames used and the start times."""

    body: BodyModel
    cameras: CameraGroup
    frames: Sequence[SessionFrame]
    costs: list[ContourCost]
    config: SessionShapeConfig
    density: float
    prior: float
    bounds: tuple[np.ndarray, np.ndarray]
    step: np.ndarray
    used: tuple[int, ...]
    t0: float
    cpu0: float


def _at_average(
    stage: _Stage, descents: list[_Descent], start_nu: np.ndarray, f0: float
) -> SessionShapeFit:
    """The stage's result at the average of the descents' end points: the shared
    shape with its standard errors and measurements, each frame's pose, and the
    check that the shape does not lower the frames' silhouette IoU."""
    body, frames, config = stage.body, stage.frames, stage.config
    give_up = functools.partial(_give_up, stage.used, stage.t0)
    states = _averaged(descents, stage.bounds)
    nu = states[0, NU]
    work, fs = _evaluated(stage.costs, states)
    if not np.all(np.isfinite(fs)):
        bad = [fr.frame for fr, c in zip(frames, fs, strict=True) if not np.isfinite(c)]
        return give_up(f"failed: no contour in frames {bad} at the averaged shape")
    weights = _frame_weights(fs, config.frame_scale)
    f_total = _session_cost(weights, fs, nu, stage.prior)
    cov, how, data_h = _shape_covariance(
        work, stage.step, weights, stage.prior, body.n_shape, descents
    )
    ends = np.array([d.states[0, NU] for d in descents])
    nu_se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    bios, bio_se = biometric_errors(body, nu, cov, stage.density)
    spread = _spread(body, ends, stage.density)
    poses = {fr.frame: BodyState.from_vector(w.y[None]) for fr, w in zip(frames, work, strict=True)}
    # The height as a stadiometer reads it: from the floor, where the fit sank the
    # soles into it (estimation.standing_height).
    # Posed once at full resolution: the soles' depth and the volumes read the same bodies.
    posed = body.pose_states(np.stack([w.y for w in work]))
    depth, depth_se = sole_depth(lowest_points(posed))
    floor_applied = config.floor_height and reads_from_floor(depth)
    if floor_applied:
        bios, bio_se = from_the_floor(bios, bio_se, depth, depth_se)
        log.info("session shape: soles %.1f mm in the floor; height read from it", -1e3 * depth)
    elif config.floor_height and depth < 0:
        log.warning(
            "session shape: soles %.1f mm below the floor (z = 0), deeper than %.0f mm: the "
            "height is the fitted body's own, not read from the floor",
            -1e3 * depth,
            1e3 * MAX_SOLE_DEPTH,
        )
    # The weight as the posed bodies hold it: the model's posing changes the volume,
    # a body's does not (estimation.posed_weight).
    canonical_weight = bios["weight_kg"]
    if config.posed_weight:
        bios, bio_se = weight_from_posed(bios, bio_se, posed_volumes(posed), stage.density)
        log.info(
            "session shape: weight %.2f kg from the posed bodies (canonical body %.2f kg)",
            bios["weight_kg"],
            canonical_weight,
        )
    ious = {
        fr.frame: silhouette_iou(body, poses[fr.frame], stage.cameras, fr.masks, fr.unknown)
        for fr in frames
    }
    mean_iou = float(np.mean([np.mean(list(v.values())) for v in ious.values()]))
    reference = float(np.nanmean([fr.iou for fr in frames]))
    kw = dict(
        nu=tuple(nu.tolist()),
        nu_se=tuple(nu_se.tolist()),
        start_nu=tuple(start_nu.tolist()),
        biometrics=bios,
        standard_errors=bio_se,
        frame_weights={fr.frame: float(w) for fr, w in zip(frames, weights, strict=True)},
        mean_iou=mean_iou,
        reference_iou=reference,
        initial_cost=f0,
        cost=f_total,
        iterations=sum(d.steps for d in descents),
        covariance=how,
        descents=len(descents),
        descent_spread=spread,
        prior_pull=prior_pull(body, nu, data_h, stage.prior, stage.density),
        floor_mm=depth * 1000.0,
        floor_height=config.floor_height,
        floor_applied=floor_applied,
        canonical_weight_kg=canonical_weight,
        posed_weight=config.posed_weight,
    )
    alignments = {
        fr.frame: Alignment(w.cost_fn, w.y.copy(), w.pairs)
        for fr, w in zip(frames, work, strict=True)
    }
    if mean_iou < reference - config.max_iou_drop:
        return give_up(
            f"rejected: the shared shape lowers the frames' mean silhouette IoU from "
            f"{reference:.3f} to {mean_iou:.3f} (more than {config.max_iou_drop})",
            alignments,
            **kw,
        )
    summary = SessionShape(
        status="ok", method=METHOD, frames=stage.used, seconds=time.perf_counter() - stage.t0, **kw
    )
    estimates = {f: StageEstimate(poses[f], dict(bios), silhouette_iou=ious[f]) for f in poses}
    log.info(
        "session shape: %d frames, %d descents, %d steps, mean IoU %.4f (per-frame fits "
        "%.4f), %.1f s (%.1f s CPU)",
        len(frames),
        len(descents),
        summary.iterations,
        mean_iou,
        reference,
        summary.seconds,
        time.process_time() - stage.cpu0,
    )
    return SessionShapeFit(summary, estimates, alignments)


def _give_up(
    used: tuple[int, ...], t0: float, status: str, alignments: dict | None = None, **kw
) -> SessionShapeFit:
    """The stage's result when it stops early (``status`` says why), timed from ``t0``."""
    log.info("session shape: %s", status)
    return SessionShapeFit(
        SessionShape(
            status=status,
            method=METHOD,
            frames=used,
            seconds=time.perf_counter() - t0,
            **kw,
        ),
        alignments=alignments or {},
    )


def _frame_costs(
    body: BodyModel,
    cameras: CameraGroup,
    frames: Sequence[SessionFrame],
    refinement: RefineConfig,
) -> list[ContourCost]:
    """Each frame's contour cost, data term only (the shape prior enters once for
    the session)."""
    data_config = replace(refinement, shape_prior=0.0)
    return [
        ContourCost(
            body,
            prepare_contours(
                cameras, fr.masks, refinement.image_scale, refinement.max_points, fr.unknown
            ),
            data_config,
        )
        for fr in frames
    ]


def _descents(
    stage: _Stage, start: list[_Frame], first: np.ndarray, progress: Progress | None
) -> list[_Descent]:
    """``config.descents`` joint descents: the first from ``start`` (the frames
    evaluated at ``first`` (F, 40 + n_shape)), the others from jittered copies of
    ``first``; a start where some frame has no contour is skipped.

    The contour cost is piecewise (which edges are on the contour, and their
    nearest outline points, change in jumps), so a descent's end point moves
    with the last digits of its start. Several descents from jittered starts,
    averaged, make the result less a matter of chance, and their spread is
    part of the standard error (docs/session-shape.md).
    """
    config, costs, bounds = stage.config, stage.costs, stage.bounds
    steps_total = config.descents * config.iterations
    ticks = iter(range(steps_total))

    def tick() -> None:
        if progress:
            progress("session shape", next(ticks, steps_total), steps_total)

    rng = np.random.default_rng(config.seed)
    descents = []
    for k in range(config.descents):
        # The first descent starts where the start was just evaluated.
        work = (
            start if k == 0 else _evaluated(costs, _jittered(first, config.jitter, rng, bounds))[0]
        )
        if not all(np.isfinite(w.f) for w in work):
            log.info("session shape: descent %d started where a frame has no contour", k)
            continue
        descents.append(_descend(work, stage.prior, bounds, config, stage.step, tick))
    if progress:
        progress("session shape", steps_total, steps_total)
    return descents


def _averaged(descents: Sequence[_Descent], bounds: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The average of the descents' end points, frame by frame (F, 40 + n_shape):
    one shared ν (the ν rows stay equal), the heading as a circular mean."""
    ends_f = np.stack([d.states for d in descents], axis=1)  # (F, K, 40 + n_shape)
    even = np.full(len(descents), 1.0 / len(descents))
    return np.clip(np.array([weighted_estimate(Y, even) for Y in ends_f]), *bounds)


def _shape_covariance(
    work: list[_Frame],
    step: np.ndarray,
    weights: np.ndarray,
    prior: float,
    n_shape: int,
    descents: Sequence[_Descent],
) -> tuple[np.ndarray, str, np.ndarray]:
    """The shared shape's covariance (n_shape, n_shape) at ``work`` and how it was
    found: the curvature's, plus the scatter of the average of K descents' end
    points (their spread / sqrt(K)) when there are several; and the data term's
    pose-marginal curvature (n_shape, n_shape) there, for :func:`prior_pull`."""
    cov, how, data_h = _covariance(_blocks(work, step), weights, prior, n_shape)
    ends = np.array([d.states[0, NU] for d in descents])
    if len(descents) > 1:
        cov = cov + np.atleast_2d(np.cov(ends.T, ddof=1)) / len(descents)
        how = f"{how} + spread of {len(descents)} descents"
    return cov, how, data_h


def _spread(body: BodyModel, ends: np.ndarray, density: float) -> dict[str, float]:
    """Per measurement, the standard deviation over the shapes ``ends`` (K, n_shape)
    (0 for one)."""
    measured = [b.to_dict() for b in measure(body, ends, density=density)]
    if len(measured) < 2:
        return {k: 0.0 for k in measured[0]}
    return {k: float(np.std([m[k] for m in measured], ddof=1)) for k in measured[0]}


def _data_curvature(
    blocks: Sequence[_Blocks], weights: np.ndarray, n_shape: int
) -> tuple[np.ndarray, list[np.ndarray], float, int]:
    """The data term's pose-marginal Gauss-Newton matrix ``Σ_f w_f S_f`` (n_shape,
    n_shape) with ``S_f = C_f - B_fᵀ A_f⁻¹ B_f``, each frame's pose-marginal gradient
    ``w_f (g_ν,f - B_fᵀ A_f⁻¹ g_pose,f)`` (n_shape,), the weighted squared residual
    and the number of residuals."""
    H = np.zeros((n_shape, n_shape))
    grads = []
    sq, count = 0.0, 0
    for w, (A, B, C, gp, gn, rr, R) in zip(weights, blocks, strict=True):
        Ainv = damped_inverse(A, 0.0)
        H = H + w * (C - B.T @ Ainv @ B)
        grads.append(w * (gn - B.T @ Ainv @ gp))
        sq += w * rr
        count += R
    return H, grads, sq, count


def prior_pull(
    body: BodyModel,
    nu: np.ndarray,
    data_h: np.ndarray,
    prior: float,
    density: float = DEFAULT_DENSITY,
) -> dict[str, float]:
    """How far the shape prior moved each measurement of the shared shape.

    At the optimum ``ν`` of data + prior, the data term's gradient balances the
    prior's, ``-prior ν``; one Gauss-Newton step of the data term alone moves
    ``ν`` to ``ν + H_d⁻¹ prior ν`` (``H_d`` the data's pose-marginal curvature,
    pseudo-inverted: a direction the frames do not constrain at all is left where
    the prior put it, since no data would move it). The pull is the measurement
    at ``ν`` minus the one there (+: the prior raised it).

    Parameters
    ----------
    body : BodyModel
    nu : (n_shape,) float
        The shared shape (with the prior).
    data_h : (n_shape, n_shape) float
        The data term's pose-marginal Gauss-Newton matrix at ``nu``.
    prior : float
        The shape prior's weight (cost ``prior * ν·ν``).
    density : float

    Returns
    -------
    dict of str to float
        Per measurement of :func:`~bodymetry.estimation.body_model.biometrics.measure`.
    """
    nu = np.asarray(nu, float)
    data_only = nu + np.linalg.pinv(data_h, rcond=1e-8, hermitian=True) @ (prior * nu)
    with_prior, without = (
        b.to_dict() for b in measure(body, np.vstack([nu, data_only]), density=density)
    )
    return {k: float(with_prior[k] - without[k]) for k in with_prior}


def _covariance(
    blocks: Sequence[_Blocks], weights: np.ndarray, prior: float, n_shape: int
) -> tuple[np.ndarray, str, np.ndarray]:
    """Covariance (n_shape, n_shape) of ν with the poses marginalized, which one, and
    the data term's pose-marginal curvature ``Σ_f w_f S_f`` (n_shape, n_shape).

    The pose-marginal Gauss-Newton matrix is ``H = Σ_f w_f S_f + prior I`` with
    ``S_f = C_f - B_fᵀ A_f⁻¹ B_f``; each frame's pose-marginal gradient is
    ``g_f = w_f (g_ν,f - B_fᵀ A_f⁻¹ g_pose,f)``.
    """
    data_h, grads, sq, count = _data_curvature(blocks, weights, n_shape)
    Hinv = np.linalg.pinv(data_h + prior * np.eye(n_shape))
    n = len(grads)
    if n >= 3:
        G = np.array(grads)
        G = G - G.mean(axis=0)
        meat = n / (n - 1) * G.T @ G
        return Hinv @ meat @ Hinv, "cluster-robust (frames)", data_h
    dof = max(count - (POSE_DIM * n + n_shape), 1)
    return sq / dof * Hinv, "Gauss-Newton (residual variance)", data_h


def biometric_errors(
    body: BodyModel, nu: np.ndarray, cov: np.ndarray, density: float = DEFAULT_DENSITY
) -> tuple[dict[str, float], dict[str, float]]:
    """Biometrics of ν and their standard errors under a covariance of ν (delta method).

    Parameters
    ----------
    body : BodyModel
    nu : (n_shape,) float
    cov : (n_shape, n_shape) float
    density : float

    Returns
    -------
    biometrics, standard_errors : dict of str to float
        ``sqrt(diag(J cov Jᵀ))`` with ``J`` the forward-difference Jacobian of
        the biometrics with respect to ν (steps of ``_BIO_STEP``: the shape
        space is in standard deviations; one batch of ``1 + n_shape`` bodies).
    """
    nu = np.asarray(nu, float)
    n = len(nu)
    h = _BIO_STEP
    batch = np.vstack([nu, nu + h * np.eye(n)])
    measured = [b.to_dict() for b in measure(body, batch, density=density)]
    keys = list(measured[0])
    values = np.array([[m[k] for k in keys] for m in measured])  # (1 + n, M)
    J = (values[1:] - values[0]).T / h  # (M, n)
    var = np.einsum("mi,ij,mj->m", J, cov, J)
    se = np.sqrt(np.clip(var, 0.0, None))
    return dict(zip(keys, values[0].tolist(), strict=True)), dict(
        zip(keys, se.tolist(), strict=True)
    )
