"""Per-rig training of the discriminative models (paper §4 and §6).

For a camera rig, render a synthetic training set like the paper's: bodies with
poses from the motion prior and shapes from the calibrated shape prior, placed
in the capture volume, their silhouettes projected through the rig's calibrated
cameras (each at its own image size: a rig may mix camera models). From each
view's silhouette, learn per camera the mixtures of experts
p(ν | X_rdf), p(θ | X_sc), p(τ | X_rdf) and, for the uncalibrated mode,
p(ν | X_sc); choose M and λ on held-out data; evaluate on a separate test set.
Models are cached by a hash of the rig, the body model and the settings.

θ is learned with the heading (root rotation about the vertical) replaced by
its cosine and sine, which do not jump at ±π.
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import multiprocessing as mp
import os
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from bodymetry.calibration.camera import CameraGroup
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.model import (
    ANCHOR_CLEARANCE,
    ANCHOR_WEIGHT,
    DEFAULT_MODEL_PATH,
    DEFAULT_SHAPE_DOFS,
    BodyModel,
    BodyState,
    shipped_model,
)
from bodymetry.estimation.body_model.motion.contact import place_root
from bodymetry.estimation.body_model.motion.prior import sample_pose_prior
from bodymetry.estimation.body_model.motion.seeds import seed_for
from bodymetry.estimation.body_model.skeleton import JOINTS, YAW, forward_kinematics
from bodymetry.estimation.codebook import Codebook, fit_codebook
from bodymetry.estimation.moe import MixtureOfExperts, fit_moe, select_moe
from bodymetry.estimation.projection import project_silhouettes
from bodymetry.estimation.rdf import rdf
from bodymetry.estimation.shape_context import ShapeContextConfig
from bodymetry.estimation.view_features import sc_features, silhouette_features
from bodymetry.fileio import load_npz, save_npz
from bodymetry.log import Progress

log = logging.getLogger(__name__)

#: Bumped when training changes so that cached models are rebuilt.
#: 3: the codebook's k-means runs Lloyd to convergence (it stopped after one step).
TRAINING_VERSION = 3
MODEL_NAMES = ("nu_rdf", "theta_sc", "tau_rdf", "nu_sc")
#: The test-set figures ``bodymetry train`` prints (keys of ``DiscriminativeModels.metrics``).
HEADLINE_METRICS = (
    "shape_rdf_improvement_over_mean",
    "shape_sc_improvement_over_mean",
    "pose_mean_angle_error_deg",
    "position_error_mm",
    "mpjpe_mm",
    "train_seconds",
)
#: N = 100 directions + the centroid (paper §3).
RDF_DIM = 102


def default_cache_dir() -> Path:
    """``$BODYMETRY_CACHE`` or ``~/.cache/bodymetry``."""
    env = os.environ.get("BODYMETRY_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "bodymetry"


def cached_models_path(key: str, cache_dir: Path | None = None) -> Path:
    """Where :func:`load_or_train` keeps the models of a rig key."""
    return (cache_dir or default_cache_dir()) / "discriminative" / f"{key}.npz"


@dataclass(frozen=True)
class TrainConfig:
    """Training-set and model-selection settings.

    Attributes
    ----------
    n_train, n_test : int
        Synthetic examples (paper: 3000 and 597); every example gives one
        silhouette per camera.
    seed : int
        Seeds the draws (training and test draws use disjoint seeds).
    volume : float
        Half-width of the square floor area the root is placed in, metres.
    codebook_size : int
        K of the shape-context codebook (paper: 100).
    codebook_examples : int
        Training examples whose descriptors build the codebook.
    codebook_samples : int
        Descriptors per scale (a random subset of the codebook examples') that
        k-means clusters. Measured on the demo rig's 320,000 descriptors: 30,000
        samples and 30 Lloyd iterations quantize held-out descriptors 11 % better
        (mean squared distance to the nearest centre) than the single iteration
        on 100,000 that k-means used to stop at, in about the same time (1.0 s
        against 1.1 s a scale); 50,000 samples gain 0.7 % more in 2x the time.
    codebook_iterations : int
        Lloyd iterations at most (the relative inertia decrease is still above
        1e-4 at 30, but each iteration costs as much as the seeding).
    sc_points : int
        Contour points sampled per silhouette for shape contexts.
    experts, ridges : tuples
        Candidates for M and λ (chosen on a validation split of the training set).
    val_fraction : float
        Share of the training set held out for choosing M and λ.
    max_iter : int
        EM iterations per fit.
    stop_when_worse : bool
        End the search over M (in increasing order) at the first M whose best
        held-out likelihood is below the previous M's
        (:func:`bodymetry.estimation.moe.select_moe`).
    """

    n_train: int = 3000
    n_test: int = 597
    seed: int = 0
    volume: float = 1.0
    codebook_size: int = 100
    codebook_examples: int = 400
    codebook_samples: int = 30_000
    codebook_iterations: int = 30
    sc_points: int = 200
    experts: tuple[int, ...] = (1, 2, 4, 8)
    ridges: tuple[float, ...] = (1.0, 10.0, 100.0)
    val_fraction: float = 0.2
    max_iter: int = 30
    stop_when_worse: bool = True

    def __post_init__(self) -> None:
        if self.n_train < 50 or self.n_test < 1:
            raise InputError(
                f"training: need n_train >= 50 and n_test >= 1, got {self.n_train}, {self.n_test}"
            )
        if not 0 < self.val_fraction < 0.5:
            raise InputError(f"training: val_fraction must be in (0, 0.5), got {self.val_fraction}")


@functools.lru_cache(maxsize=4)
def _file_digest(path: str, size: int, mtime_ns: int) -> bytes:
    # Keyed by size and modification time: a rebaked model file is hashed again.
    return hashlib.sha256(Path(path).read_bytes()).digest()


def rig_key(
    cameras: CameraGroup, config: TrainConfig, model_path: Path = DEFAULT_MODEL_PATH
) -> str:
    """Hash of everything a trained model depends on (hex, 16 characters)."""
    h = hashlib.sha256()
    h.update(f"v{TRAINING_VERSION}".encode())
    h.update(json.dumps(asdict(config), sort_keys=True).encode())
    # How bodies are posed from the file (the skeleton anchors) shapes every
    # training silhouette as much as the file itself.
    h.update(f"anchors {ANCHOR_WEIGHT!r} {ANCHOR_CLEARANCE!r}".encode())
    # ... and so does the number of shape components the models predict (a cache of
    # another count fails every frame: its ν has the wrong length).
    h.update(f"shape dofs {DEFAULT_SHAPE_DOFS}".encode())
    # The body model file (12 MB) is hashed once per process, not per call (batch
    # computes the key of every session).
    stat = Path(model_path).stat()
    h.update(_file_digest(str(Path(model_path).resolve()), stat.st_size, stat.st_mtime_ns))
    for cam in cameras:
        h.update(cam.name.encode())
        h.update(np.asarray(cam.size, np.int64).tobytes())
        for arr in (cam.K, cam.dist, cam.R, cam.t):
            h.update(np.round(np.asarray(arr, float), 9).tobytes())
    return h.hexdigest()[:16]


def theta_to_targets(theta: np.ndarray) -> np.ndarray:
    """(N, 37) -> (N, 38): the heading replaced by its cosine and sine."""
    yaw = theta[:, YAW]
    return np.concatenate(
        [np.delete(theta, YAW, axis=1), np.cos(yaw)[:, None], np.sin(yaw)[:, None]], 1
    )


def targets_to_theta(y: np.ndarray) -> np.ndarray:
    """Inverse of :func:`theta_to_targets`, (N, 38) -> (N, 37)."""
    yaw = np.arctan2(y[:, -1], y[:, -2])
    return np.insert(y[:, :-2], YAW, yaw, axis=1)


def sample_states(model: BodyModel, n: int, purpose: str, seed: int, volume: float) -> BodyState:
    """Training or test states: prior poses and shapes, feet on the floor.

    Shapes: training draws jitter the prior's training bodies (σ = 0.15 per
    component); test draws use its held-out bodies, so no test shape was seen.
    Poses: ``bodymetry.estimation.body_model.motion.prior.sample_pose_prior`` with
    disjoint seeds.
    """
    return _sample_bodies(model, n, purpose, seed, volume)[0]


def _sample_bodies(
    model: BodyModel,
    n: int,
    purpose: str,
    seed: int,
    volume: float,
    pose: Callable[[list[BodyState]], list[np.ndarray]] | None = None,
) -> tuple[BodyState, np.ndarray]:
    """:func:`sample_states` and the states' level-of-detail meshes (n, V, 3).

    Placing the feet on the floor poses every body; the meshes are kept, so
    rendering does not pose them a second time. ``pose`` maps blocks of 64
    states to their LOD vertices (default: ``model.pose`` here, one block after
    another; :func:`_training_bodies` passes a process pool).
    """
    rng = np.random.default_rng(seed_for(purpose, seed))
    bank = model.prior_shapes("train" if purpose == "train" else "heldout")
    nu = bank[rng.integers(len(bank), size=n)]
    if purpose == "train":
        nu = nu + rng.normal(0.0, 0.15, nu.shape)
    theta = sample_pose_prior(rng, n, model.limits)
    tau = place_root(theta)
    tau[:, :2] += rng.uniform(-volume, volume, (n, 2))
    rows = [slice(s, s + 64) for s in range(0, n, 64)]
    blocks = [BodyState(tau[r], theta[r], nu[r]) for r in rows]
    if pose is None:
        meshes = [model.pose(block, lod=True).vertices for block in blocks]
    else:
        meshes = pose(blocks)
    verts = np.concatenate(meshes)
    # Exact floor contact on the LOD mesh: lower each root, and its posed body with it.
    lowest = verts[..., 2].min(axis=1)
    tau[:, 2] -= lowest
    verts[..., 2] -= lowest[:, None]
    return BodyState(tau, theta, nu), verts


def _pose_job(args: tuple[int, BodyState]) -> np.ndarray:
    """Worker: LOD vertices of a block of states (the shipped model, inherited by fork)."""
    n_shape, states = args
    return shipped_model(n_shape).pose(states, lod=True).vertices


@functools.lru_cache(maxsize=2)
def _training_bodies(
    n_shape: int, n: int, purpose: str, seed: int, volume: float, workers: int = 1
) -> tuple[BodyState, np.ndarray]:
    """:func:`_sample_bodies` of the shipped model, once per process.

    The bodies do not depend on the rig (posing 3,597 of them takes several
    seconds of a core), so a process that trains several rigs (``bodymetry
    batch``) draws them once; ``workers`` processes pose them. The meshes are
    read-only.
    """
    model = shipped_model(n_shape)
    pose = None
    if workers > 1:

        def pose(blocks: list[BodyState]) -> list[np.ndarray]:
            with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork")) as pool:
                return list(pool.map(_pose_job, [(n_shape, b) for b in blocks]))

    states, verts = _sample_bodies(model, n, purpose, seed, volume, pose)
    verts.setflags(write=False)
    return states, verts


def _render_features(args) -> tuple:
    """Worker: silhouettes of a chunk of states -> RDF and SC descriptors or codes."""
    states, meshes, cameras, codebook_arrays, seed, sc_config = args
    model = shipped_model(states.nu.shape[1])
    codebook = None if codebook_arrays is None else Codebook.from_arrays(codebook_arrays)
    rng = np.random.default_rng(seed)
    C, B = len(cameras), len(states)
    rdfs = np.zeros((C, B, RDF_DIM))
    codes = None if codebook is None else np.zeros((C, B, codebook.dim))
    valid = np.zeros((C, B), bool)
    descriptors = [] if codebook is None else None
    config = sc_config if codebook is None else codebook.config
    faces = model.faces(lod=True)
    for b in range(B):
        masks = project_silhouettes(meshes[b], faces, cameras)
        for c in range(C):
            if np.count_nonzero(masks[c]) < 50:
                continue  # body (nearly) out of view: no training pair
            valid[c, b] = True
            rdfs[c, b], sc = silhouette_features(masks[c], rng, config)
            if codebook is not None:
                codes[c, b] = codebook.encode(sc)
            else:
                descriptors.append(sc)
    return rdfs, codes, valid, descriptors


def _parallel_features(
    bodies: tuple[BodyState, np.ndarray],
    cameras: CameraGroup,
    codebook,
    seed: int,
    workers: int,
    progress: Callable[[int], None] | None,
    sc_config: ShapeContextConfig | None = None,
):
    """Features of the bodies (states and their LOD meshes) in every camera, in chunks."""
    states, meshes = bodies
    chunk = 128
    jobs = [
        (
            states[s : s + chunk],
            meshes[s : s + chunk],
            cameras,
            None if codebook is None else codebook.to_arrays(),
            seed + s,
            sc_config,
        )
        for s in range(0, max(len(states), 1), chunk)  # no bodies: one empty job
    ]
    results = []
    if workers <= 1 or len(jobs) == 1:
        for job in jobs:
            results.append(_render_features(job))
            if progress:
                progress(len(job[0]))
    else:
        with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork")) as pool:
            for job, res in zip(jobs, pool.map(_render_features, jobs), strict=True):
                results.append(res)
                if progress:
                    progress(len(job[0]))
    rdfs = np.concatenate([r[0] for r in results], axis=1)
    codes = None if codebook is None else np.concatenate([r[1] for r in results], axis=1)
    valid = np.concatenate([r[2] for r in results], axis=1)
    descriptors = [d for r in results for d in (r[3] or [])] if sc_config is not None else None
    return rdfs, codes, valid, descriptors


@dataclass(frozen=True)
class DiscriminativeModels:
    """Trained per-camera mixtures for one rig.

    Attributes
    ----------
    camera_names : tuple of str
    codebook : Codebook
    models : dict
        ``models[camera][name]`` for name in ``MODEL_NAMES``.
    metrics : dict
        Test-set figures (see :func:`evaluate`).
    key : str
        The rig hash.
    """

    camera_names: tuple[str, ...]
    codebook: Codebook
    models: dict[str, dict[str, MixtureOfExperts]]
    metrics: dict = field(default_factory=dict)
    key: str = ""

    def save(self, path: Path) -> None:
        arrays: dict[str, np.ndarray] = {
            "camera_names": np.array(self.camera_names),
            "metrics": np.array(json.dumps(self.metrics)),
            "key": np.array(self.key),
        }
        arrays.update({f"codebook_{k}": v for k, v in self.codebook.to_arrays().items()})
        for cam, models in self.models.items():
            for name, moe in models.items():
                arrays.update(moe.to_arrays(f"{cam}__{name}__"))
        save_npz(path, arrays)

    @classmethod
    def load(cls, path: Path) -> DiscriminativeModels:
        data = load_npz(path)
        names = tuple(str(x) for x in data["camera_names"])
        codebook = Codebook.from_arrays(
            {k.removeprefix("codebook_"): v for k, v in data.items() if k.startswith("codebook_")}
        )
        models = {
            cam: {
                name: MixtureOfExperts.from_arrays(data, f"{cam}__{name}__") for name in MODEL_NAMES
            }
            for cam in names
        }
        return cls(names, codebook, models, json.loads(str(data["metrics"])), str(data["key"]))

    def features(
        self, camera: str, mask: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """(X_rdf, X_sc) of one silhouette seen by ``camera``."""
        return rdf(mask), sc_features(mask, self.codebook, rng)


def _outputs(states: BodyState) -> dict[str, np.ndarray]:
    return {
        "nu_rdf": states.nu,
        "theta_sc": theta_to_targets(states.theta),
        "tau_rdf": states.tau,
        "nu_sc": states.nu,
    }


def _inputs(name: str, rdf: np.ndarray, codes: np.ndarray) -> np.ndarray:
    return rdf if name.endswith("rdf") else codes


def train(
    cameras: CameraGroup,
    config: TrainConfig | None = None,
    workers: int | None = None,
    progress: Progress | None = None,
) -> DiscriminativeModels:
    """Render the training and test sets, fit and evaluate the mixtures."""
    config = config or TrainConfig()
    workers = workers or os.cpu_count() or 1
    t0 = time.perf_counter()
    # Loaded (and factorized) here, once per process and shared with the fit: the
    # render workers forked below inherit it instead of loading it per chunk.
    model = shipped_model(DEFAULT_SHAPE_DOFS)
    train_states, train_meshes = _training_bodies(
        model.n_shape, config.n_train, "train", config.seed, config.volume, workers
    )
    test_states, test_meshes = _training_bodies(
        model.n_shape, config.n_test, "test", config.seed, config.volume, workers
    )
    t_bodies = time.perf_counter() - t0
    n_cb = min(config.codebook_examples, config.n_train)
    t_cb = time.perf_counter()
    codebook, cb_set, t_codebook = _codebook_set(
        (train_states[:n_cb], train_meshes[:n_cb]), n_cb, cameras, config, workers, progress
    )
    t_cb = time.perf_counter() - t_cb - t_codebook
    t_rest = time.perf_counter()
    rest, test = _encoded_sets(
        (train_states[n_cb:], train_meshes[n_cb:]),
        (test_states, test_meshes),
        cameras,
        codebook,
        config,
        workers,
        progress,
    )
    rdf_tr, sc_tr, ok_tr = (np.concatenate(pair, axis=1) for pair in zip(cb_set, rest, strict=True))
    rdf_te, sc_te, ok_te = test
    t_render = time.perf_counter() - t0
    t_silhouettes = t_cb + time.perf_counter() - t_rest
    n_examples = config.n_train + config.n_test
    _log_rendering(n_examples, len(cameras), t_silhouettes, workers, t_bodies, t_codebook)

    t_fit = time.perf_counter()
    chosen, models = _fit_models(
        cameras, rdf_tr, sc_tr, ok_tr, _outputs(train_states), config, workers, progress
    )
    t_fit = time.perf_counter() - t_fit
    log.info("mixtures of experts: %d fitted in %.1f s", len(cameras) * len(MODEL_NAMES), t_fit)
    t_eval = time.perf_counter()
    trained = DiscriminativeModels(cameras.names, codebook, models)
    metrics = evaluate(trained, model, test_states, rdf_te, sc_te, ok_te)
    metrics["chosen"] = {k: {"M": v["n_experts"], "lambda": v["ridge"]} for k, v in chosen.items()}
    metrics["selection"] = {k: v["table"] for k, v in chosen.items()}
    metrics["render_seconds"] = round(t_render, 1)
    metrics["fit_seconds"] = round(t_fit, 1)
    metrics["timing"] = {
        "bodies_seconds": round(t_bodies, 1),
        "silhouettes_features_seconds": round(t_silhouettes, 1),
        "render_examples_per_second": round(n_examples / t_silhouettes, 1),
        "codebook_seconds": round(t_codebook, 1),
        "fit_seconds": round(t_fit, 1),
        "evaluate_seconds": round(time.perf_counter() - t_eval, 1),
        "workers": workers,
    }
    metrics["train_seconds"] = round(time.perf_counter() - t0, 1)
    metrics["n_train"], metrics["n_test"] = config.n_train, config.n_test
    return DiscriminativeModels(
        trained.camera_names, codebook, models, metrics, rig_key(cameras, config)
    )


def _encoded_sets(
    train_rest: tuple[BodyState, np.ndarray],
    test: tuple[BodyState, np.ndarray],
    cameras: CameraGroup,
    codebook: Codebook,
    config: TrainConfig,
    workers: int,
    progress: Progress | None,
) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """The features (RDFs, codebook features, usable flags) of the training
    examples after the codebook's (seed + 1) and of the test set (seed + 2)."""
    n_rest = config.n_train - min(config.codebook_examples, config.n_train)
    rest = _parallel_features(
        train_rest,
        cameras,
        codebook,
        config.seed + 1,
        workers,
        _progress_step(progress, "training set", n_rest),
    )[:3]
    tested = _parallel_features(
        test,
        cameras,
        codebook,
        config.seed + 2,
        workers,
        _progress_step(progress, "test set", config.n_test),
    )[:3]
    return rest, tested


