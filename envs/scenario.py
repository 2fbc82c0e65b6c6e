"""Scenario files (TOML): the tank, the robots with their sensors, the water and the physics rate.

HoloOcean-style: a scenario names everything a run needs. Example and every key:
``assets/scenarios/default.toml``. A bad scenario raises :class:`ScenarioError`
naming the value (unknown frame or sensor, a robot outside the tank, a negative
mass, unknown keys), never a crash deep inside MuJoCo.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from maptidal.checks import check_keys, finite_vector, require
from maptidal.envs.sensors import SENSORS, SensorNoise
from maptidal.envs.vehicle import FRAMES, VehicleConfigError, VehicleParams, load_vehicle
from maptidal.envs.water import WaterParams
from maptidal.paths import ASSETS
from maptidal.tank import DEFAULT_TANK_CONFIG, TankConfigError, TankModel, load_tank_config

SCENARIO_DIR = ASSETS / "scenarios"
DEFAULT_SCENARIO = SCENARIO_DIR / "default.toml"
HULL_MARGIN_M = 0.3  # a start pose must leave this much water around the CG


class ScenarioError(ValueError):
    """A scenario that cannot be simulated; the message says which value and why."""


@dataclass(frozen=True)
class RobotSpec:
    """One robot of a scenario: name, vehicle parameters, start pose and enabled sensors."""

    name: str
    vehicle: VehicleParams
    position: tuple[float, float, float]
    yaw_deg: float = 0.0
    sensors: tuple[str, ...] = SENSORS


@dataclass(frozen=True)
class Scenario:
    """Everything a simulation needs; build it with :func:`load_scenario` or directly."""

    name: str
    tank: TankModel
    robots: tuple[RobotSpec, ...]
    timestep_s: float = 0.002
    control_period_s: float = 0.02
    water: WaterParams = field(default_factory=WaterParams)
    current: tuple[float, float, float] = (0.0, 0.0, 0.0)
    noise: SensorNoise = field(default_factory=SensorNoise)

    @property
    def substeps(self) -> int:
        """Physics steps per control period."""
        return max(1, round(self.control_period_s / self.timestep_s))


def _require(condition: bool, message: str) -> None:
    require(condition, message, ScenarioError)


def _check_keys(table: dict, allowed: set[str], where: str) -> None:
    check_keys(table, allowed, where, ScenarioError)


# The strongest water current a scenario, an event or Simulation.set_current takes: over three times the
# BlueROV2's 1.5 m/s top speed (Blue Robotics' specifications), enough for any stress test of holding
# station; far beyond it the quadratic drag makes the physics step stiff and it diverges.
MAX_CURRENT_M_S = 5.0


def check_current(current, where: str = "the current") -> np.ndarray:
    """``current`` (m/s, world frame) as an array, or a ValueError: three finite numbers, at most
    :data:`MAX_CURRENT_M_S` in magnitude."""
    vector = np.asarray(current, float)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)):
        raise ValueError(f"{where} is three finite numbers (m/s), got {current!r}")
    if float(np.linalg.norm(vector)) > MAX_CURRENT_M_S:
        raise ValueError(
            f"{where} of {float(np.linalg.norm(vector)):g} m/s is beyond {MAX_CURRENT_M_S:g} m/s (over three "
            "times the BlueROV2's top speed)"
        )
    return vector


def _vector(value, where: str, size: int = 3) -> tuple[float, ...]:
    return finite_vector(value, where, size, ScenarioError)


def inside_tank(tank: TankModel, point: np.ndarray, margin: float = 0.0) -> bool:
    """Whether ``point`` lies in the tank's water, at least ``margin`` from walls, floor and surface."""
    x, y, z = (float(v) for v in point)
    if not margin <= z <= tank.height - margin:
        return False
    if x < tank.far_x + margin:
        return False
    # inside every wall's half-plane (the walls of the modelled end form a convex outline)
    for seg in tank.segments:
        offset = np.dot(np.array([x, y]) - seg.start, seg.inward_normal[:2])
        if offset < margin:
            return False
    return True


