"""``recording.mcap`` read back with the ``mcap`` reader and with Rerun's MCAP loader."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest
import rerun.chunk as rc
from mcap.reader import make_reader

from bodymetry.review.mcap_recording import overlay_silhouettes


@pytest.fixture(scope="module")
def mcap_file(review_run):
    return review_run.folder / "recording.mcap"


@pytest.fixture(scope="module")
def messages(mcap_file):
    with open(mcap_file, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        out = [
            (channel.topic, schema.name, message)
            for schema, channel, message in reader.iter_messages()
        ]
    return summary, out


def test_channels_schemas_and_counts(review_run, messages):
    summary, msgs = messages
    n = len(review_run.results.frames)
    cams = review_run.results.session.cameras
    expected = {
        "/tf": "foxglove.FrameTransforms",
        "/body": "foxglove.SceneUpdate",
        "/particles": "foxglove.PointCloud",
        "/measurements": "bodymetry.FrameMeasurements",
    }
    for cam in cams:
        expected[f"/cameras/{cam}/image"] = "foxglove.CompressedImage"
        expected[f"/cameras/{cam}/overlay"] = "foxglove.CompressedImage"
        expected[f"/cameras/{cam}/calibration"] = "foxglove.CameraCalibration"
    schemas = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
    assert schemas == expected
    counts = Counter(topic for topic, _, _ in msgs)
    assert counts == dict.fromkeys(expected, n)
    encodings = {ch.topic: ch.message_encoding for ch in summary.channels.values()}
    assert encodings["/measurements"] == "json"
    assert encodings["/tf"] == "protobuf"


def test_log_times_are_session_times(review_run, messages):
    _, msgs = messages
    fps = review_run.results.session.fps
    times = sorted({m.log_time for topic, _, m in msgs if topic == "/measurements"})
    expected = [round(f.frame / fps * 1e9) for f in review_run.results.frames]
    assert times == expected


def test_measurement_messages_carry_the_frame_records(review_run, messages):
    _, msgs = messages
    records = {f.frame: f for f in review_run.results.frames}
    seen = set()
    for topic, _, m in msgs:
        if topic != "/measurements":
            continue
        payload = json.loads(m.data)
        record = records[payload["frame"]]
        seen.add(record.frame)
        assert payload["status"] == record.status
        for stage, estimate in record.estimates.items():
            # results.json keeps 3 decimals; the message carries the same numbers.
            assert payload[stage]["height_mm"] == pytest.approx(
                estimate.biometrics["height_mm"], abs=1e-3
            )
            assert "state" not in payload[stage]
        assert set(payload["silhouette_iou"]) == set(record.silhouette_iou)
        assert len(payload["annealing"]["layer_log_likelihood"]) == len(
            record.annealing.layer_log_likelihood
        )
    assert seen == set(records)
    # The session stage travels with the frames it used.
    shape = review_run.results.session_shape
    assert shape is not None and shape.ok
    assert all("session" in records[f].estimates for f in shape.frames)


def test_the_session_body_is_in_the_scene(review_run, messages):
    """The ``/body`` scene has a ``session`` entity on the frames the session stage used
    (protobuf keeps the entity id as its UTF-8 bytes)."""
    _, msgs = messages
    used = set(review_run.results.session_shape.frames)
    times = {
        round(f.frame / review_run.results.session.fps * 1e9): f.frame
        for f in review_run.results.frames
    }
    with_session = {
        times[m.log_time] for topic, _, m in msgs if topic == "/body" and b"session" in m.data
    }
    assert used and with_session == used


def test_images_are_jpeg(messages):
    _, msgs = messages
    images = [m.data for topic, _, m in msgs if topic.endswith("/image")]
    assert images and all(b"\xff\xd8\xff" in data for data in images)


def test_rerun_loader_accepts_the_file(review_run, mcap_file):
    store = rc.McapReader(mcap_file).stream().collect()
    archetypes: dict[str, set[str]] = {}
    for col in store.schema().component_columns():
        archetypes.setdefault(col.entity_path, set()).add(col.archetype.rsplit(".", 1)[-1])
    cam = review_run.results.session.cameras[0]
    assert "EncodedImage" in archetypes[f"/cameras/{cam}/image"]
    assert "Pinhole" in archetypes[f"/cameras/{cam}/calibration"]
    assert "Transform3D" in archetypes["/tf"]
    assert "Points3D" in archetypes["/particles"]


def test_overlay_colours_follow_figure_4():
    image = np.zeros((40, 40, 3), np.uint8)
    observed = np.zeros((40, 40), bool)
    model = np.zeros((40, 40), bool)
    observed[2:22, 2:22] = True
    model[12:32, 12:32] = True
    out = overlay_silhouettes(image, observed, model)
    b, g, r = (int(x) for x in out[6, 6])
    assert b > r and b > 120  # observed only: light blue
    b, g, r = (int(x) for x in out[28, 28])
    assert r > 100 and g < 30 and b < 30  # model only: dark red
    b, g, r = (int(x) for x in out[16, 16])
    assert r > 150 and 60 < g < 120 and b < 10  # both: orange
    assert (out[37, 2] == 0).all()  # neither: the image
