"""The calibration stage of bodymetry (``bodymetry.calibration``; see docs/design.md)."""
