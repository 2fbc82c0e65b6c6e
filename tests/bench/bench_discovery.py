"""Benchmark: vectorised discovery against the literal pseudo-code, same process.

Times maptidal.discovery.discover and tests/bench/literal_discovery.py on wall-like
meshes of 1k, 10k and 100k faces, without and with existing tasks, checks that
both return identical tasks, and prints the speed-up ratio. Goals (issue #2):
at least 50x at 10k faces, and 100k faces in under 2 s.

Usage: python tests/bench/bench_discovery.py [--sizes 1000 10000 100000] [--literal-max 100000]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from literal_discovery import task_discovery

from maptidal.discovery import discover
from maptidal.synthetic import wall_grid_mesh


def best_of(function, repeats: int) -> tuple[float, object]:
    """Smallest wall time of ``repeats`` calls, and the last result."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return min(times), result


def main() -> int:
    """Run the benchmark table; exit status 1 if fast and literal disagree."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 100000])
    parser.add_argument(
        "--literal-max", type=int, default=100000, help="skip the literal run above this size"
    )
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()

    print(f"{'faces':>7} {'existing':>8} {'tasks':>5} {'fast (s)':>9} {'literal (s)':>11} {'ratio':>7} same")
    all_same = True
    for size in args.sizes:
        vertices, faces = wall_grid_mesh(size, seed=1)
        # Existing tasks: the output of a neighbouring, overlapping wall patch.
        shifted = vertices + np.array([0.0, 1.5, 0.0])
        existing = discover(shifted, faces).final
        for label, tasks in (("none", None), (str(len(existing)), existing)):
            fast_s, result = best_of(
                lambda v=vertices, f=faces, t=tasks: discover(v, f, existing=t), args.repeats
            )
            line = f"{len(faces):>7} {label:>8} {result.counts['final']:>5} {fast_s:>9.4f}"
            if size <= args.literal_max:
                literal_s, (literal, _) = best_of(
                    lambda v=vertices, f=faces, t=tasks: task_discovery(v, f, [] if t is None else t), 1
                )
                same = np.array_equal(np.asarray(literal, float).reshape(-1, 6), result.final)
                all_same &= same
                line += f" {literal_s:>11.3f} {literal_s / fast_s:>6.1f}x {'yes' if same else 'NO'}"
            print(line, flush=True)
    return 0 if all_same else 1


if __name__ == "__main__":
    sys.exit(main())
