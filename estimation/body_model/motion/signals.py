"""Smooth-signal primitives of the motion library (all numpy, shapes in the docstrings).

Angle wrapping, the minimum-jerk profile of scripted moves, smooth random signals
(sums of sinusoids), temporal smoothing and a running maximum (the arm fade), and
the clips into the joint limits: :func:`inner_clip` for key poses and the C²
:func:`soft_clip` for whole trajectories. The heading (``skeleton.YAW``) is never
clipped.
"""

from __future__ import annotations

import numpy as np

from bodymetry.estimation.body_model.skeleton import YAW, JointLimits


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Angles (any shape) into [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def minjerk(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk profile 0 -> 1 on ``s`` (any shape) in [0, 1].

    Speed and acceleration are zero at both ends.
    """
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


def _margins(limits: JointLimits) -> np.ndarray:
    """(37,) soft-clip margin per DOF: 0.05 rad, or a tenth of a narrower range."""
    return np.minimum(0.05, 0.1 * np.maximum(limits.upper - limits.lower, 0.0))


def inner_clip(theta: np.ndarray, limits: JointLimits) -> np.ndarray:
    """Clip key poses ``theta`` (..., 37) into the limits shrunk by the soft-clip margin.

    The heading (``YAW``) is left free.
    """
    m = _margins(limits)
    lo, hi = limits.lower + m, limits.upper - m
    out = np.clip(theta, lo, np.maximum(lo, hi))
    out[..., YAW] = np.asarray(theta)[..., YAW]
    return out


def soft_clip(theta: np.ndarray, limits: JointLimits) -> np.ndarray:
    """Smoothly squash ``theta`` (..., 37) into the limits (C², the identity inside the margins).

    Values more than the margin ``m = min(0.05, range / 10)`` inside a bound are
    unchanged; beyond, ``bound -/+ m (1 - tanh(...))`` approaches the bound without
    reaching it. The heading (root.z) is not clipped: it is wrapped.
    """
    theta = np.array(theta, dtype=float)
    m = _margins(limits)
    lo_in, hi_in = limits.lower + m, limits.upper - m
    safe_m = np.where(m > 0, m, 1.0)
    over = (theta > hi_in) & (m > 0)
    under = (theta < lo_in) & (m > 0)
    hi_val = hi_in + safe_m * np.tanh((theta - hi_in) / safe_m)
    lo_val = lo_in - safe_m * np.tanh((lo_in - theta) / safe_m)
    out = np.where(over, hi_val, np.where(under, lo_val, theta))
    out = np.where(m > 0, out, limits.lower)  # zero-width DOFs sit on their bound
    out[..., YAW] = theta[..., YAW]
    return out


def smooth_unit(rng: np.random.Generator, t: np.ndarray, f_lo, f_hi, k: int = 3) -> np.ndarray:
    """Smooth random signals (T, D) in [-1, 1] at times ``t`` (T,): ``k`` sinusoids per column.

    ``f_lo``, ``f_hi`` are (D,) (or scalar: D = 1) frequency bounds in Hz; weights sum
    to 1 so the bound holds exactly and the speed is at most ``2 pi f_hi``. Frequencies
    are drawn independently (incommensurate), so the signal does not repeat.
    """
    f_lo = np.atleast_1d(np.asarray(f_lo, dtype=float))
    f_hi = np.atleast_1d(np.asarray(f_hi, dtype=float))
    D = np.broadcast_shapes(f_lo.shape, f_hi.shape)[0]
    freq = rng.uniform(0.0, 1.0, size=(k, D)) * (f_hi - f_lo) + f_lo
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(k, D))
    weight = rng.dirichlet(np.full(k, 0.7), size=D).T  # (k, D), one component usually dominates
    arg = 2.0 * np.pi * freq[:, None, :] * t[None, :, None] + phase[:, None, :]
    return np.einsum("kd,ktd->td", weight, np.sin(arg))


def smooth_time(x: np.ndarray, fps: float, sigma_s: float) -> np.ndarray:
    """Gaussian smoothing of (F,) ``x`` over time (edges held)."""
    r = max(1, round(3.0 * sigma_s * fps))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / (sigma_s * fps)) ** 2)
    padded = np.concatenate([np.full(r, x[0]), x, np.full(r, x[-1])])
    return np.convolve(padded, k / k.sum(), mode="valid")


def max_filter(x: np.ndarray, half: int) -> np.ndarray:
    """Running maximum of (F,) ``x`` over ``2 half + 1`` frames (edges held)."""
    padded = np.concatenate([np.full(half, x[0]), x, np.full(half, x[-1])])
    return np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1).max(axis=1)
