"""Whether two runs of a session measured the same: ``python -m benchmarks.compare_runs A B``.

Compares the ``results.json`` of two run folders on what the fit decided, not
on how long it took: per person (a run of one subject is one person), every
frame's record (status, flags, each stage's state and measurements, IoU,
traces) without its ``seconds``, the summary, the session stage, the quality
gate and the warnings; and the run's warnings and models. Prints each difference and
exits 1 when there is one (0 when the runs are equal). Used to check that a
refactor or another executor (``batch`` against ``process``) changes no number.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from bodymetry.estimation.run_files import PersonResults, RunResults


def _frames(person: PersonResults) -> list[dict[str, Any]]:
    return [{k: v for k, v in r.to_json().items() if k != "seconds"} for r in person.frames]


def _session(person: PersonResults) -> dict[str, Any] | None:
    if person.session_shape is None:
        return None
    # The stage's own timing is not a result.
    return {k: v for k, v in person.session_shape.to_json().items() if k != "seconds"}


def _person_differences(a: PersonResults, b: PersonResults, name: str) -> list[str]:
    out = []
    fa, fb = _frames(a), _frames(b)
    if [f["frame"] for f in fa] != [f["frame"] for f in fb]:
        out.append(f"{name}kept frames differ")
    for x, y in zip(fa, fb, strict=False):
        for key in sorted(set(x) | set(y)):
            if x.get(key) != y.get(key):
                out.append(f"{name}frame {x['frame']}: {key} differs")
    parts = {
        "summary": (a.to_json()["summary"], b.to_json()["summary"]),
        "session_shape": (_session(a), _session(b)),
        "quality_gate": (a.quality_gate, b.quality_gate),
        "warnings": (a.warnings, b.warnings),
    }
    return out + [f"{name}{part} differs" for part, (x, y) in parts.items() if x != y]


def differences(a: RunResults, b: RunResults) -> list[str]:
    """What differs between two runs' results (empty when they measured the same)."""
    ids_a, ids_b = [p.id for p in a.persons], [p.id for p in b.persons]
    out = [] if ids_a == ids_b else [f"persons differ: {ids_a} against {ids_b}"]
    several = a.several or b.several
    for pa, pb in zip(a.persons, b.persons, strict=False):
        out += _person_differences(pa, pb, f"person {pa.id}: " if several else "")
    parts = {"warnings": (a.warnings, b.warnings), "models": (a.models, b.models)}
    return out + [f"{name} differs" for name, (x, y) in parts.items() if x != y]


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: python -m benchmarks.compare_runs RUN_A RUN_B", file=sys.stderr)
        return 2
    a, b = (RunResults.read(Path(p) / "results.json") for p in argv)
    diff = differences(a, b)
    for line in diff:
        print(line)
    n = sum(len(p.frames) for p in a.persons)
    print(
        f"{'equal' if not diff else 'DIFFERENT'}: {len(a.persons)} person(s), {n} frames, "
        f"{len(diff)} difference(s)"
    )
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
