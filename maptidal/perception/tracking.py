"""Keypoint tracking across frames with persistent landmark ids (issue [perception]): KLT optical flow
(Kimera's choice) with a forward-backward check, refilled with new keypoints where the grid runs thin.
OpenCV and numpy only."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from maptidal.perception.stereo import StereoParams, detect_keypoints, gray_image


@dataclass(frozen=True)
class TrackerParams:
    """KLT window and pyramid, the forward-backward tolerance, and the keypoint settings for refills."""

    window_px: int = 21
    pyramid_levels: int = 3
    forward_backward_px: float = 1.0
    keypoints: StereoParams = field(default_factory=StereoParams)


def track_points(
    previous: np.ndarray, current: np.ndarray, points: np.ndarray, params: TrackerParams | None = None
):
    """Where ``points`` ``(N, 2)`` of ``previous`` are in ``current``: (new points ``(N, 2)``, ok ``(N,)``).
    A point is ok when KLT finds it both ways and comes back within ``forward_backward_px``."""
    params = params or TrackerParams()
    before, after = gray_image(previous, "previous image"), gray_image(current, "current image")
    points = np.asarray(points, np.float32).reshape(-1, 1, 2)
    if len(points) == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    window = (params.window_px, params.window_px)
    forward, ok_f, _ = cv2.calcOpticalFlowPyrLK(
        before, after, points, None, winSize=window, maxLevel=params.pyramid_levels
    )
    backward, ok_b, _ = cv2.calcOpticalFlowPyrLK(
        after, before, forward, None, winSize=window, maxLevel=params.pyramid_levels
    )
    error = np.linalg.norm(backward.reshape(-1, 2) - points.reshape(-1, 2), axis=1)
    height, width = after.shape
    new = forward.reshape(-1, 2)
    inside = (new[:, 0] >= 0) & (new[:, 0] < width) & (new[:, 1] >= 0) & (new[:, 1] < height)
    ok = (
        ok_f.ravel().astype(bool) & ok_b.ravel().astype(bool) & (error <= params.forward_backward_px) & inside
    )
    return new.astype(float), ok


class LandmarkTracker:
    """Tracks keypoints from frame to frame; each keeps its landmark id while it is tracked, and new
    keypoints (new ids) fill grid cells that have lost theirs. ``update(image)`` returns (ids, pixels,
    tracked): ``tracked`` is True for the keypoints carried over from the last frame (Fig. 4A's green)."""

    def __init__(self, params: TrackerParams | None = None) -> None:
        self.params = params or TrackerParams()
        self._image: np.ndarray | None = None
        self.ids = np.zeros(0, int)
        self.pixels = np.zeros((0, 2))
        self._next_id = 0
        self.timings = {"tracking": 0.0, "detection": 0.0}  # seconds spent so far, for benchmarks

    def update(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Track into ``image``, refill, and return (ids, pixels, tracked)."""
        gray = gray_image(image, "image")
        kp = self.params.keypoints
        start = time.perf_counter()
        if self._image is not None and len(self.pixels):
            moved, ok = track_points(self._image, gray, self.pixels, self.params)
            ids, pixels = self.ids[ok], moved[ok]
        else:
            ids, pixels = np.zeros(0, int), np.zeros((0, 2))
        tracked = np.ones(len(ids), bool)
        self.timings["tracking"] += time.perf_counter() - start
        start = time.perf_counter()
        # refill: keypoints in grid cells that hold fewer than their share
        height, width = gray.shape
        share = max(1, kp.max_keypoints // (kp.grid_rows * kp.grid_cols))
        cell_of = lambda p: (  # noqa: E731
            np.minimum((p[:, 1] * kp.grid_rows / height).astype(int), kp.grid_rows - 1) * kp.grid_cols
            + np.minimum((p[:, 0] * kp.grid_cols / width).astype(int), kp.grid_cols - 1)
        )
        counts = np.bincount(cell_of(pixels), minlength=kp.grid_rows * kp.grid_cols) if len(pixels) else None
        fresh = detect_keypoints(gray, kp)
        if len(fresh):
            if len(pixels):
                distance = np.linalg.norm(fresh[:, None, :] - pixels[None, :, :], axis=2).min(axis=1)
                fresh = fresh[distance > 5.0]  # not a keypoint already tracked
            cells = cell_of(fresh) if len(fresh) else np.zeros(0, int)
            room = np.full(kp.grid_rows * kp.grid_cols, share) - (counts if counts is not None else 0)
            chosen = []
            for index, cell in enumerate(cells):
                if room[cell] > 0:
                    chosen.append(index)
                    room[cell] -= 1
            fresh = fresh[chosen]
            new_ids = np.arange(self._next_id, self._next_id + len(fresh))
            self._next_id += len(fresh)
            ids = np.concatenate([ids, new_ids])
            pixels = np.vstack([pixels, fresh]) if len(pixels) else fresh
            tracked = np.concatenate([tracked, np.zeros(len(fresh), bool)])
        self._image, self.ids, self.pixels = gray, ids, pixels
        self.timings["detection"] += time.perf_counter() - start
        return ids.copy(), pixels.copy(), tracked
