"""The compiled flight stack: :meth:`Simulation.step_periods` runs many control periods in one call to C.

Per control period the Python :meth:`~maptidal.envs.simulation.Simulation.step` runs each robot's flight
mode, mixer, thrust linearisation and thrust curve, steps the physics, counts the odometry, walks the IMU
biases, reads the sensors with noise and updates each estimator: about 0.2 ms of Python against 0.05 ms
of physics. ``_flight.c`` does the same operation for operation, so an environment step costs little
more than its physics. The Python classes stay the reference and the documentation
(``tests/test_native_flight.py`` flies both and compares them), and keep the state between calls: each
call packs what the C needs from them and writes what it changed back, so ``get_state``, ``estimate``
and everything else read the same objects whichever path ran.

The noise is the simulation's own generator's: the standard normal draws are made up front in the order
the Python path draws them, so both paths see the same noise. The C path needs the C hydrodynamics
callback (a numpy callback cannot run inside a C loop) and a C compiler; ``Simulation(...,
flight_backend="python")`` or ``MAPTIDAL_FLIGHT=python`` chooses the Python path.
"""

from __future__ import annotations

import ctypes
import logging
import os
import weakref
from pathlib import Path

import numpy as np

from maptidal.controllers.flight_modes import FLIGHT_MODES
from maptidal.controllers.mixing import _FORWARD_COUPLING_DIRECTION, FRAMES
from maptidal.controllers.pose import _force_matrix
from maptidal.envs import hydrodynamics
from maptidal.envs.native_build import build_library

log = logging.getLogger(__name__)

_SOURCE = Path(__file__).with_name("_flight.c")
MAX_THRUSTERS = 8
FLIGHT_BACKENDS = ("native", "python")

_library: ctypes.CDLL | None = None
_tried = False
_layouts: dict[int, dict[str, tuple[int, int]]] = {}


def library() -> ctypes.CDLL | None:
    """The compiled flight stack, built on first use; None without a C compiler."""
    global _library, _tried
    if not _tried:
        _tried = True
        path = build_library(_SOURCE, "flight", link_mujoco=True)
        if path is not None:
            try:
                lib = ctypes.CDLL(str(path))
                lib.maptidal_flight_layout.restype = ctypes.c_int
                lib.maptidal_flight_layout.argtypes = [
                    ctypes.c_int,
                    ctypes.c_int,
                    ctypes.POINTER(ctypes.c_char_p),
                    ctypes.POINTER(ctypes.c_int),
                ]
                # pointers travel as addresses (c_void_p): numpy's ctypes.data_as costs microseconds a call
                pointer = ctypes.c_void_p
                # periods, substeps per period, period (s), path step (m)
                timing = [ctypes.c_int, ctypes.c_int, ctypes.c_double, ctypes.c_double]
                lib.maptidal_flight_periods.restype = ctypes.c_int
                lib.maptidal_flight_periods.argtypes = [
                    pointer,  # mjModel*
                    pointer,  # mjData*
                    pointer,  # params, double per robot block
                    pointer,  # state, double per robot block
                    ctypes.c_int,  # robots
                    pointer,  # estimator order, int
                    ctypes.c_int,  # estimators
                    *timing,
                    pointer,  # noise, double
                    pointer,  # currents, double, or NULL
                    pointer,  # current slots, int
                    pointer,  # per period out, double
                    pointer,  # wall time in mj_step (s), double
                ]
                lib.maptidal_flight_batch.restype = None
                lib.maptidal_flight_batch.argtypes = [
                    ctypes.c_int,  # simulations
                    pointer,  # their mjModel*, an array
                    pointer,  # their mjData*, an array
                    pointer,  # params, a double block per simulation
                    pointer,  # state, a double block per simulation
                    pointer,  # active, int per simulation
                    *timing,
                    pointer,  # noise, double
                    ctypes.c_int,  # draws per simulation
                    pointer,  # currents, double (simulations x periods x 3)
                    pointer,  # blowing, int per simulation
                    ctypes.c_int,  # where a robot's current lives in userdata
                    pointer,  # per period out, double (simulations x periods x 2)
                    pointer,  # ran, int per simulation
                    pointer,  # wall time in mj_step (s), double, summed over threads
                    ctypes.c_int,  # threads
                ]
                _library = lib
            except OSError as error:
                log.debug("cannot load the flight library %s: %s", path, error)
    return _library


