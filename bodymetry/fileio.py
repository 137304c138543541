"""Atomic, deterministic and safe file I/O shared by every stage.

* Outputs are written atomically (temporary file in the same folder, then
  ``os.replace``) so an interrupted run never leaves a half-written file.
* ``.npz`` files are written with fixed zip timestamps so the same arrays give
  the same bytes (the body-model bake must be reproducible bit for bit).
* ``.npz`` files are read with ``allow_pickle=False`` only.
* JSON is written strict (no ``NaN``/``Infinity``, which other readers refuse):
  numpy values become plain numbers and non-finite floats become ``null``.
* Text files read whole (YAML, TOML, JSON) are read through
  :func:`read_text_limited`, so a wrong path to a huge file is a clear error,
  not minutes of parsing or an exhausted memory.
* YAML (session and calibration files, ``--set`` values) is parsed by
  :func:`parse_yaml`: safe, duplicate keys refused, ``1e-5`` a number.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import re
import tempfile
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bodymetry.errors import InputError

_ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it onto ``path`` on success.

    Parameters
    ----------
    path
        Final destination. Its parent folder is created if missing.

    Yields
    ------
    Path
        Where to write. If the block raises, the temporary file is removed and
        ``path`` is left untouched.
    """
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{final.name}.", suffix=".tmp", dir=final.parent)
    except OSError as exc:
        raise _naming(exc, final) from exc
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        # mkstemp creates the file 0600; give it the usual permissions.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, final)
    except OSError as exc:
        # The user asked for ``final``: name it, not the temporary file beside it
        # (a full disk, a folder that became read-only).
        if exc.filename is not None and Path(exc.filename) == tmp:
            raise _naming(exc, final) from exc
        raise
    finally:
        if tmp.exists():
            tmp.unlink()


def _naming(exc: OSError, path: Path) -> OSError:
    """The same error (type and errno) about ``path``."""
    return type(exc)(exc.errno, exc.strerror or str(exc), str(path))


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    write_bytes_atomic(path, text.encode("utf-8"))


def json_safe(obj: Any, where: str = "") -> Any:
    """``obj`` with numpy values made plain and non-finite floats made ``None``.

    Strict JSON has no ``NaN`` or ``Infinity`` (Python writes them, most other
    readers refuse them), and ``json`` cannot write numpy scalars or arrays.

    Parameters
    ----------
    obj
        Nested mappings, lists and tuples of ``None``, bool, int, float, str,
        numpy scalars and numpy arrays.
    where
        Where ``obj`` sits in the whole (for the error message).

    Returns
    -------
    The same structure with dicts, lists and plain scalars only.

    Raises
    ------
    TypeError
        For any other type (a programming error), naming where it sits.
    """
    if obj is None or isinstance(obj, (bool, int, str)):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, np.generic):
        return json_safe(obj.item(), where)
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist(), where)
    if isinstance(obj, Mapping):
        out = {}
        for key, value in obj.items():
            if isinstance(key, np.generic):
                key = key.item()
            if key is not None and not isinstance(key, (str, int, float, bool)):
                raise TypeError(f"JSON{where}: key {key!r} of type {type(key).__name__}")
            out[key] = json_safe(value, f"{where}[{key!r}]")
        return out
    if isinstance(obj, (list, tuple)):
        return [json_safe(value, f"{where}[{i}]") for i, value in enumerate(obj)]
    raise TypeError(f"JSON{where}: cannot write a value of type {type(obj).__name__}")


def write_json_atomic(path: str | os.PathLike[str], obj: Any) -> None:
    """Write ``obj`` as indented, strict JSON to ``path`` atomically.

    Numpy scalars and arrays are written as numbers and lists, non-finite
    floats (``nan``, ``inf``) as ``null`` (see :func:`json_safe`).

    Raises
    ------
    TypeError
        If ``obj`` holds a value JSON cannot represent (e.g. a ``Path``), naming
        where; nothing is written then.
    """
    try:
        safe = json_safe(obj)
    except TypeError as exc:
        raise TypeError(f"{path}: {exc}") from None
    write_text_atomic(path, json.dumps(safe, indent=2, sort_keys=False, allow_nan=False) + "\n")


def format_size(n_bytes: int) -> str:
    """A file size for messages: ``"812 bytes"``, ``"3.2 kB"``, ``"52.4 MB"``, ``"1 MB"``."""
    for unit, scale in (("GB", 10**9), ("MB", 10**6), ("kB", 10**3)):
        if n_bytes >= scale:
            text = f"{n_bytes / scale:.1f}"
            return f"{text.removesuffix('.0')} {unit}"
    return f"{n_bytes} bytes"


