"""Map-TIDAL task discovery on a stereo recording: the front end's keyframe meshes
(:mod:`maptidal.perception.frontend`) through discovery frame by frame
(:func:`maptidal.evaluation.comparison.discover_over_keyframes`), with the figures that say how good the map
was: the mesh error against the true surface (when the recording carries one), how it falls with the number of
observations a landmark fused, and the absolute trajectory error of the pose source (when the recording has
ground truth). No simulator: a real recording of the same shape runs the same way.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from maptidal.discovery import DiscoveryParams
from maptidal.evaluation.comparison import discover_over_keyframes
from maptidal.files import atomic_write_bytes, atomic_write_json, load_mesh, save_mesh, tasks_to_json_list
from maptidal.perception.frontend import (
    FrontEndParams,
    FrontEndRun,
    absolute_trajectory_error,
    run_frontend,
    surface_distances,
)
from maptidal.perception.recording import Recording
from maptidal.tank import TankModel

OBSERVATION_BINS = ((1, 1), (2, 3), (4, 7), (8, 15), (16, 10**9))  # fused observations per landmark


@dataclass
class FrameDiscovery:
    """What discovery on a recording gave, and the map's quality figures (None where unknown)."""

    run: FrontEndRun
    tasks: np.ndarray
    frames: list[dict]
    new_tasks: list[np.ndarray]  # per keyframe
    stages: list  # per keyframe, its DiscoveryResult (None where it was skipped)
    mesh_error_median_m: float | None
    mesh_error_by_observations: list[dict]
    ate_m: float | None
    mesh_error_p90_m: float | None = None  # the tail the median leaves out
    mesh_error_max_m: float | None = None

    def counts(self) -> dict[str, int]:
        """Discovery's stage counts summed over the keyframes (CIPs, after pruning, confirmed, final)."""
        keys = ("cips", "after_prune", "confirmed", "final")
        return {key: int(sum(frame.get(key, 0) for frame in self.frames)) for key in keys}

    def to_json(self) -> dict:
        """The ``maptidal discover-frames --json`` document."""
        return {
            "pose_source": self.run.pose_source,
            "frames": len(self.run.frames),
            "keyframes": len(self.run.keyframes),
            "keypoints_per_keyframe": [len(k.pixels) for k in self.run.keyframes],
            "mesh_faces": int(sum(len(k.keyframe.mesh.faces) for k in self.run.keyframes)),
            "mesh_error_median_m": self.mesh_error_median_m,
            "mesh_error_p90_m": self.mesh_error_p90_m,
            "mesh_error_max_m": self.mesh_error_max_m,
            "mesh_error_by_observations": self.mesh_error_by_observations,
            "ate_m": self.ate_m,
            "rejected_observations": self.run.rejected_observations,
            "counts": self.counts(),
            "per_keyframe": self.frames,
            "tasks": tasks_to_json_list(self.tasks),
        }


def true_surface(recording: Recording) -> trimesh.Trimesh | None:
    """The recording's true surface mesh (``metadata["surface"]``), or None when it has none."""
    name = recording.metadata.get("surface")
    if not name or not (recording.root / name).is_file():
        return None
    vertices, faces = load_mesh(recording.root / name)
    return trimesh.Trimesh(vertices, faces, process=False)


def discover_on_recording(
    recording: Recording,
    pose_source: str = "truth",
    frontend: FrontEndParams | None = None,
    discovery: DiscoveryParams | None = None,
    free_space_tank: TankModel | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> FrameDiscovery:
    """Run the front end over ``recording`` and discovery over its keyframes (module docstring)."""
    run = run_frontend(recording, pose_source, frontend, progress)
    start = time.perf_counter()
    outcome = discover_over_keyframes(
        run.discovery_keyframes, discovery or DiscoveryParams(), free_space_tank
    )
    run.timings["discovery"] = time.perf_counter() - start
    new_tasks, before = [], 0
    for frame in outcome.frames:
        total = frame.get("total_tasks", before)
        new_tasks.append(outcome.tasks[before:total])
        before = total
    error_median, error_p90, error_max, by_observations = None, None, None, []
    surface = true_surface(recording)
    if surface is not None and run.keyframes:
        errors = np.concatenate([surface_distances(k.keyframe.mesh.vertices, surface) for k in run.keyframes])
        observations = np.concatenate([k.observations for k in run.keyframes])
        if len(errors):
            error_median = float(np.median(errors))
            error_p90, error_max = float(np.percentile(errors, 90)), float(errors.max())
        for low, high in OBSERVATION_BINS:
            members = (observations >= low) & (observations <= high)
            if members.any():
                by_observations.append(
                    {
                        "observations": f"{low}"
                        if low == high
                        else (f"{low}+" if high > 10**6 else f"{low}-{high}"),
                        "vertices": int(members.sum()),
                        "median_error_m": float(np.median(errors[members])),
                    }
                )
    ate = None
    if "truth" in recording.pose_sources():
        truth = [recording.frames[n].poses["truth"] for n in range(len(run.frames))]
        ate = absolute_trajectory_error([record.pose for record in run.frames], truth)
    return FrameDiscovery(
        run,
        outcome.tasks,
        outcome.frames,
        new_tasks,
        outcome.results,
        error_median,
        by_observations,
        ate,
        error_p90,
        error_max,
    )


def write_outputs(
    result: FrameDiscovery, recording: Recording, out_dir: str | Path, overlays: bool = True
) -> Path:
    """Write the keyframe meshes (``keyframe_NN.ply``), the tasks (``tasks.json``, the ``maptidal
    discover`` format), the summary (``frames.json``) and, with ``overlays``, one Fig. 4-style PNG per
    keyframe (``keyframe_NN.png``); each file atomically. Returns ``out_dir``."""
    import cv2

    from maptidal.perception.overlays import keyframe_overlay

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    earlier = np.zeros((0, 6))
    keyframes = zip(result.run.keyframes, result.new_tasks, result.stages, strict=False)
    for number, (output, new, stages) in enumerate(keyframes):
        mesh = output.keyframe.mesh
        if len(mesh.faces):
            save_mesh(out / f"keyframe_{number:02d}.ply", mesh.vertices, mesh.faces)
        if overlays:
            frame = next(f for f in recording.frames if f.index == output.frame_index)
            left, _ = recording.images(frame)
            panel = keyframe_overlay(
                left,
                output.pixels,
                output.tracked,
                mesh.vertices,
                mesh.faces,
                new,
                earlier,
                output.pose,
                recording.intrinsics,
                stages,
            )
            ok, encoded = cv2.imencode(".png", cv2.cvtColor(panel, cv2.COLOR_RGB2BGR))
            if ok:
                atomic_write_bytes(out / f"keyframe_{number:02d}.png", encoded.tobytes())
        earlier = np.vstack([earlier, new])
    atomic_write_json(out / "tasks.json", {"tasks": tasks_to_json_list(result.tasks)})
    atomic_write_json(out / "frames.json", result.to_json())
    return out
