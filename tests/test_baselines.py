"""The Voronoi (Lloyd) and boustrophedon baselines."""

import numpy as np
import pytest
from geometry_oracles import distances_to_triangles
from scipy.spatial import cKDTree

from maptidal.evaluation.baselines import (
    BoustrophedonParams,
    VoronoiParams,
    boustrophedon_viewpoints,
    lane_heights,
    lane_positions,
    lloyd_relaxation,
    quantisation_energy,
    strip_samples,
    voronoi_viewpoints,
)
from maptidal.raycast import first_hit_distances
from maptidal.tank import TankModel


def test_lloyd_lowers_the_quantisation_energy_and_converges():
    params = VoronoiParams(n_seeds=12, margin_m=0.2, seed=4)
    result = lloyd_relaxation(5.4, 2.0, params)
    energies = np.array(result.energies)
    assert result.converged
    assert energies[-1] < 0.7 * energies[0]
    assert np.all(np.diff(energies) <= 1e-12)  # never rises
    assert np.all(result.seeds >= 0.2 - 1e-12)
    assert np.all(result.seeds <= np.array([5.4 - 0.2, 2.0 - 0.2]) + 1e-12)


def test_wall_avoidance_margin_holds_where_centroids_would_cross_it():
    # Free centroids of 20 cells on a 5.4 x 2 m strip lie about 0.3-0.5 m from the edges,
    # so a 0.6 m margin must clamp some seeds onto the margin box.
    result = lloyd_relaxation(5.4, 2.0, VoronoiParams(margin_m=0.6, seed=0))
    low, high = np.array([0.6, 0.6]), np.array([4.8, 1.4])
    assert np.all(result.seeds >= low - 1e-12) and np.all(result.seeds <= high + 1e-12)
    on_box = np.isclose(result.seeds, low) | np.isclose(result.seeds, high)
    assert on_box.any()


def test_lloyd_seeds_end_near_their_cell_centroids():
    params = VoronoiParams(n_seeds=6, margin_m=0.0, tolerance_m=1e-5, max_iterations=2000, seed=1)
    result = lloyd_relaxation(3.0, 2.0, params)
    samples = strip_samples(3.0, 2.0, params.sample_step_m)
    _, owner = cKDTree(result.seeds).query(samples)
    for k, seed in enumerate(result.seeds):
        centroid = samples[owner == k].mean(axis=0)
        assert np.linalg.norm(centroid - seed) < 1e-3
    assert quantisation_energy(samples, result.seeds) == pytest.approx(result.energies[-1])


def test_lloyd_rejects_a_margin_that_leaves_no_room():
    with pytest.raises(ValueError, match="no room"):
        lloyd_relaxation(1.0, 1.0, VoronoiParams(margin_m=0.6))


def _check_viewpoints_look_at_the_wall(tank: TankModel, viewpoints: np.ndarray) -> None:
    surface = tank.evaluated_surface()
    # One metre off the wall, looking at it: the ray along the view hits the walls at about 1 m.
    hits = first_hit_distances(viewpoints[:, :3], viewpoints[:, 3:], surface.triangles)
    assert np.all(hits <= 1.0 + tank.config.window.recess + 1e-6)
    assert np.all(hits >= 0.7)  # corners (bisector views) and the window recess sit a little nearer/farther
    np.testing.assert_allclose(np.linalg.norm(viewpoints[:, 3:], axis=1), 1.0)
    # Off the walls: no viewpoint is within 0.7 m of the surface, and all are inside the tank.
    distance = distances_to_triangles(viewpoints[:, :3], surface.triangles)
    assert np.all(distance >= 0.7)
    assert np.all(viewpoints[:, 0] < 0.0)
    side_y = max(abs(seg.start[1]) for seg in tank.segments)
    assert np.all(np.abs(viewpoints[:, 1]) < side_y)
    assert np.all((viewpoints[:, 2] > 0.0) & (viewpoints[:, 2] < tank.height))


def test_voronoi_viewpoints():
    tank = TankModel()
    viewpoints = voronoi_viewpoints(tank, VoronoiParams(seed=2))
    assert viewpoints.shape == (20, 6)
    _check_viewpoints_look_at_the_wall(tank, viewpoints)


