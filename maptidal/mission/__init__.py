"""The mission layer: the one part of maptidal besides the CLI that drives the simulator (``envs/``).

- :mod:`maptidal.mission.capture` flies a robot along a scripted path with the simulator's own physics
  and a go-to-pose controller on its estimated state, and writes its stereo frames and poses as a
  recording (:mod:`maptidal.perception.recording`).
"""
