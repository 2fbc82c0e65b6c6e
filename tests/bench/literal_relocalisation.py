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


def literal_locate(points, pixels, rotation, intrinsics, params, rng):
    """The camera centre by RANSAC over pairs of rays, one hypothesis at a time, each solved by least
    squares over the stacked perpendicular projections (``numpy.linalg.lstsq``): (centre, inlier
    mask), or None. Draws its pairs from ``rng`` as ``locate`` does, one ``choice`` per hypothesis."""
    points = np.asarray(points, float)
    pixels = np.asarray(pixels, float)
    n = len(points)
    if n < max(params.min_inliers, 2):
        return None
    rays = []
    for u, v in pixels:
        ray = rotation @ np.array(
            [(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy, 1.0]
        )
        rays.append(ray / math.sqrt(ray @ ray))
    rays = np.array(rays)

    def centre_of(rows):
        blocks = [np.eye(3) - np.outer(rays[i], rays[i]) for i in rows]
        if np.linalg.cond(sum(blocks)) > 1e8:
            return None
        stacked = np.vstack(blocks)
        target = np.concatenate([block @ points[i] for block, i in zip(blocks, rows, strict=True)])
        return np.linalg.lstsq(stacked, target, rcond=None)[0]

    def inliers_of(centre):
        mask = np.zeros(n, bool)
        for i in range(n):
            x, y, z = (points[i] - centre) @ rotation
            if z > 0:
                u, v = intrinsics.fx * x / z + intrinsics.cx, intrinsics.fy * y / z + intrinsics.cy
                mask[i] = math.hypot(u - pixels[i][0], v - pixels[i][1]) <= params.reprojection_px
        return mask

    best = None
    for _ in range(params.ransac_iterations):
        pair = rng.choice(n, 2, replace=False)
        centre = centre_of(pair.tolist())
        if centre is None:
            continue
        mask = inliers_of(centre)
        if best is None or mask.sum() > best.sum():
            best = mask
    if best is None or best.sum() < max(params.min_inliers, params.min_inlier_ratio * n):
        return None
    centre = None
    for _ in range(2):
        centre = centre_of(np.flatnonzero(best).tolist())
        if centre is None:
            return None
        refined = inliers_of(centre)
        if refined.sum() < params.min_inliers:
            return None
        best = refined
    return centre, best
