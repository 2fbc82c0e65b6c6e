"""Perception front end: from keypoints to Kimera-style keyframe meshes.

:mod:`maptidal.perception.mesher` takes pixels and their 3D landmarks, wherever they
came from (synthetic keyframes today, rendered stereo frames later, or a real SLAM
front end), and returns the per-keyframe mesh that task discovery consumes.
"""
