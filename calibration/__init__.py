"""The calibration stage of bodymetry (``bodymetry.calibration``; see docs/design.md).

The public API, importable from here (``from bodymetry.calibration import CameraGroup``);
each name is loaded on first use, so importing the package costs nothing.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "camera": ["Camera", "CameraGroup"],
        "io": ["Calibration", "load_calibration", "read_calibration", "save_calibration"],
        "solve": [
            "CalibrationError",
            "CalibrationOptions",
            "CalibrationResult",
            "calibrate_cameras",
        ],
        "session_calibration": ["calibrate_session", "write_calibration"],
        "charuco": ["detect_clip", "detect_image"],
        "anipose": ["export_anipose_toml", "import_anipose_toml"],
        "qualisys": ["import_qca", "read_qca"],
    },
)
