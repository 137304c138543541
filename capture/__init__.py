"""The capture stage of bodymetry (``bodymetry.capture``; see docs/design.md)."""
