"""Domain randomisation: per-episode draws of the physical vehicle, its sensors and the water, so that a
policy does not learn one simulator's exact numbers.

A draw changes the *plant* (:meth:`maptidal.envs.simulation.Simulation.set_plant`): what the physics
flies. The robot's controllers, estimator and ArduSub autopilot keep the nominal vehicle, as a real
vehicle's software keeps its parameters whatever the vehicle in the water is.

Ranges (:data:`DEFAULT_RANGES`; each key is drawn uniformly per episode, per robot), and why:

- ``mass_scale`` 0.95 to 1.05 scales mass and inertia: payloads (a DVL, a gripper, lights) add a few
  hundred grams to the Heavy's 13.5 kg (our rounding);
- ``volume_scale`` 0.98 to 1.02 scales the displaced volume, so buoyancy: von Benzon et al. (J. Mar.
  Sci. Eng. 2022)'s 0.0134 m^3 gives 131.5 N, 2.2 % under our 134.4 N trim;
- ``cb_offset_m`` -0.01 to 0.01 m moves the centre of buoyancy on each axis: published CB heights
  above the CG differ (1 cm in von Benzon 2022, 4.9 cm in the public bluerov2_ignition Heavy), and
  trim weights move it by centimetres;
- ``damping_scale`` 0.5 to 2.0 scales linear and quadratic damping: identifications disagree by about
  3x (Wu 2018's standard-frame surge drag had to be scaled 3.01x to reach Blue Robotics' 1.5 m/s);
- ``added_mass_scale`` 0.7 to 1.3 scales added mass: Wu (2018) and von Benzon (2022) differ by -46 %
  to +78 % axis by axis (on the two frames);
- ``thruster_gain`` 0.9 to 1.1, drawn per thruster, scales its thrust: our choice, for wear, fouling
  and the spread between units;
- ``deadband_scale`` 0.75 to 1.25 scales the T200's deadband: the published one is 28 us at 16 V and
  36 us at 12 V, and ESCs differ;
- ``thruster_lag_s`` 0.05 to 0.2 s is the thrust's first-order lag: our choice about the common 0.1 s;
- ``voltage_v`` 12 to 16 V picks the T200 curve
  (:func:`maptidal.controllers.thrusters.t200_curve_between`): a battery from nearly empty to full,
  between the two published curves;
- ``current_m_s`` 0 to 0.1 m/s is a horizontal water current of random heading
  (``current_heading_rad``): our choice, as pumps and filters stir a test tank little;
- ``noise_scale`` 0.5 to 2.0 scales every sensor noise level (:class:`maptidal.envs.sensors.SensorNoise`,
  datasheet-typical by default): our choice;
- ``turbidity`` 0.1 to 0.6 is the water's turbidity (:class:`maptidal.envs.water.WaterParams`): our
  choice, clear to murky tank water.
- ``turbulence_m_s`` 0 to 0.03 m/s is the standard deviation of an Ornstein-Uhlenbeck gust on each axis
  about the current, with a 2 s time constant (``MapTidal/StationKeeping-v1``'s default as the top):
  our choice, for the eddies pumps and a robot's own wake leave in a tank. It is the environment's,
  not the simulation's: :class:`maptidal.envs.gym.core.MapTidalEnv` blows the gust each control period.

``randomize=True`` draws every key from its default range; a dict draws only the keys it names, each
from ``(low, high)`` or fixed at one number (to test a policy on shifted parameters). A key not listed,
a range the wrong way round or outside what the physics allows (a mass scale of 0 or less, a voltage
outside 12 to 16 V, a turbidity outside 0 to 1) raises ValueError, never a silent clip.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from maptidal.controllers.thrusters import t200_curve_between
from maptidal.envs.scenario import check_current

# key: (low, high) drawn uniformly (the module docstring gives each one's reason)
DEFAULT_RANGES: dict[str, tuple[float, float]] = {
    "mass_scale": (0.95, 1.05),
    "volume_scale": (0.98, 1.02),
    "cb_offset_m": (-0.01, 0.01),
    "damping_scale": (0.5, 2.0),
    "added_mass_scale": (0.7, 1.3),
    "thruster_gain": (0.9, 1.1),
    "deadband_scale": (0.75, 1.25),
    "thruster_lag_s": (0.05, 0.2),
    "voltage_v": (12.0, 16.0),
    "current_m_s": (0.0, 0.1),
    "noise_scale": (0.5, 2.0),
    "turbidity": (0.1, 0.6),
    "turbulence_m_s": (0.0, 0.03),
}
# what the physics allows of each key: (lowest, highest, whether the lowest itself is allowed)
PHYSICAL_BOUNDS: dict[str, tuple[float, float, bool]] = {
    "mass_scale": (0.0, 10.0, False),
    "volume_scale": (0.0, 10.0, False),
    "cb_offset_m": (-0.2, 0.2, True),  # inside the hull
    "damping_scale": (0.0, 10.0, True),
    "added_mass_scale": (0.0, 10.0, True),
    "thruster_gain": (0.0, 2.0, False),
    "deadband_scale": (0.0, 10.0, True),  # the deadband stays under 400 us (checked when applied)
    "thruster_lag_s": (0.0, 5.0, False),
    "voltage_v": (12.0, 16.0, True),
    "current_m_s": (0.0, 5.0, True),  # check_current's bound
    "noise_scale": (0.0, 100.0, True),
    "turbidity": (0.0, 1.0, True),
    "turbulence_m_s": (0.0, 0.5, True),  # StationKeeping's own bound
}


@dataclass(frozen=True)
class Randomization:
    """The keys to draw per episode and their ranges (module docstring); build it with
    :meth:`from_option`."""

    ranges: tuple[tuple[str, float, float], ...]

    @classmethod
    def from_option(cls, option: object) -> Randomization | None:
        """The randomisation an environment's ``randomize`` option asks for: None or False for none,
        True for every key at its default range, a dict of key to ``(low, high)`` or to one number.
        Anything else raises ValueError naming the key and the bound."""
        if option is None or option is False:
            return None
        if option is True:
            return cls(tuple((key, low, high) for key, (low, high) in DEFAULT_RANGES.items()))
        if not isinstance(option, Mapping):
            raise ValueError(f"randomize must be True, False, None or a dict of ranges, got {option!r}")
        unknown = sorted(set(option) - set(DEFAULT_RANGES))
        if unknown:
            raise ValueError(f"unknown randomize key(s) {unknown}; the keys are {sorted(DEFAULT_RANGES)}")
        ranges = []
        for key, value in option.items():
            low, high = _range(key, value)
            ranges.append((key, low, high))
        return cls(tuple(ranges))

    def sample(self, rng: np.random.Generator, n_thrusters: int) -> dict[str, float | list[float]]:
        """One episode's draw: each key's value (``cb_offset_m`` three, ``thruster_gain`` one per
        thruster, ``current_m_s`` adds ``current_heading_rad``), from ``rng`` in a fixed order."""
        draw: dict[str, float | list[float]] = {}
        for key, low, high in self.ranges:
            if key == "cb_offset_m":
                draw[key] = rng.uniform(low, high, 3).tolist()
            elif key == "thruster_gain":
                draw[key] = rng.uniform(low, high, n_thrusters).tolist()
            else:
                draw[key] = float(rng.uniform(low, high))
                if key == "current_m_s":
                    draw["current_heading_rad"] = float(rng.uniform(-math.pi, math.pi))
        return draw


def _range(key: str, value: object) -> tuple[float, float]:
    """``value`` as a checked (low, high) for ``key``."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        low = high = float(value)
    elif (
        isinstance(value, tuple | list)
        and len(value) == 2
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ):
        low, high = (float(v) for v in value)
    else:
        raise ValueError(f"randomize[{key!r}] must be (low, high) or one number, got {value!r}")
    lowest, highest, inclusive = PHYSICAL_BOUNDS[key]
    above = low >= lowest if inclusive else low > lowest
    if not (math.isfinite(low) and math.isfinite(high) and low <= high and above and high <= highest):
        side = "[" if inclusive else "("
        raise ValueError(
            f"randomize[{key!r}] = {value!r}: need finite low <= high within {side}{lowest:g}, {highest:g}]"
        )
    return low, high


