"""review stage of bodymetry (see docs/ and DESIGN.md)."""
