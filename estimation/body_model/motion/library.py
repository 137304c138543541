"""The motion library: named, seeded generators of whole-body ``Motion`` sequences.

Typical use::

    motion = make_motion("mixed", n_frames=850, fps=60.0, seed=seed_for("demo", 0))
    motion = ground_motion(model, motion, nu)          # lowest vertex on z = 0

A library motion is a clip (``clips.CLIPS``) soft-clipped into the joint limits,
with the heading integrated from the clip's rate (``root.z``, wrapped into
``[-pi, pi)``) and the root τ placed by :func:`~.contact.place_root` so the feet
stay on the floor. Conventions (``estimation.body_model.skeleton``): θ (37,) in
radians, τ the root joint (mid-hip) in world coordinates, metres, z up, floor at
z = 0. Numpy only: :func:`ground_motion` takes a ``BodyModel`` but this module
does not import one at load time.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from bodymetry.estimation.body_model.motion.clips import CLIPS, Clip, ClipContext
from bodymetry.estimation.body_model.motion.contact import place_root
from bodymetry.estimation.body_model.motion.rest import RestPoseInfo, default_limits
from bodymetry.estimation.body_model.motion.seeds import motion_rng
from bodymetry.estimation.body_model.motion.signals import soft_clip
from bodymetry.estimation.body_model.skeleton import N_POSE, YAW, JointLimits

if TYPE_CHECKING:  # pragma: no cover - typing only; keeps this module numpy-only at run time
    from bodymetry.estimation.body_model.model import BodyModel


@dataclass(frozen=True)
class Motion:
    """A body motion: joint angles and root position per frame.

    Attributes
    ----------
    theta : (F, 37) float
        Joint angles, radians (layout of ``skeleton.dof_names()``); ``root.z`` is the
        heading in ``[-pi, pi)``.
    tau : (F, 3) float
        World position of the root joint (mid-hip), metres; z up, floor at z = 0.
    fps : float
        Frames per second.
    name : str
        The library motion it came from.
    """

    theta: np.ndarray
    tau: np.ndarray
    fps: float
    name: str

    def __post_init__(self) -> None:
        theta = np.array(self.theta, dtype=float)
        tau = np.array(self.tau, dtype=float)
        if theta.ndim != 2 or theta.shape[1] != N_POSE:
            raise ValueError(f"Motion.theta: expected shape (F, {N_POSE}), got {theta.shape}")
        if tau.shape != (len(theta), 3):
            raise ValueError(f"Motion.tau: expected shape ({len(theta)}, 3), got {tau.shape}")
        if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(tau))):
            raise ValueError("Motion: theta and tau must be finite")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"Motion.fps: expected a positive number, got {self.fps}")
        theta.flags.writeable = False
        tau.flags.writeable = False
        object.__setattr__(self, "theta", theta)
        object.__setattr__(self, "tau", tau)
        object.__setattr__(self, "fps", float(self.fps))

    @property
    def n_frames(self) -> int:
        return len(self.theta)

    def __len__(self) -> int:
        return len(self.theta)

    @property
    def times(self) -> np.ndarray:
        """(F,) float: seconds since the first frame."""
        return np.arange(len(self.theta)) / self.fps

    def __getitem__(self, index: slice | np.ndarray) -> Motion:
        """Frames ``index`` (a slice or index array) as a new Motion."""
        return Motion(self.theta[index], self.tau[index], self.fps, self.name)


def _finish(name: str, clip: Clip, ctx: ClipContext, root_height: float) -> Motion:
    """Clip into the limits, turn the heading from a random start, put the feet on the floor."""
    theta = soft_clip(clip.theta, ctx.limits)
    theta[:, YAW] = clip.headings(ctx.fps, ctx.rng.uniform(-np.pi, np.pi))
    tau = place_root(theta, ctx.fps, rest=ctx.rest.scaled(root_height), stance=clip.stance)
    return Motion(theta, tau, ctx.fps, name)


# ----------------------------------------------------------------------------------------
# Public generators
# ----------------------------------------------------------------------------------------
MotionGenerator = Callable[
    [int, float, np.random.Generator, JointLimits, float, RestPoseInfo], Motion
]


def _generator(name: str) -> MotionGenerator:
    clip_fn = CLIPS[name]

    def generate(
        n_frames: int,
        fps: float,
        rng: np.random.Generator,
        limits: JointLimits,
        root_height: float,
        rest_pose_info: RestPoseInfo,
    ) -> Motion:
        ctx = ClipContext(float(fps), rng, limits, rest_pose_info)
        return _finish(name, clip_fn(int(n_frames), ctx), ctx, float(root_height))

    generate.__name__ = f"generate_{name}"
    generate.__doc__ = (clip_fn.__doc__ or "").split("\n")[0]
    return generate


#: name -> generator ``(n_frames, fps, rng, limits, root_height, rest_pose_info) -> Motion``.
MOTIONS: dict[str, MotionGenerator] = {name: _generator(name) for name in CLIPS}
#: The motion sessions use unless told otherwise.
DEFAULT_MOTION = "mixed"


def make_motion(
    name: str = DEFAULT_MOTION,
    n_frames: int = 600,
    fps: float = 60.0,
    seed: int = 0,
    *,
    limits: JointLimits | None = None,
    root_height: float | None = None,
    rest: RestPoseInfo | None = None,
) -> Motion:
    """Generate library motion ``name``; the same arguments give identical arrays.

    Parameters
    ----------
    name : str
        A key of :data:`MOTIONS`.
    n_frames : int
        Frames (>= 1).
    fps : float
        Frame rate; trajectories are defined in seconds, so the rate only samples them.
    seed : int
        Non-negative; use :func:`seed_for` to keep training and test draws apart.
    limits : JointLimits, optional
        Default: the committed model's (:func:`default_limits`).
    root_height : float, optional
        Standing root (mid-hip) height of the subject, metres; default: that of
        ``rest`` (0.881 m for the mean body).
    rest : RestPoseInfo, optional
        Body proportions and named poses; default the mean body
        (``RestPoseInfo.from_model(model, nu)`` for a given subject).
    """
    if name not in MOTIONS:
        raise ValueError(f"motion: unknown name {name!r}; expected one of {sorted(MOTIONS)}")
    if isinstance(n_frames, bool) or not isinstance(n_frames, int | np.integer) or n_frames < 1:
        raise ValueError(f"motion {name}: n_frames must be a positive integer, got {n_frames!r}")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"motion {name}: fps must be positive, got {fps!r}")
    rest = RestPoseInfo.default() if rest is None else rest
    root_height = rest.root_height if root_height is None else float(root_height)
    if not (np.isfinite(root_height) and 0.3 < root_height < 2.0):
        raise ValueError(f"motion {name}: root_height must be in (0.3, 2.0) m, got {root_height}")
    limits = default_limits() if limits is None else limits
    rng = motion_rng(name, seed)
    return MOTIONS[name](int(n_frames), float(fps), rng, limits, root_height, rest)


def ground_motion(
    model: BodyModel, motion: Motion, nu: np.ndarray, *, lod: bool = True, batch: int = 64
) -> Motion:
    """Shift τ_z per frame so the lowest vertex of the posed body touches z = 0.

    Parameters
    ----------
    model : BodyModel
    motion : Motion
    nu : (n_shape,) or (1, n_shape) float
        The subject's shape.
    lod : bool
        Pose the ~3k-triangle level of detail (fast; within a few mm of the full mesh).
    batch : int
        Frames posed per call.
    """
    # Deferred: model.py pulls in scipy and the mesh code; the library is numpy-only without it.
    from bodymetry.estimation.body_model.model import BodyState

    nu = np.atleast_2d(np.asarray(nu, dtype=float))
    lowest = np.empty(len(motion))
    for s in range(0, len(motion), int(batch)):
        e = min(len(motion), s + int(batch))
        body = model.pose(BodyState(motion.tau[s:e], motion.theta[s:e], nu), lod=lod)
        lowest[s:e] = body.vertices[..., 2].min(axis=1)
    tau = motion.tau.copy()
    tau[:, 2] -= lowest
    return Motion(motion.theta, tau, motion.fps, motion.name)
