"""maptidal's Gymnasium environments, registered under the ``MapTidal/`` namespace on
``import maptidal.envs``:

- ``MapTidal/GoToPose-v1`` (:class:`maptidal.envs.gym.go_to_pose.GoToPoseEnv`): reach an inspection pose and
  hold it;
- ``MapTidal/StationKeeping-v1`` (:class:`maptidal.envs.gym.station_keeping.StationKeepingEnv`): hold a pose
  in a current and turbulence that vary per episode;
- ``MapTidal/TankInspection-v1`` (:class:`maptidal.envs.gym.tank_inspection.TankInspectionEnv`): see as much
  of the tank's evaluated walls as possible (reward: newly seen voxels, with occlusion);
- ``MapTidal/TeamInspection-v1`` (:class:`maptidal.envs.gym.team_inspection.TeamInspectionEnv`): N robots
  share that reward, Dict spaces keyed by robot; :func:`maptidal.envs.gym.team_inspection.parallel_env` is its
  PettingZoo ``ParallelEnv``.

    import gymnasium, maptidal.envs
    env = gymnasium.make("MapTidal/GoToPose-v1")

``gymnasium.make_vec("MapTidal/GoToPose-v1", num_envs=16)`` (and StationKeeping) steps the robots together
as numpy arrays (:mod:`maptidal.envs.gym.batched`); ``vectorization_mode="sync"`` or ``"async"`` gives
Gymnasium's own vectors instead.

The same tasks as dm_control environments: :func:`maptidal.envs.gym.dm_tasks.load`.
"""

from __future__ import annotations

ENVIRONMENTS = {
    "MapTidal/GoToPose-v1": "maptidal.envs.gym.go_to_pose:GoToPoseEnv",
    "MapTidal/StationKeeping-v1": "maptidal.envs.gym.station_keeping:StationKeepingEnv",
    "MapTidal/TankInspection-v1": "maptidal.envs.gym.tank_inspection:TankInspectionEnv",
    "MapTidal/TeamInspection-v1": "maptidal.envs.gym.team_inspection:TeamInspectionEnv",
}
# each registration's max_episode_steps: its class's default episode_s over the default control period of
# 0.1 s (GoToPose and StationKeeping 20 s, the inspection tasks 60 s). gymnasium.make ends episodes there
# (TimeLimit) unless given max_episode_steps (maptidal.envs.gym.core.EpisodeLength)
MAX_EPISODE_STEPS = {
    "MapTidal/GoToPose-v1": 200,
    "MapTidal/StationKeeping-v1": 200,
    "MapTidal/TankInspection-v1": 600,
    "MapTidal/TeamInspection-v1": 600,
}


# the pose tasks' batched vector environments (maptidal.envs.gym.batched): what
# gymnasium.make_vec(id, num_envs=N) returns unless told vectorization_mode="sync" or "async"
VECTOR_ENTRY_POINTS = {
    "MapTidal/GoToPose-v1": "maptidal.envs.gym.batched:go_to_pose",
    "MapTidal/StationKeeping-v1": "maptidal.envs.gym.batched:station_keeping",
}


def register_environments() -> None:
    """Register every environment with Gymnasium (idempotent)."""
    import gymnasium

    for env_id, entry_point in ENVIRONMENTS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point=entry_point,
                max_episode_steps=MAX_EPISODE_STEPS[env_id],
                disable_env_checker=False,
                vector_entry_point=VECTOR_ENTRY_POINTS.get(env_id),
            )