def hulls_overlap(a: RobotSpec, b: RobotSpec) -> bool:
    """Whether two robots' hulls could intersect at their start poses, whatever their yaw: each hull is
    taken as an upright cylinder around its CG, of radius half its longer side and its own height."""
    (la, wa, ha), (lb, wb, hb) = a.vehicle.hull_size, b.vehicle.hull_size
    offset = np.subtract(a.position, b.position)
    apart_horizontally = float(np.hypot(offset[0], offset[1])) >= (max(la, wa) + max(lb, wb)) / 2
    apart_vertically = abs(float(offset[2])) >= (ha + hb) / 2
    return not (apart_horizontally or apart_vertically)


def _tank_from(value, base: Path) -> TankModel:
    if value in (None, "osb_tank"):
        path = DEFAULT_TANK_CONFIG
    else:
        path = Path(value)
        if not path.is_absolute():
            path = (base / path) if (base / path).exists() else ASSETS / str(value) / "tank.toml"
    try:
        return TankModel(load_tank_config(path))
    except TankConfigError as err:
        raise ScenarioError(f"tank: {err}") from None


def scenario_from_dict(document: dict, base: Path | None = None) -> Scenario:
    """Build and validate a :class:`Scenario` from a parsed TOML document."""
    base = base or SCENARIO_DIR
    _check_keys(document, {"name", "tank", "physics", "water", "robots", "sensor_noise"}, "the scenario")
    tank = _tank_from(document.get("tank"), base)
    physics = document.get("physics", {})
    _check_keys(physics, {"timestep_s", "control_period_s"}, "[physics]")
    timestep = physics.get("timestep_s", 0.002)
    period = physics.get("control_period_s", 0.02)
    _require(
        isinstance(timestep, int | float) and 1e-4 <= timestep <= 0.02,
        f"physics.timestep_s must be in [0.0001, 0.02] s, got {timestep!r}",
    )
    _require(
        isinstance(period, int | float) and timestep <= period <= 1.0,
        f"physics.control_period_s must be in [timestep_s, 1] s, got {period!r}",
    )
    # the flight mode runs once a control period of whole physics steps: a period of 2.5 steps would run
    # every 2 or 3 steps (the simulator rounds) and no longer be the period asked for
    steps = period / timestep
    _require(
        abs(steps - round(steps)) <= 1e-6 * steps,
        f"physics.control_period_s ({period!r} s) must be a whole number of timesteps ({timestep!r} s)",
    )
    water_table = dict(document.get("water", {}))
    _check_keys(water_table, {"current"} | {f.name for f in fields(WaterParams)}, "[water]")
    current = _vector(water_table.pop("current", [0.0, 0.0, 0.0]), "water.current")
    try:
        check_current(current, "water.current")
    except ValueError as err:
        raise ScenarioError(str(err)) from None
    try:
        water = WaterParams(**water_table)
    except (TypeError, ValueError) as err:
        raise ScenarioError(f"[water]: {err}") from None
    try:
        noise = SensorNoise(**document.get("sensor_noise", {}))
    except (TypeError, ValueError) as err:
        raise ScenarioError(f"[sensor_noise]: {err}") from None
    robots_table = document.get("robots", [])
    _require(
        isinstance(robots_table, list) and robots_table, "a scenario needs at least one [[robots]] entry"
    )
    robots, names = [], set()
    for k, entry in enumerate(robots_table):
        robots.append(_robot_from(entry, k, tank))
        _require(robots[-1].name not in names, f"robot name {robots[-1].name!r} is used twice")
        names.add(robots[-1].name)
        for other in robots[:-1]:
            _require(
                not hulls_overlap(other, robots[-1]),
                f"robots {other.name!r} and {robots[-1].name!r} start with their hulls overlapping "
                f"(at {list(other.position)} and {list(robots[-1].position)})",
            )
    return Scenario(
        name=str(document.get("name", "scenario")),
        tank=tank,
        robots=tuple(robots),
        timestep_s=float(timestep),
        control_period_s=float(period),
        water=water,
        current=current,
        noise=noise,
    )


