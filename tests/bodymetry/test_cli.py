"""Tests for the ``bodymetry`` command line (click's CliRunner, no subprocess)."""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import click
import cv2
import numpy as np
import pytest
import trimesh
import yaml
from click.testing import CliRunner, Result

import bodymetry
import bodymetry.cli.model as cli_model
from bodymetry.capture.toy import write_toy_session
from bodymetry.cli import COMMANDS, main
from bodymetry.cli.common import describe_error, labelled_progress, warnings_to_log
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.biometrics import MEASUREMENTS, measure
from bodymetry.estimation.body_model.model import DEFAULT_SHAPE_DOFS, BodyModel
from bodymetry.estimation.records import FrameRecord
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import RunResults, SessionInfo
from bodymetry.log import PROGRESS_LOGGER, setup_logging

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
    assert info["shape_dofs"] == DEFAULT_SHAPE_DOFS
    assert info["shape_dofs_stored"] >= DEFAULT_SHAPE_DOFS
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
        (
            ",".join(["0.5"] * (DEFAULT_SHAPE_DOFS + 1)),
            ["--shape", f"{DEFAULT_SHAPE_DOFS + 1} values given", str(DEFAULT_SHAPE_DOFS)],
        ),
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
        "bodymetry.threads",  # the BLAS limit set at import (os and sys only)
    }, loaded


# --- one error handler: one line, the right exit status ---------------------------------------
def _assert_one_line(result: Result, status: int, *patterns: str) -> str:
    """Exit ``status``, one line on stderr (after any progress lines), no traceback."""
    assert result.exit_code == status, (result.exit_code, result.output, result.exception)
    assert isinstance(result.exception, SystemExit), result.exception
    assert "Traceback" not in result.output
    errors = [ln for ln in result.stderr.splitlines() if "error" in ln]
    assert len(errors) == 1, result.stderr
    line = errors[0]
    for pattern in patterns:
        assert re.search(pattern, line), (pattern, line)
    return line


@pytest.fixture()
def read_only_folder(tmp_path: Path):
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o500)
    if os.access(folder, os.W_OK):  # root ignores the mode
        folder.chmod(0o700)
        pytest.skip("running as a user who can write to a read-only folder")
    yield folder
    folder.chmod(0o700)


@pytest.mark.parametrize("command", ["process", "silhouettes"])
def test_unwritable_out_is_one_line(toy: Path, read_only_folder: Path, command: str) -> None:
    out = read_only_folder / "run"
    result = _run(command, str(toy), "--out", str(out))
    _assert_one_line(result, 2, r"^error: ", re.escape(str(out)), "Permission denied")


def test_unwritable_out_file_names_the_file_not_a_temporary(
    cached_model, read_only_folder: Path
) -> None:
    out = read_only_folder / "body.ply"
    line = _assert_one_line(_run("model", "export", "--out", str(out)), 2, "Permission denied")
    assert f"error: {out}: Permission denied" in " ".join(line.split())


@pytest.fixture()
def truncated_run(tmp_path: Path) -> Path:
    run = tmp_path / "run"
    run.mkdir()
    (run / "results.json").write_text('{"format": 2, "session": {"name": "s"}, "fra')
    return run


@pytest.mark.parametrize("command", ["evaluate", "report"])
def test_truncated_results_json_is_one_line(truncated_run: Path, command: str) -> None:
    _assert_one_line(
        _run(command, str(truncated_run)),
        2,
        r"^error: ",
        re.escape(str(truncated_run / "results.json")),
        "not a readable JSON file",
    )


def test_missing_session_is_one_line(tmp_path: Path) -> None:
    _assert_one_line(
        _run("process", str(tmp_path / "nope"), "--out", str(tmp_path / "run")),
        2,
        re.escape(str(tmp_path / "nope")),
        "session folder not found",
    )
    assert not (tmp_path / "run").exists()


