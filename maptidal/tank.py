"""The tank model: one config, one geometry, used by every part of maptidal.

The config (TOML, default ``assets/osb_tank/tank.toml``) describes the inspected end
of a long tank in top view: a flat end wall with an inset window, two angled walls
and the first part of the long side walls, plus a ladder and fouling patches. From
it this module builds

- the *wall strip*: the evaluated walls unrolled into a 2D rectangle
  ``s in [0, length] x z in [0, water_depth]`` with a map back onto the walls, used
  by the baselines and to place fouling;
- the *evaluated surface* as a trimesh mesh (walls and window recess; not the floor,
  the water surface or the ladder, as in the paper's Section IV.B);
- the *scene*: everything a camera can see (all walls, floor, ladder, the far end wall that closes the
  tank and the dark room behind the window glass), for ray casts.

Frame: origin on the floor at the centre of the end wall, x from the water into
the end wall (the wall lies in ``x = 0``), y to the left when facing it, z up.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from maptidal.paths import asset
from maptidal.raycast import Occluders

DEFAULT_TANK_CONFIG = asset("osb_tank", "tank.toml")
# The unlit observation room behind the window: its back wall stands this far behind the glass. Our
# stand-in (assets/osb_tank/README.md): through the glass a camera sees a dark plane, and the front end
# meshes it, so it is a surface of the scene (the mesh error is measured against it), not of the
# inspected region.
ROOM_DEPTH_M = 0.3


class TankConfigError(ValueError):
    """A tank config that cannot describe a tank: the message says which value and why."""


@dataclass(frozen=True)
class WindowConfig:
    """Inset window in the end wall (m); ``width = 0`` means no window."""

    width: float = 1.0
    height: float = 0.6
    recess: float = 0.1
    centre_height: float = 1.0
    centre_offset: float = 0.0


@dataclass(frozen=True)
class LadderConfig:
    """Safety ladder standing off the end wall (m); ``rails = 0`` means no ladder."""

    rails: int = 2
    centre_offset: float = 0.75
    rail_spacing: float = 0.4
    rail_width: float = 0.04
    rung_width: float = 0.025
    rung_spacing: float = 0.3
    standoff: float = 0.15
    top: float = 2.3


@dataclass(frozen=True)
class FoulingPatch:
    """A disc of fouling on the unrolled wall strip: centre (s, z) and radius, in m."""

    s: float
    z: float
    radius: float


@dataclass(frozen=True)
class TankConfig:
    """Dimensions of the inspected end of a tank; defaults are our OSB tank model."""

    name: str = "osb_tank"
    water_depth: float = 2.0
    end_wall_width: float = 2.4
    angled_length: float = 1.0
    angled_angle_deg: float = 45.0
    side_length: float = 6.0
    side_evaluated_length: float = 0.5
    # the part of each side wall in the geometry the baselines lay their points on (None: all of the
    # evaluated part). The paper's Fig. 6A draws the two apart: "solid lines show geometry used to
    # generate inspection points for Voronoi and sweeping pattern methods, dashed lines show the edges
    # of the voxelized region used to evaluate method effectiveness".
    side_baseline_length: float | None = None
    window: WindowConfig = field(default_factory=WindowConfig)
    ladder: LadderConfig = field(default_factory=LadderConfig)
    fouling: tuple[FoulingPatch, ...] = ()

    def __post_init__(self) -> None:
        _validate(self)


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise TankConfigError(message)


def _finite(name: str, value: float, minimum: float = 0.0, strict: bool = False) -> None:
    ok = isinstance(value, int | float) and math.isfinite(value)
    ok = ok and (value > minimum if strict else value >= minimum)
    bound = ">" if strict else ">="
    _require(ok, f"{name} must be a finite number {bound} {minimum}, got {value!r}")


def _validate(config: TankConfig) -> None:
    _finite("water_depth", config.water_depth, strict=True)
    _finite("end_wall.width", config.end_wall_width, strict=True)
    _finite("angled_walls.length", config.angled_length)
    _finite("side_walls.length", config.side_length)
    _finite("side_walls.evaluated_length", config.side_evaluated_length)
    _require(
        isinstance(config.angled_angle_deg, int | float) and 0.0 < config.angled_angle_deg <= 90.0,
        f"angled_walls.angle_deg must be in (0, 90], got {config.angled_angle_deg!r}",
    )
    if config.side_baseline_length is not None:
        _finite("side_walls.baseline_length", config.side_baseline_length)
        _require(
            config.side_baseline_length <= config.side_evaluated_length,
            f"side_walls.baseline_length ({config.side_baseline_length}) exceeds "
            f"side_walls.evaluated_length ({config.side_evaluated_length})",
        )
    _require(
        config.side_evaluated_length <= config.side_length,
        f"side_walls.evaluated_length ({config.side_evaluated_length}) exceeds side_walls.length "
        f"({config.side_length})",
    )
    window = config.window
    for name in ("width", "height", "recess", "centre_height"):
        _finite(f"window.{name}", getattr(window, name))
    _finite("window.centre_offset", abs(window.centre_offset))
    if window.width > 0.0:
        _require(window.height > 0.0, "window.height must be > 0 when window.width > 0")
        half_w, half_h = window.width / 2, window.height / 2
        _require(
            abs(window.centre_offset) + half_w < config.end_wall_width / 2,
            f"the window ({window.width} m wide at offset {window.centre_offset}) does not fit in the "
            f"{config.end_wall_width} m end wall",
        )
        _require(
            half_h < window.centre_height < config.water_depth - half_h,
            f"the window ({window.height} m tall centred {window.centre_height} m up) does not fit in "
            f"the {config.water_depth} m wall height",
        )
    ladder = config.ladder
    _require(isinstance(ladder.rails, int) and ladder.rails in (0, 2), "ladder.rails must be 0 or 2")
    if ladder.rails:
        for name in ("rail_spacing", "rail_width", "rung_width", "rung_spacing", "standoff", "top"):
            _finite(f"ladder.{name}", getattr(ladder, name), strict=True)
        _finite("ladder.centre_offset", abs(ladder.centre_offset))
        half_span = ladder.rail_spacing / 2 + ladder.rail_width / 2
        _require(
            abs(ladder.centre_offset) + half_span <= config.end_wall_width / 2,
            f"the ladder ({ladder.rail_spacing} m wide at offset {ladder.centre_offset}) does not fit on "
            f"the {config.end_wall_width} m end wall",
        )
        _require(ladder.standoff > ladder.rail_width / 2, "ladder.standoff must exceed half the rail width")
    for patch in config.fouling:
        _finite("fouling.radius", patch.radius, strict=True)
        _finite("fouling.z", patch.z)
        _finite("fouling.s", patch.s)


def _section(document: dict, key: str) -> dict:
    value = document.get(key, {})
    _require(isinstance(value, dict), f"[{key}] must be a table")
    return value


def _build(cls, table: dict, where: str, renames: dict[str, str] | None = None):
    renames = renames or {}
    known = {f for f in cls.__dataclass_fields__}
    kwargs = {}
    for key, value in table.items():
        name = renames.get(key, key)
        _require(name in known, f"unknown key {key!r} in [{where}]")
        kwargs[name] = value
    return cls(**kwargs)


def tank_config_from_dict(document: dict) -> TankConfig:
    """Build a validated :class:`TankConfig` from a parsed TOML document."""
    _require(isinstance(document, dict), "a tank config must be a TOML table")
    _require(
        bool(document),
        "the tank config is empty; it needs at least water_depth and [end_wall] width "
        "(assets/osb_tank/tank.toml shows every key)",
    )
    for key, where in (("water_depth", "water_depth"), ("end_wall", "[end_wall] width")):
        _require(key in document, f"the tank config has no {where}: a tank's size cannot be guessed")
    top_level = {
        "name",
        "water_depth",
        "end_wall",
        "angled_walls",
        "side_walls",
        "window",
        "ladder",
        "fouling",
    }
    for key in document:
        _require(key in top_level, f"unknown key {key!r} in the tank config")
    end_wall = _section(document, "end_wall")
    angled = _section(document, "angled_walls")
    side = _section(document, "side_walls")
    for table, where, allowed in (
        (end_wall, "end_wall", {"width"}),
        (angled, "angled_walls", {"length", "angle_deg"}),
        (side, "side_walls", {"length", "evaluated_length", "baseline_length"}),
    ):
        for key in table:
            _require(key in allowed, f"unknown key {key!r} in [{where}]")
    fouling = document.get("fouling", [])
    _require(isinstance(fouling, list), "[[fouling]] must be an array of tables")
    defaults = TankConfig()
    try:
        return TankConfig(
            name=str(document.get("name", defaults.name)),
            water_depth=document.get("water_depth", defaults.water_depth),
            end_wall_width=end_wall.get("width", defaults.end_wall_width),
            angled_length=angled.get("length", defaults.angled_length),
            angled_angle_deg=angled.get("angle_deg", defaults.angled_angle_deg),
            side_length=side.get("length", defaults.side_length),
            side_evaluated_length=side.get("evaluated_length", defaults.side_evaluated_length),
            side_baseline_length=side.get("baseline_length"),
            window=_build(WindowConfig, _section(document, "window"), "window"),
            ladder=_build(LadderConfig, _section(document, "ladder"), "ladder"),
            fouling=tuple(_build(FoulingPatch, patch, "fouling") for patch in fouling),
        )
    except TypeError as err:  # a missing required key, such as a fouling patch without radius
        raise TankConfigError(f"bad tank config: {err}") from None


def tank_config_to_dict(config: TankConfig) -> dict:
    """The tank config as the TOML document :func:`tank_config_from_dict` reads (the two round-trip), for
    a mission's event log: its report is rebuilt on the tank it was flown in."""
    side = {"length": config.side_length, "evaluated_length": config.side_evaluated_length}
    if config.side_baseline_length is not None:
        side["baseline_length"] = config.side_baseline_length
    return {
        "name": config.name,
        "water_depth": config.water_depth,
        "end_wall": {"width": config.end_wall_width},
        "angled_walls": {"length": config.angled_length, "angle_deg": config.angled_angle_deg},
        "side_walls": side,
        "window": dataclasses.asdict(config.window),
        "ladder": dataclasses.asdict(config.ladder),
        "fouling": [dataclasses.asdict(patch) for patch in config.fouling],
    }


