"""The Kimera-style mesher and the synthetic keyframes of the tank."""

import numpy as np
import pytest
from geometry_oracles import distances_to_triangles
from scipy.spatial import Delaunay

from maptidal.evaluation.coverage import voxel_centres
from maptidal.geometry import CameraModel, in_frustum
from maptidal.keyframes import (
    ExplorationParams,
    StereoCameraParams,
    exploration_keyframes,
    exploration_poses,
    render_keyframe,
    tank_landmarks,
)
from maptidal.perception.mesher import MesherParams, delaunay_triangles, kimera_mesh, triangle_quality_mask
from maptidal.tank import TankModel

IMAGE = (640, 400)


def _canonical(triangles: np.ndarray) -> set[tuple[int, ...]]:
    return {tuple(sorted(t)) for t in triangles.tolist()}


def test_subdiv2d_triangulation_equals_scipy_delaunay():
    rng = np.random.default_rng(0)
    pixels = rng.uniform([5, 5], [635, 395], size=(80, 2))
    ours = _canonical(delaunay_triangles(pixels, IMAGE))
    delaunay = Delaunay(pixels)
    reference = _canonical(delaunay.simplices)
    # Subdiv2D may attach a thin hull triangle to its virtual outer vertices, and Kimera
    # drops those: every triangle we keep is Delaunay's, and only hull triangles go missing.
    assert ours <= reference
    hull_triangles = [
        t for t, n in zip(delaunay.simplices.tolist(), delaunay.neighbors.tolist(), strict=True) if -1 in n
    ]
    assert reference - ours <= _canonical(np.array(hull_triangles))
    assert len(reference - ours) <= 3


def test_pixels_outside_the_image_or_duplicated_are_not_vertices():
    pixels = np.array([[10, 10], [600, 20], [300, 380], [700, 100], [10, 10], [np.nan, 5]], float)
    triangles = delaunay_triangles(pixels, IMAGE)
    assert _canonical(triangles) == {(0, 1, 2)}


def _wall_keypoints(rng, n=120, distance=1.5):
    """Keypoints on the wall x = 0 seen by a camera at (-distance, 0, 1) looking +x."""
    camera = StereoCameraParams()
    u = rng.uniform(0, IMAGE[0], n)
    v = rng.uniform(0, IMAGE[1], n)
    y = -(u - IMAGE[0] / 2) / camera.fx * distance
    z = 1.0 - (v - IMAGE[1] / 2) / camera.fy * distance
    return np.column_stack([u, v]), np.column_stack([np.zeros(n), y, z])


