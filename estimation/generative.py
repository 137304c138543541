"""Generative refinement: annealed importance sampling over Y = (τ, θ, ν) (paper §5).

The posterior p(Y | I) ∝ p(I | Y) p(Y) is represented by N weighted particles.
Layer k draws from q_k(Y) = Σ_i π_i N(y_i, Σ_k), a kernel density of the
previous layer's particles whose bandwidth Σ_k is the particles' own spread
times a factor that shrinks every layer, and weighs them by the likelihood
raised to a temperature β_k (annealing, Deutscher et al. 2000). β_k is chosen
adaptively: the largest value whose weights keep an effective sample size of
``target_ess`` × N (Deutscher's "survival rate"), so early layers explore and
late layers exploit. Joint limits bound θ; particles are clipped to them.

The likelihood compares, in every view, the observed silhouette O with the
projection S of the hypothesized body (the ~3,000-triangle level of detail):
pixels of S outside O are penalized by their distance to O, pixels of O
outside S by their distance to S (a bidirectional chamfer measure; the
observed side's distance map is computed once per frame), normalized by O's
area:  cost_c = (Σ_{S\\O} d_O + Σ_{O\\S} d_S) / |O|,  log p(I | Y) = -Σ_c cost_c / σ².
Images are compared at a reduced scale (``image_scale``); distances are in
full-resolution pixels. Each view is compared at its own camera's size, so a
rig may mix camera models (per-view arrays, not one stacked array).

Pixels a view marks **unknown** U (a person's pixels that someone nearer to the
camera covers) are neither person nor background: the model-outside term
measures distances to O ∪ U, so a model part hidden behind the occluder costs
nothing, while the observed-to-model term and the normalization stay on O:
cost_c = (Σ_{S\\(O∪U)} d_{O∪U} + Σ_{O\\S} d_S) / |O|. Without unknown pixels
this is the cost above, exactly.

The estimate is the weighted mean of the last layer (heading averaged on the
circle): with a narrow final kernel the particles share one mode, and the mean
is less noisy than the single best particle (which overfits silhouette noise).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from types import ModuleType

import cv2
import numpy as np

from bodymetry.calibration.camera import CameraGroup
from bodymetry.estimation.backends import default_backend, module_kernels
from bodymetry.estimation.body_model.model import THETA, BodyModel, BodyState
from bodymetry.estimation.body_model.skeleton import N_POSE, YAW
from bodymetry.estimation.projection import camera_arrays
from bodymetry.estimation.raster import INSIDE_EPS, coverage_views

_BACKENDS = ("numba", "numpy")

#: The implementation of :func:`chamfer_costs`: ``"numba"`` (fused kernels of
#: ``likelihood_kernels.py``: projection, coverage, distance transform and sums
#: for a whole batch in two calls) or ``"numpy"`` (the reference: camera by
#: camera, body by body). From ``$BODYMETRY_LIKELIHOOD``; by default numba when
#: installed. Read at every call, so tests and benchmarks may set it.
BACKEND: str = default_backend(
    "BODYMETRY_LIKELIHOOD", os.environ.get("BODYMETRY_LIKELIHOOD"), _BACKENDS, "numba"
)


def compiled_likelihood() -> ModuleType | None:
    """The compiled likelihood kernels (also used by the contour refinement), or None
    for the numpy path (see ``raster._kernels``)."""
    return module_kernels(
        globals(),
        "BACKEND",
        "bodymetry.estimation.likelihood_kernels",
        "BODYMETRY_LIKELIHOOD",
        "likelihood",
    )


@dataclass(frozen=True)
class AnnealingConfig:
    """Settings of the annealed particle filter.

    Attributes
    ----------
    n_particles : int
    n_layers : int
    image_scale : float
        Silhouettes are compared at this fraction of the camera resolution.
    target_ess : float
        Effective sample size fraction kept by each layer's temperature.
    bandwidth : float
        Kernel bandwidth as a fraction of the particles' standard deviation,
        first layer; multiplied by ``shrink`` each layer.
    shrink : float
    sigma_px : float
        Chamfer cost scale (pixels): log p(I|Y) = -Σ_c cost_c / sigma_px².
    min_std : (3,) float
        Floors of the kernel's standard deviation for τ (m), θ (rad), ν.
    """

    # Measured on the demo: with the contour refinement after it (see
    # estimation/refinement.py) 80 particles x 10 layers find the same modes
    # as 120 x 14 in half the time.
    n_particles: int = 80
    n_layers: int = 10
    image_scale: float = 0.25
    target_ess: float = 0.3
    bandwidth: float = 0.6
    shrink: float = 0.85
    sigma_px: float = 1.0
    min_std: tuple[float, float, float] = (0.005, 0.01, 0.02)

    def __post_init__(self) -> None:
        for name in ("n_particles", "n_layers"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected >= 1, got {getattr(self, name)}")
        if not 0 < self.image_scale <= 1:
            raise ValueError(f"image_scale: expected in (0, 1], got {self.image_scale}")
        if not 0 < self.target_ess < 1:
            raise ValueError(f"target_ess: expected in (0, 1), got {self.target_ess}")
        for name in ("bandwidth", "shrink", "sigma_px"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name}: expected > 0, got {getattr(self, name)}")
        if len(self.min_std) != 3 or min(self.min_std) < 0:
            raise ValueError(f"min_std: expected 3 values >= 0, got {self.min_std}")


@dataclass
class Observation:
    """One frame's observed silhouettes, prepared for the likelihood.

    Attributes
    ----------
    cameras : CameraGroup
        The rig scaled to the comparison resolution.
    masks : list of (h_c, w_c) bool
        Per view, at that view's comparison size (views may differ in size).
    dist_outside : list of (h_c, w_c) float32
        Distance (full-resolution pixels) from each pixel to the observed silhouette.
    area : (C,) float
    scale : float
    valid : (C,) bool
        Views with an observed silhouette.
    boxes : (C, 4) int
        Bounding box ``x0, y0, x1, y1`` (exclusive ends) of each observed
        silhouette at the comparison scale.
    """

    cameras: CameraGroup
    masks: list[np.ndarray]
    dist_outside: list[np.ndarray]
    area: np.ndarray
    scale: float = 1.0
    valid: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), int))
    _packed: dict | None = field(default=None, repr=False, compare=False)

    def packed(self) -> dict:
        """The usable views' arrays as the compiled kernels take them (built on first
        use and kept: an observation is not changed after it is prepared).

        Returns
        -------
        dict
            ``views`` (C',) int, ``cameras`` (:func:`camera_arrays` of those
            views), ``sizes`` (C', 2) int64, ``observed`` (C', H, W) bool and
            ``dist`` (C', H, W) float32 padded to the largest view, ``boxes``
            (C', 4) int64, ``area`` (C',) float64.
        """
        if self._packed is None:
            views = np.flatnonzero(self.valid)
            # The usable views as a sub-rig (a group is never empty: none is no cameras).
            usable = self.cameras.select(views) if len(views) else ()
            sizes = np.array([cam.size for cam in usable], np.int64).reshape(-1, 2)
            w, h = (int(v) for v in sizes.max(axis=0)) if len(views) else (1, 1)
            observed = np.zeros((len(views), h, w), bool)
            dist = np.zeros((len(views), h, w), np.float32)
            for k, c in enumerate(views):
                mh, mw = self.masks[c].shape
                observed[k, :mh, :mw] = self.masks[c]
                dist[k, :mh, :mw] = self.dist_outside[c]
            self._packed = {
                "views": views,
                "cameras": camera_arrays(usable),
                "sizes": sizes,
                "observed": observed,
                "dist": dist,
                "boxes": np.ascontiguousarray(self.boxes[views], dtype=np.int64).reshape(-1, 4),
                "area": np.ascontiguousarray(self.area[views], dtype=np.float64),
            }
        return self._packed


def prepare_observation(
    cameras: CameraGroup,
    masks: Sequence[np.ndarray] | np.ndarray,
    scale: float,
    unknown: Sequence[np.ndarray | None] | None = None,
) -> Observation:
    """Downscale the observed silhouettes and precompute their distance maps.

    Parameters
    ----------
    cameras : CameraGroup
    masks : sequence of C (H_c, W_c) bool, or (C, H, W) bool
        Observed silhouettes, each at its camera's resolution (sizes may differ
        between cameras); an all-False mask marks a view without a usable
        silhouette (it is left out of the likelihood).
    scale : float
    unknown : sequence of C ((H_c, W_c) bool or None), optional
        Per view, pixels that are neither the person's nor background (someone
        nearer covers them): the model may cover them at no cost (the
        distance map is that of ``masks | unknown``). None or empty: none.

    Raises
    ------
    ValueError
        If the masks (or unknown masks) do not match the cameras in number or size.
    """
    masks = cameras.check_masks(masks)
    hidden = unknown_masks(cameras, unknown)
    small_cams = cameras.scaled(scale)
    small, dist, area, valid, boxes = [], [], [], [], []
    for cam, mask, u in zip(small_cams, masks, hidden, strict=True):
        w, h = cam.size
        m = downscale_mask(mask, (w, h))
        small.append(m)
        x, y, bw, bh = cv2.boundingRect(m.astype(np.uint8))
        boxes.append((x, y, x + bw, y + bh))
        if m.any():
            # The model may cover unknown pixels for free: distances to O ∪ U.
            near = m if u is None else m | downscale_mask(u, (w, h))
            d = cv2.distanceTransform((~near).astype(np.uint8), cv2.DIST_L2, 3) / scale
        else:
            # No silhouette: nothing to be near (OpenCV's "far" value over a small
            # scale overflows float32). The view is left out of the likelihood.
            d = np.full((h, w), np.inf, np.float32)
        dist.append(d)
        area.append(max(m.sum(), 1) / scale**2)
        valid.append(bool(m.any()))
    return Observation(
        small_cams,
        small,
        dist,
        np.asarray(area),
        scale,
        np.asarray(valid),
        np.asarray(boxes, dtype=int).reshape(-1, 4),
    )


def downscale_mask(mask: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(h, w) bool: ``mask`` (H, W) at ``size`` (w, h), a pixel set where any of the
    pixels it covers is (area interpolation, then > 0)."""
    w, h = size
    return cv2.resize(np.asarray(mask, np.uint8), (w, h), interpolation=cv2.INTER_AREA) > 0


