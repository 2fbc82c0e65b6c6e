"""Off-screen stereo rendering: one renderer per process and model, RGB and depth in one pass.

``MUJOCO_GL`` must be set before mujoco is imported; maptidal defaults it to
``egl``, which renders through Mesa on a CPU-only machine and on NVIDIA GPUs.
Each camera is drawn once (``mjr_render``) and its colour and depth buffers are both read
back from that pass (``mjr_readPixels``), so the water model costs no extra render pass.
"""

from __future__ import annotations

import atexit
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import contextlib

import cv2
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
    model: mujoco.MjModel,
    data: mujoco.MjData,
    camera: str,
    height: int,
    width: int,
    with_depth: bool = True,
    raw_depth: bool = False,
) -> tuple[np.ndarray, np.ndarray | None]:
    """RGB ``(H, W, 3)`` uint8 and planar depth ``(H, W)`` float32 metres from one render pass.

    With ``with_depth=False`` the depth buffer is not read back and None is returned for it. With
    ``raw_depth=True`` the depth comes back as OpenGL left it: the reversed-Z buffer, rows bottom-up
    (see :func:`depth_coefficients` to convert it in one step with other per-pixel factors)."""
    renderer = shared_renderer(model, height, width)
    renderer.update_scene(data, camera=camera)
    rect = mujoco.MjrRect(0, 0, width, height)
    ctx = renderer._mjr_context  # the Renderer's own context: reuse it rather than make another
    renderer._gl_context.make_current()
    mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, ctx)
    mujoco.mjr_render(rect, renderer.scene, ctx)
    rgb = np.empty((height, width, 3), np.uint8)
    mujoco.mjr_readPixels(rgb, None, rect, ctx)
    rgb = cv2.flip(rgb, 0)  # OpenGL rows run bottom-up
    if not with_depth:
        return rgb, None
    # read separately: on Mesa one combined read costs about 0.9 ms more than two single ones
    depth = np.empty((height, width), np.float32)
    mujoco.mjr_readPixels(None, depth, rect, ctx)
    return rgb, depth if raw_depth else buffer_to_depth(cv2.flip(depth, 0), model)


def depth_coefficients(model: mujoco.MjModel) -> tuple[float, float]:
    """(c, d) such that planar depth = d / (buffer + c) for MuJoCo's reversed-Z depth buffer, as
    mujoco.Renderer converts it."""
    extent = model.stat.extent
    znear = model.vis.map.znear * extent
    zfar = model.vis.map.zfar * extent
    c_coef = -(zfar + znear) / (zfar - znear)
    d_coef = -(2.0 * zfar * znear) / (zfar - znear)
    return -0.5 * c_coef - 0.5, -0.5 * d_coef


def buffer_to_depth(buffer: np.ndarray, model: mujoco.MjModel) -> np.ndarray:
    """Planar depth (m) from MuJoCo's reversed-Z depth buffer (float32, the buffer's own precision)."""
    c_coef, d_coef = depth_coefficients(model)
    shifted = cv2.add(np.asarray(buffer, dtype=np.float32), float(c_coef))
    return cv2.divide(float(d_coef), shifted)
