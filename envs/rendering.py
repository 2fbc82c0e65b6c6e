"""Off-screen stereo rendering: one renderer per process and model, RGB and depth in one pass.

``MUJOCO_GL`` must be set before mujoco is imported; maptidal defaults it to
``egl``, which renders through Mesa on a CPU-only machine and on NVIDIA GPUs.
Each camera is drawn once (``mjr_render``). Then either its colour and depth buffers are read
back from that pass (``mjr_readPixels``) for the CPU water model, or the water model runs as a
shader on the same buffers (:func:`render_camera_underwater`, :mod:`maptidal.envs.gl_water`) and only the
finished image is read back. Neither costs an extra render pass.
"""

from __future__ import annotations

import atexit
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import contextlib

import cv2
import mujoco
import numpy as np

from maptidal.envs.gl_water import (
    CameraGeometry,
    GLWaterPass,
    is_software_renderer,
    make_gl_water_pass,
    renderer_description,
)
from maptidal.envs.water import WaterParams

# What a camera in the water sees: surfaces only. MuJoCo's default options also draw rangefinder rays
# (the DVL beams, as bright yellow lines in other robots' images), sites and the like.
_SCENE_FLAGS = (
    mujoco.mjtVisFlag.mjVIS_TEXTURE,
    mujoco.mjtVisFlag.mjVIS_STATIC,
    mujoco.mjtVisFlag.mjVIS_SKIN,
    mujoco.mjtVisFlag.mjVIS_FLEXSKIN,
)


def camera_scene_option() -> mujoco.MjvOption:
    """Visual options for a simulated camera: every sensor and debug visual off.

    Rangefinder rays, sites, frames, labels, joints, actuators, tendons, lights, cameras, contact
    points and forces, centres of mass, perturbation and selection markers are not drawn; geoms of
    groups 0 to 2 (the scene) are, with their textures. Group 3 holds the collision-only geoms.
    """
    option = mujoco.MjvOption()
    option.flags[:] = 0
    for flag in _SCENE_FLAGS:
        option.flags[flag] = 1
    option.frame = mujoco.mjtFrame.mjFRAME_NONE
    option.label = mujoco.mjtLabel.mjLABEL_NONE
    for groups in (option.sitegroup, option.jointgroup, option.tendongroup, option.actuatorgroup):
        groups[:] = 0
    option.geomgroup[:] = 0
    option.geomgroup[:3] = 1
    return option


CAMERA_SCENE_OPTION = camera_scene_option()
_renderers: dict[int, mujoco.Renderer] = {}
# the GL water pass of each renderer (None where shaders are unavailable), keyed by id(renderer)
_water_passes: dict[int, GLWaterPass | None] = {}
_cleanup_registered = False


def check_render_samples(samples: object) -> int:
    """``samples`` as a multisample anti-aliasing count (MuJoCo's ``visual/quality/offsamples``), or
    ValueError unless it is a whole number from 0 (off) to 16."""
    whole = isinstance(samples, int) and not isinstance(samples, bool)
    if not (whole and 0 <= samples <= 16):
        raise ValueError(f"render_samples must be a whole number from 0 to 16, got {samples!r}")
    return samples


def shared_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """The process's renderer for ``model`` at ``height x width`` (created once, then reused)."""
    key = id(model)
    renderer = _renderers.get(key)
    if renderer is None or renderer.height != height or renderer.width != width:
        if renderer is not None:
            _close(renderer)
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
        _close(renderer)


def _close(renderer: mujoco.Renderer) -> None:
    water_pass = _water_passes.pop(id(renderer), None)
    if water_pass is not None:
        with contextlib.suppress(Exception):
            water_pass.close()
    renderer.close()


def _release_all() -> None:
    for key in list(_renderers):
        with contextlib.suppress(Exception):
            _close(_renderers.pop(key))