def layout(which: int) -> dict[str, tuple[int, int]]:
    """Field name to (offset, size) of the C side's parameter (0) or state (1) block, as the C declares
    them; ``"__size__"`` holds the block's size."""
    if which not in _layouts:
        lib = library()
        fields: dict[str, tuple[int, int]] = {}
        name, size = ctypes.c_char_p(), ctypes.c_int()
        k = 0
        while (offset := lib.maptidal_flight_layout(which, k, ctypes.byref(name), ctypes.byref(size))) >= 0:
            fields[name.value.decode()] = (offset, size.value)
            k += 1
        fields["__size__"] = (lib.maptidal_flight_layout(which, -1, None, None), 0)
        _layouts[which] = fields
    return _layouts[which]


def check_flight_backend(backend: str) -> str:
    """``backend`` if it names a flight backend, else ValueError."""
    if backend not in FLIGHT_BACKENDS:
        raise ValueError(f"flight_backend must be one of {FLIGHT_BACKENDS}, got {backend!r}")
    return backend


def native_available(hydrodynamics_backend: str | None) -> bool:
    """Whether the compiled flight stack can run: the library builds and loads, and the installed
    hydrodynamics callback is the C one (or none)."""
    if os.environ.get("MAPTIDAL_FLIGHT", "native") == "python":
        return False
    return hydrodynamics_backend in ("native", None) and library() is not None


# the state block's fields, in the C's order (checked against its layout when a NativeFlight is made)
STATE_ORDER = (
    *(("PILOT", 6), ("FC_TIME", 1), ("HEADING", 1), ("HEADING_SET", 1), ("LAST_YAW_INPUT", 1)),
    *(("SATURATED", 3), ("RATE_PID", 15), ("DZ_INTEGRAL", 1), ("DZ_TARGET", 1), ("DZ_TARGET_SET", 1)),
    *(("DZ_CLIMB", 1), ("DZ_LIMIT", 1), ("DZ_VEL_ERROR", 1), ("XY_INTEGRAL", 2), ("XY_LAST_ERROR", 2)),
    *(("XY_LAST_SET", 1), ("HOLD_XY", 2), ("HOLD_SET", 1)),
    *(("QUAT", 4), ("POSITION", 3), ("RPY", 3), ("VELOCITY", 3), ("RATES", 3), ("EST_TIME", 1)),
    *(("ACCEL_WORLD", 3), ("VELOCITY_WORLD", 3), ("THRUST_LAGGED", 3), ("MODELLED_LAST", 1)),
    *(("ACCEL_BIAS", 3), ("GYRO_BIAS", 3), ("ACCEL_MEAN", 3), ("ACCEL_MEAN_SET", 1)),
    *(("R_ACCEL", 3), ("R_GYRO", 3), ("R_ACCEL_MEAN", 3), ("R_DEPTH", 1), ("R_PRESSURE", 1)),
    *(("R_DVL_VELOCITY", 3),),
    *(("R_BEAMS", 4), ("R_DVL_VALID", 1), ("R_HEADING", 1), ("R_FIELD", 3), ("R_THRUST", 3)),
    *(("R_THRUST_SET", 1), ("OUTPUTS", MAX_THRUSTERS), ("OUTPUTS_SET", 1), ("PATH", 1), ("ENERGY", 1)),
    *(("CONTACT_S", 1), ("VERTEX", 3), ("VERTEX_SET", 1)),
)
_ZEROS = [0.0] * 64


def _curve(curve) -> list[float]:
    return [
        curve.max_forward_n,
        curve.max_reverse_n,
        curve.deadband_us,
        curve.forward_shape,
        curve.reverse_shape,
    ]


