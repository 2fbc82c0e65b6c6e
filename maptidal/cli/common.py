"""What every ``maptidal`` subcommand shares: its argument parser class, checked argument types,
output-path checks made before any work, and the discovery and coverage option groups."""

from __future__ import annotations

import argparse
import ctypes.util
import math
import os
from pathlib import Path

from maptidal.discovery import DiscoveryParams

EXIT_BAD_INPUT = 2


class RunError(Exception):
    """A run that could not go on (the physics diverged, a renderer is missing): one line, exit 2."""


# MUJOCO_GL's values on Linux (mujoco.rendering.classic.gl_context) and the system library each one opens
# (the glfw package brings its own)
GL_LIBRARIES: dict[str, str | None] = {"egl": "EGL", "osmesa": "OSMesa", "glx": "GL", "glfw": None}
GL_OFF = ("disable", "disabled", "off", "false", "0")


def check_gl_backend() -> None:
    """Refuse, in one line, a MUJOCO_GL that MuJoCo does not know or whose library is not installed: MuJoCo
    would fail at the first import of its renderer with an AttributeError from deep in PyOpenGL."""
    value = os.environ.get("MUJOCO_GL", "").lower().strip()
    if value in GL_OFF or value in ("", "enable", "enabled", "on", "true", "1"):
        return
    advice = "MUJOCO_GL=egl, the default, renders on a CPU through Mesa and on NVIDIA GPUs"
    if value not in GL_LIBRARIES:
        raise ValueError(
            f"MUJOCO_GL={value} is not a renderer MuJoCo knows ({', '.join(GL_LIBRARIES)}); {advice}"
        )
    library = GL_LIBRARIES[value]
    if library is not None and ctypes.util.find_library(library) is None:
        raise ValueError(
            f"MUJOCO_GL={value} needs the {library} library, which is not installed here; {advice}"
        )


class UsageError(Exception):
    """A command line that does not parse; the message is the one line to print."""


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line (``maptidal sim: error: ...``), exit status 2.

    It raises :class:`UsageError` for :func:`maptidal.cli.main` to print and return 2, rather than
    exiting from inside the parser.
    """

    def error(self, message: str) -> None:  # type: ignore[override]
        """Raise the one-line usage error naming the command and the problem."""
        raise UsageError(f"{self.prog}: error: {message} (see {self.prog} --help)")


def finite_float(text: str) -> float:
    """An argparse type: a finite number (no nan or inf; 1e308 passes here and is range-checked later)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0."""
    value = finite_float(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"{text!r} must be greater than 0")
    return value


def pilot_gain(text: str) -> float:
    """An argparse type: ArduSub's joystick gain JS_GAIN, within its bounds 0.1 to 1.0
    (:class:`maptidal.controllers.convention.PilotGain`)."""
    value = finite_float(text)
    if not 0.1 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"a pilot gain is 0.1 to 1.0 (ArduSub's bounds), got {text}")
    return value


def positive_int(text: str) -> int:
    """An argparse type: a whole number >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be at least 1")
    return value


def _nearest_existing(path: Path) -> Path:
    probe = path
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    return probe


def _check_writable_parent(path: Path, shown: str) -> None:
    base = _nearest_existing(path.parent)
    if not base.is_dir():
        raise argparse.ArgumentTypeError(f"cannot write {shown}: {base} is a file, not a folder")
    if not os.access(base, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"cannot write {shown}: no permission to write in {base}")


def output_file(suffixes: tuple[str, ...] = ()):
    """An argparse type for a file to write: not a folder, in a writable place, with one of ``suffixes``."""

    def check(text: str) -> Path:
        path = Path(text)
        if path.is_dir():
            raise argparse.ArgumentTypeError(f"{text!r} is a folder; give a file name")
        if suffixes and path.suffix.lower() not in suffixes:
            raise argparse.ArgumentTypeError(
                f"{text!r} must end in {' or '.join(suffixes)} (that is the format written)"
            )
        _check_writable_parent(path, repr(text))
        return path

    return check


