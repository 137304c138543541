"""bodymetry: body pose, shape and biometrics from synchronized multi-camera video.

One import name for the whole project (docs/design.md): the stages are the
subpackages ``bodymetry.calibration``, ``bodymetry.capture``,
``bodymetry.estimation`` and ``bodymetry.review`` (installed from the top-level
folders of the same names), the synthetic studio is ``bodymetry.studio``, and
this folder holds the application (CLI, ``process``, configuration) and the
small foundation every stage shares (errors, file I/O, logging, settings).
Importing ``bodymetry`` loads nothing else, so any stage can read ``__version__``;
it does set the BLAS thread limit (:mod:`bodymetry.threads`).
"""

__version__ = "0.1.0"

# One BLAS thread per process, for every entry point (docs/design.md, "Threads"):
# set before any stage loads NumPy, so pool and Dask workers inherit it.
from bodymetry.threads import limit_threads as _limit_threads

_limit_threads()
