"""The calibration board's motion through a studio calibration clip.

:func:`board_trajectory` follows the recording protocol of docs/calibration.md
("Recording the clip") as a time-lapse: the board on the floor (it defines the
world frame), shared views between neighbouring cameras, then close sweeps in
front of each camera; key poses are held and eased into each other.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.capture.session import BoardSpec

#: Where the close sweep puts the board centre in each camera's image, in units of the
#: half image size from the principal point: a serpentine over a 3 x 3 grid (corners
#: first), so that partly visible boards reach every image corner and border.
SWEEP_GRID = ((-1, -1), (0, -1), (1, -1), (1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (0, 0))

#: A key pose of the board: world_from_board rotation (3, 3) and board centre (3,).
KeyPose = tuple[np.ndarray, np.ndarray]
#: A segment of the clip: its weight (share of the frames) and its key poses.
Segment = tuple[float, list[KeyPose]]


def _facing(normal: np.ndarray) -> np.ndarray:
    """world_from_board rotation (3, 3) of an upright board whose printed side faces ``normal``."""
    z_b = -normal / np.linalg.norm(normal)  # the printed side looks along -z_b
    x_b = np.cross([0.0, 0.0, 1.0], z_b)
    x_b /= np.linalg.norm(x_b)
    return np.stack([x_b, np.cross(z_b, x_b), z_b], axis=1)


def board_trajectory(
    n_frames: int,
    fps: float,
    rng: np.random.Generator,
    board: BoardSpec,
    cameras: CameraGroup,
    *,
    sweep_reach: float = 0.7,
    sweep_depth_m: tuple[float, float] = (1.5, 2.3),
    tilt_deg: float = 35.0,
    height_m: tuple[float, float] = (0.5, 2.2),
) -> np.ndarray:
    """Poses of the calibration board through the clip, ``x_world = R x_board + t``.

    The protocol of docs/calibration.md ("Recording the clip"), as a time-lapse:

    1. The first second the board lies face up on the floor with its pattern
       origin at the world origin and its x axis along world x: that defines
       the world frame (docs/calibration-format.md).
    2. Shared views: for each pair of neighbouring cameras, the board is held
       in the volume at 0.9-1.6 m, facing between the two, at three tilted
       poses (±25°).
    3. Close sweeps: the operator steps up to each camera in turn and holds
       the board 1.5-2.3 m in front of it at nine poses whose centres lie on a
       3 x 3 grid over the image (:data:`SWEEP_GRID`, ``sweep_reach`` of the
       half image size out from the centre, so that partly visible boards
       cover the image corners), each tilted by up to ``tilt_deg`` about both
       board axes. The image corners pin down distortion and the principal
       point; the tilts pin down the focal length.

    The board holds each key pose for 40 % of its share of the frames and moves
    smoothly (position eased, rotation slerped) to the next. Pair poses get
    one share, close sweeps two (per segment).

    Parameters
    ----------
    cameras : CameraGroup
        The rig (the operator watches each camera's live image to aim the board).
    sweep_reach, sweep_depth_m, tilt_deg : close-sweep geometry (see above).
    height_m : (float, float)
        Range of the board centre's height during the close sweeps (the
        sweep distance is shortened or lengthened to stay within it).

    Returns
    -------
    (n_frames, 4, 4) float
        Homogeneous world_from_board transforms.
    """
    w = board.squares[0] * board.square_m
    h = board.squares[1] * board.square_m
    center = np.array([w / 2, h / 2, 0.0])
    floor = np.eye(4)
    # Printed side faces the board's -z; face up means board z = world -z.
    floor[:3, :3] = np.diag([1.0, -1.0, -1.0])
    n_floor = min(n_frames, round(fps))
    out = np.empty((n_frames, 4, 4))
    out[:n_floor] = floor
    n_move = n_frames - n_floor
    if n_move <= 0 or not cameras:
        out[n_floor:] = floor
        return out
    centers = cameras.centers
    order = np.argsort(np.arctan2(centers[:, 1], centers[:, 0]))
    segments = shared_view_segments(centers, order, rng)
    for i in range(len(cameras)):
        keys = close_sweep_keys(
            cameras[order[i]], rng, sweep_reach, sweep_depth_m, tilt_deg, height_m
        )
        segments.append((2.0, keys))
    out[n_floor:] = ease_through(segments, n_move, center)
    return out


def shared_view_segments(
    centers: np.ndarray, order: np.ndarray, rng: np.random.Generator
) -> list[Segment]:
    """Step 2 of :func:`board_trajectory`: three tilted poses between each pair of
    neighbouring cameras (none for a single camera), each segment of weight 1.

    Parameters
    ----------
    centers : (C, 3) float
        Camera centres.
    order : (C,) int
        Cameras in order of azimuth.
    rng : numpy.random.Generator
        Draws the poses.
    """
    C = len(centers)
    segments: list[Segment] = []
    for i in range(C if C > 1 else 0):
        mid = 0.5 * (centers[order[i]] + centers[order[(i + 1) % C]])
        toward = mid[:2] / max(np.linalg.norm(mid[:2]), 1e-9)
        keys = []
        for _ in range(3):
            p = np.array([*(0.35 * toward + rng.uniform(-0.4, 0.4, 2)), rng.uniform(0.9, 1.6)])
            tilt = rng.uniform(-1.0, 1.0, 3) * np.deg2rad([25.0, 25.0, 15.0])
            keys.append((_facing(mid - p) @ Rotation.from_euler("xyz", tilt).as_matrix(), p))
        segments.append((1.0, keys))
    return segments


def close_sweep_keys(
    cam: Camera,
    rng: np.random.Generator,
    sweep_reach: float,
    sweep_depth_m: tuple[float, float],
    tilt_deg: float,
    height_m: tuple[float, float],
) -> list[KeyPose]:
    """Step 3 of :func:`board_trajectory`: the nine close-sweep poses in front of ``cam``.

    The sweep starts at a random cell of :data:`SWEEP_GRID` and follows the grid's
    order; see :func:`board_trajectory` for the geometry parameters.

    Returns
    -------
    list of (R (3, 3), p (3,))
        world_from_board rotations and board centres.
    """
    (fx, _, cx), (_, fy, cy) = cam.K[:2]
    half = np.array([cam.size[0], cam.size[1]]) / 2.0
    first = int(rng.integers(len(SWEEP_GRID)))
    keys = []
    for k in range(len(SWEEP_GRID)):
        g = np.asarray(SWEEP_GRID[(first + k) % len(SWEEP_GRID)], dtype=float)
        u, v = np.array([cx, cy]) + g * sweep_reach * half
        ray = np.array([(u - cx) / fx, (v - cy) / fy, 1.0])  # camera frame, z = 1
        ray_w = cam.R.T @ ray
        depth = rng.uniform(*sweep_depth_m)
        z = cam.center[2] + depth * ray_w[2]
        if abs(ray_w[2]) > 1e-9 and not height_m[0] <= z <= height_m[1]:
            zc = np.clip(z, *height_m)
            depth = float(np.clip((zc - cam.center[2]) / ray_w[2], 1.0, 3.5))
        p_cam = depth * ray
        # Upright in the image (board x along image x), facing the camera, then tilted.
        z_b = p_cam / np.linalg.norm(p_cam)
        x_b = np.cross(z_b, np.cross([1.0, 0.0, 0.0], z_b))
        x_b /= np.linalg.norm(x_b)
        R_cb = np.stack([x_b, np.cross(z_b, x_b), z_b], axis=1)
        tilt = rng.uniform(-1.0, 1.0, 3) * np.deg2rad([tilt_deg, tilt_deg, 15.0])
        R_cb = R_cb @ Rotation.from_euler("xyz", tilt).as_matrix()
        keys.append((cam.R.T @ R_cb, cam.R.T @ (p_cam - cam.t)))
    return keys


def ease_through(segments: list[Segment], n_move: int, center: np.ndarray) -> np.ndarray:
    """The board's transforms over ``n_move`` frames through the segments' key poses.

    Each key pose gets its segment's weight divided among the segment's poses as
    its share of the frames; the board holds it for 40 % of the share, then moves
    to the next (position smoothstep-eased, rotation slerped).

    Parameters
    ----------
    segments : list of (weight, [(R (3, 3), p (3,)), ...])
    n_move : int
        Frames after the floor pose.
    center : (3,) float
        The board centre in board coordinates (``p`` is where it goes).

    Returns
    -------
    (n_move, 4, 4) float
        Homogeneous world_from_board transforms.
    """
    keys = [key for _, seg in segments for key in seg]
    share = np.array([weight / len(seg) for weight, seg in segments for _ in seg])
    bounds = np.concatenate([[0.0], np.cumsum(share) / share.sum() * n_move])
    rotations = Rotation.from_matrix(np.stack([R for R, _ in keys]))
    positions = np.stack([p for _, p in keys])
    out = np.empty((n_move, 4, 4))
    for f in range(n_move):
        k = min(int(np.searchsorted(bounds, f, side="right")) - 1, len(keys) - 1)
        nxt = min(k + 1, len(keys) - 1)
        s = (f - bounds[k]) / max(bounds[k + 1] - bounds[k], 1e-9)
        a = float(np.clip((s - 0.4) / 0.6, 0.0, 1.0))
        a = a * a * (3.0 - 2.0 * a)  # smoothstep
        R = Slerp([0.0, 1.0], rotations[[k, nxt]])(a).as_matrix()
        p = (1.0 - a) * positions[k] + a * positions[nxt]
        out[f] = np.eye(4)
        out[f, :3, :3] = R
        out[f, :3, 3] = p - R @ center
    return out
