"""Tests for bodymetry.fileio: atomic writes, deterministic .npz, pickle-free reading."""

from __future__ import annotations

import gc
import io
import json
import re
import time
import zipfile

import numpy as np
import pytest

from bodymetry import fileio
from bodymetry.errors import InputError

SEED = 20240619
#: The fixed timestamp every .npz member carries (zip's epoch).
ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)


def _arrays() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(SEED)
    return {
        "float": rng.normal(size=(20, 3)),
        "int8": rng.integers(-100, 100, 50).astype(np.int8),
        "half": rng.normal(size=(4, 5)).astype(np.float16),
        "scalar": np.array(3),
        "text": np.array(["root", "knuckle_l"]),
        "json": np.array(json.dumps({"a": 1})),
        "empty": np.zeros((0, 3)),
        "fortran": np.asfortranarray(rng.normal(size=(3, 4))),
    }


def _leftovers(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


# --- atomic writes ------------------------------------------------------------------------------


def test_atomic_path_writes_and_cleans_up(tmp_path):
    target = tmp_path / "sub" / "dir" / "out.txt"  # missing parents are created
    with fileio.atomic_path(target) as tmp:
        assert tmp.parent == target.parent
        assert tmp != target
        tmp.write_text("hello")
        assert not target.exists()  # nothing visible until the block succeeds
    assert target.read_text() == "hello"
    assert _leftovers(target.parent) == []


def test_atomic_path_keeps_the_old_file_when_the_block_raises(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError, match="boom"), fileio.atomic_path(target) as tmp:
        tmp.write_text("half-written")
        raise RuntimeError("boom")
    assert target.read_text() == "old"
    assert _leftovers(tmp_path) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


def test_atomic_path_without_a_previous_file(tmp_path):
    target = tmp_path / "new.bin"
    with pytest.raises(KeyError), fileio.atomic_path(target) as tmp:
        tmp.write_bytes(b"x")
        raise KeyError("interrupted")
    assert not target.exists()
    assert list(tmp_path.iterdir()) == []


def test_atomic_write_replaces_and_uses_normal_permissions(tmp_path):
    reference = tmp_path / "reference"
    reference.write_bytes(b"")  # created the usual way, under the current umask
    target = tmp_path / "out.bin"
    fileio.write_bytes_atomic(target, b"first")
    fileio.write_bytes_atomic(target, b"second")
    assert target.read_bytes() == b"second"
    assert target.stat().st_mode & 0o777 == reference.stat().st_mode & 0o777
    assert _leftovers(tmp_path) == []


def test_write_text_and_json(tmp_path):
    fileio.write_text_atomic(tmp_path / "t.txt", "ν = 1.5σ\n")
    assert (tmp_path / "t.txt").read_bytes() == "ν = 1.5σ\n".encode()
    obj = {"height_mm": 1685.0, "names": ["a", "b"], "nested": {"x": None}}
    fileio.write_json_atomic(tmp_path / "m.json", obj)
    text = (tmp_path / "m.json").read_text(encoding="utf-8")
    assert json.loads(text) == obj
    assert text.endswith("\n")


# --- deterministic .npz ---------------------------------------------------------------------------


def test_npz_bytes_round_trip():
    arrays = _arrays()
    for compress in (True, False):
        data = fileio.npz_bytes(arrays, compress=compress)
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            assert npz.files == list(arrays)  # the mapping's order
            for name, value in arrays.items():
                assert npz[name].dtype == value.dtype, name
                np.testing.assert_array_equal(npz[name], value)


def test_npz_bytes_is_deterministic(monkeypatch):
    arrays = _arrays()
    first = fileio.npz_bytes(arrays)
    assert fileio.npz_bytes(arrays) == first
    assert fileio.npz_bytes(dict(arrays)) == first
    # Another day, another clock: the same bytes.
    later = time.time() + 400 * 86400.0
    monkeypatch.setattr(time, "time", lambda: later)
    monkeypatch.setattr(time, "localtime", lambda *a: time.gmtime(later))
    assert fileio.npz_bytes(arrays) == first
    with zipfile.ZipFile(io.BytesIO(first)) as zf:
        assert all(info.date_time == ZIP_EPOCH for info in zf.infolist())
        assert all(info.compress_type == zipfile.ZIP_DEFLATED for info in zf.infolist())


def test_npz_bytes_depends_on_the_values_and_order():
    arrays = _arrays()
    changed = dict(arrays, float=arrays["float"] + 1e-15)
    assert fileio.npz_bytes(changed) != fileio.npz_bytes(arrays)
    reordered = dict(reversed(list(arrays.items())))
    assert fileio.npz_bytes(reordered) != fileio.npz_bytes(arrays)


def test_npz_compression():
    arrays = {"zeros": np.zeros((200, 200))}
    assert len(fileio.npz_bytes(arrays)) < len(fileio.npz_bytes(arrays, compress=False)) / 10


def test_object_arrays_are_refused(tmp_path):
    with pytest.raises(TypeError, match=r"'bad'.*object"):
        fileio.npz_bytes({"ok": np.zeros(2), "bad": np.array([{"a": 1}], dtype=object)})
    with pytest.raises(TypeError, match="object"):
        fileio.save_npz(tmp_path / "x.npz", {"bad": np.array([1, "a", None], dtype=object)})
    assert list(tmp_path.iterdir()) == []


def test_save_and_load_npz(tmp_path):
    arrays = _arrays()
    path = tmp_path / "model.npz"
    fileio.save_npz(path, arrays)
    assert path.read_bytes() == fileio.npz_bytes(arrays)
    loaded = fileio.load_npz(path)
    assert list(loaded) == list(arrays)
    for name, value in arrays.items():
        np.testing.assert_array_equal(loaded[name], value)
    # A str path works too, and the result does not depend on an open file.
    assert list(fileio.load_npz(str(path))) == list(arrays)
    assert _leftovers(tmp_path) == []


# --- load_npz rejects what it cannot read safely -----------------------------------------------


def _rejects(path, *patterns: str) -> None:
    with pytest.raises(InputError, match=re.escape(str(path))) as info:
        fileio.load_npz(path)
    for pattern in patterns:
        assert re.search(pattern, str(info.value)), str(info.value)
    gc.collect()  # a leaked file handle would surface here as a ResourceWarning (an error)


def test_load_npz_missing_file(tmp_path):
    _rejects(tmp_path / "nope.npz", "not found")
    _rejects(tmp_path, "not found")  # a folder is not a file


def test_load_npz_not_an_npz(tmp_path):
    text = tmp_path / "notes.npz"
    text.write_text("just some text, long enough to not be empty\n")
    _rejects(text)
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    _rejects(empty)
    npy = tmp_path / "array.npz"
    with open(npy, "wb") as fh:
        np.save(fh, np.arange(3))
    _rejects(npy, "npy")


def test_load_npz_corrupt_zip(tmp_path):
    good = fileio.npz_bytes(_arrays())
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good[: len(good) // 2])
    _rejects(truncated)
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"PK\x03\x04" + bytes(range(256)) * 4)
    _rejects(garbage)


def test_load_npz_refuses_pickles(tmp_path):
    path = tmp_path / "pickled.npz"
    np.savez(path, ok=np.zeros(3), evil=np.array([{"run": "code"}], dtype=object))
    _rejects(path, "(?i)object|pickle")


def test_input_error_is_a_value_error(tmp_path):
    with pytest.raises(ValueError):
        fileio.load_npz(tmp_path / "missing.npz")


# --- strict JSON ------------------------------------------------------------------------------


def _strict_loads(text: str):
    """json.loads that fails on NaN / Infinity (which strict JSON does not have)."""
    return json.loads(text, parse_constant=lambda c: 1 / 0)


def test_write_json_is_strict(tmp_path):
    path = tmp_path / "a.json"
    fileio.write_json_atomic(
        path, {"a": float("nan"), "b": np.float32(1.5), "c": np.array([1, np.inf])}
    )
    assert _strict_loads(path.read_text()) == {"a": None, "b": 1.5, "c": [1.0, None]}


def test_write_json_converts_nested_numpy_values(tmp_path):
    path = tmp_path / "a.json"
    obj = {
        "ints": np.arange(3, dtype=np.int16),
        "bool": np.bool_(True),
        "nested": [(np.float64(-np.inf), 2), {"x": np.array([[np.nan, 0.25]])}],
        np.int64(7): "numpy key",
        "text": np.str_("ok"),
    }
    fileio.write_json_atomic(path, obj)
    assert _strict_loads(path.read_text()) == {
        "ints": [0, 1, 2],
        "bool": True,
        "nested": [[None, 2], {"x": [[None, 0.25]]}],
        "7": "numpy key",
        "text": "ok",
    }


def test_write_json_refuses_other_types_naming_where(tmp_path):
    path = tmp_path / "a.json"
    with pytest.raises(TypeError, match=r"a\.json.*\['frames'\]\[1\].*PosixPath"):
        fileio.write_json_atomic(path, {"frames": [1, tmp_path]})
    assert not path.exists() and _leftovers(tmp_path) == []


# --- size limits ------------------------------------------------------------------------------


def test_read_text_limited_reads_small_files(tmp_path):
    path = tmp_path / "a.yaml"
    path.write_bytes("a: 1\r\nb: é\r\n".encode())
    assert fileio.read_text_limited(path, 100, "session file") == "a: 1\nb: é\n"


def test_read_text_limited_refuses_a_large_file(tmp_path):
    path = tmp_path / "big.yaml"
    with open(path, "wb") as fh:
        fh.truncate(52_400_000)  # sparse: instant, takes no disk
    with pytest.raises(InputError) as info:
        fileio.read_text_limited(path, 1_000_000, "session file")
    assert str(info.value) == f"{path}: 52.4 MB, larger than the 1 MB limit for a session file"


def test_read_text_limited_at_the_limit(tmp_path):
    path = tmp_path / "a.txt"
    path.write_bytes(b"x" * 1000)
    assert len(fileio.read_text_limited(path, 1000, "file")) == 1000
    path.write_bytes(b"x" * 1001)
    with pytest.raises(InputError, match=r"1,001 bytes, larger than the 1 kB limit for a file"):
        fileio.read_text_limited(path, 1000, "file")


def test_read_text_limited_passes_os_errors_on(tmp_path):
    with pytest.raises(FileNotFoundError):
        fileio.read_text_limited(tmp_path / "missing", 10, "file")


@pytest.mark.parametrize(
    ("n", "text"),
    [
        (0, "0 bytes"),
        (999, "999 bytes"),
        (1000, "1 kB"),
        (1_500, "1.5 kB"),
        (256_000_000, "256 MB"),
    ],
)
def test_format_size(n, text):
    assert fileio.format_size(n) == text


def test_atomic_write_errors_name_the_file_not_the_temporary(tmp_path, monkeypatch):
    def full(*args, **kwargs):
        raise OSError(28, "No space left on device", args[0] if args else "x")

    monkeypatch.setattr(fileio.tempfile, "mkstemp", full)
    with pytest.raises(OSError) as info:
        fileio.write_text_atomic(tmp_path / "a.txt", "x")
    assert info.value.errno == 28 and info.value.filename == str(tmp_path / "a.txt")


def test_atomic_write_errors_of_the_body_name_the_file(tmp_path):
    with pytest.raises(PermissionError) as info, fileio.atomic_path(tmp_path / "a.txt") as tmp:
        raise PermissionError(13, "Permission denied", str(tmp))
    assert info.value.filename == str(tmp_path / "a.txt")
    assert _leftovers(tmp_path) == []
