"""Shape from one segmented photo without calibration (paper §6, Figure 2).

Without calibration the silhouette's position and size say nothing about the
body's size, so only the scale- and translation-invariant shape-context
feature is used: p(ν | X_sc), averaged over the rig's cameras' models (each was
trained from a different viewpoint). The body is then scaled to a reference
height the user gives, and measured: lengths scale with the height ratio s,
volume and weight with s³. Comparing two photos of one person at the same
reference height gives a weight change, as the paper's weight-loss example.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bodymetry.errors import InputError
from bodymetry.estimation.body_model.biometrics import Biometrics, body_mass_index, measure
from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.training import DiscriminativeModels

#: Silhouettes smaller than this many pixels are refused as "no person".
MIN_MASK_PIXELS = 200


def read_mask(path: str | Path) -> np.ndarray:
    """A binary person mask from an image file (non-zero = person) -> (H, W) bool."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: mask file not found")
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InputError(f"{path}: not a readable image")
    mask = image > 127
    if mask.sum() < MIN_MASK_PIXELS:
        raise InputError(
            f"{path}: the mask holds {int(mask.sum())} person pixels; no person in view?"
        )
    if mask.all():
        raise InputError(f"{path}: the mask is all person (inverted?)")
    return mask


@dataclass(frozen=True)
class PhotoEstimate:
    """Shape and measurements from one photo.

    Attributes
    ----------
    nu : (n_shape,) float
    scale : float
        Reference height / the shape's own height.
    biometrics : Biometrics
        Scaled to the reference height.
    """

    nu: np.ndarray
    scale: float
    biometrics: Biometrics


def estimate_photo(
    mask: np.ndarray,
    models: DiscriminativeModels,
    body: BodyModel,
    height_mm: float,
    seed: int = 0,
    density: float = 1000.0,
) -> PhotoEstimate:
    """Estimate shape and measurements from one silhouette at a reference height."""
    if not 500.0 <= height_mm <= 2500.0:
        raise InputError(
            f"--height-mm: expected a body height in millimetres (500-2500), got {height_mm}"
        )
    rng = np.random.default_rng(seed)
    x_sc = models.features(models.camera_names[0], mask, rng)[1]
    nu = np.mean(
        [models.models[cam]["nu_sc"].predict(x_sc[None])[0] for cam in models.camera_names], axis=0
    )
    raw = measure(body, nu[None], density=density)[0].to_dict()
    s = height_mm / raw["height_mm"]
    scaled = {
        k: v * s**3 if k in ("weight_kg", "volume_l") else v if k == "bmi" else v * s
        for k, v in raw.items()
    }
    scaled["bmi"] = body_mass_index(scaled["weight_kg"], height_mm)
    return PhotoEstimate(nu, float(s), Biometrics(**scaled))


def compare_photos(before: PhotoEstimate, after: PhotoEstimate) -> dict:
    """Measurement changes from ``before`` to ``after`` (same reference height)."""
    b, a = before.biometrics.to_dict(), after.biometrics.to_dict()
    return {f"{k}_change": a[k] - b[k] for k in b}
