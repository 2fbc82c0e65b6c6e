"""Re-run the physics mutation list of tests/README.md: apply each mutation to the source, run the physics
tests, record which test fails first, and restore the file. Every mutation must be killed.

    python tests/mutations/run_mutations.py            # all
    python tests/mutations/run_mutations.py M3 M7      # some

It edits files in place and restores them from memory afterwards (also on Ctrl-C); run it on a clean
tree.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TESTS = [
    "tests/test_fossen.py",
    "tests/test_physics.py",
    "tests/test_controllers.py",
    "tests/test_thrusters.py",
]

# id: (description, [(file, old, new), ...])
MUTATIONS: dict[str, tuple[str, list[tuple[str, str, str]]]] = {
    "M1": (
        "drop rigid-body Coriolis from the in-step solve",
        [("envs/_hydro.c", "(i < 3 ? gb[i] - mass * crb_l[i] : -crb_a[i - 3])", "(i < 3 ? gb[i] : 0.0)")],
    ),
    "M2": (
        "drop the added-mass Coriolis linear term -w x (A v_r)",
        [("envs/_hydro.c", "hydro[i] += fb[i] - (coriolis_added ? c1[i] : 0.0);", "hydro[i] += fb[i];")],
    ),
    "M3": (
        "flip the sign of the Munk moment v_r x (A v_r)",
        [
            (
                "envs/_hydro.c",
                "(coriolis_added ? c2[i] + c3[i] : 0.0)",
                "(coriolis_added ? -c2[i] + c3[i] : 0.0)",
            )
        ],
    ),
    "M4": (
        "divide the Heavy's heave added mass by 10 (vehicle file)",
        [
            (
                "assets/bluerov2/bluerov2.toml",
                "added_mass = [6.36, 7.12, 18.68,",
                "added_mass = [6.36, 7.12, 1.868,",
            )
        ],
    ),
    "M5": (
        "divide the Heavy's heave linear damping by 10 (vehicle file)",
        [
            (
                "assets/bluerov2/bluerov2.toml",
                "linear_damping = [13.7, 0.0, 33.0,",
                "linear_damping = [13.7, 0.0, 3.3,",
            )
        ],
    ),
    "M6": (
        "raise the Heavy's centre of buoyancy 10x (vehicle file)",
        [
            (
                "assets/bluerov2/bluerov2.toml",
                "centre_of_buoyancy = [0.0, 0.0, 0.01]",
                "centre_of_buoyancy = [0.0, 0.0, 0.1]",
            )
        ],
    ),
    "M7": (
        "wet fraction from the upright hull height alone (C and numpy)",
        [
            (
                "envs/_hydro.c",
                "mjtNum half = 0.5 * (fabs(R[6]) * p[SLOT_HULL_LENGTH] + fabs(R[7]) * p[SLOT_HULL_WIDTH]"
                " + fabs(R[8]) * p[SLOT_HULL]);",
                "mjtNum half = 0.5 * p[SLOT_HULL];",
            ),
            (
                "envs/hydrodynamics.py",
                "half = 0.5 * float(np.abs(np.asarray(rotation)[2]) @ np.asarray(hull_size, float))",
                "half = 0.5 * float(hull_size[2])",
            ),
        ],
    ),
    "M8": (
        "roll sign error in the Heavy's M5 mixing factors",
        [("controllers/mixing.py", "        [+1, -1, 0, -1, 0, 0],\n", "        [-1, -1, 0, -1, 0, 0],\n")],
    ),
    "M9": (
        "pitch sign error in the Heavy's M5 mixing factors",
        [("controllers/mixing.py", "        [+1, -1, 0, -1, 0, 0],\n", "        [+1, +1, 0, -1, 0, 0],\n")],
    ),
    "M10": (
        "roll sign error in the standard frame's M5 mixing factors",
        [("controllers/mixing.py", "        [+1, 0, 0, -1, 0, 0],\n", "        [-1, 0, 0, -1, 0, 0],\n")],
    ),
    "M11": (
        "added mass on the absolute instead of the relative acceleration in a current",
        [
            ("envs/_hydro.c", " - added[i] * current_turn;", ";"),
            ("envs/_hydro.c", "added[i] * (nudot + current_turn)", "added[i] * nudot"),
        ],
    ),
    "M12": (
        "T200 curve without its deadband",
        [
            (
                "controllers/thrusters.py",
                "s = np.clip((np.abs(p) - self.deadband_us) / span, 0.0, 1.0)",
                "s = np.clip(np.abs(p) / 400.0, 0.0, 1.0)",
            )
        ],
    ),
    "M13": (
        "T200 curve with the forward and reverse shapes swapped",
        [
            (
                "controllers/thrusters.py",
                "k = np.where(p >= 0, self.forward_shape, self.reverse_shape)",
                "k = np.where(p >= 0, self.reverse_shape, self.forward_shape)",
            )
        ],
    ),
    "M14": (
        "the simulator drives the actuators with the raw commands (no curve)",
        [
            (
                "envs/simulation.py",
                "normalised = self._specs[robot].vehicle.thruster.normalised_thrust(thrusters)",
                "normalised = thrusters",
            )
        ],
    ),
    "M15": (
        "the standard frame's surge damping left at Wu's uncalibrated value (vehicle file)",
        [
            (
                "assets/bluerov2/bluerov2.toml",
                "quadratic_damping = [54.72, 65.20, 111.34,",
                "quadratic_damping = [18.18, 65.20, 111.34,",
            )
        ],
    ),
}


def run(ids: list[str]) -> int:
    survived = []
    for key in ids:
        description, edits = MUTATIONS[key]
        originals = {}
        try:
            for name, old, new in edits:
                path = ROOT / name
                text = originals.setdefault(path, path.read_text())
                current = path.read_text()
                if old not in current:
                    raise SystemExit(f"{key}: the text to mutate is not in {name}; update the mutation list")
                path.write_text(current.replace(old, new, 1))
            result = subprocess.run(
                [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *TESTS],
                cwd=ROOT,
                capture_output=True,
                text=True,
            )
            failed = [
                line.split(" ", 1)[1] for line in result.stdout.splitlines() if line.startswith("FAILED ")
            ]
            verdict = f"killed by {failed[0].split(' - ')[0]}" if result.returncode else "SURVIVED"
            if not result.returncode:
                survived.append(key)
            print(f"{key}  {description}: {verdict}", flush=True)
        finally:
            for path, text in originals.items():
                path.write_text(text)
    print("all killed" if not survived else f"survived: {', '.join(survived)}")
    return 1 if survived else 0


if __name__ == "__main__":
    sys.exit(run(sys.argv[1:] or list(MUTATIONS)))
