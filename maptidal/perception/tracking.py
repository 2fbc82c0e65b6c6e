"""Keypoint tracking across frames with persistent landmark ids (issue [perception]): KLT optical flow
(Kimera's choice) with a forward-backward check, refilled with new keypoints where the grid runs thin.
OpenCV and numpy only."""

from __future__ import annotations

import time
from collections.abc import Callable
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
    # a track started from a prediction must also look like where it came from: the zero-mean normalised
    # cross-correlation of the two patches (patch_px square) at least min_correlation. The backward check
    # alone cannot tell: it starts at the old pixel, so a wrong patch found forward can come back true
    patch_px: int = 11
    min_correlation: float = 0.9
    keypoints: StereoParams = field(default_factory=StereoParams)


def track_points(
    previous: np.ndarray,
    current: np.ndarray,
    points: np.ndarray,
    params: TrackerParams | None = None,
    predicted: np.ndarray | None = None,
):
    """Where ``points`` ``(N, 2)`` of ``previous`` are in ``current``: (new points ``(N, 2)``, ok ``(N,)``).
    A point is ok when KLT finds it both ways and comes back within ``forward_backward_px``.

    ``predicted`` ``(N, 2)``, where the camera's own motion says each point will be (from the vehicle's
    attitude and dead reckoning, :meth:`LandmarkTracker.update`), starts KLT's search there instead of
    at the old pixel, as inertial-aided trackers do: a turn of 10 deg moves the image some 40 px at the
    mission's 320 px, about what KLT's pyramid reaches unaided, and the prediction leaves it a few px."""
    params = params or TrackerParams()
    before, after = gray_image(previous, "previous image"), gray_image(current, "current image")
    points = np.asarray(points, np.float32).reshape(-1, 1, 2)
    if len(points) == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    window = (params.window_px, params.window_px)
    height, width = after.shape
    guess = None
    if predicted is not None:
        guess = np.asarray(predicted, np.float32).reshape(-1, 1, 2)
        if guess.shape != points.shape or not np.all(np.isfinite(guess)):
            raise ValueError(f"predicted pixels must be finite and one per point {points.shape[:1]}")
        guess[..., 0] = np.clip(guess[..., 0], 0, width - 1)
        guess[..., 1] = np.clip(guess[..., 1], 0, height - 1)

    def klt(source, target, start, initial):
        # KLT from ``start`` in ``source`` to ``target``, its search begun at ``initial`` when given
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW if initial is not None else 0
        initial = None if initial is None else initial.copy()
        return cv2.calcOpticalFlowPyrLK(
            source, target, start, initial, winSize=window, maxLevel=params.pyramid_levels, flags=flags
        )

    forward, ok_f, _ = klt(before, after, points, guess)
    # back from where it was found; with a prediction, searching from the old pixel
    backward, ok_b, _ = klt(after, before, forward, None if guess is None else points)
    error = np.linalg.norm(backward.reshape(-1, 2) - points.reshape(-1, 2), axis=1)
    new = forward.reshape(-1, 2)
    inside = (new[:, 0] >= 0) & (new[:, 0] < width) & (new[:, 1] >= 0) & (new[:, 1] < height)
    ok = (
        ok_f.ravel().astype(bool) & ok_b.ravel().astype(bool) & (error <= params.forward_backward_px) & inside
    )
    if predicted is not None:
        candidates = np.flatnonzero(ok)
        similar = patch_correlation(before, after, points.reshape(-1, 2)[candidates], new[candidates], params)
        ok[candidates[similar < params.min_correlation]] = False
    return new.astype(float), ok


def patch_correlation(
    before: np.ndarray, after: np.ndarray, old: np.ndarray, new: np.ndarray, params: TrackerParams
) -> np.ndarray:
    """The zero-mean normalised cross-correlation of each ``patch_px`` square patch of ``before`` about
    ``old`` with that of ``after`` about ``new`` (sub-pixel centres; 0 for a flat patch)."""
    size = (params.patch_px, params.patch_px)
    out = np.zeros(len(old))
    for k, (a, b) in enumerate(zip(old, new, strict=True)):
        first = cv2.getRectSubPix(before, size, (float(a[0]), float(a[1]))).astype(np.float64).ravel()
        second = cv2.getRectSubPix(after, size, (float(b[0]), float(b[1]))).astype(np.float64).ravel()
        first, second = first - first.mean(), second - second.mean()
        norm = np.sqrt((first @ first) * (second @ second))
        out[k] = float(first @ second / norm) if norm > 0 else 0.0
    return out


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

    def update(
        self, image: np.ndarray, predict: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Track into ``image``, refill, and return (ids, pixels, tracked). ``predict(ids, pixels)``, when
        given, says where the camera's motion puts the last frame's keypoints in this one (``(N, 2)``;
        see :func:`track_points`)."""
        gray = gray_image(image, "image")
        kp = self.params.keypoints
        start = time.perf_counter()
        if self._image is not None and len(self.pixels):
            guess = predict(self.ids, self.pixels) if predict is not None else None
            moved, ok = track_points(self._image, gray, self.pixels, self.params, guess)
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
