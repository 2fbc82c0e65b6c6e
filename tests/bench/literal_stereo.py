"""A literal, keypoint-by-keypoint stereo matcher: the oracle for the vectorised
``maptidal.perception.stereo.match_stereo``. It shares no code with it beyond the grey conversion.

For each keypoint, OpenCV's ``matchTemplate`` (TM_SQDIFF) slides the left ``patch x patch`` window
along the same row of the right image over the disparity range, the best cost must beat every
candidate outside its neighbours by the ratio, the right window matched back along the left row must
land within the tolerance, and a parabola through the best cost and its neighbours gives the sub-pixel
disparity. This is how ``match_stereo`` worked until session 13.
"""

from __future__ import annotations

import cv2
import numpy as np

from maptidal.perception.stereo import StereoParams, gray_image


def _costs_along(template: np.ndarray, strip: np.ndarray) -> np.ndarray:
    return cv2.matchTemplate(strip, template, cv2.TM_SQDIFF)[0]


def literal_match_stereo(
    left: np.ndarray, right: np.ndarray, keypoints: np.ndarray, params: StereoParams | None = None
) -> np.ndarray:
    """Sub-pixel disparity of each keypoint, NaN where unmatched, one keypoint at a time."""
    params = params or StereoParams()
    left_f = gray_image(left, "left image").astype(np.float32)
    right_f = gray_image(right, "right image").astype(np.float32)
    half = params.patch // 2
    height, width = left_f.shape
    out = np.full(len(keypoints), np.nan)
    for index, (u_f, v_f) in enumerate(np.asarray(keypoints, float).reshape(-1, 2)):
        u, v = round(float(u_f)), round(float(v_f))
        if not (half <= v < height - half and half <= u < width - half):
            continue
        rows = slice(v - half, v + half + 1)
        template = left_f[rows, u - half : u + half + 1]
        x_low = max(half, u - params.max_disparity_px)
        x_high = u - params.min_disparity_px
        if x_high < x_low:
            continue
        costs = _costs_along(template, right_f[rows, x_low - half : x_high + half + 1])[::-1]
        disparities = np.arange(params.min_disparity_px, params.min_disparity_px + len(costs))
        best = int(np.argmin(costs))
        others = np.concatenate([costs[: max(best - 1, 0)], costs[best + 2 :]])
        if len(others) and not costs[best] < params.ratio * others.min():
            continue
        d = int(disparities[best])
        x = u - d
        back_high = min(width - 1 - half, x + params.max_disparity_px)
        back_costs = _costs_along(
            right_f[rows, x - half : x + half + 1], left_f[rows, x - half : back_high + half + 1]
        )
        if abs(int(np.argmin(back_costs)) - d) > params.lr_tolerance_px:
            continue
        offset = 0.0
        if 0 < best < len(costs) - 1:
            denominator = costs[best - 1] - 2 * costs[best] + costs[best + 1]
            if denominator > 0:
                offset = 0.5 * (costs[best - 1] - costs[best + 1]) / denominator
        out[index] = d + float(np.clip(offset, -0.5, 0.5))
    return out
