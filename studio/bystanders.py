"""Bystanders: other people standing still in the studio's room during a recording.

Real lab recordings rarely show the subject alone: an operator or a colleague
stands by the wall, in the view of a camera or two. A bystander here is another
SCAPE body of the calibrated prior (a held-out body other than the subject's)
in a relaxed standing pose with its own arm hang, elbow bend and head turn,
wearing its own shirt and trousers, standing still for the whole clip. The
renderer draws it through the subject's own raster, shading and shadow map
(:class:`~bodymetry.studio.render.Body`), so it is lit and casts a shadow like
the subject and is z-buffered against it; the ground-truth silhouettes stay the
subject's.

Placement (:func:`place_bystanders`) keeps the multi-view test cases clean:
each bystander is seen by at least one and at most ``max_views`` cameras (a
camera sees a good part of the body or none of it), never overlaps the
subject's image footprint over the whole clip in any camera (so it never stands
between a camera and the subject, nor right behind the subject), keeps clear
of the walls, the cameras and the other bystanders, and stands at least
``min_distance_m`` from the volume centre. Every draw comes from one seed.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import cv2
import numpy as np

from bodymetry.calibration.camera import CameraGroup
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.model import ADULT_YEARS, BodyModel, BodyState
from bodymetry.estimation.body_model.motion.ik import (
    arm_angles,
    neutral_pose,
    set_dofs,
    straight_elbow,
    unit,
)
from bodymetry.estimation.body_model.motion.library import Motion, ground_motion
from bodymetry.estimation.body_model.motion.rest import RestPoseInfo
from bodymetry.estimation.body_model.motion.signals import inner_clip, wrap_angle
from bodymetry.estimation.body_model.skeleton import JOINT_SLICES, JOINTS, PARTS, YAW
from bodymetry.studio.lens import lens_radius_limit, project_for_raster
from bodymetry.studio.scene import Appearance, Room

log = logging.getLogger(__name__)

#: Shirt albedos (BGR, 0..1) bystanders wear.
SHIRTS: dict[str, tuple[float, float, float]] = {
    "white": (0.80, 0.80, 0.78),
    "grey": (0.45, 0.45, 0.46),
    "navy": (0.36, 0.19, 0.12),
    "green": (0.24, 0.46, 0.22),
    "mustard": (0.16, 0.58, 0.74),
    "black": (0.08, 0.08, 0.09),
    "teal": (0.50, 0.46, 0.12),
}
#: Trouser albedos (BGR, 0..1).
TROUSERS: dict[str, tuple[float, float, float]] = {
    "jeans": (0.55, 0.36, 0.21),
    "black": (0.07, 0.07, 0.08),
    "khaki": (0.40, 0.55, 0.62),
    "grey": (0.30, 0.30, 0.32),
}
_SHIRT_PARTS = tuple(PARTS.index(p) for p in ("torso", "upper_arm_l", "upper_arm_r"))
_TROUSER_PARTS = tuple(PARTS.index(p) for p in ("pelvis", "thigh_l", "shin_l", "thigh_r", "shin_r"))
#: The most bystanders a session may ask for (more do not fit beside a 3 x 3 m volume).
MAX_BYSTANDERS = 6


@dataclass(frozen=True)
class BystanderPlacement:
    """Where bystanders may stand (see the module docstring).

    Attributes
    ----------
    min_distance_m : float
        Floor distance of the root from the volume centre (the world origin).
    wall_clearance_m : float
        Every vertex stays this far inside the walls.
    camera_clearance_m : float
        Floor distance of every vertex from each camera's position.
    spacing_m : float
        Floor distance between the roots of two bystanders.
    max_views : int
        A bystander is seen by at least one and at most this many cameras.
    min_visible_fraction : float
        A camera that sees a bystander at all sees at least this fraction of its
        vertices (no slivers at the image border).
    clearance_px : float
        Pixels between a bystander and the subject's image footprint (the union
        over the clip of the convex hulls of the projected subject), in every camera.
    attempts : int
        Candidate positions tried per bystander before giving up.
    """

    min_distance_m: float = 2.0
    wall_clearance_m: float = 0.05
    camera_clearance_m: float = 0.6
    spacing_m: float = 0.8
    max_views: int = 2
    min_visible_fraction: float = 0.5
    clearance_px: float = 10.0
    attempts: int = 500

    def __post_init__(self) -> None:
        if self.max_views < 1:
            raise ValueError(f"BystanderPlacement.max_views must be >= 1, got {self.max_views}")
        if not 0.0 < self.min_visible_fraction <= 1.0:
            raise ValueError(
                "BystanderPlacement.min_visible_fraction must be in (0, 1], got "
                f"{self.min_visible_fraction}"
            )
        if self.attempts < 1:
            raise ValueError(f"BystanderPlacement.attempts must be >= 1, got {self.attempts}")


@dataclass(frozen=True)
class Bystander:
    """One person standing still in the room.

    Attributes
    ----------
    heldout_index : int
        Which held-out body of the calibrated prior (its shape ``nu``).
    nu : (n_shape,) float
    theta : (37,) float
        Joint angles (``root.z`` is the heading).
    tau : (3,) float
        Root (mid-hip) position, metres; the lowest vertex touches the floor.
    shirt, trousers : str
        Keys of :data:`SHIRTS` and :data:`TROUSERS`.
    seen_by : tuple of str
        Names of the cameras that see it.
    """

    heldout_index: int
    nu: tuple[float, ...]
    theta: tuple[float, ...]
    tau: tuple[float, float, float]
    shirt: str
    trousers: str
    seen_by: tuple[str, ...] = ()

    def state(self) -> BodyState:
        """The (1-frame) body state."""
        return BodyState(np.array([self.tau]), np.array([self.theta]), np.array([self.nu]))

    def vertices(self, model: BodyModel) -> np.ndarray:
        """(V, 3) float posed full-mesh vertices, world metres."""
        return model.pose(self.state()).vertices[0]

    def appearance(self, base: Appearance | None = None) -> Appearance:
        """``base`` (default :class:`Appearance`) in this bystander's shirt and trousers."""
        base = base or Appearance()
        colors = np.array(base.part_colors, dtype=float, copy=True)
        colors[list(_SHIRT_PARTS)] = SHIRTS[self.shirt]
        colors[list(_TROUSER_PARTS)] = TROUSERS[self.trousers]
        return dataclasses.replace(base, part_colors=colors)

    @property
    def heading_deg(self) -> float:
        """Direction the body faces, degrees from +x towards +y."""
        yaw = self.theta[YAW]
        return float(np.degrees(np.arctan2(-np.cos(yaw), np.sin(yaw))))

    def to_json(self) -> dict:
        """A JSON-ready description (for ``ground_truth/studio.json``)."""
        return {
            "heldout_index": self.heldout_index,
            "position_m": [round(self.tau[0], 4), round(self.tau[1], 4)],
            "heading_deg": round(self.heading_deg, 2),
            "seen_by": list(self.seen_by),
            "shirt": self.shirt,
            "trousers": self.trousers,
            "nu": list(self.nu),
            "theta": list(self.theta),
            "tau": list(self.tau),
        }


