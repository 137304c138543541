"""Qualisys .qca.txt reading: a known answer from Pose2Sim's own conversion, and bad files."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodymetry.calibration import qualisys
from bodymetry.calibration.qualisys import import_qca, natural_key, read_qca
from bodymetry.errors import InputError

QCA = Path(__file__).resolve().parents[1] / "data" / "pose2sim" / "calibration" / "Calib.qca.txt"

#: Our cameras equal Pose2Sim's to this (absolute; pixels, metres, radians, unitless).
TOL = 1e-9

# Computed with Pose2Sim 0.10.49's own code: `calib_qca_fun` and `read_qca`
# (Pose2Sim/calibration.py), `world_to_camera_persp`, `rotate_cam` and
# `natural_sort_key` (Pose2Sim/common.py) copied verbatim into a scratch script
# (lxml's etree swapped for xml.etree.ElementTree, which has the same
# findall/get), run on tests/data/pose2sim/calibration/Calib.qca.txt with binning_factor=1.
# Values printed with repr. `rvec` is the Rodrigues vector Pose2Sim writes to
# its TOML, `T` its translation (metres), `D` its 4 distortion coefficients.
POSE2SIM = {
    "cam01": {
        "size": (1088, 1920),
        "fx": 1681.244873046875,
        "fy": 1681.075439453125,
        "cx": 532.97369384375,
        "cy": 948.137390140625,
        "D": [-0.000721609375, 0.002187234375, 9.5e-06, 1.078125e-05],
        "rvec": [1.6882754799999993, 1.0483220499999997, -0.41955852000000016],
        "T": [0.3211048899999996, 0.9563320600000009, 2.8907130499999996],
        "residual": 0.402,
    },
    "cam02": {
        "size": (1088, 1920),
        "fx": 1673.729614265625,
        "fy": 1673.79724121875,
        "cx": 534.494567875,
        "cy": 963.225891109375,
        "D": [-0.000747609375, 0.00213728125, 1.51875e-05, 4.546875e-06],
        "rvec": [1.34975875, 1.5963809099999993, -1.1983285799999999],
        "T": [-0.11152829000000014, 0.7766184800000001, 3.0675519599999994],
        "residual": 0.444749,
    },
    "cam03": {
        "size": (1088, 1920),
        "fx": 1681.598388671875,
        "fy": 1681.509887703125,
        "cx": 513.20837403125,
        "cy": 955.005126953125,
        "D": [-0.000729765625, 0.00215034375, -8.46875e-06, -8.078125e-06],
        "rvec": [0.8109654899999995, -2.1972129299999996, 1.3760277799999996],
        "T": [-0.7934803899999995, 0.32283594000000126, 4.353514870000001],
        "residual": 0.450323,
    },
    "cam04": {
        "size": (1088, 1920),
        "fx": 1675.234985359375,
        "fy": 1675.204223640625,
        "cx": 540.106201171875,
        "cy": 964.0302734375,
        "D": [-0.000744265625, 0.002104171875, 4.328125e-06, 3.109375e-06],
        "rvec": [1.4045571699999995, -1.3887412699999993, 0.42535743000000026],
        "T": [0.5030217200000007, 0.04894934000000107, 4.406564460000002],
        "residual": 0.504772,
    },
}

# Points in the capture volume (metres, z up): seen by all four cameras.
POINTS = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.2, -0.1, 1.5], [-0.3, 0.2, 0.8]])


def test_known_answer_from_pose2sim():
    group = import_qca(QCA)
    assert group.names == tuple(POSE2SIM)
    for cam in group:
        ref = POSE2SIM[cam.name]
        assert cam.size == ref["size"]
        K = np.array([[ref["fx"], 0, ref["cx"]], [0, ref["fy"], ref["cy"]], [0, 0, 1]])
        np.testing.assert_allclose(cam.K, K, rtol=0, atol=TOL)
        np.testing.assert_allclose(cam.dist[:4], ref["D"], rtol=0, atol=TOL)
        assert cam.dist[4] == 0.0  # radialDistortion3 is 0 in the file (Pose2Sim drops it)
        R_ref = Rotation.from_rotvec(ref["rvec"]).as_matrix()
        np.testing.assert_allclose(cam.R, R_ref, rtol=0, atol=TOL)
        np.testing.assert_allclose(cv2.Rodrigues(cam.R)[0].ravel(), ref["rvec"], rtol=0, atol=TOL)
        np.testing.assert_allclose(cam.t, ref["T"], rtol=0, atol=TOL)


def test_points_project_as_pose2sim_and_back():
    """Project with our cameras and with OpenCV on Pose2Sim's figures; cast rays back."""
    for cam in import_qca(QCA):
        ref = POSE2SIM[cam.name]
        K = np.array([[ref["fx"], 0, ref["cx"]], [0, ref["fy"], ref["cy"]], [0, 0, 1]])
        theirs, _ = cv2.projectPoints(
            POINTS, np.array(ref["rvec"]), np.array(ref["T"]), K, np.array(ref["D"])
        )
        ours = cam.project(POINTS)
        np.testing.assert_allclose(ours, theirs.reshape(-1, 2), rtol=0, atol=1e-6)
        w, h = cam.size
        assert np.all((ours >= 0) & (ours < [w, h])), (cam.name, ours)
        # Back: the ray through each pixel passes through its point.
        rays = cam.ray(ours)
        offsets = POINTS - cam.center
        along = np.sum(offsets * rays, axis=1)
        assert np.all(along > 0)
        miss = np.linalg.norm(offsets - along[:, None] * rays, axis=1)
        assert miss.max() < 1e-9


