"""Each package exports its public API (``from bodymetry.calibration import CameraGroup``)."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

PACKAGES = ("calibration", "capture", "estimation", "review", "studio")


@pytest.mark.parametrize("package", PACKAGES)
def test_every_exported_name_resolves_to_its_module_object(package):
    mod = importlib.import_module(f"bodymetry.{package}")
    assert mod.__all__, f"bodymetry.{package} exports nothing"
    for name in mod.__all__:
        obj = getattr(mod, name)
        assert name in dir(mod)
        # The same object as in its own module: an export is never a copy.
        home = getattr(obj, "__module__", None)
        if home is not None and home.startswith("bodymetry."):
            assert getattr(importlib.import_module(home), name) is obj


def test_an_unknown_name_is_an_attribute_error():
    mod = importlib.import_module("bodymetry.estimation")
    with pytest.raises(AttributeError):
        mod.NoSuchThing  # noqa: B018


def test_importing_a_package_loads_none_of_its_modules():
    """The exports load on first use: ``import bodymetry.estimation`` stays cheap."""
    code = (
        "import sys, bodymetry.calibration, bodymetry.capture, bodymetry.estimation, "
        "bodymetry.review, bodymetry.studio\n"
        "print(' '.join(m for m in sys.modules if m.startswith('bodymetry.') and m.count('.') > 1))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == []
