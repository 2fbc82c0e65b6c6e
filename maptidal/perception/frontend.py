"""The stereo front end, frame by frame: from a recording's images and poses to Kimera-style keyframe meshes
(issue [perception]). OpenCV, numpy and trimesh only: it reads a recording folder
(:mod:`maptidal.perception.recording`), never the simulator, so a real OAK-D recording runs the same way.

Each frame:

1. **Track** the left image's keypoints from the last frame with KLT, refilling thin grid cells
   (:class:`~maptidal.perception.tracking.LandmarkTracker`): a keypoint keeps its landmark id while it is
   tracked (Fig. 4A's green), new ones get new ids (red).
2. **Match** each keypoint along its row in the right image and **triangulate** it
   (:mod:`~maptidal.perception.stereo`), inside the depth band.
3. **Localise** the camera by the chosen pose source: ``truth``, ``dr`` (the robot's dead reckoning,
   recorded beside the images) or ``vo`` (dead reckoning corrected by frame-to-frame PnP on the tracked
   landmarks, :mod:`~maptidal.perception.odometry`, and relocalised against the robot's own map of
   anchors, :mod:`~maptidal.perception.relocalisation`).
4. **Fuse** the observations into world-frame landmarks, weighted by their stereo covariance, outliers
   rejected (:mod:`~maptidal.perception.landmarks`).
5. At a **keyframe** (:mod:`~maptidal.perception.keyframing`), mesh the keypoints matched in this frame at
   their fused landmark positions with :func:`maptidal.perception.mesher.kimera_mesh`, ready for
   discovery.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import trimesh

from maptidal.geometry import point_triangle_distances
from maptidal.keyframes import Keyframe
from maptidal.perception.dense import DenseDepthParams
from maptidal.perception.keyframing import KeyframeParams, KeyframeSelector
from maptidal.perception.landmarks import FusionParams, LandmarkMap, stereo_covariances
from maptidal.perception.mesher import MesherParams, kimera_mesh
from maptidal.perception.odometry import OdometryParams, VisualOdometry, relative_motion
from maptidal.perception.recording import CameraIntrinsics, CameraPose, Recording, RecordingError
from maptidal.perception.relocalisation import AnchorMap, RelocalisationParams, describe, project
from maptidal.perception.stereo import (
    FrontEndInputError,
    StereoParams,
    gray_image,
    match_stereo,
    triangulate,
)
from maptidal.perception.tracking import LandmarkTracker, TrackerParams

POSE_SOURCES = ("truth", "dr", "vo")


@dataclass(frozen=True)
class FrontEndParams:
    """Every stage's settings; ``max_keyframes`` stops after that many keyframes (the paper used its
    first 7)."""

    stereo: StereoParams = field(default_factory=StereoParams)
    tracker: TrackerParams = field(default_factory=TrackerParams)
    fusion: FusionParams = field(default_factory=FusionParams)
    keyframes: KeyframeParams = field(default_factory=KeyframeParams)
    mesher: MesherParams = field(default_factory=MesherParams)
    odometry: OdometryParams = field(default_factory=OdometryParams)
    relocalisation: RelocalisationParams = field(default_factory=RelocalisationParams)
    # the keyframes' dense stereo depth, for a robot's map (maptidal.perception.dense)
    dense: DenseDepthParams = field(default_factory=DenseDepthParams)
    max_keyframes: int | None = None
    # start each keypoint's KLT search where the camera's motion since the last frame (the pose source's:
    # attitude and dead reckoning) puts it (maptidal.perception.tracking.track_points). Unaided, the robot
    # without a DVL kept a median of 1 to 5 of 25 to 40 keypoints through a frame turning 5 to 14 deg,
    # and its visual odometry failed on 80 % of frames (tests/bench/diag_localisation.py, session 17)
    predict_tracks: bool = True


@dataclass
class FrameRecord:
    """What one frame gave: keypoints (and how many were tracked from the last frame), stereo matches,
    PnP inliers (vo only), the pose used, and whether it became a keyframe."""

    index: int
    time_s: float
    keypoints: int
    tracked: int
    matched: int
    pnp_inliers: int | None
    pose: CameraPose
    keyframe: bool = False
    relocalised: bool = False  # vo only: the pose was fixed against the anchor map this frame


@dataclass
class KeyframeOutput:
    """A keyframe for discovery (:class:`maptidal.keyframes.Keyframe`) and what its overlays show: the
    frame it came from and the pose used there, its keypoints (pixels), which were tracked, and the
    observations per vertex."""

    keyframe: Keyframe
    frame_index: int
    pose: CameraPose
    pixels: np.ndarray
    tracked: np.ndarray
    observations: np.ndarray


class FrontEnd:
    """Runs the module's five steps on one frame at a time (:meth:`process`)."""

    def __init__(
        self, intrinsics: CameraIntrinsics, pose_source: str = "truth", params: FrontEndParams | None = None
    ):
        if pose_source not in POSE_SOURCES:
            raise ValueError(f"pose source must be one of {POSE_SOURCES}, got {pose_source!r}")
        self.intrinsics = intrinsics
        self.pose_source = pose_source
        self.params = params or FrontEndParams()
        # the tracker refills with the stereo front end's own detector settings
        tracker = dataclasses.replace(self.params.tracker, keypoints=self.params.stereo)
        self.tracker = LandmarkTracker(tracker)
        self.landmarks = LandmarkMap(self.params.fusion)
        self.selector = KeyframeSelector(self.params.keyframes)
        self.odometry = VisualOdometry(self.params.odometry)
        self.anchors = AnchorMap(intrinsics, self.params.relocalisation)
        self._jumps_seen = 0
        self._last_time_s: float | None = None
        self._previous_points: dict[int, np.ndarray] = {}
        self._previous_pose: CameraPose | None = None
        self.keyframes_made = 0
        self._stage_s = dict.fromkeys(("matching", "triangulation", "localisation", "fusion", "meshing"), 0.0)

    def _predictor(self, pose: CameraPose):
        """Where the camera's motion from the last frame's pose to ``pose`` puts the last frame's keypoints
        (``predict_tracks``): each stereo point moved rigidly and projected; a keypoint without one at the
        median depth of those with one (2 m when there are none). None on the first frame."""
        previous = self._previous_pose
        if not self.params.predict_tracks or previous is None:
            return None
        k = self.intrinsics
        known = self._previous_points

        def predict(ids: np.ndarray, pixels: np.ndarray) -> np.ndarray:
            depths = [point[2] for point in known.values() if point[2] > 0]
            depth = float(np.median(depths)) if depths else 2.0
            pixels = np.asarray(pixels, float)
            points = np.column_stack(
                [
                    (pixels[:, 0] - k.cx) / k.fx * depth,
                    (pixels[:, 1] - k.cy) / k.fy * depth,
                    np.full(len(pixels), depth),
                ]
            )
            for row, landmark in enumerate(ids):
                point = known.get(int(landmark))
                if point is not None and point[2] > 0:
                    points[row] = point
            guess, depth_now = project(previous.to_world(points), pose.position, pose.rotation, k)
            return np.where((depth_now > 0.05)[:, None], guess, pixels)  # behind the camera: as it was

        return predict

    @property
    def timings(self) -> dict[str, float]:
        """Seconds spent so far in each stage (tracking, detection, matching, triangulation,
        localisation, fusion, meshing), for benchmarks."""
        return {**self.tracker.timings, **self._stage_s}

    def process(
        self,
        index: int,
        time_s: float,
        left: np.ndarray,
        right: np.ndarray,
        pose: CameraPose,
        unaided_s: float = 0.0,
        unmodelled_m: float = 0.0,
    ) -> tuple[FrameRecord, KeyframeOutput | None]:
        """One frame; ``pose`` is the source's pose (for ``vo``, the dead-reckoned one it corrects),
        ``unaided_s`` how long since the last frame the dead reckoning ran without its DVL, and
        ``unmodelled_m`` how far it may have moved since then that its motion model did not say
        (:meth:`maptidal.perception.odometry.VisualOdometry.update`)."""
        k = self.intrinsics
        clock = self._stage_s
        ids, pixels, tracked = self.tracker.update(left, self._predictor(pose))
        self._previous_pose = pose  # the source's pose, before the front end corrects it
        start = time.perf_counter()
        disparity = match_stereo(left, right, pixels, self.params.stereo)
        clock["matching"] += time.perf_counter() - start
        start = time.perf_counter()
        points_camera, kept = triangulate(
            pixels, disparity, k.fx, k.fy, k.cx, k.cy, k.baseline_m, self.params.stereo
        )
        clock["triangulation"] += time.perf_counter() - start
        start = time.perf_counter()
        inliers, relocalised = None, False
        if self.pose_source == "vo":
            common = [row for row in np.flatnonzero(tracked) if int(ids[row]) in self._previous_points]
            motion = None
            if common:
                previous = np.array([self._previous_points[int(ids[row])] for row in common])
                motion = relative_motion(previous, pixels[common], k.matrix, self.params.odometry)
                inliers = 0 if motion is None else motion[2]
            dt = time_s - self._last_time_s if self._last_time_s is not None else 0.0
            pose = self.odometry.update(pose, motion, dt, unaided_s, unmodelled_m)
            # with a DVL too: over 1200 s of the default mission, seeds 0 to 2, the DVL robot was 1.7 to 3.0
            # cm off (median) with relocalisation and 2.4 to 9.4 cm on its DVL alone (session 15)
            if self.params.relocalisation.enabled:
                pose, relocalised = self._relocalise(left, pixels, points_camera, kept, pose)
        self._previous_points = {int(ids[row]): points_camera[n] for n, row in enumerate(kept)}
        self._last_time_s = time_s
        clock["localisation"] += time.perf_counter() - start
        start = time.perf_counter()
        covariances = stereo_covariances(points_camera, disparity[kept], k.fx, self.params.fusion)
        world = pose.to_world(points_camera)
        world_covariances = pose.rotation @ covariances @ pose.rotation.T
        if self.pose_source != "truth":
            world_covariances = world_covariances + self.params.fusion.pose_sigma_m**2 * np.eye(3)
        if self.params.fusion.enabled:
            self.landmarks.add(ids[kept], world, world_covariances)
        clock["fusion"] += time.perf_counter() - start
        record = FrameRecord(index, time_s, len(ids), int(tracked.sum()), len(kept), inliers, pose)
        record.relocalised = relocalised
        limit = self.params.max_keyframes
        if limit is not None and self.keyframes_made >= limit:
            return record, None
        if not self.selector.is_keyframe(time_s, pose):
            return record, None
        record.keyframe = True
        start = time.perf_counter()
        landmarks = np.full((len(ids), 3), np.nan)
        if self.params.fusion.enabled:
            landmarks[kept] = self.landmarks.positions(ids[kept])
        else:
            landmarks[kept] = world
        mesh = kimera_mesh(
            pixels, landmarks, (k.width, k.height), pose.position, pose.forward, self.params.mesher
        )
        keyframe = Keyframe(pose.position, pose.forward, pixels, landmarks, ids, mesh)
        observations = (
            self.landmarks.observations(ids[mesh.keypoint_ids])
            if len(mesh.keypoint_ids)
            else np.zeros(0, int)
        )
        self.keyframes_made += 1
        clock["meshing"] += time.perf_counter() - start
        return record, KeyframeOutput(keyframe, index, pose, pixels, tracked, observations)

    def _relocalise(
        self,
        left: np.ndarray,
        pixels: np.ndarray,
        points_camera: np.ndarray,
        kept: np.ndarray,
        pose: CameraPose,
    ) -> tuple[CameraPose, bool]:
        """Fix ``pose`` against the anchor map where it can, then make anchors of this frame's unmatched
        stereo points (a frame whose fix was refused for jumping too far makes none: its pose, or its
        matches, are wrong)."""
        points = np.full((len(pixels), 3), np.nan)
        points[kept] = points_camera
        descriptors, valid = describe(
            gray_image(left, "left image"),
            pixels,
            points[:, 2],
            self.intrinsics,
            self.params.relocalisation.support_m,
        )
        gated = self.anchors.refused["gate"]
        fix, matched = self.anchors.relocalise(pose, pixels, descriptors, valid, self.odometry.sigma_m)
        if self.anchors.refused["gate"] > gated:
            self.odometry.surprised()  # the prediction, or the fix, is off by more than it allowed
        if fix is not None:
            pose = self.odometry.correct(fix.centre, fix.sigma_m)
        jumped = self.anchors.refused["jump"]
        usable = valid & np.isfinite(points).all(axis=1)
        usable[matched] = False
        sure = self.odometry.sigma_m <= self.params.relocalisation.max_anchor_sigma_m
        if sure and (fix is not None or jumped == self._jumps_seen):
            self.anchors.add(pose, pixels, points, descriptors, usable, self.odometry.sigma_m)
        self._jumps_seen = jumped
        return pose, fix is not None


