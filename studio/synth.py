"""``bodymetry synth``: render a complete ground-truth session, as a lab would record it.

A session folder (``docs/session-format.md``) holds, per camera, the recording
(H.264), an empty-scene background clip (unless ``background_clip`` is off, as in
most real recordings) and a ChArUco calibration clip; the true
``calibration.yaml``; and ``ground_truth/`` with the subject's biometrics, the
per-frame state and joints, and the true silhouettes of the kept frames.
Optionally, bystanders (:mod:`bodymetry.studio.bystanders`) stand still in the
room during the recording, each seen by one or two cameras; they are absent from
the background and calibration clips (recorded before they came in) and from the
ground-truth silhouettes, and ``ground_truth/studio.json`` describes them.
With ``--people N`` (:mod:`bodymetry.studio.people`), ``N - 1`` other persons
walk past the subject, crossing it in some cameras; each has its own ground
truth in ``ground_truth/persons/<k>/`` (the subject's stays where it was), and
every person's hidden pixels are written as ``occluded/`` masks.
The subject is a body of our model (a shape ν) or, with
``--subject independent:...``, a body the model was not built from
(:mod:`bodymetry.studio.independent`, skinned, optionally clothed), whose
ground truth has no ν. The session's :class:`~bodymetry.studio.looks.Look`
(``--look``) sets the subject's clothing colours, the room and the light of
every clip; bystanders keep their own clothes in that room and light.

Cameras render in parallel worker processes (one camera per task); every random
draw comes from the configuration's seed, so the same configuration gives the
same session.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import multiprocessing as mp
import queue as queue_module
import shutil
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.calibration.io import save_calibration
from bodymetry.capture.ground_truth import (
    GROUND_TRUTH_OCCLUDED,
    GROUND_TRUTH_SHADOWS,
    GROUND_TRUTH_SILHOUETTES,
    GROUND_TRUTH_STATES,
    StudioRecord,
    SubjectTruth,
    person_folder,
)
from bodymetry.capture.session import BoardSpec, Session, SessionCamera, save_session
from bodymetry.capture.video import H264Writer
from bodymetry.errors import InputError
from bodymetry.estimation.body_model.biometrics import measure
from bodymetry.estimation.body_model.model import ADULT_YEARS, BodyModel, BodyState
from bodymetry.estimation.body_model.motion.library import (
    MOTIONS,
    Motion,
    ground_motion,
    make_motion,
)
from bodymetry.estimation.body_model.motion.rest import RestPoseInfo
from bodymetry.estimation.body_model.motion.seeds import seed_for
from bodymetry.fileio import save_npz, write_bytes_atomic
from bodymetry.studio.board_motion import board_trajectory
from bodymetry.studio.bystanders import (
    MAX_BYSTANDERS,
    BystanderPlacement,
    place_bystanders,
)
from bodymetry.studio.independent import IndependentSpec, IndependentSubject
from bodymetry.studio.looks import Look, recorded_look
from bodymetry.studio.people import MAX_PEOPLE, Person, draw_people
from bodymetry.studio.render import Body, Effects, Studio
from bodymetry.studio.rig import studio_rig
from bodymetry.studio.scene import Appearance, BoardPose, BoardTexture

log = logging.getLogger(__name__)

#: The board of the studio's calibration clips (a 1.0 x 0.8 m ChArUco print with large 4x4-bit
#: markers, like the boards motion-capture labs use for room-sized volumes).
STUDIO_BOARD = BoardSpec(squares=(5, 4), square_mm=200.0, marker_mm=150.0, dictionary="DICT_4X4_50")


@dataclass(frozen=True)
class SubjectSpec:
    """Who is recorded.

    Attributes
    ----------
    nu : (n_shape,) float or None
        Explicit shape; None draws one.
    heldout_index : int or None
        Use body ``heldout_index`` of the calibrated prior's held-out bodies.
    seed : int
        Picks a held-out body when neither ``nu`` nor ``heldout_index`` is given.
    independent : IndependentSpec or None
        A subject whose geometry the body model was not built from
        (:mod:`bodymetry.studio.independent`); it has no ν.
    """

    nu: tuple[float, ...] | None = None
    heldout_index: int | None = None
    seed: int = 0
    independent: IndependentSpec | None = None

    @classmethod
    def parse(cls, text: str | None, default_seed: int) -> SubjectSpec:
        """``None`` | ``"seed:N"`` | ``"heldout:N"`` | ``"nu:v1,v2,..."`` |
        ``"independent:SEED[,body=K|edge=KEY][,clothing=tight|shorts|loose|draped|skirt|dress|long_skirt][,ease=MM][,hair=0|1]"``."""
        if text is None:
            return cls(seed=default_seed)
        kind, _, value = text.partition(":")
        if kind == "independent":
            return cls(independent=IndependentSpec.parse(value))
        try:
            if kind == "seed":
                return cls(seed=int(value))
            if kind == "heldout":
                return cls(heldout_index=int(value))
            if kind == "nu":
                nu = tuple(float(v) for v in value.split(",") if v.strip())
                if not nu or not np.all(np.isfinite(nu)):
                    raise ValueError(value)
                return cls(nu=nu)
        except ValueError as exc:
            raise InputError(f"--subject {text!r}: could not read the value ({exc})") from exc
        raise InputError(
            f"--subject {text!r}: expected seed:N, heldout:N, nu:v1,v2,... or "
            "independent:SEED[,body=K|edge=KEY][,clothing=loose][,hair=1]"
        )

    def resolve(self, model) -> tuple[np.ndarray, dict]:
        """The shape (n_shape,) and a description for ``subject.json``."""
        if self.independent is not None:
            raise InputError(
                f"--subject {self.independent.to_text()}: an independent subject has no shape ν"
            )
        heldout = model.prior_shapes("heldout")
        if self.nu is not None:
            if len(self.nu) > model.n_shape:
                raise InputError(
                    f"--subject nu: {len(self.nu)} values, the model uses {model.n_shape}"
                )
            nu = np.pad(np.asarray(self.nu, float), (0, model.n_shape - len(self.nu)))
            return nu, {"source": "explicit nu"}
        index = self.heldout_index
        if index is None:
            # A seed draws an adult, as the studio always has; children (and any
            # held-out body) are one ``heldout:N`` or ``independent:...,edge=`` away.
            adults = np.flatnonzero(model.prior_ages("heldout") >= ADULT_YEARS)
            rng = np.random.default_rng(seed_for("test", self.seed))
            index = int(adults[rng.integers(len(adults))])
        if not 0 <= index < len(heldout):
            raise InputError(f"--subject heldout:{index}: expected 0..{len(heldout) - 1}")
        return heldout[index], {"source": "calibrated prior, held-out body", "heldout_index": index}


@dataclass(frozen=True)
class SynthConfig:
    """What ``bodymetry synth`` renders.

    Attributes
    ----------
    frames : int
        Frames of the recording.
    fps : float
        Frame rate (the studio's cameras are synchronized; no offsets).
    frame_step : int
        Processing keeps every ``frame_step``-th frame; ground-truth silhouettes
        are written for those.
    cameras : int
        Cameras around the volume.
    size : (int, int)
        Image width and height.
    seed : int
        Seeds the rig (unless ``rig_seed`` is given), the motion, the noise;
        the subject unless given.
    rig_seed : int or None
        Seeds the camera rig alone: sessions of one lab share their rig (and
        so their calibration and trained discriminative models) while subject,
        motion and noise change with ``seed``.
    motion : str
        A name of ``bodymetry.estimation.body_model.motion.library.MOTIONS``.
    subject : SubjectSpec
    shadows : bool
        The key light casts the person's shadow on the floor.
    background_frames, calibration_frames : int
        Lengths of the empty-scene and ChArUco clips.
    crf : int
        H.264 quality (lower = better, bigger).
    background_clip : bool
        Write the empty-scene clips (``background/``); off, the session names none,
        like most real recordings.
    bystanders : int
        People standing still in the room during the recording
        (0..``MAX_BYSTANDERS``), drawn and placed from ``seed``.
    bystander_placement : BystanderPlacement
        Where bystanders may stand.
    look : Look
        The subject's clothing colours, the room and the light
        (:mod:`bodymetry.studio.looks`); the default is the saturated clothes in the
        textured lab under the hard key light.
    people : int
        Persons recorded (1..``MAX_PEOPLE``): the subject and ``people - 1`` others
        walking past it (:mod:`bodymetry.studio.people`), drawn from ``seed``.
    """

    frames: int = 200
    fps: float = 60.0
    frame_step: int = 25
    cameras: int = 4
    size: tuple[int, int] = (640, 480)
    seed: int = 0
    rig_seed: int | None = None
    motion: str = "mixed"
    subject: SubjectSpec = field(default_factory=SubjectSpec)
    shadows: bool = True
    background_frames: int = 30
    calibration_frames: int = 300
    crf: int = 20
    background_clip: bool = True
    bystanders: int = 0
    bystander_placement: BystanderPlacement = field(default_factory=BystanderPlacement)
    look: Look = field(default_factory=Look)
    people: int = 1

    def __post_init__(self) -> None:
        if not isinstance(self.look, Look):
            raise InputError(f"SynthConfig.look: expected a Look, got {type(self.look).__name__}")
        if self.frames < 1:
            raise InputError(f"--frames: expected at least 1, got {self.frames}")
        if not self.fps > 0:
            raise InputError(f"--fps: expected a positive rate, got {self.fps}")
        if self.frame_step < 1:
            raise InputError(f"--frame-step: expected at least 1, got {self.frame_step}")
        if self.cameras < 1:
            raise InputError(f"--cameras: expected at least 1, got {self.cameras}")
        w, h = self.size
        if w < 64 or h < 48 or w % 2 or h % 2:
            raise InputError(f"--size: expected even width >= 64 and height >= 48, got {w}x{h}")
        if self.motion not in MOTIONS:
            raise InputError(
                f"--motion {self.motion!r}: expected one of {', '.join(sorted(MOTIONS))}"
            )
        if (self.background_clip and self.background_frames < 1) or self.calibration_frames < 30:
            raise InputError("background clips need >= 1 frame and calibration clips >= 30 frames")
        if not 0 <= self.bystanders <= MAX_BYSTANDERS:
            raise InputError(f"--bystanders: expected 0..{MAX_BYSTANDERS}, got {self.bystanders}")
        if isinstance(self.people, bool) or not 1 <= self.people <= MAX_PEOPLE:
            raise InputError(f"--people: expected 1..{MAX_PEOPLE}, got {self.people}")


def _png(mask: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", mask.astype(np.uint8) * 255)
    if not ok:  # pragma: no cover - OpenCV failure
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


@dataclass(frozen=True)
class _PersonTrack:
    """What a camera job renders of a person besides the subject.

    Attributes
    ----------
    index : int
        1.. (its ``ground_truth/persons/<index>/``).
    spec : IndependentSpec
    tau : (F, 3) float
    theta : (F, 37) float
    appearance : Appearance
    """

    index: int
    spec: IndependentSpec
    tau: np.ndarray
    theta: np.ndarray
    appearance: Appearance

    @classmethod
    def of(cls, person: Person) -> _PersonTrack:
        m = person.motion
        return cls(person.index, person.spec, m.tau, m.theta, person.appearance())


@dataclass(frozen=True)
class _CameraJob:
    index: int
    camera: Camera
    config: SynthConfig
    out: Path
    tau: np.ndarray
    theta: np.ndarray
    nu: np.ndarray | None
    board_poses: np.ndarray
    bystanders: tuple[Body, ...] = ()
    independent: IndependentSpec | None = None
    people: tuple[_PersonTrack, ...] = ()

    def pose(self, model: BodyModel, subject: IndependentSubject | None, frames: slice):
        """Rendered vertices (B, V, 3) of the subject at ``frames``."""
        if subject is not None:
            return subject.pose(self.tau[frames], self.theta[frames])[0]
        return model.pose(BodyState(self.tau[frames], self.theta[frames], self.nu[None])).vertices


def _scene(
    studio: Studio, job: _CameraJob, vertices: np.ndarray, people: list[Body], rng
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """One recording frame of the job's camera.

    Returns
    -------
    image : (H, W, 3) uint8
    shadow : (H, W) bool
    masks : (P, H, W) bool
        Every person's visible pixels, the subject first.
    occluded, full : (P, H, W) bool or None
        Every person's hidden pixels and whole projection (None for one person).
    """
    if not people:
        image, person, shadow = studio.render_frame(
            job.camera, vertices, rng, others=job.bystanders
        )
        return image, shadow, person[None], None, None
    out = studio.render_people(job.camera, vertices, rng, people=people, others=job.bystanders)
    return out.image, out.shadow_mask, out.masks, out.occluded, out.full


def _write_masks(
    folders: list[Path], kind: str, camera: str, frame: int, masks: np.ndarray
) -> None:
    """Write each person's mask (P, H, W) as ``<folder>/<kind>/<camera>/<frame>.png``."""
    for folder, mask in zip(folders, masks, strict=True):
        write_bytes_atomic(folder / kind / camera / f"{frame:06d}.png", _png(mask))


def _render_camera(job: _CameraJob, progress) -> dict:
    """Render one camera's recording (with the bystanders), background and calibration
    clips and masks."""
    cfg, cam = job.config, job.camera
    if job.independent is not None:
        model = BodyModel.load()
        subject = IndependentSubject(job.independent, model=model)
    else:
        model = BodyModel.load(n_shape=len(job.nu))
        subject = None
    base = subject.appearance() if subject is not None else Appearance()
    studio = Studio.from_model(
        model,
        appearance=cfg.look.appearance(base),
        shadows=cfg.shadows,
        effects=Effects(seed=cfg.seed),
        room=cfg.look.build_room(),
        light=cfg.look.build_light(),
    )
    rng = np.random.default_rng([cfg.seed, job.index, 1])
    shadow_fraction = []
    occluded = np.zeros(1 + len(job.people))  # hidden over whole-projection pixels, summed
    whole = np.zeros(1 + len(job.people))
    kept = set(range(0, cfg.frames, cfg.frame_step))
    gt = job.out / "ground_truth"
    folders = [gt] + [person_folder(gt, p.index) for p in job.people]
    walkers = [IndependentSubject(p.spec, model=model) for p in job.people]
    with H264Writer(job.out / "videos" / f"{cam.name}.mp4", cfg.fps, cfg.size, cfg.crf) as writer:
        for start in range(0, cfg.frames, 16):
            stop = min(cfg.frames, start + 16)
            verts = job.pose(model, subject, slice(start, stop))
            others = [
                w.pose(p.tau[start:stop], p.theta[start:stop])[0]
                for w, p in zip(walkers, job.people, strict=True)
            ]
            for k, frame in enumerate(range(start, stop)):
                people = [Body(v[k], p.appearance) for v, p in zip(others, job.people, strict=True)]
                image, shadow, masks, hidden, full = _scene(studio, job, verts[k], people, rng)
                writer.write(image)
                if frame in kept:
                    _write_masks(folders, GROUND_TRUTH_SILHOUETTES, cam.name, frame, masks)
                    # Stored, not re-rendered when scored: a later body model would move them.
                    _write_masks([gt], GROUND_TRUTH_SHADOWS, cam.name, frame, shadow[None])
                    if hidden is not None:
                        _write_masks(folders, GROUND_TRUTH_OCCLUDED, cam.name, frame, hidden)
                        occluded += hidden.sum(axis=(1, 2))
                        whole += full.sum(axis=(1, 2))
                    if masks[0].any():
                        shadow_fraction.append(float(shadow.sum() / masks[0].sum()))
                progress.put(1)
    if cfg.background_clip:
        with H264Writer(
            job.out / "background" / f"{cam.name}.mp4", cfg.fps, cfg.size, cfg.crf
        ) as writer:
            for _ in range(cfg.background_frames):
                writer.write(studio.render_background(cam, rng))
                progress.put(1)
    board = STUDIO_BOARD.create_board()
    texture = BoardTexture.from_charuco(board)
    with H264Writer(
        job.out / "calibration" / f"{cam.name}.mp4", cfg.fps, cfg.size, cfg.crf
    ) as writer:
        for T in job.board_poses:
            frame = studio.render_board(cam, texture, BoardPose(T[:3, :3], T[:3, 3]), rng)
            writer.write(frame.image)
            progress.put(1)
    return {
        "camera": cam.name,
        "shadow_to_person_area": shadow_fraction,
        "occluded_fraction": (occluded / np.maximum(whole, 1)).tolist(),
    }


def synthesize(
    out: str | Path,
    config: SynthConfig,
    workers: int | None = None,
    on_progress: Callable[[int, int], None] | None = None,
    overwrite: bool = False,
) -> Session:
    """Render a session folder.

    Parameters
    ----------
    out : path
        Session folder to create (must be empty or absent unless ``overwrite``).
    config : SynthConfig
    workers : int, optional
        Worker processes (default: one per core, at most one per camera).
    on_progress : callable(done, total), optional
        Called as frames finish (for progress bars).
    overwrite : bool
        Replace an existing folder.

    Returns
    -------
    Session
        The session as written (loadable with ``capture.session.load_session``).
    """
    out = Path(out)
    _empty_folder(out, overwrite)
    t0 = time.perf_counter()
    model = BodyModel.load()
    subject = _SubjectMotion.draw(model, config)
    rig_seed = config.seed if config.rig_seed is None else config.rig_seed
    cameras = studio_rig(config.cameras, config.size, seed=rig_seed)
    board_poses = board_trajectory(
        config.calibration_frames,
        config.fps,
        np.random.default_rng([config.seed, 99]),
        STUDIO_BOARD,
        cameras,
    )

    # Ground truth that does not need rendering.
    bio, joints, sparse_vertices = subject.truth(model, config.frames)
    people, truths, subject, joints, sparse_vertices = _draw_people(
        model, cameras, config, subject, joints, sparse_vertices
    )
    bystanders = place_bystanders(
        model,
        cameras,
        sparse_vertices,
        config.bystanders,
        config.seed,
        exclude_heldout=tuple(
            [subject.info["heldout_index"]] if "heldout_index" in subject.info else []
        ),
        placement=config.bystander_placement,
        room=config.look.build_room(),
    )
    del sparse_vertices
    _write_ground_truth(out, config, subject, joints, board_poses, bio)
    for person, (person_bio, person_joints, _) in zip(people, truths, strict=True):
        _write_person_truth(out, config, person, person_bio, person_joints)
    _write_true_calibration(out, cameras)

    # The look dresses the subject (_render_camera); bystanders wear their own clothes.
    independent = config.subject.independent
    others = tuple(Body(b.vertices(model), b.appearance(Appearance())) for b in bystanders)
    tracks = tuple(_PersonTrack.of(p) for p in people)
    jobs = [
        _CameraJob(
            i, cam, config, out, *subject.rendered(), board_poses, others, independent, tracks
        )
        for i, cam in enumerate(cameras)
    ]
    results = _render_cameras(jobs, workers, _frame_total(config), on_progress)
    session = _session_record(out, config, cameras)
    save_session(session, out)
    _write_studio_record(out, config, subject, bystanders, results, t0, people)
    log.info("rendered %s in %.1f s", out, time.perf_counter() - t0)
    return session


def _draw_people(
    model: BodyModel,
    cameras: CameraGroup,
    config: SynthConfig,
    subject: _SubjectMotion,
    joints: np.ndarray,
    sparse_vertices: np.ndarray,
) -> tuple[list[Person], list[tuple], _SubjectMotion, np.ndarray, np.ndarray]:
    """The persons besides the subject (none unless ``config.people`` > 1), their
    :meth:`Person.truth`, the subject moved to make room for them, its joints
    (F, 15, 3) and the sparse vertices of everyone (F, N, 3), for the bystanders to
    keep clear of."""
    if config.people == 1:
        return [], [], subject, joints, sparse_vertices
    base = subject.independent.appearance() if subject.independent is not None else Appearance()
    exclude = () if subject.independent is None else (subject.independent.index,)
    people, offset = draw_people(
        model,
        cameras,
        subject.motion.tau,
        sparse_vertices,
        config.look.appearance(base),
        config.people - 1,
        config.seed,
        motion=config.motion,
        fps=config.fps,
        exclude_bodies=exclude,
    )
    shift = np.r_[offset, 0.0]
    motion = subject.motion
    moved = dataclasses.replace(
        subject, motion=Motion(motion.theta, motion.tau + shift, motion.fps, motion.name)
    )
    truths = [p.truth() for p in people]
    everyone = [sparse_vertices + shift] + [t[2] for t in truths]
    return people, truths, moved, joints + shift, np.concatenate(everyone, axis=1)


def _write_person_truth(
    out: Path, config: SynthConfig, person: Person, bio: dict, joints: np.ndarray
) -> None:
    """Write ``ground_truth/persons/<k>/``'s states and ``subject.json`` of a person
    (its biometrics and joints (F, 15, 3), :meth:`Person.truth`)."""
    folder = person_folder(out / "ground_truth", person.index)
    states = {
        "frame": np.arange(config.frames),
        "tau": person.motion.tau,
        "theta": person.motion.theta,
        "joints": joints,
    }
    save_npz(folder / GROUND_TRUTH_STATES, states)
    SubjectTruth.from_json(
        {**{k: round(v, 3) for k, v in bio.items()}, **person.subject.describe()}
    ).write(folder)


def _write_true_calibration(out: Path, group: CameraGroup) -> None:
    """Write the true cameras as the session's ``calibration.yaml``."""
    save_calibration(
        out / "calibration.yaml",
        group,
        extra={
            "world": {
                "frame": "z up, floor z = 0, metres",
                "note": "true cameras of a bodymetry studio session",
            }
        },
    )


def _frame_total(config: SynthConfig) -> int:
    """Frames rendered in all: every camera's recording, background and calibration clips."""
    background_frames = config.background_frames if config.background_clip else 0
    return config.cameras * (config.frames + background_frames + config.calibration_frames)


def _write_studio_record(
    out: Path,
    config: SynthConfig,
    subject: _SubjectMotion,
    bystanders: list,
    results: list[dict],
    t0: float,
    people: Sequence[Person] = (),
) -> None:
    """Write ``ground_truth/studio.json``: the configuration, motion seed, bystanders,
    persons (with each camera's fraction of their whole projection that another
    person hides, over the kept frames), render time (since ``t0``,
    ``time.perf_counter``) and each camera's mean shadow-to-person area."""
    shadow = {r["camera"]: float(np.mean(r["shadow_to_person_area"] or [0.0])) for r in results}
    persons = []
    if people:
        persons.append({"index": 0, "subject": "the subject (ground_truth/subject.json)"})
        persons += [p.to_json() for p in people]
        for k, entry in enumerate(persons):
            entry["occluded_fraction"] = {
                r["camera"]: round(r["occluded_fraction"][k], 4) for r in results
            }
    StudioRecord(
        config={**asdict(config), "subject": asdict(config.subject)},
        motion_seed=subject.motion_seed,
        bystanders=[b.to_json() for b in bystanders],
        render_seconds=round(time.perf_counter() - t0, 2),
        shadow_to_person_area_mean=shadow,
        persons=persons,
    ).write(out / "ground_truth")


def _empty_folder(out: Path, overwrite: bool) -> None:
    """Create ``out``, or empty it when ``overwrite``.

    Raises
    ------
    InputError
        ``out`` holds files and ``overwrite`` is off.
    """
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise InputError(
                f"{out}: folder exists and is not empty (use --overwrite to replace it)"
            )
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)