def restore_sensor_noise(sim) -> None:
    """Give every robot of ``sim`` the scenario's sensor noise again. Called before ``sim.reset``, which
    draws the IMU biases at the robots' noise levels: otherwise an episode's start would depend on the
    last episode's draw (a reused environment and a fresh one, reset with one seed, started 0.5 mm
    apart)."""
    for robot in sim.robots:
        sim.set_sensor_noise(robot, sim.scenario.noise)


def apply(sim, robot: str, draw: Mapping[str, object]) -> None:
    """Give ``robot`` of ``sim`` (a :class:`maptidal.envs.simulation.Simulation`, just reset) the drawn
    plant, sensor noise, water and current; keys not drawn keep the scenario's values. The turbulence is
    the environment's to blow (module docstring)."""
    # what the robot believes of itself, the scenario's: each draw is made about it, never about the last
    vehicle = next(spec.vehicle for spec in sim.scenario.robots if spec.name == robot)
    mass = float(draw.get("mass_scale", 1.0))
    if mass != 1.0:
        inertia = tuple(v * mass for v in vehicle.inertia)  # the same shape, heavier
        vehicle = dataclasses.replace(vehicle, mass=vehicle.mass * mass, inertia=inertia)
    if "volume_scale" in draw:
        vehicle = dataclasses.replace(vehicle, buoyancy_n=vehicle.buoyancy_n * float(draw["volume_scale"]))
    if "cb_offset_m" in draw:
        cb = tuple(float(c + d) for c, d in zip(vehicle.centre_of_buoyancy, draw["cb_offset_m"], strict=True))
        vehicle = dataclasses.replace(vehicle, centre_of_buoyancy=cb)
    if "damping_scale" in draw:
        scale = float(draw["damping_scale"])
        vehicle = dataclasses.replace(
            vehicle,
            linear_damping=tuple(v * scale for v in vehicle.linear_damping),
            quadratic_damping=tuple(v * scale for v in vehicle.quadratic_damping),
        )
    if "added_mass_scale" in draw:
        scale = float(draw["added_mass_scale"])
        vehicle = dataclasses.replace(vehicle, added_mass=tuple(v * scale for v in vehicle.added_mass))
    thruster = vehicle.thruster
    curve = thruster.curve
    if "voltage_v" in draw:
        curve = t200_curve_between(float(draw["voltage_v"]))
    if "deadband_scale" in draw:
        deadband = curve.deadband_us * float(draw["deadband_scale"])
        if not deadband < 400.0:
            raise ValueError(f"randomize: a deadband of {deadband:.0f} us leaves no thrust (T200: under 400)")
        curve = dataclasses.replace(curve, deadband_us=deadband)
    lag = float(draw.get("thruster_lag_s", thruster.time_constant_s))
    if curve is not thruster.curve or lag != thruster.time_constant_s:
        thruster = dataclasses.replace(thruster, curve=curve, time_constant_s=lag, voltage_v=curve.voltage_v)
        vehicle = dataclasses.replace(vehicle, thruster=thruster)
    sim.set_plant(robot, vehicle, draw.get("thruster_gain"))
    if "noise_scale" in draw:
        scale, noise = float(draw["noise_scale"]), sim.scenario.noise
        scaled = {f.name: getattr(noise, f.name) * scale for f in dataclasses.fields(noise)}
        # the biases drawn at the reset, at the scenario's levels (restore_sensor_noise), scaled with them
        sim.set_sensor_noise(robot, dataclasses.replace(noise, **scaled), rescale_biases=True)
    if "turbidity" in draw:
        sim.set_water(dataclasses.replace(sim.scenario.water, turbidity=float(draw["turbidity"])))
    if "current_m_s" in draw:
        speed, heading = float(draw["current_m_s"]), float(draw["current_heading_rad"])
        sim.set_current(check_current([speed * math.cos(heading), speed * math.sin(heading), 0.0]))
