"""Benchmark: voxel-frustum counting on the default tank, against a naive per-voxel loop.

Both run in this process on the same voxels and viewpoints and must agree exactly;
the ratio is what matters, not the absolute times. Run with ``make bench``.
"""

from __future__ import annotations

import time

import numpy as np

from maptidal.evaluation.baselines import strip_to_viewpoints
from maptidal.evaluation.coverage import CoverageModel
from maptidal.geometry import _inside_local, _view_frames
from maptidal.tank import TankModel


def naive_views(viewpoints: np.ndarray, voxels: np.ndarray, camera) -> np.ndarray:
    """Per voxel, test every viewpoint's frustum (the loop the paper's description suggests)."""
    frames = _view_frames(viewpoints)
    counts = np.zeros(len(voxels), dtype=np.int64)
    for index, voxel in enumerate(voxels):
        local = np.einsum("nij,nj->ni", frames, voxel - viewpoints[:, :3])
        counts[index] = np.count_nonzero(_inside_local(local[:, 0], local[:, 1], local[:, 2], camera))
    return counts


def random_viewpoints(tank: TankModel, count: int, rng: np.random.Generator) -> np.ndarray:
    """Viewpoints 1 m off random points of the walls, looking at them."""
    s = rng.uniform(0.0, tank.strip_length, count)
    z = rng.uniform(0.0, tank.height, count)
    return strip_to_viewpoints(tank, s, z, 1.0)


def main() -> None:
    """Print the timing table."""
    tank = TankModel()
    model = CoverageModel.from_tank(tank)
    rng = np.random.default_rng(0)
    print(f"default tank: {len(model.voxels)} voxels of {model.params.voxel_m} m")
    print(f"{'viewpoints':>10} {'vectorised (s)':>15} {'naive (s)':>10} {'ratio':>7}")
    for count in (20, 100, 1000):
        viewpoints = random_viewpoints(tank, count, rng)
        start = time.perf_counter()
        fast = model.views(viewpoints)
        fast_s = time.perf_counter() - start
        start = time.perf_counter()
        slow = naive_views(viewpoints, model.voxels, model.params.camera)
        slow_s = time.perf_counter() - start
        assert np.array_equal(fast, slow), "the vectorised count disagrees with the naive loop"
        print(f"{count:>10} {fast_s:>15.4f} {slow_s:>10.3f} {slow_s / fast_s:>6.1f}x")


if __name__ == "__main__":
    main()
