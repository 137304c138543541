"""Standing height read from the floor, as a stadiometer reads it.

The biometrics measure the canonical body: the distance from the soles to the
top of the head of the fitted shape standing at θ = 0. That is the height only
when the fitted body stands *on* the floor. Fitted to silhouettes it can stand
in it: under a dark shoe the soft contact shadow on the floor blends with the
shoe into pixels the capture stage calls person, the silhouettes reach a pixel
row too low, and the fit answers with a body whose soles sink below the floor
while its crown stays where the silhouettes put it. On the studio's tight
subjects the session stage's soles stood 1-8 mm in the floor (median over
frames), and the heights read 1-8 mm high by about as much (the soles' depth
and the height's excess moved together between captured and true silhouettes:
seed 82 -8.4 -> -2.6 mm and +10.5 -> +4.6 mm; docs/session-shape.md, "Where
the height error comes from").

A stadiometer measures from the floor to the crown. The calibration gives the
floor (world z = 0, docs/calibration-format.md), and the crown is where the
silhouettes put it, so where the fitted soles sink below the floor the height
is read from the floor: the canonical height less the soles' depth (the median
over the frames of each frame's lowest point, so a frame with both feet off the
ground does not count against the others). It is one-sided: soles above the
floor are left alone, since a foot lifted, a force plate or a step, a world
whose z = 0 lies below the floor, or feet the segmentation lost all put them
there, and none of them says the crown is lower.

Sinking is not the only reason for soles below z = 0: the person may stand on
a floor lower than the calibration's (beside a treadmill or a platform whose
top the calibration took for the floor, on a mat the board lay on). Shadow
bleeding under the shoes sank the studio's soles at most 8.4 mm (58 sessions,
median 2.7 mm); on Pose2Sim's `Demo_MultiPerson` the woman's fitted soles
stood 32 mm below z = 0 in the median frame with her feet outlined right in
every view, beside the man on the treadmill, whose soles stood 15-47 mm above
it. So the floor is trusted only down to :data:`MAX_SOLE_DEPTH`
(:func:`reads_from_floor`); deeper, the height stays the fitted body's own and
the run says so (the ``floor`` caveat, :mod:`bodymetry.estimation.caveats`).

``--set session_shape.floor_height=false`` keeps the canonical height (a world
whose z = 0 is not the floor, e.g. a calibration board's own top surface lying
on a thick mat).
"""

from __future__ import annotations

import numpy as np

from bodymetry.estimation.body_model.biometrics import body_mass_index
from bodymetry.estimation.body_model.model import PosedBody
from bodymetry.estimation.outline_check import median_standard_error

__all__ = ["MAX_SOLE_DEPTH", "from_the_floor", "lowest_points", "reads_from_floor", "sole_depth"]

#: The deepest the fitted soles may stand below the floor (metres) for the height
#: to be read from it: about twice the studio's deepest (8.4 mm over 58 sessions).
MAX_SOLE_DEPTH = 0.015


def reads_from_floor(depth: float) -> bool:
    """Whether the height is read from the floor for soles ``depth`` metres below it
    (:func:`sole_depth`): when they sink, by at most :data:`MAX_SOLE_DEPTH`."""
    return -MAX_SOLE_DEPTH <= depth < 0.0


def lowest_points(posed: PosedBody) -> np.ndarray:
    """Height (F,) of each posed body's lowest vertex above the floor, metres.

    Parameters
    ----------
    posed : PosedBody
        The fitted bodies at full resolution, world frame (floor at z = 0), e.g.
        :meth:`BodyModel.pose_states` of the frames' ``[τ, θ, ν]``.
    """
    return posed.vertices[..., 2].min(axis=1)


def sole_depth(lowest: np.ndarray) -> tuple[float, float]:
    """How far the fitted soles stood below the floor, and its standard error (metres).

    Parameters
    ----------
    lowest : (F,) float
        Each frame's lowest point above the floor (:func:`lowest_points`).

    Returns
    -------
    depth : float
        The median of ``lowest`` when it is below the floor (negative), else 0.
    se : float
        The standard error of that median over the frames (1.2533 σ/√F; 0 when
        the depth is 0 or there is one frame).
    """
    lowest = np.asarray(lowest, dtype=float)
    if lowest.ndim != 1 or lowest.size == 0 or not np.all(np.isfinite(lowest)):
        raise ValueError(f"lowest: expected (F,) finite values, got {lowest!r}")
    depth = min(float(np.median(lowest)), 0.0)
    if depth == 0.0 or lowest.size < 2:
        return depth, 0.0
    return depth, median_standard_error(lowest)


def from_the_floor(
    biometrics: dict[str, float],
    standard_errors: dict[str, float],
    depth: float,
    depth_se: float,
) -> tuple[dict[str, float], dict[str, float]]:
    """The measurements with the height read from the floor (see the module docstring).

    Parameters
    ----------
    biometrics, standard_errors : dict of str to float
        The canonical body's measurements (``height_mm``, ``weight_kg``, ``bmi``, ...)
        and their standard errors.
    depth, depth_se : float
        The soles' depth below the floor and its standard error, metres
        (:func:`sole_depth`; 0: nothing changes).

    Returns
    -------
    biometrics, standard_errors : dict of str to float
        New dicts: ``height_mm`` plus ``depth``, its standard error with
        ``depth_se`` added in quadrature, and ``bmi`` of the new height.
    """
    out, se = dict(biometrics), dict(standard_errors)
    if depth == 0.0:
        return out, se
    out["height_mm"] = biometrics["height_mm"] + depth * 1000.0
    se["height_mm"] = float(np.hypot(standard_errors.get("height_mm", 0.0), depth_se * 1000.0))
    if "bmi" in out and "weight_kg" in out:
        out["bmi"] = body_mass_index(out["weight_kg"], out["height_mm"])
    return out, se
