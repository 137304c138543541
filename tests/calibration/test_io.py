"""calibration.yaml: exact round trips, one test per bad input."""

from __future__ import annotations

import copy
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from camera_groups import assert_groups_equal, make_group
from scipy.spatial.transform import Rotation
from yaml_edits import delete_at, set_at

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.calibration.io import (
    CALIBRATION_FORMAT,
    Calibration,
    load_calibration,
    read_calibration,
    save_calibration,
)
from bodymetry.errors import InputError
from bodymetry.schema import dump_yaml

EXTRA = {
    "world": {"frame": "board on the floor, z up", "note": "x: along the board's long side"},
    "quality": {
        "cam_00": {"rms_px": 0.21, "frames_read": 300, "boards_detected": 211},
        "overall": {"rms_px": 0.25, "converged": True, "date": "2026-11-22", "none": None},
    },
}


# -- YAML round trip ------------------------------------------------------------
def test_yaml_round_trip_is_byte_exact(tmp_path: Path) -> None:
    group = make_group()
    first = tmp_path / "calibration.yaml"
    save_calibration(first, group, extra=EXTRA)
    calib = read_calibration(first)
    assert_groups_equal(calib.cameras, group)
    assert calib.world == EXTRA["world"] and calib.quality == EXTRA["quality"]
    second = tmp_path / "again.yaml"
    save_calibration(second, calib)
    assert second.read_bytes() == first.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["again.yaml", "calibration.yaml"]


def test_yaml_extreme_floats_exact(tmp_path: Path) -> None:
    cam = Camera(
        "odd name: 1",
        (641, 479),
        [[1e3 / 3, 1e-300, 320.1], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]],
        [5e-324, -0.0, 1e-5, 1.5e20, 2.0**-40],
        np.eye(3),
        [-0.0, 1e-17, 123456789.123456789],
    )
    path = tmp_path / "c.yaml"
    save_calibration(path, CameraGroup([cam]))
    back = load_calibration(path)
    assert_groups_equal(back, CameraGroup([cam]))
    assert np.signbit(back[0].dist[1]) and np.signbit(back[0].t[0])
    # Plain PyYAML (YAML 1.1) reads the same numbers, not strings.
    data = yaml.safe_load(path.read_text())
    assert data["cameras"][0]["dist"] == cam.dist.tolist()
    assert data["cameras"][0]["name"] == "odd name: 1"