def test_mesh_faces_face_their_camera_and_vertices_are_landmarks():
    rng = np.random.default_rng(1)
    pixels, landmarks = _wall_keypoints(rng)
    position, forward = np.array([-1.5, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    mesh = kimera_mesh(pixels, landmarks, IMAGE, position, forward)
    assert len(mesh.faces) > 100
    v, f = mesh.vertices, mesh.faces
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    to_camera = position - v[f].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", normals, to_camera) > 0)
    np.testing.assert_array_equal(v, landmarks[mesh.keypoint_ids])


def test_keypoints_without_a_landmark_are_dropped():
    rng = np.random.default_rng(2)
    pixels, landmarks = _wall_keypoints(rng, n=60)
    landmarks[:10] = np.nan
    mesh = kimera_mesh(pixels, landmarks, IMAGE, np.array([-1.5, 0, 1.0]), np.array([1.0, 0, 0]))
    assert not set(range(10)) & set(mesh.keypoint_ids.tolist())
    assert np.isfinite(mesh.vertices).all()


def test_bad_triangle_filters():
    camera, forward = np.zeros(3), np.array([1.0, 0, 0])
    flat = np.array([[[1.0, 0, 0], [1.0, 0.3, 0], [1.0, 0, 0.3]]])  # faces the camera
    deep = np.array([[[1.0, 0, 0], [3.0, 0.05, 0], [2.0, 0, 0.05]]])  # along the ray: elongated in depth
    sliver = np.array([[[1.0, 0, 0], [1.0, 1.0, 0], [1.0, 0.99, 0.1]]])  # side ratio tiny
    huge = np.array([[[5.0, 0, 0], [5.0, 3.0, 0], [5.0, 0, 3.0]]])  # longest side > 2 m
    params = MesherParams()
    corners = np.concatenate([flat, deep, sliver, huge])
    np.testing.assert_array_equal(
        triangle_quality_mask(corners, camera, forward, params), [True, False, False, False]
    )
    off = MesherParams(0.0, 0.0, 0.0)  # thresholds <= 0 skip the tests
    assert triangle_quality_mask(corners, camera, forward, off).all()


@pytest.fixture(scope="module")
def tank():
    return TankModel()


def test_landmarks_lie_on_the_tank(tank):
    landmarks = tank_landmarks(tank)
    triangles = tank.scene_triangles()
    sample = landmarks[np.random.default_rng(0).choice(len(landmarks), 200, replace=False)]
    distances = distances_to_triangles(sample, triangles)
    # On a surface; ladder points lie on a member's axis line, within its half width (2 cm).
    assert max(distances) < 0.021
    assert np.all(landmarks[:, 2] >= -1e-9) and np.all(landmarks[:, 2] <= tank.height + 1e-9)


def test_keyframe_keeps_visible_landmarks_in_both_images(tank):
    camera = StereoCameraParams()
    triangles = tank.scene_triangles()
    hidden = np.array([[0.5, 0.0, 1.0], [-0.5, 0.0, 1.0]])  # behind the end wall; in open water
    landmarks = np.vstack([tank_landmarks(tank), hidden])
    frame = render_keyframe(
        triangles,
        landmarks,
        np.array([-1.5, 0.0, 1.0]),
        np.array([1.0, 0, 0]),
        camera,
        np.random.default_rng(0),
    )
    assert len(landmarks) - 2 not in frame.landmark_ids  # occluded by the wall
    assert len(frame.landmark_ids) <= camera.max_keypoints
    assert np.all((frame.pixels >= 0) & (frame.pixels < [camera.width, camera.height]))
    # The right camera, one baseline to the right (-y here), sees them too.
    offsets = landmarks[frame.landmark_ids] - np.array([-1.5, -camera.baseline_m, 1.0])
    u_right = camera.width / 2 + camera.fx * (-offsets[:, 1]) / offsets[:, 0]
    assert np.all((u_right >= 0) & (u_right < camera.width))
    # Noise moves a landmark along its ray only: its pixel is unchanged.
    noisy = frame.landmarks - np.array([-1.5, 0.0, 1.0])
    u = camera.width / 2 + camera.fx * (-noisy[:, 1]) / noisy[:, 0]
    np.testing.assert_allclose(u, frame.pixels[:, 0])
    assert len(frame.mesh.faces) > 50


def test_depth_noise_grows_with_range_as_stereo(tank):
    camera = StereoCameraParams(max_keypoints=10_000, max_range_m=10.0)
    empty = np.empty((0, 3, 3))
    rng = np.random.default_rng(5)
    for depth in (1.0, 2.5):
        points = np.column_stack(
            [np.full(4000, depth), rng.uniform(-0.3, 0.3, 4000), rng.uniform(-0.2, 0.2, 4000)]
        )
        frame = render_keyframe(empty, points, np.zeros(3), np.array([1.0, 0, 0]), camera, rng)
        errors = frame.landmarks[:, 0] - depth
        expected = depth**2 * camera.disparity_sigma_px / (camera.fx * camera.baseline_m)
        assert np.std(errors) == pytest.approx(expected, rel=0.1)
        assert abs(np.mean(errors)) < 4 * expected / np.sqrt(len(errors))


def test_exploration_views_the_whole_evaluated_region(tank):
    camera = StereoCameraParams()
    frustum = CameraModel(camera.hfov_deg, camera.vfov_deg, camera.max_range_m)
    voxels = voxel_centres(tank.evaluated_surface(), 0.1)
    seen = np.zeros(len(voxels), bool)
    for position, forward in exploration_poses(tank, ExplorationParams()):
        seen |= in_frustum(np.concatenate([position, forward]), voxels, frustum)
    assert seen.all()


def test_exploration_keyframes_are_deterministic(tank):
    a = exploration_keyframes(tank, ExplorationParams(heights_m=(1.0,), yaw_step_deg=60.0), seed=3)
    b = exploration_keyframes(tank, ExplorationParams(heights_m=(1.0,), yaw_step_deg=60.0), seed=3)
    assert len(a) == 4
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.mesh.faces, y.mesh.faces)
        np.testing.assert_array_equal(x.landmarks, y.landmarks)
