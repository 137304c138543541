"""The numba set-up (:mod:`bodymetry.jit`): its on-disk cache folder and lazy import."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

needs_numba = pytest.mark.skipif(
    importlib.util.find_spec("numba") is None, reason="numba is not installed"
)


@needs_numba
def test_numba_cache_dir_only_when_the_package_is_read_only(tmp_path):
    from bodymetry.jit import numba_cache_dir

    here = Path(__file__).parent
    assert numba_cache_dir(here, {}, writable=True) is None
    assert numba_cache_dir(here, {"NUMBA_CACHE_DIR": "/x"}, writable=False) is None
    env = {"BODYMETRY_CACHE": str(tmp_path)}
    assert numba_cache_dir(here, env, writable=False) == str(tmp_path / "numba")
    default = Path.home() / ".cache" / "bodymetry" / "numba"
    assert numba_cache_dir(here, {}, writable=False) == str(default)


def test_importing_the_stages_does_not_import_numba():
    code = (
        "import sys\n"
        "import bodymetry.estimation.raster, bodymetry.estimation.generative\n"
        "import bodymetry.estimation.body_model.scape\n"
        "print('numba' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