def test_yaml_layout(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    save_calibration(path, make_group(1))
    text = path.read_text()
    assert f"format: {CALIBRATION_FORMAT}\n" in text
    assert "    size: [640, 480]\n" in text
    assert "    K:\n      - [" in text


def test_yaml_accepts_hand_written_numbers(tmp_path: Path) -> None:
    """Integers, YAML-1.2 exponents (``1e-5``) and R rounded to 6 digits are fine."""
    R = Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix()
    rows = ", ".join("[" + ", ".join(f"{v:.6f}" for v in row) + "]" for row in R)
    text = (
        f"format: {CALIBRATION_FORMAT}\ncameras:\n"
        "  - {name: a, size: [640, 480], K: [[800, 0, 320], [0, 800, 240], [0, 0, 1]],\n"
        f"     dist: [1e-5, 0, 0, 0], R: [{rows}], t: [1, 2, 3]}}\n"
    )
    path = tmp_path / "c.yaml"
    path.write_text(text)
    cam = load_calibration(path)[0]
    assert cam.dist[0] == 1e-5 and cam.K[0, 0] == 800.0
    np.testing.assert_allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(cam.R, R, atol=2e-6)


def test_save_rejects_bad_extra(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    with pytest.raises(ValueError, match="unknown keys"):
        save_calibration(path, make_group(1), extra={"qualty": {}})
    with pytest.raises(InputError, match="world"):
        save_calibration(path, make_group(1), extra={"world": [1, 2]})
    assert not path.exists() and list(tmp_path.iterdir()) == []


# -- malformed calibration.yaml: one test per class ---------------------------------------
def _valid_data() -> dict[str, Any]:
    group = make_group(3)
    return {
        "format": CALIBRATION_FORMAT,
        "cameras": [
            {
                "name": c.name,
                "size": list(c.size),
                "K": c.K.tolist(),
                "dist": c.dist.tolist(),
                "R": c.R.tolist(),
                "t": c.t.tolist(),
            }
            for c in group
        ],
    }


def _load_edited(tmp_path: Path, edit: Callable[[dict[str, Any]], Any]) -> InputError:
    data = copy.deepcopy(_valid_data())
    result = edit(data)
    path = tmp_path / "calibration.yaml"
    path.write_text(yaml.safe_dump(data if result is None else result))
    with pytest.raises(InputError) as info:
        load_calibration(path)
    assert str(path) in str(info.value)
    return info.value


def _rename(old: str, new: str) -> Callable[[dict[str, Any]], None]:
    def edit(data: dict[str, Any]) -> None:
        data[new] = data.pop(old)

    return edit


def _not_rotation(data: dict[str, Any]) -> None:
    data["cameras"][1]["R"] = (np.array(data["cameras"][1]["R"]) * 1.01).tolist()


def _reflection(data: dict[str, Any]) -> None:
    data["cameras"][1]["R"] = (-np.array(data["cameras"][1]["R"])).tolist()


@pytest.mark.parametrize(
    ("edit", "field", "message"),
    [
        # missing key
        (delete_at("format"), "format", "missing key 'format'"),
        (delete_at("cameras"), "cameras", "missing key 'cameras'"),
        (delete_at("cameras.2.K"), r"cameras\[2\]\.K", "missing key 'K'"),
        (delete_at("cameras.0.dist"), r"cameras\[0\]\.dist", "missing key 'dist'"),
        # unknown key / typo
        (set_at("cameras.0.distortion", [0, 0, 0, 0]), r"cameras\[0\]\.distortion", "unknown key"),
        (_rename("cameras", "camers"), "cameras", "'camers': a typo"),
        # unknown format version / kind
        (set_at("format", "bodymetry-calibration/2"), "format", "unknown format version"),
        (set_at("format", "bodymetry-session/1"), "format", "wrong kind of file"),
        (set_at("format", 1), "format", "expected the string"),
        # wrong type
        (set_at("cameras.1.name", 7), r"cameras\[1\]\.name", "expected a string"),
        (set_at("cameras.1.K", "eye(3)"), r"cameras\[1\]\.K", "expected a 3x3"),
        (set_at("cameras.1.t.2", "far"), r"cameras\[1\]\.t\[2\]", "expected a number"),
        (set_at("cameras.1.t.2", True), r"cameras\[1\]\.t\[2\]", "expected a number"),
        (set_at("cameras.1.size", 640), r"cameras\[1\]\.size", r"\[width, height\]"),
        (set_at("cameras.1.size.0", 640.5), r"cameras\[1\]\.size\[0\]", "expected an integer"),
        (set_at("cameras.1.size.1", 0), r"cameras\[1\]\.size\[1\]", ">= 1"),
        (set_at("cameras", {"a": 1}), "cameras", "expected a list of cameras"),
        (set_at("cameras", []), "cameras", "at least one camera"),
        (set_at("cameras.0", [1, 2]), r"cameras\[0\]", "expected a mapping"),
        (set_at("world", "lab"), "world", "expected a mapping"),
        # wrong matrix shape
        (
            set_at("cameras.2.K", [[800, 0, 320], [0, 800, 240]]),
            r"cameras\[2\]\.K",
            "3 items, got 2",
        ),
        (set_at("cameras.2.R.1", [0, 1]), r"cameras\[2\]\.R\[1\]", "3 items, got 2"),
        (set_at("cameras.2.t", [0, 1]), r"cameras\[2\]\.t", "3 items, got 2"),
        (set_at("cameras.2.dist", [0, 0, 0]), r"cameras\[2\]\.dist", "4 or 5 or 8 or 12 or 14"),
        # bad values
        (set_at("cameras.0.K.2", [0, 0, 2]), r"cameras\[0\]\.K", r"\[0, 0, 1\]"),
        (set_at("cameras.0.K.0.0", -800), r"cameras\[0\]\.K", "positive focal"),
        (_not_rotation, r"cameras\[1\]\.R", "rotation matrix"),
        (_reflection, r"cameras\[1\]\.R", "reflection"),
        # non-finite numbers
        (set_at("cameras.0.t.1", float("nan")), r"cameras\[0\]\.t\[1\]", "finite"),
        (set_at("cameras.0.K.0.2", float("inf")), r"cameras\[0\]\.K\[0\]\[2\]", "finite"),
        # duplicate names
        (set_at("cameras.2.name", "cam_00"), r"cameras\[2\]\.name", r"duplicate.*cameras\[0\]"),
        # not a mapping at the top
        (lambda d: [d], "", "expected a mapping"),
        (lambda d: "just text", "", "expected a mapping"),
    ],
)
def test_malformed_calibration(
    tmp_path: Path, edit: Callable[[dict[str, Any]], Any], field: str, message: str
) -> None:
    err = str(_load_edited(tmp_path, edit))
    if field:
        assert re.search(rf"calibration\.yaml: {field}: ", err), err
    assert re.search(message, err), err


def test_malformed_yaml_syntax(tmp_path: Path) -> None:
    path = tmp_path / "calibration.yaml"
    path.write_text("format: bodymetry-calibration/1\ncameras: [\n  - name: a\n")
    with pytest.raises(InputError, match=r"calibration\.yaml: not valid YAML at line \d+, col"):
        load_calibration(path)


def test_duplicate_yaml_key(tmp_path: Path) -> None:
    path = tmp_path / "calibration.yaml"
    path.write_text(dump_yaml(_valid_data()).replace("    dist:", "    K: [1]\n    dist:", 1))
    with pytest.raises(InputError, match=r"calibration\.yaml: not valid YAML.*duplicate key 'K'"):
        load_calibration(path)


def test_empty_and_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "calibration.yaml"
    path.write_text("")
    with pytest.raises(InputError, match=r"calibration\.yaml: expected a mapping.*null"):
        load_calibration(path)
    with pytest.raises(InputError, match=r"nope\.yaml: calibration file not found"):
        load_calibration(tmp_path / "nope.yaml")
    with pytest.raises(InputError, match="found a folder"):
        load_calibration(tmp_path)


def test_oversized_calibration_files(tmp_path: Path) -> None:
    """calibration.yaml is refused by its size before parsing."""
    yaml_path = tmp_path / "calibration.yaml"
    save_calibration(yaml_path, make_group())
    with open(yaml_path, "ab") as fh:  # a valid file padded with 2 MB of spaces
        fh.write(b" " * 2_000_000)
    with pytest.raises(InputError) as info:
        load_calibration(yaml_path)
    message = str(info.value)
    assert message.startswith(f"{yaml_path}: 2 MB, larger than the 1 MB limit")
    assert message.endswith("for a calibration file")


def test_calibration_dataclass_save(tmp_path: Path) -> None:
    calib = Calibration(make_group(2), world={"frame": "floor"})
    save_calibration(tmp_path / "c.yaml", calib, extra={"quality": {"cam_00": {"rms_px": 0.1}}})
    back = read_calibration(tmp_path / "c.yaml")
    assert back.world == {"frame": "floor"} and back.quality == {"cam_00": {"rms_px": 0.1}}
