"""Local refinement of a body fit by silhouette-contour alignment (beyond the paper).

The annealed particle filter (:mod:`estimation.generative`) finds the right
mode but, with ~100 particles in 49 dimensions, stops a few centimetres from
its optimum: the limbs are roughly placed, the shape compensates. This stage
polishes a state by damped Gauss-Newton (Levenberg-Marquardt) on a contour
alignment cost, an iterative-closest-point scheme between

* the model's **occluding contour**: midpoints of the mesh edges whose two
  faces turn one towards, one away from the camera and which project onto the
  boundary of the model silhouette (the visible outline, not the hidden folds),
* the observed silhouette's **boundary points**, at sub-pixel positions
  (the midpoints between 4-neighbour inside/outside pixel pairs).

Each view contributes the mean squared distance from every model contour point
to its nearest observed point and from every observed point to its nearest
model contour point (both directions: one alone lets the body shrink or grow),
with a Huber weight so a segmentation error cannot pull the body far. A
Gaussian prior on ν (the shape space is in standard deviations) keeps
unobserved shape directions at the population mean. Correspondences are
re-found after every accepted step.

The Jacobian is taken by forward differences of the level-of-detail mesh: one
batched pose of 1 + 49 states per iteration (~30 ms). Joint limits bound θ.
Everything is deterministic (no random choices).

The contours come from :mod:`bodymetry.estimation.contours`, the damping from
:mod:`bodymetry.estimation.least_squares`; this module holds the settings, the
cost (:class:`ContourCost`, shared with the session stage) and the descent
(:func:`refine`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, replace
from types import ModuleType

import cv2
import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from bodymetry.calibration.camera import Camera
from bodymetry.estimation.body_model.model import NU, POSE_DIM, THETA, BodyModel, BodyState
from bodymetry.estimation.body_model.skeleton import YAW
from bodymetry.estimation.contours import (
    ContourObservation,
    contour_ids,
    contour_topology,
    face_frames,
    mask_at,
    mesh_edges,
    occluding_contour,
    outline_samples,
)
from bodymetry.estimation.generative import compiled_likelihood, project_planes, state_bounds
from bodymetry.estimation.least_squares import Damping, damped_step, marquardt
from bodymetry.estimation.projection import camera_arrays, fill_silhouette
from bodymetry.estimation.raster import coverage_views

#: How far from a contour edge (camera pixels, a square window) a part of the model's
#: silhouette must reach ``RefineConfig.thin_px`` deep for the camera to resolve it.
THIN_WINDOW = 2


@dataclass(frozen=True)
class RefineConfig:
    """Settings of the contour refinement.

    Attributes
    ----------
    iterations : int
        Most Levenberg-Marquardt steps.
    image_scale : float
        Model silhouettes (visibility of contour edges) are rasterized at this
        fraction of the camera resolution; distances are in those pixels.
    max_points : int
        Observed boundary points kept per view (evenly spread along the list).
    huber_px : float
        Residuals longer than this (working pixels) get Huber weights.
    shape_prior : float
        Weight of the ν ~ N(0, I) prior against the mean squared pixel residual
        per view.
    steps : (3,) float
        Finite-difference steps for τ (m), θ (rad), ν.
    tolerance : float
        Stop when a step lowers the cost by less than this fraction.
    screen_iterations : int
        Steps given to each candidate start before the best one is refined
        further (:func:`bodymetry.estimation.fit.polish`).
    full_mesh : bool
        Measure the residuals on the full-resolution mesh (its occluding
        contour), with the Jacobian of the level of detail mapped onto it
        (:func:`full_from_lod`). The level of detail lies slightly inside the
        full surface: fitted with it, the shape grows to fill the outline
        (measured from the true demo states with the true silhouettes: +0.1 to
        +1.9 kg, against -0.1 to +1.1 kg with the full mesh). Screening the
        starts uses the level of detail either way.
    visibility_scale : float
        The silhouette that decides which contour edges are on the visible
        outline is rasterized at this fraction of the camera resolution. An
        edge counts as visible within one raster pixel of the outside, so a
        coarse raster admits the zig-zag contour edges that lie just inside
        the outline; those make the model look smaller than it is and the fit
        inflates the body to compensate.
    outline_offsets : bool
        Compare like with like: each contour edge's residual is taken less
        its own offset from the model's rendered outline (the residual mesh
        rasterized at the camera's resolution, its boundary found as the
        observed one's), held fixed within a step. A mesh's occluding contour
        zig-zags and the rendered outline is its outermost part, so its edges
        lie on average a fraction of a pixel inside the outline they draw;
        without the correction the fit grows the body to close that gap.
    thin_px : float
        Leave out the model-to-observed residuals of contour edges on parts of
        the model's own silhouette (at the camera's resolution) narrower than
        about ``2 * thin_px`` camera pixels: where no pixel of the part lies more
        than ``thin_px`` inside it within :data:`THIN_WINDOW` pixels of the edge.
        A part the camera does not resolve (a child's spread fingers) covers no
        pixel whole, capture keeps few of its pixels, and its contour has
        nothing observed to align with, as an occluded one has not; pulled
        inwards regardless, the fit shortens the hand. The observed-to-model
        residuals stay. 0 (the per-frame fits): none left out; the session
        stage sets it (``SessionShapeConfig.thin_px``). Needs
        ``outline_offsets`` (the model's own silhouettes).
    """

    iterations: int = 15
    image_scale: float = 0.5
    max_points: int = 400
    huber_px: float = 3.0
    shape_prior: float = 0.05
    steps: tuple[float, float, float] = (1e-3, 2e-3, 1e-2)
    tolerance: float = 1e-4
    screen_iterations: int = 3
    full_mesh: bool = True
    visibility_scale: float = 1.0
    outline_offsets: bool = True
    thin_px: float = 0.0

    def __post_init__(self) -> None:
        for name in ("iterations", "screen_iterations"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}: expected >= 0, got {getattr(self, name)}")
        if self.max_points < 3:
            raise ValueError(f"max_points: expected >= 3, got {self.max_points}")
        for name in ("image_scale", "visibility_scale"):
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"{name}: expected in (0, 1], got {getattr(self, name)}")
        for name in ("huber_px", "tolerance"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name}: expected > 0, got {getattr(self, name)}")
        if self.shape_prior < 0:
            raise ValueError(f"shape_prior: expected >= 0, got {self.shape_prior}")
        if len(self.steps) != 3 or min(self.steps) <= 0:
            raise ValueError(f"steps: expected 3 values > 0, got {self.steps}")
        if not self.thin_px >= 0:
            raise ValueError(f"thin_px: expected >= 0, got {self.thin_px}")


@dataclass(frozen=True)
class RefineResult:
    """Outcome of :func:`refine`.

    Attributes
    ----------
    vector : (40 + n_shape,) float
        Refined ``[τ, θ, ν]``.
    cost : float
        Final contour cost (mean squared working pixels, summed over views, plus prior).
    initial_cost : float
    iterations : int
        Accepted steps.
    """

    vector: np.ndarray
    cost: float
    initial_cost: float
    iterations: int

    @property
    def state(self) -> BodyState:
        return BodyState.from_vector(self.vector[None])


def _nearest(
    tree: cKDTree, model: np.ndarray, observed: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest observed point of each model point (n,) and nearest model point of each
    observed point (m,); ``tree`` holds ``observed``.

    With the compiled backend one pass over all pairs
    (``likelihood_kernels.nearest_pairs_kernel``), else the k-d trees; the same
    indices but for exact ties in distance (either point is then a nearest one).
    """
    kernels = compiled_likelihood()
    if kernels is None:
        _, j = tree.query(model)
        _, k = cKDTree(model).query(observed)
        return j, k
    j = np.empty(len(model), np.int64)
    k = np.empty(len(observed), np.int64)
    kernels.nearest_pairs_kernel(
        np.require(model, np.float64, ["C", "W"]),
        np.require(observed, np.float64, ["C", "W"]),
        j,
        k,
    )
    return j, k


@dataclass(frozen=True)
class _Pairs:
    """Correspondences of one view and direction: edges (n, 2) -> targets (n, 2).

    The residual of a pair is the model point's offset from its target along
    the observed outline's normal there (point-to-line): the model's contour
    is sampled at mesh edges a few pixels apart, and point-to-point distances
    would reward sampling density rather than alignment.

    ``source``, optional: this pair's edges are the previous pair's edges at
    these indices (the observed-to-model direction picks model edges of the
    model-to-observed one); :meth:`ContourCost.residuals` then takes their
    projections from that pair's instead of projecting them again.
    """

    camera: int
    edges: np.ndarray
    targets: np.ndarray
    normals: np.ndarray
    weight: float
    source: np.ndarray | None = None


@dataclass(frozen=True)
class _Silhouette:
    """A model silhouette (H, W) bool at ``camera``'s resolution, and the box
    ``low`` (x0, y0) to ``high`` (x1, y1) (exclusive) that holds its outline."""

    mask: np.ndarray
    camera: Camera
    low: np.ndarray
    high: np.ndarray

    def thin(self, thin_px: float) -> Callable[[np.ndarray, Camera], np.ndarray]:
        """Whether points lie on a part of this silhouette too thin for the camera
        (:attr:`RefineConfig.thin_px`): a function of (N, 2) points in ``working``
        pixels and that camera, giving (N,) bool (outside the image: False)."""
        (x0, y0), (x1, y1) = self.low, self.high
        thin = np.zeros(self.mask.shape, bool)
        if x1 > x0 and y1 > y0:
            box = np.ascontiguousarray(self.mask[y0:y1, x0:x1], np.uint8)
            depth = cv2.distanceTransform(box, cv2.DIST_L2, 3)
            size = 2 * THIN_WINDOW + 1
            local = cv2.dilate(depth, np.ones((size, size), np.uint8))
            thin[y0:y1, x0:x1] = local < thin_px

        def on_thin(points: np.ndarray, working: Camera) -> np.ndarray:
            scale = working.K[0, 0] / self.camera.K[0, 0]
            return mask_at(thin, (points + 0.5) / scale - 0.5)

        return on_thin

    def outline(self, working: Camera, config: RefineConfig) -> np.ndarray:
        """(M, 2) outline samples in ``working``'s pixels, traced and sampled as the
        observed outline is (:func:`prepare_contours`)."""
        (x0, y0), (x1, y1) = self.low, self.high
        if x1 <= x0 or y1 <= y0:
            return np.zeros((0, 2))
        points = outline_samples(self.mask[y0:y1, x0:x1], config.max_points)
        scale = working.K[0, 0] / self.camera.K[0, 0]  # the working scale, exactly
        return (points + (x0, y0) + 0.5) * scale - 0.5


class ContourCost:
    """The alignment cost of one frame for one body model (see the module docstring).

    With ``config.full_mesh``, residuals are measured on the full-resolution mesh and its
    Jacobian comes from the level of detail through :func:`full_from_lod`;
    otherwise everything is the level of detail.
    """

    def __init__(self, model: BodyModel, obs: ContourObservation, config: RefineConfig):
        self.model = model
        self.obs = obs
        self.config = config
        full = self.full = config.full_mesh
        self.lod_faces = model.faces(lod=True)
        self.faces = model.faces(lod=not full)
        self.edges, self.edge_faces = _edges(model, lod=not full)
        self.map = full_from_lod(model) if full else None
        self._last: tuple[bytes, np.ndarray] | None = None
        originals = obs.cameras if obs.originals is None else obs.originals
        # The views with an observed outline (fixed for the frame) at their own size:
        # where the model's own silhouettes are drawn (outline_offsets).
        self._own_views = [c for c, tree in enumerate(obs.trees) if tree is not None]
        self._own_cameras = originals.select(self._own_views) if self._own_views else None
        self._own_arrays = camera_arrays(self._own_cameras) if self._own_views else None
        self.visibility = originals.scaled(config.visibility_scale)
        self._cam_arrays = [camera_arrays([cam]) for cam in obs.cameras]
        self._vis_arrays = [camera_arrays([cam]) for cam in self.visibility]
        # The residual mesh's topology, checked once for the contour kernel.
        self._topology = (
            contour_topology(self.faces, self.edges, self.edge_faces, self._n_vertices())
            if compiled_likelihood() is not None
            else None
        )

    def _n_vertices(self) -> int:
        """Vertices of the residual mesh."""
        return (self.model.full if self.full else self.model.lod).n_vertices

    def vertices(self, Y: np.ndarray, lod: bool | None = None) -> np.ndarray:
        """(B, V, 3) vertices of states (B, 40 + n_shape): the residual mesh, or the given one."""
        lod = not self.full if lod is None else lod
        return self.model.pose(BodyState.from_vector(np.atleast_2d(Y)), lod=lod).vertices

    def perturbed(
        self, y: np.ndarray, step: np.ndarray, rows: np.ndarray | None = None
    ) -> np.ndarray:
        """Residual-mesh vertices (1 + n, V, 3) of ``y`` and of ``y`` moved by each step.

        One batched pose of the level of detail; with the full mesh, its
        displacements are mapped onto the full mesh posed at ``y``, for the
        vertices ``rows`` only (default: all; the others are left unset).
        """
        lod = self.vertices(np.vstack([y, y + np.diag(step)]), lod=True)
        if not self.full:
            return lod
        base = self._posed(y)
        rows = np.arange(len(base)) if rows is None else rows
        out = np.empty((len(lod), *base.shape))
        out[:, rows] = self._moved_rows(lod, base, rows)
        return out

    def _moved_rows(self, lod: np.ndarray, base: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """(1 + n, len(rows), 3): the full mesh's ``rows`` at ``y`` and moved by each
        level-of-detail displacement ``lod[1:] - lod[0]`` (see :meth:`perturbed`)."""
        kernels = compiled_likelihood()
        if kernels is not None:
            # One pass, the same sums (likelihood_kernels.moved_rows_kernel).
            rows64 = np.require(rows, np.int64, ["C", "W"])
            if rows64.size and (rows64.min() < 0 or rows64.max() >= self.map.shape[0]):
                raise IndexError(f"rows out of range for {self.map.shape[0]} vertices")
            if lod.shape[1] != self.map.shape[1] or base.shape[0] != self.map.shape[0]:
                raise ValueError(
                    f"_moved_rows: lod has {lod.shape[1]} vertices, base {base.shape[0]}; "
                    f"the map is {self.map.shape}"
                )
            out = np.empty((len(lod), len(rows64), 3))
            kernels.moved_rows_kernel(
                self.map.indptr, self.map.indices, self.map.data, rows64,
                np.require(lod, np.float64, ["C", "W"]), np.require(base, np.float64, ["C", "W"]),
                out,
            )  # fmt: skip
            return out
        d = lod[1:] - lod[0]  # (n, V_lod, 3)
        n, v_lod, _ = d.shape
        moved = self.map[rows] @ d.transpose(1, 0, 2).reshape(v_lod, n * 3)
        out = np.empty((n + 1, len(rows), 3))
        out[0] = base[rows]
        out[1:] = base[rows] + moved.reshape(len(rows), n, 3).transpose(1, 0, 2)
        return out

    def perturbed_residuals(
        self, y: np.ndarray, step: np.ndarray, pairs: list[_Pairs]
    ) -> tuple[np.ndarray, np.ndarray]:
        """``residuals(perturbed(y, step, used), pairs)``, the same numbers, with
        ``used`` the vertices of the pairs' edges.

        With the full mesh only those vertices are built (a few thousand of 13k,
        not a (1 + n, V, 3) array of mostly unset rows) and the pairs' edges are
        renumbered into them.
        """
        if not self.full:
            return self.residuals(self.perturbed(y, step), pairs)
        used = np.unique(np.concatenate([p.edges.ravel() for p in pairs]))
        lod = self.vertices(np.vstack([y, y + np.diag(step)]), lod=True)
        compact = self._moved_rows(lod, self._posed(y), used)
        local = [replace(p, edges=np.searchsorted(used, p.edges)) for p in pairs]
        return self.residuals(compact, local)

    def pairs(self, V: np.ndarray, lod: np.ndarray | None = None) -> list[_Pairs]:
        """Nearest-point correspondences in both directions, every usable view.

        Contour edges are found on a raster at ``visibility_scale``; the
        residuals are in working pixels.

        ``lod``: the level of detail of the same state, whose raster decides
        the visibility of a full mesh's contour edges.
        """
        out = []
        # The compiled contour pass takes the frames from the vertices itself.
        frames = face_frames(V, self.faces) if compiled_likelihood() is None else None
        owns = self._own_silhouettes(V) if self.config.outline_offsets else {}
        for c in range(len(self.obs.cameras)):
            tree = self.obs.trees[c]
            if tree is None:
                continue
            vis = self.visibility[c]
            own = owns.get(c)
            if own is not None and vis.size == own.mask.shape[::-1]:
                visible = own.mask  # the residual mesh's own raster at the camera's size
            elif lod is not None:
                visible = fill_silhouette(vis.project(lod), self.lod_faces, vis.size)
            else:
                visible = None
            kernels = compiled_likelihood()
            if kernels is not None and self._topology is not None:
                ids = contour_ids(
                    kernels, V, self._topology, vis, self._vis_arrays[c], self.obs.centers[c],
                    visible,
                )  # fmt: skip
            else:
                ids = occluding_contour(
                    V,
                    self.faces,
                    self.edges,
                    self.edge_faces,
                    vis,
                    self.obs.centers[c],
                    visible,
                    frames,
                )
            if len(ids) == 0:
                continue
            e = self.edges[ids]
            p = self._project(c, V, e)
            hidden = self.obs.in_unknown(c, p)
            if hidden.any():
                # Outline behind someone nearer: nothing observed to align it with.
                e, p = e[~hidden], p[~hidden]
                if len(e) == 0:
                    continue
            pts, nrm = self.obs.points[c], self.obs.normals[c]
            j, k = _nearest(tree, p, pts)
            to_model, to_observed = pts[j], pts
            outline = None if own is None else own.outline(self.obs.cameras[c], self.config)
            if outline is not None and len(outline):
                # The edge's offset from its own rendered outline, along the observed
                # normal the residual is measured on: the target moves by as much, so
                # the residual compares outline with outline.
                _, near = cKDTree(outline).query(p)
                delta = np.einsum("ij,ij->i", p - outline[near], nrm[j])
                to_model = to_model + delta[:, None] * nrm[j]
                to_observed = to_observed + delta[k][:, None] * nrm
            model_side = _Pairs(c, e, to_model, nrm[j], 1.0 / len(e))
            source: np.ndarray | None = k
            if own is not None and self.config.thin_px > 0:
                # Each residual keeps its weight: what is left out weighs nothing.
                keep = ~own.thin(self.config.thin_px)(p, self.obs.cameras[c])
                if not keep.all():
                    model_side = _Pairs(c, e[keep], to_model[keep], nrm[j][keep], 1.0 / len(e))
                    source = None  # its edges are no longer the ones k indexes
            if len(model_side.edges):
                out.append(model_side)
            out.append(_Pairs(c, e[k], to_observed, nrm, 1.0 / len(k), source=source))
        return out

    def _own_silhouettes(self, V: np.ndarray) -> dict[int, _Silhouette]:
        """The residual mesh's silhouettes (``V`` (V, 3)) in the usable views at the
        cameras' own resolution, by view index (views where no vertex projects are
        left out). One projection and one raster pass for all views."""
        views, cams = self._own_views, self._own_cameras
        if not views:
            return {}
        kernels = compiled_likelihood()
        if kernels is not None:
            planes = project_planes(kernels, V[None], self._own_arrays)  # (2, 1, C, V)
        else:
            planes = np.moveaxis(np.stack([cam.project(V) for cam in cams]), -1, 0)[:, None]
        pixels = np.moveaxis(planes, 0, -1)  # (1, C, V, 2)
        masks = coverage_views(pixels[0], self.faces, list(cams.sizes), closed=True)
        out = {}
        for k, (c, cam) in enumerate(zip(views, cams, strict=True)):
            xs, ys = planes[0, 0, k], planes[1, 0, k]
            lo, hi = np.array([xs.min(), ys.min()]), np.array([xs.max(), ys.max()])
            if not (np.isfinite(lo).all() and np.isfinite(hi).all()):  # NaN: behind it
                finite = np.isfinite(xs) & np.isfinite(ys)
                if not finite.any():
                    continue
                lo = np.array([xs[finite].min(), ys[finite].min()])
                hi = np.array([xs[finite].max(), ys[finite].max()])
            w, h = cam.size
            low = np.clip(np.floor(lo).astype(int) - 2, 0, None)
            high = np.minimum(np.ceil(hi).astype(int) + 3, (w, h))
            out[c] = _Silhouette(masks[k], cam, low, high)
        return out

    def _project(self, c: int, V: np.ndarray, e: np.ndarray) -> np.ndarray:
        """Projected edge midpoints; V may carry leading batch axes.

        The compiled kernel (the likelihood's backend) gathers, averages and
        projects in one pass over the edges instead of building the midpoints
        of every state; same expressions, pixels equal to about 1e-12.
        """
        kernels = compiled_likelihood()
        if kernels is None:
            mid = 0.5 * (V[..., e[:, 0], :] + V[..., e[:, 1], :])
            return self.obs.cameras[c].project(mid)
        lead = V.shape[:-2]
        flat = np.require(V.reshape(-1, *V.shape[-2:]), np.float64, ["C", "W"])
        out = np.empty((len(flat), len(e), 2))
        ends = np.require(e, np.int64, ["C", "W"])
        if len(e) and (ends.min() < 0 or ends.max() >= flat.shape[1]):
            raise IndexError(f"edge indices out of range for {flat.shape[1]} vertices")
        kernels.project_midpoints_kernel(flat, ends, *self._cam_arrays[c], out)
        return out.reshape(*lead, len(e), 2)

    def residuals(self, V: np.ndarray, pairs: list[_Pairs]) -> tuple[np.ndarray, np.ndarray]:
        """Weighted residuals (..., R) and their Huber IRLS weights (R,) (from the first state)."""
        kernels = compiled_likelihood()
        if kernels is not None:
            return self._residuals_numba(kernels, V, pairs)
        res, robust = [], []
        h = self.config.huber_px
        previous: tuple[_Pairs, np.ndarray] | None = None
        for p in pairs:
            if previous is not None and self._reuses(previous, p):
                q = previous[1][..., p.source, :]  # the same midpoints, projected once
            else:
                q = self._project(p.camera, V, p.edges)
            previous = (p, q)
            # Two products and one sum, as ``((q - targets) * normals).sum(-1)`` adds
            # them, without a reduction over a length-2 axis (slow in numpy).
            d = (q[..., 0] - p.targets[:, 0]) * p.normals[:, 0] + (
                q[..., 1] - p.targets[:, 1]
            ) * p.normals[:, 1]
            res.append(d * np.sqrt(p.weight))
            length = np.abs(d.reshape(-1, d.shape[-1])[0])
            robust.append(np.sqrt(np.where(length <= h, 1.0, h / np.maximum(length, 1e-12))))
        return np.concatenate(res, axis=-1), np.concatenate(robust)

    @staticmethod
    def _reuses(previous: tuple[_Pairs, np.ndarray], p: _Pairs) -> bool:
        """Whether ``p``'s edges are the previous pair's at ``p.source`` (same view), so
        their projections can be taken from that pair's."""
        return (
            p.source is not None
            and previous[0].camera == p.camera
            and len(p.source) == len(p.edges)
            and (len(p.source) == 0 or p.source.max() < len(previous[0].edges))
            and np.array_equal(previous[0].edges[p.source], p.edges)
        )

    def _residuals_numba(
        self, kernels: ModuleType, V: np.ndarray, pairs: list[_Pairs]
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`residuals` with the point-to-line residuals by a kernel written into
        one preallocated array (``likelihood_kernels.line_residuals_kernel``, numpy's
        expressions: the same numbers)."""
        lead = V.shape[:-2]
        S = int(np.prod(lead, dtype=np.int64))
        R = sum(len(p.edges) for p in pairs)
        out = np.empty((S, R))
        first = np.empty(R)
        col = 0
        previous: tuple[_Pairs, np.ndarray] | None = None
        for p in pairs:
            if previous is not None and self._reuses(previous, p):
                q, index = previous[1], np.require(p.source, np.int64, ["C", "W"])
            else:
                q = self._project(p.camera, V, p.edges).reshape(S, len(p.edges), 2)
                index = np.arange(len(p.edges), dtype=np.int64)
            previous = (p, q)
            n = len(p.edges)
            kernels.line_residuals_kernel(
                q, index, np.require(p.targets, np.float64, ["C", "W"]),
                np.require(p.normals, np.float64, ["C", "W"]), float(np.sqrt(p.weight)),
                out, col, first[col : col + n],
            )  # fmt: skip
            col += n
        h = self.config.huber_px
        length = np.abs(first)
        robust = np.sqrt(np.where(length <= h, 1.0, h / np.maximum(length, 1e-12)))
        return out.reshape(*lead, R), robust

    def linearize(
        self, y: np.ndarray, pairs: list[_Pairs], step: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Robustly weighted residuals and their forward-difference Jacobian at ``y``.

        Parameters
        ----------
        y : (n,) float
            The state ``[τ, θ, ν]``.
        pairs : list of _Pairs
            The correspondences found for ``y`` (:meth:`evaluate`).
        step : (n,) float
            Finite-difference step per state dimension.

        Returns
        -------
        r : (R,) float
            Residuals times their Huber IRLS weights (``(r ** 2).sum()`` is the
            data cost of ``y``).
        J : (R, n) float
            Their derivatives (the weights held fixed), for Gauss-Newton.
        """
        # Only the vertices of the contour edges enter the residuals.
        r, w = self.perturbed_residuals(y, step, pairs)
        J = ((r[1:] - r[0]) / step[:, None]).T * w[:, None]
        return r[0] * w, J

    def _posed(self, y: np.ndarray) -> np.ndarray:
        """Residual-mesh vertices (V, 3) of one state; the last one is remembered (the
        iteration evaluates a state, then differentiates at it)."""
        key = np.asarray(y, dtype=float).tobytes()
        if self._last is None or self._last[0] != key:
            self._last = (key, self.vertices(y)[0])
        return self._last[1]

    def evaluate(self, y: np.ndarray) -> tuple[float, list[_Pairs]]:
        """Cost of a state and the correspondences found for it."""
        V = self._posed(y)
        pairs = self.pairs(V, self.vertices(y, lod=True)[0] if self.full else None)
        if not pairs:
            return np.inf, pairs
        r, w = self.residuals(V, pairs)
        nu = y[NU]
        return float(((r * w) ** 2).sum() + self.config.shape_prior * nu @ nu), pairs


@dataclass(frozen=True)
class Alignment:
    """One frame's contour cost and the correspondences it found at ``state``
    (what :meth:`ContourCost.evaluate` returned there), kept for a later reader
    at the same state (the outline check after the session stage).

    Attributes
    ----------
    cost : ContourCost
        Holds the prepared observation (``cost.obs``).
    state : (40 + n_shape,) float
    pairs : list
        The correspondences at ``state``.
    """

    cost: ContourCost
    state: np.ndarray
    pairs: list

    def pairs_at(self, state: np.ndarray) -> list:
        """The correspondences at ``state``: the kept ones when it is the same state."""
        y = np.asarray(state, dtype=float)
        return self.pairs if np.array_equal(y, self.state) else self.cost.evaluate(y)[1]


def _edges(model: BodyModel, lod: bool) -> tuple[np.ndarray, np.ndarray]:
    """:func:`mesh_edges` of the model's level of detail or full mesh (computed once)."""
    cache = model.__dict__.setdefault("_refinement_edges", {})
    if lod not in cache:
        cache[lod] = mesh_edges(model.faces(lod=lod))
    return cache[lod]


def full_from_lod(model: BodyModel, k: int = 4) -> sparse.csr_matrix:
    """Map level-of-detail displacements onto the full mesh (for derivatives).

    Each full-mesh vertex moves as the inverse-distance blend of its ``k``
    nearest level-of-detail vertices of the same body part, found in the rest
    pose of the mean shape. The map is only used for the Jacobian of the
    full-mesh residuals: an inexact Jacobian slows Gauss-Newton but leaves its
    fixed points where the full-mesh residuals balance.

    Returns
    -------
    (V_full, V_lod) sparse float
        Rows sum to 1. Computed once per loaded model.
    """
    cache = model.__dict__.setdefault("_full_from_lod", {})
    if k in cache:
        return cache[k]
    rest = BodyState.rest(model.n_shape)
    full = model.pose(rest).vertices[0]
    lod = model.pose(rest, lod=True).vertices[0]
    lod_parts = np.full(len(lod), -1)
    lod_parts[model.faces(lod=True).reshape(-1)] = np.repeat(model.lod.arrays.parts, 3)
    rows, cols, vals = [], [], []
    for part in np.unique(model.vertex_parts):
        mine = np.flatnonzero(model.vertex_parts == part)
        pool = np.flatnonzero(lod_parts == part)
        if len(pool) == 0:  # no LOD vertex carries this part: any part will do
            pool = np.arange(len(lod))
        kk = min(k, len(pool))
        dist, idx = cKDTree(lod[pool]).query(full[mine], k=kk)
        dist, idx = dist.reshape(len(mine), kk), idx.reshape(len(mine), kk)
        w = 1.0 / np.maximum(dist, 1e-6)
        rows.append(np.repeat(mine, kk))
        cols.append(pool[idx].reshape(-1))
        vals.append((w / w.sum(axis=1, keepdims=True)).reshape(-1))
    out = sparse.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(len(full), len(lod)),
    )
    cache[k] = out
    return out


def difference_steps(config: RefineConfig, n_shape: int) -> np.ndarray:
    """Finite-difference steps (40 + n_shape,) for ``[τ, θ, ν]`` (``config.steps``)."""
    return np.r_[
        np.full(3, config.steps[0]),
        np.full(37, config.steps[1]),
        np.full(n_shape, config.steps[2]),
    ]


def _gauss_newton_step(
    cost_fn: ContourCost,
    y: np.ndarray,
    JJ: np.ndarray,
    g: np.ndarray,
    bounds: tuple[np.ndarray, np.ndarray],
    lam: float,
) -> tuple[float, tuple[np.ndarray, list]]:
    """:func:`refine`'s step from ``y`` damped by ``lam``: its cost, state and pairs."""
    dy = -np.linalg.solve(marquardt(JJ, lam), g)
    y_new = np.clip(y + dy, *bounds)
    f_new, pairs_new = cost_fn.evaluate(y_new)
    return f_new, (y_new, pairs_new)


def refine(
    model: BodyModel,
    obs: ContourObservation,
    initial: np.ndarray,
    config: RefineConfig | None = None,
) -> RefineResult:
    """Polish a state ``[τ, θ, ν]`` by contour alignment (Levenberg-Marquardt).

    Parameters
    ----------
    model : BodyModel
    obs : ContourObservation
        From :func:`prepare_contours`.
    initial : (40 + n_shape,) float
    config : RefineConfig, optional

    Returns
    -------
    RefineResult
        The initial state comes back unchanged when no step lowers the cost
        (or no view shows a contour).
    """
    config = config or RefineConfig()
    y = np.asarray(initial, dtype=float).copy()
    n = len(y)
    if n != POSE_DIM + model.n_shape:
        raise ValueError(f"initial: expected {POSE_DIM + model.n_shape} values, got {n}")
    lo, hi = state_bounds(model)
    # Heading is an angle: wrap it rather than clip it at ±π.
    yaw = THETA.start + YAW
    y[yaw] = (y[yaw] + np.pi) % (2 * np.pi) - np.pi
    y = np.clip(y, lo, hi)
    step = difference_steps(config, model.n_shape)
    cost_fn = ContourCost(model, obs, config)
    f, pairs = cost_fn.evaluate(y)
    f0, accepted, damping = f, 0, Damping()
    if not np.isfinite(f):
        return RefineResult(y, f, f0, 0)
    prior = np.zeros((model.n_shape, n))
    prior[:, NU] = np.eye(model.n_shape) * np.sqrt(config.shape_prior)
    for _ in range(config.iterations):
        r0, J = cost_fn.linearize(y, pairs, step)
        JJ = J.T @ J + prior.T @ prior
        g = J.T @ r0 + prior.T @ (prior @ y)

        propose = functools.partial(_gauss_newton_step, cost_fn, y, JJ, g, (lo, hi))
        step_taken, f, improved = damped_step(propose, f, damping, config.tolerance)
        if step_taken is not None:
            y, pairs = step_taken
            accepted += 1
        if not improved:
            break
    return RefineResult(y, f, f0, accepted)