_VEHICLE_OVERRIDES = {
    "mass",
    "buoyancy_n",
    "inertia",
    "added_mass",
    "linear_damping",
    "quadratic_damping",
    "added_mass_coriolis",
}


def _robot_from(entry: dict, index: int, tank: TankModel) -> RobotSpec:
    where = f"robots[{index}]"
    _require(isinstance(entry, dict), f"{where} must be a table")
    _check_keys(entry, {"name", "frame", "position", "yaw_deg", "sensors"} | _VEHICLE_OVERRIDES, where)
    name = str(entry.get("name", f"rov{index}"))
    _require(name.isidentifier(), f"{where}.name must be a plain identifier, got {name!r}")
    frame = entry.get("frame", "heavy")
    _require(frame in FRAMES, f"{where}.frame: unknown frame {frame!r}; choose one of {', '.join(FRAMES)}")
    overrides = {key: entry[key] for key in _VEHICLE_OVERRIDES if key in entry}
    overrides = {k: tuple(v) if isinstance(v, list) else v for k, v in overrides.items()}
    try:
        vehicle = load_vehicle(frame, **overrides)
    except VehicleConfigError as err:
        raise ScenarioError(f"{where}: {err}") from None
    position = _vector(entry.get("position"), f"{where}.position")
    _require(
        inside_tank(tank, np.array(position), HULL_MARGIN_M),
        f"{where}.position {list(position)} is outside the tank's water "
        f"(or within {HULL_MARGIN_M} m of a wall, the floor or the surface)",
    )
    yaw = entry.get("yaw_deg", 0.0)
    _require(
        isinstance(yaw, int | float) and math.isfinite(yaw) and abs(yaw) <= 360.0,
        f"{where}.yaw_deg must be a number of degrees in [-360, 360], got {yaw!r}",
    )
    sensors = entry.get("sensors", list(SENSORS))
    _require(isinstance(sensors, list), f"{where}.sensors must be a list")
    for sensor in sensors:
        _require(
            sensor in SENSORS, f"{where}.sensors: unknown sensor {sensor!r}; known: {', '.join(SENSORS)}"
        )
    return RobotSpec(name, vehicle, position, float(yaw), tuple(sensors))


def read_scenario_file(path: str | Path | None = None, default: Path = DEFAULT_SCENARIO) -> tuple[Path, dict]:
    """Find and parse a scenario TOML (``default`` when ``path`` is None; a bare name looks in
    assets/scenarios): its resolved path and document, or ScenarioError naming the file."""
    path = Path(path) if path is not None else default
    if not path.exists() and (SCENARIO_DIR / f"{path}.toml").exists():
        path = SCENARIO_DIR / f"{path}.toml"
    _require(path.is_file(), f"scenario not found: {path}")
    try:
        return path, tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ScenarioError(f"{path}: not valid TOML ({err})") from None


def load_scenario(path: str | Path | None = None) -> Scenario:
    """Read a scenario TOML (default ``assets/scenarios/default.toml``; a bare name looks there)."""
    path, document = read_scenario_file(path)
    try:
        return scenario_from_dict(document, path.parent)
    except ScenarioError as err:
        raise ScenarioError(f"{path}: {err}") from None


def with_frame(scenario: Scenario, frame: str) -> Scenario:
    """The same scenario with every robot switched to ``frame`` ("heavy" or "standard")."""
    _require(frame in FRAMES, f"unknown frame {frame!r}; choose one of {', '.join(FRAMES)}")
    robots = tuple(replace(robot, vehicle=load_vehicle(frame)) for robot in scenario.robots)
    return replace(scenario, robots=robots)
