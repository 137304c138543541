"""bodymetry: body pose, shape and biometrics from synchronized multi-camera video.

The pipeline stages live in the top-level packages ``capture``, ``calibration``,
``estimation`` and ``review``; this package holds the command line and the small
pieces every stage shares (file I/O, logging, errors).
"""

__version__ = "0.1.0"