def test_malformed_session_yaml_is_one_line(toy: Path, tmp_path: Path) -> None:
    session = tmp_path / "s"
    shutil.copytree(toy, session)
    (session / "session.yaml").write_text("format: bodymetry-session/1\ncameras: [a\n")
    _assert_one_line(
        _run("process", str(session), "--out", str(tmp_path / "run")),
        2,
        re.escape(str(session / "session.yaml")),
        "not valid YAML at line",
    )


def _boom(*args, **kwargs):
    raise ZeroDivisionError("float division by zero")


def test_internal_error_is_one_line_with_status_1(monkeypatch, toy: Path, tmp_path: Path) -> None:
    import bodymetry.cli.process as cli_process

    monkeypatch.setattr(cli_process, "process_session", _boom)
    result = _run("process", str(toy), "--out", str(tmp_path / "run"))
    line = _assert_one_line(result, 1)
    assert line == (
        "internal error: ZeroDivisionError: float division by zero (run with -v for the traceback)"
    )


def test_internal_error_with_v_prints_the_traceback(monkeypatch, toy: Path, tmp_path: Path) -> None:
    import bodymetry.cli.process as cli_process

    monkeypatch.setattr(cli_process, "process_session", _boom)
    result = _run("-v", "process", str(toy), "--out", str(tmp_path / "run"))
    assert result.exit_code == 1
    assert "Traceback (most recent call last)" in result.stderr
    assert "in _boom" in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last == "internal error: ZeroDivisionError: float division by zero"


def _raise(exc: BaseException):
    raise exc


@pytest.mark.parametrize(
    ("exc", "message", "status"),
    [
        (
            PermissionError(13, "Permission denied", "/data/run/results.json"),
            "error: /data/run/results.json: Permission denied",
            2,
        ),
        (OSError(28, "No space left on device"), "error: No space left on device", 2),
        (
            FileNotFoundError(2, "No such file or directory", "/a", None, "/b"),
            "error: /a -> /b: No such file or directory",
            2,
        ),
        (
            json.JSONDecodeError("Expecting value", "{", 1),
            "error: not valid JSON: Expecting value: line 1 column 2 (char 1)",
            2,
        ),
        (
            UnicodeDecodeError("utf-8", b"\xff", 0, 1, "invalid start byte"),
            "error: not utf-8 text: invalid start byte at byte 0",
            2,
        ),
        (
            yaml.YAMLError("mapping values\n  are not allowed here"),
            "error: not valid YAML: mapping values are not allowed here",
            2,
        ),
        (
            InputError("session.yaml: fps: expected a number > 0, got 0"),
            "error: session.yaml: fps: expected a number > 0, got 0",
            2,
        ),
        (
            KeyError("cam_00"),
            "internal error: KeyError: 'cam_00' (run with -v for the traceback)",
            1,
        ),
    ],
)
def test_describe_error(exc, message, status) -> None:
    assert describe_error(exc) == (message, status)


def test_describe_opencv_error() -> None:
    try:
        cv2.cvtColor(np.zeros((0, 0, 3), np.uint8), cv2.COLOR_BGR2GRAY)
    except cv2.error as exc:
        message, status = describe_error(exc)
    assert status == 2
    assert message.startswith("error: OpenCV could not process an image or video: ")
    assert "\n" not in message and "cvtColor" in message


def test_click_usage_errors_keep_their_status() -> None:
    result = _run("process", "--quality", "superb")
    assert result.exit_code == 2 and "superb" in result.stderr


# --- process: no frame measured ---------------------------------------------------------------
def _failed_results(statuses: dict[int, str]) -> RunResults:
    return RunResults.of_subject(
        session=SessionInfo("/s", "s", ("cam_00",), 25.0, 10),
        config=ProcessConfig(),
        frames=tuple(FrameRecord(f, s) for f, s in statuses.items()),
        summary={},
    )


