"""Fossen hydrodynamics and thrust for BlueROV2s in MuJoCo, applied every physics step.

The model, per robot, in the body frame (x forward, y left, z up, origin at the
centre of gravity; T. I. Fossen, Handbook of Marine Craft Hydrodynamics and Motion
Control, 2011, with diagonal added mass and damping)::

    M_RB nudot + C_RB(nu) nu + M_A nudot_r + C_A(nu_r) nu_r + D(nu_r) nu_r + g(eta) = tau_thrust

- ``C_A(nu_r) nu_r`` (the added-mass Coriolis terms, the Munk moment among them) is
  implemented in full and switched per vehicle (``added_mass_coriolis``): on for the
  Heavy, off for the standard frame (assets/bluerov2/README.md). With von Benzon's CB
  1 cm above the CG the Heavy's linearised pitch equation is unstable above about 0.48 m/s;
  with the 4.9 cm we use it leans under 20 deg at full surge in MANUAL; STABILIZE holds it level;
- ``nu_r = nu - [R^T v_current; 0]``: damping, added mass and C_A act on the velocity
  relative to an irrotational, constant water current, whose body-frame rate of change
  ``-w x (R^T v_current)`` is part of ``nudot_r``;
- ``D(nu_r) = diag(D_lin) + diag(D_quad) |nu_r|`` (linear and quadratic damping);
- ``g(eta)``: weight at the CG (MuJoCo's gravity) and buoyancy ``B`` straight up at
  the centre of buoyancy, which sits above the CG, so the vehicle rights itself;
  near the surface buoyancy scales with the wet fraction of the hull box's vertical
  extent at its attitude (:func:`hull_wet_fraction`);
- ``tau_thrust``: each thruster's force along its direction at its position: ``a`` times
  full forward thrust (51.4 N at 16 V) or full reverse thrust (39.9 N), fading out across the
  water surface. ``a`` (MuJoCo actuator state) is the normalised thrust after the 0.1 s lag;
  what the lag filters is the static thrust of the command through ArduSub's linear
  command-to-PWM mapping and the T200's measured curve with its deadband
  (:mod:`maptidal.controllers.thrusters`, applied by ``Simulation`` when it sets the controls).

**Added mass.** MuJoCo's body mass is one scalar, and the BlueROV2's added mass is
anisotropic (Heavy: 6.4 kg in surge, 18.7 kg in heave), so it cannot be folded into
the body. Using last step's acceleration (gz-sim's approach) is unstable. Instead,
within each step we compute every other force first and solve the diagonal system
``nudot = (tau_other - M_A c) / (M_RB + M_A)`` exactly, ``c = [w x (R^T v_current); 0]``,
then apply ``-M_A (nudot + c)``. MuJoCo then
moves the rigid body as ``M_RB nudot = tau_other - M_A nudot``, which is the Fossen
equation above: no feedback through a stale acceleration, so it is as stable as
the damping itself. Contact forces are not part of ``tau_other``, so in a collision
the vehicle meets the wall with its dry mass.

**MuJoCo's fluid model is off.** It gives no buoyancy and would count drag twice.

Two implementations share the parameter layout in ``mjData.userdata``: the C
callback in ``_hydro.c`` (built on first use with the system C compiler against
MuJoCo's headers; the default) and :func:`passive_forces` in numpy, used where no
compiler exists and as the reference the C code is tested against. Both are
installed as ``mjcb_passive``, a process-wide MuJoCo hook; models without our
userdata marker are left alone.
"""

from __future__ import annotations

import ctypes
import logging
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from maptidal.envs.native_build import build_library
from maptidal.envs.vehicle import VehicleParams

log = logging.getLogger(__name__)

MAGIC = 4242.0
HEADER = 4  # magic, number of robots, enabled flag, water surface height (m)
BLOCK = 86  # doubles per robot
SLOT_HULL = 80  # hull height (m), for the wet fraction near the surface
SLOT_HULL_LENGTH = (
    83  # hull length and width (m): with the height, the hull's vertical extent at any attitude
)
SLOT_HULL_WIDTH = 84
SLOT_CORIOLIS = 81  # 1.0: include C_A(nu_r) nu_r
SLOT_CURRENT = 26  # the water current (m/s, world), three slots
SLOT_THRUST_FADE = 82  # half-width (m) of a thruster's fade-out at the water surface
MAX_THRUSTERS = 8
_SOURCE = Path(__file__).with_name("_hydro.c")


