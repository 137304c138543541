"""Tests for the ``bodymetry`` command line (click's CliRunner, no subprocess)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import click
import cv2
import numpy as np
import pytest
import trimesh
from click.testing import CliRunner, Result

import bodymetry
import bodymetry.cli.model as cli_model
from bodymetry.capture.toy import write_toy_session
from bodymetry.cli import COMMANDS, main
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
    real = cli_model._load_model

    def load(path, n_shape):
        return model if path is None and n_shape == model.n_shape else real(path, n_shape)

    monkeypatch.setattr(cli_model, "_load_model", load)
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


# --- silhouettes ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def toy(tmp_path_factory) -> Path:
    """2 cameras, 40 frames, every 10th kept, nobody in view at frame 20; with ground truth."""
    folder = tmp_path_factory.mktemp("toy") / "s"
    write_toy_session(folder, cameras=2, frames=40, frame_step=10, empty_frames=(20,), seed=1)
    return folder


def test_silhouettes_json(toy: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    result = _run("silhouettes", str(toy), "--out", str(out), "--json")
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    assert data["frames"] == 4 and data["ground_truth"] is True
    assert set(data["cameras"]) == {"cam_00", "cam_01"}
    for entry in data["cameras"].values():
        assert entry["frames"] == 4
        assert entry["iou_mean"] > 0.85 and entry["iou_min"] > 0.85
        assert "shadow_false_positive" in entry
        assert entry["flags"] == {"empty": [20]}
    assert (out / "masks" / "cam_01" / "000030.png").is_file()
    assert (out / "overlays" / "cam_00" / "000000.jpg").is_file()
    saved = json.loads((out / "silhouettes.json").read_text())
    assert len(saved["per_frame"]) == 4
    assert {k: v for k, v in saved.items() if k != "per_frame"} == data
    mask = cv2.imread(str(out / "masks" / "cam_00" / "000010.png"), cv2.IMREAD_GRAYSCALE)
    assert set(np.unique(mask)) <= {0, 255} and mask.shape == (120, 160)


def test_silhouettes_table(toy: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    result = _run("silhouettes", str(toy), "--out", str(out), "--no-overlays")
    assert result.exit_code == 0, result.output
    assert "IoU mean" in result.stderr and "empty x1" in result.stderr
    assert f"wrote masks and overlays to {out}/" in " ".join(result.stderr.split())
    assert not (out / "overlays").exists()


def test_silhouettes_missing_session_is_one_line_error(tmp_path: Path) -> None:
    _assert_user_error(_run("silhouettes", str(tmp_path / "nope")), "not found")


# --- the command group ----------------------------------------------------------------------------


def test_help_lists_every_command():
    result = _run("--help")
    assert result.exit_code == 0, result.output
    listed = re.findall(r"^  (\S+)  ", result.stdout.split("Commands:")[1], re.MULTILINE)
    assert listed == sorted(COMMANDS)
    assert "demo" not in COMMANDS


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_each_command_has_help(name):
    result = _run(name, "--help")
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith("Usage: ") and f" {name} [OPTIONS]" in result.stdout


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_registered_help_line_is_the_docstring(name):
    """The group's list shows the registered line; it must say what the command says."""
    command = main.get_command(click.Context(main), name)
    assert command is not None and command.name == name
    registered = click.Command(name, help=COMMANDS[name][1])
    assert registered.get_short_help_str(1000) == command.get_short_help_str(1000)


def test_model_subcommands_have_help():
    for sub in ("bake", "info", "export"):
        result = _run("model", sub, "--help")
        assert result.exit_code == 0, result.output


def test_top_level_help_imports_no_command_module():
    """`bodymetry --help` stays fast: it lists the commands without importing them."""
    code = (
        "import sys\n"
        "from bodymetry.cli import main\n"
        "try:\n"
        "    main(['--help'])\n"
        "except SystemExit:\n"
        "    pass\n"
        "mods = [m for m in sys.modules if m.startswith('bodymetry.') or m == 'numpy']\n"
        "print(' '.join(sorted(mods)), file=sys.stderr)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    loaded = set(proc.stderr.split())
    assert loaded <= {
        "bodymetry.cli",
        "bodymetry.errors",
        "bodymetry.log",
        "bodymetry.cli.common",
        "bodymetry.cli.lazy",
    }, loaded
