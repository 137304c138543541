"""What the synthetic studio contains: the lab room, the key light, the subject's
clothing, and a printed ChArUco calibration board.

Everything here is geometry and reflectance (albedo in [0, 1], BGR channel
order); :mod:`bodymetry.studio.render` turns it into camera images.

World frame (docs/design.md): right-handed, z up, floor at z = 0, metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from bodymetry.estimation.body_model.geometry import neighbour_mean
from bodymetry.estimation.body_model.parts import PART_COLORS

# --- light --------------------------------------------------------------------


@dataclass(frozen=True)
class Light:
    """A distant key light plus a sky-like ambient term, both of one colour.

    Because ambient and key share one colour, a cast shadow (ambient only) has
    exactly the chromaticity of the lit surface: it is only darker.

    Attributes
    ----------
    direction : (3,) float
        Unit vector along which the light travels (from the light into the
        room; its z is negative).
    color : (3,) float
        BGR tint of both the key and the ambient light (max 1).
    key : float
        Irradiance of the key light on a surface facing it.
    ambient : float
        Irradiance of the ambient light on an upward-facing surface; a surface
        facing sideways gets ``ambient * (1 - sky_falloff / 2)``, a downward one
        ``ambient * (1 - sky_falloff)``.
    sky_falloff : float
        How much less ambient light reaches surfaces facing down.
    penumbra : float
        Standard deviation of the soft shadow edge, metres (an extended light).
    """

    direction: np.ndarray = field(
        default_factory=lambda: Light.direction_from_angles(azimuth_deg=35.0, elevation_deg=52.0)
    )
    color: np.ndarray = field(default_factory=lambda: np.array([0.93, 0.98, 1.0]))
    key: float = 0.62
    ambient: float = 0.50
    sky_falloff: float = 0.25
    penumbra: float = 0.012

    def __post_init__(self) -> None:
        d = np.asarray(self.direction, dtype=float).reshape(-1)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) < 1e-9:
            raise ValueError(f"Light.direction must be a finite non-zero 3-vector, got {d}")
        d = d / np.linalg.norm(d)
        if d[2] >= -1e-3:
            raise ValueError(f"Light.direction must point downwards (z < 0), got {d.tolist()}")
        c = np.asarray(self.color, dtype=float).reshape(-1)
        if c.shape != (3,) or np.any(c < 0):
            raise ValueError(f"Light.color must be 3 non-negative values, got {c}")
        if self.key < 0 or self.ambient < 0 or self.penumbra < 0:
            raise ValueError("Light.key, Light.ambient and Light.penumbra must be >= 0")
        object.__setattr__(self, "direction", d)
        object.__setattr__(self, "color", c)

    @staticmethod
    def direction_from_angles(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
        """Travel direction of a light standing at ``azimuth`` (from +x towards +y)
        and ``elevation`` above the horizon, (3,)."""
        az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
        towards_light = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        return -towards_light

    def irradiance(self, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ambient and key irradiance on surfaces with unit ``normals`` (..., 3).

        Returns
        -------
        ambient, direct : (...,) float
            Scalars (multiply by ``color``); ``direct`` is what a shadow removes.
        """
        n = np.asarray(normals)
        amb = self.ambient * (1.0 - self.sky_falloff * 0.5 * (1.0 - n[..., 2]))
        direct = self.key * np.maximum(0.0, -(n @ self.direction))
        return amb, direct

    def frame(self) -> np.ndarray:
        """Rotation (3, 3) light_from_world: rows e1, e2, direction (right-handed),
        so light-space z is depth along the light."""
        d = self.direction
        helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = np.cross(helper, d)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(d, e1)
        return np.stack([e1, e2, d])


# --- procedural texture helpers -------------------------------------------------


