"""Build the MuJoCo world with MjSpec: the tank from its config, and BlueROV2s attached to it.

The tank comes from the same :class:`maptidal.tank.TankModel` as coverage
evaluation, so physics, renderer and coverage share one geometry. Each flat
surface is a textured plane for the renderer (planes take 2D textures) with a thin
box behind it for collisions. Robots are built as separate specs and attached with
a name prefix (``rov0/``), each with its own cameras, sensors and thrusters.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import mujoco
import numpy as np

from maptidal.camera import StereoCameraParams
from maptidal.envs.hydrodynamics import userdata_size
from maptidal.envs.textures import TextureParams, concrete_texture, floor_texture, fouling_texture
from maptidal.envs.vehicle import VehicleParams
from maptidal.tank import TankModel

WALL_THICKNESS = 0.1  # m, collision boxes behind each surface
# Geom groups: 0 the tank's surfaces and the ladder (the geometry of maptidal.tank.TankModel) and the
# robots' visible parts; 1 thin decorations on the surfaces (window frame, fouling discs); 3 the
# invisible collision geoms. Cameras draw groups 0 to 2 (maptidal.envs.rendering).
DECORATION_GROUP = 1
DEPTH_SENSOR_POSITION = (-0.1, 0.0, 0.1)  # m from the CG: the pressure sensor on the electronics tube's end
_S = mujoco.mjtSensor
# Every robot's MuJoCo sensors: (name, type, site); maptidal.envs.sensors reads them by these names.
ROBOT_SENSORS: tuple[tuple[str, mujoco.mjtSensor, str], ...] = (
    ("accelerometer", _S.mjSENS_ACCELEROMETER, "imu"),
    ("gyro", _S.mjSENS_GYRO, "imu"),
    ("magnetometer", _S.mjSENS_MAGNETOMETER, "imu"),
    ("velocimeter", _S.mjSENS_VELOCIMETER, "dvl"),
    ("depth_pos", _S.mjSENS_FRAMEPOS, "depth"),
    *((f"beam{k}", _S.mjSENS_RANGEFINDER, f"beam{k}") for k in range(4)),
)


@dataclass(frozen=True)
class RobotPlacement:
    """A robot to put in the world: its name (prefix), vehicle and start pose (m, rad)."""

    name: str
    vehicle: VehicleParams
    position: tuple[float, float, float]
    yaw: float = 0.0


def quat_from_axes(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The unit quaternion (w, x, y, z) of the frame whose axes are ``x``, ``y`` and ``z``.

    The axes must be orthonormal and right-handed: ``mju_mat2Quat`` silently turns a reflection
    (determinant -1) into some rotation, which once put the ladder's rungs across the wall.
    """
    matrix = np.column_stack([x, y, z]).astype(float)
    if not np.allclose(matrix.T @ matrix, np.eye(3), atol=1e-6) or np.linalg.det(matrix) < 0.0:
        raise ValueError(f"axes are not a right-handed orthonormal frame: {matrix.T.round(4).tolist()}")
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, matrix.ravel())
    return quat


_TEXTURES = {"concrete": concrete_texture, "fouling": fouling_texture, "floor": floor_texture}


@functools.lru_cache(maxsize=16)
def _texture_pixels(name: str, params: TextureParams | None) -> tuple[bytes, int, int]:
    # the procedural textures are the same for the same parameters and took 0.4 s of a world's 0.5 s to
    # draw: each world after the first (a batch of environments builds one per robot) reuses them
    image = np.ascontiguousarray(_TEXTURES[name](params))
    return image.tobytes(), image.shape[1], image.shape[0]


def _add_texture(spec: mujoco.MjSpec, name: str, textures: TextureParams | None) -> None:
    pixels, width, height = _texture_pixels(name, textures)
    texture = spec.add_texture(
        name=name,
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        width=width,
        height=height,
        nchannel=3,
    )
    texture.data = pixels


def _add_material(spec: mujoco.MjSpec, name: str, texture: str | None = None, **attributes) -> None:
    material = spec.add_material(name=name, **attributes)
    if texture is not None:
        material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = texture


