"""Session ingest: sync checks, frame subsampling, offsets, truncated and missing videos."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from bodymetry.capture.ingest import check_sync, probe_video, read_frame_sets
from bodymetry.capture.session import load_session
from bodymetry.capture.toy import write_toy_session
from bodymetry.errors import InputError


def _stamp(image: np.ndarray) -> int:
    """The frame number written into the toy frame's top-left block."""
    return round(float(image[1:6, 1:6].mean()) / 4)


@pytest.fixture(scope="module")
def toy(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("toy") / "s"
    write_toy_session(folder, cameras=2, frames=40, frame_step=10)
    return folder


def test_sync_report_and_kept_frames(toy: Path) -> None:
    report = check_sync(load_session(toy))
    assert report.n_frames == 40
    assert report.kept.tolist() == [0, 10, 20, 30]
    assert report.warnings == ()
    assert [v.size for v in report.videos] == [(160, 120)] * 2


@pytest.mark.parametrize("method", ["sequential", "seek"])
def test_frame_sets_are_the_kept_frames(toy: Path, method: str) -> None:
    sets = list(read_frame_sets(load_session(toy), method=method))
    assert [fs.frame for fs in sets] == [0, 10, 20, 30]
    for fs in sets:
        assert fs.valid.all() and fs.flags == ((), ())
        assert [_stamp(im) for im in fs.images] == [fs.frame, fs.frame]


def test_seek_and_sequential_agree(toy: Path) -> None:
    session = load_session(toy)
    a = list(read_frame_sets(session, method="sequential"))
    b = list(read_frame_sets(session, method="seek", threads=1))
    for x, y in zip(a, b, strict=True):
        for u, v in zip(x.images, y.images, strict=True):
            np.testing.assert_array_equal(u, v)


def test_frame_offsets_line_cameras_up(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    write_toy_session(folder, cameras=3, frames=30, frame_step=10, offsets=[0, 3, 7])
    session = load_session(folder)
    assert [c.frame_offset for c in session.cameras] == [0, 3, 7]
    report = check_sync(session)
    assert report.n_frames == 30 and report.warnings == ()
    for fs in read_frame_sets(session, report):
        # Video frame f + offset holds stamp f + offset; the scene content is the same frame.
        stamps = [_stamp(im) for im in fs.images]
        assert stamps == [fs.frame, fs.frame + 3, fs.frame + 7]


def test_mismatched_frame_counts_warn_and_cut(tmp_path: Path, caplog) -> None:
    folder = tmp_path / "s"
    write_toy_session(folder, cameras=3, frames=40, frame_step=10, frame_counts=[40, 40, 25])
    session = load_session(folder)
    with caplog.at_level(logging.WARNING):
        report = check_sync(session)
    assert report.n_frames == 25
    assert report.kept.tolist() == [0, 10, 20]
    assert len(report.warnings) == 1 and "cam_02" in report.warnings[0]
    assert "cam_00" not in report.warnings[0]
    assert "cam_02" in caplog.text
    with pytest.raises(InputError, match=r"cam_02.*has 25"):
        check_sync(session, strict=True)


def test_offset_past_the_end(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    write_toy_session(folder, cameras=2, frames=20, frame_step=10)
    text = (folder / "session.yaml").read_text()
    text = text.replace(
        "video: videos/cam_01.avi", "video: videos/cam_01.avi\n    frame_offset: 20"
    )
    (folder / "session.yaml").write_text(text)
    session = load_session(folder)
    with pytest.raises(InputError, match="'cam_01': frame_offset 20 is past the end"):
        check_sync(session)


def test_fps_mismatch_names_the_camera(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    write_toy_session(folder, cameras=2, frames=20, frame_step=10, fps=30.0)
    text = (folder / "session.yaml").read_text().replace("fps: 30.0", "fps: 60.0")
    (folder / "session.yaml").write_text(text)
    with pytest.raises(InputError, match=r"'cam_00'.*30 fps.*fps: 60"):
        check_sync(load_session(folder))


def test_size_mismatch_with_calibration(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    write_toy_session(folder, cameras=2, frames=12, frame_step=10)
    text = (folder / "calibration.yaml").read_text()
    (folder / "calibration.yaml").write_text(text.replace("160", "320", 1))
    with pytest.raises(InputError, match=r"'cam_00'.*160x120.*320x120"):
        check_sync(load_session(folder))


def test_missing_video_file(toy: Path, tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"cam_07.*not found"):
        probe_video(tmp_path / "nope.avi", "cam_07")
    # Removed after the session was loaded: ingest names the camera and the file.
    folder = tmp_path / "s"
    write_toy_session(folder, cameras=2, frames=12, frame_step=10)
    session = load_session(folder)
    (folder / "videos" / "cam_01.avi").unlink()
    with pytest.raises(InputError, match=r"'cam_01'.*not found.*cam_01\.avi"):
        check_sync(session)
    # And load_session refuses it outright.
    with pytest.raises(InputError, match="cam_01"):
        load_session(folder)


def test_not_a_video(tmp_path: Path) -> None:
    path = tmp_path / "junk.mp4"
    path.write_bytes(b"\x00" * 4096)
    with pytest.raises(InputError, match="'cam_00': cannot open the video"):
        probe_video(path, "cam_00")


def test_truncated_video_reads_what_it_can_and_flags_the_rest(tmp_path: Path, caplog) -> None:
    folder = tmp_path / "s"
    write_toy_session(folder, cameras=2, frames=40, frame_step=5)
    video = folder / "videos" / "cam_01.avi"
    data = video.read_bytes()
    video.write_bytes(data[: len(data) // 2])
    session = load_session(folder)
    report = check_sync(session)
    assert report.n_frames == 40  # declared by the header; the tail is missing
    with caplog.at_level(logging.WARNING):
        sets = list(read_frame_sets(session, report))
    assert len(sets) == 8
    valid = np.array([fs.valid for fs in sets])
    assert valid[:, 0].all()
    assert valid[0, 1] and not valid[-1, 1]
    first_bad = int(np.argmin(valid[:, 1]))
    assert not valid[first_bad:, 1].any()  # once it stops, the rest is flagged
    assert all(fs.flags[1] == ("unreadable",) for fs in sets[first_bad:])
    assert all(fs.images[1] is None for fs in sets[first_bad:])
    # The readable frames are the right ones.
    for fs in sets[:first_bad]:
        assert _stamp(fs.images[1]) == fs.frame
    assert "cam_01" in caplog.text and "truncated or corrupt" in caplog.text
    assert caplog.text.count("stopped decoding") == 1


def test_truncated_mp4_without_index_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "cut.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30, (64, 48))
    for i in range(10):
        writer.write(np.full((48, 64, 3), 10 * i, np.uint8))
    writer.release()
    path.write_bytes(path.read_bytes()[:-200])  # the index (moov) is at the end
    with pytest.raises(InputError, match="'cam_03': cannot open the video"):
        probe_video(path, "cam_03")


def test_frames_must_increase(toy: Path) -> None:
    with pytest.raises(InputError, match="increasing"):
        list(read_frame_sets(load_session(toy), frames=[10, 0]))
    with pytest.raises(InputError, match="read method"):
        list(read_frame_sets(load_session(toy), method="random"))
