"""Tests for the ``bodymetry`` command line (click's CliRunner, no subprocess)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner, Result

import bodymetry
from bodymetry import cli
from bodymetry.cli import main
from bodymetry.estimation.body_model.biometrics import MEASUREMENTS, measure
from bodymetry.estimation.body_model.model import BodyModel

# --------------------------------------------------------------------------------------
# Tolerances, all in one place.
# --------------------------------------------------------------------------------------
# Mesh files against the model's own vertices (PLY/OBJ round trip; metres).
ATOL_MESH = 1e-6
# Rounding in `model info` (0.1 mm, 0.01 kg).
ATOL_INFO_MM = 0.05
ATOL_INFO_KG = 0.005
# The LOD's triangle count (target 3,000).
LOD_TRIANGLES = (2500, 3500)


@pytest.fixture(scope="module")
def model() -> BodyModel:
    return BodyModel.load()


@pytest.fixture()
def cached_model(monkeypatch, model):
    """Serve the default model from memory (loading it costs ~0.4 s per command)."""
    real = cli._load_model

    def load(path, n_shape):
        return model if path is None and n_shape == model.n_shape else real(path, n_shape)

    monkeypatch.setattr(cli, "_load_model", load)
    return model


def _run(*args: str) -> Result:
    return CliRunner().invoke(main, list(args))


def _assert_user_error(result: Result, *patterns: str) -> None:
    """Exit status 2, one line on stderr naming the problem, no traceback."""
    assert result.exit_code == 2, (result.exit_code, result.output, result.exception)
    assert isinstance(result.exception, SystemExit)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: ")
    assert "Traceback" not in result.output
    for pattern in patterns:
        assert re.search(pattern, lines[0]), (pattern, lines[0])


def _load_mesh(path) -> trimesh.Trimesh:
    mesh = trimesh.load(path, process=False, force="mesh")
    assert isinstance(mesh, trimesh.Trimesh)
    return mesh


def test_version():
    result = _run("--version")
    assert result.exit_code == 0
    assert bodymetry.__version__ in result.stdout


# --- model info -----------------------------------------------------------------------------------


def test_model_info_json(model):
    result = _run("model", "info", "--json")  # the real loader, end to end
    assert result.exit_code == 0, result.output
    assert result.stdout.endswith("\n") and result.stdout.count("\n") == 1  # one line
    info = json.loads(result.stdout)  # and nothing else on stdout
    assert info["vertices"] == 13380
    assert info["triangles"] == 26756
    assert len(info["parts"]) == 15 and info["parts"][0] == "pelvis"
    assert info["pose_dofs"] == 37
    assert info["shape_dofs"] == 9
    assert info["shape_dofs_stored"] >= 9
    assert LOD_TRIANGLES[0] <= info["lod_triangles"] <= LOD_TRIANGLES[1]
    assert info["lod_vertices"] == model.lod.n_vertices
    assert "knuckle_l" in info["keypoints"]
    bio = measure(model, np.zeros(model.n_shape))[0].to_dict()
    mean = info["mean_body"]
    assert set(mean) == set(MEASUREMENTS)
    assert mean["height_mm"] == pytest.approx(bio["height_mm"], abs=ATOL_INFO_MM)
    assert mean["arm_span_mm"] == pytest.approx(bio["arm_span_mm"], abs=ATOL_INFO_MM)
    assert mean["weight_kg"] == pytest.approx(bio["weight_kg"], abs=ATOL_INFO_KG)
    prov = info["provenance"]
    assert re.fullmatch(r"[0-9a-f]{64}", prov["wheel_sha256"])
    assert prov["wheel"].endswith(".whl")
    assert "licences" in prov


def test_model_info_table(cached_model):
    result = _run("model", "info", "--shape-dofs", "9")
    assert result.exit_code == 0, result.output
    assert "13380" in result.stderr and "26756" in result.stderr


def test_model_info_missing_model_file(tmp_path):
    path = tmp_path / "missing.npz"
    _assert_user_error(_run("model", "info", "--model", str(path)), re.escape(str(path)))


def test_model_info_corrupt_model_file(tmp_path):
    path = tmp_path / "corrupt.npz"
    path.write_bytes(b"not a zip at all")
    _assert_user_error(_run("model", "info", "--model", str(path)), re.escape(str(path)))


def test_too_many_shape_dofs():
    _assert_user_error(_run("model", "info", "--shape-dofs", "999"), "n_shape", "999")


# --- model export ---------------------------------------------------------------------------------


@pytest.mark.parametrize("ext", [".ply", ".obj"])
def test_export_tpose(cached_model, tmp_path, ext):
    out = tmp_path / f"body{ext}"
    result = _run("model", "export", "--pose", "tpose", "--out", str(out))
    assert result.exit_code == 0, result.output
    mesh = _load_mesh(out)
    assert len(mesh.vertices) == 13380
    assert len(mesh.faces) == 26756
    np.testing.assert_array_equal(mesh.faces, cached_model.faces())
    assert mesh.vertices[:, 2].min() == pytest.approx(0.0, abs=ATOL_MESH)  # feet on the floor
    assert mesh.is_watertight and mesh.volume > 0
    # Arms out: the T-pose is wider than the body is tall, almost.
    extent = mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)
    assert extent[0] > 0.85 * extent[2]
    assert [p.name for p in tmp_path.iterdir()] == [out.name]  # no temporary files left


def test_export_rest_pose_is_the_canonical_body(cached_model, tmp_path):
    out = tmp_path / "rest.ply"
    result = _run("model", "export", "--pose", "rest", "--shape", "1.5, -0.5", "--out", str(out))
    assert result.exit_code == 0, result.output
    nu = np.zeros((1, cached_model.n_shape))
    nu[0, :2] = [1.5, -0.5]
    np.testing.assert_allclose(
        _load_mesh(out).vertices, cached_model.canonical_vertices(nu)[0], atol=ATOL_MESH
    )


def test_export_lod(cached_model, tmp_path):
    out = tmp_path / "lod.ply"
    result = _run("model", "export", "--lod", "--pose", "apose", "--out", str(out))
    assert result.exit_code == 0, result.output
    mesh = _load_mesh(out)
    assert len(mesh.vertices) == cached_model.lod.n_vertices
    np.testing.assert_array_equal(mesh.faces, cached_model.faces(lod=True))
    assert mesh.is_watertight


def test_export_bad_extension(tmp_path):
    out = tmp_path / ("a-rather-long-folder-name-" * 3) / "body.xyz"
    _assert_user_error(
        _run("model", "export", "--out", str(out)), "unsupported extension", r"\.ply"
    )
    assert not out.exists()


@pytest.mark.parametrize(
    ("shape", "patterns"),
    [
        ("1,2,x", ["--shape", "comma-separated numbers", re.escape("'1,2,x'")]),
        (",".join(["0.5"] * 10), ["--shape", "10 values given", "9"]),
        ("nan", ["--shape", "finite"]),
        ("[bold]1,[/x]", ["--shape", re.escape("'[bold]1,[/x]'")]),  # text, not markup
    ],
)
def test_export_bad_shape(cached_model, tmp_path, shape, patterns):
    out = tmp_path / "body.ply"
    _assert_user_error(_run("model", "export", "--shape", shape, "--out", str(out)), *patterns)
    assert not out.exists()


def test_export_unknown_pose_is_a_usage_error(tmp_path):
    result = _run("model", "export", "--pose", "cartwheel", "--out", str(tmp_path / "b.ply"))
    assert result.exit_code == 2
    assert "cartwheel" in result.stderr
    assert "Traceback" not in result.output


# --- demo -------------------------------------------------------------------------------------


def test_demo(cached_model, tmp_path):
    out = tmp_path / "demo"
    result = _run("demo", "--out", str(out))
    assert result.exit_code == 0, result.output
    measurements = json.loads((out / "measurements.json").read_text(encoding="utf-8"))
    assert len(measurements) == 5 and "mean" in measurements
    for values in measurements.values():
        assert set(values) == set(MEASUREMENTS)
    mean = measure(cached_model, np.zeros(cached_model.n_shape))[0].to_dict()
    assert measurements["mean"] == pytest.approx(mean, rel=1e-12)
    meshes = sorted(out.glob("body_*.ply"))
    assert len(meshes) == 5
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["measurements.json", *(p.name for p in meshes)]
    )
    for path in meshes[:2]:
        mesh = _load_mesh(path)
        assert len(mesh.vertices) == 13380 and len(mesh.faces) == 26756
