"""Perception front end: from stereo images to Kimera-style keyframe meshes.

- :mod:`maptidal.perception.stereo`: keypoints on the left image (ORB, FAST, GFTT, SIFT, bucketed),
  matches along the rectified row (SAD, ratio test, left-right check, sub-pixel) and triangulation;
- :mod:`maptidal.perception.tracking`: KLT tracking with a forward-backward check and persistent
  landmark ids, refilled from the grid (:class:`~maptidal.perception.tracking.LandmarkTracker`);
- :mod:`maptidal.perception.mesher` takes pixels and their 3D landmarks, wherever they came from
  (synthetic keyframes, rendered stereo frames, or a real SLAM front end), and returns the
  per-keyframe mesh that task discovery consumes.

Landmark fusion, keyframe selection and localisation are still to come (issue [perception]).
"""