def output_dir(text: str) -> Path:
    """An argparse type for a folder to write into: a folder or nothing yet, in a writable place."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a file; give a folder")
    if path.exists():
        if not os.access(path, os.W_OK | os.X_OK):
            raise argparse.ArgumentTypeError(f"cannot write into {text!r}: no permission")
    else:
        _check_writable_parent(path, repr(text))
    return path


def add_output_folder(parser: argparse.ArgumentParser, default: str) -> None:
    """The ``--out DIR`` option of a command that writes a folder of results (checked before any work)."""
    parser.add_argument(
        "--out",
        type=output_dir,
        default=Path(default),
        metavar="DIR",
        help="output folder (default %(default)s)",
    )


PNG_FILE = output_file((".png",))
JSON_FILE = output_file((".json",))


def add_discovery_params(parser: argparse.ArgumentParser) -> None:
    """The discovery parameters (defaults: the paper's best values and the OAK-D's field of view)."""
    defaults = DiscoveryParams()
    group = parser.add_argument_group("discovery parameters (defaults: the paper's best values)")
    options = (
        (
            "--standoff",
            defaults.standoff,
            "M",
            "L_i, CIP distance from the surface, in (0, 100] (default %s m)",
        ),
        ("--r-ex", defaults.r_ex, "M", "radius of exclusion, in (0, 100] (default %s m)"),
        ("--theta-ex", defaults.theta_ex, "RAD", "angle of exclusion, in (0, pi] (default %s rad)"),
        ("--threshold", defaults.threshold, "T", "keypoint score to confirm a CIP, in [0, 1] (default %s)"),
        ("--p-s", defaults.p_s, "P", "self-pruning scale of r_ex and theta_ex, in (0, 1] (default %s)"),
        ("--hfov-deg", defaults.hfov_deg, "DEG", "camera horizontal field of view (default %.1f deg, OAK-D)"),
        ("--vfov-deg", defaults.vfov_deg, "DEG", "camera vertical field of view (default %.1f deg, OAK-D)"),
    )
    for flag, default, metavar, text in options:
        group.add_argument(flag, type=finite_float, default=default, metavar=metavar, help=text % default)
    group.add_argument(
        "--range",
        dest="range_m",
        type=finite_float,
        default=None,
        metavar="M",
        help="frustum far plane, in (0, 100] m (default 2 x standoff)",
    )


def discovery_params_from(args: argparse.Namespace) -> DiscoveryParams:
    """The :class:`DiscoveryParams` the parsed options describe (raises DiscoveryInputError if bad)."""
    return DiscoveryParams(
        standoff=args.standoff,
        r_ex=args.r_ex,
        theta_ex=args.theta_ex,
        threshold=args.threshold,
        p_s=args.p_s,
        hfov_deg=args.hfov_deg,
        vfov_deg=args.vfov_deg,
        range_m=args.range_m,
    )


def add_coverage_args(parser: argparse.ArgumentParser) -> None:
    """The coverage model's options: tank, voxel size, far plane and occlusion."""
    from maptidal.evaluation.coverage import CoverageParams

    defaults = CoverageParams()
    group = parser.add_argument_group("coverage model")
    group.add_argument(
        "--tank",
        metavar="CONFIG",
        help="tank config TOML (default: the bundled OSB tank, osb_tank/tank.toml)",
    )
    group.add_argument(
        "--voxel",
        type=positive_float,
        default=defaults.voxel_m,
        metavar="M",
        help="voxel size (default %(default)s m; at most a million voxels)",
    )
    group.add_argument(
        "--far",
        type=positive_float,
        default=defaults.far_m,
        metavar="M",
        help="frustum far plane, in (0, 100] (default %(default)s m)",
    )
    group.add_argument(
        "--occlusion",
        action="store_true",
        help="count a voxel only when the ray to it is unblocked (the paper does not)",
    )


def coverage_params_from(args: argparse.Namespace, discovery: DiscoveryParams | None = None):
    """The :class:`maptidal.evaluation.coverage.CoverageParams` of the parsed options, with discovery's
    camera."""
    from maptidal.evaluation.coverage import CoverageParams

    camera = discovery or DiscoveryParams()
    return CoverageParams(
        voxel_m=args.voxel,
        far_m=args.far,
        hfov_deg=camera.hfov_deg,
        vfov_deg=camera.vfov_deg,
        occlusion=args.occlusion,
    )


def add_executor_args(parser: argparse.ArgumentParser, what: str) -> None:
    """``--jobs``, ``--executor local|ray`` and ``--ray-address`` (:mod:`maptidal.executors`)."""
    parser.add_argument(
        "--jobs",
        type=positive_int,
        default=1,
        metavar="N",
        help=f"{what} at once: local processes (at most the CPU count), or the CPUs of a local Ray "
        "instance (default %(default)s)",
    )
    parser.add_argument(
        "--executor",
        choices=("local", "ray"),
        default="local",
        help="local processes (default), or a Ray cluster (pip install -e .[ray]); the same runs give "
        "the same numbers on either",
    )
    parser.add_argument(
        "--ray-address",
        metavar="ADDR",
        help="the Ray cluster to join (ray.init(address=ADDR), e.g. 10.0.0.2:6379 or auto); without it, "
        "--executor ray starts a local Ray instance with --jobs CPUs",
    )


def check_executor_args(args: argparse.Namespace) -> None:
    """Refuse ``--ray-address`` without ``--executor ray`` before any work."""
    if args.ray_address is not None and args.executor != "ray":
        raise ValueError("--ray-address needs --executor ray")


def jobs_for(args: argparse.Namespace, runs: int, command: str) -> int:
    """``--jobs`` as it will run: on Ray as given; locally at most one process per run and per CPU
    (:func:`maptidal.executors.usable_jobs`), saying so on stderr when that is fewer than asked."""
    import sys

    from maptidal.executors import usable_jobs

    if getattr(args, "executor", "local") == "ray":
        return args.jobs
    jobs = usable_jobs(args.jobs, runs)
    if jobs < args.jobs:
        print(f"maptidal {command}: using {jobs} processes (the runs and the CPU count)", file=sys.stderr)
    return jobs


def add_capture_args(parser: argparse.ArgumentParser, refinement: bool = True) -> None:
    """``--capture paper|sweep`` (the synthetic keyframes' path), ``--mesher configs|code-defaults`` (the
    mesher's thresholds) and, with ``refinement``, ``--no-refinement`` (one triangulation per keyframe
    instead of Kimera-like landmark fusion)."""
    parser.add_argument(
        "--capture",
        choices=("paper", "sweep"),
        default="paper",
        help="keyframes: the paper's protocol, 7 keyframes rising 0.5 m 1 m in front of the end wall "
        "(paper, default), or two yaw sweeps from the centre line 1.5 m from it (sweep)",
    )
    parser.add_argument(
        "--mesher",
        choices=("configs", "code-defaults"),
        default="configs",
        help="the synthetic keyframes' mesher thresholds for bad triangles, two readings of Kimera-VIO: "
        "the flag files it ships (configs, default: side ratio 0.2, elongation 0.2, longest side 2 m) or "
        "its code's own defaults (code-defaults: 0.5, 0.5, 0.5 m)",
    )
    if refinement:
        parser.add_argument(
            "--no-refinement",
            dest="refinement",
            action="store_false",
            help="triangulate every keyframe's landmarks afresh, rather than fuse each landmark over the "
            "frames it is tracked in as Kimera's back end does (the default)",
        )
