"""A literal, line-by-line transcription of the paper's Algorithms 1-3.

Ruediger & Banerjee, Map-TIDAL, Algorithms 1 (Task Discovery Process), 2 (Pruning)
and 3 (Additional Functions), the paper (docs/references.md). Python lists and
loops, one scipy Delaunay per CIP, nothing clever: it is the oracle that the
vectorised maptidal.discovery is tested and benchmarked against. It shares no
code with maptidal.discovery.

Where the pseudo-code leaves a detail open, the choice recorded in issue #2 is
followed:
- n = 1 starts the output and the comparison set as *copies* of the confirmed
  tasks, and Algorithm 1's final line returns Prune(remains, confirmed, 1) itself
  (the confirmed tasks are not appended twice);
- angle(X, Y) = arccos(clip(dX . dY, -1, 1)) between view directions;
- zero-area faces produce no CIP.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import Delaunay

# The OAK-D stereo pair from Luxonis' spec sheet, worked out here on its own: 2.35 mm focal length,
# 3 um pixels binned 2x2 to 640 x 400, so f = 2.35 mm / 6 um px and a pinhole field of view of
# 2 atan(320 / f) x 2 atan(200 / f).
_OAKD_F_PX = 2.35e-3 / 6e-6
OAKD_HFOV_DEG = math.degrees(2 * math.atan(320 / _OAKD_F_PX))
OAKD_VFOV_DEG = math.degrees(2 * math.atan(200 / _OAKD_F_PX))


def distance(x, y):
    """Euclidean distance between the positions of two viewpoints."""
    dx, dy, dz = x[0] - y[0], x[1] - y[1], x[2] - y[2]
    return math.sqrt(dx * dx + dy * dy + dz * dz)


def angle(x, y):
    """Angle between the view directions of two viewpoints."""
    dot = x[3] * y[3] + x[4] * y[4] + x[5] * y[5]
    return float(np.arccos(min(1.0, max(-1.0, dot))))


def generate_points(polygons, L_i):
    """Algorithm 3, Generate Points."""
    C = []
    for x in polygons:
        v0, v1, v2 = np.asarray(x[0], float), np.asarray(x[1], float), np.asarray(x[2], float)
        normal = np.cross(v1 - v0, v2 - v0)
        length = math.sqrt(normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2])
        if length == 0.0:
            continue
        n = normal / length
        c = (v0 + v1 + v2) / 3.0
        p = c + L_i * n
        theta = -1 * n
        C.append(
            (
                float(p[0]),
                float(p[1]),
                float(p[2]),
                float(theta[0]),
                float(theta[1]),
                float(theta[2]),
            )
        )
    return C


def prune(C, C_comp, n, r_ex, theta_ex, p_s):
    """Algorithm 2, Prune."""
    precheck = 1
    C_pruned = []
    C_compare = []
    if n == 0:
        C_compare = list(C_comp)
    elif n == 1:
        C_pruned = list(C_comp)
        C_compare = list(C_comp)
    elif n == 2:
        C_pruned.append(C[0])
        C_compare.append(C[0])
        r_ex = r_ex * p_s
        theta_ex = theta_ex * p_s
    for X in C:
        d = []
        alpha = []
        for Y in C_compare:
            d.append(distance(X, Y))
        for Y in C_compare:
            alpha.append(angle(X, Y))
        keep = 1
        for i in range(0, len(d)):
            if d[i] < r_ex:
                precheck = 0
                if alpha[i] < theta_ex:
                    keep = 0
                    break
        if keep == 1:
            C_pruned.append(X)
            if n == 1 or n == 2:
                C_compare.append(X)
    if n == 0 and precheck == 1:
        C_pruned = prune(C, [], 2, r_ex, theta_ex, p_s)
    return C_pruned


def transform_fov(X, hfov_deg, vfov_deg, far):
    """The camera pyramid (apex and four far corners) placed at viewpoint X."""
    p = np.array(X[:3])
    view = np.array(X[3:])
    reference = np.array([1.0, 0.0, 0.0]) if abs(view[2]) > 0.99 else np.array([0.0, 0.0, 1.0])
    right = np.cross(view, reference)
    right = right / np.linalg.norm(right)
    up = np.cross(right, view)
    half_w = far * math.tan(math.radians(hfov_deg) / 2)
    half_h = far * math.tan(math.radians(vfov_deg) / 2)
    corners = [p]
    for sx in (-1, 1):
        for sy in (-1, 1):
            corners.append(p + far * view + sx * half_w * right + sy * half_h * up)
    return np.array(corners)


def calculate_scores(C, K, hfov_deg, vfov_deg, far):
    """Algorithm 3, Calculate Scores."""
    S = []
    for X in C:
        FOV_t = transform_fov(X, hfov_deg, vfov_deg, far)
        T = int(np.sum(Delaunay(FOV_t).find_simplex(K) >= 0))
        S.append(T / len(K))
    return S


def task_discovery(
    vertices,
    faces,
    T_e,
    L_i=1.0,
    r_ex=1.7,
    theta_ex=0.25,
    t=0.75,
    p_s=0.7,
    hfov_deg=OAKD_HFOV_DEG,
    vfov_deg=OAKD_VFOV_DEG,
    far=None,
    keypoints=None,
):
    """Algorithm 1, Task Discovery Process. Returns (T_new, stages)."""
    far = 2.0 * L_i if far is None else far
    K = np.asarray(vertices, float) if keypoints is None else np.asarray(keypoints, float)
    P = [[vertices[i] for i in face] for face in faces]
    C = generate_points(P, L_i)
    stages = {"cips": len(C)}
    if len(T_e) == 0:
        C = prune(C, [], 2, r_ex, theta_ex, p_s)
    else:
        C = prune(C, [tuple(row) for row in T_e], 0, r_ex, theta_ex, p_s)
    stages["after_prune"] = len(C)
    T_new = []
    C_remains = []
    S = calculate_scores(C, K, hfov_deg, vfov_deg, far)
    for i in range(len(S)):
        if S[i] >= t:
            T_new.append(C[i])
        else:
            C_remains.append(C[i])
    stages["confirmed"] = len(T_new)
    T_new = prune(C_remains, T_new, 1, r_ex, theta_ex, p_s)
    stages["final"] = len(T_new)
    return T_new, stages
