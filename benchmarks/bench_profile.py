"""Where one frame's fit spends its time: ``python -m benchmarks profile``.

Fits kept frames of the demo recording (default preset) under ``cProfile`` and
splits the time by what the code does, from each function's own time (not
counting what it calls), so the next bottleneck is visible. Times are the
process's CPU time (the machine may be shared), wall time beside the total:

- ``rasterize``: the triangle rasterizer (``estimation/raster.py``, its
  kernels) and model silhouettes (``estimation/projection.py``);
- ``pose``: posing the body model (forward kinematics, SCAPE Eq. 1 and solve,
  ``estimation/body_model``);
- ``biometrics``: the measurements of the fitted body (``body_model/biometrics.py``
  and the mesh geometry it uses);
- ``chamfer``: the likelihood (``estimation/generative.py``) and the annealing's
  bookkeeping. With the compiled likelihood this includes the coverage of the
  model silhouettes and the model's distance transforms: one fused kernel
  (``likelihood_kernels.chamfer_kernel``) does both, so the likelihood's
  rasterization is counted here, not under ``rasterize``;
- ``projection``: vertices through the cameras' lens model (``Camera.project``
  and the compiled projection kernels);
- ``refinement``: the contour refinement (``estimation/refinement.py``,
  ``contours.py``, ``least_squares.py``, its compiled contour kernel);
- ``discriminative``: features and mixtures of experts;
- ``fit (other)``: the per-frame fit's own glue (``estimation/fit.py``);
- ``other``: numpy and OpenCV calls made by none of the above's own code, Python.

Time inside numpy or OpenCV is charged to the bodymetry function that called
it. Uses the user's model cache (training the demo rig first when it is
missing: minutes). ``BODYMETRY_PROFILE_FRAMES`` sets how many frames (default 3).
"""

from __future__ import annotations

import cProfile
import os
import pstats
import time
from collections import defaultdict
from pathlib import Path

from bodymetry.capture.segmentation import segment_session
from bodymetry.capture.session import load_session
from bodymetry.cli import DEMO_SESSION
from bodymetry.estimation import generative, raster
from bodymetry.estimation.body_model import scape
from bodymetry.estimation.fit import shared_body_model
from bodymetry.estimation.resolution import WorkingResolution
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.training import cached_models_path, load_or_train
from bodymetry.frame_jobs import FitJob, run_fit_job

#: Compiled kernels named by function (their module serves several categories).
KERNELS = {
    "chamfer_kernel": "chamfer",
    "chamfer_distance_3x3": "chamfer",
    "project_kernel": "projection",
    "project_midpoints_kernel": "projection",
    "contour_kernel": "refinement",
    "nearest_pairs_kernel": "refinement",
    "moved_rows_kernel": "refinement",
    "line_residuals_kernel": "refinement",
}

#: Source path fragments -> category (first match wins).
CATEGORIES = (
    ("estimation/raster.py", "rasterize"),
    ("estimation/raster_kernels.py", "rasterize"),
    ("estimation/body_model/biometrics.py", "biometrics"),
    ("estimation/body_model/geometry.py", "biometrics"),
    ("estimation/body_model/", "pose"),
    ("estimation/projection.py", "rasterize"),
    ("estimation/refinement.py", "refinement"),
    ("estimation/contours.py", "refinement"),
    ("estimation/least_squares.py", "refinement"),
    ("estimation/generative.py", "chamfer"),
    ("estimation/likelihood_kernels.py", "chamfer"),
    ("estimation/features.py", "discriminative"),
    ("estimation/rdf.py", "discriminative"),
    ("estimation/shape_context.py", "discriminative"),
    ("estimation/codebook.py", "discriminative"),
    ("estimation/view_features.py", "discriminative"),
    ("estimation/moe.py", "discriminative"),
    ("estimation/training.py", "discriminative"),
    ("calibration/camera.py", "projection"),
    ("estimation/fit.py", "fit (other)"),
)


