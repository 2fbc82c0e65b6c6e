"""The mission layer: the one part of maptidal besides the CLI that drives the simulator (``envs/``).

- :mod:`maptidal.mission.capture` flies a robot along a scripted path with the simulator's own physics
  and a go-to-pose controller on its estimated state, and writes its stereo frames and poses as a
  recording (:mod:`maptidal.perception.recording`).
- :mod:`maptidal.mission.run` is the closed-loop Map-TIDAL mission (``maptidal run``), set up from a
  mission file by :mod:`maptidal.mission.config`.
- :mod:`maptidal.mission.perception` runs the robots' front ends and discovery beside the mission's loop,
  in a worker process or inline, with a fixed one-frame latency.
- :mod:`maptidal.mission.outputs` writes the event log, trajectories, snapshots, plots and report, and
  rebuilds them from the log; :mod:`maptidal.mission.video` writes ``--video``'s MP4.
- :mod:`maptidal.mission.batch` runs many missions (``maptidal batch``) on local processes or Ray.
"""