def _add_quad(body, corners: np.ndarray, normal: np.ndarray, material: str, collide: bool = True) -> None:
    """A textured plane over the quad and, behind it, a collision box of WALL_THICKNESS."""
    u, v = corners[1] - corners[0], corners[3] - corners[0]
    lu, lv = np.linalg.norm(u), np.linalg.norm(v)
    u, v = u / lu, v / lv
    n = np.asarray(normal, float)
    if np.dot(np.cross(u, v), n) < 0:
        u, v, lu, lv = v, u, lv, lu
    quat = quat_from_axes(u, v, n)
    centre = corners.mean(axis=0)
    body.add_geom(
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[lu / 2, lv / 2, 0.05],
        pos=centre,
        quat=quat,
        material=material,
        contype=0,
        conaffinity=0,
        group=0,
    )
    if collide:
        body.add_geom(
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[lu / 2, lv / 2, WALL_THICKNESS / 2],
            pos=centre - n * WALL_THICKNESS / 2,
            quat=quat,
            rgba=[0.5, 0.5, 0.5, 0.0],
            group=3,
        )


def build_tank_spec(tank: TankModel, textures: TextureParams | None = None) -> mujoco.MjSpec:
    """The tank as an MjSpec: walls (the far end wall that closes the tank too), window (glass, frame
    and the dark room behind it), ladder, fouling, floor, lights."""
    textures = textures or TextureParams()
    spec = mujoco.MjSpec()
    spec.modelname = tank.config.name
    spec.stat.extent = 1.0  # fog distances in metres
    spec.visual.global_.offwidth = 1280
    spec.visual.global_.offheight = 800
    spec.visual.headlight.ambient = [0.25, 0.25, 0.25]
    spec.visual.headlight.diffuse = [0.35, 0.35, 0.35]
    for name in _TEXTURES:
        _add_texture(spec, name, textures)
    repeat = [1.0 / textures.tile_m] * 2
    _add_material(spec, "wall", "concrete", texrepeat=repeat, texuniform=True, specular=0.1)
    _add_material(spec, "floor", "floor", texrepeat=[1.0, 1.0], texuniform=True, specular=0.05)
    _add_material(spec, "fouling", "fouling", texrepeat=[4.0, 4.0], texuniform=True)
    _add_material(spec, "glass", rgba=[0.35, 0.45, 0.5, 0.55], specular=0.9, shininess=0.9, reflectance=0.3)
    _add_material(spec, "window_frame", rgba=[0.12, 0.12, 0.13, 1.0], specular=0.4)
    _add_material(spec, "steel", rgba=[0.72, 0.72, 0.75, 1.0], specular=0.8, shininess=0.6)
    world = spec.worldbody
    for corners, normal, kind in tank.scene_quads(include_floor=True):
        # the room behind the glass is dark and out of reach (the pane in front of it collides)
        material = {"pane": "glass", "floor": "floor", "room": "window_frame"}.get(kind, "wall")
        _add_quad(world, corners, normal, material, collide=kind != "room")
    if tank.has_window():
        _add_window_frame(world, tank)
    for centre, half, axes in tank.ladder_boxes():
        world.add_geom(
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=half,
            pos=centre,
            quat=quat_from_axes(*axes),
            material="steel",
        )
    _add_fouling(world, tank)
    depth = tank.height
    for k, x in enumerate((-1.0, -4.0)):
        world.add_light(
            name=f"overhead{k}",
            pos=[x, 0.0, depth + 2.5],
            dir=[0.3, 0.0, -1.0],
            diffuse=[0.55, 0.55, 0.55],
            specular=[0.1, 0.1, 0.1],
            castshadow=False,
        )
    return spec


