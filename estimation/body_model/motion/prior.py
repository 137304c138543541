"""The pose prior: independent θ draws for discriminative training sets.

The paper (§6) draws its training poses from motion capture; here they are frames
of the library's ``mixed`` clips, so training sees every action of the library,
blends included, within the joint limits. Root positions for such independent
poses come from :func:`~.contact.place_root` (without ``fps``), exact floor contact
from grounding the posed mesh. Seeds: ``seeds.seed_for("train", i)`` for training
draws, ``"test"`` for held-out ones.
"""

from __future__ import annotations

import numpy as np

from bodymetry.estimation.body_model.motion.clips import CLIPS, ClipContext
from bodymetry.estimation.body_model.motion.rest import RestPoseInfo, default_limits
from bodymetry.estimation.body_model.motion.signals import soft_clip
from bodymetry.estimation.body_model.skeleton import N_POSE, YAW, JointLimits


def sample_pose_prior(
    rng: np.random.Generator,
    n: int,
    limits: JointLimits | None = None,
    *,
    rest: RestPoseInfo | None = None,
    clip_seconds: float = 12.0,
    per_clip: int = 6,
    uniform_heading: bool = True,
) -> np.ndarray:
    """Independent pose draws (n, 37) for training sets (the paper's §6 draws from mocap).

    Draws ``ceil(n / per_clip)`` ``mixed`` clips of ``clip_seconds`` (sampled at 10 fps)
    and takes ``per_clip`` distinct random frames of each, then shuffles. With
    ``uniform_heading`` the heading is redrawn uniformly in [-pi, pi) (the clips'
    headings only drift). For root positions use :func:`~.contact.place_root` (independent
    frames) and then ground the posed mesh (as :func:`~.library.ground_motion` does).
    """
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
        raise ValueError(f"sample_pose_prior: n must be a non-negative integer, got {n!r}")
    per_clip = int(per_clip)
    frames = max(per_clip, round(clip_seconds * 10.0))
    if per_clip < 1:
        raise ValueError(f"sample_pose_prior: per_clip must be >= 1, got {per_clip}")
    limits = default_limits() if limits is None else limits
    rest = RestPoseInfo.default() if rest is None else rest
    ctx = ClipContext(10.0, rng, limits, rest)
    out = np.empty((0, N_POSE))
    chunks = []
    for _ in range(-(-int(n) // per_clip)):
        clip = CLIPS["mixed"](frames, ctx)
        theta = soft_clip(clip.theta, limits)
        theta[:, YAW] = clip.headings(ctx.fps, rng.uniform(-np.pi, np.pi))
        chunks.append(theta[rng.choice(frames, size=per_clip, replace=False)])
    if chunks:
        out = np.concatenate(chunks)[: int(n)]
        out = out[rng.permutation(len(out))]
    if uniform_heading:
        out[:, YAW] = rng.uniform(-np.pi, np.pi, size=len(out))
    return out
