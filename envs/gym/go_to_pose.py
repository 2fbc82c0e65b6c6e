"""``MapTidal/GoToPose-v1``: fly one BlueROV2 to an inspection pose and hold it."""

from __future__ import annotations

import math

import numpy as np

from maptidal.envs.gym.core import SAFE_BOX, PoseTargetEnv


class GoToPoseEnv(PoseTargetEnv):
    """One BlueROV2 in the OSB tank reaches a random inspection pose (position and yaw) and holds it.

    ## Action space

    ``Box(-1, 1, (6,), float32)``: the normalised pilot command of ``controllers/convention.py``, flown
    through ArduSub's STABILIZE (the default ``action="pilot"``; ``flight_mode`` picks another, below).
    Actions outside the box are clipped to it, as Gymnasium expects; NaN or infinite ones raise:

    | index | axis | +1 means |
    |---|---|---|
    | 0 | surge | full forward |
    | 1 | sway | full right |
    | 2 | heave | full up |
    | 3 | roll | lean right (STABILIZE: 45 deg, ANGLE_MAX) |
    | 4 | pitch | nose up (STABILIZE: 45 deg, ANGLE_MAX) |
    | 5 | yaw | turn right (STABILIZE: 151.9 deg/s, ACRO_YAW_P x 45 deg) |

    ``action="thrusters"``: ``Box(-1, 1, (n,))``, one command per thruster (8 on the Heavy, 6 on the
    standard frame), in ArduSub's motor order, straight to the thrusters: no flight mode, no mixer and
    no pilot gain (a vehicle takes these as servo outputs, not as MANUAL_CONTROL).

    ## Observation space

    A ``Dict`` (or, with ``flat_obs=True``, the same entries concatenated in this order into one Box):

    | key | shape | content | unit |
    |---|---|---|---|
    | pose | 6 | estimated x, y, z (tank frame, z up), roll, pitch (nose down +), yaw | m, rad |
    | velocity | 6 | estimated body velocity u, v, w (x fwd, y left, z up), rates p, q, r | m/s, rad/s |
    | depth | 1 | depth sensor reading | m |
    | imu | 6 | accelerometer (specific force) and gyro, body frame | m/s^2, rad/s |
    | target | 4 | target offset in the heading frame (forward, left, up), yaw error | m, rad |
    | left | (H, W, 3) | with ``obs_images="left"``: the left camera image | uint8 |
    | stereo | (2, H, W, 3) | with ``obs_images="stereo"``: both camera images | uint8 |

    The state is what the robot's own sensors give (IMU, depth, DVL, compass, with noise, dead
    reckoning in ``controllers/estimation.py``), never ground truth.

    ## Rewards

    Per step, from the true pose:

    | term | value |
    |---|---|
    | progress | ``10 x`` the distance gained towards the target (m) |
    | turning | ``2 x`` the yaw error reduced (rad) |
    | held | ``1`` while within 0.1 m and 5 deg of the target |
    | energy | ``- 0.05 x`` the mean squared thruster command |
    | contact | ``- 10 x`` the seconds of the step in contact with the tank |

    Progress and turning are differences of a potential, so over an episode they add up to what was
    gained overall: no path pays more than the straight one, and leaving pays back what arriving got.

    ## Starting state

    A random pose in the tank's safe box (x in [-3.0, -0.8] m, y in [-0.8, 0.8] m, z in [0.5, 1.5] m,
    any yaw), at rest; the target is a random pose 0.5 to 1.5 m away inside the same box.
    ``reset(options={"pose": (x, y, z, yaw), "target": (x, y, z, yaw), "current": (vx, vy, vz)})`` fixes
    any of them instead (each checked: in the tank's water, a current of at most 5 m/s).

    ## Episode end

    Never terminated: a collision costs per second in contact, and the robot may surface, as a real one
    would (in v0 both ended the episode, which gave policies a way out). Truncated: made by
    ``gymnasium.make``, after ``max_episode_steps`` steps (TimeLimit; registered 200, 20 s at the default
    0.1 s period; ``make(..., max_episode_steps=N)`` changes it); constructed directly, after
    ``episode_s`` (default 20 s). ``episode_s`` is not taken through ``make``
    (``maptidal.envs.gym.core.EpisodeLength``). ``info["is_success"]`` is true while within tolerance.

    ## Arguments

    ``gymnasium.make("MapTidal/GoToPose-v1", action="pilot", flat_obs=False, obs_images=None,
    image_size=(80, 128), control_period_s=0.1, frame="heavy", scenario=None, render_mode=None,
    pilot_gain=1.0, flight_mode=None, randomize=None, max_episode_steps=200)``; the class itself takes
    ``episode_s=20.0`` instead of ``max_episode_steps``. ``flight_mode``: the ArduSub mode a pilot
    action is flown in, "stabilize" (the default), "manual", "alt_hold" (heave a climb rate) or
    "poshold" (needs a DVL). ``pilot_gain``: ArduSub's JS_GAIN, which scales surge, sway, heave and yaw
    as MANUAL_CONTROL is scaled on a vehicle (1: full authority at 1; ArduSub's default is 0.5).
    ``randomize``: domain randomisation per episode (:mod:`maptidal.envs.randomization`): True draws
    the vehicle's mass, buoyancy, centre of buoyancy, damping, added mass, thrusters, voltage, the
    current, sensor noise and turbidity from cited ranges; a dict draws the keys it names, from
    ``(low, high)`` or fixed at one number. The draw is ``reset``'s ``info["randomization"]``.

    ## Version history

    - v1: contacts cost per second and end nothing; surfacing ends nothing.
    - v0: first version (maptidal 0.1).
    """

    def _start_episode(self, pose=None, target=None) -> None:
        start, yaw = pose if pose is not None else self._sample_pose()
        self.sim.place(self.robot, start, yaw)
        low, high = SAFE_BOX
        for _ in range(100):
            offset = self.np_random.normal(size=3)
            offset *= self.np_random.uniform(0.5, 1.5) / np.linalg.norm(offset)
            drawn = start + offset
            if np.all(drawn >= low) and np.all(drawn <= high):
                break
        else:
            drawn = np.clip(start + offset, low, high)
        drawn_yaw = float(self.np_random.uniform(-math.pi, math.pi))  # drawn anyway: the same stream
        self.target, self.target_yaw = target if target is not None else (drawn, drawn_yaw)
        self._previous = self._target_errors(self.sim.ground_truth(self.robot))[:2]

    def _reward(self, truth: dict) -> tuple[float, bool, dict]:
        distance, yaw_error, within = self._target_errors(truth)
        reward = 10.0 * (self._previous[0] - distance) + 2.0 * (self._previous[1] - yaw_error)
        reward -= 0.05 * self._energy + self._contact_cost
        reward += 1.0 if within else 0.0
        self._previous = (distance, yaw_error)
        info = {
            "is_success": within,
            "distance_m": distance,
            "yaw_error_rad": yaw_error,
            "contact_s": self._contact_s,
        }
        return reward, False, info
