"""calibration stage of bodymetry (see docs/ and DESIGN.md)."""
