"""A run of two persons made from the tiny review run (format 3, ``persons/K/``)."""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path
from typing import Any

#: Added to person 1's heights (mm) in the two-person fixture: each person's numbers
#: differ, so a test can tell whose are shown where.
PERSON1_HEIGHT_SHIFT_MM = 111.0


def two_person_copy(review_run: Any, folder: Path) -> Path:
    """A copy of the review run as a run of two persons (format 3, ``persons/K/``).

    Person 0 is the fixture's subject; person 1 the same fits with every
    height (per frame, per stage, the summary and the session stage) raised by
    :data:`PERSON1_HEIGHT_SHIFT_MM`. Each person's frame files are in
    ``persons/K/frames`` and ``persons/K/meshes`` as ``process`` keeps them for a
    run of several persons; the review files of the copy are removed.
    """
    shutil.copytree(review_run.folder, folder)
    for name in (
        "recording.rrd",
        "recording.mcap",
        "report.html",
        "report.pdf",
        "measurements.csv",
    ):
        (folder / name).unlink(missing_ok=True)
    for person in ("0", "1"):
        for sub in ("frames", "meshes"):
            shutil.copytree(review_run.folder / sub, folder / "persons" / person / sub)
    for sub in ("frames", "meshes"):
        shutil.rmtree(folder / sub)
    data = json.loads((folder / "results.json").read_text())
    first = data["persons"][0]
    second = copy.deepcopy(first)
    second["id"] = 1
    second["told_apart"] = True
    second["warnings"] = ["person 1 was hidden behind person 0 in cam_01 for a while"]
    for frame in second["frames"]:
        for stage in ("discriminative", "generative", "session"):
            estimate = frame.get(stage) or {}  # the biometrics beside the state
            if estimate.get("height_mm") is not None:
                estimate["height_mm"] += PERSON1_HEIGHT_SHIFT_MM
    for stats in second["summary"].values():
        if stats.get("height_mm", {}).get("mean") is not None:
            stats["height_mm"]["mean"] += PERSON1_HEIGHT_SHIFT_MM
    shape = second.get("session_shape") or {}
    if shape.get("biometrics", {}).get("height_mm") is not None:
        shape["biometrics"]["height_mm"] += PERSON1_HEIGHT_SHIFT_MM
    first["told_apart"] = True
    data["persons"] = [first, second]
    (folder / "results.json").write_text(json.dumps(data))
    return folder
