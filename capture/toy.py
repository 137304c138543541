"""Toy sessions for tests and examples: no body, no renderer, a second to write.

A textured room-like background with sensor noise, a "person" (an upright
ellipse in a colour unlike the background) walking across it, and its cast
shadow (the background darkened, same chromaticity) on one side. Each frame's
number is written into the top-left block's brightness so that tests can check
which video frame they got. Videos are MJPG AVI (OpenCV writes them anywhere);
ground-truth silhouettes are written for the kept frames.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bodymetry.calibration.camera import Camera, CameraGroup
from bodymetry.calibration.io import save_calibration
from bodymetry.capture.session import Session, SessionCamera, save_session

__all__ = ["ToyScene", "toy_background", "toy_frame", "write_toy_session", "write_video"]

#: The top-left block that carries the frame number (brightness = 4 x (frame % 60)).
STAMP = 8


@dataclass(frozen=True)
class ToyScene:
    """What :func:`toy_frame` draws.

    Attributes
    ----------
    size : (int, int)
        ``(width, height)``.
    person_bgr : (3,) float
        The person's colour.
    shadow_gain : float
        Shadow brightness as a fraction of the background (same chromaticity).
    noise : float
        Gaussian noise sigma, DN.
    """

    size: tuple[int, int] = (160, 120)
    person_bgr: tuple[float, float, float] = (40.0, 50.0, 170.0)
    shadow_gain: float = 0.6
    noise: float = 2.0


def toy_background(scene: ToyScene, seed: int = 0) -> np.ndarray:
    """(H, W, 3) float32 noise-free background: a beige-grey gradient with tiles."""
    w, h = scene.size
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    base = np.array([150.0, 165.0, 175.0], np.float32) * (0.75 + 0.25 * yy / h)[..., None]
    tiles = ((xx // 16 + yy // 16) % 2)[..., None] * np.array([12.0, 10.0, 6.0], np.float32)
    speckle = cv2.GaussianBlur(rng.normal(0, 6, (h, w)).astype(np.float32), (0, 0), 2)[..., None]
    return np.clip(base + tiles + speckle, 0, 255).astype(np.float32)


def toy_person_mask(scene: ToyScene, center: tuple[float, float]) -> np.ndarray:
    """(H, W) bool: the toy person (an upright ellipse) at ``center`` (x, y) pixels."""
    w, h = scene.size
    mask = np.zeros((h, w), np.uint8)
    axes = (max(int(0.06 * w), 3), max(int(0.28 * h), 6))
    cv2.ellipse(mask, (int(center[0]), int(center[1])), axes, 0, 0, 360, 1, -1)
    return mask > 0


def toy_frame(
    scene: ToyScene,
    background: np.ndarray,
    people: list[tuple[float, float]],
    rng: np.random.Generator,
    frame_number: int | None = None,
    shadows: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render one toy frame.

    Returns
    -------
    image : (H, W, 3) uint8
    person : (H, W) bool
    shadow : (H, W) bool (not person)
    """
    w, h = scene.size
    img = background.copy()
    person = np.zeros((h, w), bool)
    shadow = np.zeros((h, w), bool)
    for cx, cy in people:
        p = toy_person_mask(scene, (cx, cy))
        if shadows:
            # The shadow: the person's footprint sheared to the right along the floor.
            s = np.zeros((h, w), np.uint8)
            foot = (int(cx), int(cy + 0.26 * h))
            cv2.ellipse(
                s,
                (foot[0] + int(0.12 * w), foot[1]),
                (int(0.12 * w), max(int(0.03 * h), 2)),
                0,
                0,
                360,
                1,
                -1,
            )
            shadow |= s > 0
        person |= p
    shadow &= ~person
    img[shadow] *= scene.shadow_gain
    img[person] = np.asarray(scene.person_bgr, np.float32)
    img = cv2.GaussianBlur(img, (0, 0), 0.6)
    img += rng.normal(0, scene.noise, img.shape).astype(np.float32)
    if frame_number is not None:
        img[:STAMP, :STAMP] = 4 * (frame_number % 60)
    return np.clip(img, 0, 255).round().astype(np.uint8), person, shadow


