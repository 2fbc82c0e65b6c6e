"""``MapTidal/TankInspection-v1``: one robot inspects the OSB tank's walls with its camera."""

from __future__ import annotations

import math

import mujoco
import numpy as np
from gymnasium import spaces

from maptidal.envs.gym.core import SAFE_BOX, MapTidalEnv
from maptidal.evaluation.coverage import CoverageModel, CoverageParams, SeenVoxels

SECTORS = 8  # coverage summary: the evaluated walls in eight sectors around the tank's centre line
REWARD_PER_VOXEL = 0.01


def camera_viewpoint(truth: dict, camera_position) -> np.ndarray:
    """The viewpoint row (camera position, viewing direction) of a robot from its true pose
    (:meth:`maptidal.envs.simulation.Simulation.ground_truth`) and its camera's body position."""
    matrix = np.zeros(9)
    mujoco.mju_quat2Mat(matrix, np.asarray(truth["quaternion"], float))
    rotation = matrix.reshape(3, 3)
    return np.concatenate(
        (np.asarray(truth["position"]) + rotation @ np.asarray(camera_position, float), rotation[:, 0])
    )


class WallCoverage:
    """The tank's evaluated walls as voxels (:class:`maptidal.evaluation.coverage.CoverageModel`, with
    occlusion), which of them cameras have seen so far, and a summary: the share seen, overall and in
    :data:`SECTORS` sectors by bearing from (-1.5, 0), a point on the tank's centre line."""

    def __init__(self, tank, voxel_m: float = 0.05) -> None:
        self.model = CoverageModel.from_tank(tank, CoverageParams(voxel_m=voxel_m, occlusion=True))
        bearings = np.arctan2(*(self.model.voxels[:, :2] - np.array([-1.5, 0.0])).T[::-1])
        edges = np.linspace(bearings.min(), bearings.max() + 1e-9, SECTORS + 1)
        self._sector = np.clip(np.searchsorted(edges, bearings, side="right") - 1, 0, SECTORS - 1)
        self._sector_size = np.maximum(np.bincount(self._sector, minlength=SECTORS), 1)
        self._tracker = SeenVoxels(self.model)  # rays only to voxels not yet seen
        self._summary: np.ndarray | None = None

    @property
    def seen(self) -> np.ndarray:
        """Which wall voxels have been seen."""
        return self._tracker.seen

    def reset(self) -> None:
        """Nothing seen."""
        self._tracker.reset()
        self._summary: np.ndarray | None = None

    def restore(self, seen: np.ndarray) -> None:
        """Take up from a copy of an earlier :attr:`seen`."""
        self._tracker.restore(seen)
        self._summary = None

    def look(self, viewpoints: np.ndarray) -> int:
        """Count what the viewpoints ``(N, 6)`` see; the number of voxels newly seen."""
        newly = self._tracker.look(viewpoints)
        if newly:
            self._summary = None
        return newly

    def summary(self) -> np.ndarray:
        """``(1 + SECTORS,)``: the share seen overall, then per sector (recounted only after news)."""
        if self._summary is None:
            per_sector = np.bincount(self._sector[self.seen], minlength=SECTORS) / self._sector_size
            self._summary = np.concatenate(([self.seen.mean()], per_sector))
        return self._summary.copy()


class TankInspectionEnv(MapTidalEnv):
    """One BlueROV2 looks at as much of the tank's evaluated walls as it can.

    ## Action space

    As ``MapTidal/GoToPose-v1``: ``Box(-1, 1, (6,), float32)`` pilot commands through STABILIZE, or
    ``action="thrusters"``.

    ## Observation space

    pose, velocity, depth and imu as in ``MapTidal/GoToPose-v1`` (estimated, from the robot's sensors),
    optional images, and:

    | key | shape | content | unit |
    |---|---|---|---|
    | coverage | 9 | share of the evaluated wall voxels seen so far, then per sector | 0..1 |

    The 8 sectors split the walls by bearing from (-1.5, 0), a point on the tank's centre line.

    ## Rewards

    Per step: ``0.01 x`` the wall voxels newly seen by the robot's camera (the OAK-D frustum, 2 m range, with
    occlusion, counted by :class:`maptidal.evaluation.coverage.CoverageModel` on 5 cm voxels, from the true
    camera pose), ``- 0.05 x`` the mean squared thruster command, ``- 10 x`` the seconds of the step in
    contact with the tank. Looking again at seen voxels earns nothing.

    ## Starting state

    A random position in the tank's safe box, facing the end wall within +-60 deg, at rest (or the
    ``pose`` of ``reset(options=...)``, with a ``current`` too: MapTidalEnv.reset); what the camera sees
    there counts as seen.

    ## Episode end

    Never terminated: a collision costs per second in contact and the robot may surface (in v0 both
    ended the episode, and a policy ramming the nearest wall saw more before the end than one doing
    nothing, which floated up and ended too). Truncated as in ``MapTidal/GoToPose-v1``: after 600 steps
    made by ``gymnasium.make`` (``max_episode_steps``), after ``episode_s`` (default 60 s) constructed
    directly.
    ``info["coverage"]`` is the share seen.

    ## Arguments

    Those of ``MapTidal/GoToPose-v1`` (``max_episode_steps`` 600 and ``episode_s`` 60 s here), and
    ``voxel_m=0.05``.

    ## Version history

    - v1: contacts cost per second and end nothing; surfacing ends nothing.
    - v0: first version (maptidal 0.1).
    """

    def __init__(self, *args, voxel_m: float = 0.05, episode_s: float = 60.0, **kwargs) -> None:
        super().__init__(*args, episode_s=episode_s, **kwargs)
        self.walls = WallCoverage(self.scenario.tank, voxel_m)
        self.coverage = self.walls.model

    @property
    def seen(self) -> np.ndarray:
        """Which wall voxels the camera has seen this episode."""
        return self.walls.seen

    def _task_spaces(self) -> dict[str, spaces.Space]:
        return {"coverage": spaces.Box(0.0, 1.0, (SECTORS + 1,), np.float32)}

    def _task_observation(self) -> dict[str, np.ndarray]:
        if not hasattr(self, "walls"):  # the base class builds a first observation before __init__ ends
            return {"coverage": np.zeros(SECTORS + 1)}
        return {"coverage": self.walls.summary()}

    def _task_state(self) -> dict:
        return {"seen": self.walls.seen.copy()}

    def _set_task_state(self, state: dict) -> None:
        self.walls.restore(state["seen"])

    def _look(self, truth: dict) -> int:
        return self.walls.look(camera_viewpoint(truth, self.vehicle.sensors.camera_position)[None, :])

    def _start_episode(self, pose=None) -> None:
        low, high = SAFE_BOX
        start = self.np_random.uniform(low, high)
        yaw = float(self.np_random.uniform(-math.pi / 3, math.pi / 3))
        if pose is not None:
            start, yaw = pose
        self.sim.place(self.robot, start, yaw)
        self.walls.reset()
        self._look(self.sim.ground_truth(self.robot))

    def _reward(self, truth: dict) -> tuple[float, bool, dict]:
        new = self._look(truth)
        reward = REWARD_PER_VOXEL * new - 0.05 * self._energy - self._contact_cost
        # the summary's first entry is the share seen (recounted only after news)
        info = {"new_voxels": new, "coverage": float(self.walls.summary()[0]), "contact_s": self._contact_s}
        return reward, False, info