def load_tank_config(path: str | Path | None = None) -> TankConfig:
    """Read and validate a tank config (TOML); ``None`` loads the default OSB tank."""
    path = Path(path) if path is not None else DEFAULT_TANK_CONFIG
    if not path.is_file():
        raise TankConfigError(f"tank config not found: {path}")
    try:
        document = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise TankConfigError(f"{path}: not valid TOML ({err})") from None
    try:
        return tank_config_from_dict(document)
    except TankConfigError as err:
        raise TankConfigError(f"{path}: {err}") from None


def open_water_config(size_m: float = 30.0) -> TankConfig:
    """A plain box of water ``size_m`` wide, long and deep, with no window, ladder or angled walls: for
    vehicle dynamics and control studies away from the tank's walls (start near its middle)."""
    return TankConfig(
        name="open_water",
        water_depth=size_m,
        end_wall_width=size_m,
        angled_length=0.0,
        side_length=size_m,
        side_evaluated_length=0.5,
        window=WindowConfig(width=0.0),
        ladder=LadderConfig(rails=0),
    )


@dataclass(frozen=True)
class WallSegment:
    """One flat wall of the evaluated strip, in top view: from ``start`` to ``end``."""

    name: str
    start: np.ndarray  # (2,) x, y
    end: np.ndarray  # (2,)
    s0: float  # strip coordinate of ``start``

    @property
    def length(self) -> float:
        """Length of the wall (m)."""
        return float(np.linalg.norm(self.end - self.start))

    @property
    def tangent(self) -> np.ndarray:
        """Unit vector (3,) along the wall, in the direction of increasing s."""
        d = (self.end - self.start) / self.length
        return np.array([d[0], d[1], 0.0])

    @property
    def inward_normal(self) -> np.ndarray:
        """Unit normal (3,) pointing from the wall into the water."""
        t = self.tangent
        return np.array([t[1], -t[0], 0.0])


