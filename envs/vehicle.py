"""BlueROV2 vehicle parameters, read from ``assets/bluerov2/bluerov2.toml``.

One dataclass per concern: :class:`ThrusterParams` (T200 curve, PWM range and lag) and
:class:`VehicleParams` (rigid body, Fossen coefficients, thruster layout, hull).
Sources of every number: ``assets/bluerov2/README.md``.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np

from maptidal.controllers.pose import VehicleModel
from maptidal.controllers.thrusters import (
    T200_POWER,
    PwmRange,
    ThrustCurve,
    ThrusterPower,
    linear_curve,
    t200_curve,
)
from maptidal.paths import asset

VEHICLE_FILE = asset("bluerov2", "bluerov2.toml")
FRAMES = ("standard", "heavy")


class VehicleConfigError(ValueError):
    """A vehicle description that cannot be simulated; the message names the value."""


THRUSTER_MODELS = ("t200", "linear")


@dataclass(frozen=True)
class ThrusterParams:
    """Blue Robotics T200 thrusters: the thrust curve, ArduSub's PWM range, the lag and the surface fade.

    model: "t200" (the maker's measured thrust against pulse width at ``voltage_v``, with its deadband;
    :mod:`maptidal.controllers.thrusters`) or "linear" (thrust proportional to command with the same maxima,
    for studies). pwm_min_us, pwm_max_us: ArduSub's MOT_PWM_MIN and MOT_PWM_MAX, through which a
    thruster command maps linearly to pulse width. time_constant_s: first-order lag of the thrust
    towards the curve's static thrust (the curve acts first, as a propeller's speed lags its ESC).
    surface_fade_m: a thruster's thrust fades linearly from full, when its centre is this far
    under the water surface, to none, when it is this far above (half the T200's ~0.1 m duct; a
    propeller in air pushes nothing, and one breaking the surface ventilates). curve: set only to
    replace the curve that model and voltage_v name. power: the electrical power each thruster draws
    against its thrust, for the simulator's energy count (the T200's, fitted to the maker's data)."""

    model: str = "t200"
    voltage_v: float = 16.0
    pwm_min_us: float = 1100.0
    pwm_max_us: float = 1900.0
    time_constant_s: float = 0.1
    surface_fade_m: float = 0.05
    curve: ThrustCurve | None = None
    power: ThrusterPower = T200_POWER

    def __post_init__(self) -> None:
        if self.model not in THRUSTER_MODELS:
            raise VehicleConfigError(
                f"thruster.model {self.model!r}: choose one of {', '.join(THRUSTER_MODELS)}"
            )
        _check_positive("thruster.time_constant_s", [self.time_constant_s])
        _check_positive("thruster.surface_fade_m", [self.surface_fade_m], allow_zero=True)
        try:
            PwmRange(self.pwm_min_us, self.pwm_max_us)
            if self.curve is None:
                curve = t200_curve(self.voltage_v)
                if self.model == "linear":
                    curve = linear_curve(curve.max_forward_n, curve.max_reverse_n)
                object.__setattr__(self, "curve", curve)
        except ValueError as error:
            raise VehicleConfigError(f"thruster: {error}") from None

    @property
    def pwm_range(self) -> PwmRange:
        """ArduSub's thruster output range."""
        return PwmRange(self.pwm_min_us, self.pwm_max_us)

    @property
    def max_forward_n(self) -> float:
        """Thrust (N) at full forward command (with the default PWM range, the curve's maximum)."""
        return float(self.forces([1.0])[0])

    @property
    def max_reverse_n(self) -> float:
        """Thrust magnitude (N) at full reverse command."""
        return float(-self.forces([-1.0])[0])

    def forces(self, commands) -> np.ndarray:
        """Static thrust (N, along each thruster's direction) of thruster commands in [-1, 1]."""
        return self.curve.thrust_from_command(commands, self.pwm_range)

    def normalised_thrust(self, commands) -> np.ndarray:
        """Static thrust of thruster commands as a fraction of full forward (>= 0) or full reverse
        (< 0) thrust: what the actuators' first-order lag filters."""
        forces = self.forces(commands)
        return np.where(forces >= 0, forces / self.curve.max_forward_n, forces / self.curve.max_reverse_n)

    def lagged_forces(self, act) -> np.ndarray:
        """Thrust (N) of the actuators' lagged normalised thrust in [-1, 1]."""
        act = np.asarray(act, float)
        return np.where(act >= 0, act * self.curve.max_forward_n, act * self.curve.max_reverse_n)

    def power_w(self, act: list[float]) -> float:
        """The electrical power (W) the thrusters draw, summed, at the lagged normalised thrusts ``act``:
        :attr:`power` at :meth:`lagged_forces`, in plain Python (see ThrusterPower.total_watts)."""
        forward, reverse = self.curve.max_forward_n, self.curve.max_reverse_n
        return self.power.total_watts([x * forward if x >= 0 else x * reverse for x in act])