def read_text_limited(
    path: str | os.PathLike[str], max_bytes: int, what: str, encoding: str = "utf-8"
) -> str:
    """Read a whole text file, refusing one larger than ``max_bytes``.

    Newlines are translated as :meth:`pathlib.Path.read_text` does.

    Parameters
    ----------
    path
        The file.
    max_bytes
        The largest size accepted (bytes).
    what
        What the file is, for the message (``"session file"``).
    encoding
        Text encoding (strict decoding).

    Raises
    ------
    InputError
        ``"<path>: 52.4 MB, larger than the 1 MB limit for a session file"``.
    OSError, UnicodeDecodeError
        As from :meth:`pathlib.Path.read_text`; callers name the file.
    """
    path = Path(path)
    limit = format_size(max_bytes)
    with open(path, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        if size > max_bytes:
            shown = format_size(size)
            if shown == limit:  # 1,000,001 bytes is not "1 MB, larger than 1 MB"
                shown = f"{size:,} bytes"
            raise InputError(f"{path}: {shown}, larger than the {limit} limit for a {what}")
        # Read one byte past the limit: a pipe or special file reports no size,
        # and a file may grow while it is read.
        data = fh.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise InputError(f"{path}: more than the {limit} limit for a {what}")
    return data.decode(encoding).replace("\r\n", "\n").replace("\r", "\n")


def npz_bytes(arrays: Mapping[str, np.ndarray], compress: bool = True) -> bytes:
    """Serialize arrays to ``.npz`` bytes that depend only on the arrays.

    ``np.savez`` stamps each member with the current time; this writes the same
    format with a fixed timestamp and a fixed member order (the mapping's).

    Parameters
    ----------
    arrays
        Name -> array. Object arrays are refused (they would need pickle).
    compress
        Deflate the members (``np.savez_compressed`` equivalent).
    """
    buffer = io.BytesIO()
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(buffer, "w", compression=method) as zf:
        for name, value in arrays.items():
            array = np.asanyarray(value)
            if array.dtype.hasobject:
                raise TypeError(f"array {name!r} has dtype object; refusing to pickle it")
            member = io.BytesIO()
            np.lib.format.write_array(member, array, allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_EPOCH)
            info.compress_type = method
            info.external_attr = 0o644 << 16
            zf.writestr(info, member.getvalue(), compresslevel=9 if compress else None)
    return buffer.getvalue()


def save_npz(path: str | os.PathLike[str], arrays: Mapping[str, np.ndarray]) -> None:
    """Write a deterministic compressed ``.npz`` atomically (see :func:`npz_bytes`)."""
    write_bytes_atomic(path, npz_bytes(arrays))


def load_npz(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """Read every array of an ``.npz`` file without allowing pickle.

    Raises
    ------
    InputError
        If the file is missing, not a zip of ``.npy`` members, or holds objects.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    try:
        # Open the file here: np.load leaks its own handle when the zip is corrupt.
        with open(path, "rb") as fh:
            data = np.load(fh, allow_pickle=False)
            if not isinstance(data, np.lib.npyio.NpzFile):  # a plain .npy file
                raise InputError(f"{path}: not a .npz archive (a single .npy array)")
            with data:
                return {name: data[name] for name in data.files}
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"{path}: not a readable .npz file ({exc})") from exc


# --------------------------------------------------------------------------
# YAML reading: safe loader, duplicate keys refused, YAML 1.2 floats.
# --------------------------------------------------------------------------
class _SafeStrictLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses duplicate keys and reads ``1e-5`` as a float.

    PyYAML implements YAML 1.1, where ``1e-5`` (no dot, or no exponent sign) is a
    *string*; YAML 1.2 and every other tool read it as a number.
    """


_FLOAT_12 = re.compile(
    r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$",
)
_SafeStrictLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12, list("-+0123456789."))


def _construct_mapping_no_duplicates(loader: yaml.SafeLoader, node: yaml.MappingNode) -> dict:
    loader.flatten_mapping(node)
    seen: dict[Any, int] = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        try:
            hash(key)
        except TypeError:
            raise yaml.constructor.ConstructorError(
                "while constructing a mapping",
                node.start_mark,
                "found an unhashable key",
                key_node.start_mark,
            ) from None
        if key in seen:
            raise yaml.constructor.ConstructorError(
                "while constructing a mapping",
                node.start_mark,
                f"found duplicate key {key!r} (first on line {seen[key] + 1})",
                key_node.start_mark,
            )
        seen[key] = key_node.start_mark.line
    return loader.construct_mapping(node, deep=True)


_SafeStrictLoader.add_constructor(
    yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping_no_duplicates
)


def parse_yaml(text: str) -> Any:
    """Parse YAML text safely (no object construction), refusing duplicate keys."""
    return yaml.load(text, Loader=_SafeStrictLoader)  # a SafeLoader subclass: safe


#: The largest JSON file read whole by default (a long run's ``results.json`` at the best
#: quality stays well under; anything larger is the wrong file).
JSON_MAX_BYTES = 256_000_000


def read_json_object(
    path: Path, max_bytes: int = JSON_MAX_BYTES, what: str = "run JSON file"
) -> dict[str, Any]:
    """A JSON object from a file; InputError naming the file when it is unreadable.

    Parameters
    ----------
    path
        The file.
    max_bytes
        The largest file read (default :data:`JSON_MAX_BYTES`).
    what
        What the file is, for the size-limit message.

    Raises
    ------
    InputError
        Missing, unreadable, too large or malformed file, or not a JSON object.
    """
    path = Path(path)
    try:
        data = json.loads(read_text_limited(path, max_bytes, what))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not a readable JSON file ({exc})") from exc
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a JSON object, got {type(data).__name__}")
    return data