@dataclass(frozen=True, eq=False)
class _SubjectMotion:
    """The recorded subject and its grounded motion.

    Attributes
    ----------
    nu : (n_shape,) float or None
        The shape of a body of our model; None for an independent subject.
    info : dict
        The subject's description for ``subject.json``.
    independent : IndependentSubject or None
    motion : Motion
        τ (F, 3) and θ (F, 37), lowest point on the floor.
    motion_seed : int
    """

    nu: np.ndarray | None
    info: dict
    independent: IndependentSubject | None
    motion: Motion
    motion_seed: int

    @classmethod
    def draw(cls, model: BodyModel, config: SynthConfig) -> _SubjectMotion:
        """Resolve the configuration's subject and make its motion, standing on the floor."""
        independent = None
        if config.subject.independent is not None:
            independent = IndependentSubject(config.subject.independent, model=model)
            nu, subject_info = None, independent.describe()
            rest = independent.rest_pose_info()
        else:
            nu, subject_info = config.subject.resolve(model)
            rest = RestPoseInfo.from_model(model, nu)
        motion_seed = seed_for("test", config.seed)
        motion = make_motion(
            config.motion, config.frames, config.fps, motion_seed, limits=model.limits, rest=rest
        )
        if independent is None:
            motion = ground_motion(model, motion, nu, lod=False)
        else:
            tau = motion.tau.copy()
            tau[:, 2] -= independent.lowest_point(motion.tau, motion.theta)
            motion = Motion(motion.theta, tau, motion.fps, motion.name)
        return cls(nu, subject_info, independent, motion, motion_seed)

    def rendered(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """What a camera job poses: τ (F, 3), θ (F, 37) and ν (or None)."""
        return self.motion.tau, self.motion.theta, self.nu

    def truth(self, model: BodyModel, frames: int) -> tuple[dict, np.ndarray, np.ndarray]:
        """The subject's true biometrics, joints and a sparse sample of its posed vertices.

        Returns
        -------
        bio : dict
            Biometrics (``Biometrics.to_dict``).
        joints : (F, 15, 3) float
            True joints (of the nude body's skinning for an independent subject:
            what MPJPE is scored against).
        sparse_vertices : (F, V / 7, 3) float
            Every 7th posed vertex (to place bystanders clear of the subject).
        """
        motion, nu, independent = self.motion, self.nu, self.independent
        if independent is None:
            bio = measure(model, nu[None])[0].to_dict()
            posed = model.pose(BodyState(motion.tau, motion.theta, nu[None]))
            joints, sparse_vertices = posed.joints, posed.vertices[:, ::7]
            del posed
        else:
            # The nude body: true joints of the skinning (what MPJPE is scored against).
            bio = independent.biometrics().to_dict()
            batches = [
                independent.pose(motion.tau[s : s + 32], motion.theta[s : s + 32])
                for s in range(0, frames, 32)
            ]
            joints = np.concatenate([j for _, j in batches])
            sparse_vertices = np.concatenate([v[:, ::7] for v, _ in batches])
            del batches
        return bio, joints, sparse_vertices


def _write_ground_truth(
    out: Path,
    config: SynthConfig,
    subject: _SubjectMotion,
    joints: np.ndarray,
    board_poses: np.ndarray,
    bio: dict,
) -> None:
    """Write ``ground_truth/``'s per-frame states and ``subject.json``.

    Parameters
    ----------
    joints : (F, 15, 3) float
    board_poses : (calibration_frames, 4, 4) float
        The calibration clip's board transforms.
    bio : dict
        The subject's biometrics.
    """
    nu, motion = subject.nu, subject.motion
    states = {
        "frame": np.arange(config.frames),
        "tau": motion.tau,
        "theta": motion.theta,
        "joints": joints,
        "board_poses": board_poses,
    }
    if nu is not None:  # an independent subject has no ν
        states["nu"] = nu
    save_npz(out / "ground_truth" / GROUND_TRUTH_STATES, states)
    SubjectTruth.from_json(
        {
            **{k: round(v, 3) for k, v in bio.items()},
            **({"nu": nu.tolist()} if nu is not None else {}),
            **subject.info,
        }
    ).write(out / "ground_truth")


def _render_cameras(
    jobs: list[_CameraJob],
    workers: int | None,
    total: int,
    on_progress: Callable[[int, int], None] | None,
) -> list[dict]:
    """Render every camera's clips in worker processes, reporting progress.

    Parameters
    ----------
    workers : int or None
        Worker processes (default: one per core, at most one per job).
    total : int
        Frames to render in all (for ``on_progress``).

    Returns
    -------
    list of dict
        Each job's :func:`_render_camera` result, in job order (worker errors re-raised).
    """
    n_workers = max(1, min(workers or mp.cpu_count() or 1, len(jobs)))
    ctx = mp.get_context("fork")
    with ctx.Manager() as manager:
        queue = manager.Queue()
        with ProcessPoolExecutor(n_workers, mp_context=ctx) as pool:
            futures = [pool.submit(_render_camera, job, queue) for job in jobs]
            done = 0
            while done < total and not all(f.done() for f in futures):
                with contextlib.suppress(queue_module.Empty):
                    done += queue.get(timeout=0.2)
                if on_progress:
                    on_progress(done, total)
            results = [f.result() for f in futures]  # re-raises worker errors
        if on_progress:
            on_progress(total, total)
    return results


def _session_record(out: Path, config: SynthConfig, cameras: CameraGroup) -> Session:
    """The rendered folder's session description (``session.yaml``)."""
    return Session(
        folder=out,
        name=out.name,
        fps=config.fps,
        frame_step=config.frame_step,
        cameras=tuple(
            SessionCamera(
                cam.name,
                f"videos/{cam.name}.mp4",
                background=f"background/{cam.name}.mp4" if config.background_clip else None,
            )
            for cam in cameras
        ),
        calibration_file="calibration.yaml",
        calibration_clips={cam.name: f"calibration/{cam.name}.mp4" for cam in cameras},
        board=STUDIO_BOARD,
        ground_truth="ground_truth",
        subject={"note": "synthetic subject, see ground_truth/subject.json"},
    )


def describe(session: Session) -> str:
    """A one-paragraph summary of a rendered session (for the CLI)."""
    gt = SubjectTruth.read(session.folder / "ground_truth")
    studio = StudioRecord.read(session.folder / "ground_truth")
    if gt is None or studio is None:
        raise InputError(f"{session.folder}: not a studio session (no ground_truth/ records)")
    extras = []
    bystanders = studio.bystanders
    if bystanders:
        seen = "; ".join(
            f"at ({b['position_m'][0]:.1f}, {b['position_m'][1]:.1f}) m seen by "
            + ", ".join(b["seen_by"])
            for b in bystanders
        )
        extras.append(f"{len(bystanders)} bystander(s) ({seen})")
    if studio.people > 1:
        crossing = "; ".join(
            f"person {p['index']} crosses in " + (", ".join(p.get("crossings", {})) or "none")
            for p in studio.persons
            if p.get("index", 0) > 0
        )
        extras.append(f"{studio.people} people ({crossing})")
    if all(cam.background is None for cam in session.cameras):
        extras.append("no background clip")
    look = recorded_look(session.folder / "ground_truth")
    if not look.is_default:
        extras.append(f"look {look.label} ({look.appearance_class})")
    return (
        f"{session.folder}: {len(session.cameras)} cameras, {studio.config['frames']} frames at "
        f"{session.fps:g} fps, subject {gt.measurements['height_mm']:.0f} mm / "
        f"{gt.measurements['weight_kg']:.1f} kg, "
        + "".join(f"{e}, " for e in extras)
        + f"rendered in {studio.render_seconds:.0f} s"
    )