def write_video(path: str | Path, frames: list[np.ndarray], fps: float = 30.0) -> Path:
    """Write BGR frames as an MJPG ``.avi`` (quality 95)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
    writer.set(cv2.VIDEOWRITER_PROP_QUALITY, 95)
    for frame in frames:
        writer.write(frame)
    writer.release()
    return path


def toy_cameras(names: list[str], size: tuple[int, int]) -> CameraGroup:
    """Cameras on a circle looking at the origin (only the names and sizes matter here)."""
    cams = []
    w, h = size
    for i, name in enumerate(names):
        a = 2 * np.pi * i / len(names)
        R = np.array(
            [[-np.sin(a), np.cos(a), 0.0], [0.0, 0.0, -1.0], [-np.cos(a), -np.sin(a), 0.0]]
        )
        center = np.array([3 * np.cos(a), 3 * np.sin(a), 1.5])
        K = [[w, 0.0, w / 2], [0.0, w, h / 2], [0.0, 0.0, 1.0]]
        cams.append(Camera(name, (w, h), K, [0.0] * 5, R, -R @ center))
    return CameraGroup(cams)


def write_toy_session(
    folder: str | Path,
    *,
    cameras: int = 2,
    frames: int = 40,
    frame_step: int = 10,
    fps: float = 30.0,
    scene: ToyScene | None = None,
    offsets: list[int] | None = None,
    frame_counts: list[int] | None = None,
    background_frames: int = 12,
    backgrounds: bool = True,
    shadows: bool = True,
    second_person: bool = False,
    empty_frames: tuple[int, ...] = (),
    seed: int = 0,
) -> Session:
    """Write a toy session folder (videos, background clips, calibration, ground truth).

    Parameters
    ----------
    offsets : list of int, optional
        Per camera ``frame_offset``: the camera's video starts with that many
        extra frames (its session frame ``f`` is video frame ``f + offset``).
    frame_counts : list of int, optional
        Per camera session frames actually written (default ``frames``).
    second_person : bool
        A second person-sized blob stands still far from the first.
    empty_frames : tuple of int
        Session frames with nobody in view.
    """
    folder = Path(folder)
    scene = scene or ToyScene()
    w, h = scene.size
    names = [f"cam_{i:02d}" for i in range(cameras)]
    offsets = offsets or [0] * cameras
    frame_counts = frame_counts or [frames] * cameras
    save_calibration(folder / "calibration.yaml", toy_cameras(names, scene.size))
    cams = []
    for c, name in enumerate(names):
        rng = np.random.default_rng([seed, c])
        bg = toy_background(scene, seed * 100 + c)
        images = []
        for f in range(-offsets[c], frame_counts[c]):
            cx = (0.25 + 0.5 * ((f % frames) / max(frames - 1, 1))) * w
            people = [] if f in empty_frames else [(cx, 0.5 * h)]
            if second_person:
                people.append((0.9 * w if cx < 0.5 * w else 0.1 * w, 0.5 * h))
            image, person, _ = toy_frame(scene, bg, people, rng, f + offsets[c], shadows)
            images.append(image)
            if f >= 0 and f % frame_step == 0:
                gt = folder / "ground_truth" / "silhouettes" / name / f"{f:06d}.png"
                gt.parent.mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(gt), person.astype(np.uint8) * 255)
        write_video(folder / "videos" / f"{name}.avi", images, fps)
        background = None
        if backgrounds:
            clip = [toy_frame(scene, bg, [], rng, None, False)[0] for _ in range(background_frames)]
            write_video(folder / "background" / f"{name}.avi", clip, fps)
            background = f"background/{name}.avi"
        cams.append(SessionCamera(name, f"videos/{name}.avi", offsets[c], background))
    session = Session(
        folder=folder,
        name=folder.name,
        fps=fps,
        cameras=tuple(cams),
        frame_step=frame_step,
        calibration_file="calibration.yaml",
        ground_truth="ground_truth",
    )
    save_session(session, folder)
    return session