def test_camera_centres_are_the_qca_positions_and_notes():
    qca = read_qca(QCA)
    np.testing.assert_allclose(
        qca.cameras["cam01"].center,
        [1.4602323709212087, -1.9091590482454608, 1.8965058524092062],
        rtol=0,
        atol=TOL,
    )
    assert {n: r for n, r in qca.residuals_mm.items()} == {
        n: ref["residual"] for n, ref in POSE2SIM.items()
    }
    assert set(qca.models.values()) == {"none"}


def _edited(tmp_path: Path, edit, name: str = "bad.qca.txt") -> Path:
    path = tmp_path / name
    path.write_text(edit(QCA.read_text()))
    return path


def _one_line_error(path: Path, match: str, **kwargs) -> str:
    with pytest.raises(InputError) as info:
        read_qca(path, **kwargs)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    assert re.search(match, message), message
    return message


def test_doctype_and_entities_are_refused(tmp_path):
    bomb = (
        '<?xml version="1.0"?>\n<!DOCTYPE lolz [<!ENTITY lol "lol">'
        '<!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">]>\n'
        "<calibration><cameras><camera serial='&lol2;'/></cameras></calibration>\n"
    )
    path = tmp_path / "bomb.qca.txt"
    path.write_text(bomb)
    _one_line_error(path, "DOCTYPE or ENTITY")


def test_size_limit(tmp_path, monkeypatch):
    monkeypatch.setattr(qualisys, "QCA_MAX_BYTES", 1000)
    _one_line_error(QCA, "larger than the .* limit for a Qualisys calibration file")


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda s: s[: len(s) // 2], "not valid XML"),
        (lambda s: "<calibration/>", "no <cameras><camera> elements"),
        (lambda s: s.replace('focalLengthU="107599.671875" ', "", 1), "no attribute 'focalL"),
        (lambda s: s.replace('r11="0.5536380477336265"', 'r11="abc"', 1), "expected a number"),
        (lambda s: s.replace('r11="0.5536380477336265"', 'r11="2.0"', 1), "not a rotation"),
        (lambda s: s.replace('serial="cam02"', 'serial="cam01"', 1), "duplicate serial"),
        (lambda s: s.replace('serial="cam02"', 'serial=""', 1), "has no 'serial'"),
        (lambda s: re.sub(r"<fov_video [^>]*/>", "", s, count=1), "no <fov_video>"),
        (lambda s: s.replace('right="1087"', 'right="-5"'), "expected whole positive sizes"),
    ],
)
def test_malformed_files_give_one_line_errors(tmp_path, edit, match):
    _one_line_error(_edited(tmp_path, edit), match)


def test_missing_file_and_bad_binning(tmp_path):
    _one_line_error(tmp_path / "none.qca.txt", "not found")
    with pytest.raises(InputError, match="binning_factor"):
        read_qca(QCA, binning_factor=0)


def test_binning_factor_halves_the_intrinsics_as_pose2sim():
    one, two = import_qca(QCA), import_qca(QCA, binning_factor=2)
    for a, b in zip(one, two, strict=True):
        assert b.size == (a.size[0] // 2, a.size[1] // 2)
        # fov_video left / top are 0 here, so everything in 1/64 px is halved.
        np.testing.assert_allclose(b.K[:2], a.K[:2] / 2, rtol=0, atol=TOL)
        np.testing.assert_allclose(b.dist, a.dist / 2, rtol=0, atol=TOL)
        np.testing.assert_array_equal(b.R, a.R)


def test_natural_order_window_offset_and_tangential_spelling(tmp_path):
    def edit(text: str) -> str:
        text = text.replace('serial="cam02"', 'serial="cam10"')
        text = text.replace('serial="cam03"', 'serial="cam2"')
        # A video window starting at (8, 16): the principal point moves by it.
        text = text.replace(
            '<fov_video bottom="1919" left="0" right="1087" top="0"/>',
            '<fov_video bottom="1935" left="8" right="1095" top="16"/>',
            1,
        )
        return text.replace("tangentalDistortion", "tangentialDistortion", 2)

    qca = read_qca(_edited(tmp_path, edit))
    assert qca.cameras.names == ("cam01", "cam2", "cam04", "cam10")
    cam = qca.cameras["cam01"]
    assert cam.size == (1088, 1920)
    ref = POSE2SIM["cam01"]
    np.testing.assert_allclose(cam.K[:2, 2], [ref["cx"] - 8, ref["cy"] - 16], rtol=0, atol=TOL)
    np.testing.assert_allclose(cam.dist[2:4], ref["D"][2:], rtol=0, atol=TOL)
    assert natural_key("cam2") < natural_key("cam10")
