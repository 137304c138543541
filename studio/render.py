"""Rendering of the synthetic capture studio: camera images with ground truth.

Pipeline of :meth:`Studio.render_frame` for one camera:

1. The body mesh is projected *with* the camera's lens distortion and rasterized
   by :func:`rasterize`, a vectorized numpy z-buffer (no per-triangle Python
   loop). Body triangles are small (a few pixels), so drawing them with
   straight edges between distorted vertices is exact to far below a pixel;
   no image is resampled, and the person mask is exactly the raster. Other
   bodies (:class:`Body`: bystanders, and the other people of a multi-person
   session, posed anew each frame) go through the same raster and shading into
   the same z-buffer; the person mask keeps the person's visible pixels, and
   :meth:`Studio.render_people` gives every person's visible pixels and whole
   projection (:class:`PeopleFrame`).
2. Room (floor, walls, ceiling) and calibration board are computed analytically
   per output pixel by intersecting the pixel's *undistorted* ray (cached per
   camera) with their planes, with box-filtered procedural textures.
3. Shadows: the casters (bodies, board) are rasterized orthographically from the
   key light into a depth map (a shadow map, 1 cm texels) whose coverage is
   blurred for a soft penumbra; room and board pixels behind a caster in
   light space lose the key light's contribution and keep the ambient, so a
   shadow is darker by a constant factor with unchanged chromaticity.
4. Camera: per-camera constant gain, white balance and vignetting; optical
   blur (Gaussian, σ ≈ 0.7 px); per-frame exposure flicker; sensor noise
   (read noise + shot noise); 8-bit quantization. Compression is the video
   writer's job.

Rays and projection with the lens model are in :mod:`bodymetry.studio.lens`; the
board's visible pixels and texture sampling in :mod:`bodymetry.studio.board_render`.

Coordinates follow docs/design.md: world z up, floor z = 0, metres; cameras OpenCV.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
import scipy.sparse as sp

from bodymetry.calibration.camera import Camera
from bodymetry.estimation.body_model.skeleton import PARTS
from bodymetry.estimation.raster import Raster, rasterize
from bodymetry.studio.board_render import (
    BoardSheet,
    board_albedo,
    board_hits,
    board_region,
    sample_image,
    texture_footprint,
)
from bodymetry.studio.lens import lens_radius_limit, pixel_rays, project_for_raster
from bodymetry.studio.scene import (
    Appearance,
    BoardPose,
    BoardTexture,
    Light,
    Room,
)

# =============================================================================
# Per-camera cache keys; body coverage on the output grid
# =============================================================================


def _camera_key(camera: Camera) -> tuple:
    return (
        camera.name,
        camera.size,
        camera.K.tobytes(),
        camera.dist.tobytes(),
        camera.R.tobytes(),
        camera.t.tobytes(),
    )


def _bbox_mean(
    flags: np.ndarray, py: np.ndarray, px: np.ndarray, s: int, w: int, h: int
) -> np.ndarray:
    """Average values on covered sub-pixels into output pixels, within their bounding box.

    Parameters
    ----------
    flags : (N,) or (N, C) float32
        Value of each covered sub-pixel (uncovered sub-pixels count as 0).
    py, px : (N,) int
        Sub-pixel rows and columns on the ``(H*s, W*s)`` grid.
    s, w, h : int
        Supersampling factor and output image size.

    Returns
    -------
    (H*W,) or (H*W, C) float32
    """
    extra = flags.shape[1:]
    out = np.zeros((h * w, *extra), np.float32)
    if py.size == 0:
        return out
    by0, by1 = int(py.min()) // s, int(py.max()) // s + 1
    bx0, bx1 = int(px.min()) // s, int(px.max()) // s + 1
    bh, bw = by1 - by0, bx1 - bx0
    local = (py - by0 * s) * (bw * s) + (px - bx0 * s)
    grid = np.zeros((bh * s * bw * s, *extra), np.float32)
    grid[local] = flags
    out.reshape(h, w, *extra)[by0:by1, bx0:bx1] = grid.reshape(bh, s, bw, s, *extra).mean(
        axis=(1, 3)
    )
    return out


def _downsample_bodies(
    pixels: np.ndarray,
    depth: np.ndarray,
    rad: np.ndarray,
    owner: np.ndarray,
    n_tracked: int,
    s: int,
    w: int,
    h: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Average the supersampled raster of the bodies into output pixels, touching
    only its bounding box.

    Parameters
    ----------
    pixels : (N,) int
        Covered sub-pixels (flat indices into the ``(H*s, W*s)`` grid).
    depth : (H*s, W*s) float32
        Nearest body depth per sub-pixel (inf: none).
    rad : (N, 3) float32
        Radiance of each covered sub-pixel.
    owner : (N,) int
        The body each covered sub-pixel shows (index into the rendered bodies).
    n_tracked : int
        Bodies ``0 .. n_tracked - 1`` get their own coverage (the people whose
        masks are wanted; bystanders after them do not).
    s, w, h : int
        Supersampling factor and output image size.

    Returns
    -------
    cov : (H*W,) float32
        Coverage by any body.
    tracked_cov : (n_tracked, H*W) float32
        Coverage by each tracked body (its visible part).
    out : (H*W, 3) float32
        Coverage-weighted radiance.
    near : (H*W,) float32
        Nearest depth (inf where no body).
    """
    tracked_cov = np.zeros((n_tracked, h * w), np.float32)
    if s == 1:
        cov = np.zeros(h * w, np.float32)
        out = np.zeros((h * w, 3), np.float32)
        cov[pixels] = 1.0
        out[pixels] = rad
        for k in range(n_tracked):
            tracked_cov[k, pixels[owner == k]] = 1.0
        return cov, tracked_cov, out, depth.reshape(-1)
    ws = w * s
    py, px = pixels // ws, pixels % ws
    # One pass over the box: coverage, radiance and each tracked body's coverage.
    flags = np.concatenate(
        [
            np.ones((pixels.size, 1), np.float32),
            rad.astype(np.float32),
            (owner[:, None] == np.arange(n_tracked)[None]).astype(np.float32),
        ],
        axis=1,
    )
    mean = _bbox_mean(flags, py, px, s, w, h)
    near = np.full(h * w, np.inf, np.float32)
    if pixels.size:
        by0, by1 = int(py.min()) // s, int(py.max()) // s + 1
        bx0, bx1 = int(px.min()) // s, int(px.max()) // s + 1
        sub_depth = depth[by0 * s : by1 * s, bx0 * s : bx1 * s]
        near.reshape(h, w)[by0:by1, bx0:bx1] = sub_depth.reshape(by1 - by0, s, bx1 - bx0, s).min(
            axis=(1, 3)
        )
    tracked_cov[:] = mean[:, 4:].T
    return mean[:, 0].copy(), tracked_cov, mean[:, 1:4].copy(), near


