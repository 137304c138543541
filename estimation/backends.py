"""Choosing between a compiled path and its numpy reference, in one place.

The rasterizer (``BODYMETRY_RASTER``), the silhouette likelihood and the contour
refinement's kernels (``BODYMETRY_LIKELIHOOD``), the shape-context features
(``BODYMETRY_FEATURES``), the skeleton's forward kinematics and the body model's
anchor targets (``BODYMETRY_SKELETON``), the SCAPE edges
(``BODYMETRY_SCAPE_EDGES``) and the SCAPE solve (``BODYMETRY_SCAPE_SOLVER``) each
have a fast path from an optional package and a reference path. An environment
variable picks one; unset, the fast path is used when its package is installed
(checked without importing it, so that importing bodymetry stays cheap).
"""

from __future__ import annotations

import importlib
import importlib.util
import logging
import os
from types import ModuleType

log = logging.getLogger(__name__)

__all__ = ["compiled_kernels", "default_backend", "load_kernels"]


def default_backend(env_var: str, value: str | None, choices: tuple[str, str], package: str) -> str:
    """The backend named by ``value`` (an environment variable's content), or, when
    it is empty, ``choices[0]`` if ``package`` is installed, else ``choices[1]``.

    Raises
    ------
    ValueError
        When ``value`` names no backend (the message names ``env_var``).
    """
    if value:
        if value not in choices:
            raise ValueError(
                f"{env_var} must be {' or '.join(repr(c) for c in choices)}, got {value!r}"
            )
        return value
    return choices[0] if importlib.util.find_spec(package) is not None else choices[1]


_loaded: dict[str, ModuleType | None] = {}


def compiled_kernels(
    backend: str, setting: str, module: str, env_var: str, what: str
) -> ModuleType | None:
    """The kernels ``module`` when ``backend`` is ``"numba"``, None for ``"numpy"``.

    Imported once (:func:`load_kernels`); None also when numba fails to import
    and the user did not ask for it, and the caller then sets its backend to
    ``"numpy"``.

    Raises
    ------
    ValueError
        For any other ``backend`` (the message names ``setting``, the module
        attribute that holds it).
    """
    if backend == "numpy":
        return None
    if backend != "numba":
        raise ValueError(f"{setting} must be 'numba' or 'numpy', got {backend!r}")
    if module not in _loaded:
        _loaded[module] = load_kernels(module, env_var, what)
    return _loaded[module]


def module_kernels(
    namespace: dict, attr: str, module: str, env_var: str, what: str
) -> ModuleType | None:
    """:func:`compiled_kernels` for the backend a module keeps in ``namespace[attr]``.

    ``namespace`` is that module's ``globals()``; when numba was chosen by
    default but fails to import, the setting falls back to ``"numpy"`` there,
    so the module's numpy path is used from then on.
    """
    setting = f"{namespace['__name__'].rsplit('.', 1)[-1]}.{attr}"
    kernels = compiled_kernels(namespace[attr], setting, module, env_var, what)
    if kernels is None:
        namespace[attr] = "numpy"
    return kernels


def load_kernels(module: str, env_var: str, what: str) -> ModuleType | None:
    """Import the compiled kernels ``module``; None (and a warning) when numba fails
    to import and the user did not ask for it, so the caller uses its numpy path.

    Raises
    ------
    ImportError
        When ``env_var`` asks for numba explicitly and it fails to import.
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        if os.environ.get(env_var) == "numba":
            raise ImportError(f"{env_var}=numba but numba fails to import: {exc}") from exc
        log.warning("numba fails to import (%s): using the numpy %s", exc, what)
        return None