def test_boustrophedon_lanes_and_points():
    tank = TankModel()
    params = BoustrophedonParams()
    spacing = params.lane_spacing()
    # the OAK-D's footprint height at 1 m, from its spec sheet: 400 px x 6 um (binned) / 2.35 mm
    assert spacing == pytest.approx(400 * 6e-6 / 2.35e-3 - 0.1)
    heights = lane_heights(tank.height, params)
    footprint = spacing + 0.1
    # The lanes' footprints, overlapping by 0.1 m, cover the whole height.
    assert heights[0] - footprint / 2 <= 0.0 and heights[-1] + footprint / 2 >= tank.height
    np.testing.assert_allclose(np.diff(heights), spacing)
    along = lane_positions(tank, params)
    corners = tank.corner_s()
    # Corners plus two points inside every section longer than 1 m (only the 2.4 m end wall).
    assert len(along) == len(corners) + 2
    assert set(np.round(corners, 9)) <= set(np.round(along, 9))
    viewpoints = boustrophedon_viewpoints(tank, params)
    assert len(viewpoints) == len(heights) * len(along)
    _check_viewpoints_look_at_the_wall(tank, viewpoints)
    # Boustrophedon: the second lane runs back the way the first came.
    first, second = viewpoints[: len(along)], viewpoints[len(along) : 2 * len(along)]
    np.testing.assert_allclose(first[:, :2], second[::-1, :2])


def test_baselines_follow_another_tank():
    from maptidal.tank import TankConfig

    tank = TankModel(TankConfig(end_wall_width=6.0, water_depth=3.0))
    viewpoints = boustrophedon_viewpoints(tank)
    # 3 m at 0.92 m lane spacing with 0.1 m overlap: 3 lanes reach 2.86 m, so 4 are needed
    assert len(lane_heights(3.0, BoustrophedonParams())) == 4
    _check_viewpoints_look_at_the_wall(tank, viewpoints)
    _check_viewpoints_look_at_the_wall(tank, voronoi_viewpoints(tank))


def test_the_seed_generator_spreads_seeds_on_a_jittered_grid():
    """The generator reading of the paper's Voronoi tool: a regular grid at regularity 1 without Lloyd
    steps (cell centres), every seed inside the wall-avoidance margin, and Lloyd steps lowering the
    quantisation energy from the jittered start."""
    from maptidal.evaluation.baselines import (
        VoronoiParams,
        jittered_grid_seeds,
        quantisation_energy,
        strip_samples,
        voronoi_seeds,
    )

    regular = jittered_grid_seeds(5.4, 2.0, VoronoiParams(layout="generator", regularity=1.0, lloyd_steps=0))
    assert len(regular) == 20
    # round(sqrt(20 x 4.9 / 1.5)) = 8 columns, ceil(20 / 8) = 3 rows of (4.9 / 8) x (1.5 / 3) m cells
    # from (0.25, 0.25): the seeds sit on that lattice's centres, 20 of its 24 cells
    columns = (regular[:, 0] - 0.25) / (4.9 / 8) - 0.5
    rows = (regular[:, 1] - 0.25) / (1.5 / 3) - 0.5
    assert np.allclose(columns, np.round(columns)) and np.allclose(rows, np.round(rows))
    for regularity in (0.0, 0.5):
        params = VoronoiParams(layout="generator", regularity=regularity, lloyd_steps=0, seed=3)
        seeds = voronoi_seeds(5.4, 2.0, params)
        assert np.all(seeds >= 0.25 - 1e-12) and np.all(seeds[:, 0] <= 5.15) and np.all(seeds[:, 1] <= 1.75)
        samples = strip_samples(5.4, 2.0, 0.02)
        relaxed = voronoi_seeds(
            5.4, 2.0, VoronoiParams(layout="generator", regularity=regularity, lloyd_steps=3, seed=3)
        )
        assert quantisation_energy(samples, relaxed) < quantisation_energy(samples, seeds)
    with pytest.raises(ValueError):
        VoronoiParams(layout="websvg")


def test_a_fully_jittered_seed_stays_in_its_own_cell():
    """At regularity 0 each seed lies anywhere in its grid cell, never in a neighbour's: one seed per
    cell of the 8 x 3 lattice, and together they spread over more than a regular grid's offsets."""
    from maptidal.evaluation.baselines import VoronoiParams, jittered_grid_seeds

    for seed in range(5):
        params = VoronoiParams(layout="generator", regularity=0.0, lloyd_steps=0, seed=seed)
        seeds = jittered_grid_seeds(5.4, 2.0, params)
        cell = np.array([4.9 / 8, 1.5 / 3])
        cells = np.floor((seeds - 0.25) / cell).astype(int)
        assert len({tuple(c) for c in cells}) == 20
        assert np.all((cells >= 0) & (cells < [8, 3]))
        offsets = (seeds - 0.25) / cell - cells  # position within the cell, 0..1
        assert offsets.std() > 0.2  # not the cell centres
