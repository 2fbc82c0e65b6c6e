"""Off-screen stereo rendering: one renderer per process and model, RGB and depth in one pass.

``MUJOCO_GL`` must be set before mujoco is imported; maptidal defaults it to
``egl``, which renders through Mesa on a CPU-only machine and on NVIDIA GPUs.
Each camera is drawn once (``mjr_render``) and its colour and depth buffers are read
back together (``mjr_readPixels``), so the water model costs no extra render pass.
"""

from __future__ import annotations

import atexit
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import contextlib

import mujoco
import numpy as np

_renderers: dict[int, mujoco.Renderer] = {}
_cleanup_registered = False


def shared_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """The process's renderer for ``model`` at ``height x width`` (created once, then reused)."""
    key = id(model)
    renderer = _renderers.get(key)
    if renderer is None or renderer.height != height or renderer.width != width:
        if renderer is not None:
            renderer.close()
        renderer = mujoco.Renderer(model, height=height, width=width)
        _renderers[key] = renderer
        global _cleanup_registered
        if not _cleanup_registered:
            # registered after mujoco's EGL module, so it runs before EGL is terminated
            atexit.register(_release_all)
            _cleanup_registered = True
    return renderer


def release(model: mujoco.MjModel) -> None:
    """Free the renderer of ``model`` (its GL context), if any."""
    renderer = _renderers.pop(id(model), None)
    if renderer is not None:
        renderer.close()


def _release_all() -> None:
    for key in list(_renderers):
        with contextlib.suppress(Exception):
            _renderers.pop(key).close()


def render_camera(
    model: mujoco.MjModel, data: mujoco.MjData, camera: str, height: int, width: int
) -> tuple[np.ndarray, np.ndarray]:
    """RGB ``(H, W, 3)`` uint8 and planar depth ``(H, W)`` float32 metres from one render pass."""
    renderer = shared_renderer(model, height, width)
    renderer.update_scene(data, camera=camera)
    rect = mujoco.MjrRect(0, 0, width, height)
    ctx = renderer._mjr_context  # the Renderer's own context: reuse it rather than make another
    renderer._gl_context.make_current()
    mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, ctx)
    mujoco.mjr_render(rect, renderer.scene, ctx)
    rgb = np.empty((height, width, 3), np.uint8)
    depth = np.empty((height, width), np.float32)
    mujoco.mjr_readPixels(rgb, depth, rect, ctx)
    # OpenGL rows run bottom-up
    rgb, depth = rgb[::-1], depth[::-1]
    return np.ascontiguousarray(rgb), buffer_to_depth(depth, model)


def buffer_to_depth(buffer: np.ndarray, model: mujoco.MjModel) -> np.ndarray:
    """Planar depth (m) from MuJoCo's reversed-Z depth buffer, as mujoco.Renderer converts it."""
    extent = model.stat.extent
    znear = np.float32(model.vis.map.znear * extent)
    zfar = np.float32(model.vis.map.zfar * extent)
    c_coef = -(zfar + znear) / (zfar - znear)
    d_coef = -(np.float32(2) * zfar * znear) / (zfar - znear)
    c_coef, d_coef = np.float32(-0.5) * c_coef - np.float32(0.5), np.float32(-0.5) * d_coef
    return (d_coef / (buffer.astype(np.float64) + c_coef)).astype(np.float32)
