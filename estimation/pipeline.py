"""``bodymetry process``: from a session folder to measurements, one frame at a time.

For every kept frame: silhouettes (capture stage) -> discriminative estimate
(per camera mixtures of experts, paper §4) -> generative refinement (annealed
particle filter, §5) -> biometrics of the canonical body of the fitted ν.
Frames run in parallel worker processes; each finished frame is written to
``RUN/frames/FFFFFF.json`` atomically, so a killed run resumes from the
frames it finished. ``results.json`` (schema: docs/outputs.md) summarizes the
run: per frame and per stage the measurements, and mean / std / n per stage
over the frames that succeeded.
"""

from __future__ import annotations

import functools
import json
import logging
import multiprocessing as mp
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from bodymetry.calibration.camera import Camera
from bodymetry.capture.session import Session, load_session
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.biometrics import measure
from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.generative import (
    AnnealingConfig,
    AnnealingResult,
    Observation,
    anneal,
    chamfer_costs,
    prepare_observation,
)
from bodymetry.estimation.projection import project_silhouettes
from bodymetry.estimation.refinement import (
    ContourObservation,
    RefineConfig,
    RefineResult,
    prepare_contours,
    refine,
)
from bodymetry.estimation.training import (
    DiscriminativeModels,
    TrainConfig,
    load_or_train,
    targets_to_theta,
)
from bodymetry.fileio import save_npz, write_json_atomic

log = logging.getLogger(__name__)

#: The three measurements of the paper's Figure 3.
CORE = ("height_mm", "arm_span_mm", "weight_kg")
#: Views with fewer person pixels than this are treated as having no silhouette.
MIN_PIXELS = 400


@dataclass(frozen=True)
class ProcessConfig:
    """What ``bodymetry process`` does.

    Attributes
    ----------
    quality : str
        ``fast``, ``default`` or ``best`` (particles, layers, image scale).
    seed : int
    density : float
        kg/m³ for weight.
    initial_particles : int
        Draws from the discriminative mixtures that start the search.
    min_iou : float
        Quality gate: a frame whose fitted body overlaps the observed
        silhouettes less than this (mean IoU over its views) is marked
        ``"poor fit: ..."`` and left out of the summary; its numbers stay in
        its record. On the demo the fits that found the person's pose score
        0.90-0.96, those stuck in a wrong pose or limb configuration 0.82-0.87
        (their height errors are 11-53 mm, weight errors up to 25 kg).
    """

    quality: str = "default"
    seed: int = 0
    density: float = 1000.0
    initial_particles: int = 400
    min_iou: float = 0.9

    @property
    def annealing(self) -> AnnealingConfig:
        return AnnealingConfig.preset(self.quality)

    @property
    def refinement(self) -> RefineConfig:
        return RefineConfig.preset(self.quality)


def _jsonable_state(state: BodyState) -> dict:
    return {
        "tau": state.tau[0].tolist(),
        "theta": state.theta[0].tolist(),
        "nu": state.nu[0].tolist(),
    }


def _core(bio: dict) -> dict:
    return {k: round(bio[k], 3) for k in bio}


