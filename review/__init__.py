"""The review stage of bodymetry (``bodymetry.review``; see docs/design.md)."""