def _add_window_frame(world, tank: TankModel) -> None:
    """A dark frame, 4 cm wide, around the window opening on the wall plane."""
    bl, br, tr, tl = tank.window_rim()
    normal = tank.segment("end").inward_normal
    width = 0.04
    for a, b in ((bl, br), (br, tr), (tr, tl), (tl, bl)):
        along = b - a
        length = float(np.linalg.norm(along))
        u = along / length
        v = np.cross(normal, u)
        centre = (a + b) / 2 + normal * 0.005 - v * width / 2
        world.add_geom(
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[length / 2 + width, width / 2, 0.005],
            pos=centre,
            quat=quat_from_axes(u, v, normal),
            material="window_frame",
            contype=0,
            conaffinity=0,
            group=DECORATION_GROUP,
        )


def _add_fouling(world, tank: TankModel) -> None:
    """Thin discs of growth on the walls at the config's fouling patches."""
    for patch in tank.config.fouling:
        points, normals = tank.strip_to_world(np.array([patch.s]), np.array([patch.z]))
        n = normals[0]
        u = np.cross([0.0, 0.0, 1.0], n)
        u /= np.linalg.norm(u)
        world.add_geom(
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            size=[patch.radius, 0.003, 0],
            pos=points[0] + n * 0.004,
            quat=quat_from_axes(u, np.cross(n, u), n),
            material="fouling",
            contype=0,
            conaffinity=0,
            group=DECORATION_GROUP,
        )


def camera_offsets(vehicle: VehicleParams, camera: StereoCameraParams) -> dict[str, np.ndarray]:
    """Body-frame positions of the left and right camera centres (left is +y)."""
    centre = np.asarray(vehicle.sensors.camera_position, float)
    half = np.array([0.0, camera.baseline_m / 2, 0.0])
    return {"left": centre + half, "right": centre - half}