@dataclass(frozen=True)
class SensorMounts:
    """Where the sensors sit on the vehicle (m, body frame from the CG)."""

    camera_position: tuple[float, float, float] = (0.22, 0.0, 0.0)
    dvl_position: tuple[float, float, float] = (-0.05, 0.0, -0.12)
    dvl_beam_angle_deg: float = 22.5
    dvl_min_range_m: float = 0.05
    dvl_max_range_m: float = 50.0


@dataclass(frozen=True)
class VehicleParams:
    """A BlueROV2 frame: rigid body, Fossen coefficients (magnitudes) and thrusters.

    6-vectors are ordered surge, sway, heave, roll, pitch, yaw along the body axes
    x forward, y left, z up; the body origin is the centre of gravity.
    """

    frame: str
    ardusub_frame: str
    mass: float
    inertia: tuple[float, float, float]
    buoyancy_n: float
    centre_of_buoyancy: tuple[float, float, float]
    added_mass: tuple[float, ...]
    linear_damping: tuple[float, ...]
    quadratic_damping: tuple[float, ...]
    hull_size: tuple[float, float, float]
    thruster_positions: tuple[tuple[float, float, float], ...]
    thruster_directions: tuple[tuple[float, float, float], ...]
    thruster: ThrusterParams = field(default_factory=ThrusterParams)
    sensors: SensorMounts = field(default_factory=SensorMounts)
    added_mass_coriolis: bool = False

    def __post_init__(self) -> None:
        _check_positive(f"{self.frame}.mass", [self.mass])
        _check_positive(f"{self.frame}.inertia", self.inertia)
        _check_positive(f"{self.frame}.hull_size", self.hull_size)
        _check_positive(f"{self.frame}.buoyancy_n", [self.buoyancy_n])
        for name in ("added_mass", "linear_damping", "quadratic_damping"):
            values = getattr(self, name)
            if len(values) != 6:
                raise VehicleConfigError(f"{self.frame}.{name} needs 6 values, got {len(values)}")
            _check_positive(f"{self.frame}.{name}", values, allow_zero=True)
        if len(self.thruster_positions) != len(self.thruster_directions):
            raise VehicleConfigError(f"{self.frame}: thruster positions and directions differ in number")
        for direction in self.thruster_directions:
            if not math.isclose(float(np.linalg.norm(direction)), 1.0, abs_tol=1e-3):
                raise VehicleConfigError(f"{self.frame}: thruster direction {direction} is not a unit vector")

    @property
    def n_thrusters(self) -> int:
        """Number of thrusters (6 standard, 8 Heavy)."""
        return len(self.thruster_positions)

    @property
    def weight_n(self) -> float:
        """Weight in water-free terms, m g (N), with g = 9.81 m/s^2."""
        return self.mass * 9.81

    def rigid_body_mass(self) -> np.ndarray:
        """Diagonal of M_RB ``(6,)``: mass on the three linear axes, then inertia."""
        return np.array([self.mass] * 3 + list(self.inertia))

    def controller_model(self) -> VehicleModel:
        """What :mod:`maptidal.controllers.pose` needs of this vehicle: M_RB + M_A, linear damping,
        thrusters."""
        return VehicleModel(
            inertia=tuple(float(v) for v in self.rigid_body_mass() + np.asarray(self.added_mass)),
            linear_damping=tuple(self.linear_damping),
            quadratic_damping=tuple(self.quadratic_damping),
            thruster_positions=self.thruster_positions,
            thruster_directions=self.thruster_directions,
            max_forward_n=self.thruster.max_forward_n,
            max_reverse_n=self.thruster.max_reverse_n,
            thrust_curve=self.thruster.curve,
            pwm_range=self.thruster.pwm_range,
            ardusub_frame=self.ardusub_frame,
            net_buoyancy_n=self.buoyancy_n - self.weight_n,
            thrust_lag_s=self.thruster.time_constant_s,
        )


def _check_positive(name: str, values, allow_zero: bool = False) -> None:
    for value in values:
        ok = isinstance(value, int | float) and math.isfinite(value)
        ok = ok and (value >= 0.0 if allow_zero else value > 0.0)
        if not ok:
            bound = ">= 0" if allow_zero else "> 0"
            raise VehicleConfigError(f"{name} must be finite and {bound}, got {value!r}")


def _tuple(value):
    return tuple(_tuple(v) for v in value) if isinstance(value, list) else value


@cache
def _document(path: Path) -> dict:
    return tomllib.loads(path.read_text())


def load_vehicle(frame: str = "heavy", path: str | Path | None = None, **overrides) -> VehicleParams:
    """The parameters of the BlueROV2 ``frame`` ("standard" or "heavy").

    ``overrides`` replace fields, e.g. ``mass=-1`` to check that bad values are refused.
    """
    if frame not in FRAMES:
        raise VehicleConfigError(f"unknown frame {frame!r}; choose one of {', '.join(FRAMES)}")
    document = _document(Path(path) if path is not None else VEHICLE_FILE)
    table = {key: _tuple(value) for key, value in document[frame].items()}
    table.update(overrides)
    return VehicleParams(
        frame=frame,
        thruster=ThrusterParams(**document.get("thruster", {})),
        sensors=SensorMounts(**{k: _tuple(v) for k, v in document.get("sensors", {}).items()}),
        **table,
    )
