"""Whether two runs of a session measured the same: ``python -m benchmarks.compare_runs A B``.

Compares the ``results.json`` of two run folders on what the fit decided, not
on how long it took: every frame's record (status, flags, each stage's state
and measurements, IoU, traces) without its ``seconds``, the summary, the
session stage, the quality gate and the warnings. Prints each difference and
exits 1 when there is one (0 when the runs are equal). Used to check that a
refactor or another executor (``batch`` against ``process``) changes no number.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from bodymetry.estimation.run_files import RunResults


def _frames(results: RunResults) -> list[dict[str, Any]]:
    return [{k: v for k, v in r.to_json().items() if k != "seconds"} for r in results.frames]


def _session(results: RunResults) -> dict[str, Any] | None:
    if results.session_shape is None:
        return None
    # The stage's own timing is not a result.
    return {k: v for k, v in results.session_shape.to_json().items() if k != "seconds"}


def differences(a: RunResults, b: RunResults) -> list[str]:
    """What differs between two runs' results (empty when they measured the same)."""
    out = []
    fa, fb = _frames(a), _frames(b)
    if [f["frame"] for f in fa] != [f["frame"] for f in fb]:
        out.append("kept frames differ")
    for x, y in zip(fa, fb, strict=False):
        for key in sorted(set(x) | set(y)):
            if x.get(key) != y.get(key):
                out.append(f"frame {x['frame']}: {key} differs")
    parts = {
        "summary": (a.to_json()["summary"], b.to_json()["summary"]),
        "session_shape": (_session(a), _session(b)),
        "quality_gate": (a.quality_gate, b.quality_gate),
        "warnings": (a.warnings, b.warnings),
        "models": (a.models, b.models),
    }
    out += [f"{name} differs" for name, (x, y) in parts.items() if x != y]
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: python -m benchmarks.compare_runs RUN_A RUN_B", file=sys.stderr)
        return 2
    a, b = (RunResults.read(Path(p) / "results.json") for p in argv)
    diff = differences(a, b)
    for line in diff:
        print(line)
    n = len(a.frames)
    print(f"{'equal' if not diff else 'DIFFERENT'}: {n} frames, {len(diff)} difference(s)")
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
