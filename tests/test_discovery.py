"""Map-TIDAL discovery against the paper's figures and a literal transcription of its pseudo-code."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from literal_discovery import task_discovery as literal_discovery

from maptidal.discovery import (
    DiscoveryInputError,
    DiscoveryParams,
    discover,
    generate_points,
    prune,
)
from maptidal.synthetic import wall_grid_mesh, wall_keyframe_mesh


def task(position, direction):
    d = np.asarray(direction, dtype=float)
    return np.concatenate([np.asarray(position, dtype=float), d / np.linalg.norm(d)])


def rotated_x(angle):
    """A unit direction at ``angle`` rad from +x, in the x-y plane."""
    return [math.cos(angle), math.sin(angle), 0.0]


PARAMS = DiscoveryParams()  # r_ex 1.7 m, theta_ex 0.25 rad, p_s 0.7


# --- Step 1: Generate Points -------------------------------------------------------------------


def test_generate_points_follows_the_winding_normal_and_skips_degenerate_faces():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [2, 0, 0]], dtype=float)
    faces = np.array([[0, 1, 2], [0, 2, 1], [0, 1, 4], [0, 1, 3]])  # third is degenerate (collinear)
    cips = generate_points(vertices, faces, standoff=1.5)
    assert len(cips) == 3
    centroid = np.array([1 / 3, 1 / 3, 0])
    np.testing.assert_allclose(cips[0], [*(centroid + [0, 0, 1.5]), 0, 0, -1])  # CCW seen from +z
    np.testing.assert_allclose(cips[1], [*(centroid - [0, 0, 1.5]), 0, 0, 1])  # reversed winding
    np.testing.assert_allclose(cips[2], [1 / 3, -1.5, 1 / 3, 0, 1, 0])  # x cross z = -y


# --- Step 2: pruning, the paper's Fig. 3b -----------------------------------------------------

EXISTING = task([0, 0, 0], [1, 0, 0])


def test_fig3b_case_a_no_task_within_r_ex_is_kept():
    # Another CIP is close to the existing task, so precheck fails and mode 0 applies.
    near_blocked = task([0.5, 0, 0], [1, 0, 0])
    case_a = task([0, 2.0, 0], [1, 0, 0])  # 2.0 m away, aligned
    pruned, mode = prune(np.vstack([near_blocked, case_a]), EXISTING[None], 0, PARAMS)
    assert mode == "existing"
    np.testing.assert_array_equal(pruned, case_a[None])


def test_fig3b_case_b_within_r_ex_but_outside_theta_ex_is_kept():
    case_b = task([0, 1.0, 0], rotated_x(0.4))  # 1 m away, 0.4 rad apart
    pruned, mode = prune(case_b[None], EXISTING[None], 0, PARAMS)
    assert mode == "existing"
    np.testing.assert_array_equal(pruned, case_b[None])


def test_fig3b_case_c_within_both_is_removed():
    case_c = task([0, 1.0, 0], rotated_x(0.1))
    pruned, mode = prune(case_c[None], EXISTING[None], 0, PARAMS)
    assert mode == "existing"
    assert len(pruned) == 0


def test_distance_comparison_is_strict():
    at_limit = task([1.5, 0, 0], [1, 0, 0])  # exactly r_ex away, aligned
    params = DiscoveryParams(r_ex=1.5)
    # At exactly r_ex nothing is within r_ex: precheck holds, self-pruning of one CIP keeps it.
    pruned, mode = prune(at_limit[None], EXISTING[None], 0, params)
    assert mode == "self(precheck)"
    np.testing.assert_array_equal(pruned, at_limit[None])
    closer = task([1.25, 0, 0], [1, 0, 0])
    assert len(prune(closer[None], EXISTING[None], 0, params)[0]) == 0


def test_precheck_falls_back_to_self_pruning_when_no_task_is_near():
    rng = np.random.default_rng(0)
    candidates = np.hstack([rng.uniform(0, 2, (60, 3)), np.tile([1.0, 0, 0], (60, 1))])
    far_task = task([100, 0, 0], [1, 0, 0])
    pruned, mode = prune(candidates, far_task[None], 0, PARAMS)
    self_pruned, self_mode = prune(candidates, np.empty((0, 6)), 2, PARAMS)
    assert (mode, self_mode) == ("self(precheck)", "self")
    np.testing.assert_array_equal(pruned, self_pruned)


def test_precheck_fails_on_any_pair_within_r_ex_whatever_the_angle():
    # One CIP is near the existing task but faces away: precheck is false, nothing is pruned,
    # and the aligned duplicate pair survives (no self-pruning happened).
    facing_away = task([0.5, 0, 0], [-1, 0, 0])
    duplicate = task([0.5, 0.1, 0], [-1, 0, 0])
    pruned, mode = prune(np.vstack([facing_away, duplicate]), EXISTING[None], 0, PARAMS)
    assert mode == "existing"
    assert len(pruned) == 2


def test_self_pruning_uses_thresholds_scaled_by_p_s():
    first = task([0, 0, 0], [1, 0, 0])
    at_1_3_m = task([0, 1.3, 0], [1, 0, 0])  # within r_ex (1.7) but not r_ex * p_s (1.19)
    at_1_0_m = task([0, 1.0, 0], rotated_x(0.2))  # within 1.19 m, angle 0.2 > 0.25 * 0.7
    at_0_5_m = task([0, 0.5, 0], rotated_x(0.15))  # within both scaled thresholds
    pruned, mode = prune(np.vstack([first, at_1_3_m, at_1_0_m, at_0_5_m]), np.empty((0, 6)), 2, PARAMS)
    assert mode == "self"
    np.testing.assert_array_equal(pruned, np.vstack([first, at_1_3_m, at_1_0_m]))  # C[0] once


# --- Step 4: final pruning, the paper's Fig. 3d ------------------------------------------------


def test_fig3d_final_pruning_removes_the_later_of_two_close_aligned_candidates():
    confirmed = task([5, 5, 0], [1, 0, 0])[None]
    earlier = task([0, 0, 0], [1, 0, 0])
    later = task([0, 1.3, 0], rotated_x(0.1))
    final, _ = prune(np.vstack([earlier, later]), confirmed, 1, PARAMS)
    np.testing.assert_array_equal(final, np.vstack([confirmed, earlier]))
    final_reversed, _ = prune(np.vstack([later, earlier]), confirmed, 1, PARAMS)
    np.testing.assert_array_equal(final_reversed, np.vstack([confirmed, later]))


def test_final_pruning_compares_against_confirmed_tasks():
    confirmed = task([0, 0, 0], [1, 0, 0])[None]
    shadowed = task([0, 1.0, 0], [1, 0, 0])
    distinct = task([0, 1.0, 0], [0, 1, 0])
    final, _ = prune(np.vstack([shadowed, distinct]), confirmed, 1, PARAMS)
    np.testing.assert_array_equal(final, np.vstack([confirmed, distinct]))


# --- Whole algorithm ------------------------------------------------------------------------------


def _as_rows(tasks):
    return np.asarray(tasks, dtype=float).reshape(-1, 6)


def test_discover_matches_the_literal_pseudo_code_on_a_keyframe():
    # A patch about one camera footprint wide, so that some CIPs reach t = 0.75.
    vertices, faces = wall_keyframe_mesh(0.0, width=1.7, height=1.3, seed=3)
    result = discover(vertices, faces)
    literal, stages = literal_discovery(vertices, faces, [])
    assert result.counts == stages
    np.testing.assert_array_equal(result.final, _as_rows(literal))
    assert result.counts["confirmed"] > 0 and len(result.remains) > 0  # both branches exercised


def test_scores_and_stages_are_consistent():
    vertices, faces = wall_keyframe_mesh(0.5, seed=1)
    result = discover(vertices, faces)
    t = result.params.threshold
    np.testing.assert_array_equal(result.confirmed, result.after_prune[result.scores >= t])
    np.testing.assert_array_equal(result.remains, result.after_prune[result.scores < t])
    np.testing.assert_array_equal(result.final[: len(result.confirmed)], result.confirmed)
    assert np.all((result.scores >= 0) & (result.scores <= 1))


def test_multi_frame_run_chains_existing_tasks():
    frame1 = wall_keyframe_mesh(-0.6, seed=10)
    frame2 = wall_keyframe_mesh(0.4, seed=11)
    first = discover(*frame1)
    second = discover(*frame2, existing=first.final)
    literal_first, _ = literal_discovery(*frame1, [])
    literal_second, stages = literal_discovery(*frame2, _as_rows(literal_first))
    np.testing.assert_array_equal(second.final, _as_rows(literal_second))
    assert second.counts == stages
    assert second.pruning_mode == "existing"
    assert second.counts["after_prune"] < first.counts["after_prune"]
    # No new task is excluded by an existing one (within both r_ex and theta_ex).
    p = second.params
    for new in second.final:
        d = np.linalg.norm(first.final[:, :3] - new[:3], axis=1)
        angle = np.arccos(np.clip(first.final[:, 3:] @ new[3:], -1, 1))
        assert not np.any((d < p.r_ex) & (angle < p.theta_ex))
        # and the output never repeats an existing task
        assert not np.any(np.all(first.final == new, axis=1))


def test_explicit_keypoints_replace_mesh_vertices():
    vertices, faces = wall_keyframe_mesh(0.0, seed=2)
    keypoints = vertices[np.abs(vertices[:, 1]) < 0.3]  # a cluster in the centre
    with_keypoints = discover(vertices, faces, keypoints=keypoints)
    literal, stages = literal_discovery(vertices, faces, [], keypoints=keypoints)
    np.testing.assert_array_equal(with_keypoints.final, _as_rows(literal))
    assert with_keypoints.counts == stages


# --- Properties (hypothesis) ----------------------------------------------------------------------


def _random_case(seed, n_vertices, n_faces, n_existing):
    rng = np.random.default_rng(seed)
    vertices = rng.uniform([-0.3, -2, -1], [0.3, 2, 1], (n_vertices, 3))
    faces = rng.integers(0, n_vertices, (n_faces, 3))
    faces[: n_faces // 10, 1] = faces[: n_faces // 10, 0]  # some zero-area faces
    existing = np.hstack([rng.uniform(-2, 2, (n_existing, 3)), rng.normal(size=(n_existing, 3))])
    existing[:, 3:] /= np.linalg.norm(existing[:, 3:], axis=1, keepdims=True)
    params = DiscoveryParams(
        r_ex=float(rng.uniform(0.3, 2.0)),
        theta_ex=float(rng.uniform(0.1, 1.2)),
        threshold=float(rng.uniform(0.0, 0.5)),
        p_s=float(rng.uniform(0.4, 1.0)),
    )
    return vertices, faces, existing, params


CASES = st.tuples(st.integers(0, 2**32 - 1), st.integers(3, 40), st.integers(1, 80), st.integers(0, 6))


@settings(max_examples=60, deadline=None)
@given(CASES)
def test_property_fast_discovery_equals_literal_transcription(case):
    vertices, faces, existing, params = _random_case(*case)
    if not np.any(
        np.linalg.norm(np.cross(*(vertices[faces[:, k]] - vertices[faces[:, 0]] for k in (1, 2))), axis=1) > 0
    ):
        return  # all faces degenerate: covered by the bad-input tests
    result = discover(vertices, faces, existing=existing, params=params)
    literal, stages = literal_discovery(
        vertices,
        faces,
        existing,
        L_i=params.standoff,
        r_ex=params.r_ex,
        theta_ex=params.theta_ex,
        t=params.threshold,
        p_s=params.p_s,
    )
    assert result.counts == stages
    np.testing.assert_array_equal(result.final, _as_rows(literal))


@settings(max_examples=60, deadline=None)
@given(CASES)
def test_property_final_pruning_leaves_no_excluded_pairs(case):
    vertices, faces, existing, params = _random_case(*case)
    try:
        result = discover(vertices, faces, existing=existing, params=params)
    except DiscoveryInputError:
        return
    added = result.final[len(result.confirmed) :]
    reference = np.vstack([result.confirmed, added])
    for i, row in enumerate(added):
        others = np.delete(reference, len(result.confirmed) + i, axis=0)
        d = np.linalg.norm(others[:, :3] - row[:3], axis=1)
        angle = np.arccos(np.clip(others[:, 3:] @ row[3:], -1, 1))
        assert not np.any((d < params.r_ex) & (angle < params.theta_ex))


@settings(max_examples=25, deadline=None)
@given(CASES)
def test_property_discovery_is_deterministic(case):
    vertices, faces, existing, params = _random_case(*case)
    try:
        first = discover(vertices, faces, existing=existing, params=params)
    except DiscoveryInputError:
        return
    second = discover(vertices.copy(), faces.copy(), existing=existing.copy(), params=params)
    for stage in ("cips", "after_prune", "scores", "confirmed", "final"):
        np.testing.assert_array_equal(getattr(first, stage), getattr(second, stage))


def test_large_wall_matches_literal():
    vertices, faces = wall_grid_mesh(3000, seed=4)
    result = discover(vertices, faces)
    literal, stages = literal_discovery(vertices, faces, [])
    assert result.counts == stages
    np.testing.assert_array_equal(result.final, _as_rows(literal))


# --- Bad input ------------------------------------------------------------------------------------

GOOD_VERTICES = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float)
GOOD_FACES = np.array([[0, 1, 2]])


@pytest.mark.parametrize(
    ("vertices", "faces", "message"),
    [
        (np.empty((0, 3)), np.empty((0, 3), dtype=int), "empty"),
        (GOOD_VERTICES, np.empty((0, 3), dtype=int), "empty"),
        (np.array([[0, 0, 0], [np.nan, 0, 0], [0, 1, 0]]), GOOD_FACES, "NaN"),
        (np.array([[0, 0, 0], [np.inf, 0, 0], [0, 1, 0]]), GOOD_FACES, "infinite"),
        (GOOD_VERTICES, np.array([[0, 1, 3]]), "indices"),
        (GOOD_VERTICES, np.array([[0, -1, 2]]), "indices"),
        (GOOD_VERTICES, np.array([[0, 1]]), "triangles"),
        (GOOD_VERTICES, np.array([[0, 0, 1], [2, 2, 2]]), "zero area"),
        (np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2]], dtype=float), GOOD_FACES, "zero area"),
    ],
)
def test_bad_meshes_get_a_clear_error(vertices, faces, message):
    with pytest.raises(DiscoveryInputError, match=message):
        discover(vertices, faces)


def test_bad_existing_tasks_and_keypoints_get_a_clear_error():
    with pytest.raises(DiscoveryInputError, match="unit"):
        discover(GOOD_VERTICES, GOOD_FACES, existing=[[0, 0, 0, 2.0, 0, 0]])
    with pytest.raises(DiscoveryInputError, match="NaN"):
        discover(GOOD_VERTICES, GOOD_FACES, existing=[[0, 0, np.nan, 1.0, 0, 0]])
    with pytest.raises(DiscoveryInputError, match="shape"):
        discover(GOOD_VERTICES, GOOD_FACES, keypoints=np.zeros((4, 2)))
    with pytest.raises(DiscoveryInputError, match="NaN"):
        discover(GOOD_VERTICES, GOOD_FACES, keypoints=np.array([[0, 0, np.nan]]))


@pytest.mark.parametrize(
    "field",
    [
        {"r_ex": 0},
        {"theta_ex": -0.1},
        {"p_s": 1.5},
        {"threshold": 1.2},
        {"standoff": float("nan")},
        {"hfov_deg": 200},
        {"range_m": -2},
    ],
)
def test_bad_parameters_get_a_clear_error(field):
    with pytest.raises(DiscoveryInputError):
        DiscoveryParams(**field)


@pytest.mark.parametrize("seed", range(4))
def test_confirm_decides_exactly_as_the_scores_do(seed):
    """Bounds settle most CIPs; the decision must still equal S >= t, including t equal to a score."""
    from maptidal.discovery import calculate_scores, confirm

    vertices, faces = wall_grid_mesh(3000, seed=seed)
    candidates = generate_points(vertices, faces, DiscoveryParams().standoff)[::7]
    camera = DiscoveryParams().camera
    scores = calculate_scores(candidates, vertices, camera)
    for threshold in (0.0, float(np.median(scores)), float(scores.max()), 0.75, 1.0):
        mask, _ = confirm(candidates, vertices, camera, threshold)
        np.testing.assert_array_equal(mask, scores >= threshold)


def test_result_scores_are_exact_when_asked():
    from maptidal.discovery import calculate_scores

    vertices, faces = wall_grid_mesh(2000, seed=5)
    result = discover(vertices, faces)
    np.testing.assert_array_equal(
        result.scores, calculate_scores(result.after_prune, vertices, result.params.camera)
    )
