"""Size limits on the run files read whole (results.json, frame records)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from bodymetry.errors import InputError
from bodymetry.estimation.records import FRAME_RECORD_MAX_BYTES, FrameRecord
from bodymetry.estimation.run_files import RunResults
from bodymetry.fileio import JSON_MAX_BYTES, read_json_object


def _sparse(path: Path, size: int) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        fh.truncate(size)  # a sparse file: instant, takes no disk
    return path


def test_oversized_results_json(tmp_path: Path) -> None:
    path = _sparse(tmp_path / "run" / "results.json", JSON_MAX_BYTES + 52_400_000)
    with pytest.raises(InputError) as info:
        RunResults.read(path)
    assert str(info.value) == f"{path}: 308.4 MB, larger than the 256 MB limit for a run JSON file"


def test_oversized_frame_record(tmp_path: Path) -> None:
    path = _sparse(tmp_path / "run" / "frames" / "000025.json", FRAME_RECORD_MAX_BYTES + 1)
    with pytest.raises(
        InputError,
        match=re.escape(f"{path}: 4,000,001 bytes, larger than the 4 MB limit for a frame record"),
    ):
        FrameRecord.read(path)


def test_a_frame_record_under_the_limit_is_parsed(tmp_path: Path) -> None:
    path = tmp_path / "frames" / "000025.json"
    path.parent.mkdir()
    path.write_text('{"frame": 25}' + " " * 3_000_000)
    assert read_json_object(path) == {"frame": 25}


def test_explicit_limit(tmp_path: Path) -> None:
    path = tmp_path / "evaluation.json"
    path.write_text('{"a": 1}')
    assert read_json_object(path, max_bytes=8) == {"a": 1}
    with pytest.raises(InputError, match="8 bytes, larger than the 7 bytes limit"):
        read_json_object(path, max_bytes=7)