def _coverage(pixels: np.ndarray, s: int, w: int, h: int) -> np.ndarray:
    """(H*W,) float32 coverage of output pixels by sub-pixels ``pixels`` of the
    ``(H*s, W*s)`` grid."""
    if s == 1:
        cov = np.zeros(h * w, np.float32)
        cov[pixels] = 1.0
        return cov
    ws = w * s
    return _bbox_mean(np.ones(pixels.size, np.float32), pixels // ws, pixels % ws, s, w, h)


# =============================================================================
# Studio
# =============================================================================


@dataclass(frozen=True)
class Effects:
    """Camera and sensor effects. All noise is drawn from the ``rng`` passed
    to a render call; per-camera constants come from ``seed`` and the camera name.

    Attributes
    ----------
    exposure : float
        Digital numbers per unit radiance (albedo x irradiance).
    blur_sigma : float
        Optical blur, pixels (Gaussian σ; 0 = none).
    read_noise : float
        Gaussian sensor noise σ, DN.
    shot_noise : float
        Photon noise: variance per DN of signal (σ² = read² + shot·I).
    flicker : float
        Relative σ of the per-frame exposure (gain) fluctuation.
    camera_gain_spread : float
        Relative σ of each camera's constant gain.
    white_balance_spread : float
        Relative σ of each camera's constant per-channel gain.
    vignetting : float
        Relative fall-off at the image corners (cos⁴-like, quadratic in radius).
    seed : int
        Seed of the per-camera constants.
    """

    exposure: float = 235.0
    blur_sigma: float = 0.7
    read_noise: float = 2.5
    shot_noise: float = 0.03
    flicker: float = 0.012
    camera_gain_spread: float = 0.025
    white_balance_spread: float = 0.012
    vignetting: float = 0.12
    seed: int = 0


class Frame(NamedTuple):
    """One rendered camera image with its ground truth.

    Attributes
    ----------
    image : (H, W, 3) uint8
        BGR image.
    person_mask : (H, W) bool
        Pixels where the person is visible (the raster that made the image).
    shadow_mask : (H, W) bool
        Non-person pixels (room, board) darkened by more than half of the
        full shadow: the person's and the board's cast shadows.
    """

    image: np.ndarray
    person_mask: np.ndarray
    shadow_mask: np.ndarray


class Body(NamedTuple):
    """Another person in the room: rendered, shaded and shadowed like the subject and
    z-buffered against it. As one of ``others`` (a bystander) it is never part of a
    mask; as one of ``people`` (:meth:`Studio.render_people`) it gets its own. The
    caller passes each frame's vertices, so a body may move from frame to frame.

    Attributes
    ----------
    vertices : (V, 3) float
        Posed vertices of the studio's mesh, world metres.
    appearance : Appearance or None
        Clothing colours (the studio's own when None); the per-vertex modulation
        (fabric variation, hair) is the studio's.
    """

    vertices: np.ndarray
    appearance: Appearance | None = None


class PeopleFrame(NamedTuple):
    """One rendered camera image of several people with each one's ground truth.

    Person 0 is the subject (``masks[0]`` equals :attr:`Frame.person_mask` of the
    same scene); persons 1.. are the ``people`` of :meth:`Studio.render_people`.

    Attributes
    ----------
    image : (H, W, 3) uint8
        BGR image.
    masks : (P, H, W) bool
        Each person's visible pixels; no pixel belongs to two persons.
    full : (P, H, W) bool
        Each person's whole projection, as if alone in the room (``masks[k]`` is
        inside ``full[k]``).
    shadow_mask : (H, W) bool
        As :attr:`Frame.shadow_mask` (no body's pixels).
    """

    image: np.ndarray
    masks: np.ndarray
    full: np.ndarray
    shadow_mask: np.ndarray

    @property
    def occluded(self) -> np.ndarray:
        """(P, H, W) bool: pixels of each person's whole projection that another
        person's visible pixels cover (where that person is hidden by someone)."""
        union = self.masks.any(axis=0)
        return self.full & union[None] & ~self.masks


class BoardFrame(NamedTuple):
    """:class:`Frame` plus the pixels where the calibration board is visible."""

    image: np.ndarray
    person_mask: np.ndarray
    shadow_mask: np.ndarray
    board_mask: np.ndarray


class _Rendered(NamedTuple):
    """What :meth:`Studio._render` makes of one camera image.

    Attributes
    ----------
    image : (H, W, 3) uint8
    person, shadow, board : (H, W) bool
        Where the subject is, where a shadow falls on the scene (not on a body),
        where the board is.
    visible : (P, H, W) bool
        Each tracked person's visible pixels (the subject first; P = 0 without one).
    full : (P, H, W) bool or None
        Each tracked person's whole projection (None unless asked for).
    """

    image: np.ndarray
    person: np.ndarray
    shadow: np.ndarray
    board: np.ndarray
    visible: np.ndarray
    full: np.ndarray | None


@dataclass
class _CameraCache:
    rays_world: np.ndarray  # (H*W, 3) world directions (camera depth = ray parameter)
    r_limit: float
    bg_ambient: np.ndarray  # (H*W, 3) float32 radiance from the ambient light
    bg_direct: np.ndarray  # (H*W, 3) float32 radiance from the key light (unshadowed)
    bg_light: np.ndarray  # (3, H*W) float32 light-space coordinates of the room pixels
    camera_gain: np.ndarray  # (H, W, 3) float32 exposure x vignetting x gain x white balance


@dataclass
class _ShadowMap:
    origin: np.ndarray  # (2,) light-space x, y of texel (0, 0)'s centre
    texel: float
    coverage: np.ndarray  # (h, w) float32, blurred occupancy
    zmin: np.ndarray  # (h, w) float32, min-filtered caster depth


@dataclass
class _Layers:
    """What one render has drawn before shadows and compositing (None: not drawn).

    Attributes
    ----------
    body_cov : (H*W,) float32
        Coverage by any body.
    tracked_cov : (P, H*W) float32
        Visible coverage of each tracked person (the subject first).
    full_cov : (P, H*W) float32
        Coverage of each tracked person's own raster (as if alone; only when asked).
    person_rad : (H*W, 3) float32
        Radiance x coverage of the bodies.
    person_depth : (H*W,) float32
        Nearest body depth (inf where none).
    board_px : (N,) int
        Pixels where the board is visible.
    board_rad : (N, 3) float32
        Their albedo.
    board_light : (3, N) float32
        Their light-space coordinates.
    board_side_direct : ((N,) float32, (N,) float32)
        Ambient and direct irradiance of the board's visible side.
    """

    body_cov: np.ndarray | None = None
    tracked_cov: np.ndarray | None = None
    full_cov: np.ndarray | None = None
    person_rad: np.ndarray | None = None
    person_depth: np.ndarray | None = None
    board_px: np.ndarray | None = None
    board_rad: np.ndarray | None = None
    board_light: np.ndarray | None = None
    board_side_direct: tuple[np.ndarray, np.ndarray] | None = None


class Studio:
    """The synthetic lab: room, light, subject appearance and camera effects.

    Parameters
    ----------
    faces : (T, 3) int
        The body mesh's triangles (outward, counter-clockwise).
    face_parts : (T,) int
        Body part of each triangle (order of ``skeleton.PARTS``), for colours.
    room, light, appearance, effects : optional
        Scene description; defaults give a 6 x 6 m lab with a key light at 52°
        elevation.
    vertex_modulation : (V, 3) float, optional
        Per-vertex albedo modulation (see ``Appearance.vertex_modulation``);
        default: computed from ``appearance`` without hair.
    shadows : bool
        Cast shadows of the person and the board.
    shadow_texel : float
        Shadow-map texel size, metres.
    supersample : int
        Rasterize the body on an ``s``-times finer grid and average (1 = off;
        edges are then softened by the optical blur only).
    """

    def __init__(
        self,
        faces: np.ndarray,
        face_parts: np.ndarray,
        *,
        room: Room | None = None,
        light: Light | None = None,
        appearance: Appearance | None = None,
        effects: Effects | None = None,
        vertex_modulation: np.ndarray | None = None,
        shadows: bool = True,
        shadow_texel: float = 0.01,
        supersample: int = 1,
    ) -> None:
        faces = np.asarray(faces, dtype=np.int64)
        face_parts = np.asarray(face_parts, dtype=np.int64).reshape(-1)
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(f"Studio: faces must have shape (T, 3), got {faces.shape}")
        if face_parts.shape[0] != faces.shape[0]:
            raise ValueError(
                f"Studio: face_parts must have {faces.shape[0]} entries, got {face_parts.shape[0]}"
            )
        if int(supersample) < 1:
            raise ValueError(f"Studio: supersample must be >= 1, got {supersample}")
        if shadow_texel <= 0:
            raise ValueError(f"Studio: shadow_texel must be > 0, got {shadow_texel}")
        self.faces = faces
        self.face_parts = face_parts
        self.n_vertices = int(faces.max()) + 1
        self.room = room or Room()
        self.light = light or Light()
        self.appearance = appearance or Appearance()
        self.effects = effects or Effects()
        self.shadows = bool(shadows)
        self.shadow_texel = float(shadow_texel)
        self.supersample = int(supersample)
        self.face_albedo = self.appearance.face_albedo(face_parts).astype(np.float32)
        if vertex_modulation is None:
            vertex_modulation = self.appearance.vertex_modulation(faces, self.n_vertices)
        vm = np.asarray(vertex_modulation, dtype=np.float32)
        if vm.shape != (self.n_vertices, 3):
            raise ValueError(
                f"Studio: vertex_modulation must have shape ({self.n_vertices}, 3), got {vm.shape}"
            )
        self.vertex_modulation = vm
        # Vertex normal = sum of adjacent (area-weighted) face normals.
        t = faces.shape[0]
        self._face_to_vertex = sp.csr_matrix(
            (np.ones(3 * t), (faces.reshape(-1), np.repeat(np.arange(t), 3))),
            shape=(self.n_vertices, t),
        )
        self._light_R = self.light.frame()
        self._cache: dict[tuple, _CameraCache] = {}
        self._r_limits: dict[tuple, float] = {}

    @classmethod
    def from_model(cls, model, **kwargs) -> Studio:
        """A studio for ``estimation.body_model.BodyModel``'s full mesh, with hair."""
        appearance = kwargs.pop("appearance", None) or Appearance()
        faces = model.faces()
        face_parts = model.full.arrays.parts
        rest = model.canonical_vertices(np.zeros((1, model.n_shape)))[0]
        head = PARTS.index("head")
        head_vertices = np.unique(faces[face_parts == head])
        mod = appearance.vertex_modulation(
            faces,
            rest.shape[0],
            rest_vertices=rest,
            head_vertices=head_vertices,
            skin_color=np.asarray(appearance.part_colors)[head],
        )
        return cls(faces, face_parts, appearance=appearance, vertex_modulation=mod, **kwargs)

    # --- public API -----------------------------------------------------------------
    def render_frame(
        self,
        camera: Camera,
        vertices: np.ndarray | None,
        rng: np.random.Generator | int | None = None,
        *,
        effects: bool = True,
        others: Sequence[Body] = (),
    ) -> Frame:
        """Render the person (or the empty room if ``vertices`` is None).

        Parameters
        ----------
        camera : Camera
        vertices : (V, 3) float or None
            Posed body vertices, world metres.
        rng : Generator or int
            Source of the per-frame flicker and noise (required when ``effects``).
        effects : bool
            False: no blur, flicker or noise (the clean frame used to check masks);
            per-camera gain, white balance and vignetting stay.
        others : sequence of Body
            Bystanders: rendered through the same raster, shading and shadow map as
            the person and z-buffered against it; the person mask stays the
            person's visible pixels, the shadow mask excludes every body.

        Returns
        -------
        Frame
        """
        out = self._render(camera, vertices, None, rng, effects, others)
        return Frame(out.image, out.person, out.shadow)

    def render_people(
        self,
        camera: Camera,
        vertices: np.ndarray,
        rng: np.random.Generator | int | None = None,
        *,
        people: Sequence[Body] = (),
        effects: bool = True,
        others: Sequence[Body] = (),
    ) -> PeopleFrame:
        """Render the subject and other people, with each one's visible and whole masks.

        Everyone goes through the same raster, z-buffer, shading and shadow map as
        :meth:`render_frame`; with no ``people`` the image and ``masks[0]`` are
        those of :meth:`render_frame`.

        Parameters
        ----------
        camera : Camera
        vertices : (V, 3) float
            The subject's posed vertices (person 0).
        rng : Generator or int
            As :meth:`render_frame`.
        people : sequence of Body
            Persons 1.. at this frame (their own clothes).
        effects : bool
            As :meth:`render_frame`.
        others : sequence of Body
            Bystanders: drawn, in no person's mask.

        Returns
        -------
        PeopleFrame
        """
        if vertices is None:
            raise ValueError("render_people: the subject's vertices are required")
        out = self._render(
            camera, vertices, None, rng, effects, [*people, *others], len(people), True
        )
        return PeopleFrame(out.image, out.visible, out.full, out.shadow)

    def render_background(
        self,
        camera: Camera,
        rng: np.random.Generator | int | None = None,
        *,
        effects: bool = True,
    ) -> np.ndarray:
        """(H, W, 3) uint8 BGR image of the empty room (same light, camera, noise model)."""
        return self._render(camera, None, None, rng, effects).image

    def render_board(
        self,
        camera: Camera,
        board: BoardTexture,
        pose: BoardPose,
        rng: np.random.Generator | int | None = None,
        *,
        vertices: np.ndarray | None = None,
        effects: bool = True,
    ) -> BoardFrame:
        """Render a calibration board at ``pose`` (and the person, if given).

        The board is z-tested against the person, casts a shadow, and receives
        the person's shadow.
        """
        if not isinstance(board, BoardTexture):
            raise ValueError(f"render_board: board must be a BoardTexture, got {type(board)}")
        if not isinstance(pose, BoardPose):
            raise ValueError(f"render_board: pose must be a BoardPose, got {type(pose)}")
        out = self._render(
            camera, vertices, BoardSheet(board, pose, self._mips(board)), rng, effects
        )
        return BoardFrame(out.image, out.person, out.shadow, out.board)

    def person_raster(self, camera: Camera, vertices: np.ndarray) -> Raster:
        """The body's raster in ``camera`` (distorted image, no supersampling)."""
        xy, z, valid = project_for_raster(camera, vertices, 1, self._r_limit(camera))
        return rasterize(xy, z, self.faces, camera.size, cull="back", valid=valid)

    # --- caches -----------------------------------------------------------------------
    def _mips(self, board: BoardTexture) -> list[np.ndarray]:
        cached = getattr(self, "_mip_cache", None)
        if cached is None or cached[0] is not board:
            self._mip_cache = (board, board.mipmaps())
        return self._mip_cache[1]

    def _r_limit(self, camera: Camera) -> float:
        """The lens model's valid normalized radius (from the image border's rays)."""
        key = _camera_key(camera)
        if key in self._cache:
            return self._cache[key].r_limit
        hit = self._r_limits.get(key)
        if hit is None:
            hit = lens_radius_limit(camera)
            self._r_limits[key] = hit
        return hit

    def _camera(self, camera: Camera) -> _CameraCache:
        key = _camera_key(camera)
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        w, h = camera.size
        rays = pixel_rays(camera)
        rays_world = rays @ camera.R  # R.T @ ray for each ray
        origin = camera.center
        tpar, surface = self.room.intersect(origin, rays_world)
        pts = origin + tpar[..., None] * rays_world
        # Footprint (metres per pixel) of each pixel on its surface.
        dx = np.zeros_like(tpar)
        for axis in (0, 1):
            g = np.gradient(pts, axis=axis)
            dx = np.maximum(dx, np.linalg.norm(g, axis=-1))
        # Across a surface edge the gradient is meaningless; use the ray-based estimate.
        est = tpar * np.linalg.norm(rays_world, axis=-1) / camera.K[0, 0]
        dx = np.where(dx > 4 * est, est, dx)
        albedo = self.room.albedo(pts, surface, dx)
        normals = self.room.normals()[surface]
        amb, direct = self.light.irradiance(normals)
        col = np.asarray(self.light.color)
        emit = self.room.emission(pts, surface, dx)
        lit = albedo * amb[..., None] * (1.0 - np.minimum(emit, 1.0))[..., None] + emit[..., None]
        bg_amb = (lit * col).reshape(-1, 3).astype(np.float32)
        bg_dir = (albedo * direct[..., None] * col).reshape(-1, 3).astype(np.float32)
        bg_light = (pts.reshape(-1, 3) @ self._light_R.T).T.astype(np.float32).copy()
        # Per-camera constants.
        crng = np.random.default_rng([self.effects.seed, zlib.crc32(camera.name.encode())])
        gain = 1.0 + self.effects.camera_gain_spread * crng.standard_normal()
        wb = 1.0 + self.effects.white_balance_spread * crng.standard_normal(3)
        cx, cy = camera.K[0, 2], camera.K[1, 2]
        yy, xx = np.mgrid[0:h, 0:w]
        rr = ((xx - cx) ** 2 + (yy - cy) ** 2) / (0.25 * (w * w + h * h))
        vig = 1.0 - self.effects.vignetting * np.clip(rr, 0, 1.5)
        cam_gain = (self.effects.exposure * gain * vig[..., None] * wb).astype(np.float32)
        entry = _CameraCache(
            rays_world.reshape(-1, 3),
            self._r_limit(camera),
            bg_amb,
            bg_dir,
            bg_light,
            cam_gain,
        )
        self._cache[key] = entry
        return entry

    # --- shadows ------------------------------------------------------------------
    def _shadow_maps(
        self, casters: list[tuple[np.ndarray, np.ndarray, str]]
    ) -> tuple[np.ndarray, float, list[np.ndarray]]:
        """Orthographic depth maps, one per caster, on a grid shared by all.

        Parameters
        ----------
        casters : list of (vertices (N, 3), faces (T, 3), cull)

        Returns
        -------
        origin : (2,) float
            Light-space x, y of texel (0, 0)'s centre.
        texel : float
        depths : list of (h, w) float32
            Nearest light-space depth per texel (inf: no caster).
        """
        lr = self._light_R
        q_all = [v @ lr.T for v, _, _ in casters]
        tau = self.shadow_texel
        sig = self.light.penumbra / tau
        pad = int(np.ceil(3 * sig)) + 2
        lo = np.min([q[:, :2].min(0) for q in q_all], axis=0)
        hi = np.max([q[:, :2].max(0) for q in q_all], axis=0)
        origin = np.floor(lo / tau) * tau - pad * tau
        size = (np.ceil((hi - origin) / tau).astype(int) + pad + 1).tolist()
        if size[0] * size[1] > 16_000_000:
            raise ValueError(
                f"shadow map of {size[0]}x{size[1]} texels: casters too large for "
                f"shadow_texel={tau}"
            )
        depths = []
        for q, (_, f, cull) in zip(q_all, casters, strict=True):
            r = rasterize(
                (q[:, :2] - origin) / tau, q[:, 2], f, tuple(size), perspective=False, cull=cull
            )
            depths.append(r.depth)
        return origin, tau, depths

    def _finish_shadow_map(self, origin: np.ndarray, tau: float, zmin: np.ndarray) -> _ShadowMap:
        """Soft coverage (blurred occupancy) and min-filtered depth of a depth map."""
        sig = self.light.penumbra / tau
        occ = np.isfinite(zmin).astype(np.float32)
        zfin = np.where(np.isfinite(zmin), zmin, np.float32(1e9)).astype(np.float32)
        if sig > 0:
            k = 2 * int(np.ceil(2 * sig)) + 1
            occ = cv2.GaussianBlur(occ, (0, 0), sig)
            zfin = cv2.erode(zfin, np.ones((k, k), np.uint8))
        return _ShadowMap(origin, tau, occ, zfin)

    @staticmethod
    def _shadow_lookup(smap: _ShadowMap, q: np.ndarray, bias: float = 0.02) -> np.ndarray:
        """Shadow amount in [0, 1] for receivers at light-space coordinates q (3, N)."""
        mx = (q[0] - smap.origin[0]) / smap.texel
        my = (q[1] - smap.origin[1]) / smap.texel
        cov = sample_image(smap.coverage, mx, my, cv2.INTER_LINEAR, 0.0)
        zc = sample_image(smap.zmin, mx, my, cv2.INTER_NEAREST, 1e9)
        return np.where(q[2] > zc + bias, cov, 0.0).astype(np.float32)

    # --- the render -----------------------------------------------------------------
    def _render(
        self,
        camera: Camera,
        vertices: np.ndarray | None,
        board: BoardSheet | None,
        rng: np.random.Generator | int | None,
        effects: bool,
        others: Sequence[Body] = (),
        n_people: int = 0,
        full: bool = False,
    ) -> _Rendered:
        """One image: the bodies, the board, their shadows, composited, then the camera.

        Parameters
        ----------
        others : sequence of Body
            Bodies besides the subject; the first ``n_people`` are tracked persons
            (they get masks), the rest bystanders.
        n_people : int
        full : bool
            Also each tracked person's whole (unoccluded) projection.
        """
        if not isinstance(camera, Camera):
            raise ValueError(
                f"render: camera must be a calibration.camera.Camera, got {type(camera)}"
            )
        if effects:
            if rng is None:
                raise ValueError("render: rng (Generator or int seed) is required with effects")
            rng = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
        cache = self._camera(camera)
        w, h = camera.size
        s = self.supersample

        # --- bodies (the person, then bystanders): one z-buffer, shading -------------------
        bodies = self._bodies(vertices, others)
        # Tracked bodies come first in `bodies`: the subject, then the people.
        n_tracked = 0 if vertices is None else 1 + int(n_people)
        layers = _Layers()
        if bodies:
            pixels, depth, rad, owner, alone = self._raster_bodies(
                camera, cache, bodies, n_tracked if full else 0
            )
            layers.body_cov, layers.tracked_cov, layers.person_rad, layers.person_depth = (
                _downsample_bodies(pixels, depth, rad, owner, n_tracked, s, w, h)
            )
            if full:
                layers.full_cov = np.stack([_coverage(a, s, w, h) for a in alone])

        # --- board: analytic ray-plane intersection --------------------------------------
        if board is not None:
            layers.board_px, layers.board_rad, layers.board_light, layers.board_side_direct = (
                self._board_pixels(camera, cache, board, layers.person_depth)
            )

        shade_bg, shade_board = self._shadows(cache, w * h, bodies, board, layers)
        rad, visible, body_mask, board_mask, shadow_amount = self._composite(
            cache, w * h, layers, shade_bg, shade_board
        )
        person_mask = visible[0] if n_tracked else np.zeros(w * h, bool)
        shadow_mask = (shadow_amount > 0.5) & ~person_mask & ~body_mask
        img = rad.reshape(h, w, 3) * cache.camera_gain
        if effects:
            img = self._camera_effects(img, rng)
        out = np.clip(img + 0.5, 0, 255).astype(np.uint8)
        whole = None
        if full:
            whole = (
                (layers.full_cov >= 0.5).reshape(-1, h, w)
                if layers.full_cov is not None
                else np.zeros((n_tracked, h, w), bool)
            )
        return _Rendered(
            out,
            person_mask.reshape(h, w),
            shadow_mask.reshape(h, w),
            board_mask.reshape(h, w),
            visible.reshape(-1, h, w),
            whole,
        )

    def _shadows(
        self,
        cache: _CameraCache,
        npx: int,
        bodies: list[tuple[np.ndarray, np.ndarray]],
        board: BoardSheet | None,
        layers: _Layers,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Shadow amounts on the background and on the board's visible pixels.

        Returns
        -------
        shade_bg : (H*W,) float32
            Shadow of every caster (bodies and board) on the room.
        shade_board : (N,) float32 or None
            Shadow of the bodies on the board's pixels (None: no board, no body
            or no shadows).
        """
        shade_bg = np.zeros(npx, np.float32)
        shade_board = None
        if not self.shadows:
            return shade_bg, shade_board
        casters = [(v, self.faces, "back") for v, _ in bodies]
        if board is not None:
            corners = board.pose.to_world(board.texture.corners())
            casters.append((corners, np.array([[0, 1, 2], [0, 2, 3]]), "none"))
        if not casters:
            return shade_bg, shade_board
        origin, tau, depths = self._shadow_maps(casters)
        all_map = self._finish_shadow_map(origin, tau, np.minimum.reduce(depths))
        q = cache.bg_light
        hh, ww = all_map.coverage.shape
        sel = np.flatnonzero(
            (q[0] >= origin[0] - tau)
            & (q[0] <= origin[0] + ww * tau)
            & (q[1] >= origin[1] - tau)
            & (q[1] <= origin[1] + hh * tau)
        )
        if sel.size:
            shade_bg[sel] = self._shadow_lookup(all_map, q[:, sel])
        if bodies and layers.board_px is not None and layers.board_px.size:
            person_map = self._finish_shadow_map(
                origin, tau, np.minimum.reduce(depths[: len(bodies)])
            )
            shade_board = self._shadow_lookup(person_map, layers.board_light)
        return shade_bg, shade_board

    def _composite(
        self,
        cache: _CameraCache,
        npx: int,
        layers: _Layers,
        shade_bg: np.ndarray,
        shade_board: np.ndarray | None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Composite the room, the board and the bodies in linear radiance.

        Returns
        -------
        rad : (H*W, 3) float
            Radiance of every pixel.
        visible : (P, H*W) bool
            Each tracked person's visible pixels (coverage >= 0.5; a pixel two
            persons cover by half each goes to the first, so no pixel is shared).
        body_mask, board_mask : (H*W,) bool
        shadow_amount : (H*W,) float32
            Shadow on the room and the board (before the bodies cover it).
        """
        col = np.asarray(self.light.color, dtype=np.float32)
        board_px = layers.board_px
        body_cov, tracked_cov, person_rad = layers.body_cov, layers.tracked_cov, layers.person_rad
        rad = cache.bg_ambient + cache.bg_direct * (1.0 - shade_bg)[:, None]
        shadow_amount = shade_bg.copy()
        board_mask = np.zeros(npx, bool)
        if board_px is not None and board_px.size:
            sb = shade_board if shade_board is not None else np.zeros(board_px.size, np.float32)
            amb_b, dir_b = layers.board_side_direct
            rad[board_px] = layers.board_rad * (amb_b + dir_b * (1.0 - sb))[:, None] * col
            shadow_amount[board_px] = sb
            board_mask[board_px] = True
        n_tracked = 0 if tracked_cov is None else tracked_cov.shape[0]
        visible = np.zeros((n_tracked, npx), bool)
        body_mask = np.zeros(npx, bool)
        if body_cov is not None:
            if board_px is not None and board_px.size:
                # Where the board is in front of a body, the board wins the whole pixel.
                front = np.zeros(npx, bool)
                front[board_px] = True
                body_cov = np.where(front, 0.0, body_cov).astype(np.float32)
                tracked_cov = np.where(front[None], 0.0, tracked_cov).astype(np.float32)
                person_rad = np.where(front[:, None], 0.0, person_rad).astype(np.float32)
            rad = rad * (1.0 - body_cov)[:, None] + person_rad * col
            taken = np.zeros(npx, bool)
            for k in range(n_tracked):
                visible[k] = (tracked_cov[k] >= 0.5) & ~taken
                taken |= visible[k]
            body_mask = body_cov >= 0.5
        return rad, visible, body_mask, board_mask, shadow_amount

    def _camera_effects(self, img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The camera's blur, flicker and noise on an image (H, W, 3) of camera values."""
        ef = self.effects
        if ef.blur_sigma > 0:
            img = cv2.GaussianBlur(img, (0, 0), ef.blur_sigma)
        img = img * np.float32(1.0 + ef.flicker * rng.standard_normal())
        sigma = np.sqrt(ef.read_noise**2 + ef.shot_noise * np.maximum(img, 0.0))
        return img + sigma * rng.standard_normal(img.shape, dtype=np.float32)

    def _bodies(
        self, vertices: np.ndarray | None, others: Sequence[Body]
    ) -> list[tuple[np.ndarray, np.ndarray]]:
        """The bodies to draw as (vertices (V, 3) float64, face albedo (T, 3) float32),
        the person first; every vertex array checked against the mesh."""
        bodies = []
        entries = ([] if vertices is None else [(vertices, None)]) + [
            (b.vertices, b.appearance) for b in others
        ]
        for i, (verts, appearance) in enumerate(entries):
            v = np.asarray(verts, dtype=np.float64)
            if v.shape != (self.n_vertices, 3):
                what = "vertices" if i == 0 and vertices is not None else "others[].vertices"
                raise ValueError(
                    f"render: {what} must have shape ({self.n_vertices}, 3), got {v.shape}"
                )
            albedo = (
                self.face_albedo
                if appearance is None
                else appearance.face_albedo(self.face_parts).astype(np.float32)
            )
            bodies.append((v, albedo))
        return bodies

    def _raster_bodies(
        self,
        camera: Camera,
        cache: _CameraCache,
        bodies: list[tuple[np.ndarray, np.ndarray]],
        n_alone: int = 0,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
        """Rasterize and shade every body on the supersampled grid and keep the nearest.

        Parameters
        ----------
        n_alone : int
            Also return the own raster's sub-pixels of the first ``n_alone`` bodies.

        Returns
        -------
        pixels : (N,) int64
            Covered sub-pixels (flat indices into the ``(H*s, W*s)`` grid).
        depth : (H*s, W*s) float32
            Nearest body depth (inf where none).
        rad : (N, 3) float32
            Radiance (without the light's colour) of the nearest body per sub-pixel.
        owner : (N,) int32
            The nearest body (index into ``bodies``).
        alone : list of (M,) int64
            Sub-pixels each of the first ``n_alone`` bodies covers on its own.
        """
        w, h = camera.size
        s = self.supersample
        depth = None
        owner = None
        rad_full = None
        alone = []
        for k, (v, albedo) in enumerate(bodies):
            xy, z, valid = project_for_raster(camera, v, s, cache.r_limit)
            r = rasterize(xy, z, self.faces, (w * s, h * s), cull="back", valid=valid)
            if k < n_alone:
                alone.append(np.asarray(r.pixels, np.int64))
            rad = self._shade_person(v, r, albedo)
            if depth is None:
                depth = r.depth.copy()
                owner = np.full(depth.size, -1, np.int32)
                owner[r.pixels] = 0
                rad_full = np.zeros((depth.size, 3), np.float32)
                rad_full[r.pixels] = rad
                continue
            flat = depth.reshape(-1)
            nearer = r.depth.reshape(-1)[r.pixels] < flat[r.pixels]
            win = r.pixels[nearer]
            flat[win] = r.depth.reshape(-1)[win]
            owner[win] = k
            rad_full[win] = rad[nearer]
        pixels = np.flatnonzero(owner >= 0)
        return pixels, depth, rad_full[pixels], owner[pixels], alone

    def _shade_person(
        self, v: np.ndarray, r: Raster, face_albedo: np.ndarray | None = None
    ) -> np.ndarray:
        """Radiance (without the light's colour) of a body's covered pixels (N, 3);
        ``face_albedo`` (T, 3): its clothing (default the studio's appearance)."""
        f = self.faces
        fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        vn = self._face_to_vertex @ fn
        vn /= np.linalg.norm(vn, axis=1, keepdims=True) + 1e-12
        tri = r.tri.reshape(-1)[r.pixels]
        fv = f[tri]  # (N, 3)
        b = r.bary.astype(np.float64)
        n = vn[fv[:, 0]] * b[:, 0:1] + vn[fv[:, 1]] * b[:, 1:2] + vn[fv[:, 2]] * b[:, 2:3]
        n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
        mod = self.vertex_modulation
        m = mod[fv[:, 0]] * b[:, 0:1] + mod[fv[:, 1]] * b[:, 1:2] + mod[fv[:, 2]] * b[:, 2:3]
        amb, direct = self.light.irradiance(n)
        alb = (self.face_albedo if face_albedo is None else face_albedo)[tri] * m
        return (alb * (amb + direct)[:, None]).astype(np.float32)

    def _board_pixels(
        self,
        camera: Camera,
        cache: _CameraCache,
        board: BoardSheet,
        person_depth: np.ndarray | None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """Pixels where the board is visible, their albedo (N, 3), light-space
        coordinates (3, N) and (ambient, direct) irradiance of the visible side."""
        tex = board.texture
        empty = (
            np.zeros(0, np.int64),
            np.zeros((0, 3), np.float32),
            np.zeros((3, 0), np.float32),
            (np.zeros(0), np.zeros(0)),
        )
        region = board_region(camera, cache.r_limit, board)
        if region is None:
            return empty
        x0, x1, y0, y1 = region
        ys, xs = np.mgrid[y0 : y1 + 1, x0 : x1 + 1]
        pix = (ys * camera.size[0] + xs).reshape(-1)
        d = cache.rays_world[pix]  # (N, 3)
        lam, p, pb, inside = board_hits(camera, board, d)
        if person_depth is not None:
            inside &= lam < person_depth[pix]
        gh, gw = ys.shape
        u, vv, foot = texture_footprint(tex, pb, gh, gw)
        sel = np.flatnonzero(inside)
        if sel.size == 0:
            return empty
        alb = board_albedo(board, u.reshape(-1)[sel], vv.reshape(-1)[sel], foot[sel])
        # Visible side: the printed side faces -z of the board.
        nrm = board.pose.R[:, 2]
        facing_front = (d[sel] @ nrm) > 0  # ray runs along +z: sees the -z side
        alb = np.where(facing_front, alb, np.float32(tex.back_albedo))
        side_n = np.where(facing_front[:, None], -nrm[None], nrm[None])
        amb, direct = self.light.irradiance(side_n)
        bl = (p[sel] @ self._light_R.T).T.astype(np.float32)
        return (
            pix[sel],
            np.repeat(alb[:, None], 3, axis=1),
            bl,
            (amb.astype(np.float32), direct.astype(np.float32)),
        )