def test_process_with_no_measured_frame_exits_3(monkeypatch, toy: Path, tmp_path: Path) -> None:
    import bodymetry.cli.process as cli_process

    results = _failed_results(
        {
            0: "no silhouette in any camera",
            10: "poor fit: mean silhouette IoU 0.41 < 0.90",
            20: "no silhouette in any camera",
            30: "no silhouette in any camera",
            40: "no silhouette in any camera",
        }
    )
    monkeypatch.setattr(cli_process, "process_session", lambda *a, **k: results)
    run = tmp_path / "run"
    result = _run("process", str(toy), "--out", str(run), "--no-review")
    line = _assert_one_line(result, 3)
    assert " ".join(line.split()) == (
        "error: no frame of 5 could be measured: 4 no silhouette in any camera "
        "(frames 0, 20, 30, ...); 1 poor fit (frame 10); "
        f"per frame in {run / 'results.json'}"
    )


def test_every_frame_a_poor_fit_says_what_may_hide_the_body(
    monkeypatch, toy: Path, tmp_path: Path
) -> None:
    """Every frame fitted and none well (the studio's long skirts): the error says what
    can cause it, with the best fit's IoU."""
    import bodymetry.cli.process as cli_process

    frames = tuple(
        FrameRecord(
            f,
            f"poor fit: mean silhouette IoU {iou:.2f} < 0.80",
            silhouette_iou={"a": iou - 0.05, "b": iou + 0.05},
        )
        for f, iou in ((0, 0.6), (10, 0.62), (20, 0.61))
    )
    results = RunResults.of_subject(
        session=SessionInfo("/s", "s", ("cam_00",), 25.0, 10),
        config=ProcessConfig(),
        frames=frames,
        summary={},
    )
    monkeypatch.setattr(cli_process, "process_session", lambda *a, **k: results)
    run = tmp_path / "run"
    result = _run("process", str(toy), "--out", str(run), "--no-review")
    line = " ".join(_assert_one_line(result, 3).split())
    assert line.startswith("error: no frame of 3 could be measured: 3 poor fit (frames 0, 10, 20)")
    assert "fitted no frame's silhouettes well (the best frame's mean IoU 0.62)" in line
    assert "a long skirt or coat" in line
    assert line.endswith(f"per frame in {run / 'results.json'}")


# --- progress without a terminal --------------------------------------------------------------
class _Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_log_progress_lines(caplog) -> None:
    clock = _Clock()
    caplog.set_level(logging.INFO, logger=PROGRESS_LOGGER)
    with labelled_progress(terminal=False, clock=clock) as update:
        label = "training: rendering examples"
        update(label, 0, 3597)  # start: a line
        for done in range(1, 1200):  # ~one per ms: nothing for 10 s
            clock.now += 0.005
            update(label, done, 3597)
        clock.now = 1000.0 + 10.0
        update(label, 1200, 3597)  # 10 s, a third done: eta 20 s
        clock.now += 5.0
        update(label, 1500, 3597)  # too soon
        clock.now += 110.0
        update(label, 2000, 3597)  # 125 s for 2000: eta ~100 s
        clock.now += 1.0
        update(label, 3597, 3597)  # completion, whenever it comes
        update(label, 3597, 3597)  # once
        update("review: recording", 3, 3)  # starts complete
    lines = [r.getMessage() for r in caplog.records if r.name == PROGRESS_LOGGER]
    assert lines == [
        "training: rendering examples 0/3597 (0 %)",
        "training: rendering examples 1200/3597 (33 %), eta 20 s",
        "training: rendering examples 2000/3597 (55 %), eta 2 min",
        "training: rendering examples 3597/3597 (100 %), took 2 min",
        "review: recording 3/3 (100 %)",
    ]
    assert all(r.levelno == logging.INFO for r in caplog.records)


def test_progress_lines_show_at_the_default_verbosity(capsys) -> None:
    setup_logging(0)
    try:
        with labelled_progress(terminal=False) as update:
            update("fitting", 0, 4)
            logging.getLogger("bodymetry.process").info("not shown by default")
        err = capsys.readouterr().err
        assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d INFO fitting 0/4 \(0 %\)\n", err), err
    finally:
        logging.getLogger().handlers.clear()


