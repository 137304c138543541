"""The SCAPE body model at run time: load the baked file, shape and pose bodies.

Typical use::

    model = BodyModel.load()                      # the committed model, ν in R^9
    state = BodyState.rest(model.n_shape)         # τ = 0, θ = 0, ν = 0 (mean body)
    body = model.pose(state)                      # PosedBody with vertices, joints
    canon = model.canonical_vertices(state.nu)    # standing rest pose, feet on z = 0
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from bodymetry.errors import InputError
from bodymetry.estimation.body_model import geometry
from bodymetry.estimation.body_model.scape import ScapeArrays, ScapeMesh
from bodymetry.estimation.body_model.skeleton import (
    JOINTS,
    N_POSE,
    PARTS,
    JointLimits,
    posed_skeleton,
    skeleton_kernels,
)
from bodymetry.fileio import load_npz

#: The committed model file.
DEFAULT_MODEL_PATH = Path(__file__).with_name("data") / "body_model.npz"
#: Bumped when the file layout changes incompatibly.
MODEL_FORMAT = 1
#: Layout version of the studio's bank of independent bodies
#: (``studio/data/independent_bodies.npz``): written by the maintainers' bake
#: (``bake.independent``), read by ``studio.independent``; bumped when it changes incompatibly.
INDEPENDENT_FORMAT = 1
DEFAULT_SHAPE_DOFS = 12
#: Bodies of the prior at least this old (years) are adults: ν = 0 is their mean body
#: (the bake), and the studio draws its subjects by seed among them.
ADULT_YEARS = 18.0
#: Skeleton anchors of the posed solve (see :meth:`BodyModel.pose`): every vertex at
#: least ANCHOR_CLEARANCE metres (rest body) from any other part is pulled towards
#: where its part's rigid motion about the skeleton carries it, with this weight
#: against one edge equation. 0.3 and 2-8 cm gave the same fit to skinned bodies.
ANCHOR_WEIGHT = 0.3
ANCHOR_CLEARANCE = 0.03


#: Where τ, θ and ν sit in a state vector ``[τ, θ, ν]`` (:meth:`BodyState.vector`).
TAU = slice(0, 3)
THETA = slice(3, 3 + N_POSE)
NU = slice(3 + N_POSE, None)
#: Length of ``[τ, θ]`` (40): ν starts here.
POSE_DIM = 3 + N_POSE


@dataclass(frozen=True)
class BodyState:
    """A batch of body states Y = (τ, θ, ν).

    Attributes
    ----------
    tau : (B, 3) float
        World position of the root joint (mid-point of the hips), metres.
    theta : (B, 37) float
        Joint angles, radians (layout in ``skeleton``).
    nu : (B, n_shape) float
        Shape coefficients, in standard deviations of the training bodies.
    """

    tau: np.ndarray
    theta: np.ndarray
    nu: np.ndarray

    def __post_init__(self) -> None:
        tau = np.atleast_2d(np.asarray(self.tau, dtype=float))
        theta = np.atleast_2d(np.asarray(self.theta, dtype=float))
        nu = np.atleast_2d(np.asarray(self.nu, dtype=float))
        if tau.shape[-1] != 3 or theta.shape[-1] != N_POSE:
            raise ValueError(
                f"BodyState: expected tau (B, 3) and theta (B, {N_POSE}), "
                f"got {tau.shape} and {theta.shape}"
            )
        B = max(len(tau), len(theta), len(nu))
        for name, arr in (("tau", tau), ("theta", theta), ("nu", nu)):
            if len(arr) not in (1, B):
                raise ValueError(f"BodyState.{name}: batch size {len(arr)} does not match {B}")
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"BodyState.{name}: contains NaN or infinity")
        object.__setattr__(self, "tau", np.broadcast_to(tau, (B, 3)).copy())
        object.__setattr__(self, "theta", np.broadcast_to(theta, (B, N_POSE)).copy())
        object.__setattr__(self, "nu", np.broadcast_to(nu, (B, nu.shape[-1])).copy())

    def __len__(self) -> int:
        return len(self.tau)

    @classmethod
    def rest(cls, n_shape: int = DEFAULT_SHAPE_DOFS, batch: int = 1) -> BodyState:
        """The mean body in its rest pose with the root joint at the origin."""
        return cls(np.zeros((batch, 3)), np.zeros((batch, N_POSE)), np.zeros((batch, n_shape)))

    def vector(self) -> np.ndarray:
        """(B, 3 + 37 + n_shape) concatenation ``[τ, θ, ν]``."""
        return np.concatenate([self.tau, self.theta, self.nu], axis=1)

    @classmethod
    def from_vector(cls, y: np.ndarray) -> BodyState:
        """Inverse of :meth:`vector` for ``y`` of shape (B, 40 + n_shape)."""
        y = np.atleast_2d(np.asarray(y, dtype=float))
        return cls(y[:, TAU], y[:, THETA], y[:, NU])

    def __getitem__(self, index: int | slice | np.ndarray) -> BodyState:
        return BodyState(self.tau[index], self.theta[index], self.nu[index])


@dataclass(frozen=True)
class PosedBody:
    """Meshes and joints of a batch of posed bodies.

    Attributes
    ----------
    vertices : (B, V, 3) float
        World coordinates, metres.
    faces : (T, 3) int
    joints : (B, 15, 3) float
        Joint centres (order of ``skeleton.JOINTS``).
    keypoints : (B, K, 3) float
        Joints plus extra keypoints (order of ``BodyModel.keypoint_names``).
    """

    vertices: np.ndarray
    faces: np.ndarray
    joints: np.ndarray
    keypoints: np.ndarray


def _scape_arrays(data: dict[str, np.ndarray], prefix: str) -> ScapeArrays:
    return ScapeArrays(
        template=data[f"{prefix}_template"].astype(float),
        faces=data[f"{prefix}_faces"].astype(np.int64),
        parts=data[f"{prefix}_parts"].astype(np.int64),
        shape_mean=data[f"{prefix}_shape_mean"].astype(float),
        shape_basis=data[f"{prefix}_shape_basis"].astype(float),
        pose_joints=data[f"{prefix}_pose_joints"].astype(np.int64),
        pose_coef=data[f"{prefix}_pose_coef"].astype(float),
    )


def _sparse(data: dict[str, np.ndarray], prefix: str) -> sp.csr_matrix:
    shape = tuple(int(x) for x in data[f"{prefix}_shape"])
    return sp.csr_matrix(
        (data[f"{prefix}_vals"].astype(float), (data[f"{prefix}_rows"], data[f"{prefix}_cols"])),
        shape=shape,
    )


def rigid_targets(
    rest: np.ndarray,
    parts: np.ndarray,
    rest_joints: np.ndarray,
    rot: np.ndarray,
    joints: np.ndarray,
) -> np.ndarray:
    """Where each part's rigid motion about its joint carries points of the rest body.

    A point ``p`` of part ``k`` goes to ``R[k] @ (p - rest_joints[k]) + joints[k]``
    (the skeleton anchors' targets, :meth:`BodyModel.pose`).

    Parameters
    ----------
    rest : (B, N, 3) or (N, 3) float
        The points in the rest pose.
    parts : (N,) int
        Each point's part, sorted (the points of a part are one slice).
    rest_joints : (B, 15, 3) or (15, 3) float
    rot : (B, 15, 3, 3) float
        Global part rotations (``skeleton.forward_kinematics``).
    joints : (B, 15, 3) float
        Posed joint positions.

    Returns
    -------
    (B, N, 3) float
    """
    B = len(rot)
    rest = np.broadcast_to(rest, (B, *np.shape(rest)[-2:]))
    rest_joints = np.broadcast_to(rest_joints, (B, len(PARTS), 3))
    out = np.empty(rest.shape)
    bounds = np.searchsorted(parts, np.arange(len(PARTS) + 1))
    for p in range(len(PARTS)):
        sel = slice(bounds[p], bounds[p + 1])
        rel = rest[:, sel] - rest_joints[:, p, None]
        out[:, sel] = joints[:, p, None] + rel @ np.swapaxes(rot[:, p], 1, 2)
    return out


class BodyModel:
    """Our SCAPE body model (paper §2) built from the MakeHuman body.

    Parameters
    ----------
    data : dict of arrays
        The contents of a baked model file.
    n_shape : int
        Shape components used (ν's length); at most the number stored.
    """

    def __init__(self, data: dict[str, np.ndarray], n_shape: int = DEFAULT_SHAPE_DOFS) -> None:
        fmt = int(data["format"]) if "format" in data else -1
        if fmt != MODEL_FORMAT:
            raise InputError(f"body model: format {fmt}, this bodymetry reads {MODEL_FORMAT}")
        self.data = data
        self.n_shape = int(n_shape)
        self.full = ScapeMesh(_scape_arrays(data, "full"), self.n_shape)
        self.lod = ScapeMesh(_scape_arrays(data, "lod"), self.n_shape)
        self.lod_map = _sparse(data, "lod_map")
        self.keypoint_regressor = _sparse(data, "keypoint_regressor")
        self.keypoint_names: tuple[str, ...] = tuple(str(x) for x in data["keypoint_names"])
        self.keypoint_parts = data["keypoint_parts"].astype(np.int64)
        self.hinge_axes = data["hinge_axes"].astype(float)
        self.limits = JointLimits(
            data["limit_lower"].astype(float), data["limit_upper"].astype(float)
        )
        self.poses = {
            "tpose": data["pose_tpose"].astype(float),
            "apose": data["pose_apose"].astype(float),
        }
        self.provenance: dict = json.loads(str(data["provenance"]))
        self.vertex_parts = data["vertex_parts"].astype(np.int64)
        self.landmarks: dict[str, int] = {
            str(k): int(v)
            for k, v in zip(data["landmark_names"], data["landmark_vertices"], strict=True)
        }

    @classmethod
    def load(cls, path: str | Path | None = None, n_shape: int = DEFAULT_SHAPE_DOFS) -> BodyModel:
        """Load a baked model file (default: the one shipped with bodymetry)."""
        path = DEFAULT_MODEL_PATH if path is None else Path(path)
        data = load_npz(path)
        if "format" not in data or "full_shape_basis" not in data:
            raise InputError(
                f"{path}: not a bodymetry body model file (no 'format' or 'full_shape_basis' array)"
            )
        if int(data["format"]) != MODEL_FORMAT:
            raise InputError(
                f"{path}: body model format {int(data['format'])}, this bodymetry reads "
                f"{MODEL_FORMAT}"
            )
        n_max = data["full_shape_basis"].shape[0]
        if not 0 < n_shape <= n_max:
            raise InputError(f"{path}: n_shape must be 1..{n_max}, got {n_shape}")
        return cls(data, n_shape)

    # --- properties ---------------------------------------------------------
    @property
    def parts(self) -> tuple[str, ...]:
        return PARTS

    @property
    def n_shape_stored(self) -> int:
        return int(self.data["full_shape_basis"].shape[0])

    def prior_shapes(self, split: str = "train") -> np.ndarray:
        """ν of the bodies drawn from the calibrated prior when the model was baked.

        Parameters
        ----------
        split : {"train", "heldout"}
            The bodies the shape space was learned from, or the held-out ones
            (use these for test subjects).

        Returns
        -------
        (n, n_shape) float
        """
        if split not in ("train", "heldout"):
            raise ValueError(f"split: expected 'train' or 'heldout', got {split!r}")
        return self.data[f"{split}_nu"][:, : self.n_shape].astype(float)

    def prior_ages(self, split: str = "train") -> np.ndarray:
        """Age in years (n,) of the bodies of :meth:`prior_shapes` (same order).

        The bake draws the population from 5 to 90 years, children included
        (docs/body-model.md); callers that want adults select ``>= 18``.
        """
        if split not in ("train", "heldout"):
            raise ValueError(f"split: expected 'train' or 'heldout', got {split!r}")
        return self.data[f"{split}_age_years"].astype(float)

    def faces(self, lod: bool = False) -> np.ndarray:
        """Triangles (T, 3) of the full mesh or of the level of detail, in file order.

        The array is shared (converted once at load); do not modify it.
        """
        return self._faces[lod]

    @cached_property
    def _faces(self) -> dict[bool, np.ndarray]:
        return {
            lod: self.data["lod_faces" if lod else "full_faces"].astype(np.int64)
            for lod in (False, True)
        }

    def _mesh(self, lod: bool) -> ScapeMesh:
        return self.lod if lod else self.full

    # --- shape (linear in ν) --------------------------------------------------
    @cached_property
    def _canonical_basis(self) -> np.ndarray:
        """(1 + n, V, 3): unposed full mesh = basis[0] + Σ ν_i basis[1 + i] (vertex 0 pinned)."""
        return self._unposed_basis(self.full)

    def _unposed_basis(self, mesh: ScapeMesh) -> np.ndarray:
        """(1 + n, V, 3): the mean unposed mesh and the change per unit of each ν_i."""
        n = self.n_shape
        nu = np.vstack([np.zeros(n), np.eye(n)])
        solved = mesh.solve(mesh.edges(None, None, nu))
        solved[1:] -= solved[0]
        return solved

    @cached_property
    def _vertex_areas(self) -> np.ndarray:
        """(V,) a third of the template area of the triangles around each vertex."""
        faces = self.faces()
        area = geometry.triangle_areas(self.full.arrays.template, faces)
        return np.bincount(
            faces.reshape(-1), np.repeat(area / 3.0, 3), minlength=self.full.n_vertices
        )

    @cached_property
    def _keypoint_basis(self) -> np.ndarray:
        """(1 + n, K, 3) keypoints of the canonical basis (linear, like the mesh)."""
        return np.stack([self.keypoint_regressor @ b for b in self._canonical_basis])

    @cached_property
    def _rest_basis(self) -> dict[bool, np.ndarray]:
        """Per resolution, (1 + n, V, 3): the unposed mesh, linear in ν, in the full
        mesh's canonical (pinned) frame, the frame of the rest keypoints."""
        # Align the LOD frame to the full one through the barycentric map.
        solved = self._unposed_basis(self.lod)
        mapped = np.stack([self.lod_map @ b for b in self._canonical_basis])
        lod = solved + (mapped - solved).mean(axis=1, keepdims=True)
        return {False: self._canonical_basis, True: lod}

    @cached_property
    def _anchor_basis(self) -> dict[bool, np.ndarray]:
        """Per resolution, (1 + n, 3): pelvis-vertex centroid minus root joint, unposed.

        Posed meshes are placed so their pelvis centroid sits where the rigid
        pelvis carries it; the offset is linear in ν like everything unposed.
        """
        root = self._keypoint_basis[:, 0]
        return {
            lod: self._rest_basis[lod][:, self._pelvis_vertices[lod]].mean(axis=1) - root
            for lod in (False, True)
        }

    def parts_of_vertices(self, lod: bool = False) -> np.ndarray:
        """(V,) int: each vertex's body part (that of an incident triangle), for the
        full mesh (:attr:`vertex_parts`, stored by the bake by the same rule) or
        the level of detail."""
        if not lod:
            return self.vertex_parts
        faces = self.faces(lod=True)
        out = np.zeros(self.lod.n_vertices, np.int64)
        out[faces.reshape(-1)] = np.repeat(self.lod.arrays.parts, 3)
        return out

    def skeleton_anchors(self, lod: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The vertices the posed solve anchors to the skeleton, and their parts.

        A vertex is anchored when all its triangles belong to one part and it
        lies at least :data:`ANCHOR_CLEARANCE` from every vertex of another part
        (rest template): the part's inside, away from the joints, where the
        body moves rigidly with its bone.

        Returns
        -------
        vertices : (Na,) int
        parts : (Na,) int
        """
        return self._skeleton_anchors[lod]

    @cached_property
    def _skeleton_anchors(self) -> dict[bool, tuple[np.ndarray, np.ndarray]]:
        out = {}
        for lod in (False, True):
            mesh = self._mesh(lod)
            faces, parts, rest = mesh.arrays.faces, mesh.arrays.parts, mesh.arrays.template
            V = len(rest)
            incidence = sp.csr_matrix(
                (np.ones(faces.size), (faces.reshape(-1), np.repeat(parts, 3))),
                shape=(V, len(PARTS)),
            )
            single = np.asarray((incidence > 0).sum(axis=1)).ravel() == 1
            part = np.asarray(incidence.argmax(axis=1)).ravel()
            keep = np.zeros(V, bool)
            for p in range(len(PARTS)):
                mine = np.flatnonzero(single & (part == p))
                others = np.flatnonzero(~single | (part != p))
                if len(mine) and len(others):
                    gap = cKDTree(rest[others]).query(rest[mine])[0]
                    keep[mine[gap >= ANCHOR_CLEARANCE]] = True
            # Sorted by part, so each part's anchors are one slice in pose().
            idx = np.flatnonzero(keep)
            idx = idx[np.argsort(part[idx], kind="stable")]
            out[lod] = (idx, part[idx])
            mesh.set_anchors(idx, ANCHOR_WEIGHT)
        return out

    @cached_property
    def _rest_anchor_basis(self) -> dict[bool, np.ndarray]:
        """Per resolution, (1 + n, Na, 3): the anchors' unposed positions.

        C-contiguous: the fancy index alone gives strides (24, 240, 8), which the
        compiled targets would copy on every pose (2.8 MB for the full mesh).
        """
        return {
            lod: np.ascontiguousarray(self._rest_basis[lod][:, self._skeleton_anchors[lod][0]])
            for lod in (False, True)
        }

    @cached_property
    def _pelvis_vertices(self) -> dict[bool, np.ndarray]:
        """Per resolution, the vertices of the pelvis part (the placement anchor)."""
        pelvis = PARTS.index("pelvis")
        return {
            lod: np.unique(self.faces(lod)[self._mesh(lod).arrays.parts == pelvis])
            for lod in (False, True)
        }

    def _check_nu(self, nu: np.ndarray) -> np.ndarray:
        nu = np.atleast_2d(np.asarray(nu, dtype=float))
        if nu.shape[-1] != self.n_shape:
            raise ValueError(f"nu: expected shape (B, {self.n_shape}), got {nu.shape}")
        return nu

    def _linear(self, basis: np.ndarray, nu: np.ndarray) -> np.ndarray:
        # One multiply-add pass per component, in order: every state's values are
        # the same bits in any batch (a BLAS product rounds by batch size), and
        # 5x faster than einsum's loop on the anchors (80 states, 1.2k vertices).
        kernels = skeleton_kernels()
        if kernels is not None and nu.ndim == 2 and nu.shape[1] == len(basis) - 1:
            # The same sums in one pass (skeleton_kernels.linear_kernel): same bits.
            out = np.empty((len(nu), *basis.shape[1:]))
            kernels.linear_kernel(
                np.ascontiguousarray(basis, dtype=np.float64).reshape(len(basis), -1),
                np.ascontiguousarray(nu, dtype=np.float64),
                out.reshape(len(nu), -1),
            )
            return out
        out = np.broadcast_to(basis[0], (len(nu), *basis.shape[1:])).copy()
        for i in range(nu.shape[1]):
            out += nu[:, i].reshape(-1, *([1] * (basis.ndim - 1))) * basis[1 + i]
        return out

    def rest_keypoints(self, nu: np.ndarray) -> np.ndarray:
        """Keypoints (B, K, 3) of the unposed body, in the canonical frame of
        :meth:`canonical_vertices` (root joint above the origin, feet on z = 0)."""
        nu = self._check_nu(nu)
        verts = self._linear(self._canonical_basis, nu)
        kp = self._linear(self._keypoint_basis, nu)
        return kp - self._canonical_offset(verts, kp)[:, None, :]

    @staticmethod
    def _canonical_offset(verts: np.ndarray, kp: np.ndarray) -> np.ndarray:
        offset = kp[:, 0].copy()
        offset[:, 2] = verts[..., 2].min(axis=1)
        return offset

    def canonical_vertices(self, nu: np.ndarray) -> np.ndarray:
        """The unposed (rest-pose, standing) full mesh for each shape.

        Parameters
        ----------
        nu : (B, n_shape) float

        Returns
        -------
        (B, V, 3) float
            Lowest point on z = 0, root joint above the origin.
        """
        nu = self._check_nu(nu)
        verts = self._linear(self._canonical_basis, nu)
        kp = self._linear(self._keypoint_basis, nu)
        return verts - self._canonical_offset(verts, kp)[:, None, :]

    def shape_from_vertices(self, vertices: np.ndarray) -> np.ndarray:
        """Least-squares ν of unposed bodies given as full meshes (any translation).

        This is the projection onto the model's shape space in vertex space: the
        ν whose canonical mesh, best translated, is closest to ``vertices`` in the
        area-weighted least-squares sense.

        Parameters
        ----------
        vertices : (B, V, 3) float
            Rest-pose bodies in full correspondence with the template.

        Returns
        -------
        (B, n_shape) float
        """
        vertices = np.asarray(vertices, dtype=float)
        if vertices.ndim == 2:
            vertices = vertices[None]
        if vertices.shape[1:] != (self.full.n_vertices, 3):
            raise ValueError(
                f"vertices: expected shape (B, {self.full.n_vertices}, 3), got {vertices.shape}"
            )
        # Each vertex weighs by the surface area around it (a third of its
        # triangles' areas), so the dense face and hands do not dominate the fit.
        w = np.sqrt(self._vertex_areas)[:, None]
        basis = self._canonical_basis - self._canonical_basis.mean(axis=1, keepdims=True)
        A = (basis[1:] * w).reshape(self.n_shape, -1).T  # (3V, n)
        b = ((vertices - vertices.mean(axis=1, keepdims=True) - basis[0]) * w).reshape(
            len(vertices), -1
        )
        nu, *_ = np.linalg.lstsq(A, b.T, rcond=None)
        return nu.T

    def _anchor_targets(
        self,
        lod: bool,
        nu: np.ndarray,
        rest_joints: np.ndarray,
        rot: np.ndarray,
        joints: np.ndarray,
    ) -> np.ndarray:
        """(B, Na, 3): where each part's rigid motion about its joint carries its anchors."""
        _, parts = self._skeleton_anchors[lod]
        kernels = skeleton_kernels()
        if kernels is not None:
            # One pass (skeleton_kernels.anchor_targets_kernel): the same rest
            # positions, the rotation summed in order (equal to rounding).
            basis = self._rest_anchor_basis[lod]
            B = len(nu)
            out = np.empty((B, basis.shape[1], 3))
            kernels.anchor_targets_kernel(
                np.ascontiguousarray(basis, dtype=np.float64),
                np.ascontiguousarray(nu, dtype=np.float64),
                np.ascontiguousarray(parts, dtype=np.int64),
                np.ascontiguousarray(np.broadcast_to(rest_joints, (B, len(PARTS), 3))),
                np.ascontiguousarray(np.broadcast_to(rot, (B, len(PARTS), 3, 3))),
                np.ascontiguousarray(np.broadcast_to(joints, (B, len(PARTS), 3))),
                out,
            )
            return out
        rest = self._linear(self._rest_anchor_basis[lod], nu)  # (B, Na, 3)
        return rigid_targets(rest, parts, rest_joints, rot, joints)

    # --- pose ------------------------------------------------------------------
    def pose(
        self,
        state: BodyState,
        lod: bool = False,
        pose_deformation: bool = True,
        skeleton_anchors: bool = True,
    ) -> PosedBody:
        """Meshes, joints and keypoints of posed, shaped bodies (Eq. 1 + solve).

        Parameters
        ----------
        state : BodyState
            Batch of B states.
        lod : bool
            Build the ~3,000-triangle level of detail instead of the full mesh.
        pose_deformation : bool
            Apply the learned Q (False: rigid parts only, for comparison).
        skeleton_anchors : bool
            Anchor each part's inside to its bone (False: SCAPE's plain
            least squares, for comparison).
        """
        nu = self._check_nu(state.nu)
        rest_kp = self._linear(self._keypoint_basis, nu)  # canonical (pinned) frame
        rest_joints = rest_kp[:, : len(JOINTS)]
        local, rot, joints = posed_skeleton(state.theta, state.tau, rest_joints, self.hinge_axes)
        local = local if pose_deformation else None
        mesh = self._mesh(lod)
        # SCAPE's least squares alone lets errors of the learned deformations add up
        # along the body: with both arms overhead the head sank 4 cm against the
        # skinned body the deformations were learned from. Anchoring each part's
        # inside to its bone (rigid about the skeleton's joints) keeps the parts
        # where the skeleton puts them and leaves the deformations to the seams
        # (docs/body-model.md, "Skeleton anchors").
        targets = None
        if skeleton_anchors:
            targets = self._anchor_targets(lod, nu, rest_joints, rot, joints)
        verts = mesh.solve(mesh.edges(rot, local, nu), targets)
        anchor = self._linear(self._anchor_basis[lod], nu)  # (B, 3)
        want = state.tau + np.einsum("bij,bj->bi", rot[:, 0], anchor)
        have = verts[:, self._pelvis_vertices[lod]].mean(axis=1)
        kernels = skeleton_kernels()
        if kernels is not None and verts.flags.c_contiguous:
            # The same additions (skeleton_kernels.translate_kernel), 8x faster.
            kernels.translate_kernel(verts, np.ascontiguousarray(want - have))
        else:
            verts += (want - have)[:, None, :]
        # Extra keypoints ride rigidly on their part.
        parts = self.keypoint_parts
        rel = rest_kp - rest_joints[:, parts]
        kp = joints[:, parts] + np.einsum("bkij,bkj->bki", rot[:, parts], rel)
        return PosedBody(verts, self.faces(lod), joints, kp)

    def pose_states(self, states: np.ndarray, lod: bool = False) -> PosedBody:
        """:meth:`pose` of state vectors, checked against this model.

        Parameters
        ----------
        states : (F, 40 + n_shape) float
            ``[τ, θ, ν]`` per body.
        lod : bool
            The level of detail instead of the full mesh.

        Raises
        ------
        ValueError
            For states of another width (another number of shape components).
        """
        states = np.atleast_2d(np.asarray(states, dtype=float))
        if states.ndim != 2 or states.shape[1] != POSE_DIM + self.n_shape:
            raise ValueError(f"states: expected (F, {POSE_DIM + self.n_shape}), got {states.shape}")
        return self.pose(BodyState.from_vector(states), lod=lod)


def shipped_model(n_shape: int = DEFAULT_SHAPE_DOFS) -> BodyModel:
    """The shipped body model with ``n_shape`` components, loaded once per process.

    Training and fitting share it, so its factorizations and anchors, built on
    first use, are built once; forked workers inherit them. Treat it as
    read-only.
    """
    return _shipped(int(n_shape))  # one cache entry however n_shape is passed


@functools.lru_cache(maxsize=2)
def _shipped(n_shape: int) -> BodyModel:
    return BodyModel.load(n_shape=n_shape)