def build_robot_spec(vehicle: VehicleParams, camera: StereoCameraParams | None = None) -> mujoco.MjSpec:
    """One BlueROV2 as an MjSpec: free body, hull, thrusters, sensors and the stereo pair.

    Thruster actuators only carry the command and its first-order lag (MuJoCo
    ``filterexact`` dynamics, zero gain): the hydrodynamics callback turns the lagged
    state into thrust (asymmetric T200 limits) together with the Fossen forces.
    """
    camera = camera or StereoCameraParams()
    spec = mujoco.MjSpec()
    spec.modelname = f"bluerov2_{vehicle.frame}"
    _add_material(spec, "hull", rgba=[0.1, 0.1, 0.12, 1.0], specular=0.3)
    _add_material(spec, "float", rgba=[0.05, 0.35, 0.75, 1.0], specular=0.2)
    _add_material(spec, "tube", rgba=[0.75, 0.75, 0.8, 0.9], specular=0.6)
    base = spec.worldbody.add_body(name="base")
    base.add_freejoint(name="root")
    base.explicitinertial = True
    base.mass = vehicle.mass
    base.inertia = list(vehicle.inertia)
    base.ipos = [0.0, 0.0, 0.0]
    length, width, height = vehicle.hull_size
    base.add_geom(
        name="hull",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[length / 2, width / 2, height / 2],
        rgba=[0, 0, 0, 0],
        group=3,
    )
    # visual parts: buoyancy floats on top, electronics tube, frame plates
    base.add_geom(
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[length / 2, width / 2 - 0.02, 0.035],
        pos=[0, 0, height / 2 - 0.035],
        material="float",
        contype=0,
        conaffinity=0,
    )
    base.add_geom(
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[0.05, length / 2 - 0.03, 0],
        quat=[0.7071, 0, 0.7071, 0],
        pos=[0, 0, -0.02],
        material="tube",
        contype=0,
        conaffinity=0,
    )
    for side in (-1, 1):
        base.add_geom(
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[length / 2, 0.006, height / 2 - 0.02],
            pos=[0, side * (width / 2 - 0.006), -0.01],
            material="hull",
            contype=0,
            conaffinity=0,
        )
    for k, (pos, direction) in enumerate(
        zip(vehicle.thruster_positions, vehicle.thruster_directions, strict=True)
    ):
        z = np.asarray(direction, float) / np.linalg.norm(direction)
        x = np.cross([0.0, 0.0, 1.0], z) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        x /= np.linalg.norm(x)
        quat = quat_from_axes(x, np.cross(z, x), z)
        base.add_site(name=f"thruster{k + 1}", pos=list(pos), quat=quat, size=[0.01, 0, 0])
        base.add_geom(
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            size=[0.05, 0.035, 0],
            pos=list(pos),
            quat=quat,
            material="hull",
            contype=0,
            conaffinity=0,
        )
        actuator = spec.add_actuator(name=f"thruster{k + 1}", target=f"thruster{k + 1}")
        actuator.trntype = mujoco.mjtTrn.mjTRN_SITE
        actuator.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT
        actuator.dynprm[0] = vehicle.thruster.time_constant_s
        actuator.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        actuator.gainprm[0] = 0.0  # thrust is applied by the hydrodynamics callback
        actuator.biastype = mujoco.mjtBias.mjBIAS_NONE
        actuator.ctrllimited = True
        actuator.ctrlrange = [-1.0, 1.0]
        actuator.gear = [0, 0, 1, 0, 0, 0]
    base.add_site(name="imu", pos=[0, 0, 0])
    # stereo pair looking along body +x, image up = body +z (MuJoCo cameras look along -z)
    for side, position in camera_offsets(vehicle, camera).items():
        cam = base.add_camera(
            name=side,
            pos=list(position),
            quat=quat_from_axes(
                np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([-1.0, 0.0, 0.0])
            ),
        )
        cam.resolution = [camera.width, camera.height]
        cam.sensor_size = [float(camera.width), float(camera.height)]
        cam.focal_pixel = [camera.fx, camera.fy]
    base.add_light(
        name="lumen",
        pos=list(vehicle.sensors.camera_position),
        dir=[1, 0, -0.15],
        diffuse=[0.45, 0.45, 0.42],
        cutoff=60,
        exponent=4,
        castshadow=False,
    )
    mounts = vehicle.sensors
    base.add_site(name="dvl", pos=list(mounts.dvl_position))
    base.add_site(name="depth", pos=list(DEPTH_SENSOR_POSITION))
    tilt = math.radians(mounts.dvl_beam_angle_deg)
    for k, azimuth in enumerate((45.0, 135.0, 225.0, 315.0)):
        a = math.radians(azimuth)
        # rangefinders measure along the site's +z: point it down and out at the beam angle
        z = np.array([math.sin(tilt) * math.cos(a), math.sin(tilt) * math.sin(a), -math.cos(tilt)])
        x = np.cross([0.0, 0.0, 1.0], z)
        x /= np.linalg.norm(x)
        base.add_site(
            name=f"beam{k}", pos=list(mounts.dvl_position), quat=quat_from_axes(x, np.cross(z, x), z)
        )
    for name, kind, site in ROBOT_SENSORS:
        sensor = spec.add_sensor(name=name, type=kind, objname=site)
        sensor.objtype = mujoco.mjtObj.mjOBJ_SITE
        if kind == _S.mjSENS_RANGEFINDER:
            sensor.intprm[0] = 1 << int(mujoco.mjtRayDataField.mjRAYDATA_DIST)  # distance only
    return spec


def compose(
    tank: TankModel,
    robots: list[RobotPlacement],
    timestep: float = 0.002,
    textures: TextureParams | None = None,
    camera: StereoCameraParams | None = None,
    magnetic_field: tuple[float, float, float] = (0.15, 0.0, -0.48),
) -> mujoco.MjSpec:
    """The world spec: the tank with every robot attached at its start pose (``name/`` prefix).

    ``magnetic_field`` (Gauss, world frame) points north along +x with a steep
    inclination, roughly as in Trondheim (about 73 deg down).
    """
    spec = build_tank_spec(tank, textures)
    spec.option.timestep = timestep
    spec.option.magnetic = list(magnetic_field)
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.nuserdata = userdata_size(len(robots))
    for placement in robots:
        frame = spec.worldbody.add_frame(
            pos=list(placement.position),
            quat=[math.cos(placement.yaw / 2), 0, 0, math.sin(placement.yaw / 2)],
        )
        spec.attach(build_robot_spec(placement.vehicle, camera), prefix=f"{placement.name}/", frame=frame)
    return spec