def test_without_a_terminal_commands_log_progress(truncated_run: Path) -> None:
    """CliRunner's stderr is no terminal: no rich bar escape codes reach it."""
    result = _run("report", str(truncated_run))
    assert "\x1b[" not in result.stderr


# --- warnings ---------------------------------------------------------------------------------
def test_numeric_warnings_go_to_the_debug_log(caplog, capsys, monkeypatch) -> None:
    # Only pytest's own handlers: a command run by an earlier test leaves its stderr
    # handler on the root logger, which caplog's DEBUG level would open up.
    root = logging.getLogger()
    own = [h for h in root.handlers if type(h).__module__.startswith("_pytest")]
    monkeypatch.setattr(root, "handlers", own)
    caplog.set_level(logging.DEBUG)
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        with warnings_to_log():
            assert np.isnan(np.mean(np.array([])))  # "Mean of empty slice"
            warnings.warn("old option", FutureWarning, stacklevel=1)
    assert "Mean of empty slice" not in capsys.readouterr().err
    debug = [r.getMessage() for r in caplog.records if r.levelno == logging.DEBUG]
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert debug[0].startswith("RuntimeWarning: Mean of empty slice")
    assert warned == ["FutureWarning: old option"]


def test_process_with_caveats_exits_5_and_says_why(monkeypatch, toy: Path, tmp_path: Path) -> None:
    """Measured, but on thin and ambiguous evidence: two people in view in frame 10, and
    one frame of five measured. The run's numbers are written; the status says 5."""
    import dataclasses

    import bodymetry.cli.process as cli_process

    base = _failed_results({f: "no silhouette in any camera" for f in (0, 10, 20, 30, 40)})
    frames = list(base.frames)
    frames[1] = dataclasses.replace(frames[1], status="ok", persons=2)
    results = base.with_person(frames=tuple(frames))
    monkeypatch.setattr(cli_process, "process_session", lambda *a, **k: results)
    result = _run("process", str(toy), "--out", str(tmp_path / "run"), "--no-review")
    assert result.exit_code == 5, (result.exit_code, result.output, result.exception)
    assert "Traceback" not in result.output
    text = " ".join(result.output.split())
    assert (
        "caveat (several_persons): more than one person in the capture volume in 1 of 5 "
        "kept frames (frame 10)" in text
    )
    assert "caveat (thin_evidence): only 1 of 5 kept frames measured (frame 10)" in text


def test_process_of_two_persons_names_each_and_exits_5_for_the_unmeasured_one(
    monkeypatch, toy: Path, tmp_path: Path
) -> None:
    """Two persons told apart: one table each, caveats prefixed by their person, and a
    person of several measured in no frame is a caveat (status 5), not silence."""
    import dataclasses

    import bodymetry.cli.process as cli_process

    base = _failed_results({f: "no silhouette in any camera" for f in (0, 10, 20, 30, 40)})
    ok = tuple(dataclasses.replace(f, status="ok") for f in base.frames)
    measured = dataclasses.replace(base.person, frames=ok, told_apart=True)
    missed = dataclasses.replace(base.person, id=1, told_apart=True)
    results = dataclasses.replace(base, persons=(measured, missed))
    monkeypatch.setattr(cli_process, "process_session", lambda *a, **k: results)
    result = _run("process", str(toy), "--out", str(tmp_path / "run"), "--no-review")
    assert result.exit_code == 5, (result.exit_code, result.output, result.exception)
    text = " ".join(result.output.split())
    assert "s person 0: 5 of 5 kept frames measured" in text
    assert "s person 1: 0 of 5 kept frames measured" in text
    assert "caveat (unmeasured): person 1: no frame of 5 could be measured" in text
    assert "caveat (unmeasured): person 0" not in text and "persons/*/frames/" in text
