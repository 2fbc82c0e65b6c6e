"""A mission's video (``maptidal run --video``): frames from a camera behind the team, each robot's latest
view inset with its name, and the time, the tasks and the share inspected written on."""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from maptidal.envs.views import overview_camera, third_person_frame


class VideoSettings(Protocol):
    """What the video takes of a mission's settings (``maptidal.mission.run.MissionParams`` has it)."""

    video_size: tuple[int, int]
    video_frames_per_sim_s: float
    video_playback_fps: float


class FilmedMission(Protocol):
    """What the video reads of a running mission (``maptidal.mission.run.Mission`` has it): named here
    rather than imported, so that this module does not depend on the loop that uses it."""

    sim: Any
    writer: Any
    robots: dict
    intrinsics: Any
    tasks: dict
    # the executor the mission's cameras are drawn on: the video draws there too, never beside them
    drawing: Any

    def inspected_pct(self) -> float: ...


class MissionVideo:
    """``mission.mp4``: a camera behind the team (looking at the live robots' centroid) with each robot's
    latest left image inset and the time and task counts written on; written to ``mission.part.mp4``
    and renamed when the mission ends, so a killed mission leaves no file that looks whole."""

    def __init__(self, mission: FilmedMission, params: VideoSettings) -> None:
        import cv2
        import mujoco

        self.mission = mission
        self.every_s = 1.0 / params.video_frames_per_sim_s
        self.next_s = 0.0
        width, height = params.video_size
        # all of the mission's drawing is on its one drawing thread: a second thread drawing at the same
        # time as the cameras crashed Mesa's EGL (a segmentation fault in a test run with two workers)
        self.renderer = mission.drawing.submit(mujoco.Renderer, mission.sim.model, height, width).result()
        self.path = mission.writer.root / "mission.mp4"
        self.partial = self.path.with_name("mission.part.mp4")  # OpenCV picks the container by extension
        self.writer = cv2.VideoWriter(
            str(self.partial), cv2.VideoWriter_fourcc(*"mp4v"), params.video_playback_fps, (width, height)
        )
        if not self.writer.isOpened():
            mission.drawing.submit(self.renderer.close).result()
            raise RuntimeError("this OpenCV build cannot write MP4 (mp4v) video")
        self.frames = 0
        self.closed = False

    def frame_due(self, now: float) -> None:
        """Write a frame if one is due at ``now``."""
        if now < self.next_s - 1e-9:
            return
        import cv2

        self.next_s += self.every_s
        mission = self.mission
        names = list(mission.robots)
        live = [r.name for r in mission.robots.values() if r.active] or names
        centre = np.mean([mission.sim.ground_truth(name)["position"] for name in live], axis=0)
        blank = np.zeros((mission.intrinsics.height, mission.intrinsics.width, 3), np.uint8)
        insets = {r.name: r.last_left if r.last_left is not None else blank for r in mission.robots.values()}
        # drawn on the drawing thread while this one waits: the physics holds still meanwhile
        frame = mission.drawing.submit(
            third_person_frame,
            mission.sim,
            self.renderer,
            names,
            overview_camera(centre),
            insets,
            labels=True,
        ).result()
        done = sum(1 for t in mission.tasks.values() if t["completed"])
        inspected = mission.inspected_pct()
        text = f"t = {now:5.1f} s   tasks {done}/{len(mission.tasks)} done   {inspected:.0f} % inspected"
        bgr = cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)
        cv2.putText(bgr, text, (8, bgr.shape[0] - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
        self.writer.write(bgr)
        self.frames += 1

    def close(self) -> None:
        """Finish the file and give it its name."""
        self.writer.release()
        self.mission.drawing.submit(self.renderer.close).result()
        self.partial.replace(self.path)
        self.closed = True

    def abandon(self) -> None:
        """For a mission that ended early (interrupted, or failed): finish the file so that it plays, but
        keep its partial name, and free the renderer now (left to the garbage collector, it would be
        freed after EGL has shut down, with a traceback)."""
        if self.closed:
            return
        self.writer.release()
        self.mission.drawing.submit(self.renderer.close).result()
        self.closed = True
