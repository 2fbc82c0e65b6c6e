"""The stereo front end's first stages: keypoints on the left image, matches along the rectified row,
and triangulation (issue [perception]). OpenCV and numpy only; it takes images and intrinsics, never the
simulator, so it runs unchanged on real OAK-D recordings.

- **Keypoints**: ORB (default), FAST, GFTT (Shi-Tomasi, Kimera's choice) or SIFT, spread over a grid of
  cells (bucketing: each cell keeps its strongest responses), capped at ``max_keypoints``.
- **Matching**: the pair is rectified, so a left keypoint's match lies on the same row of the right
  image, ``disparity`` pixels to the left. For each keypoint a ``patch x patch`` window is compared by
  the sum of squared differences (TM_SQDIFF, exact in integers, every keypoint at once) at every
  disparity in the range;
  the best must beat the second best outside its neighbours by the ``ratio``; a left-right check
  matches the right window back along the row and must land within ``lr_tolerance_px`` of the
  keypoint; a parabola through the costs at the best disparity and its neighbours gives the sub-pixel
  disparity.
- **Triangulation**: ``Z = f_x b / d``, ``X = (u - c_x) Z / f_x``, ``Y = (v - c_y) Z / f_y`` in the left
  camera's frame (x right, y down, z forward), kept within the depth band (default 0.3 to 4 m).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

DETECTORS = ("orb", "fast", "gftt", "sift")


class FrontEndInputError(ValueError):
    """Images the front end cannot use: the message names the problem (size, type, emptiness)."""


@dataclass(frozen=True)
class StereoParams:
    """Detector, bucketing, matching and depth-band settings of the stereo front end."""

    detector: str = "orb"
    max_keypoints: int = 400
    grid_rows: int = 4
    grid_cols: int = 6
    min_disparity_px: int = 1
    max_disparity_px: int = 96  # 0.31 m at f = 392 px and b = 7.5 cm
    patch: int = 9
    ratio: float = 0.85
    lr_tolerance_px: float = 1.0
    min_depth_m: float = 0.3
    max_depth_m: float = 4.0

    def __post_init__(self) -> None:
        if self.detector not in DETECTORS:
            raise ValueError(f"detector must be one of {DETECTORS}, got {self.detector!r}")
        if not (self.patch >= 3 and self.patch % 2 == 1):
            raise ValueError(f"patch must be an odd size of at least 3 px, got {self.patch}")
        if not (0 <= self.min_disparity_px < self.max_disparity_px):
            raise ValueError("need 0 <= min_disparity_px < max_disparity_px")
        if not (0 < self.ratio <= 1):
            raise ValueError(f"ratio must be in (0, 1], got {self.ratio}")


def gray_image(image: np.ndarray, name: str) -> np.ndarray:
    """``image`` as 8-bit grey, or :class:`FrontEndInputError` naming ``name`` and the problem."""
    array = np.asarray(image)
    if array.ndim == 3 and array.shape[2] == 3:
        array = cv2.cvtColor(array.astype(np.uint8), cv2.COLOR_RGB2GRAY)
    if array.ndim != 2 or array.size == 0:
        raise FrontEndInputError(f"{name} must be an (H, W) or (H, W, 3) image, got shape {array.shape}")
    if array.dtype != np.uint8:
        raise FrontEndInputError(f"{name} must be 8-bit, got {array.dtype}")
    return array


def detect_keypoints(image: np.ndarray, params: StereoParams | None = None) -> np.ndarray:
    """Keypoints ``(N, 2)`` (u, v pixels) on ``image``, bucketed over the grid, strongest first per cell."""
    params = params or StereoParams()
    gray = gray_image(image, "image")
    height, width = gray.shape
    margin = params.patch  # keep the matching windows inside the image
    if params.detector == "gftt":
        corners = cv2.goodFeaturesToTrack(gray, params.max_keypoints * 4, 0.01, 5, blockSize=7)
        points = np.zeros((0, 2)) if corners is None else corners.reshape(-1, 2)
        responses = -np.arange(len(points), dtype=float)  # returned strongest first
    else:
        detector = {
            "orb": lambda: cv2.ORB_create(
                nfeatures=params.max_keypoints * 4, edgeThreshold=margin, patchSize=margin
            ),
            "fast": lambda: cv2.FastFeatureDetector_create(threshold=10),
            "sift": lambda: cv2.SIFT_create(nfeatures=params.max_keypoints * 4),
        }[params.detector]()
        found = detector.detect(gray, None)
        points = np.array([k.pt for k in found], float).reshape(-1, 2)
        responses = np.array([k.response for k in found], float)
    inside = (
        (points[:, 0] >= margin)
        & (points[:, 0] < width - margin)
        & (points[:, 1] >= margin)
        & (points[:, 1] < height - margin)
    )
    points, responses = points[inside], responses[inside]
    per_cell = max(1, params.max_keypoints // (params.grid_rows * params.grid_cols))
    rows = np.minimum((points[:, 1] * params.grid_rows / height).astype(int), params.grid_rows - 1)
    cols = np.minimum((points[:, 0] * params.grid_cols / width).astype(int), params.grid_cols - 1)
    kept = []
    for cell in np.unique(rows * params.grid_cols + cols):
        members = np.flatnonzero(rows * params.grid_cols + cols == cell)
        kept.extend(members[np.argsort(-responses[members])][:per_cell].tolist())
    return points[np.array(sorted(kept), int)] if kept else np.zeros((0, 2))


def _row_windows(padded: np.ndarray, pad: int, rows: np.ndarray, starts: np.ndarray, half: int, count: int):
    """``(N, patch, count + 2 half)`` strips of an image padded by ``pad`` columns on each side: for
    keypoint n, the patch's rows around ``rows[n]`` and the columns from ``starts[n] - half`` on."""
    patch = 2 * half + 1
    windows = np.lib.stride_tricks.sliding_window_view(padded, (patch, count + 2 * half))
    return windows[rows - half, starts - half + pad]