def unknown_masks(
    cameras: CameraGroup, unknown: Sequence[np.ndarray | None] | None
) -> list[np.ndarray | None]:
    """Per camera the unknown pixels (H_c, W_c) bool, None where a view has none.

    Parameters
    ----------
    cameras : CameraGroup
        C cameras.
    unknown : sequence of C ((H_c, W_c) bool or None), or None/empty (none anywhere)

    Raises
    ------
    ValueError
        When there is not one entry per camera or a mask is not its camera's size.
    """
    if unknown is None or len(unknown) == 0:
        return [None] * len(cameras)
    if len(unknown) != len(cameras):
        raise ValueError(f"unknown masks: {len(unknown)} for {len(cameras)} cameras")
    filled = [
        np.zeros(cam.size[::-1], bool) if u is None else u
        for cam, u in zip(cameras, unknown, strict=True)
    ]
    return [u if u.any() else None for u in cameras.check_masks(filled)]


def chamfer_costs(obs: Observation, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Bidirectional chamfer cost of bodies in every view.

    Parameters
    ----------
    obs : Observation
    vertices : (V, 3) or (B, V, 3) float
        One body or a batch (projected together, camera by camera).
    faces : (T, 3) int
        A closed mesh (:func:`estimation.projection.fill_silhouette`).

    Returns
    -------
    (C,) or (B, C) float
    """
    verts = np.asarray(vertices, dtype=float)
    single = verts.ndim == 2
    verts = verts[None] if single else verts
    costs = np.zeros((len(verts), len(obs.cameras)))
    views = np.flatnonzero(obs.valid)
    if len(views) == 0:
        return costs[0] if single else costs
    kernels = compiled_likelihood()
    if kernels is not None:
        costs[:, views] = _chamfer_numba(kernels, obs, verts, faces)
        return costs[0] if single else costs
    # Views of different sizes share one pass on a padded canvas (exact, see
    # coverage_views); one size is the plain stacked pass.
    sizes = [obs.cameras.sizes[c] for c in views]
    # (B, C', V, 2): every body in every usable view, projected camera by camera.
    pixels = np.stack([obs.cameras[c].project(verts) for c in views], axis=1)
    for b in range(len(verts)):
        models = coverage_views(pixels[b], faces, sizes, closed=True)
        for k, c in enumerate(views):
            costs[b, c] = _view_cost(obs, c, models[k], pixels[b, k])
    return costs[0] if single else costs


def project_planes(
    kernels: ModuleType, verts: np.ndarray, cameras: tuple[np.ndarray, ...]
) -> np.ndarray:
    """Bodies through cameras by the compiled projection, as two coordinate planes.

    Parameters
    ----------
    kernels : module
        :func:`compiled_likelihood`'s.
    verts : (B, V, 3) float
    cameras : tuple of arrays
        :func:`~bodymetry.estimation.projection.camera_arrays` of C cameras.

    Returns
    -------
    (2, B, C, V) float
        u and v (NaN behind a camera). The kernel writes (B, C, V, 2) pixels;
        through a view of this array its u and v land in two contiguous planes,
        which the raster and chamfer kernels take without a copy.
    """
    B, V, _ = verts.shape
    planes = np.empty((2, B, len(cameras[0]), V))
    kernels.project_kernel(np.ascontiguousarray(verts), *cameras, np.moveaxis(planes, 0, -1))
    return planes


def _chamfer_numba(
    kernels: ModuleType, obs: Observation, verts: np.ndarray, faces: np.ndarray
) -> np.ndarray:
    """(B, C') costs of the usable views by the fused kernels (one call each)."""
    pack = obs.packed()
    B, V, _ = verts.shape
    planes = project_planes(kernels, verts, pack["cameras"])
    out = np.empty((B, planes.shape[2]))
    status = kernels.chamfer_kernel(
        planes[0],
        planes[1],
        np.require(faces, np.int64, ["C", "W"]),
        pack["sizes"],
        int(pack["sizes"][:, 1].max()),
        pack["observed"],
        pack["dist"],
        pack["boxes"],
        pack["area"],
        float(obs.scale),
        INSIDE_EPS,
        out,
    )
    if status != 0:
        raise IndexError(f"chamfer_costs: face indices out of range for {V} vertices")
    return out


def _view_cost(obs: Observation, c: int, model: np.ndarray, pixels: np.ndarray) -> float:
    """The chamfer cost of one model silhouette (h, w) in view ``c``; ``pixels`` (V, 2)
    are the projected vertices (for the crop of the model's distance transform)."""
    observed = obs.masks[c]
    w, h = obs.cameras[c].size
    extra = model & ~observed
    missing = observed & ~model
    cost = obs.dist_outside[c][extra].sum()
    if missing.any():
        if not model.any():
            # The body covers no pixel of this view (off the image or behind the
            # camera): no distance to it exists. OpenCV would fill the map with
            # FLT_MAX, whose sum overflows to the same infinity with a warning.
            return float("inf")
        # The distance to the model only matters inside the observed box; the box of
        # both silhouettes holds every model pixel, so the distance transform of that
        # crop is exact (and 2-4x smaller than the image).
        ox0, oy0, ox1, oy1 = obs.boxes[c]
        lo = np.nan_to_num(np.nanmin(pixels, axis=0), nan=0.0)
        hi = np.nan_to_num(np.nanmax(pixels, axis=0), nan=0.0)
        x0 = int(max(0, min(ox0, np.floor(lo[0]))))
        y0 = int(max(0, min(oy0, np.floor(lo[1]))))
        x1 = int(min(w, max(ox1, np.ceil(hi[0]) + 1)))
        y1 = int(min(h, max(oy1, np.ceil(hi[1]) + 1)))
        crop = (~model[y0:y1, x0:x1]).astype(np.uint8)
        d_model = cv2.distanceTransform(crop, cv2.DIST_L2, 3)
        cost += d_model[missing[y0:y1, x0:x1]].sum() / obs.scale
    return float(cost / obs.scale**2 / obs.area[c])


@dataclass(frozen=True)
class AnnealingResult:
    """Outcome of the annealed search for one frame.

    Attributes
    ----------
    state : BodyState
        The estimate (batch of one).
    particles : (N, 3 + 37 + n) float
        Last layer's particles ``[τ, θ, ν]``.
    weights : (N,) float
        Their normalized weights.
    layer_log_likelihood : (L,) float
        Weighted mean log-likelihood of each layer (for plots).
    layer_beta : (L,) float
        Temperatures chosen.
    best_cost : float
        Lowest summed chamfer cost seen (pixels).
    """

    state: BodyState
    particles: np.ndarray
    weights: np.ndarray
    layer_log_likelihood: np.ndarray
    layer_beta: np.ndarray
    best_cost: float


def _log_likelihoods(model: BodyModel, obs: Observation, Y: np.ndarray, sigma: float) -> np.ndarray:
    states = BodyState.from_vector(Y)
    faces = model.faces(lod=True)
    out = np.empty(len(Y))
    # Batches bound the memory of the numpy path's candidate arrays; the compiled
    # path needs little, and fewer, larger batches save the pose's per-call work
    # (forward kinematics): a layer of 80 in one call. The vertices do not depend
    # on the batching (tested).
    chunk = 64 if compiled_likelihood() is None else 256
    for s in range(0, len(Y), chunk):
        verts = model.pose(states[s : s + chunk], lod=True).vertices
        out[s : s + len(verts)] = -chamfer_costs(obs, verts, faces).sum(axis=1) / sigma**2
    return out


def _temperature(loglik: np.ndarray, target_ess: float) -> float:
    """Largest β in (0, 1] whose weights keep ESS >= target_ess × N (bisection)."""
    n = len(loglik)
    ll = loglik - loglik.max()

    def ess(beta: float) -> float:
        w = np.exp(beta * ll)
        return w.sum() ** 2 / (w**2).sum() / n

    if ess(1.0) >= target_ess:
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ess(mid) >= target_ess else (lo, mid)
    return max(lo, 1e-12)


#: Shape coefficients are kept within this many standard deviations.
NU_BOUND = 4.0


def state_bounds(model: BodyModel) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds (40 + n_shape,) of ``[τ, θ, ν]``: joint limits, ±NU_BOUND on ν."""
    n = model.n_shape
    lo = np.r_[np.full(3, -np.inf), model.limits.lower, np.full(n, -NU_BOUND)]
    hi = np.r_[np.full(3, np.inf), model.limits.upper, np.full(n, NU_BOUND)]
    return lo, hi


def weighted_estimate(Y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The weighted mean (40 + n_shape,) of states ``Y`` (N, 40 + n_shape) under
    weights ``w`` (N,) summing to 1; the heading (yaw), which wraps at ±π, as a
    circular mean."""
    est = w @ Y
    yaw = THETA.start + YAW
    est[yaw] = np.arctan2(w @ np.sin(Y[:, yaw]), w @ np.cos(Y[:, yaw]))
    return est


def anneal(
    model: BodyModel,
    obs: Observation,
    initial: np.ndarray,
    config: AnnealingConfig,
    rng: np.random.Generator,
) -> AnnealingResult:
    """Run the annealed particle filter from initial particles.

    Parameters
    ----------
    model : BodyModel
    obs : Observation
        From :func:`prepare_observation`.
    initial : (N0, 40 + n_shape) float
        Initial particles ``[τ, θ, ν]`` (e.g. drawn from the discriminative mixtures);
        all are weighed in the first layer, which resamples ``config.n_particles``.
    config : AnnealingConfig
    rng : Generator
    """
    if not obs.valid.any():
        raise ValueError("no view has an observed silhouette")
    lo, hi = state_bounds(model)
    N = config.n_particles
    # The first layer weighs every initial draw (they are cheap next to a search
    # that starts in the wrong mode); later layers carry N particles.
    Y = np.clip(np.atleast_2d(initial), lo, hi)
    floor = np.r_[
        np.full(3, config.min_std[0]),
        np.full(N_POSE, config.min_std[1]),
        np.full(model.n_shape, config.min_std[2]),
    ]
    layer_ll, layer_beta = [], []
    best = np.inf
    w = np.full(len(Y), 1.0 / len(Y))
    factor = config.bandwidth
    for layer in range(config.n_layers):
        if layer > 0:
            # Resample by weight, then perturb with the shrinking kernel.
            idx = rng.choice(len(Y), size=N, p=w)
            spread = np.sqrt(np.maximum(np.cov(Y.T, aweights=w).diagonal(), 0.0))
            std = np.maximum(factor * spread, floor)
            Y = np.clip(Y[idx] + rng.standard_normal((N, Y.shape[1])) * std, lo, hi)
            factor *= config.shrink
        ll = _log_likelihoods(model, obs, Y, config.sigma_px)
        if not np.isfinite(ll.max()):
            raise ValueError("no particle's body is seen in the views with a silhouette")
        best = min(best, -ll.max() * config.sigma_px**2)
        beta = _temperature(ll, config.target_ess)
        w = np.exp(beta * (ll - ll.max()))
        w /= w.sum()
        # A body outside a view has log-likelihood -inf and weight 0: leave it out of
        # the layer's mean (0 x -inf is NaN); finite terms are summed as before.
        layer_ll.append(float(w @ np.where(w > 0, ll, 0.0)))
        layer_beta.append(beta)
    est = weighted_estimate(Y, w)
    return AnnealingResult(
        BodyState.from_vector(est[None]),
        Y,
        w,
        np.asarray(layer_ll),
        np.asarray(layer_beta),
        float(best),
    )
