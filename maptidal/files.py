"""Reading and writing maptidal's files: meshes, keypoints and task lists.

Task lists (TASKS.json) have the shape ``{"tasks": [{"position": [x, y, z],
"direction": [dx, dy, dz]}, ...]}``; other top-level keys are ignored, so the
``maptidal discover --json`` output of one frame is the ``--existing`` input of
the next. Every file is written atomically (a temporary file, then a rename),
so an interrupted run never leaves half a file behind.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np

from maptidal.discovery import DiscoveryInputError, tasks_to_json_list, validate_mesh, validate_viewpoints

MESH_SUFFIXES = (".ply", ".obj", ".stl")


def _process_umask() -> int:
    """The process's umask, read without changing it where Linux tells it (os.umask can only be read by
    setting it, which would race with threads creating files)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically, creating parent folders. The file gets the mode a plain
    ``open`` would give it (0666 less the umask), not mkstemp's private 0600."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as err:  # name the file the caller asked for, not a folder or temporary name
        raise type(err)(err.errno, err.strerror, str(path)) from None
    try:
        os.fchmod(handle, 0o666 & ~_process_umask())
        with os.fdopen(handle, "wb") as stream:
            stream.write(data)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    return path


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def save_png(figure, path: str | os.PathLike, dpi: int = 110) -> Path:
    """Save a matplotlib ``figure`` as a PNG at ``path`` atomically, and close it."""
    import io

    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    plt.close(figure)
    return atomic_write_bytes(path, buffer.getvalue())


def atomic_write_json(path: str | os.PathLike, document: object) -> Path:
    """Write ``document`` as indented JSON to ``path`` atomically."""
    return atomic_write_text(path, json.dumps(document, indent=2) + "\n")


def tasks_from_json_document(document: object, source: str = "tasks") -> np.ndarray:
    """Parse a ``{"tasks": [...]}`` document into validated ``(N, 6)`` rows."""
    if not isinstance(document, dict) or not isinstance(document.get("tasks"), list):
        raise DiscoveryInputError(f"{source}: expected an object with a 'tasks' list")
    rows = []
    for index, task in enumerate(document["tasks"]):
        if not isinstance(task, dict):
            raise DiscoveryInputError(f"{source}: task {index} is not an object")
        position, direction = task.get("position"), task.get("direction")
        if not (isinstance(position, list) and len(position) == 3):
            raise DiscoveryInputError(f"{source}: task {index} needs a 3-element 'position'")
        if not (isinstance(direction, list) and len(direction) == 3):
            raise DiscoveryInputError(f"{source}: task {index} needs a 3-element 'direction'")
        if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in position + direction):
            raise DiscoveryInputError(f"{source}: task {index} has a non-numeric coordinate")
        rows.append([*position, *direction])
    return validate_viewpoints(np.asarray(rows, dtype=float).reshape(-1, 6), f"{source}: tasks")


def _require_file(path: str | os.PathLike, what: str) -> Path:
    path = Path(path)
    if not path.exists():
        raise DiscoveryInputError(f"{what} not found: {path}")
    if not path.is_file():
        raise DiscoveryInputError(f"{what} is not a file: {path}")
    return path


def load_tasks(path: str | os.PathLike) -> np.ndarray:
    """Load and validate a TASKS.json file as ``(N, 6)`` rows."""
    path = _require_file(path, "task file")
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise DiscoveryInputError(f"{path}: not valid JSON ({err})") from err
    return tasks_from_json_document(document, str(path))


def save_tasks(path: str | os.PathLike, rows: np.ndarray, **extra: object) -> Path:
    """Write a TASKS.json file atomically; ``extra`` keys (counts, params) go beside 'tasks'."""
    return atomic_write_json(path, {**extra, "tasks": tasks_to_json_list(rows)})


def load_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Load a triangle mesh (PLY, OBJ or STL) as validated ``(vertices, faces)``.

    The file is read without trimesh's processing, so vertex and face order are
    those of the file (discovery is order dependent).
    """
    import trimesh

    path = _require_file(path, "mesh file")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise DiscoveryInputError(
            f"{path}: unsupported mesh format {path.suffix!r}; use one of {', '.join(MESH_SUFFIXES)}"
        )
    try:
        loaded = trimesh.load(path, process=False, force="mesh")
    except Exception as err:  # trimesh raises many types for malformed files
        raise DiscoveryInputError(f"{path}: could not read the mesh ({err})") from err
    vertices = np.asarray(getattr(loaded, "vertices", np.empty((0, 3))), dtype=float)
    faces = np.asarray(getattr(loaded, "faces", np.empty((0, 3))))
    if faces.size == 0:
        raise DiscoveryInputError(f"{path}: the mesh has no triangles")
    return validate_mesh(vertices, faces)


def save_mesh(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray) -> Path:
    """Write a triangle mesh atomically; the format follows the suffix (.ply, .obj or .stl).

    Vertex and face order are kept (no merging or reordering), so :func:`load_mesh` reads back the
    same mesh and discovery gives the same tasks.
    """
    import trimesh

    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise DiscoveryInputError(f"{path}: a mesh file must end in one of {', '.join(MESH_SUFFIXES)}")
    mesh = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces), process=False)
    return atomic_write_bytes(path, mesh.export(file_type=path.suffix.lower()[1:]))


def load_keypoints(path: str | os.PathLike) -> np.ndarray:
    """Load keypoints ``(K, 3)`` from a .npy array or a PLY point cloud (or mesh vertices)."""
    import trimesh

    path = _require_file(path, "keypoint file")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            points = np.load(path, allow_pickle=False)
        elif suffix == ".ply":
            points = np.asarray(trimesh.load(path, process=False).vertices)
        else:
            raise DiscoveryInputError(f"{path}: keypoints must be a .npy array or a .ply point cloud")
    except DiscoveryInputError:
        raise
    except Exception as err:
        raise DiscoveryInputError(f"{path}: could not read keypoints ({err})") from err
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise DiscoveryInputError(f"{path}: keypoints must have shape (K>0, 3), got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise DiscoveryInputError(f"{path}: keypoints contain NaN or infinite values")
    return points