def _ssd_along(templates: np.ndarray, strips: np.ndarray) -> np.ndarray:
    """``(N, K)`` sums of squared differences of each ``(patch, patch)`` template at the K column
    offsets of its strip. Exact: the terms are whole numbers, and float32 adds them without rounding
    while every partial sum stays below 2^24 (patches up to 15 px: 225 x 255^2); larger patches are
    summed in float64."""
    patch = templates.shape[2]
    count = strips.shape[2] - patch + 1
    exact = np.float32 if patch * patch * 255**2 < 2**24 else np.float64
    templates, strips = templates.astype(exact, copy=False), strips.astype(exact, copy=False)
    costs = np.zeros((len(strips), count), exact)
    for column in range(patch):  # one template column against every offset at once
        difference = strips[:, :, column : column + count] - templates[:, :, column : column + 1]
        costs += np.einsum("nrk,nrk->nk", difference, difference)
    return costs


def match_stereo(
    left: np.ndarray, right: np.ndarray, keypoints: np.ndarray, params: StereoParams | None = None
) -> np.ndarray:
    """Sub-pixel disparity (px) of each left keypoint in the right image; NaN where the match is
    ambiguous (ratio test), inconsistent (left-right check) or off the image.

    Every keypoint is matched at once: the costs at each disparity are exact integer sums of squared
    differences, the same numbers as ``cv2.matchTemplate(..., TM_SQDIFF)`` per keypoint, which a test
    checks against that literal loop."""
    params = params or StereoParams()
    left_gray, right_gray = gray_image(left, "left image"), gray_image(right, "right image")
    if left_gray.shape != right_gray.shape:
        raise FrontEndInputError(
            f"left and right images differ in size: {left_gray.shape} and {right_gray.shape}"
        )
    half = params.patch // 2
    height, width = left_gray.shape
    points = np.asarray(keypoints, float).reshape(-1, 2)
    out = np.full(len(points), np.nan)
    if not len(points):
        return out
    # Python's round (half to even), as the per-keypoint matcher did
    u_all = np.rint(points[:, 0]).astype(int)
    v_all = np.rint(points[:, 1]).astype(int)
    lowest, highest = params.min_disparity_px, params.max_disparity_px
    # a keypoint's disparities run from the minimum to as far as its window stays in the right image
    top = np.minimum(highest, u_all - half)
    usable = (
        (half <= v_all) & (v_all < height - half) & (half <= u_all) & (u_all < width - half) & (top >= lowest)
    )
    index = np.flatnonzero(usable)
    if not len(index):
        return out
    u, v, top = u_all[index], v_all[index], top[index]
    count = highest - lowest + 1
    pad = highest + params.patch  # every window lies inside the padded images
    left_p, right_p = (
        np.pad(image.astype(np.float32), ((0, 0), (pad, pad))) for image in (left_gray, right_gray)
    )
    templates = _row_windows(left_p, pad, v, u, half, 1)  # count 1: the patch itself
    # candidate right positions x = u - d for d = highest .. lowest, left to right
    costs = _ssd_along(templates, _row_windows(right_p, pad, v, u - highest, half, count)).astype(float)
    costs = costs[:, ::-1]  # d increasing from the minimum
    disparities = lowest + np.arange(count)
    costs[disparities[None, :] > top[:, None]] = np.inf  # windows off the image's left edge
    best = np.argmin(costs, axis=1)
    rows = np.arange(len(index))
    best_cost = costs[rows, best]
    # the ratio test: better than every candidate outside the best's neighbours (ties are ambiguous)
    near_best = np.abs(np.arange(count)[None, :] - best[:, None]) <= 1
    others = np.where(near_best, np.inf, costs).min(axis=1)
    clear = ~np.isfinite(others) | (best_cost < params.ratio * others)
    d = disparities[best]
    # left-right check: the right window's best match back along the left row
    x = u - d
    back_count = highest + 1
    back = _ssd_along(
        _row_windows(right_p, pad, v, x, half, 1),
        _row_windows(left_p, pad, v, x, half, back_count),
    ).astype(float)
    back_high = np.minimum(width - 1 - half, x + highest)
    back[np.arange(back_count)[None, :] > (back_high - x)[:, None]] = np.inf
    consistent = np.abs(np.argmin(back, axis=1) - d) <= params.lr_tolerance_px
    # a parabola through the best cost and its neighbours
    inner = (best > 0) & (best < top - lowest)
    before = costs[rows, np.maximum(best - 1, 0)]
    after = costs[rows, np.minimum(best + 1, count - 1)]
    denominator = np.where(inner, before - 2 * best_cost + after, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        offset = np.where(denominator > 0, 0.5 * (before - after) / denominator, 0.0)
    matched = clear & consistent
    out[index[matched]] = d[matched] + np.clip(offset[matched], -0.5, 0.5)
    return out


def triangulate(
    keypoints: np.ndarray,
    disparity: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    baseline_m: float,
    params: StereoParams | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points ``(M, 3)`` (x right, y down, z forward) of the matched keypoints within the
    depth band, and the indices of the keypoints they come from."""
    params = params or StereoParams()
    keypoints = np.asarray(keypoints, float).reshape(-1, 2)
    disparity = np.asarray(disparity, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = fx * baseline_m / disparity
    keep = np.flatnonzero(np.isfinite(depth) & (depth >= params.min_depth_m) & (depth <= params.max_depth_m))
    z = depth[keep]
    x = (keypoints[keep, 0] - cx) * z / fx
    y = (keypoints[keep, 1] - cy) * z / fy
    return np.column_stack([x, y, z]), keep
