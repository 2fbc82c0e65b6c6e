"""Keyframe overlays like the paper's Fig. 4, each panel on the keyframe's left image: A the keypoints
(green tracked from the last frame, red new), B the keyframe mesh projected, C the tasks known before
this keyframe (grey arrows), D the candidate inspection points (teal), E those left after the first
pruning, F the confirmed ones (green) and the remaining ones (red), G the new tasks (orange) after the
final pruning. OpenCV and numpy only."""

from __future__ import annotations

import cv2
import numpy as np

from maptidal.perception.recording import CameraIntrinsics, CameraPose

GREEN, RED, ORANGE, GREY, CYAN = (40, 200, 40), (230, 40, 40), (255, 150, 0), (170, 170, 170), (0, 220, 255)
TEAL = (0, 160, 150)
ARROW_M = 0.3  # drawn length of a task's viewing direction


def project(
    points_world: np.ndarray, pose: CameraPose, intrinsics: CameraIntrinsics
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(N, 2)`` of world points and whether each lies in front of the camera ``(N,)``."""
    camera = (np.asarray(points_world, float).reshape(-1, 3) - pose.position) @ pose.rotation
    depth = camera[:, 2]
    in_front = depth > 1e-3
    safe = np.where(in_front, depth, 1.0)
    u = intrinsics.fx * camera[:, 0] / safe + intrinsics.cx
    v = intrinsics.fy * camera[:, 1] / safe + intrinsics.cy
    return np.column_stack([u, v]), in_front


def _rgb(image: np.ndarray) -> np.ndarray:
    array = np.asarray(image, np.uint8)
    return cv2.cvtColor(array, cv2.COLOR_GRAY2RGB) if array.ndim == 2 else array.copy()


def _label(panel: np.ndarray, text: str) -> None:
    # sized to stay legible when keyframe_overlay halves the panel
    cv2.putText(panel, text, (10, 36), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (0, 0, 0), 5, cv2.LINE_AA)
    cv2.putText(panel, text, (10, 36), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (255, 255, 255), 2, cv2.LINE_AA)


def keypoint_panel(image: np.ndarray, pixels: np.ndarray, tracked: np.ndarray) -> np.ndarray:
    """Fig. 4A: keypoints, green where tracked from the last frame, red where new."""
    panel = _rgb(image)
    for (u, v), carried in zip(np.asarray(pixels).reshape(-1, 2), np.asarray(tracked, bool), strict=True):
        cv2.circle(panel, (round(u), round(v)), 3, GREEN if carried else RED, -1, cv2.LINE_AA)
    _label(
        panel,
        f"A: {int(np.sum(tracked))} tracked (green), {int(np.sum(~np.asarray(tracked, bool)))} new (red)",
    )
    return panel


def mesh_panel(
    image: np.ndarray, vertices: np.ndarray, faces: np.ndarray, pose: CameraPose, intrinsics: CameraIntrinsics
) -> np.ndarray:
    """Fig. 4B: the keyframe mesh's edges projected into the image."""
    panel = _rgb(image)
    pixels, in_front = project(vertices, pose, intrinsics)
    for face in np.asarray(faces, int).reshape(-1, 3):
        if in_front[face].all():
            corners = np.round(pixels[face]).astype(np.int32).reshape(-1, 1, 2)
            cv2.polylines(panel, [corners], True, CYAN, 1, cv2.LINE_AA)
    _label(panel, f"B: mesh, {len(faces)} faces")
    return panel


def viewpoint_panel(
    image: np.ndarray,
    layers: list[tuple[np.ndarray, tuple[int, int, int]]],
    label: str,
    pose: CameraPose,
    intrinsics: CameraIntrinsics,
) -> np.ndarray:
    """Viewpoint rows ``(N, 6)`` drawn as arrows from their position along their viewing direction, one
    colour per layer (later layers on top), with ``label``."""
    panel = _rgb(image)
    for rows, colour in layers:
        rows = np.asarray(rows, float).reshape(-1, 6)
        if len(rows) == 0:
            continue
        tails, tail_front = project(rows[:, :3], pose, intrinsics)
        heads, head_front = project(rows[:, :3] + ARROW_M * rows[:, 3:], pose, intrinsics)
        for tail, head, ok in zip(tails, heads, tail_front & head_front, strict=True):
            if ok and np.all(np.abs(np.r_[tail, head]) < 1e4):
                start, end = tuple(np.round(tail).astype(int)), tuple(np.round(head).astype(int))
                cv2.arrowedLine(panel, start, end, colour, 2, cv2.LINE_AA, tipLength=0.25)
    _label(panel, label)
    return panel


def task_panel(
    image: np.ndarray,
    new_tasks: np.ndarray,
    earlier_tasks: np.ndarray,
    pose: CameraPose,
    intrinsics: CameraIntrinsics,
) -> np.ndarray:
    """Fig. 4G: tasks as arrows from their position along their viewing direction (new: orange)."""
    count = len(np.asarray(new_tasks).reshape(-1, 6))
    label = f"G: {count} new tasks (orange)"
    return viewpoint_panel(image, [(earlier_tasks, GREY), (new_tasks, ORANGE)], label, pose, intrinsics)


def keyframe_overlay(
    image: np.ndarray,
    pixels: np.ndarray,
    tracked: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    new_tasks: np.ndarray,
    earlier_tasks: np.ndarray,
    pose: CameraPose,
    intrinsics: CameraIntrinsics,
    stages=None,
) -> np.ndarray:
    """Fig. 4's panels as one RGB image at half size: A keypoints, B mesh, C earlier tasks, D CIPs, then
    E after the first pruning, F confirmed and remaining, G new tasks. ``stages`` is the keyframe's
    :class:`maptidal.discovery.DiscoveryResult` (None: D to F are left empty)."""
    empty = np.zeros((0, 6))
    cips, pruned, confirmed, remains = (
        (stages.cips, stages.after_prune, stages.confirmed, stages.remains)
        if stages is not None
        else (empty,) * 4
    )
    panels = [
        keypoint_panel(image, pixels, tracked),
        mesh_panel(image, vertices, faces, pose, intrinsics),
        viewpoint_panel(
            image, [(earlier_tasks, GREY)], f"C: {len(earlier_tasks)} earlier tasks", pose, intrinsics
        ),
        viewpoint_panel(image, [(cips, TEAL)], f"D: {len(cips)} CIPs", pose, intrinsics),
        viewpoint_panel(image, [(pruned, TEAL)], f"E: {len(pruned)} after pruning", pose, intrinsics),
        viewpoint_panel(
            image,
            [(remains, RED), (confirmed, GREEN)],
            f"F: {len(confirmed)} confirmed, {len(remains)} remain (red)",
            pose,
            intrinsics,
        ),
        task_panel(image, new_tasks, earlier_tasks, pose, intrinsics),
        np.full_like(_rgb(image), 255),
    ]
    small = [
        cv2.resize(panel, (panel.shape[1] // 2, panel.shape[0] // 2), interpolation=cv2.INTER_AREA)
        for panel in panels
    ]
    return np.vstack([np.hstack(small[:4]), np.hstack(small[4:])])