@dataclass
class FrontEndRun:
    """A whole recording through the front end: per-frame records and the keyframes."""

    pose_source: str
    frames: list[FrameRecord]
    keyframes: list[KeyframeOutput]
    rejected_observations: int
    timings: dict[str, float] = field(default_factory=dict)  # seconds per stage (FrontEnd.timings)

    @property
    def discovery_keyframes(self) -> list[Keyframe]:
        """The keyframes as :func:`maptidal.evaluation.comparison.discover_over_keyframes` takes them."""
        return [output.keyframe for output in self.keyframes]


def run_frontend(
    recording: Recording,
    pose_source: str = "truth",
    params: FrontEndParams | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> FrontEndRun:
    """Run the front end over every frame of ``recording`` (stopping after ``max_keyframes``). The ``dr``
    and ``vo`` sources need the recording's ``dr`` poses (or a real vehicle's ``estimate``)."""
    if pose_source not in POSE_SOURCES:
        raise ValueError(f"pose source must be one of {POSE_SOURCES}, got {pose_source!r}")
    available = recording.pose_sources()
    wanted = "truth" if pose_source == "truth" else ("dr" if "dr" in available else "estimate")
    if wanted not in available:
        hint = ""
        if pose_source == "truth" and available & {"dr", "estimate"}:
            hint = " (a real vehicle's recording has no ground truth: use --pose dr or --pose vo)"
        raise RecordingError(
            f"{recording.root}: --pose {pose_source} needs {wanted!r} poses in every frame; "
            f"it has {sorted(available)}{hint}"
        )
    params = params or FrontEndParams()
    sensors = recording.metadata.get("sensors")
    if isinstance(sensors, list) and "dvl" not in sensors and params.odometry.has_dvl:
        # the robot had no DVL: its dead reckoning's horizontal motion is model-aided where the recording
        # says so (the simulator's, from `maptidal capture`), and otherwise taken to be nothing
        model_aided = recording.metadata.get("dead_reckoning") == "model-aided" and wanted == "dr"
        odometry = dataclasses.replace(params.odometry, has_dvl=False, model_aided=model_aided)
        params = dataclasses.replace(params, odometry=odometry)
    front = FrontEnd(recording.intrinsics, pose_source, params)
    frames, keyframes = [], []
    for n, frame in enumerate(recording.frames):
        left, right = recording.images(frame)
        record, keyframe = front.process(frame.index, frame.time_s, left, right, frame.poses[wanted])
        frames.append(record)
        if keyframe is not None:
            keyframes.append(keyframe)
        if progress is not None:
            progress(n + 1, len(recording.frames))
        if params.max_keyframes is not None and len(keyframes) >= params.max_keyframes:
            if progress is not None:
                progress(len(recording.frames), len(recording.frames))  # the rest is not needed
            break
    if not any(record.keypoints for record in frames):
        raise FrontEndInputError(
            f"{recording.root}: no keypoints in any frame (textureless or blurred images?)"
        )
    return FrontEndRun(pose_source, frames, keyframes, front.landmarks.rejected, front.timings)


def absolute_trajectory_error(estimated: list[CameraPose], truth: list[CameraPose]) -> float:
    """RMS position error (m) of an estimated trajectory against the truth, frame by frame. No alignment:
    every estimate starts at the true pose, as the robot's estimator does when it is armed at a known
    spot, so the error is the drift itself."""
    if len(estimated) != len(truth) or not estimated:
        raise ValueError("the trajectories must be non-empty and of the same length")
    errors = [np.linalg.norm(e.position - t.position) for e, t in zip(estimated, truth, strict=True)]
    return float(np.sqrt(np.mean(np.square(errors))))


def surface_distances(points: np.ndarray, surface: trimesh.Trimesh) -> np.ndarray:
    """Distance (m) from each point ``(N, 3)`` to the nearest point of ``surface``."""
    return point_triangle_distances(points, surface.triangles)