def has_mirrors(model: mujoco.MjModel) -> bool:
    """Whether any opaque geom of ``model`` reflects (a material with reflectance above 0): MuJoCo draws
    the scene mirrored in it, which can show what lies behind a camera. It draws no reflection in a
    geom with any transparency, such as the tank's window pane (alpha 0.55): a test checks that a robot
    facing the pane never sees its own frame in it, and that it does once the pane is opaque."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    scene = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom))
    view = mujoco.MjvCamera()
    view.type = mujoco.mjtCamera.mjCAMERA_FREE
    mujoco.mjv_updateScene(model, data, CAMERA_SCENE_OPTION, None, view, mujoco.mjtCatBit.mjCAT_ALL, scene)
    return any(scene.geoms[i].reflectance > 0 and scene.geoms[i].rgba[3] >= 1.0 for i in range(scene.ngeom))


def geoms_behind_camera(model: mujoco.MjModel, camera: str) -> np.ndarray:
    """Ids of the visual geoms on ``camera``'s own body that lie wholly behind its near clipping plane:
    every corner of each geom's bounding box is nearer the camera's plane than ``znear``, or behind it.
    OpenGL clips them from every image that camera takes, so leaving them out of its scene changes no
    pixel and spares drawing them (a BlueROV2's frame, thrusters and floats are behind its cameras).
    None in a model with a mirror (:func:`has_mirrors`), where they could show in its reflection."""
    if has_mirrors(model):
        return np.zeros(0, dtype=int)
    cam = model.camera(camera).id
    body = model.cam_bodyid[cam]
    to_camera = np.zeros(9)
    mujoco.mju_quat2Mat(to_camera, model.cam_quat[cam])
    to_camera = to_camera.reshape(3, 3)
    near = model.vis.map.znear * model.stat.extent
    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
    hidden = []
    for geom in np.flatnonzero((model.geom_bodyid == body) & (model.geom_group < 3)):
        to_body = np.zeros(9)
        mujoco.mju_quat2Mat(to_body, model.geom_quat[geom])
        centre, half = model.geom_aabb[geom, :3], model.geom_aabb[geom, 3:]
        corners = model.geom_pos[geom] + (centre + signs * half) @ to_body.reshape(3, 3).T
        depth = -((corners - model.cam_pos[cam]) @ to_camera)[:, 2]  # MuJoCo's cameras look along -z
        if depth.max() < near:
            hidden.append(int(geom))
    return np.array(hidden, dtype=int)


def update_camera_scene(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    camera: str,
    scene: mujoco.MjvScene,
    hidden: np.ndarray | None = None,
) -> mujoco.MjvScene:
    """Fill ``scene`` with what the model camera ``camera`` sees in ``data`` now (the camera's scene
    options). The scene is a snapshot: drawing it later, even on another thread while the physics steps
    on, draws this moment.

    ``hidden`` geoms (:func:`geoms_behind_camera`) are left out: MuJoCo skips a geom whose colour has
    zero alpha, so their alphas are zero for this call only. Update scenes of one model on one thread."""
    view = mujoco.MjvCamera()
    view.type = mujoco.mjtCamera.mjCAMERA_FIXED
    view.fixedcamid = model.camera(camera).id
    everything = mujoco.mjtCatBit.mjCAT_ALL
    if hidden is None or not len(hidden):
        mujoco.mjv_updateScene(model, data, CAMERA_SCENE_OPTION, None, view, everything, scene)
        return scene
    alphas = model.geom_rgba[hidden, 3].copy()
    model.geom_rgba[hidden, 3] = 0.0
    try:
        mujoco.mjv_updateScene(model, data, CAMERA_SCENE_OPTION, None, view, everything, scene)
    finally:
        model.geom_rgba[hidden, 3] = alphas
    return scene


def _draw(model: mujoco.MjModel, scene: mujoco.MjvScene, height: int, width: int) -> mujoco.Renderer:
    """Draw ``scene`` into the shared renderer's off-screen buffer; returns that renderer."""
    renderer = shared_renderer(model, height, width)
    ctx = renderer._mjr_context  # the Renderer's own context: reuse it rather than make another
    renderer._gl_context.make_current()
    mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, ctx)
    mujoco.mjr_render(mujoco.MjrRect(0, 0, width, height), scene, ctx)
    return renderer


def render_camera(
    model: mujoco.MjModel,
    scene: mujoco.MjvScene,
    height: int,
    width: int,
    with_depth: bool = True,
    raw_depth: bool = False,
) -> tuple[np.ndarray, np.ndarray | None]:
    """RGB ``(H, W, 3)`` uint8 and planar depth ``(H, W)`` float32 metres from one render pass of a
    camera's scene (:func:`update_camera_scene`).

    With ``with_depth=False`` the depth buffer is not read back and None is returned for it. With
    ``raw_depth=True`` the depth comes back as OpenGL left it: the reversed-Z buffer, rows bottom-up
    (see :func:`depth_coefficients` to convert it in one step with other per-pixel factors)."""
    renderer = _draw(model, scene, height, width)
    rect = mujoco.MjrRect(0, 0, width, height)
    ctx = renderer._mjr_context
    rgb = np.empty((height, width, 3), np.uint8)
    mujoco.mjr_readPixels(rgb, None, rect, ctx)
    rgb = cv2.flip(rgb, 0)  # OpenGL rows run bottom-up
    if not with_depth:
        return rgb, None
    # read separately: on Mesa one combined read costs about 0.9 ms more than two single ones
    depth = np.empty((height, width), np.float32)
    mujoco.mjr_readPixels(None, depth, rect, ctx)
    return rgb, depth if raw_depth else buffer_to_depth(cv2.flip(depth, 0), model)


def gl_water_available(model: mujoco.MjModel, height: int, width: int, geometry: CameraGeometry) -> bool:
    """Whether the water model can run as a shader in this process's renderer for ``model``."""
    return _water_pass(shared_renderer(model, height, width), geometry) is not None


def describe_renderer(model: mujoco.MjModel, height: int, width: int) -> str:
    """GL_RENDERER and GL_VERSION of this process's renderer for ``model`` (for logs and benches)."""
    return renderer_description(shared_renderer(model, height, width))


def renders_on_gpu(model: mujoco.MjModel, height: int, width: int) -> bool:
    """Whether this process's renderer for ``model`` draws on a GPU rather than a CPU rasteriser."""
    return not is_software_renderer(shared_renderer(model, height, width))


def _water_pass(renderer: mujoco.Renderer, geometry: CameraGeometry) -> GLWaterPass | None:
    key = id(renderer)
    if key not in _water_passes:
        _water_passes[key] = make_gl_water_pass(renderer, geometry)
    water_pass = _water_passes[key]
    if water_pass is not None and water_pass.geometry != geometry:
        water_pass.geometry = geometry
        water_pass.invalidate()
    return water_pass


def render_camera_underwater(
    model: mujoco.MjModel,
    scene: mujoco.MjvScene,
    geometry: CameraGeometry,
    water: WaterParams,
    height: int,
    width: int,
    seed: int = 0,
    with_depth: bool = False,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Like :func:`render_camera` with ``raw_depth=True``, but the water model runs on the GL side
    (:mod:`maptidal.envs.gl_water`) and the returned RGB is already the underwater image. Call
    :func:`gl_water_available` first: this raises RuntimeError where the shader cannot run."""
    renderer = _draw(model, scene, height, width)
    water_pass = _water_pass(renderer, geometry)
    if water_pass is None:
        raise RuntimeError("the GL water pass is unavailable in this GL context")
    return water_pass.apply(water, seed=seed, with_depth=with_depth)


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