def _pwm(pwm_range) -> list[float]:
    return [pwm_range.pwm_min_us, pwm_range.pwm_max_us]


def _noise_params(noise) -> dict[str, float]:
    """The sensor noise levels (:class:`maptidal.envs.sensors.SensorNoise`)."""
    return {
        "ACCEL_SIGMA": noise.accel_sigma,
        "ACCEL_WALK": noise.accel_bias_walk,
        "GYRO_SIGMA": noise.gyro_sigma,
        "GYRO_WALK": noise.gyro_bias_walk,
        "DEPTH_SIGMA": noise.depth_sigma,
        "DVL_SIGMA": noise.dvl_sigma,
        "COMPASS_SIGMA_DEG": noise.compass_sigma_deg,
    }


def _mixer_params(mixer) -> dict[str, object]:
    """ArduSub's frame factors and forward-vertical coupling (:mod:`maptidal.controllers.mixing`)."""
    values: dict[str, object] = {
        "MIX_6DOF": mixer.frame == "vectored_6dof",
        "MIX_COUPLING": mixer.forward_vertical_coupling,
        "MIX_FACTORS": FRAMES[mixer.frame],
    }
    if mixer.frame == "vectored":
        values["MIX_REAR"] = _FORWARD_COUPLING_DIRECTION
    return values


def _thrust_params(plant, gains, believed, mode_params) -> dict[str, object]:
    """The plant's thrust curve, gains and power law (what the physics pushes with), and the believed
    curve the flight modes linearise against."""
    power = plant.thruster.power
    return {
        "PLANT_CURVE": _curve(plant.thruster.curve),
        "PLANT_PWM": _pwm(plant.thruster.pwm_range),
        "GAINS": gains,
        "POWER": [
            power.forward_coefficient,
            power.forward_exponent,
            power.reverse_coefficient,
            power.reverse_exponent,
        ],
        "LINEARISE": mode_params.linearise_thrust,
        "LIN_CURVE": _curve(believed.thruster.curve),
        "LIN_PWM": _pwm(believed.thruster.pwm_range),
    }


def _body_force_params(model) -> dict[str, object]:
    """What the estimator takes the thrusters' commanded force from without a DVL fix
    (:meth:`maptidal.controllers.pose.VehicleModel.body_force`)."""
    n = len(model.thruster_positions)
    matrix = np.zeros((3, MAX_THRUSTERS))
    matrix[:, :n] = _force_matrix(model)
    linear = model.thrust_curve is None
    return {
        "BF_LINEAR": linear,
        "BF_CURVE": [model.max_forward_n, model.max_reverse_n, 0.0, 0.0, 0.0]
        if linear
        else _curve(model.thrust_curve),
        "BF_PWM": _pwm(model.pwm_range),
        "BF_MATRIX": matrix,
    }


def _estimator_params(params) -> dict[str, object]:
    """:class:`maptidal.controllers.estimation.EstimatorParams` and its motion model."""
    values: dict[str, object] = {
        "SURFACE_Z": params.surface_z_m,
        "DEPTH_SENSOR_POS": params.depth_sensor_position,
        "DVL_POS": params.dvl_position,
        "TILT_K": params.tilt_correction_rad_s,
        "HEADING_K": params.heading_correction_rad_s,
    }
    model = params.motion_model
    if model is not None:
        values.update(
            HAS_MOTION_MODEL=True,
            MM_INERTIA=model.inertia,
            MM_LINEAR=model.linear_damping,
            MM_QUADRATIC=model.quadratic_damping,
            MM_BUOYANCY=model.net_buoyancy_n,
            MM_LAG=model.thrust_lag_s,
        )
    return values


