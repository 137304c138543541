"""Run every benchmark, or the ones named: ``python -m benchmarks [body_model ...]``.

Results are printed and written as JSON to ``benchmarks/results/<name>.json``
(``<name>_<flag>.json`` for a run with ``--flag``).
"""

from __future__ import annotations

import datetime
import importlib
import json
import os
import platform
import sys
from pathlib import Path

# BLAS threads: importing bodymetry limits them (bodymetry/threads.py).

BENCHMARKS = (
    "body_model",
    "studio",
    "discriminative",
    "calibration",
    "capture",
    "pipeline",
    "real",
)
#: Reports that are not timed benchmarks (run only when named).
REPORTS = {
    "arm_evidence": "benchmarks.bench_arm_evidence",
    "codebase": "benchmarks.codebase",
    "fusion_fit": "benchmarks.fusion_fit",
    "hidden_pixels": "benchmarks.bench_hidden_pixels",
    "imports": "benchmarks.imports",
    "person_tracks": "benchmarks.bench_person_tracks",
    "persons": "benchmarks.bench_persons",
    "posing": "benchmarks.bench_posing",
    "profile": "benchmarks.bench_profile",
    "rendered_weight": "benchmarks.bench_rendered_weight",
    "session_bias": "benchmarks.bench_session_bias",
    "session_spread": "benchmarks.bench_session_spread",
    "shape_space": "benchmarks.bench_shape_space",
    "standing_shape": "benchmarks.bench_standing_shape",
    "studio_accuracy": "benchmarks.bench_studio_accuracy",
    "thin_parts": "benchmarks.bench_thin_parts",
    "two_persons": "benchmarks.bench_two_persons",
}


def main(argv: list[str]) -> int:
    # ``--flag`` options go to every named benchmark's run() as flag=True
    # (e.g. ``pipeline --independent``).
    flags = {a[2:].replace("-", "_"): True for a in argv if a.startswith("--")}
    argv = [a for a in argv if not a.startswith("--")]
    names = argv or list(BENCHMARKS)
    unknown = [n for n in names if n not in BENCHMARKS and n not in REPORTS]
    if unknown:
        print(
            f"unknown benchmark(s) {unknown}; available: {', '.join([*BENCHMARKS, *REPORTS])}",
            file=sys.stderr,
        )
        return 2
    out_dir = Path(__file__).with_name("results")
    out_dir.mkdir(exist_ok=True)
    for name in names:
        module = importlib.import_module(REPORTS.get(name, f"benchmarks.bench_{name}"))
        result = module.run(**flags)
        result["machine"] = _machine()
        text = json.dumps(result, indent=2)
        print(f"== {name}\n{text}")
        # A flagged run is another benchmark's result: pipeline --independent ->
        # pipeline_independent.json beside pipeline.json.
        suffix = "".join(f"_{f}" for f in sorted(flags))
        (out_dir / f"{name}{suffix}.json").write_text(text + "\n")
    return 0


def _machine() -> dict:
    """What ran the benchmark: results differ in their last digits between CPUs
    (README, "The same code on three machines"), so the CPU and its widest vector
    instructions are recorded beside the date."""
    model, flags = platform.processor() or platform.machine(), set()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        for line in cpuinfo.read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name":
                model = value.strip()
            elif key.strip() == "flags":
                flags = set(value.split())
    simd = next((f for f in ("avx512f", "avx2", "sse4_2") if f in flags), None)
    return {
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "cpu": model,
        "simd": simd,
        "date": datetime.date.today().isoformat(),
    }


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