@dataclass(frozen=True)
class RobotSlot:
    """Where one robot lives in a compiled model: its body, free-joint dofs and thruster acts."""

    body_id: int
    dof_adr: int
    act_adr: int


def userdata_size(n_robots: int) -> int:
    """Number of doubles of ``mjData.userdata`` needed for ``n_robots``."""
    return HEADER + BLOCK * n_robots


def pack_userdata(
    userdata: np.ndarray,
    slots: list[RobotSlot],
    vehicles: list[VehicleParams],
    current_world: np.ndarray | None = None,
    enabled: bool = True,
    water_surface_z: float = 1e9,
) -> None:
    """Write the parameters of every robot into ``userdata`` (an ``mjData.userdata`` view).

    Above ``water_surface_z`` a robot loses buoyancy in proportion to how much of
    its hull is out of the water, so it floats at the surface instead of flying.
    """
    if len(userdata) < userdata_size(len(slots)):
        raise ValueError(f"userdata holds {len(userdata)} doubles, {userdata_size(len(slots))} needed")
    current = np.zeros(3) if current_world is None else np.asarray(current_world, float)
    userdata[:] = 0.0
    userdata[:HEADER] = [MAGIC, len(slots), 1.0 if enabled else 0.0, water_surface_z]
    for k, (slot, vehicle) in enumerate(zip(slots, vehicles, strict=True)):
        if vehicle.n_thrusters > MAX_THRUSTERS:
            raise ValueError(f"at most {MAX_THRUSTERS} thrusters per robot")
        block = np.zeros(BLOCK)
        block[:4] = [slot.body_id, slot.dof_adr, slot.act_adr, vehicle.n_thrusters]
        block[4:10] = vehicle.added_mass
        block[10:16] = vehicle.linear_damping
        block[16:22] = vehicle.quadratic_damping
        block[22] = vehicle.buoyancy_n
        block[23:26] = vehicle.centre_of_buoyancy
        block[SLOT_CURRENT : SLOT_CURRENT + 3] = current
        # full thrust each way: the actuators carry the lagged normalised thrust (Simulation applies the
        # static T200 curve to the commands before the lag)
        block[29:31] = [vehicle.thruster.curve.max_forward_n, vehicle.thruster.curve.max_reverse_n]
        layout = np.hstack([vehicle.thruster_positions, vehicle.thruster_directions]).ravel()
        block[31 : 31 + len(layout)] = layout
        block[SLOT_HULL] = vehicle.hull_size[2]
        block[SLOT_HULL_LENGTH], block[SLOT_HULL_WIDTH] = vehicle.hull_size[:2]
        block[SLOT_CORIOLIS] = 1.0 if vehicle.added_mass_coriolis else 0.0
        block[SLOT_THRUST_FADE] = vehicle.thruster.surface_fade_m
        userdata[HEADER + k * BLOCK : HEADER + (k + 1) * BLOCK] = block


def set_enabled(userdata: np.ndarray, enabled: bool) -> None:
    """Switch the hydrodynamics and thrust of every robot on or off (for baselines)."""
    userdata[2] = 1.0 if enabled else 0.0


def hull_wet_fraction(hull_size, rotation: np.ndarray, cg_z: float, surface_z: float) -> float:
    """How much of the hull is under water, from its vertical extent at its attitude: 1 submerged, 0 out.

    The hull is a box (length, width, height) about the CG; rotated by ``rotation`` (body to world) it
    spans ``cg_z +- h`` with ``h = (|R20| L + |R21| W + |R22| H) / 2``, so a vehicle on its side near the
    surface is judged by its width, not its upright height.
    """
    half = 0.5 * float(np.abs(np.asarray(rotation)[2]) @ np.asarray(hull_size, float))
    if half <= 0:
        return 1.0
    return float(np.clip((surface_z - (cg_z - half)) / (2.0 * half), 0.0, 1.0))