def discriminative_particles(
    models: DiscriminativeModels,
    masks: np.ndarray,
    valid: np.ndarray,
    n: int,
    rng: np.random.Generator,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Initial particles [τ, θ, ν] drawn from every usable camera's mixtures.

    Returns the particles (n, 40 + n_shape) and each camera's point prediction.
    """
    per = max(1, n // max(1, int(np.count_nonzero(valid))))
    particles, points = [], []
    for c, name in enumerate(models.camera_names):
        if not valid[c]:
            continue
        x_rdf, x_sc = models.features(name, masks[c], rng)
        m = models.models[name]
        nu = m["nu_rdf"].sample(x_rdf, per, rng)
        theta = targets_to_theta(m["theta_sc"].sample(x_sc, per, rng))
        tau = m["tau_rdf"].sample(x_rdf, per, rng)
        particles.append(np.hstack([tau, theta, nu]))
        point = np.hstack(
            [
                m["tau_rdf"].predict(x_rdf[None])[0],
                targets_to_theta(m["theta_sc"].predict(x_sc[None], mode="gate"))[0],
                m["nu_rdf"].predict(x_rdf[None])[0],
            ]
        )
        points.append(point)
    return np.vstack(particles), points


def fit_frame(
    frame: int,
    masks: np.ndarray,
    flags: list[list[str]],
    cameras: list[Camera],
    models: DiscriminativeModels,
    config: ProcessConfig,
    out: Path | None = None,
) -> dict:
    """Fit one frame; returns its record for ``results.json`` (never raises for bad data).

    With ``out`` (the run folder), a fitted frame also writes
    ``out/meshes/FFFFFF.ply`` (the fitted full-resolution body) and
    ``out/frames/FFFFFF.npz`` (the last annealing layer's particles and weights,
    for review), both atomically and before the caller writes the record.
    """
    t0 = time.perf_counter()
    body = shared_body_model()
    rng = np.random.default_rng([config.seed, frame])
    valid = np.array(
        [m.sum() >= MIN_PIXELS and "unreadable" not in f for m, f in zip(masks, flags, strict=True)]
    )
    record: dict = {
        "frame": int(frame),
        "flags": {c.name: list(f) for c, f in zip(cameras, flags, strict=True)},
    }
    if valid.sum() == 0:
        record["status"] = "no silhouette in any camera"
        return record
    try:
        particles, points = discriminative_particles(
            models, masks, valid, config.initial_particles, rng
        )
        particles[:, 3:40] = body.limits.clip(particles[:, 3:40])
        points = [np.r_[p[:3], body.limits.clip(p[3:40]), p[40:]] for p in points]
        observed = np.where(valid[:, None, None], masks, False)
        obs = prepare_observation(cameras, observed, config.annealing.image_scale)
        faces = body.faces(lod=True)
        # Discriminative estimate: the camera prediction that explains all views best.
        costs = [
            chamfer_costs(
                obs, body.pose(BodyState.from_vector(p[None]), lod=True).vertices[0], faces
            ).sum()
            for p in points
        ]
        disc_state = BodyState.from_vector(points[int(np.argmin(costs))][None])
        t_disc = time.perf_counter() - t0
        fit = generative_fit(
            body,
            cameras,
            observed,
            particles,
            config,
            rng,
            {
                f"discriminative {cameras[c].name}": p
                for c, p in zip(np.flatnonzero(valid), points, strict=True)
            },
            obs,
        )
        result, refined, chosen = fit.annealing, fit.refined, fit.start
        t_gen = time.perf_counter() - t0 - t_disc
    except (ValueError, np.linalg.LinAlgError) as exc:
        record["status"] = f"fit failed: {exc}"
        return record
    if not np.all(np.isfinite(refined.vector)) or not np.isfinite(result.best_cost):
        record["status"] = "likelihood collapse (non-finite estimate)"
        return record
    state = refined.state
    bios = measure(body, np.vstack([disc_state.nu, state.nu]), density=config.density)
    fitted = body.pose(state, lod=True).vertices[0]
    model_masks = project_silhouettes(fitted, faces, cameras)
    iou = {}
    for c, cam in enumerate(cameras):
        if valid[c]:
            inter = np.logical_and(model_masks[c], masks[c]).sum()
            iou[cam.name] = round(
                float(inter / max(np.logical_or(model_masks[c], masks[c]).sum(), 1)), 4
            )
    if out is not None:
        _write_frame_artifacts(out, frame, body, state, result)
    mean_iou = float(np.mean(list(iou.values())))
    status = (
        "ok"
        if mean_iou >= config.min_iou
        else f"poor fit: mean silhouette IoU {mean_iou:.2f} < {config.min_iou:.2f}"
    )
    record.update(
        {
            "status": status,
            "discriminative": {**_core(bios[0].to_dict()), "state": _jsonable_state(disc_state)},
            "generative": {**_core(bios[1].to_dict()), "state": _jsonable_state(state)},
            "silhouette_iou": iou,
            "annealing": {
                "layer_log_likelihood": result.layer_log_likelihood.round(4).tolist(),
                "layer_beta": result.layer_beta.round(6).tolist(),
                "particle_std": {
                    "tau_m": result.particles[:, :3].std(axis=0).round(4).tolist(),
                    "nu": result.particles[:, 40:].std(axis=0).round(4).tolist(),
                },
            },
            "refinement": {
                "start": chosen,
                "initial_cost_px2": round(refined.initial_cost, 4),
                "cost_px2": round(refined.cost, 4),
                "iterations": refined.iterations,
            },
            "seconds": {
                "discriminative": round(t_disc, 2),
                "annealing": round(fit.seconds[0], 2),
                "refinement": round(fit.seconds[1], 2),
                "generative": round(t_gen, 2),
                "total": round(time.perf_counter() - t0, 2),
            },
        }
    )
    return record


@dataclass(frozen=True)
class GenerativeFit:
    """The generative stage's outcome for one frame.

    Attributes
    ----------
    annealing : AnnealingResult
        The annealed particle filter (paper §5).
    refined : RefineResult
        The contour refinement of the best start (the estimate).
    start : str
        Which start the refinement came from.
    seconds : (float, float)
        Time spent annealing and refining.
    """

    annealing: AnnealingResult
    refined: RefineResult
    start: str
    seconds: tuple[float, float]


def generative_fit(
    body: BodyModel,
    cameras: list[Camera],
    masks: np.ndarray,
    initial: np.ndarray,
    config: ProcessConfig,
    rng: np.random.Generator,
    extra_starts: dict[str, np.ndarray] | None = None,
    obs: Observation | None = None,
) -> GenerativeFit:
    """Annealed search from initial particles, then contour refinement.

    Parameters
    ----------
    body : BodyModel
    cameras : list of Camera
    masks : (C, H, W) bool
        Observed silhouettes; all-False views are left out.
    initial : (N0, 40 + n_shape) float
        Initial particles.
    config : ProcessConfig
    rng : Generator
    extra_starts : name -> (40 + n_shape,) float, optional
        More starts for the refinement (e.g. each camera's discriminative
        prediction), besides the annealing's weighted mean and best particle.
    obs : Observation, optional
        The prepared observation, if the caller has it already.
    """
    t0 = time.perf_counter()
    obs = obs or prepare_observation(cameras, masks, config.annealing.image_scale)
    result = anneal(body, obs, initial, config.annealing, rng)
    t1 = time.perf_counter()
    contours = prepare_contours(
        cameras, masks, config.refinement.image_scale, config.refinement.max_points
    )
    starts = {
        "annealing mean": result.state.vector()[0],
        "best particle": result.particles[int(np.argmax(result.weights))],
        **(extra_starts or {}),
    }
    refined, chosen = polish(body, contours, starts, config.refinement)
    return GenerativeFit(result, refined, chosen, (t1 - t0, time.perf_counter() - t1))


def polish(
    body: BodyModel,
    contours: ContourObservation,
    candidates: dict[str, np.ndarray],
    config: RefineConfig,
) -> tuple[RefineResult, str]:
    """Refine several starting states briefly, then the most promising one fully.

    Parameters
    ----------
    body : BodyModel
    contours : ContourObservation
    candidates : name -> (40 + n_shape,) float
        E.g. the annealing estimate, its best particle, each camera's
        discriminative prediction (modes the annealing may have missed).
    config : RefineConfig

    Returns
    -------
    RefineResult
        The refined state (its ``initial_cost`` is the chosen start's).
    str
        The name of the candidate it started from.
    """
    # Screening is on the level of detail with a working-resolution raster (cheap);
    # the chosen start gets the full config.
    screen = replace(
        config,
        iterations=config.screen_iterations,
        full_mesh=False,
        visibility_scale=config.image_scale,
    )
    trials = {name: refine(body, contours, y, screen) for name, y in candidates.items()}
    name = min(trials, key=lambda k: trials[k].cost)
    first = trials[name]
    rest = refine(
        body,
        contours,
        first.vector,
        replace(config, iterations=config.iterations - first.iterations),
    )
    return replace(
        rest, initial_cost=first.initial_cost, iterations=first.iterations + rest.iterations
    ), name


def _write_frame_artifacts(
    out: Path, frame: int, body: BodyModel, state: BodyState, result
) -> None:
    from bodymetry.review.meshes import write_mesh

    full = body.pose(state).vertices[0]
    write_mesh(out / "meshes" / f"{frame:06d}.ply", full, body.faces(), body.full.arrays.parts)
    save_npz(
        out / "frames" / f"{frame:06d}.npz",
        {
            "particles": result.particles.astype(np.float32),
            "weights": result.weights.astype(np.float32),
            "state": state.vector()[0],
        },
    )


def summarize(records: list[dict]) -> dict:
    """Mean, std and n per stage and measurement over the frames that succeeded."""
    ok = [r for r in records if r.get("status") == "ok"]
    out = {}
    for stage in ("discriminative", "generative"):
        out[stage] = {}
        for key in ok[0][stage] if ok else CORE:
            if key == "state":
                continue
            values = np.array([r[stage][key] for r in ok], float)
            out[stage][key] = {
                "mean": float(values.mean()) if len(values) else None,
                "std": float(values.std(ddof=1))
                if len(values) > 1
                else 0.0
                if len(values)
                else None,
                "n": len(values),
            }
    return out


@functools.lru_cache(maxsize=1)
def shared_body_model() -> BodyModel:
    """The body model, loaded once per process (workers fit many frames)."""
    return BodyModel.load()


@functools.lru_cache(maxsize=2)
def _discriminative(path: Path) -> DiscriminativeModels:
    return DiscriminativeModels.load(path)


def _fit_worker(args) -> dict:
    frame, masks, flags, cameras, models_path, config, out = args
    return fit_frame(frame, masks, flags, cameras, _discriminative(models_path), config, out)


def process_session(
    session_path: str | Path,
    out: str | Path,
    config: ProcessConfig | None = None,
    workers: int | None = None,
    cache_dir: Path | None = None,
    progress: Callable[[str, int, int], None] | None = None,
    train_config: TrainConfig | None = None,
    review: bool = True,
    pdf: bool = False,
) -> dict:
    """Run the whole pipeline on a session; writes ``out/results.json`` and returns it.

    ``train_config`` sets the discriminative training (default: the paper's 3000
    examples); frames already in ``out/frames/`` are not fitted again. With
    ``review`` the review outputs follow (``recording.rrd``, ``recording.mcap``,
    ``report.html``, ``measurements.csv``; ``report.pdf`` with ``pdf``; see
    docs/review.md); they are built after ``results.json`` is written and a
    failure there is logged, never raised.
    """
    from bodymetry.capture.silhouette import segment_session

    config = config or ProcessConfig()
    AnnealingConfig.preset(config.quality)  # an unknown preset fails before any work
    session: Session = load_session(session_path)
    out = Path(out)
    frames_dir = out / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    cameras = _session_cameras(session, out, progress)
    models, reused = load_or_train(
        cameras,
        train_config or TrainConfig(),
        cache_dir,
        workers=workers,
        progress=(lambda label, d, t: progress(f"training: {label}", d, t)) if progress else None,
    )
    t_train = time.perf_counter() - t0
    models_path = _models_file(models, cache_dir)

    done = {int(p.stem): json.loads(p.read_text()) for p in frames_dir.glob("*.json")}
    pending = []
    t1 = time.perf_counter()
    n_kept = 0
    for sil in segment_session(session, keep_images=False):
        n_kept += 1
        if sil.frame in done:
            continue
        pending.append(
            (
                sil.frame,
                sil.stack(),
                [list(f) for f in sil.flags],
                cameras,
                models_path,
                config,
                out,
            )
        )
    t_sil = time.perf_counter() - t1
    if progress:
        progress("frames", len(done), n_kept)
    workers = max(1, workers or mp.cpu_count() or 1)
    t2 = time.perf_counter()
    ctx = mp.get_context("fork")
    with ProcessPoolExecutor(workers, mp_context=ctx) as pool:
        futures = [pool.submit(_fit_worker, job) for job in pending]
        for fut in as_completed(futures):
            record = fut.result()
            write_json_atomic(frames_dir / f"{record['frame']:06d}.json", record)
            done[record["frame"]] = record
            if progress:
                progress("frames", len(done), n_kept)
    records = [done[f] for f in sorted(done)]
    results = {
        "session": {
            "path": str(Path(session_path).resolve()),
            "name": session.name,
            "cameras": list(session.camera_names),
            "fps": session.fps,
            "frame_step": session.frame_step,
        },
        "config": {
            **asdict(config),
            "annealing": asdict(config.annealing),
            "refinement": asdict(config.refinement),
            "models": models.key,
            "models_reused": reused,
        },
        "frames": records,
        "summary": summarize(records),
        "timing_seconds": {
            "training": round(t_train, 1),
            "silhouettes": round(t_sil, 1),
            "fitting": round(time.perf_counter() - t2, 1),
            "total": round(time.perf_counter() - t0, 1),
        },
    }
    truth = _ground_truth(session)
    if truth is not None:
        results["ground_truth"] = truth
    write_json_atomic(out / "results.json", results)
    if review:
        _build_review(out, pdf, progress)
    return results


def _build_review(out: Path, pdf: bool, progress: Callable[[str, int, int], None] | None) -> None:
    """The review stage (review.build); the results are already safe on disk."""
    from bodymetry.review.build import build_review

    try:
        build_review(out, pdf=pdf, progress=progress)
    except Exception:  # results.json is written; the review is extra
        log.exception("%s: building the review outputs failed", out)


def _session_cameras(
    session: Session, out: Path, progress: Callable[[str, int, int], None] | None = None
) -> list[Camera]:
    """The session's cameras: its calibration file, or solved from its ChArUco clips.

    A solved calibration is written to ``out/calibration.yaml`` (with its report)
    and reused when the run resumes; the session folder is not modified.
    """
    if session.calibration_path is not None and session.calibration_path.is_file():
        return list(session.calibration())
    solved = out / "calibration.yaml"
    if solved.is_file():
        from bodymetry.calibration.io import load_calibration

        return list(load_calibration(solved).subset(session.camera_names))
    if session.calibration_clips and session.board is not None:
        from bodymetry.calibration.session_calibration import calibrate_session, write_calibration

        log.info("%s: no calibration.yaml; solving it from the ChArUco clips", session.folder)
        result, _ = calibrate_session(
            session,
            on_progress=(lambda label, d, t: progress(f"calibration: {label}", d, t))
            if progress
            else None,
        )
        write_calibration(result, solved)
        return list(result.cameras.subset(session.camera_names))
    raise InputError(
        f"{session.folder}: no calibration.yaml and no ChArUco clips to solve one from "
        "(see docs/session-format.md)"
    )


def _models_file(models: DiscriminativeModels, cache_dir: Path | None) -> Path:
    from bodymetry.estimation.training import default_cache_dir

    return (cache_dir or default_cache_dir()) / "discriminative" / f"{models.key}.npz"


def _ground_truth(session: Session) -> dict | None:
    gt = session.ground_truth_path
    if gt is None or not (gt / "subject.json").is_file():
        return None
    return json.loads((gt / "subject.json").read_text())