def _flight_params(controller) -> dict[str, object]:
    """A flight controller's mode, stick scaling, rate-loop gains and position-control gains."""
    m = controller.params
    g = controller.depth_control.gains
    return {
        "MODE": FLIGHT_MODES.index(controller.mode),
        "MAX_LEAN_DEG": m.max_lean_deg,
        "MAX_YAW_RATE_DEG_S": m.max_yaw_rate_deg_s,
        "RP_DZ": m.roll_pitch_dead_zone,
        "YAW_DZ": m.yaw_dead_zone,
        "THR_DZ": m.throttle_dead_zone,
        "TRANS_DZ": m.translation_dead_zone,
        "RATE_RP": _acpid_gains(controller.rate[0].gains),
        "RATE_YAW": _acpid_gains(controller.rate[2].gains),
        "POS_GAINS": [
            g.pos_z_p,
            g.vel_z_p,
            g.acc_z_p,
            g.acc_z_i,
            g.acc_z_imax,
            g.pilot_speed_up_m_s,
            g.pilot_speed_down_m_s,
            g.pilot_accel_z_m_s2,
            g.surface_depth_m,
            g.pos_xy_p,
            g.vel_xy_p,
            g.vel_xy_i,
            g.vel_xy_d,
            g.vel_xy_imax_cm_s2,
            g.angle_max_deg,
            g.max_speed_m_s,
        ],
        "FC_SURFACE_Z": controller.depth_control.surface_z_m,
    }


def _acpid_gains(g) -> list[float]:
    return [g.kp, g.ki, g.kd, g.imax, g.target_filter_hz, g.error_filter_hz, g.derivative_filter_hz]


class _Block:
    """One flat block of doubles with named fields (a view of the C layout)."""

    def __init__(self, which: int) -> None:
        self.fields = layout(which)
        self.size = self.fields["__size__"][0]

    def index(self, name: str) -> int:
        """Where field ``name`` starts in the block."""
        return self.fields[name][0]


