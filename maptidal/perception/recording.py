"""A stereo recording on disk: the one shape the front end reads, from the simulator or a real OAK-D.

    RECORDING/
        intrinsics.json   {"width", "height", "fx", "fy", "cx", "cy", "baseline_m"}: the rectified pair
        poses.json        {"version": 1, "metadata": {...}, "frames": [{"index", "time_s", "left", "right",
                           "poses": {SOURCE: {"position": [x, y, z], "quaternion": [w, x, y, z]}}}]}
        left/000000.png   left images (8-bit grey or RGB)
        right/000000.png  right images, the same size

A pose is the left camera's optical frame (x right, y down, z forward) in the world: ``position`` is the
camera centre (m) and ``quaternion`` (w, x, y, z) rotates optical-frame vectors into the world. Each frame
may carry several pose sources: ``truth`` (the simulator's ground truth) and ``dr`` (the robot's dead
reckoning) from a simulated capture, or a real vehicle's ``estimate``. ``metadata`` may name the
``scenario`` and ``tank``, and a ``surface`` file in the folder (a mesh of the true surfaces, which
a simulated capture writes) from which the front end reports its mesh error.

:class:`RecordingWriter` writes frames as they come: each image atomically, then ``poses.json``
atomically, so a recording cut short is readable up to its last frame. :func:`load_recording` checks
everything it reads and raises :class:`RecordingError` with a one-line reason.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from maptidal.files import atomic_write_bytes, atomic_write_json

RECORDING_VERSION = 1
BLACK_FRAME_STD = 1.0  # an image whose grey levels vary less than this carries nothing to match


class RecordingError(ValueError):
    """A recording the front end cannot use; the message names the file and the problem."""


@dataclass(frozen=True)
class CameraIntrinsics:
    """A rectified stereo pair: image size (px), focal lengths and principal point (px), baseline (m)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and value > 0):
                raise RecordingError(f"intrinsics: {name} must be a positive whole number, got {value!r}")
        for name in ("fx", "fy", "baseline_m"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise RecordingError(f"intrinsics: {name} must be a positive finite number, got {value!r}")
        for name in ("cx", "cy"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise RecordingError(f"intrinsics: {name} must be a finite number, got {value!r}")

    @property
    def matrix(self) -> np.ndarray:
        """The 3 x 3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def to_dict(self) -> dict:
        """The ``intrinsics.json`` document."""
        return {k: getattr(self, k) for k in ("width", "height", "fx", "fy", "cx", "cy", "baseline_m")}

    @classmethod
    def from_dict(cls, document: object) -> CameraIntrinsics:
        """Read an ``intrinsics.json`` document (RecordingError on missing or bad fields)."""
        keys = ("width", "height", "fx", "fy", "cx", "cy", "baseline_m")
        if not isinstance(document, dict) or any(k not in document for k in keys):
            raise RecordingError(f"intrinsics.json must hold {', '.join(keys)}")
        return cls(**{k: document[k] for k in keys})


def rotation_from_quaternion(quaternion) -> np.ndarray:
    """The rotation matrix of a unit quaternion (w, x, y, z) (normalised first)."""
    w, x, y, z = np.asarray(quaternion, float) / np.linalg.norm(quaternion)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quaternion_from_rotation(rotation: np.ndarray) -> np.ndarray:
    """The unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (Shepperd's method)."""
    m = np.asarray(rotation, float)
    trace = np.trace(m)
    candidates = [trace, m[0, 0], m[1, 1], m[2, 2]]
    k = int(np.argmax(candidates))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif k == 1:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif k == 2:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    return q if q[0] >= 0 else -q


@dataclass(frozen=True)
class CameraPose:
    """The left camera's optical frame in the world: centre ``position`` (m) and ``rotation`` (optical
    to world; its columns are the image's right, down and forward axes)."""

    position: np.ndarray
    rotation: np.ndarray

    @property
    def forward(self) -> np.ndarray:
        """The optical axis (unit, world frame)."""
        return self.rotation[:, 2]

    def to_world(self, points_camera: np.ndarray) -> np.ndarray:
        """Optical-frame points ``(N, 3)`` in the world frame."""
        return np.asarray(points_camera, float).reshape(-1, 3) @ self.rotation.T + self.position

    def to_dict(self) -> dict:
        """``{"position": [...], "quaternion": [w, x, y, z]}``."""
        return {
            "position": [float(v) for v in self.position],
            "quaternion": [float(v) for v in quaternion_from_rotation(self.rotation)],
        }

    @classmethod
    def from_dict(cls, document: object, where: str) -> CameraPose:
        """Read ``{"position", "quaternion"}`` (RecordingError naming ``where`` when bad)."""
        if not isinstance(document, dict) or "position" not in document or "quaternion" not in document:
            raise RecordingError(f"{where}: a pose needs a position and a quaternion")
        try:
            position = np.asarray(document["position"], float)
            quaternion = np.asarray(document["quaternion"], float)
        except (TypeError, ValueError) as err:
            raise RecordingError(f"{where}: pose values must be numbers ({err})") from None
        if position.shape != (3,) or quaternion.shape != (4,):
            raise RecordingError(f"{where}: a pose is a 3-vector position and a 4-vector quaternion")
        if not (np.all(np.isfinite(position)) and np.all(np.isfinite(quaternion))):
            raise RecordingError(f"{where}: the pose holds NaN or infinite values")
        if np.linalg.norm(quaternion) < 1e-6:
            raise RecordingError(f"{where}: the quaternion is zero")
        return cls(position, rotation_from_quaternion(quaternion))


@dataclass(frozen=True)
class RecordedFrame:
    """One stereo frame: its index and time (s), its image files and its poses by source."""

    index: int
    time_s: float
    left: Path
    right: Path
    poses: dict[str, CameraPose]


@dataclass
class Recording:
    """A loaded recording (:func:`load_recording`): where it is, its intrinsics, frames and metadata."""

    root: Path
    intrinsics: CameraIntrinsics
    frames: list[RecordedFrame]
    metadata: dict = field(default_factory=dict)

    def pose_sources(self) -> set[str]:
        """The pose sources every frame carries."""
        sources = [set(frame.poses) for frame in self.frames]
        return set.intersection(*sources) if sources else set()

    def images(self, frame: RecordedFrame) -> tuple[np.ndarray, np.ndarray]:
        """The frame's (left, right) images as arrays, checked: both present, readable, the size of the
        intrinsics, and not black."""
        pair = []
        for side, path in (("left", frame.left), ("right", frame.right)):
            if not path.is_file():
                raise RecordingError(f"frame {frame.index}: the {side} image {path} is missing")
            image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if image is None:
                raise RecordingError(f"frame {frame.index}: the {side} image {path} is not a readable image")
            if image.dtype != np.uint8:
                raise RecordingError(f"frame {frame.index}: the {side} image {path} is not 8-bit")
            if image.ndim == 3:
                image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB if image.shape[2] == 3 else cv2.COLOR_BGRA2RGB)
            size = (image.shape[1], image.shape[0])
            expected = (self.intrinsics.width, self.intrinsics.height)
            if size != expected:
                raise RecordingError(
                    f"frame {frame.index}: the {side} image is {size[0]} x {size[1]}, the intrinsics say "
                    f"{expected[0]} x {expected[1]}"
                )
            if float(image.std()) < BLACK_FRAME_STD:
                raise RecordingError(f"frame {frame.index}: the {side} image {path} is blank (black or flat)")
            pair.append(image)
        return pair[0], pair[1]


def _read_json(path: Path, what: str) -> object:
    if not path.is_file():
        raise RecordingError(f"{path.parent}: no {what} ({path.name})")
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise RecordingError(f"{path}: not valid JSON ({err})") from None


def load_recording(root: str | Path) -> Recording:
    """Read and check a recording folder (module docstring); RecordingError says what is wrong."""
    root = Path(root)
    if not root.is_dir():
        raise RecordingError(f"{root}: no such recording folder")
    intrinsics = CameraIntrinsics.from_dict(_read_json(root / "intrinsics.json", "intrinsics"))
    document = _read_json(root / "poses.json", "pose file")
    if not isinstance(document, dict) or not isinstance(document.get("frames"), list):
        raise RecordingError(f"{root / 'poses.json'}: expected an object with a list of frames")
    frames: list[RecordedFrame] = []
    last_time = -math.inf
    for position, entry in enumerate(document["frames"]):
        where = f"poses.json frame {position}"
        if not isinstance(entry, dict):
            raise RecordingError(f"{where}: a frame is an object")
        for key in ("index", "time_s", "left", "right", "poses"):
            if key not in entry:
                raise RecordingError(f"{where}: missing {key!r}")
        time_s = entry["time_s"]
        if not (isinstance(time_s, int | float) and math.isfinite(time_s)) or time_s <= last_time:
            raise RecordingError(f"{where}: time_s must be finite and increasing, got {time_s!r}")
        last_time = float(time_s)
        if not isinstance(entry["poses"], dict) or not entry["poses"]:
            raise RecordingError(f"{where}: needs at least one pose source")
        poses = {
            str(source): CameraPose.from_dict(pose, f"{where} pose {source!r}")
            for source, pose in entry["poses"].items()
        }
        frames.append(
            RecordedFrame(
                int(entry["index"]), float(time_s), root / entry["left"], root / entry["right"], poses
            )
        )
    if not frames:
        raise RecordingError(f"{root / 'poses.json'}: the recording holds no frames")
    on_disk = len(list((root / "left").glob("*.png"))) if (root / "left").is_dir() else 0
    if on_disk != len(frames):
        raise RecordingError(
            f"{root}: poses.json lists {len(frames)} frames but left/ holds {on_disk} images: the pose file "
            "does not match the frames"
        )
    metadata = document.get("metadata", {})
    return Recording(root, intrinsics, frames, metadata if isinstance(metadata, dict) else {})


class RecordingWriter:
    """Writes a recording frame by frame (module docstring): each image atomically, then ``poses.json``."""

    def __init__(self, root: str | Path, intrinsics: CameraIntrinsics, metadata: dict | None = None) -> None:
        self.root = Path(root)
        for side in ("left", "right"):
            (self.root / side).mkdir(parents=True, exist_ok=True)
            for stale in (self.root / side).glob("*.png"):  # an earlier recording in the same folder
                stale.unlink()
        self.intrinsics = intrinsics
        self.metadata = dict(metadata or {})
        self.frames: list[dict] = []
        atomic_write_json(self.root / "intrinsics.json", intrinsics.to_dict())
        self._write_poses()

    def add(self, time_s: float, left: np.ndarray, right: np.ndarray, poses: dict[str, CameraPose]) -> int:
        """Write one frame (RGB or grey uint8 images, poses by source); returns its index."""
        index = len(self.frames)
        names = {}
        for side, image in (("left", left), ("right", right)):
            array = np.asarray(image)
            if array.ndim == 3:
                array = cv2.cvtColor(array, cv2.COLOR_RGB2BGR)
            ok, encoded = cv2.imencode(".png", array)
            if not ok:
                raise RecordingError(f"frame {index}: could not encode the {side} image")
            names[side] = f"{side}/{index:06d}.png"
            atomic_write_bytes(self.root / names[side], encoded.tobytes())
        self.frames.append(
            {
                "index": index,
                "time_s": float(time_s),
                **names,
                "poses": {source: pose.to_dict() for source, pose in poses.items()},
            }
        )
        self._write_poses()
        return index

    def _write_poses(self) -> None:
        atomic_write_json(
            self.root / "poses.json",
            {"version": RECORDING_VERSION, "metadata": self.metadata, "frames": self.frames},
        )
