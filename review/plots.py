"""Figures and images of the report: per-frame plots (matplotlib, Agg), silhouette
overlays of camera images, and renders of the fitted body.

Figures are :class:`matplotlib.figure.Figure` objects made without pyplot (no
global state, no display): the HTML report embeds them as PNG, the PDF report
saves the same objects as vector pages.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from typing import Any

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from bodymetry.estimation.body_model.biometrics import MEASUREMENTS
from bodymetry.estimation.body_model.model import BodyModel
from bodymetry.estimation.body_model.skeleton import PARTS
from bodymetry.estimation.raster import rasterize
from bodymetry.estimation.records import STAGES, FrameRecord
from bodymetry.review.meshes import PART_COLORS
from bodymetry.review.run_data import RunData

#: Colours per stage (matplotlib), as in the Rerun recording.
STAGE_COLORS = {
    "discriminative": "#4682e6",
    "generative": "#dc5028",
    "session": "#2a9d55",
    "actual": "#222222",
}
STAGE_LABELS = {
    "discriminative": "discriminative",
    "generative": "disc. + generative",
    "session": "session (one shape ± s.e.)",
    "actual": "actual",
}
#: Human-readable names of the measurements.
LABELS = {
    "height_mm": "Height",
    "arm_span_mm": "Arm span",
    "weight_kg": "Weight",
    "volume_l": "Volume",
    "chest_mm": "Chest girth",
    "waist_mm": "Waist girth",
    "hip_mm": "Hip girth",
    "shoulder_breadth_mm": "Shoulder breadth",
    "inseam_mm": "Inseam",
    "arm_length_mm": "Arm length",
    "bmi": "BMI",
}


def label(key: str) -> str:
    """``"Height (mm)"`` for ``"height_mm"``."""
    return f"{LABELS.get(key, key)} ({MEASUREMENTS.get(key, '')})"


def figure(width_in: float, height_in: float) -> Figure:
    """A matplotlib figure without pyplot (Agg canvas)."""
    # No layout engine: constrained layout doubles the drawing time; each figure
    # places its axes with subplots_adjust.
    fig = Figure(figsize=(width_in, height_in), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def png_bytes(fig: Any, dpi: int = 100) -> bytes:
    """PNG bytes of a figure."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def measurement_plots(run: RunData, keys: Sequence[str] | None = None) -> Any:
    """One panel per measurement: its value per frame for each stage, the truth as a line.

    Frames left out of the summary (failed, or failing a quality gate) are marked
    by grey lines across the panels.
    """
    ok = run.fitted_frames
    present = ok[0].estimates["generative"].biometrics if ok else {}
    keys = list(keys or [k for k in MEASUREMENTS if k in present])
    cols = 3
    rows = max(1, -(-len(keys) // cols))
    height = 2.3 * rows
    fig = figure(11.0, height)
    axes = fig.subplots(rows, cols, squeeze=False)
    fig.subplots_adjust(
        left=0.06, right=0.99, top=1 - 0.3 / height, bottom=0.3 / height, hspace=0.45, wspace=0.2
    )
    frames = np.array([r.frame for r in ok])
    failed = [r.frame for r in run.frames if not r.ok]
    truth = run.ground_truth.measurements if run.ground_truth else {}
    for ax, key in zip(axes.flat, keys, strict=False):
        for stage in STAGES:
            values = np.array([_value(r, stage, key) for r in ok], float)
            if not np.isfinite(values).any():
                continue  # e.g. a run without the session stage
            se = _session_error(run, key) if stage == "session" else None
            if se is not None:
                ax.fill_between(
                    frames, values - se, values + se, color=STAGE_COLORS[stage], alpha=0.2, lw=0
                )
            ax.plot(
                frames,
                values,
                "o-",
                ms=2.5,
                lw=1.2,
                color=STAGE_COLORS[stage],
                label=STAGE_LABELS[stage],
            )
        if key in truth:
            ax.axhline(truth[key], color=STAGE_COLORS["actual"], ls="--", lw=1, label="actual")
        for f in failed:
            ax.axvline(f, color="0.8", lw=0.8, zorder=0)
        ax.set_title(label(key), fontsize=9)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(keys) :]:
        ax.set_axis_off()
    if keys:
        handles, labels = axes.flat[0].get_legend_handles_labels()
        spare = list(axes.flat)[len(keys) :]
        if spare:  # the legend in the first empty panel
            spare[0].legend(handles, labels, loc="center", fontsize=9, title="x: session frame")
        else:
            fig.legend(handles, labels, loc="lower center", ncols=3, fontsize=8)
            fig.subplots_adjust(bottom=0.7 / height)
    return fig


def _session_error(run: RunData, key: str) -> float | None:
    """The standard error of the session's value of a measurement (None without one)."""
    s = run.results.summary.get("session", {}).get(key)
    return None if s is None or s.std is None else s.std


def _value(record: FrameRecord, stage: str, key: str) -> float:
    """A stage's measurement of a frame (NaN when the stage or the value is missing)."""
    est = record.estimates.get(stage)
    return est.biometrics.get(key, np.nan) if est is not None else np.nan


def fit_quality_plots(run: RunData) -> Any:
    """Silhouette IoU per camera and the annealing log-likelihood per frame."""
    ok = run.fitted_frames
    fig = figure(11.0, 2.6)
    ax_iou, ax_ll, ax_std = fig.subplots(1, 3)
    fig.subplots_adjust(left=0.05, right=0.99, top=0.9, bottom=0.17, wspace=0.18)
    frames = [r.frame for r in ok]
    for name in run.camera_names:
        ax_iou.plot(
            frames,
            [r.silhouette_iou.get(name, np.nan) for r in ok],
            "o-",
            ms=2,
            lw=1,
            label=name,
        )
    ax_iou.set_title("silhouette IoU of the fit", fontsize=9)
    ax_iou.set_ylim(0, 1)
    ax_iou.legend(fontsize=7, ncols=2)
    layers = [r.annealing.layer_log_likelihood if r.annealing is not None else () for r in ok]
    n_layers = max((len(x) for x in layers), default=0)
    cmap = matplotlib.colormaps["viridis"]
    for i in range(n_layers):
        ax_ll.plot(
            frames,
            [x[i] if i < len(x) else np.nan for x in layers],
            lw=1,
            color=cmap(i / max(n_layers - 1, 1)),
            label=f"layer {i + 1}" if i in (0, n_layers - 1) else None,
        )
    ax_ll.set_title("log-likelihood per annealing layer", fontsize=9)
    if n_layers:
        ax_ll.legend(fontsize=7)
    std = np.array([_tau_std(r) for r in ok], float).reshape(-1, 3)
    for i, axis in enumerate("xyz"):
        ax_std.plot(frames, 1000 * std[:, i], lw=1, label=f"τ {axis}")
    ax_std.set_title("particle spread (std of τ, mm)", fontsize=9)
    ax_std.legend(fontsize=7)
    for ax in (ax_iou, ax_ll, ax_std):
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        ax.set_xlabel("session frame", fontsize=8)
    return fig


def _tau_std(record: FrameRecord) -> tuple[float, ...]:
    """The last annealing layer's spread of τ (m), NaN when the frame has no trace."""
    trace = record.annealing
    if trace is None or len(trace.tau_std_m) != 3:
        return (np.nan, np.nan, np.nan)
    return trace.tau_std_m


# --- body renders ------------------------------------------------------------------------
def front_direction(body: BodyModel, vertices: np.ndarray) -> np.ndarray:
    """Horizontal unit vector (3,) the body faces: from the ankles towards the toes."""
    faces = body.faces()
    parts = np.asarray(body.full.arrays.parts)
    feet = [PARTS.index("foot_l"), PARTS.index("foot_r")]
    foot_vertices = np.unique(faces[np.isin(parts, feet)])
    legs = [PARTS.index("shin_l"), PARTS.index("shin_r")]
    shin_vertices = np.unique(faces[np.isin(parts, legs)])
    if len(foot_vertices) == 0 or len(shin_vertices) == 0:
        # A model without feet or shins faces nowhere in particular: the default
        # (the mean of an empty selection would be NaN, and a RuntimeWarning).
        return np.array([0.0, -1.0, 0.0])
    d = vertices[foot_vertices].mean(axis=0) - vertices[shin_vertices].mean(axis=0)
    d[2] = 0.0
    n = np.linalg.norm(d)
    return d / n if n > 1e-9 else np.array([0.0, -1.0, 0.0])


def render_body(
    vertices: np.ndarray,
    faces: np.ndarray,
    face_rgb: np.ndarray,
    view: np.ndarray,
    size: tuple[int, int] = (240, 480),
    extent_m: float = 2.05,
) -> np.ndarray:
    """Orthographic render of a mesh seen along ``view`` with z up, lit from the viewer.

    Parameters
    ----------
    vertices : (V, 3) float
        Metres, z up, feet near z = 0.
    faces : (T, 3) int
        Outward counter-clockwise triangles.
    face_rgb : (T, 3) uint8
    view : (3,) float
        Horizontal viewing direction (from the eye into the scene).
    size : (width, height)
        Pixels.
    extent_m : float
        Height of the image in metres (the scale; the body is centred horizontally).

    Returns
    -------
    (H, W, 3) uint8 RGB, white background (only that for an empty mesh).

    Raises
    ------
    ValueError
        If ``view`` is zero or not finite.
    """
    w, h = size
    fwd = np.asarray(view, float)
    norm = np.linalg.norm(fwd)
    if not norm > 0:  # also NaN
        raise ValueError(f"render_body: view must be a non-zero direction, got {view!r}")
    fwd = fwd / norm
    image = np.full((h, w, 3), 255, np.uint8)
    if len(vertices) == 0 or len(faces) == 0:
        return image  # nothing to draw (and no centre to take the mean of)
    up = np.array([0.0, 0.0, 1.0])
    right = np.cross(fwd, up)
    scale = h / extent_m
    centre = vertices.mean(axis=0)
    x = (vertices - centre) @ right * scale + w / 2
    y = h - 0.03 * h - vertices[:, 2] * scale
    depth = vertices @ fwd
    raster = rasterize(np.stack([x, y], axis=1), depth, faces, (w, h), perspective=False)
    p = vertices[faces]
    normals = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    shade = 0.35 + 0.65 * np.clip(-(normals @ fwd), 0.0, 1.0)
    tri = raster.tri
    covered = tri >= 0
    image[covered] = np.clip(face_rgb[tri[covered]] * shade[tri[covered], None], 0, 255).astype(
        np.uint8
    )
    return image


def body_views(body: BodyModel, nu: np.ndarray, height_px: int = 440) -> dict[str, Any]:
    """Front and side renders of the canonical body of shape ``nu`` (9,).

    Returns
    -------
    dict with ``front`` and ``side`` (H, W, 3) uint8 RGB images.
    """
    vertices = body.canonical_vertices(np.asarray(nu, float)[None])[0]
    faces = body.faces()
    face_rgb = PART_COLORS[np.asarray(body.full.arrays.parts)]
    front = front_direction(body, vertices)
    side = np.cross(np.array([0.0, 0.0, 1.0]), front)
    return {
        # Looking at the body's front: the eye looks against the direction it faces.
        "front": render_body(vertices, faces, face_rgb, -front, (height_px * 3 // 4, height_px)),
        "side": render_body(vertices, faces, face_rgb, side, (height_px // 2, height_px)),
    }


def body_figure(renders: dict[str, dict[str, np.ndarray]]) -> Any:
    """Renders side by side at one scale, e.g. ``{"fitted": body_views(...), "actual": ...}``."""
    views = [(f"{who}: {view}", img) for who, v in renders.items() for view, img in v.items()]
    if not views:
        raise ValueError("body_figure: no render to show")
    widths = [img.shape[1] for _, img in views]
    height = max(img.shape[0] for _, img in views)
    fig = figure(sum(widths) / height * 4.0 + 0.2 * len(views), 4.4)
    axes = fig.subplots(1, len(views), squeeze=False, width_ratios=widths)[0]
    fig.subplots_adjust(left=0.01, right=0.99, top=0.93, bottom=0.01, wspace=0.05)
    for ax, (title, image) in zip(axes, views, strict=True):
        ax.imshow(image)
        ax.set_title(title, fontsize=9)
        ax.set_axis_off()
    return fig


def image_grid(rows: Sequence[tuple[str, Sequence[np.ndarray]]], col_titles: Sequence[str]) -> Any:
    """A figure of image rows (RGB), one label per row, for the PDF overlays page."""
    n_rows = max(1, len(rows))
    n_cols = max(1, max((len(r[1]) for r in rows), default=1))
    fig = figure(11.0, 11.0 * n_rows / n_cols * 0.75 + 0.6)
    axes = fig.subplots(n_rows, n_cols, squeeze=False)
    fig.subplots_adjust(left=0.01, right=0.99, top=0.93, bottom=0.01, wspace=0.03, hspace=0.15)
    for i, (title, images) in enumerate(rows):
        for j in range(n_cols):
            ax = axes[i, j]
            ax.set_axis_off()
            if j < len(images):
                ax.imshow(images[j])
                ax.set_title(
                    f"{title}, {col_titles[j]}" if j < len(col_titles) else title, fontsize=8
                )
    return fig
