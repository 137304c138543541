"""anipose / FreeMoCap calibration.toml: exact round trips through calibration.yaml, bad inputs."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from camera_groups import assert_groups_equal, make_group
from scipy.spatial.transform import Rotation

from bodymetry.calibration.anipose import export_anipose_toml, import_anipose_toml
from bodymetry.calibration.io import CALIBRATION_MAX_BYTES, load_calibration, save_calibration
from bodymetry.errors import InputError


# -- TOML -------------------------------------------------------------------------------
def test_yaml_toml_yaml_round_trip(tmp_path: Path) -> None:
    group = make_group(4, seed=3)
    save_calibration(tmp_path / "a.yaml", group)
    toml_path = tmp_path / "calibration.toml"
    export_anipose_toml(toml_path, load_calibration(tmp_path / "a.yaml"), metadata={"error": 0.3})
    back = import_anipose_toml(toml_path)  # metadata.units = "m"
    assert_groups_equal(back, group, rot_tol=1e-12)
    save_calibration(tmp_path / "b.yaml", back)
    again = load_calibration(tmp_path / "b.yaml")
    assert_groups_equal(again, group, rot_tol=1e-12)
    # And once more through TOML: stable.
    export_anipose_toml(tmp_path / "again.toml", again)
    assert_groups_equal(import_anipose_toml(tmp_path / "again.toml"), group, rot_tol=1e-12)


ANIPOSE_TOML = """\
[cam_0]
name = "A"
size = [ 1280, 1024,]
matrix = [ [ 1000.0, 0.0, 640.0,], [ 0.0, 1000.0, 512.0,], [ 0.0, 0.0, 1.0,],]
distortions = [ -0.1, 0.01, 0.0, 0.0, 0.0,]
rotation = [ 0.1, -0.2, 0.3,]
translation = [ 100.0, -250.0, 3000.0,]

[cam_1]
name = "B"
size = [ 1280.0, 1024.0,]
matrix = [ [ 1010.0, 0.0, 641.0,], [ 0.0, 1010.0, 510.0,], [ 0.0, 0.0, 1.0,],]
distortions = [ -0.12, 0.02, 0.0, 0.0, 0.0,]
rotation = [ -0.1, 0.5, 0.0,]
translation = [ -900.0, 50.0, 2800.0,]
fisheye = false

[metadata]
adjusted = true
error = 0.5
"""


def test_import_anipose_millimetres(tmp_path: Path) -> None:
    path = tmp_path / "calibration.toml"
    path.write_text(ANIPOSE_TOML)
    group = import_anipose_toml(path, units="mm")
    assert group.names == ("A", "B") and group[1].size == (1280, 1024)
    np.testing.assert_allclose(group[0].t, [0.1, -0.25, 3.0], rtol=1e-15)
    np.testing.assert_allclose(group[0].R, Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix())
    with pytest.raises(InputError, match="does not say the unit"):
        import_anipose_toml(path)
    with pytest.raises(InputError, match=r"calibration\.toml.*units='mm'"):
        import_anipose_toml(path, units="m")


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda s: s.replace('name = "B"', 'name = "A"'), r"cam_1\.name: duplicate camera name"),
        (lambda s: s.replace("fisheye = false", "fisheye = true"), r"cam_1\.fisheye: fisheye"),
        (lambda s: s.replace("rotation = [ -0.1, 0.5, 0.0,]\n", ""), r"cam_1\.rotation: missing"),
        (
            lambda s: s.replace(
                "[ 0.0, 0.0, 1.0,],]\ndistortions = [ -0.12", "]\ndistortions = [ -0.12"
            ),
            r"cam_1\.matrix: expected a 3x3",
        ),
        (lambda s: s.replace("[cam_1]", "[cam_1"), "not valid TOML"),
        (
            lambda s: s + '\n[metadata2]\nunits = "furlong"\n',
            r"metadata2\.name: missing key 'name'",
        ),
        (lambda s: s.replace("error = 0.5", 'units = "m"'), r"metadata\.units: the file says 'm'"),
    ],
)
def test_import_anipose_errors(tmp_path: Path, edit: Callable[[str], str], message: str) -> None:
    path = tmp_path / "calibration.toml"
    path.write_text(edit(ANIPOSE_TOML))
    with pytest.raises(InputError, match=message) as info:
        import_anipose_toml(path, units="mm")
    assert str(path) in str(info.value)


def test_oversized_calibration_toml(tmp_path: Path) -> None:
    """calibration.toml is refused by its size before parsing."""
    toml_path = tmp_path / "calibration.toml"
    export_anipose_toml(toml_path, make_group())
    with open(toml_path, "r+b") as fh:
        fh.truncate(CALIBRATION_MAX_BYTES + 1)
    with pytest.raises(
        InputError,
        match=r"calibration\.toml: 1,000,001 bytes, larger than the 1 MB limit for a "
        r"calibration TOML file",
    ):
        import_anipose_toml(toml_path)
