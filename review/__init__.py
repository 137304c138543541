"""The review stage of bodymetry (``bodymetry.review``; see docs/design.md).

The public API, importable from here (``from bodymetry.review import build_review``);
each name is loaded on first use, so importing the package costs nothing.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "build": ["ReviewSummary", "build_review"],
        "report": ["ReportFiles", "build_report"],
        "run_data": ["RunData", "load_run"],
        "evaluation": ["evaluate_run"],
        "cohort": ["write_cohort"],
    },
)