def _box_triangles(centre: np.ndarray, half: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """The 12 triangles (12, 3, 3) of a box with the given centre, half sizes and axes (rows)."""
    box = trimesh.creation.box(extents=2.0 * half)
    vertices = box.vertices @ axes + centre
    return vertices[box.faces]


class TankModel:
    """Geometry derived from a :class:`TankConfig`: strip, surface mesh and scene."""

    def __init__(self, config: TankConfig | None = None) -> None:
        self.config = config or TankConfig()
        self.segments = self._segments()
        self.strip_length = sum(seg.length for seg in self.segments)
        self.height = self.config.water_depth

    # ----- top view ---------------------------------------------------------------
    def _segments(self) -> list[WallSegment]:
        c = self.config
        half = c.end_wall_width / 2
        angle = math.radians(c.angled_angle_deg)
        ax, ay = c.angled_length * math.sin(angle), c.angled_length * math.cos(angle)
        side_y = half + ay
        points = [
            ("side_left", (-ax - c.side_evaluated_length, side_y), (-ax, side_y)),
            ("angled_left", (-ax, side_y), (0.0, half)),
            ("end", (0.0, half), (0.0, -half)),
            ("angled_right", (0.0, -half), (-ax, -side_y)),
            ("side_right", (-ax, -side_y), (-ax - c.side_evaluated_length, -side_y)),
        ]
        segments, s = [], 0.0
        for name, start, end in points:
            start, end = np.array(start, float), np.array(end, float)
            length = float(np.linalg.norm(end - start))
            if length > 1e-9:
                segments.append(WallSegment(name, start, end, s))
                s += length
        return segments

    @property
    def far_x(self) -> float:
        """x of the far end wall: where the side walls end (``side_walls.length`` beyond the angled walls).
        The tank is closed there."""
        c = self.config
        return -c.angled_length * math.sin(math.radians(c.angled_angle_deg)) - c.side_length

    @property
    def half_width(self) -> float:
        """Half the distance between the side walls (m)."""
        c = self.config
        return c.end_wall_width / 2 + c.angled_length * math.cos(math.radians(c.angled_angle_deg))

    def baseline_geometry(self) -> TankModel:
        """The tank the baselines lay their points on: this one, with each side wall's part cut to
        ``side_baseline_length`` where that is set (the paper's Fig. 6A: generation geometry and
        evaluated region differ)."""
        length = self.config.side_baseline_length
        if length is None or length == self.config.side_evaluated_length:
            return self
        return TankModel(
            dataclasses.replace(
                self.config, side_evaluated_length=length, side_baseline_length=None, fouling=()
            )
        )

    def segment(self, name: str) -> WallSegment:
        """The wall segment called ``name`` (side_left, angled_left, end, ...)."""
        for seg in self.segments:
            if seg.name == name:
                return seg
        raise KeyError(name)

    def corner_s(self) -> np.ndarray:
        """Strip coordinates of the section corners, both ends included."""
        return np.array([seg.s0 for seg in self.segments] + [self.strip_length])

    def strip_to_world(self, s: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map strip coordinates to wall points ``(N, 3)`` and inward normals ``(N, 3)``.

        At a corner between two walls the normal is the bisector of theirs, so a
        viewpoint placed there looks into the corner.
        """
        s = np.clip(np.atleast_1d(np.asarray(s, float)), 0.0, self.strip_length)
        z = np.atleast_1d(np.asarray(z, float))
        points = np.zeros((len(s), 3))
        normals = np.zeros((len(s), 3))
        starts = np.array([seg.s0 for seg in self.segments])
        index = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(self.segments) - 1)
        for k, seg in enumerate(self.segments):
            mask = index == k
            local = (s[mask] - seg.s0)[:, None]
            points[mask, :2] = seg.start + local * seg.tangent[:2]
            normals[mask] = seg.inward_normal
        points[:, 2] = z
        for k in range(1, len(self.segments)):
            corner = np.isclose(s, self.segments[k].s0, atol=1e-9)
            bisector = self.segments[k - 1].inward_normal + self.segments[k].inward_normal
            normals[corner] = bisector / np.linalg.norm(bisector)
        return points, normals

    # ----- surfaces -----------------------------------------------------------------
    def window_rim(self, depth: float = 0.0) -> np.ndarray:
        """Corners ``(4, 3)`` of the window opening, ``depth`` m behind the wall plane:
        bottom-left, bottom-right, top-right, top-left (left/right facing the end wall)."""
        window = self.config.window
        seg = self.segment("end")
        t, n, up = seg.tangent, seg.inward_normal, np.array([0.0, 0.0, 1.0])
        centre = np.array([*seg.start, 0.0]) + (seg.length / 2 + window.centre_offset) * t
        centre = centre + window.centre_height * up - depth * n
        return np.array(
            [
                centre + sx * window.width / 2 * t + sz * window.height / 2 * up
                for sx, sz in ((-1, -1), (1, -1), (1, 1), (-1, 1))
            ]
        )

    def has_window(self) -> bool:
        """Whether the config has a window and the strip an end wall to hold it."""
        return self.config.window.width > 0.0 and any(seg.name == "end" for seg in self.segments)

    def _wall_quads(self, seg: WallSegment) -> list[tuple[np.ndarray, np.ndarray]]:
        """Quads (4 corners, wanted normal) covering one wall, with the window hole cut out."""
        p0 = np.array([*seg.start, 0.0])
        t, n = seg.tangent, seg.inward_normal
        up = np.array([0.0, 0.0, 1.0])

        def quad(u0: float, u1: float, z0: float, z1: float):
            corners = [p0 + u * t + z * up for u, z in ((u0, z0), (u1, z0), (u1, z1), (u0, z1))]
            return np.array(corners), n

        if seg.name != "end" or not self.has_window():
            return [quad(0.0, seg.length, 0.0, self.height)]
        window = self.config.window
        u_c = seg.length / 2 + window.centre_offset
        u0, u1 = u_c - window.width / 2, u_c + window.width / 2
        z0, z1 = window.centre_height - window.height / 2, window.centre_height + window.height / 2
        quads = [
            quad(0.0, u0, 0.0, self.height),
            quad(u1, seg.length, 0.0, self.height),
            quad(u0, u1, 0.0, z0),
            quad(u0, u1, z1, self.height),
            (self.window_rim(window.recess), n),  # the pane, at the back of the recess
        ]
        if window.recess > 0.0:
            bl, br, tr, tl = self.window_rim()
            r = window.recess

            def reveal(a: np.ndarray, b: np.ndarray, normal: np.ndarray):
                # A side of the recess: from edge a-b on the wall plane back to the pane.
                return np.array([a, b, b - r * n, a - r * n]), normal

            quads += [
                reveal(bl, br, up),  # sill faces up
                reveal(tl, tr, -up),  # head faces down
                reveal(bl, tl, t),  # left jamb faces +t
                reveal(br, tr, -t),  # right jamb faces -t
            ]
        return quads

    def _evaluated_quads(self) -> list[tuple[np.ndarray, np.ndarray]]:
        return [quad for seg in self.segments for quad in self._wall_quads(seg)]

    @staticmethod
    def _quads_to_mesh(quads: list[tuple[np.ndarray, np.ndarray]]) -> trimesh.Trimesh:
        triangles = []
        for corners, normal in quads:
            for tri in (corners[[0, 1, 2]], corners[[0, 2, 3]]):
                if np.dot(np.cross(tri[1] - tri[0], tri[2] - tri[0]), normal) < 0.0:
                    tri = tri[[0, 2, 1]]
                triangles.append(tri)
        return trimesh.Trimesh(**trimesh.triangles.to_kwargs(np.array(triangles)))

    def evaluated_surface(self) -> trimesh.Trimesh:
        """The evaluated walls and window recess, normals towards the water (paper Sec. IV.B)."""
        return self._quads_to_mesh(self._evaluated_quads())

    def ladder_boxes(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """The ladder as boxes ``(centre, half sizes, axes rows)``: rails, then rungs."""
        ladder = self.config.ladder
        if not ladder.rails or "end" not in {seg.name for seg in self.segments}:
            return []
        seg = self.segment("end")
        t, n, up = seg.tangent, seg.inward_normal, np.array([0.0, 0.0, 1.0])
        # a right-handed frame (along the wall, out of the wall, up): a rotation, as MuJoCo needs
        axes = np.array([t, np.cross(up, t), up])
        origin = (
            np.array([*seg.start, 0.0]) + (seg.length / 2 + ladder.centre_offset) * t + ladder.standoff * n
        )
        boxes = []
        for side in (-0.5, 0.5):
            centre = origin + side * ladder.rail_spacing * t + ladder.top / 2 * up
            boxes.append((centre, np.array([ladder.rail_width, ladder.rail_width, ladder.top]) / 2, axes))
        rung_half = np.array([ladder.rail_spacing / 2, ladder.rung_width / 2, ladder.rung_width / 2])
        z = ladder.rung_spacing
        while z < ladder.top - ladder.rung_width:
            boxes.append((origin + z * up, rung_half, axes))
            z += ladder.rung_spacing
        return boxes

    def scene_quads(
        self, include_floor: bool = True, include_enclosure: bool = True
    ) -> list[tuple[np.ndarray, np.ndarray, str]]:
        """Every flat surface a camera in the water can see: ``(corners (4, 3), normal, kind)``.

        ``kind`` is "wall", "pane" (the window glass), "reveal" (the window recess
        sides), "room" (the dark back wall of the room behind the glass, :data:`ROOM_DEPTH_M`
        behind it) or "floor". The whole side walls are included, not only their
        evaluated part, with the far end wall that closes the tank where they end
        (:attr:`far_x`), and the floor of the whole tank; the water surface and the
        ladder (see :meth:`ladder_boxes`) are not. ``include_enclosure=False`` leaves out
        the far end wall and the room, the surfaces beyond the inspected end.
        """
        c = self.config
        quads: list[tuple[np.ndarray, np.ndarray, str]] = []
        for seg in self.segments:
            for k, (corners, normal) in enumerate(self._wall_quads(seg)):
                kind = "wall"
                if seg.name == "end" and self.has_window() and k == 4:
                    kind = "pane"
                elif seg.name == "end" and self.has_window() and k > 4:
                    kind = "reveal"
                quads.append((corners, normal, kind))
                if kind == "pane" and include_enclosure:
                    quads.append((corners - ROOM_DEPTH_M * np.asarray(normal), normal, "room"))
        far_x, side_y = self.far_x, self.half_width
        near_x = min(float(min(seg.start[0], seg.end[0])) for seg in self.segments)
        if c.side_length > c.side_evaluated_length:
            for sign in (1.0, -1.0):
                a = np.array([near_x, sign * side_y, 0.0])
                b = np.array([far_x, sign * side_y, 0.0])
                corners = np.array([a, b, b + [0, 0, self.height], a + [0, 0, self.height]])
                quads.append((corners, np.array([0.0, -sign, 0.0]), "wall"))
        if include_enclosure:
            corners = np.array(
                [
                    [far_x, side_y, 0.0],
                    [far_x, -side_y, 0.0],
                    [far_x, -side_y, self.height],
                    [far_x, side_y, self.height],
                ]
            )
            quads.append((corners, np.array([1.0, 0.0, 0.0]), "wall"))
        if include_floor:
            corners = np.array(
                [[far_x, -side_y, 0.0], [0.0, -side_y, 0.0], [0.0, side_y, 0.0], [far_x, side_y, 0.0]]
            )
            quads.append((corners, np.array([0.0, 0.0, 1.0]), "floor"))
        return quads

    @functools.cached_property
    def scene_occluders(self) -> Occluders:
        """:meth:`scene_triangles` (floor and ladder included) prepared for ray casting, once per tank."""
        return Occluders.of(self.scene_triangles())

    def scene_triangles(
        self, include_floor: bool = True, include_ladder: bool = True, include_enclosure: bool = True
    ) -> np.ndarray:
        """Every surface a camera in the water can see, as triangles ``(T, 3, 3)``.

        The surfaces of :meth:`scene_quads` plus, optionally, the ladder.
        """
        quads = [(c, n) for c, n, _ in self.scene_quads(include_floor, include_enclosure)]
        triangles = [self._quads_to_mesh(quads).triangles]
        if include_ladder:
            triangles += [_box_triangles(*box) for box in self.ladder_boxes()]
        return np.concatenate(triangles, axis=0)


def tank_toml(document: dict, header: str = "") -> str:
    """A tank document (as :func:`tank_config_from_dict` takes it) as TOML text: top-level values, then
    one table per section and ``[[fouling]]`` entries; ``header`` lines become comments at the top.
    Reading the text back with tomllib gives the same document."""

    def value(item) -> str:
        if isinstance(item, bool):
            return "true" if item else "false"
        if isinstance(item, int | float):
            return repr(float(item)) if isinstance(item, float) else str(item)
        if isinstance(item, str):
            return '"' + item.replace("\\", "\\\\").replace('"', '\\"') + '"'
        raise TypeError(f"a tank document holds numbers, booleans and strings, not {item!r}")

    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    if lines:
        lines.append("")
    tables = {k: v for k, v in document.items() if isinstance(v, dict)}
    arrays = {k: v for k, v in document.items() if isinstance(v, list)}
    for key, item in document.items():
        if key not in tables and key not in arrays:
            lines.append(f"{key} = {value(item)}")
    for key, table in tables.items():
        lines += ["", f"[{key}]", *(f"{k} = {value(v)}" for k, v in table.items())]
    for key, entries in arrays.items():
        for entry in entries:
            lines += ["", f"[[{key}]]", *(f"{k} = {value(v)}" for k, v in entry.items())]
    return "\n".join(lines) + "\n"