def thruster_wet_fractions(
    thruster_positions: np.ndarray, rotation: np.ndarray, cg_z: float, surface_z: float, fade_m: float
) -> np.ndarray:
    """How much of each thruster's thrust acts: 1 under water, 0 in air, linear across the surface."""
    depth_below = surface_z - (cg_z + np.asarray(thruster_positions, float) @ np.asarray(rotation)[2])
    if fade_m <= 0:
        return (depth_below > 0).astype(float)
    return np.clip(depth_below / (2.0 * fade_m) + 0.5, 0.0, 1.0)


def body_wrench(
    vehicle: VehicleParams,
    rotation: np.ndarray,
    velocity_world: np.ndarray,
    angular_velocity_body: np.ndarray,
    act: np.ndarray,
    gravity: np.ndarray,
    current_world: np.ndarray | None = None,
    wet_fraction: float = 1.0,
    thruster_wet: np.ndarray | None = None,
) -> np.ndarray:
    """The wrench ``(6,)`` [force; torque] at the CG, body frame, that MuJoCo must add.

    ``rotation`` is body-to-world ``(3, 3)``. The result excludes gravity and the
    rigid-body Coriolis terms (MuJoCo computes those) and includes added mass
    solved within the step (see the module docstring). ``thruster_wet`` scales each
    thruster's force (see :func:`thruster_wet_fractions`; default all 1).
    """
    R = np.asarray(rotation, float)
    w = np.asarray(angular_velocity_body, float)
    v = R.T @ np.asarray(velocity_world, float)
    current = np.zeros(3) if current_world is None else np.asarray(current_world, float)
    vr = v - R.T @ current
    nur = np.concatenate([vr, w])
    added = np.asarray(vehicle.added_mass)
    forces = vehicle.thruster.lagged_forces(act)
    if thruster_wet is not None:
        forces = forces * np.asarray(thruster_wet, float)
    positions = np.asarray(vehicle.thruster_positions)
    directions = np.asarray(vehicle.thruster_directions)
    thrust_f = forces @ directions
    thrust = np.concatenate([thrust_f, np.cross(positions, forces[:, None] * directions).sum(axis=0)])
    hydro = -(np.asarray(vehicle.linear_damping) + np.asarray(vehicle.quadratic_damping) * np.abs(nur)) * nur
    buoyancy = wet_fraction * vehicle.buoyancy_n * R.T @ np.array([0.0, 0.0, 1.0])
    hydro[:3] += buoyancy
    hydro[3:] += np.cross(vehicle.centre_of_buoyancy, buoyancy)
    if vehicle.added_mass_coriolis:
        av, aw = added[:3] * vr, added[3:] * w
        hydro[:3] -= np.cross(w, av)
        hydro[3:] -= np.cross(vr, av) + np.cross(w, aw)
    rigid = vehicle.rigid_body_mass()
    gravity_b = vehicle.mass * R.T @ np.asarray(gravity, float)
    coriolis = np.concatenate([vehicle.mass * np.cross(w, v), np.cross(w, rigid[3:] * w)])
    # added mass acts on the relative acceleration: nudot_r = nudot + [w x (R^T v_c); 0] for a constant
    # current seen from a turning body
    current_turn = np.concatenate([np.cross(w, R.T @ current), np.zeros(3)])
    other = thrust + hydro + np.concatenate([gravity_b, np.zeros(3)]) - coriolis - added * current_turn
    nudot = other / (rigid + added)
    return thrust + hydro - added * (nudot + current_turn)


def _robots_in(userdata: np.ndarray):
    for k in range(int(userdata[1])):
        block = userdata[HEADER + k * BLOCK : HEADER + (k + 1) * BLOCK]
        yield block