def _category(filename: str, function: str = "") -> str | None:
    path = filename.replace(os.sep, "/")
    if "estimation/likelihood_kernels.py" in path and function in KERNELS:
        return KERNELS[function]
    for fragment, name in CATEGORIES:
        if fragment in path:
            return name
    return None


def split(stats: pstats.Stats) -> dict[str, float]:
    """Seconds per category: each function's own time; a library function's time
    (numpy, OpenCV, builtins) goes to the categories of the bodymetry code that
    called it, directly or through other library functions, in proportion to the
    time each call path spent in it."""
    raw = stats.stats  # type: ignore[attr-defined]
    memo: dict[tuple, dict[str, float]] = {}

    def owners(func: tuple, seen: frozenset) -> dict[str, float]:
        """Fractions of ``func``'s time per category."""
        if func in memo:
            return memo[func]
        own = _category(func[0], func[2])
        if own is not None:
            return {own: 1.0}
        callers = raw.get(func, (0, 0, 0, 0, {}))[4]
        mix: dict[str, float] = defaultdict(float)
        total = 0.0
        for caller, entry in callers.items():
            if caller in seen:
                continue
            for name, frac in owners(caller, seen | {func}).items():
                mix[name] += entry[2] * frac
            total += entry[2]
        result = {k: v / total for k, v in mix.items()} if total > 0 else {"other": 1.0}
        memo[func] = result
        return result

    out: dict[str, float] = defaultdict(float)
    for func, (_, _, tottime, _, _) in raw.items():
        for name, frac in owners(func, frozenset()).items():
            out[name] += tottime * frac
    return dict(out)


def run() -> dict:
    n_frames = int(os.environ.get("BODYMETRY_PROFILE_FRAMES", "3"))
    config = ProcessConfig()
    session = load_session(DEMO_SESSION)
    resolution = WorkingResolution.choose(session.calibration(), config.working_person_px)
    cameras = resolution.apply(session.calibration())
    models, _ = load_or_train(cameras, config.training, config.cache_dir)
    models_path = cached_models_path(models.key, config.cache_dir)
    shared_body_model()  # loaded outside the profile
    kept = list(segment_session(session, keep_images=False))
    # Spread the frames over the recording (standing, walking, arms raised).
    step = max(1, len(kept) // n_frames)
    frames = kept[::step][:n_frames]
    names = cameras.names
    jobs = [
        FitJob(
            sil.frame,
            resolution.downscale(names, sil.masks),
            [list(f) for f in sil.flags],
            cameras,
            models_path,
            config.fit,
            sil.landmarks,
        )
        for sil in frames
    ]
    # CPU time of this process, for the profile and the total: on a machine shared
    # with other jobs, wall time counts their share of the cores too.
    profiler = cProfile.Profile(time.process_time)
    t0, c0 = time.perf_counter(), time.process_time()
    profiler.enable()
    for job in jobs:
        run_fit_job(job)
    profiler.disable()
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    parts = split(pstats.Stats(profiler))
    per_frame = {
        k: round(v / len(jobs), 2) for k, v in sorted(parts.items(), key=lambda kv: -kv[1])
    }
    return {
        "setup": f"demo, frames {[s.frame for s in frames]}, default preset, one core, "
        "cProfile on, CPU time",
        "seconds_per_frame": round(cpu / len(jobs), 2),
        "wall_seconds_per_frame": round(wall / len(jobs), 2),
        "split_seconds_per_frame": per_frame,
        "split_fraction": {
            k: round(v / max(sum(per_frame.values()), 1e-9), 3) for k, v in per_frame.items()
        },
        "backends": {
            "raster": raster.BACKEND,
            "likelihood": generative.BACKEND,
            "scape_edges": scape.EDGES_BACKEND,
            "scape_solver": scape.SOLVER,
        },
        "note": "cProfile slows every Python call; compare the fractions, not the seconds",
        "models": str(Path(models.path).name),
    }
