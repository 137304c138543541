"""The synthetic capture studio: renders ground-truth multi-camera sessions."""