class NativeFlight:
    """The compiled flight stack of one :class:`~maptidal.envs.simulation.Simulation` (which owns it)."""

    def __init__(self, sim, path_step_m: float) -> None:
        # a weak reference: the simulation owns this object, and a cycle would leave it (and its GL
        # context) to the cyclic garbage collector, which may close a context in the middle of a render
        self._sim = weakref.ref(sim)
        self.path_step_m = path_step_m
        self.lib = library()
        self.params_block = _Block(0)
        self.state_block = _Block(1)
        n = len(sim.robots)
        self.params = np.zeros((n, self.params_block.size))
        self.state = np.zeros((n, self.state_block.size))
        self._params_key: list[tuple | None] = [None] * n
        self._supported_key: tuple | None = None
        self._supported = False
        self.wall = np.zeros(1)
        self._current_slots = np.array(
            [hydrodynamics.HEADER + k * hydrodynamics.BLOCK + hydrodynamics.SLOT_CURRENT for k in range(n)],
            dtype=np.intc,
        )
        fields = self.state_block.fields
        order = tuple((name, size) for name, (_, size) in fields.items() if name != "__size__")
        if order != STATE_ORDER:
            raise RuntimeError(f"_flight.c's state layout is not the one native_flight.py packs: {order}")
        self._offsets = {name: offset for name, (offset, _) in fields.items()}
        self._flight_size = self._offsets["QUAT"]
        self._estimate_size = self._offsets["ACCEL_BIAS"] - self._offsets["QUAT"]
        self._readings_size = self._offsets["OUTPUTS"] - self._offsets["R_ACCEL"]
        # the arrays that live as long as this object, and their addresses for the C call
        self._noise = np.zeros(0)
        self._per_period = np.zeros((0, n, 2))
        self._addresses = (
            self.params.ctypes.data,
            self.state.ctypes.data,
            self._current_slots.ctypes.data,
            self.wall.ctypes.data,
        )

    @property
    def sim(self):
        """The simulation this stack flies."""
        return self._sim()

    # ----- packing ------------------------------------------------------------------------------
    def _key(self, robot: str) -> tuple:
        """The objects ``robot``'s parameters come from; a new object anywhere means packing again (they
        are frozen dataclasses or replaced whole, never changed in place)."""
        sim = self.sim
        autopilot = sim._autopilots.get(robot)
        controller = autopilot.controller if autopilot is not None else None
        estimator = sim._estimators.get(robot)
        return (
            controller,
            estimator,
            sim._plants[robot],
            sim._thruster_gains[robot],
            sim._sensors[robot].noise,
            sim._mixers[robot],
            sim.mode_params,
            controller.params if controller is not None else None,
            estimator.params if estimator is not None else None,
            sim._vehicle_models[robot],
        )

    def _pack_params(self, k: int, robot: str) -> None:
        """Write ``robot``'s parameters into its block, when any object they come from has changed."""
        sim = self.sim
        key = self._key(robot)
        old = self._params_key[k]
        if old is not None and all(a is b for a, b in zip(old, key, strict=True)):
            return
        controller, estimator, plant, gains, noise, mixer, mode_params, *_ = key
        values = {
            **self._robot_params(robot),
            **_noise_params(noise),
            **_mixer_params(mixer),
            **_thrust_params(plant, gains, sim._specs[robot].vehicle, mode_params),
            **_body_force_params(sim._vehicle_models[robot]),
        }
        values["HAS_AUTOPILOT"] = controller is not None
        values["HAS_ESTIMATOR"] = estimator is not None
        if estimator is not None:
            values.update(_estimator_params(estimator.params))
        if controller is not None:
            values.update(_flight_params(controller))
        row = self.params[k]
        row[:] = 0.0
        for name, value in values.items():
            flat = np.ravel(np.asarray(value, float))
            offset = self.params_block.index(name)
            row[offset : offset + len(flat)] = flat
        self._params_key[k] = key

    def _robot_params(self, robot: str) -> dict[str, object]:
        """Where ``robot`` lives in the model and which sensors it reads, and where."""
        sim = self.sim
        slot = sim._slots[robot]
        sensors = sim._sensors[robot]
        starts = {name: s.start for name, s in sensors._slices.items()}
        return {
            "N_THR": sim._specs[robot].vehicle.n_thrusters,
            "CTRL_ADR": sim._ctrl_adr[robot],
            "ACT_ADR": slot.act_adr,
            "QPOS_ADR": sim._position_adr[robot],
            "DOF_ADR": slot.dof_adr,
            "BODY_ID": slot.body_id,
            "EN_IMU": "imu" in sensors.enabled,
            "EN_DEPTH": "depth" in sensors.enabled,
            "EN_DVL": "dvl" in sensors.enabled,
            "EN_COMPASS": "compass" in sensors.enabled,
            "ADR_ACCEL": starts["accelerometer"],
            "ADR_GYRO": starts["gyro"],
            "ADR_MAG": starts["magnetometer"],
            "ADR_VELOCIMETER": starts["velocimeter"],
            "ADR_DEPTH_POS": starts["depth_pos"],
            "ADR_BEAM": [starts[f"beam{j}"] for j in range(4)],
            "DVL_LOW": sensors.dvl_range[0],
            "DVL_HIGH": sensors.dvl_range[1],
            "WATER_DEPTH": sensors.water_depth,
        }

    def supported(self) -> bool:
        """Whether every robot's configuration is one the C side flies as the Python does: at most
        :data:`MAX_THRUSTERS` thrusters, roll and pitch rate loops with one set of gains, and the
        horizontal position loop with the depth loop's gains (worked out again when an autopilot
        changes)."""
        key = tuple(autopilot.controller for autopilot in self.sim._autopilots.values())
        old = self._supported_key
        if old is None or len(old) != len(key) or any(a is not b for a, b in zip(old, key, strict=True)):
            self._supported_key, self._supported = key, self._check_supported()
        return self._supported

    def _check_supported(self) -> bool:
        for robot in self.sim.robots:
            if self.sim._specs[robot].vehicle.n_thrusters > MAX_THRUSTERS:
                return False
            autopilot = self.sim._autopilots.get(robot)
            if autopilot is not None:
                c = autopilot.controller
                if c.rate[0].gains != c.rate[1].gains or c.position_control.gains != c.depth_control.gains:
                    return False
        return True

    def _pack_state(self, k: int, robot: str) -> None:
        """Write ``robot``'s state from the Python objects into its block, as one list in the C layout's
        order (:data:`STATE_ORDER`)."""
        sim = self.sim
        values: list[float] = []
        autopilot = sim._autopilots.get(robot)
        if autopilot is not None:
            c = autopilot.controller
            d, h = c.depth_control, c.position_control
            values += autopilot.pilot.tolist()
            values += (
                c.time_s,
                c._heading or 0.0,
                c._heading is not None,
                c._last_yaw_input_s,
                *c._saturated,
            )
            for pid in c.rate:
                values += (pid.integrator, pid._reset_filter, pid._target, pid._error, pid._derivative)
            values += (d._integral, d.target_z or 0.0, d.target_z is not None, d.target_climb_m_s, d.limit)
            values += (d._velocity_error, *h._integral.tolist())
            values += (0.0, 0.0, False) if h._last_error is None else (*h._last_error.tolist(), True)
            values += (0.0, 0.0, False) if c._hold_xy is None else (*c._hold_xy.tolist(), True)
        else:
            values += _ZEROS[: self._flight_size]
        estimator = sim._estimators.get(robot)
        if estimator is not None:
            e = estimator.state
            values += estimator.quaternion.tolist()
            values += e.position.tolist()
            values += e.rpy.tolist()
            values += e.velocity_body.tolist()
            values += e.angular_velocity_body.tolist()
            values.append(e.time_s)
            values += e.acceleration_world.tolist()
            values += estimator._velocity_world.tolist()
            values += estimator.thrust_lagged.tolist()
            values.append(estimator.modelled_last)
        else:
            values += _ZEROS[: self._estimate_size]
        sensors = sim._sensors[robot]
        values += sensors.accel_bias.tolist()
        values += sensors.gyro_bias.tolist()
        mean = sensors.mean_specific_force
        values += (0.0, 0.0, 0.0, False) if mean is None else (*mean.tolist(), True)
        values += _ZEROS[: self._readings_size]
        outputs = sim._thruster_outputs.get(robot)
        if outputs is None:
            values += _ZEROS[: MAX_THRUSTERS + 1]
        else:
            values += outputs.tolist()
            values += _ZEROS[: MAX_THRUSTERS - len(outputs)]
            values.append(1.0)
        odometry = sim._odometry[robot]
        values += (odometry.path_m, odometry.thruster_energy_j, odometry.contact_s)
        vertex = odometry.last_vertex
        values += (0.0, 0.0, 0.0, False) if vertex is None else (*vertex, True)
        self.state[k] = values

    def _unpack_state(self, k: int, robot: str) -> None:
        """Write what the C changed of ``robot``'s state back into the Python objects."""
        sim = self.sim
        v = self.state[k].tolist()
        o = self._offsets
        autopilot = sim._autopilots.get(robot)
        if autopilot is not None:
            c = autopilot.controller
            c.time_s = v[o["FC_TIME"]]
            c._heading = v[o["HEADING"]] if v[o["HEADING_SET"]] else None
            c._last_yaw_input_s = v[o["LAST_YAW_INPUT"]]
            j = o["SATURATED"]
            c._saturated = [v[j] != 0.0, v[j + 1] != 0.0, v[j + 2] != 0.0]
            j = o["RATE_PID"]
            for pid in c.rate:
                pid.integrator, reset, pid._target, pid._error, pid._derivative = v[j : j + 5]
                pid._reset_filter = reset != 0.0
                j += 5
            d = c.depth_control
            d._integral = v[o["DZ_INTEGRAL"]]
            d.target_z = v[o["DZ_TARGET"]] if v[o["DZ_TARGET_SET"]] else None
            d.target_climb_m_s = v[o["DZ_CLIMB"]]
            d.limit = int(v[o["DZ_LIMIT"]])
            d._velocity_error = v[o["DZ_VEL_ERROR"]]
            h = c.position_control
            j = o["XY_INTEGRAL"]
            h._integral = np.array(v[j : j + 2])
            j = o["XY_LAST_ERROR"]
            h._last_error = np.array(v[j : j + 2]) if v[o["XY_LAST_SET"]] else None
            j = o["HOLD_XY"]
            c._hold_xy = np.array(v[j : j + 2]) if v[o["HOLD_SET"]] else None
        estimator = sim._estimators.get(robot)
        row = self.state[k]
        if estimator is not None:
            e = estimator.state
            j = o["QUAT"]
            estimator.quaternion = row[j : j + 4].copy()
            # in place where the Python updates in place, so a reference someone holds moves alike
            e.position[:] = row[j + 4 : j + 7]
            e.rpy[:] = row[j + 7 : j + 10]
            e.velocity_body = row[j + 10 : j + 13].copy()
            e.angular_velocity_body = row[j + 13 : j + 16].copy()
            e.time_s = v[j + 16]
            e.acceleration_world = row[j + 17 : j + 20].copy()
            estimator._velocity_world = row[j + 20 : j + 23].copy()
            estimator.thrust_lagged = row[j + 23 : j + 26].copy()
            estimator.modelled_last = v[j + 26] != 0.0
            sim._readings[robot] = self._readings(robot, v)
        sensors = sim._sensors[robot]
        j = o["ACCEL_BIAS"]
        sensors.accel_bias[:] = row[j : j + 3]
        sensors.gyro_bias[:] = row[j + 3 : j + 6]
        j = o["ACCEL_MEAN"]
        sensors.mean_specific_force = row[j : j + 3].copy() if v[o["ACCEL_MEAN_SET"]] else None
        if v[o["OUTPUTS_SET"]]:
            j = o["OUTPUTS"]
            sim._thruster_outputs[robot] = row[j : j + sim._specs[robot].vehicle.n_thrusters].copy()
        odometry = sim._odometry[robot]
        j = o["PATH"]
        odometry.path_m, odometry.thruster_energy_j, odometry.contact_s = v[j : j + 3]
        j = o["VERTEX"]
        odometry.last_vertex = tuple(v[j : j + 3]) if v[o["VERTEX_SET"]] else None

    def blocks(self, robot: str) -> tuple[np.ndarray, np.ndarray]:
        """``robot``'s parameter and state blocks as its simulation's objects hold them now, its last
        readings included (copies): where a batch that flies the robot in its own blocks starts from."""
        k = self.sim.robots.index(robot)
        self._pack_params(k, robot)
        self._pack_state(k, robot)
        state = self.state[k].copy()
        readings, o = self.sim._readings.get(robot, {}), self._offsets

        def put(name: str, values) -> None:
            values = np.ravel(np.asarray(values, float))
            state[o[name] : o[name] + len(values)] = values

        if "imu" in readings:
            put("R_ACCEL", readings["imu"]["accel"])
            put("R_GYRO", readings["imu"]["gyro"])
            put("R_ACCEL_MEAN", readings["imu"]["accel_mean"])
        if "depth" in readings:
            put("R_DEPTH", readings["depth"]["depth_m"])
            put("R_PRESSURE", readings["depth"]["pressure_pa"])
        if "dvl" in readings:
            dvl = readings["dvl"]
            put("R_DVL_VALID", dvl["valid"])
            if dvl["velocity_body"] is not None:
                put("R_DVL_VELOCITY", dvl["velocity_body"])
        if "compass" in readings:
            put("R_HEADING", readings["compass"]["heading_deg"])
            put("R_FIELD", readings["compass"]["field_gauss"])
        if "thrust" in readings:
            put("R_THRUST", readings["thrust"]["force_body"])
            put("R_THRUST_SET", 1.0)
        return self.params[k].copy(), state

    def _readings(self, robot: str, v: list[float]) -> dict:
        """The last period's readings as :meth:`RobotSensors.read` gives them (and the thrust reading
        the simulation adds without a DVL fix), from the state's values ``v``."""
        sensors = self.sim._sensors[robot]
        o = self._offsets
        enabled = sensors.enabled
        out: dict = {}
        if "imu" in enabled:
            j = o["R_ACCEL"]
            out["imu"] = {"accel": v[j : j + 3], "gyro": v[j + 3 : j + 6], "accel_mean": v[j + 6 : j + 9]}
        if "depth" in enabled:
            out["depth"] = {"depth_m": v[o["R_DEPTH"]], "pressure_pa": v[o["R_PRESSURE"]]}
        if "dvl" in enabled:
            low, high = sensors.dvl_range
            valid = v[o["R_DVL_VALID"]] != 0.0
            j = o["R_DVL_VELOCITY"]
            beams = v[o["R_BEAMS"] : o["R_BEAMS"] + 4]
            out["dvl"] = {
                "velocity_body": v[j : j + 3] if valid else None,
                "beam_ranges_m": [r if low <= r <= high else None for r in beams],
                "valid": valid,
            }
        if "compass" in enabled:
            j = o["R_FIELD"]
            out["compass"] = {"heading_deg": v[o["R_HEADING"]], "field_gauss": v[j : j + 3]}
        if v[o["R_THRUST_SET"]]:
            j = o["R_THRUST"]
            out["thrust"] = {"force_body": v[j : j + 3]}
        return out

    # ----- running ------------------------------------------------------------------------------
    def draws_per_period(self, estimating: list[str]) -> int:
        """How many standard normal draws one period takes: the bias walks of every robot, then the
        reads of each estimating robot (as :class:`~maptidal.envs.sensors.RobotSensors` draws them)."""
        total = 6 * len(self.sim.robots)
        for robot in estimating:
            enabled = self.sim._sensors[robot].enabled
            total += 6 * ("imu" in enabled) + ("depth" in enabled) + 3 * ("dvl" in enabled)
            total += "compass" in enabled
        return total

    def run(self, n_periods: int, currents: np.ndarray | None) -> tuple[np.ndarray, int]:
        """Fly ``n_periods`` control periods; per period and robot (mean squared thruster output,
        touching), and how many periods ran (fewer when the state went bad in the next)."""
        sim = self.sim
        robots = sim.robots
        for k, robot in enumerate(robots):
            self._pack_params(k, robot)
            self._pack_state(k, robot)
        estimating = list(sim._estimators)
        order = self._order(estimating)
        draws = n_periods * self.draws_per_period(estimating)
        if len(self._noise) < draws:
            self._noise = np.zeros(draws)
            self._noise_address = self._noise.ctypes.data
        sim.rng.standard_normal(out=self._noise[:draws])
        if self._per_period.shape[0] != n_periods:
            self._per_period = np.zeros((n_periods, len(robots), 2))
            self._per_period_address = self._per_period.ctypes.data
        per_period = self._per_period
        self.wall[0] = 0.0
        if currents is not None:
            currents = np.ascontiguousarray(currents, float)
        scenario = sim.scenario
        params, state, current_slots, wall = self._addresses
        ran = self.lib.maptidal_flight_periods(
            sim.model._address,
            sim.data._address,
            params,
            state,
            len(robots),
            self._order_address,
            len(order),
            n_periods,
            scenario.substeps,
            scenario.substeps * scenario.timestep_s,
            self.path_step_m,
            self._noise_address,
            currents.ctypes.data if currents is not None else None,
            current_slots,
            self._per_period_address,
            wall,
        )
        for k, robot in enumerate(robots):
            self._unpack_state(k, robot)
        sim.wall_time_s += float(self.wall[0])
        return per_period.copy(), ran

    def _order(self, estimating: list[str]) -> np.ndarray:
        """The estimating robots' indices, in the order their estimates update (cached)."""
        key = tuple(estimating)
        if getattr(self, "_order_key", None) != key:
            self._order_key = key
            self._order_array = np.array([self.sim.robots.index(r) for r in estimating], dtype=np.intc)
            self._order_address = self._order_array.ctypes.data
        return self._order_array
