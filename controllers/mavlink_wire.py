"""ArduSub's MAVLink interface as plain data: the pilot command on the wire, the flight-mode numbers,
and frame conversions between MAVLink's NED / FRD and our world (z up) and body (FLU) frames.

Both ends use it: :mod:`maptidal.controllers.mavlink_bridge` encodes, the simulator's MAVLink vehicle decodes,
so one 6-DOF pilot command means the same thing on a real ArduSub vehicle and in the simulator.

**Pilot command on the wire** (ArduSub, ``ArduSub/joystick.cpp`` and the MANUAL_CONTROL definition):

- MANUAL_CONTROL x = forward, y = lateral (right +), r = yaw (turn right +), each in [-1000, 1000];
  z = throttle in [0, 1000] with 500 neutral (ArduSub's convention, up above 500);
- MANUAL_CONTROL has no roll or pitch, so those go as RC_CHANNELS_OVERRIDE on ArduSub's channels
  1 (pitch) and 2 (roll), 1500 +- 400 us (RC range 1100-1900); the other channels are sent as
  65535 ("leave this channel alone"). ArduSub accepts RC overrides only from its GCS (SYSID_MYGCS,
  default 255). The sign of the pitch channel (higher = nose up) is our reading, not checked on a
  vehicle.

**Frames.** MAVLink's LOCAL_POSITION_NED is north-east-down, and ATTITUDE is the FRD body's roll,
pitch and yaw (yaw clockwise from north). Our world has z up with x north and y west (so it stays
right-handed), and our body is x forward, y left, z up; our pitch is positive nose down and our yaw
counter-clockwise from +x (:mod:`maptidal.controllers.estimation`). So roll is shared, and pitch, yaw and the
body y and z rates change sign.
"""

from __future__ import annotations

import math

import numpy as np

from .convention import pilot_command

# ArduSub's custom_mode numbers (ArduSub/defines.h)
ARDUSUB_MODES: dict[str, int] = {
    "stabilize": 0,
    "acro": 1,
    "alt_hold": 2,
    "auto": 3,
    "guided": 4,
    "circle": 7,
    "surface": 9,
    "poshold": 16,
    "manual": 19,
    "motor_detect": 20,
    "surftrak": 21,
}
MODE_NAMES: dict[int, str] = {number: name for name, number in ARDUSUB_MODES.items()}
# the modes this package's bridge sets, and the simulator's vehicle flies
BRIDGE_MODES = ("manual", "stabilize", "alt_hold", "poshold", "guided")

GCS_SYSTEM_ID = 255  # ArduSub's SYSID_MYGCS default
RC_NEUTRAL_US = 1500
RC_SPAN_US = 400
RC_IGNORE = 65535  # RC_CHANNELS_OVERRIDE: leave this channel alone
RC_PITCH_CHANNEL, RC_ROLL_CHANNEL = 1, 2  # ArduSub's RC map (1-based)


class WireError(ValueError):
    """A pilot message that cannot be decoded (values out of range or not numbers)."""


def encode_pilot(command) -> tuple[dict[str, int], list[int]]:
    """A pilot command (anything :func:`maptidal.controllers.convention.pilot_command` takes) as
    MANUAL_CONTROL fields ``{x, y, z, r}`` and the 8 channels of an RC_CHANNELS_OVERRIDE (roll and pitch)."""
    surge, sway, heave, roll, pitch, yaw = pilot_command(command)
    manual = {
        "x": round(float(surge * 1000)),
        "y": round(float(sway * 1000)),
        "z": round(float(500 + heave * 500)),
        "r": round(float(yaw * 1000)),
    }
    channels = [RC_IGNORE] * 8
    channels[RC_PITCH_CHANNEL - 1] = round(float(RC_NEUTRAL_US + pitch * RC_SPAN_US))
    channels[RC_ROLL_CHANNEL - 1] = round(float(RC_NEUTRAL_US + roll * RC_SPAN_US))
    return manual, channels


def decode_manual_control(x: float, y: float, z: float, r: float) -> np.ndarray:
    """MANUAL_CONTROL's fields as surge, sway, heave, yaw in [-1, 1] (ArduSub's scaling).

    Values outside their ranges are clamped, as ArduSub clamps the RC overrides it makes of them
    (``constrain_int16(..., 1100, 1900)`` in ``transform_manual_control_to_rc_override``): x = 5000 is
    full forward. Non-finite values raise :class:`WireError`, so a corrupt packet never moves a
    thruster (MAVLink's int16 fields cannot carry them; a decoder fed by other means can)."""
    values = (float(x), float(y), float(z), float(r))
    if not all(math.isfinite(v) for v in values):
        raise WireError(f"MANUAL_CONTROL fields must be finite, got {values}")
    surge, sway, yaw = (max(-1000.0, min(1000.0, v)) / 1000 for v in (values[0], values[1], values[3]))
    heave = (max(0.0, min(1000.0, values[2])) - 500) / 500
    return np.array([surge, sway, heave, yaw])


def manual_control_in_range(x: float, y: float, z: float, r: float) -> bool:
    """Whether MANUAL_CONTROL's fields lie in their ranges (x, y, r in [-1000, 1000], z in [0, 1000])."""
    return all(-1000 <= v <= 1000 for v in (x, y, r)) and 0 <= z <= 1000


def decode_rc_channel(pulse_us: int) -> float | None:
    """One RC override channel as a value in [-1, 1]; None when the channel is released (0) or
    ignored (65535)."""
    if pulse_us in (0, RC_IGNORE):
        return None
    if not 800 <= pulse_us <= 2200:
        raise WireError(f"RC override pulse {pulse_us} us is not a pulse width")
    return float(np.clip((pulse_us - RC_NEUTRAL_US) / RC_SPAN_US, -1.0, 1.0))


def rpy_from_ned(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """ATTITUDE's FRD roll, pitch, yaw (rad) as our roll, pitch (nose down +), yaw (counter-clockwise)."""
    return np.array([roll, -pitch, math.atan2(math.sin(-yaw), math.cos(-yaw))])


def rpy_to_ned(rpy) -> tuple[float, float, float]:
    """Our roll, pitch, yaw as MAVLink's FRD roll, pitch, yaw (yaw in [-pi, pi], clockwise from north)."""
    roll, pitch, yaw = (float(v) for v in rpy)
    return roll, -pitch, math.atan2(math.sin(-yaw), math.cos(-yaw))


def flu_from_frd(vector) -> np.ndarray:
    """A body vector (rates, velocities, forces) from FRD to FLU, or back: y and z change sign."""
    v = np.asarray(vector, float)
    return np.array([v[0], -v[1], -v[2]])


def world_from_ned(north: float, east: float, down: float, surface_z_m: float = 0.0) -> np.ndarray:
    """A NED position (origin at the water surface above our world origin) in our world frame."""
    return np.array([north, -east, surface_z_m - down])


def ned_from_world(position, surface_z_m: float = 0.0) -> tuple[float, float, float]:
    """Our world position as NED with its origin at the water surface."""
    x, y, z = (float(v) for v in position)
    return x, -y, surface_z_m - z


def world_velocity_from_ned(velocity_ned) -> np.ndarray:
    """A NED velocity in our world frame (x north, y west, z up)."""
    v = np.asarray(velocity_ned, float)
    return np.array([v[0], -v[1], -v[2]])