def _log_rendering(
    n_examples: int,
    n_cameras: int,
    seconds: float,
    workers: int,
    t_bodies: float,
    t_codebook: float,
) -> None:
    """Log the training set's rendering rate and the times of its parts."""
    log.info(
        "training set: %d bodies x %d cameras rendered with features in %.1f s "
        "(%.0f examples/s, %d workers); bodies %.1f s, codebook %.1f s",
        n_examples,
        n_cameras,
        seconds,
        n_examples / seconds,
        workers,
        t_bodies,
        t_codebook,
    )


def _progress_step(progress: Progress | None, label: str, total: int) -> Callable[[int], None]:
    """A callback that adds ``k`` examples done to ``label``'s count and reports
    it to ``progress`` (when given) as ``progress(label, done, total)``."""
    done = [0]

    def advance(k: int) -> None:
        done[0] += k
        if progress:
            progress(label, done[0], total)

    return advance


def _codebook_set(
    bodies: tuple[BodyState, np.ndarray],
    n_cb: int,
    cameras: CameraGroup,
    config: TrainConfig,
    workers: int,
    progress: Progress | None,
) -> tuple[Codebook, tuple[np.ndarray, np.ndarray, np.ndarray], float]:
    """The codebook, from the shape contexts of the first ``n_cb`` training examples
    ``bodies`` (all cameras), and those examples' features, encoded from their
    descriptors (not rendered again).

    Returns
    -------
    codebook : Codebook
    features : ((C, n, n_rdf), (C, n, S * K), (C, n) bool)
        The examples' RDFs, codebook features and usable flags.
    seconds : float
        Fitting the codebook and encoding the examples (rendering excluded).
    """
    sc_config = ShapeContextConfig(n_points=config.sc_points)
    rdf_cb, _, ok_cb, descriptors = _parallel_features(
        bodies,
        cameras,
        None,
        config.seed,
        workers,
        _progress_step(progress, "codebook", n_cb),
        sc_config,
    )
    t_codebook = time.perf_counter()
    codebook = fit_codebook(
        descriptors,
        config.codebook_size,
        np.random.default_rng(config.seed),
        config=sc_config,
        max_samples=config.codebook_samples,
        max_iter=config.codebook_iterations,
    )
    sc_cb = np.zeros((len(cameras), n_cb, codebook.dim))
    it = iter(descriptors)
    for b in range(n_cb):
        for c in range(len(cameras)):
            if ok_cb[c, b]:
                sc_cb[c, b] = codebook.encode(next(it))
    return codebook, (rdf_cb, sc_cb, ok_cb), time.perf_counter() - t_codebook