def _standing_pose(
    model: BodyModel, nu: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """A relaxed standing pose with its own arm hang, elbow bend and head turn.

    Returns
    -------
    theta : (37,) float
        Heading 0 (facing -y).
    tau : (3,) float
        Root above the origin, lowest vertex on the floor.
    """
    rest = RestPoseInfo.from_model(model, nu)
    theta = neutral_pose(rest, model.limits)
    for side in ("l", "r"):
        hang = unit(rng.uniform(0.12, 0.40), rng.uniform(-0.25, 0.15), -1.0)
        theta[JOINT_SLICES[JOINTS.index(f"shoulder_{side}")]] = arm_angles(
            hang, side, rest, model.limits
        )
        set_dofs(theta, **{f"elbow_{side}": straight_elbow(rest) + rng.uniform(0.05, 0.7)})
    set_dofs(theta, neck__z=rng.uniform(-0.4, 0.4), neck__x=rng.uniform(-0.1, 0.15))
    theta = inner_clip(theta, model.limits)
    theta[YAW] = 0.0
    still = Motion(theta[None], np.array([[0.0, 0.0, rest.root_height]]), 1.0, "bystander")
    still = ground_motion(model, still, nu, lod=False)
    return still.theta[0].copy(), still.tau[0].copy()


def subject_footprints(
    cameras: CameraGroup, vertices: np.ndarray, clearance_px: float = 0.0
) -> dict[str, np.ndarray]:
    """Where the subject can appear in each camera over the clip.

    Parameters
    ----------
    cameras : CameraGroup
    vertices : (F, N, 3) float
        The subject's vertices (any subset, e.g. every 7th) in the frames to cover.
    clearance_px : float
        Grow each footprint by this many pixels.

    Returns
    -------
    dict of camera name -> (H, W) bool
        Union over the frames of the convex hull of the projected vertices, grown.
    """
    shift = 4
    out = {}
    for cam in cameras:
        w, h = cam.size
        mask = np.zeros((h, w), np.uint8)
        r_limit = lens_radius_limit(cam)
        for frame in np.asarray(vertices, dtype=float):
            xy, _, valid = project_for_raster(cam, frame, 1, r_limit)
            if valid.sum() < 3:
                continue
            pts = np.round(xy[valid] * (1 << shift)).astype(np.int32)
            hull = cv2.convexHull(np.clip(pts, -(1 << 24), 1 << 24))
            cv2.fillConvexPoly(mask, hull, 1, cv2.LINE_8, shift)
        if clearance_px > 0:
            k = 2 * int(np.ceil(clearance_px)) + 1
            mask = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
        out[cam.name] = mask.astype(bool)
    return out


def _views(
    cameras: CameraGroup,
    r_limits: list[float],
    points: np.ndarray,
    footprints: dict[str, np.ndarray],
    min_visible_fraction: float,
) -> tuple[str, ...] | None:
    """Cameras that see ``points`` (N, 3); None when a camera sees only a sliver of
    them or the seen points touch the subject's footprint."""
    seen = []
    for cam, r_limit in zip(cameras, r_limits, strict=True):
        w, h = cam.size
        xy, _, valid = project_for_raster(cam, points, 1, r_limit)
        px = np.round(xy).astype(np.int64)
        inside = valid & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
        fraction = inside.mean()
        if fraction == 0:
            continue
        if fraction < min_visible_fraction:
            return None
        if footprints[cam.name][px[inside, 1], px[inside, 0]].any():
            return None
        seen.append(cam.name)
    return tuple(seen)


def place_bystanders(
    model: BodyModel,
    cameras: CameraGroup,
    subject_vertices: np.ndarray,
    n: int,
    seed: int,
    *,
    room: Room | None = None,
    exclude_heldout: tuple[int, ...] = (),
    placement: BystanderPlacement | None = None,
) -> list[Bystander]:
    """Draw ``n`` bystanders and place them in the room (see the module docstring).

    Parameters
    ----------
    model : BodyModel
    cameras : CameraGroup
        The rig.
    subject_vertices : (F, N, 3) float
        The subject's vertices (a subset is enough) over the clip, for its footprints.
    n : int
        Bystanders to place (0..MAX_BYSTANDERS).
    seed : int
        Seeds every draw (bodies, poses, clothes, positions).
    room : Room, optional
        The studio's room (default :class:`Room`).
    exclude_heldout : tuple of int
        Held-out bodies not to use (the subject's).
    placement : BystanderPlacement, optional

    Returns
    -------
    list of Bystander

    Raises
    ------
    InputError
        When ``n`` is out of range or not all bystanders fit.
    """
    if not 0 <= n <= MAX_BYSTANDERS:
        raise InputError(f"--bystanders: expected 0..{MAX_BYSTANDERS}, got {n}")
    if n == 0:
        return []
    placement = placement or BystanderPlacement()
    room = room or Room()
    rng = np.random.default_rng([int(seed), 0xB75])
    heldout = model.prior_shapes("heldout")
    # Adults, as the studio's subjects drawn by seed (studio.synth).
    adults = np.flatnonzero(model.prior_ages("heldout") >= ADULT_YEARS)
    free = [int(i) for i in adults if i not in set(exclude_heldout)]
    indices = rng.choice(free, size=n, replace=False)
    lo, hi = room.bounds[:, :2] + [[placement.wall_clearance_m], [-placement.wall_clearance_m]]
    site = _Site(
        cameras=cameras,
        r_limits=[lens_radius_limit(cam) for cam in cameras],
        footprints=subject_footprints(cameras, subject_vertices, placement.clearance_px),
        lo=lo,
        hi=hi,
        cam_xy=cameras.centers[:, :2],
        placement=placement,
    )
    placed: list[Bystander] = []
    for index in indices:
        bystander = _place_one(model, site, index, heldout[index], placed, rng)
        if bystander is None:
            raise InputError(
                f"--bystanders {n}: placed {len(placed)}, found no room for another beside "
                f"the subject's volume within {placement.attempts} tries (each must be seen by "
                f"1..{placement.max_views} of {len(cameras)} cameras and clear of the subject "
                "in every view); ask for fewer"
            )
        placed.append(bystander)
        log.info(
            "bystander %d: held-out body %d at (%.2f, %.2f) m, seen by %s",
            len(placed),
            index,
            bystander.tau[0],
            bystander.tau[1],
            ", ".join(bystander.seen_by),
        )
    return placed


@dataclass(frozen=True, eq=False)
class _Site:
    """Where bystanders may stand: the rig, the subject's footprints and the room.

    Attributes
    ----------
    cameras : CameraGroup
    r_limits : list of float
        Each camera's lens radius limit.
    footprints : dict of camera name -> (H, W) bool
        The subject's grown footprints.
    lo, hi : (2,) float
        Floor bounds (x, y) within the wall clearance.
    cam_xy : (C, 2) float
        Camera centres on the floor plan.
    placement : BystanderPlacement
    """

    cameras: CameraGroup
    r_limits: list[float]
    footprints: dict[str, np.ndarray]
    lo: np.ndarray
    hi: np.ndarray
    cam_xy: np.ndarray
    placement: BystanderPlacement


def _place_one(
    model: BodyModel,
    site: _Site,
    index: int,
    nu: np.ndarray,
    placed: list[Bystander],
    rng: np.random.Generator,
) -> Bystander | None:
    """Pose and dress held-out body ``index`` (shape ``nu`` (n_shape,)) and find it a spot.

    Draws, in order: the standing pose, the shirt, the trousers, then up to
    ``placement.attempts`` spots (:func:`_try_spot`).

    Returns
    -------
    Bystander or None
        Placed with its ``seen_by``; None when no attempt found room.
    """
    theta0, tau0 = _standing_pose(model, nu, rng)
    v0 = model.pose(BodyState(tau0[None], theta0[None], nu[None])).vertices[0]
    local = v0[::3] - [tau0[0], tau0[1], 0.0]
    shirt = str(rng.choice(list(SHIRTS)))
    trousers = str(rng.choice(list(TROUSERS)))
    draft = Bystander(int(index), tuple(map(float, nu)), (), (0.0, 0.0, 0.0), shirt, trousers)
    for _ in range(site.placement.attempts):
        bystander = _try_spot(model, site, placed, rng, draft, theta0, tau0, local)
        if bystander is not None:
            return bystander
    return None


def _try_spot(
    model: BodyModel,
    site: _Site,
    placed: list[Bystander],
    rng: np.random.Generator,
    draft: Bystander,
    theta0: np.ndarray,
    tau0: np.ndarray,
    local: np.ndarray,
) -> Bystander | None:
    """One random spot and heading for a bystander, or None when it does not fit.

    Parameters
    ----------
    draft : Bystander
        Its held-out body, shape and clothes (pose and place to fill in).
    theta0 : (37,) float
        Its standing pose at heading 0.
    tau0 : (3,) float
        Its root at heading 0, above the origin.
    local : (M, 3) float
        A subset of its rest vertices about the root's floor point.

    Returns
    -------
    Bystander or None
        Placed (pose, position, ``seen_by``) when the spot is clear of the walls,
        the cameras and the other bystanders, and 1..``max_views`` cameras see it
        clear of the subject's footprint.
    """
    placement, lo, hi = site.placement, site.lo, site.hi
    xy = rng.uniform(lo, hi)
    if np.hypot(*xy) < placement.min_distance_m:
        return None
    if any(np.hypot(*(xy - b.tau[:2])) < placement.spacing_m for b in placed):
        return None
    # Face the room's centre, give or take 70 degrees.
    facing = np.arctan2(-xy[1], -xy[0]) + rng.uniform(-1.2, 1.2)
    yaw = facing + np.pi / 2  # heading 0 faces -y (azimuth -90 degrees)
    c, s = np.cos(yaw), np.sin(yaw)
    pts = local @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
    pts[:, :2] += xy
    if np.any(pts[:, :2] < lo) or np.any(pts[:, :2] > hi):
        return None
    d_cam = np.linalg.norm(pts[:, None, :2] - site.cam_xy[None], axis=-1)
    if d_cam.min() < placement.camera_clearance_m:
        return None
    seen = _views(site.cameras, site.r_limits, pts, site.footprints, placement.min_visible_fraction)
    if seen is None or not 1 <= len(seen) <= placement.max_views:
        return None
    theta = theta0.copy()
    theta[YAW] = float(wrap_angle(theta0[YAW] + yaw))
    tau = (float(xy[0]), float(xy[1]), float(tau0[2]))
    bystander = dataclasses.replace(draft, theta=tuple(map(float, theta)), tau=tau)
    # The posed body, not the turned copy, decides.
    final = bystander.vertices(model)[::3]
    seen = _views(
        site.cameras, site.r_limits, final, site.footprints, placement.min_visible_fraction
    )
    if seen is None or not 1 <= len(seen) <= placement.max_views:
        return None
    return dataclasses.replace(bystander, seen_by=seen)
