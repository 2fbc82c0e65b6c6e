"""A literal, anchor-by-anchor guided match: the oracle for ``AnchorMap.match``. It shares no code with
it: every anchor is projected with the pinhole model written out, every keypoint compared with every
anchor within the search radius of it, one pair at a time in float32 as SIFT descriptors are stored.

For each keypoint with a descriptor, the candidates are the anchors in front of the camera, within the
depth band's looser bounds (half the nearest, twice the farthest) and within the search radius of the
keypoint in the image; it takes the nearest by descriptor distance when that distance is at most
``max_distance`` and below ``ratio`` times the second nearest (Lowe's test). An anchor taken by several
keypoints keeps the nearest of them.
"""

from __future__ import annotations

import math

import numpy as np


def literal_match(anchors, pose, pixels, descriptors, valid, sigma_m: float) -> tuple[list[int], list[int]]:
    """Keypoint rows and the anchors they match, sorted by anchor (``anchors`` an ``AnchorMap``)."""
    params, k = anchors.params, anchors.intrinsics
    radius = min(max(3.0 * sigma_m * k.fx, params.min_search_radius_px), params.max_search_radius_px)
    taken: dict[int, tuple[float, int]] = {}
    for row in range(len(pixels)):
        if not valid[row]:
            continue
        scored = []
        for index, point in enumerate(anchors.points):
            x, y, z = (np.asarray(point, float) - pose.position) @ pose.rotation
            if not params.min_depth_m * 0.5 < z < params.max_depth_m * 2.0:
                continue
            u, v = k.fx * x / z + k.cx, k.fy * y / z + k.cy
            if math.hypot(u - pixels[row][0], v - pixels[row][1]) > radius:
                continue
            difference = anchors.descriptors[index].astype(np.float32) - descriptors[row].astype(np.float32)
            scored.append((float(np.sqrt(np.sum(difference * difference, dtype=np.float64))), index))
        if not scored:
            continue
        scored.sort()
        distance, index = scored[0]
        if distance > params.max_distance:
            continue
        if len(scored) > 1 and distance >= params.ratio * scored[1][0]:
            continue
        if index not in taken or distance < taken[index][0]:
            taken[index] = (distance, row)
    matched = sorted(taken)
    return [taken[index][1] for index in matched], matched
