"""Damped least squares (Levenberg-Marquardt) shared by the contour refinement
(:mod:`bodymetry.estimation.refinement`) and the session stage
(:mod:`bodymetry.estimation.session_shape`).

* :class:`Damping` and :func:`damped_step`: the damping schedule (try ever more
  damped steps until one lowers the cost);
* :func:`marquardt` and :func:`damped_inverse`: two ways of damping a normal
  matrix, side by side. They differ on purpose in the last digits (each keeps
  the results its caller has always had): :func:`marquardt` returns the damped
  matrix ``A + λ (diag A + 1e-9)``, whose floor ``1e-9`` is scaled by ``λ``;
  :func:`damped_inverse` returns the *inverse* of
  ``A + λ diag A + (1e-9 + 1e-9 tr(A) / n) I``, whose floor does not depend on
  ``λ`` (so the matrix stays invertible at ``λ = 0``, where the session stage
  takes a covariance) and grows with the matrix's mean diagonal.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Damping", "damped_inverse", "damped_step", "marquardt"]


@dataclass
class Damping:
    """The Levenberg-Marquardt damping λ of one descent (:func:`damped_step`).

    Divided by 3 after an accepted step (down to 1e-6), multiplied by 4 after a
    rejected one; shared by the frame refinement and the session stage.
    """

    lam: float = 1e-2


def damped_step(
    propose: Callable[[float], tuple[float, Any]],
    cost: float,
    damping: Damping,
    tolerance: float,
    *,
    max_lam: float = 1e4,
    retries: int | None = None,
) -> tuple[Any, float, bool]:
    """Try ever more damped steps until one lowers ``cost``.

    Parameters
    ----------
    propose : callable
        ``propose(lam)`` -> (the cost of the step damped by ``lam``, the step's
        payload), e.g. the new state and its correspondences.
    cost : float
        The current cost.
    damping : Damping
        Updated in place.
    tolerance : float
        A step that lowers the cost by less than this fraction is accepted but
        ends the descent (``improved`` False).
    max_lam : float
        Give up once λ exceeds this (checked before each try) ...
    retries : int, optional
        ... or, when given, after this many tries whatever λ.

    Returns
    -------
    payload : object or None
        The accepted step's payload; None when every try raised the cost.
    cost : float
        Its cost (the input cost when none was accepted).
    improved : bool
        Whether to go on descending.
    """
    tries = 0
    while (tries < retries) if retries is not None else (damping.lam <= max_lam):
        tries += 1
        new_cost, payload = propose(damping.lam)
        if new_cost < cost:
            damping.lam = max(damping.lam / 3.0, 1e-6)
            return payload, new_cost, cost - new_cost > tolerance * cost
        damping.lam *= 4.0
    return None, cost, False


def marquardt(A: np.ndarray, lam: float) -> np.ndarray:
    """``A + λ (diag A + 1e-9)``: a normal matrix damped by Marquardt's scaling
    (the 1e-9 keeps directions no residual sees solvable).

    Unlike :func:`damped_inverse`, the floor is scaled by ``λ`` (nothing is
    added at ``λ = 0``) and the damped matrix is returned, for the caller to
    solve with.

    Parameters
    ----------
    A : (n, n) float
        A symmetric positive semi-definite normal matrix.
    lam : float
        Damping λ >= 0.

    Returns
    -------
    (n, n) float
        The damped matrix.
    """
    return A + lam * np.diag(np.diag(A) + 1e-9)


def damped_inverse(A: np.ndarray, lam: float) -> np.ndarray:
    """``(A + λ diag A + ε)⁻¹`` of a frame's pose block (ε keeps unseen joints solvable).

    Unlike :func:`marquardt`, the floor ``ε = (1e-9 + 1e-9 tr(A) / n) I`` is
    added whatever ``λ`` (the matrix is invertible at ``λ = 0`` too) and scales
    with the mean diagonal, and the inverse is returned, not the matrix.

    Parameters
    ----------
    A : (n, n) float
        A symmetric positive semi-definite normal matrix.
    lam : float
        Damping λ >= 0.

    Returns
    -------
    (n, n) float
        The inverse of the damped matrix.
    """
    damped = A + np.diag(lam * np.diag(A) + 1e-9 + 1e-9 * np.trace(A) / len(A))
    return np.linalg.inv(damped)
