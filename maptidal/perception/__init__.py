"""Perception front end: from stereo images to Kimera-style keyframe meshes (issue [perception]).

- :mod:`maptidal.perception.recording`: the recording folder the front end reads (images, intrinsics,
  poses by source), its checks and an incremental writer;
- :mod:`maptidal.perception.stereo`: keypoints on the left image (ORB, FAST, GFTT, SIFT, bucketed),
  matches along the rectified row (SSD, ratio test, left-right check, sub-pixel) and triangulation;
- :mod:`maptidal.perception.tracking`: KLT tracking with a forward-backward check and persistent
  landmark ids, refilled from the grid (:class:`~maptidal.perception.tracking.LandmarkTracker`);
- :mod:`maptidal.perception.landmarks`: world-frame fusion of each landmark's observations, weighted by
  their stereo covariance, with outlier rejection;
- :mod:`maptidal.perception.keyframing`: keyframes by time, translation and rotation;
- :mod:`maptidal.perception.odometry`: frame-to-frame PnP fused with dead reckoning;
- :mod:`maptidal.perception.frontend`: the stages frame by frame, and over a whole recording;
- :mod:`maptidal.perception.mesher` takes pixels and their 3D landmarks, wherever they came from
  (synthetic keyframes, rendered stereo frames, or a real SLAM front end), and returns the
  per-keyframe mesh that task discovery consumes;
- :mod:`maptidal.perception.overlays`: Fig. 4-style pictures of a keyframe.

None of them imports the simulator: a real OAK-D recording in the same folder shape runs unchanged.
"""
