"""Vehicle sensors: IMU, depth (pressure), DVL, compass; and ground truth, kept apart.

MuJoCo computes the ideal signals (accelerometer, gyro, magnetometer, velocimeter,
rangefinders, site position); this module adds what real sensors add: white noise
and, for the IMU, a bias that random-walks; the DVL drops out when a beam finds no
bottom within range. Noise is drawn from the simulation's seeded generator, so a
run is reproducible.

Conventions: body frame x forward, y left, z up. The accelerometer reads specific
force (about +9.81 m/s^2 on z at rest). Compass heading is degrees clockwise from
magnetic north, which is the world +x axis (towards the end wall).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from maptidal.envs.world import ROBOT_SENSORS

WATER_DENSITY = 1000.0  # kg/m^3, fresh water tank
ATMOSPHERE_PA = 101325.0
SENSORS = ("imu", "depth", "dvl", "compass", "stereo")


@dataclass(frozen=True)
class SensorNoise:
    """Noise levels; defaults are typical of a BlueROV2's Pixhawk IMU, Bar30 and DVL A50.

    White-noise standard deviations per sample, and bias random-walk rates per
    sqrt(s). Set everything to 0 for ideal sensors.
    """

    accel_sigma: float = 0.02  # m/s^2
    accel_bias_walk: float = 0.001  # m/s^2/sqrt(s)
    gyro_sigma: float = 0.002  # rad/s
    gyro_bias_walk: float = 0.0001  # rad/s/sqrt(s)
    depth_sigma: float = 0.002  # m (Bar30: 2 mm resolution)
    dvl_sigma: float = 0.005  # m/s
    compass_sigma_deg: float = 1.0

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"sensor noise {name} must be finite and >= 0, got {value!r}")


class RobotSensors:
    """Reads one robot's sensors from MuJoCo and adds noise and bias."""

    def __init__(
        self,
        model: mujoco.MjModel,
        prefix: str,
        enabled: tuple[str, ...],
        noise: SensorNoise,
        dvl_range: tuple[float, float],
        water_depth: float,
    ) -> None:
        self.enabled = enabled
        self.noise = noise
        self.dvl_range = dvl_range
        self.water_depth = water_depth
        self.body_id = int(model.body(f"{prefix}base").id)
        self._slices = {}
        for name, _, _ in ROBOT_SENSORS:
            sensor = model.sensor(f"{prefix}{name}")
            self._slices[name] = slice(sensor.adr[0], sensor.adr[0] + sensor.dim[0])
        self.accel_bias = np.zeros(3)
        self.gyro_bias = np.zeros(3)
        # the specific force (m/s^2, body) averaged over the last control period, as the simulation
        # measures it from the body's velocity change (Simulation.advance_physics); None: not flown yet
        self.mean_specific_force: np.ndarray | None = None

    def reset(self, rng: np.random.Generator) -> None:
        """Draw fresh IMU biases (one bias-walk step's worth of spread)."""
        self.accel_bias = rng.normal(0.0, self.noise.accel_bias_walk, 3)
        self.gyro_bias = rng.normal(0.0, self.noise.gyro_bias_walk, 3)
        self.mean_specific_force = None

    def advance(self, dt: float, rng: np.random.Generator) -> None:
        """Let the IMU biases random-walk over ``dt`` seconds."""
        root = math.sqrt(dt)
        self.accel_bias += rng.normal(0.0, self.noise.accel_bias_walk * root, 3)
        self.gyro_bias += rng.normal(0.0, self.noise.gyro_bias_walk * root, 3)

    def read(self, data: mujoco.MjData, rng: np.random.Generator) -> dict:
        """Noisy readings of the enabled sensors, as plain floats and lists."""
        raw = {name: data.sensordata[s].copy() for name, s in self._slices.items()}
        n = self.noise
        out: dict = {}
        if "imu" in self.enabled:
            accel_noise = rng.normal(0, n.accel_sigma, 3)
            mean = raw["accelerometer"] if self.mean_specific_force is None else self.mean_specific_force
            out["imu"] = {
                "accel": (raw["accelerometer"] + self.accel_bias + accel_noise).tolist(),
                "gyro": (raw["gyro"] + self.gyro_bias + rng.normal(0, n.gyro_sigma, 3)).tolist(),
                # the last control period's mean (its velocity change over its length, as a real IMU's
                # delta velocity gives it: ArduPilot's estimators read AP_InertialSensor's
                # get_delta_velocity), with the same bias and noise draw as the sample
                "accel_mean": (mean + self.accel_bias + accel_noise).tolist(),
            }
        if "depth" in self.enabled:
            depth = self.water_depth - float(raw["depth_pos"][2]) + rng.normal(0, n.depth_sigma)
            out["depth"] = {"depth_m": depth, "pressure_pa": ATMOSPHERE_PA + WATER_DENSITY * 9.81 * depth}
        if "dvl" in self.enabled:
            ranges = np.array([raw[f"beam{k}"][0] for k in range(4)])
            low, high = self.dvl_range
            valid = bool(np.all((ranges >= low) & (ranges <= high)))
            velocity = raw["velocimeter"] + rng.normal(0, n.dvl_sigma, 3)
            out["dvl"] = {
                "velocity_body": velocity.tolist() if valid else None,
                "beam_ranges_m": [float(r) if low <= r <= high else None for r in ranges],
                "valid": valid,
            }
        if "compass" in self.enabled:
            field = raw["magnetometer"]
            # tilt compensation with the vehicle's attitude, as the autopilot's AHRS provides it
            # (raw accelerometer tilt is off by the vehicle's own acceleration)
            up_body = data.xmat[self.body_id].reshape(3, 3)[2]
            heading = heading_from_field(field, up_body)
            out["compass"] = {
                "heading_deg": float((heading + rng.normal(0, n.compass_sigma_deg)) % 360.0),
                "field_gauss": field.tolist(),
            }
        return out


def heading_from_field(field_body: np.ndarray, up_body: np.ndarray) -> float:
    """Tilt-compensated compass heading (deg clockwise from north) from the body-frame field.

    ``up_body`` is the world vertical in body axes (any length); the field's
    horizontal part gives north.
    """
    # plain floats: numpy costs more than the arithmetic on 3-vectors, and this runs every control period
    ux, uy, uz = np.asarray(up_body, float).tolist()
    norm = math.sqrt(ux * ux + uy * uy + uz * uz)
    ux, uy, uz = ux / norm, uy / norm, uz / norm
    fx, fy, fz = np.asarray(field_body, float).tolist()
    along = fx * ux + fy * uy + fz * uz
    hx, hy, hz = fx - along * ux, fy - along * uy, fz - along * uz  # the field's horizontal part
    ax, ay, az = 1.0 - ux * ux, -ux * uy, -ux * uz  # body forward, made horizontal
    lx, ly, lz = uy * az - uz * ay, uz * ax - ux * az, ux * ay - uy * ax  # up x forward: left
    # angle from north to forward, clockwise seen from above
    angle = math.atan2(hx * lx + hy * ly + hz * lz, hx * ax + hy * ay + hz * az)
    return math.degrees(angle) % 360.0
