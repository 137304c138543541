"""Mesh files (PLY, OBJ, GLB, STL) of fitted bodies, written with trimesh."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

# Defined with the body model (the studio uses it too); other review modules import it from here.
from bodymetry.estimation.body_model.parts import PART_COLORS
from bodymetry.fileio import atomic_path

MESH_FORMATS = (".ply", ".obj", ".glb", ".stl")


def write_mesh(
    path: str | Path, vertices: np.ndarray, faces: np.ndarray, face_parts: np.ndarray | None = None
) -> None:
    """Write a triangle mesh atomically; the format follows the extension.

    Parameters
    ----------
    path : path
        ``.ply``, ``.obj``, ``.glb`` or ``.stl``.
    vertices : (V, 3) float
        Metres.
    faces : (T, 3) int
    face_parts : (T,) int, optional
        Part index per triangle, for per-face colours where the format has them.
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in MESH_FORMATS:
        raise ValueError(f"{path}: unsupported mesh extension {ext!r}; use one of {MESH_FORMATS}")
    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=float), np.asarray(faces), process=False)
    if face_parts is not None and ext in (".ply", ".glb"):
        rgb = PART_COLORS[np.asarray(face_parts)]
        mesh.visual.face_colors = np.concatenate(
            [rgb, np.full((len(rgb), 1), 255, np.uint8)], axis=1
        )
    with atomic_path(path) as tmp:
        mesh.export(tmp, file_type=ext[1:])
