"""numba, set up once for every compiled kernel of bodymetry.

The kernel modules (``estimation.raster_kernels``, ``feature_kernels``,
``likelihood_kernels``, ``body_model.scape_kernels``,
``body_model.skeleton_kernels``) take numba from here::

    from bodymetry.jit import numba

Importing this module imports numba (about 0.35 s), so the stages import their
kernel modules lazily, only when their backend is ``"numba"``: importing the
rasterizer, the features or the body model does not import numba.

Compiled code is cached on disk (``cache=True``): next to each kernel's source
when its ``__pycache__`` is writable, else under ``$NUMBA_CACHE_DIR``, which
:func:`numba_cache_dir` points to the bodymetry cache when it is unset. numba
reads that variable when it is first imported, so it is set here, before the
import; a kernel module that imported numba itself first would fix the cache
folder too early.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path

__all__ = ["inline_copy", "numba", "numba_cache_dir"]


def numba_cache_dir(
    package_dir: Path, environ: dict[str, str] | os._Environ, writable: bool
) -> str | None:
    """Where numba should cache the kernels, when its default would not do.

    Numba caches next to the source when the package folder is writable
    (an editable install) and otherwise in a user-wide folder; when neither is
    usable it raises at decoration time. An installed, read-only package gets
    ``$BODYMETRY_CACHE/numba`` (default ``~/.cache/bodymetry/numba``), next to
    the trained models.

    Parameters
    ----------
    package_dir : Path
        The folder of the installed package (this module's).
    environ : mapping
        The environment (``NUMBA_CACHE_DIR``, ``BODYMETRY_CACHE``).
    writable : bool
        Whether ``package_dir`` (its ``__pycache__``) can be written.

    Returns
    -------
    str or None
        The folder to set as ``NUMBA_CACHE_DIR``; None to leave numba's choice
        (the user set one, or the package folder is writable).
    """
    if environ.get("NUMBA_CACHE_DIR") or writable:
        return None
    root = environ.get("BODYMETRY_CACHE")
    base = Path(root).expanduser() if root else Path.home() / ".cache" / "bodymetry"
    return str(base / "numba")


def _package_writable(package_dir: Path) -> bool:
    pycache = package_dir / "__pycache__"
    target = pycache if pycache.is_dir() else package_dir
    return os.access(target, os.W_OK)


_here = Path(__file__).resolve().parent
_cache = numba_cache_dir(_here, os.environ, _package_writable(_here))
if _cache is not None:
    os.makedirs(_cache, exist_ok=True)
    os.environ["NUMBA_CACHE_DIR"] = _cache

import numba  # noqa: E402  (after NUMBA_CACHE_DIR is set)

if _cache is not None and "numba.core.config" in sys.modules:
    # numba reads its environment once at import; it may have been imported before.
    numba.core.config.reload_config()


def inline_copy(kernel: Callable) -> Callable:
    """A copy of a compiled function that numba inlines into its callers.

    The copy compiles the same Python function (``kernel.py_func``), so the same
    expressions, with ``cache=True, nogil=True, inline="always"``: a kernel's
    tight loop calls the copy with no call overhead, while other callers (and
    the tests) keep the ordinary, separately compiled function.

    Parameters
    ----------
    kernel : numba dispatcher
        A function decorated with ``numba.njit``.

    Returns
    -------
    numba dispatcher
        The inlining copy.
    """
    return numba.njit(cache=True, nogil=True, inline="always")(kernel.py_func)
