"""Weight read from the posed bodies the silhouettes show, not from the canonical one.

A body's volume does not change when it moves. The body model's does: posing
the mesh (per-part rotations, the learned pose deformation, the least-squares
stitching of the parts) loses volume where joints bend and gains some where
the shoulders lift. Over the studio's benchmark fits (41 sessions, each fitted
shape in each of its frames' poses) the posed volume differed from the
canonical body's by -5.2 to +1.7 kg, most of it at the hips in flexion. The
fit matches the posed silhouettes, so where a pose loses volume the fit makes
the shape fuller to fill them, and the canonical body, measured unposed,
keeps that excess: the session stage read the weight +0.72 kg high on
average, and six of the 41 sessions beyond issue 15's 1.5 kg.

The posed bodies are what the silhouettes measured. So the session stage reads
the volume from them: the median over the frames of the fitted body's volume
in each frame's pose (the median, so that the few poses in which the model
loses most do not decide it), times the density. On the same fits this reads
+0.30 kg on average (RMS 1.07 -> 0.82 kg, one session beyond 1.5 kg). The
standard error adds the median's sampling error over the frames to the
shape's. Only the volume, the weight and the BMI change.

``--set session_shape.posed_weight=false`` keeps the canonical body's weight.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from bodymetry.estimation.body_model import geometry
from bodymetry.estimation.body_model.biometrics import body_mass_index
from bodymetry.estimation.body_model.model import PosedBody
from bodymetry.estimation.outline_check import median_standard_error

__all__ = ["posed_volumes", "weight_from_posed"]


def posed_volumes(posed: PosedBody) -> np.ndarray:
    """Volume (F,) of each posed body, m³.

    Parameters
    ----------
    posed : PosedBody
        The fitted bodies at full resolution (closed and watertight, so the
        divergence theorem's sum is the volume whatever the pose), e.g.
        :meth:`BodyModel.pose_states` of the frames' ``[τ, θ, ν]``.
    """
    return np.atleast_1d(geometry.mesh_volume(posed.vertices, posed.faces))


def weight_from_posed(
    biometrics: Mapping[str, float],
    standard_errors: Mapping[str, float],
    volumes: np.ndarray,
    density: float,
) -> tuple[dict[str, float], dict[str, float]]:
    """The measurements with the volume read from the posed bodies.

    Parameters
    ----------
    biometrics, standard_errors : mapping of str to float
        The canonical body's measurements and their standard errors (mm, kg, l;
        ``height_mm`` as the session reports it, for the BMI).
    volumes : (F,) float
        :func:`posed_volumes`, m³.
    density : float
        kg/m³.

    Returns
    -------
    biometrics, standard_errors : dict of str to float
        New dicts: ``volume_l`` the median posed volume, ``weight_kg`` it times
        the density, ``bmi`` from that weight (where ``height_mm`` is given); the
        volume's and weight's standard errors add the median's
        (:func:`~bodymetry.estimation.outline_check.median_standard_error`) to the
        shape's in quadrature, the BMI's adds the relative errors of weight and
        height. Everything else as given.
    """
    volumes = np.asarray(volumes, dtype=float)
    if volumes.ndim != 1 or len(volumes) == 0 or not np.all(np.isfinite(volumes)):
        raise ValueError(f"posed volumes: expected finite values (F,), got {volumes!r}")
    if not density > 0:
        raise ValueError(f"density: expected a positive value in kg/m^3, got {density}")
    volume = float(np.median(volumes))
    volume_se = median_standard_error(volumes) if len(volumes) > 1 else 0.0
    bios, se = dict(biometrics), dict(standard_errors)
    bios["volume_l"] = volume * 1000.0
    bios["weight_kg"] = volume * density
    for key, scale in (("volume_l", 1000.0), ("weight_kg", density)):
        se[key] = float(np.hypot(se.get(key, 0.0), volume_se * scale))
    if "height_mm" in bios:
        bios["bmi"] = body_mass_index(bios["weight_kg"], bios["height_mm"])
        # Relative errors add: BMI = weight / height².
        se["bmi"] = bios["bmi"] * float(
            np.hypot(
                se["weight_kg"] / bios["weight_kg"],
                2 * se.get("height_mm", 0.0) / bios["height_mm"],
            )
        )
    return bios, se
