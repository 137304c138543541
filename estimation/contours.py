"""Contours for the contour refinement: the observed outline and the model's.

* the observed silhouette's **boundary points** (:func:`boundary_points`), at
  sub-pixel positions (the midpoints between 4-neighbour inside/outside pixel
  pairs), sampled along the outline with its outward normals
  (:func:`prepare_contours`, a frame's :class:`ContourObservation`);
* the model's **occluding contour** (:func:`occluding_contour`): the mesh edges
  (:func:`mesh_edges`) whose two faces turn one towards, one away from the
  camera and which project onto the boundary of the model silhouette (the
  visible outline, not the hidden folds).

:mod:`bodymetry.estimation.refinement` aligns the two. Everything is
deterministic (no random choices).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from types import ModuleType

import cv2
import numpy as np
from scipy.ndimage import map_coordinates
from scipy.spatial import cKDTree

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.estimation.generative import compiled_likelihood, downscale_mask, unknown_masks
from bodymetry.estimation.projection import camera_arrays, fill_silhouette

__all__ = [
    "ContourObservation",
    "ContourTopology",
    "boundary_points",
    "contour_ids",
    "contour_topology",
    "face_frames",
    "mask_at",
    "mesh_edges",
    "near_outside",
    "near_region",
    "occluding_contour",
    "outline_normals",
    "outline_samples",
    "prepare_contours",
]


def boundary_points(mask: np.ndarray) -> np.ndarray:
    """Sub-pixel boundary of a binary mask.

    Parameters
    ----------
    mask : (H, W) bool

    Returns
    -------
    (P, 2) float
        ``(x, y)`` pixel coordinates of the midpoints between horizontally or
        vertically adjacent pixels of which exactly one is inside: the
        0.5-level crossing of the mask, unbiased (the boundary pixels' centres
        lie half a pixel inside).
    """
    m = np.asarray(mask, dtype=bool)
    if m.ndim != 2:
        raise ValueError(f"mask must be 2-D, got shape {m.shape}")
    ys, xs = np.nonzero(m[:, :-1] != m[:, 1:])
    horizontal = np.c_[xs + 0.5, ys]
    ys, xs = np.nonzero(m[:-1] != m[1:])
    vertical = np.c_[xs, ys + 0.5]
    return np.vstack([horizontal, vertical]).astype(float)


def mesh_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edges of a closed triangle mesh with their two faces.

    Parameters
    ----------
    faces : (T, 3) int

    Returns
    -------
    edges : (E, 2) int
        Vertex pairs, each edge once.
    edge_faces : (E, 2) int
        The two triangles sharing each edge.

    Raises
    ------
    ValueError
        If some edge does not have exactly two faces (mesh not closed and manifold).
    """
    faces = np.asarray(faces)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    owner = np.tile(np.arange(len(faces)), 3)
    key = np.sort(e, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, owner = key[order], owner[order]
    _, counts = np.unique(key, axis=0, return_counts=True)
    if len(counts) * 2 != len(key) or np.any(counts != 2):
        raise ValueError("mesh is not closed: an edge does not have exactly two faces")
    return key[0::2], np.c_[owner[0::2], owner[1::2]]


@dataclass
class ContourObservation:
    """Observed boundary points of one frame, ready for :func:`refine`.

    Attributes
    ----------
    cameras : CameraGroup
        Scaled to the working resolution.
    centers : (C, 3) float
        Camera centres (world, metres).
    points : list of (P_c, 2) float
        Boundary points per view in working pixels (empty where the view has none).
    normals : list of (P_c, 2) float
        Outward unit normals of the observed outline at those points.
    trees : list of cKDTree or None
    originals : CameraGroup or None
        The rig at its own resolution (None: ``cameras``).
    unknown : list of ((h_c, w_c) bool or None)
        Per view at the working resolution, pixels that are neither the
        person's nor background (someone nearer covers them): model outline
        points there have nothing to align with (:meth:`in_unknown`). Empty:
        none in any view.
    """

    cameras: CameraGroup
    centers: np.ndarray
    points: list[np.ndarray]
    normals: list[np.ndarray]
    trees: list[cKDTree | None]
    originals: CameraGroup | None = None
    unknown: list[np.ndarray | None] = field(default_factory=list)

    @property
    def valid(self) -> np.ndarray:
        return np.array([t is not None for t in self.trees])

    @property
    def scale(self) -> float:
        """The working scale: working pixels per pixel of the masks (``Camera.scaled``)."""
        if self.originals is None or len(self.cameras) == 0:
            return 1.0
        return float(self.cameras[0].K[0, 0] / self.originals[0].K[0, 0])

    def in_unknown(self, c: int, points: np.ndarray) -> np.ndarray:
        """(P,) bool: which of view ``c``'s working pixels ``points`` (P, 2) fall
        on its unknown pixels (all False where it has none; outside the image:
        False)."""
        u = self.unknown[c] if self.unknown else None
        if u is None or len(points) == 0:
            return np.zeros(len(points), bool)
        return mask_at(u, points)


def mask_at(mask: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(P,) bool: ``mask`` (H, W) bool at the pixels nearest ``points`` (P, 2) float
    (x, y); False outside the image and for NaN points."""
    h, w = mask.shape
    ij = np.round(np.nan_to_num(points, nan=-1.0)).astype(int)
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
    out = np.zeros(len(points), bool)
    out[inside] = mask[ij[inside, 1], ij[inside, 0]]
    return out


#: Observed outline points within this many pixels (at the masks' resolution) of
#: an unknown pixel are dropped: that stretch of outline is the occluder's edge.
UNKNOWN_MARGIN_PX = 2


def prepare_contours(
    cameras: CameraGroup,
    masks: Sequence[np.ndarray] | np.ndarray,
    scale: float,
    max_points: int = 400,
    unknown: Sequence[np.ndarray | None] | None = None,
) -> ContourObservation:
    """Boundary points of the observed silhouettes at the working scale.

    Every view is handled at its own camera's size (a rig may mix sizes); the
    points, normals and visibility rasters are per view.

    Parameters
    ----------
    cameras : CameraGroup
    masks : sequence of C (H_c, W_c) bool, or (C, H, W) bool
        Observed silhouettes, each at its camera's resolution; an all-False
        mask leaves the view out.
    scale : float
    max_points : int
        Evenly spread subset kept per view.
    unknown : sequence of C ((H_c, W_c) bool or None), optional
        Per view, pixels that are neither the person's nor background (someone
        nearer covers them): the observed outline points bordering them
        (within :data:`UNKNOWN_MARGIN_PX`) are dropped, and the model's outline
        points that fall on them are left unpaired by the refinement.

    Raises
    ------
    ValueError
        If the masks (or unknown masks) do not match the cameras in number or size.
    """
    masks = cameras.check_masks(masks)
    hidden = unknown_masks(cameras, unknown)
    small = cameras.scaled(scale)
    points, normals, trees = [], [], []
    for mask, u in zip(masks, hidden, strict=True):
        p = outline_samples(mask, max_points)
        if u is not None and len(p):
            p = p[~near_region(u, p, UNKNOWN_MARGIN_PX)]
        normals.append(outline_normals(mask, p))
        # Pixel centres map as x' = (x + 0.5) s - 0.5 (see Camera.scaled).
        points.append((p + 0.5) * scale - 0.5)
        trees.append(cKDTree(points[-1]) if len(p) >= 10 else None)
    small_unknown = (
        [
            None if u is None else downscale_mask(u, cam.size)
            for u, cam in zip(hidden, small, strict=True)
        ]
        if any(u is not None for u in hidden)
        else []
    )
    return ContourObservation(
        small, cameras.centers, points, normals, trees, cameras, small_unknown
    )


def near_region(region: np.ndarray, points: np.ndarray, r: int) -> np.ndarray:
    """(P,) bool: which outline points (P, 2) (x, y, between pixel centres) lie within
    ``r`` pixels of a ``region`` (H, W) pixel (the unknown pixels someone covers, the
    clothing)."""
    near = cv2.dilate(region.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8)) > 0
    h, w = near.shape
    # A point between two pixels borders both: test the pixels on either side.
    out = np.zeros(len(points), bool)
    for f in (np.floor, np.ceil):
        x = np.clip(f(points[:, 0]).astype(int), 0, w - 1)
        y = np.clip(f(points[:, 1]).astype(int), 0, h - 1)
        out |= near[y, x]
    return out


def outline_samples(mask: np.ndarray, max_points: int) -> np.ndarray:
    """At most ``max_points`` of a mask's :func:`boundary_points`, evenly spread
    along their list (the observed outline and the model's own, for
    :class:`RefineConfig.outline_offsets`, are sampled alike).

    Returns
    -------
    (P, 2) float
        ``(x, y)`` pixels, ``P <= max_points``.
    """
    p = boundary_points(mask)
    if len(p) > max_points:
        p = p[np.linspace(0, len(p) - 1, max_points).round().astype(int)]
    return p


def outline_normals(mask: np.ndarray, points: np.ndarray, smooth_px: float = 2.0) -> np.ndarray:
    """Outward unit normals of a mask's outline at given points.

    Parameters
    ----------
    mask : (H, W) bool
    points : (P, 2) float
        ``(x, y)`` pixels, e.g. from :func:`boundary_points`.
    smooth_px : float
        Gaussian smoothing of the mask before taking its gradient (pixels).

    Returns
    -------
    (P, 2) float
        Minus the normalized gradient of the smoothed mask (zero where flat).
    """
    soft = cv2.GaussianBlur(np.asarray(mask, np.float32), (0, 0), smooth_px)
    gy, gx = np.gradient(soft)
    rc = np.asarray(points, float).reshape(-1, 2)[:, ::-1].T  # (row, col) for map_coordinates
    n = -np.c_[map_coordinates(gx, rc, order=1), map_coordinates(gy, rc, order=1)].astype(float)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def occluding_contour(
    vertices: np.ndarray,
    faces: np.ndarray,
    edges: np.ndarray,
    edge_faces: np.ndarray,
    camera: Camera,
    center: np.ndarray,
    silhouette: np.ndarray | None = None,
    frames: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Edges on the visible outline of a mesh seen by one camera.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (T, 3) int
    edges, edge_faces : from :func:`mesh_edges`
    camera : Camera
        At the working resolution.
    center : (3,) float
        Camera centre.
    silhouette : (H, W) bool, optional
        The silhouette that decides visibility (default: the mesh's own,
        rasterized here). A coarser mesh of the same body gives the same
        answer at a fraction of the cost (the full mesh's contour lies within
        a fraction of a pixel of its level of detail's).
    frames : ((T, 3), (T, 3)) float, optional
        :func:`face_frames` of the mesh, when the caller has them (they do not
        depend on the camera).

    Returns
    -------
    (K,) int
        Indices into ``edges`` of the contour-generator edges whose projected
        midpoint lies on the boundary of the silhouette (within one pixel of
        the outside).
    """
    kernels = compiled_likelihood()
    if kernels is not None:
        # One compiled pass (it takes the face frames from the vertices itself).
        topology = contour_topology(faces, edges, edge_faces, len(vertices))
        return contour_ids(
            kernels, vertices, topology, camera, camera_arrays([camera]), center, silhouette
        )
    normal, centroid = face_frames(vertices, faces) if frames is None else frames
    facing = np.einsum("ij,ij->i", normal, centroid - center) < 0
    generator = np.nonzero(facing[edge_faces[:, 0]] != facing[edge_faces[:, 1]])[0]
    ends = edges[generator]
    if silhouette is None:
        pixels = camera.project(vertices)
        mask = fill_silhouette(pixels, faces, camera.size)
        mid = 0.5 * (pixels[ends[:, 0]] + pixels[ends[:, 1]])
    else:
        # Only the contour edges' ends need projecting (a full mesh has 13k vertices).
        mask = silhouette
        p = camera.project(vertices[ends.reshape(-1)]).reshape(-1, 2, 2)
        mid = 0.5 * (p[:, 0] + p[:, 1])
    w, h = camera.size
    ij = np.round(np.nan_to_num(mid, nan=-1.0)).astype(int)
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
    keep = np.zeros(len(generator), bool)
    keep[ok] = near_outside(mask, ij[ok])
    return generator[keep]


@dataclass(frozen=True)
class ContourTopology:
    """A mesh's ``faces, edges, edge_faces`` as the contour kernel takes them
    (C-ordered int64), checked once to index ``n_vertices`` vertices and the faces."""

    faces: np.ndarray
    edges: np.ndarray
    edge_faces: np.ndarray
    n_vertices: int


def contour_topology(
    faces: np.ndarray, edges: np.ndarray, edge_faces: np.ndarray, n_vertices: int
) -> ContourTopology:
    """Check and convert a mesh's topology for :func:`contour_ids`.

    Raises
    ------
    IndexError
        For an index out of range (the kernel does not check).
    """
    i64 = [np.require(a, np.int64, ["C", "W"]) for a in (faces, edges, edge_faces)]
    for name, a, n in zip(
        ("faces", "edges", "edge_faces"), i64, (n_vertices, n_vertices, len(faces)), strict=True
    ):
        if a.size and (a.min() < 0 or a.max() >= n):
            raise IndexError(f"occluding_contour: {name} out of range for {n} entries")
    return ContourTopology(i64[0], i64[1], i64[2], int(n_vertices))


def contour_ids(
    kernels: ModuleType,
    vertices: np.ndarray,
    topology: ContourTopology,
    camera: Camera,
    arrays: tuple[np.ndarray, ...],
    center: np.ndarray,
    silhouette: np.ndarray | None,
) -> np.ndarray:
    """:func:`occluding_contour` by the compiled kernel, from a checked
    :func:`contour_topology` and the camera's :func:`camera_arrays` (a caller
    finding the contour of one mesh many times prepares both once).

    Raises
    ------
    IndexError
        When ``vertices`` are not the ``topology.n_vertices`` it was checked for.
    """
    if len(vertices) != topology.n_vertices:
        raise IndexError(
            f"occluding_contour: {len(vertices)} vertices, the topology indexes "
            f"{topology.n_vertices}"
        )
    if silhouette is None:
        silhouette = fill_silhouette(camera.project(vertices), topology.faces, camera.size)
    out = np.empty(len(topology.edges), np.int64)
    n = kernels.contour_kernel(
        np.require(vertices, np.float64, ["C", "W"]), topology.faces,
        np.asarray(center, np.float64), topology.edges, topology.edge_faces,
        np.require(silhouette, np.bool_, ["C", "W"]), *arrays, out,
    )  # fmt: skip
    return out[:n]


def near_outside(mask: np.ndarray, ij: np.ndarray) -> np.ndarray:
    """Whether pixels lie within one pixel of a mask's outside.

    The same answer as ``cv2.distanceTransform(mask, DIST_L2, 3)[y, x] <= 1``
    (the 3x3 mask's steps are 0.955 across an edge and 1.3693 across a corner,
    and the image border is not outside), from the pixel and its four
    neighbours instead of a transform of the whole image.

    Parameters
    ----------
    mask : (H, W) bool
    ij : (K, 2) int
        ``(x, y)`` pixels inside the image.

    Returns
    -------
    (K,) bool
    """
    m = np.asarray(mask, dtype=bool)
    h, w = m.shape
    x, y = ij[:, 0], ij[:, 1]
    out = ~m[y, x]
    for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        xx, yy = x + dx, y + dy
        inside = (xx >= 0) & (xx < w) & (yy >= 0) & (yy < h)
        out |= inside & ~m[np.clip(yy, 0, h - 1), np.clip(xx, 0, w - 1)]
    return out


def face_frames(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unnormalized normals (T, 3) and centroids (T, 3) of a mesh's triangles."""
    v0, v1, v2 = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    return np.cross(v1 - v0, v2 - v0), (v0 + v1 + v2) / 3.0