def _select_job(args: tuple) -> dict:
    """Worker: cross-validated M and λ of one model on the first camera's split."""
    X, Y, X_val, Y_val, config = args
    sel = select_moe(
        X,
        Y,
        X_val,
        Y_val,
        config.experts,
        config.ridges,
        seed=config.seed,
        stop_when_worse=config.stop_when_worse,
        max_iter=config.max_iter,
    )
    return {"n_experts": sel.n_experts, "ridge": sel.ridge, "table": sel.table}


def _fit_job(args: tuple) -> MixtureOfExperts:
    """Worker: one camera's model on all its training examples with the chosen M and λ."""
    X, Y, n_experts, ridge, config = args
    rng = np.random.default_rng(config.seed)
    return fit_moe(X, Y, n_experts, ridge, rng, max_iter=config.max_iter).model


def _fit_models(
    cameras: CameraGroup,
    rdf: np.ndarray,
    codes: np.ndarray,
    valid: np.ndarray,
    outputs: dict[str, np.ndarray],
    config: TrainConfig,
    workers: int,
    progress: Progress | None,
) -> tuple[dict[str, dict], dict[str, dict[str, MixtureOfExperts]]]:
    """Choose M and λ per model on the first camera, then fit every camera's models.

    The fits are independent jobs (a model's four camera fits wait for its
    selection only), run on ``workers`` processes, heaviest first (the
    shape-context inputs have 300 dimensions, the RDF ones 102). Every fit is
    seeded by ``config.seed``, so the models do not depend on the scheduling.

    Returns
    -------
    chosen : dict
        Per model name: ``n_experts``, ``ridge`` and the selection ``table``.
    models : dict
        ``models[camera][name]``.
    """
    rng = np.random.default_rng(config.seed)
    splits = []
    for c, cam in enumerate(cameras):
        idx = np.flatnonzero(valid[c])
        if len(idx) < 50:
            raise InputError(
                f"camera {cam.name}: the body is visible in only {len(idx)} training examples"
            )
        perm = rng.permutation(idx)  # drawn for every camera: the same draws as ever
        n_val = int(len(perm) * config.val_fraction)
        splits.append((idx, perm[:n_val], perm[n_val:]))

    def data(name: str, c: int, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _inputs(name, rdf[c], codes[c])[rows], outputs[name][rows]

    _, val, fit_idx = splits[0]
    order = sorted(MODEL_NAMES, key=lambda n: -_inputs(n, rdf[0], codes[0]).shape[1])
    select_args = {name: (*data(name, 0, fit_idx), *data(name, 0, val), config) for name in order}
    chosen: dict[str, dict] = {}
    fitted: dict[tuple[str, int], MixtureOfExperts] = {}

    def fit_args(name: str, c: int) -> tuple:
        X, Y = data(name, c, splits[c][0])
        return X, Y, chosen[name]["n_experts"], chosen[name]["ridge"], config

    def report() -> None:
        if progress:
            progress("fitting", len(fitted), len(cameras) * len(MODEL_NAMES))

    if workers <= 1:
        for name in order:
            chosen[name] = _select_job(select_args[name])
            for c in range(len(cameras)):
                fitted[name, c] = _fit_job(fit_args(name, c))
                report()
    else:
        with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork")) as pool:
            pending = {pool.submit(_select_job, select_args[n]): (n, None) for n in order}
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    name, c = pending.pop(future)
                    if c is None:
                        chosen[name] = future.result()
                        for k in range(len(cameras)):
                            pending[pool.submit(_fit_job, fit_args(name, k))] = (name, k)
                    else:
                        fitted[name, c] = future.result()
                        report()
    chosen = {name: chosen[name] for name in MODEL_NAMES}
    models = {
        cam.name: {name: fitted[name, c] for name in MODEL_NAMES} for c, cam in enumerate(cameras)
    }
    return chosen, models


#: Bodies per block in the test-set evaluation: the full meshes (13,380 vertices) of a
#: block stay in cache (the whole test set at once is memory-bound, 5x slower).
_CHUNK = 32


def _vertex_errors(
    model: BodyModel, nu: np.ndarray, truth: np.ndarray, rows: np.ndarray | None = None
) -> np.ndarray:
    """Mean vertex distance (B,) of the canonical bodies of ``nu`` (B, n) from ``truth``
    (B, V, 3), or from ``truth[rows]`` (taken a chunk at a time: the test set's
    meshes are hundreds of MB, and a copy of them all costs seconds here)."""
    rows = np.arange(len(nu)) if rows is None else rows
    out = np.empty(len(nu))
    for s in range(0, len(nu), _CHUNK):
        d = model.canonical_vertices(nu[s : s + _CHUNK]) - truth[rows[s : s + _CHUNK]]
        out[s : s + _CHUNK] = np.sqrt(np.einsum("bvi,bvi->bv", d, d)).mean(axis=1)
    return out


def _joints(model: BodyModel, states: BodyState) -> np.ndarray:
    """World joint positions (B, 15, 3) of ``model.pose(states).joints``, without the mesh.

    Forward kinematics needs only the rest joints' offsets from their parents,
    which the canonical rest keypoints give (the mesh solve, which ``pose``
    also does, took most of the test-set evaluation's time).
    """
    rest = np.concatenate(
        [
            model.rest_keypoints(states.nu[s : s + _CHUNK])[:, : len(JOINTS)]
            for s in range(0, len(states), _CHUNK)
        ]
    )
    return forward_kinematics(states.theta, states.tau, rest, model.hinge_axes)[1]


def evaluate(
    trained: DiscriminativeModels,
    model: BodyModel,
    states: BodyState,
    rdf: np.ndarray,
    codes: np.ndarray,
    valid: np.ndarray,
) -> dict:
    """Test-set figures, averaged over cameras (each camera's own prediction).

    * ``shape_*_improvement_over_mean``: 1 - (mean vertex error of the predicted
      canonical body) / (that of the mean body), as the paper's "performance
      increase over simply using the mean shape";
    * ``pose_mean_angle_error_deg``: mean absolute joint-angle error (heading wrapped);
    * ``position_error_mm``: root position error;
    * ``mpjpe_mm``: mean per-joint position error of the posed skeleton.
    """
    n_examples = {}
    truth_canon = np.concatenate(
        [model.canonical_vertices(states.nu[s : s + _CHUNK]) for s in range(0, len(states), _CHUNK)]
    )
    err_mean = _vertex_errors(model, np.zeros((len(states), model.n_shape)), truth_canon)
    true_joints = _joints(model, states)
    per_cam = {}
    for c, cam in enumerate(trained.camera_names):
        idx = np.flatnonzero(valid[c])
        m = trained.models[cam]
        out = {}
        for name in ("nu_rdf", "nu_sc"):
            X = _inputs(name, rdf[c, idx], codes[c, idx])
            err = _vertex_errors(model, m[name].predict(X), truth_canon, idx)
            out[f"shape_{name.split('_')[1]}_improvement_over_mean"] = float(
                1 - err.mean() / err_mean[idx].mean()
            )
            out[f"shape_{name.split('_')[1]}_vertex_error_mm"] = float(1000 * err.mean())
        theta = targets_to_theta(m["theta_sc"].predict(codes[c, idx], mode="gate"))
        d = theta - states.theta[idx]
        d[:, YAW] = (d[:, YAW] + np.pi) % (2 * np.pi) - np.pi
        out["pose_mean_angle_error_deg"] = float(np.degrees(np.abs(d).mean()))
        tau = m["tau_rdf"].predict(rdf[c, idx])
        out["position_error_mm"] = float(
            1000 * np.linalg.norm(tau - states.tau[idx], axis=1).mean()
        )
        nu = m["nu_rdf"].predict(rdf[c, idx])
        pred_j = _joints(model, BodyState(tau, theta, nu))
        out["mpjpe_mm"] = float(1000 * np.linalg.norm(pred_j - true_joints[idx], axis=-1).mean())
        per_cam[cam] = out
        n_examples[cam] = len(idx)
    keys = next(iter(per_cam.values())).keys()
    summary = {k: float(np.mean([v[k] for v in per_cam.values()])) for k in keys}
    summary["mean_shape_vertex_error_mm"] = float(1000 * err_mean.mean())
    summary["per_camera"] = per_cam
    summary["test_examples_per_camera"] = n_examples
    return summary


def load_or_train(
    cameras: CameraGroup,
    config: TrainConfig | None = None,
    cache_dir: Path | None = None,
    workers: int | None = None,
    progress: Progress | None = None,
) -> tuple[DiscriminativeModels, bool]:
    """Cached models for this rig, training them first if needed.

    Returns
    -------
    (models, reused) : reused is True when the cache already had them.
    """
    config = config or TrainConfig()
    key = rig_key(cameras, config)
    path = cached_models_path(key, cache_dir)
    if path.exists():
        try:
            return DiscriminativeModels.load(path), True
        except (InputError, ValueError, KeyError) as exc:
            log.warning("cached models %s unreadable (%s); retraining", path, exc)
    models = train(cameras, config, workers=workers, progress=progress)
    models.save(path)
    return models, False