def passive_forces(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """The numpy implementation of the hydrodynamics callback (same layout as ``_hydro.c``)."""
    ud = data.userdata
    if model.nuserdata < HEADER or ud[0] != MAGIC or ud[2] == 0.0:
        return
    for block in _robots_in(ud):
        body, dof, act, nthr = (int(x) for x in block[:4])
        layout = block[31 : 31 + 6 * nthr].reshape(nthr, 6)
        vehicle = _vehicle_from_block(block, layout, model.body_mass[body], model.body_inertia[body])
        R = data.xmat[body].reshape(3, 3)
        hull = (block[SLOT_HULL_LENGTH], block[SLOT_HULL_WIDTH], block[SLOT_HULL])
        wet = hull_wet_fraction(hull, R, data.xipos[body, 2], ud[3])
        thruster_wet = thruster_wet_fractions(
            layout[:, :3], R, data.xipos[body, 2], ud[3], block[SLOT_THRUST_FADE]
        )
        wrench = body_wrench(
            vehicle,
            R,
            data.qvel[dof : dof + 3],
            data.qvel[dof + 3 : dof + 6],
            data.act[act : act + nthr],
            model.opt.gravity,
            block[26:29],
            wet,
            thruster_wet,
        )
        if not np.all(np.isfinite(wrench)):
            continue
        data.qfrc_passive[dof : dof + 3] += R @ wrench[:3]
        data.qfrc_passive[dof + 3 : dof + 6] += wrench[3:]


def _vehicle_from_block(block, layout, mass, inertia) -> VehicleParams:
    from maptidal.controllers.thrusters import linear_curve
    from maptidal.envs.vehicle import ThrusterParams

    return VehicleParams(
        frame="packed",
        ardusub_frame="",
        mass=float(mass),
        inertia=tuple(float(i) for i in inertia),
        buoyancy_n=float(block[22]),
        centre_of_buoyancy=tuple(block[23:26]),
        added_mass=tuple(block[4:10]),
        linear_damping=tuple(block[10:16]),
        quadratic_damping=tuple(block[16:22]),
        hull_size=(float(block[SLOT_HULL_LENGTH]), float(block[SLOT_HULL_WIDTH]), float(block[SLOT_HULL])),
        thruster_positions=tuple(map(tuple, layout[:, :3])),
        thruster_directions=tuple(map(tuple, layout[:, 3:])),
        thruster=ThrusterParams(
            surface_fade_m=float(block[SLOT_THRUST_FADE]),
            curve=linear_curve(float(block[29]), float(block[30])),  # only its maxima are packed
        ),
        added_mass_coriolis=bool(block[SLOT_CORIOLIS]),
    )


# ----- the native callback ------------------------------------------------------------
_native: ctypes.CDLL | None = None
_installed: str | None = None


def build_native(force: bool = False) -> Path | None:
    """Compile ``_hydro.c`` (once per source and MuJoCo version); the library path, or None.

    Needs a C compiler (``$CC`` or ``cc``) and MuJoCo's headers, which the mujoco
    wheel ships. Failure is not an error: the numpy callback takes over.
    """
    return build_library(_SOURCE, "hydro", force=force)


def install_callback(prefer_native: bool = True) -> str:
    """Install the hydrodynamics as MuJoCo's passive-force callback; returns "native" or "numpy"."""
    global _native, _installed
    if prefer_native and os.environ.get("MAPTIDAL_HYDRO", "native") != "numpy":
        if _native is None:
            path = build_native()
            if path is not None:
                _native = ctypes.CDLL(str(path))
        if _native is not None:
            if _installed != "native":
                mujoco.set_mjcb_passive(_native.maptidal_hydro_passive)
                _installed = "native"
            return "native"
        warnings.warn(
            "no C compiler found: using the numpy hydrodynamics (about 10x slower)",
            RuntimeWarning,
            stacklevel=2,
        )
    if _installed != "numpy":
        mujoco.set_mjcb_passive(passive_forces)
        _installed = "numpy"
    return "numpy"


def uninstall_callback() -> None:
    """Remove the passive-force callback (for baselines: bare MuJoCo with no hydrodynamics)."""
    global _installed
    mujoco.set_mjcb_passive(None)
    _installed = None


def installed_backend() -> str | None:
    """Which callback is installed: "native", "numpy" or None."""
    return _installed