def _hash01(*ints: np.ndarray, seed: int = 0) -> np.ndarray:
    """Deterministic pseudo-random values in [0, 1) from integer lattice coordinates."""
    h = np.uint64(0x9E3779B97F4A7C15) ^ np.uint64((seed * 0x85EBCA6B + 0x1234567) & (2**64 - 1))
    for k, a in enumerate(ints):
        a64 = np.asarray(a).astype(np.int64).astype(np.uint64)
        h = h ^ (a64 + np.uint64(0x9E3779B97F4A7C15) + np.uint64(k * 0x632BE5AB))
        h = h * np.uint64(0xBF58476D1CE4E5B9)
        h = h ^ (h >> np.uint64(31))
        h = h * np.uint64(0x94D049BB133111EB)
        h = h ^ (h >> np.uint64(29))
    return (h >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def value_noise(u: np.ndarray, v: np.ndarray, seed: int = 0) -> np.ndarray:
    """Smooth 2D value noise in [0, 1) (lattice spacing 1), same shape as ``u``."""
    iu, iv = np.floor(u), np.floor(v)
    fu, fv = u - iu, v - iv
    fu = fu * fu * (3 - 2 * fu)
    fv = fv * fv * (3 - 2 * fv)
    iu, iv = iu.astype(np.int64), iv.astype(np.int64)
    n00 = _hash01(iu, iv, seed=seed)
    n10 = _hash01(iu + 1, iv, seed=seed)
    n01 = _hash01(iu, iv + 1, seed=seed)
    n11 = _hash01(iu + 1, iv + 1, seed=seed)
    return (n00 * (1 - fu) + n10 * fu) * (1 - fv) + (n01 * (1 - fu) + n11 * fu) * fv


def fractal_noise(
    u: np.ndarray, v: np.ndarray, footprint: np.ndarray, octaves: int = 4, seed: int = 0
) -> np.ndarray:
    """Zero-mean fractal noise (about ±0.5) whose octaves finer than the pixel
    ``footprint`` (same units as u, v) fade out, so distant surfaces do not alias."""
    out = np.zeros_like(u)
    amp, freq = 0.5, 1.0
    for o in range(octaves):
        fade = np.clip(1.5 - 2.0 * footprint * freq, 0.0, 1.0)
        out += amp * fade * (value_noise(u * freq, v * freq, seed=seed + 101 * o) - 0.5)
        amp *= 0.5
        freq *= 2.0
    return out


# --- room ----------------------------------------------------------------------

#: Surface ids of :meth:`Room.intersect`.
FLOOR, CEILING, WALL_XMIN, WALL_XMAX, WALL_YMIN, WALL_YMAX = range(6)
SURFACE_NAMES = ("floor", "ceiling", "wall_xmin", "wall_xmax", "wall_ymin", "wall_ymax")


@dataclass(frozen=True)
class WallPanel:
    """A flat rectangle on a wall (door, whiteboard, poster, cabinet).

    ``u`` runs along the wall (metres from the wall's left end seen from inside
    the room), ``z`` is height; the colour is an albedo (BGR, 0..1).
    """

    wall: int
    u: tuple[float, float]
    z: tuple[float, float]
    color: tuple[float, float, float]
    frame: float = 0.0  # width of a darker frame around it, metres


def _default_panels() -> tuple[WallPanel, ...]:
    return (
        WallPanel(WALL_YMAX, (4.1, 5.05), (0.0, 2.1), (0.33, 0.40, 0.47), frame=0.05),  # door
        WallPanel(WALL_XMIN, (1.2, 3.6), (0.9, 2.0), (0.90, 0.91, 0.90), frame=0.03),  # board
        WallPanel(WALL_XMAX, (0.8, 1.6), (1.3, 2.2), (0.55, 0.45, 0.30), frame=0.01),  # poster
        WallPanel(WALL_XMAX, (4.3, 5.4), (0.0, 1.0), (0.42, 0.44, 0.47), frame=0.0),  # cabinet
        WallPanel(WALL_YMIN, (2.2, 3.0), (1.25, 2.0), (0.35, 0.55, 0.62), frame=0.01),  # poster
        WallPanel(WALL_YMIN, (0.3, 1.5), (0.0, 0.75), (0.30, 0.32, 0.36), frame=0.0),  # bench
    )


@dataclass(frozen=True)
class Room:
    """A box-shaped lab room with a tiled floor and painted walls.

    The defaults are the studio's textured lab; the texture amplitudes below set
    to zero (and no panels, no baseboard) give a plain room of flat paint and
    linoleum (:mod:`bodymetry.studio.looks`).

    Attributes
    ----------
    size : (2,) float
        Extent along x and y, metres; the room is centred on ``center``.
    height : float
        Ceiling height, metres.
    center : (2,) float
        Floor-plan centre (x, y).
    tile : float
        Floor tile edge, metres.
    floor_color, wall_color, ceiling_color, baseboard_color : (3,) float
        Albedo (BGR, 0..1).
    panels : tuple of WallPanel
    ceiling_lights : tuple of (x0, x1, y0, y1)
        Glowing light fixtures on the ceiling (world x, y extents, metres;
        by default strips along the walls).
    ceiling_light_radiance : float
        Their radiance, in units of albedo x irradiance (> 1 saturates).
    seed : int
        Seed of the per-tile colour variation and the surface noise.
    tile_tone, tile_hue : float
        Peak-to-peak relative brightness and blue-red tint variation from tile to tile.
    grout_depth : float
        How much the 6 mm grout lines between tiles darken the floor (0: no grout).
    floor_cloud, floor_speckle : float
        Amplitudes of the floor's coarse (0.35 m) and fine (12 mm) relative noise.
    wall_mottle : float
        Amplitude of the walls' low-frequency (0.6 m) relative paint noise.
    baseboard_height : float
        Height of the dark baseboard along the walls, metres (0: none).
    """

    size: tuple[float, float] = (6.0, 6.0)
    height: float = 3.0
    center: tuple[float, float] = (0.0, 0.0)
    tile: float = 0.5
    floor_color: tuple[float, float, float] = (0.50, 0.56, 0.60)
    wall_color: tuple[float, float, float] = (0.74, 0.79, 0.81)
    ceiling_color: tuple[float, float, float] = (0.82, 0.83, 0.83)
    baseboard_color: tuple[float, float, float] = (0.22, 0.23, 0.25)
    panels: tuple[WallPanel, ...] = field(default_factory=_default_panels)
    ceiling_lights: tuple[tuple[float, float, float, float], ...] = (
        (-1.5, 1.5, 2.4, 2.6),
        (-1.5, 1.5, -2.6, -2.4),
        (2.4, 2.6, -1.5, 1.5),
        (-2.6, -2.4, -1.5, 1.5),
    )
    ceiling_light_radiance: float = 1.4
    seed: int = 7
    tile_tone: float = 0.10
    tile_hue: float = 0.04
    grout_depth: float = 0.45
    floor_cloud: float = 0.10
    floor_speckle: float = 0.10
    wall_mottle: float = 0.06
    baseboard_height: float = 0.10

    def __post_init__(self) -> None:
        if len(self.size) != 2 or min(self.size) <= 0 or self.height <= 0:
            raise ValueError(
                f"Room: size and height must be positive, got {self.size}, {self.height}"
            )
        amplitudes = {
            "tile_tone": self.tile_tone,
            "tile_hue": self.tile_hue,
            "grout_depth": self.grout_depth,
            "floor_cloud": self.floor_cloud,
            "floor_speckle": self.floor_speckle,
            "wall_mottle": self.wall_mottle,
        }
        bad = {k: v for k, v in amplitudes.items() if not 0.0 <= v <= 1.0}
        if bad:
            raise ValueError(f"Room: texture amplitudes must be in [0, 1], got {bad}")
        if not 0.0 <= self.baseboard_height < self.height:
            raise ValueError(
                f"Room: baseboard_height must be in [0, {self.height}), got {self.baseboard_height}"
            )

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float: min and max corner of the room box."""
        cx, cy = self.center
        sx, sy = self.size
        return np.array([[cx - sx / 2, cy - sy / 2, 0.0], [cx + sx / 2, cy + sy / 2, self.height]])

    def normals(self) -> np.ndarray:
        """(6, 3) inward unit normal of each surface id."""
        return np.array(
            [[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], dtype=float
        )

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where rays from ``origin`` (inside the room) leave the box.

        Parameters
        ----------
        origin : (3,) float
        dirs : (..., 3) float
            Ray directions (any length).

        Returns
        -------
        t : (...,) float
            Ray parameter of the hit (``origin + t * dirs``).
        surface : (...,) int8
            Surface id (FLOOR, CEILING, WALL_*).
        """
        lo, hi = self.bounds
        o = np.asarray(origin, dtype=float)
        d = np.asarray(dirs, dtype=float)
        ts = []
        with np.errstate(divide="ignore", invalid="ignore"):
            for axis, bound, sign in ((2, lo, -1), (2, hi, 1), (0, lo, -1), (0, hi, 1),
                                      (1, lo, -1), (1, hi, 1)):  # fmt: skip
                comp = d[..., axis]
                t = (bound[axis] - o[axis]) / comp
                ts.append(np.where(sign * comp > 1e-12, t, np.inf))
        t_all = np.stack(ts, axis=-1)
        surface = np.argmin(t_all, axis=-1).astype(np.int8)
        t = np.take_along_axis(t_all, surface[..., None].astype(np.int64), axis=-1)[..., 0]
        return t, surface

    def emission(
        self, points: np.ndarray, surface: np.ndarray, footprint: np.ndarray
    ) -> np.ndarray:
        """Emitted radiance (...,) of the ceiling light fixtures at world ``points``."""
        out = np.zeros(surface.shape, dtype=np.float64)
        m = surface == CEILING
        if not np.any(m) or not self.ceiling_lights:
            return out
        p, f = points[m], np.asarray(footprint, dtype=float)[m]
        cov = np.zeros(p.shape[0])
        for x0, x1, y0, y1 in self.ceiling_lights:
            cx = _coverage(np.abs(p[:, 0] - 0.5 * (x0 + x1)), 0.5 * abs(x1 - x0), f)
            cy = _coverage(np.abs(p[:, 1] - 0.5 * (y0 + y1)), 0.5 * abs(y1 - y0), f)
            cov = np.maximum(cov, cx * cy)
        out[m] = self.ceiling_light_radiance * cov
        return out

    def _wall_uv(self, points: np.ndarray, surface: np.ndarray) -> np.ndarray:
        """Along-wall coordinate u (metres from the left end seen from inside)."""
        lo, hi = self.bounds
        x, y = points[..., 0], points[..., 1]
        u = np.zeros_like(x)
        # Seen from inside, facing the wall: left end is where the wall starts.
        u = np.where(surface == WALL_XMIN, hi[1] - y, u)
        u = np.where(surface == WALL_XMAX, y - lo[1], u)
        u = np.where(surface == WALL_YMIN, x - lo[0], u)
        u = np.where(surface == WALL_YMAX, hi[0] - x, u)
        return u

    def albedo(self, points: np.ndarray, surface: np.ndarray, footprint: np.ndarray) -> np.ndarray:
        """Surface albedo (..., 3) BGR at world ``points`` (..., 3) on ``surface`` (...,),
        filtered for a pixel ``footprint`` (..., metres per pixel)."""
        out = np.empty((*surface.shape, 3), dtype=np.float64)
        fp = np.asarray(footprint, dtype=float)
        seed = self.seed

        # Floor: tiles with per-tile tone, grout lines, fine speckle.
        m = surface == FLOOR
        if np.any(m):
            p, f = points[m], fp[m]
            u, v = p[:, 0] / self.tile, p[:, 1] / self.tile
            iu, iv = np.floor(u), np.floor(v)
            tone = 1.0 + self.tile_tone * (_hash01(iu, iv, seed=seed) - 0.5)
            hue = self.tile_hue * (_hash01(iu, iv, seed=seed + 1) - 0.5)
            col = np.asarray(self.floor_color) * tone[:, None]
            col = col * (1.0 + np.stack([hue, 0 * hue, -hue], axis=1))
            cloud = fractal_noise(p[:, 0] / 0.35, p[:, 1] / 0.35, f / 0.35, 3, seed + 2)
            speck = fractal_noise(p[:, 0] / 0.012, p[:, 1] / 0.012, f / 0.012, 2, seed + 3)
            col = col * (1.0 + self.floor_cloud * cloud + self.floor_speckle * speck)[:, None]
            du = np.abs(u - np.round(u)) * self.tile
            dv = np.abs(v - np.round(v)) * self.tile
            grout = np.maximum(_coverage(du, 0.003, f), _coverage(dv, 0.003, f))
            col = col * (1.0 - self.grout_depth * grout)[:, None]
            out[m] = col

        # Ceiling: plain, slightly mottled.
        m = surface == CEILING
        if np.any(m):
            p, f = points[m], fp[m]
            n = fractal_noise(p[:, 0] / 0.5, p[:, 1] / 0.5, f / 0.5, 3, seed + 4)
            out[m] = np.asarray(self.ceiling_color) * (1.0 + 0.05 * n)[:, None]

        # Walls: paint with low-frequency mottling, baseboard, panels.
        m = surface >= WALL_XMIN
        if np.any(m):
            p, f, s = points[m], fp[m], surface[m]
            u = self._wall_uv(p, s)
            z = p[:, 2]
            n = fractal_noise(u / 0.6 + 17.0 * s, z / 0.6, f / 0.6, 4, seed + 5)
            col = np.asarray(self.wall_color) * (1.0 + self.wall_mottle * n)[:, None]
            if self.baseboard_height > 0:
                half = 0.5 * self.baseboard_height
                base = _coverage(np.abs(z - half), half, f)
                col = col * (1 - base[:, None]) + np.asarray(self.baseboard_color) * base[:, None]
            for panel in self.panels:
                on = s == panel.wall
                if not np.any(on):
                    continue
                cu = 0.5 * (panel.u[0] + panel.u[1])
                cz = 0.5 * (panel.z[0] + panel.z[1])
                hu = 0.5 * (panel.u[1] - panel.u[0])
                hz = 0.5 * (panel.z[1] - panel.z[0])
                du, dz = np.abs(u - cu), np.abs(z - cz)
                inside = _coverage(du, hu, f) * _coverage(dz, hz, f) * on
                pc = np.asarray(panel.color)
                if panel.frame > 0:
                    inner = (
                        _coverage(du, hu - panel.frame, f) * _coverage(dz, hz - panel.frame, f) * on
                    )
                    frame_col = pc * 0.55
                    patch = frame_col[None] * (1 - inner[:, None]) + pc[None] * inner[:, None]
                else:
                    patch = np.broadcast_to(pc, col.shape)
                col = col * (1 - inside[:, None]) + patch * inside[:, None]
            out[m] = col
        return np.clip(out, 0.0, 1.0)


def _coverage(dist: np.ndarray, half_width: float, footprint: np.ndarray) -> np.ndarray:
    """Fraction of a pixel (box of width ``footprint`` centred at ``dist``) that
    lies within ``|x| <= half_width``: an anti-aliased band."""
    fp = np.maximum(footprint, 1e-6)
    a = np.clip(dist - 0.5 * fp, -half_width, half_width)
    b = np.clip(dist + 0.5 * fp, -half_width, half_width)
    return (b - a) / fp


# --- the subject's clothing -----------------------------------------------------


@dataclass(frozen=True)
class Appearance:
    """Clothing colours of the subject.

    Attributes
    ----------
    part_colors : (15, 3) float
        Albedo (BGR, 0..1) per body part (order of ``skeleton.PARTS``).
    hair_color : (3,) float
        Albedo of the hair (top and back of the head).
    variation : float
        Amplitude of the smooth per-vertex albedo variation (folds, fabric).
    seed : int
    """

    part_colors: np.ndarray = field(
        default_factory=lambda: PART_COLORS[:, ::-1].astype(float) / 255.0 * 0.95
    )
    hair_color: np.ndarray = field(default_factory=lambda: np.array([0.07, 0.10, 0.16]))
    variation: float = 0.10
    seed: int = 3

    def face_albedo(self, face_parts: np.ndarray) -> np.ndarray:
        """(T, 3) float albedo of each triangle from its part."""
        return np.asarray(self.part_colors, dtype=float)[np.asarray(face_parts)]

    def vertex_modulation(
        self,
        faces: np.ndarray,
        n_vertices: int,
        rest_vertices: np.ndarray | None = None,
        head_vertices: np.ndarray | None = None,
        skin_color: np.ndarray | None = None,
    ) -> np.ndarray:
        """(V, 3) float multiplicative albedo modulation per vertex: smooth noise
        (a mesh-smoothed random field) plus hair on the head.

        Parameters
        ----------
        faces : (T, 3) int
        n_vertices : int
        rest_vertices : (V, 3) float, optional
            The body standing (z up, facing -y), to place the hair.
        head_vertices : (H,) int, optional
            Vertices of the head part.
        skin_color : (3,) float, optional
            Albedo of the head part (to turn into hair colour by modulation).
        """
        rng = np.random.default_rng(self.seed)
        smooth = neighbour_mean(faces, n_vertices)
        fine = rng.standard_normal(n_vertices)
        coarse = rng.standard_normal(n_vertices)
        for _ in range(2):
            fine = 0.5 * fine + 0.5 * (smooth @ fine)
        for _ in range(25):
            coarse = 0.5 * coarse + 0.5 * (smooth @ coarse)
        fine /= fine.std() + 1e-12
        coarse /= coarse.std() + 1e-12
        lum = 1.0 + self.variation * (0.35 * fine + 0.65 * coarse)
        mod = np.repeat(lum[:, None], 3, axis=1)
        if rest_vertices is not None and head_vertices is not None and skin_color is not None:
            rv = np.asarray(rest_vertices, dtype=float)
            hv = np.asarray(head_vertices)
            top = rv[hv, 2].max()
            front = rv[hv, 1].min()  # the body faces -y
            depth = rv[hv, 1].max() - front
            z_rel = top - rv[hv, 2]
            y_rel = (rv[hv, 1] - front) / max(depth, 1e-6)  # 0 face, 1 back of head
            # Hairline: high on the forehead, low at the back of the head.
            hairline = 0.075 + 0.10 * np.clip((y_rel - 0.35) / 0.5, 0, 1)
            w = np.clip((hairline - z_rel) / 0.012 + 0.5, 0, 1)
            ratio = np.asarray(self.hair_color) / np.maximum(np.asarray(skin_color), 1e-3)
            mod[hv] = mod[hv] * (1 - w[:, None]) + (ratio[None] * lum[hv, None]) * w[:, None]
        return mod


# --- calibration board -----------------------------------------------------------


@dataclass(frozen=True)
class BoardTexture:
    """A printed planar target (e.g. ChArUco) and its physical size.

    Board frame (OpenCV's ChArUco object frame): origin at the outer top-left
    corner of the pattern, x along the pattern's columns, y along its rows
    (down the printed image), z = x × y; the printed side faces -z. The sheet
    extends ``margin`` metres beyond the pattern on every side.

    Attributes
    ----------
    image : (h, w) float32
        Albedo of the printed sheet including its margin, 0..1.
    pattern_size : (2,) float
        Pattern width and height, metres.
    margin : float
        White border around the pattern, metres.
    back_albedo : float
        Albedo of the back of the board.
    """

    image: np.ndarray
    pattern_size: tuple[float, float]
    margin: float
    back_albedo: float = 0.32

    @classmethod
    def from_charuco(
        cls,
        board: cv2.aruco.CharucoBoard,
        margin: float | None = None,
        pixels_per_square: int = 64,
        black: float = 0.04,
        white: float = 0.86,
    ) -> BoardTexture:
        """Print ``board`` (from ``cv2.aruco.CharucoBoard``) with a white margin
        (default half a square)."""
        sx, sy = board.getChessboardSize()
        square = float(board.getSquareLength())
        if margin is None:
            margin = 0.5 * square
        img = board.generateImage((sx * pixels_per_square, sy * pixels_per_square), marginSize=0)
        pad = round(margin / square * pixels_per_square)
        img = cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)
        alb = black + (white - black) * (img.astype(np.float32) / 255.0)
        return cls(alb, (sx * square, sy * square), pad * square / pixels_per_square)

    @property
    def sheet_size(self) -> tuple[float, float]:
        """Printed sheet width and height including margins, metres."""
        return (self.pattern_size[0] + 2 * self.margin, self.pattern_size[1] + 2 * self.margin)

    def corners(self) -> np.ndarray:
        """(4, 3) float sheet corners in the board frame (TL, TR, BR, BL)."""
        m = self.margin
        w, h = self.pattern_size
        return np.array([[-m, -m, 0], [w + m, -m, 0], [w + m, h + m, 0], [-m, h + m, 0]], float)

    def mipmaps(self) -> list[np.ndarray]:
        """Image pyramid of the albedo (level 0 = full resolution)."""
        levels = [self.image.astype(np.float32)]
        while min(levels[-1].shape) > 8:
            prev = levels[-1]
            levels.append(
                cv2.resize(
                    prev,
                    ((prev.shape[1] + 1) // 2, (prev.shape[0] + 1) // 2),
                    interpolation=cv2.INTER_AREA,
                )
            )
        return levels


@dataclass(frozen=True)
class BoardPose:
    """Where a board is: ``x_world = R @ x_board + t``.

    Attributes
    ----------
    R : (3, 3) float
        Rotation world_from_board.
    t : (3,) float
        Position of the board origin, metres.
    """

    R: np.ndarray
    t: np.ndarray

    def __post_init__(self) -> None:
        R = np.asarray(self.R, dtype=float)
        t = np.asarray(self.t, dtype=float).reshape(-1)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
            raise ValueError(f"BoardPose.R must be a 3x3 rotation, got shape {R.shape}")
        if np.linalg.det(R) < 0:
            raise ValueError("BoardPose.R must have det +1")
        if t.shape != (3,):
            raise ValueError(f"BoardPose.t must have 3 values, got shape {t.shape}")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """Board-frame points (..., 3) -> world (..., 3)."""
        return np.asarray(points, dtype=float) @ self.R.T + self.t
