"""A mission file: a scenario TOML (``maptidal.envs.scenario``) with an optional ``[mission]`` table:

    [mission]
    duration_s = 180
    pose_source = "vo"     # what each robot meshes and flies on: vo, dr or truth (an oracle)
    frame_rate_hz = 1.0    # stereo frames per robot per second
    frame_rate_no_dvl_hz = 1.0  # ... of a robot without a DVL
    motion_model_error = 0.0    # how far off the estimators' motion models are (0: exact, 0.3: 30 %)
    relocalise = true      # a robot without a DVL relocalises against its own map (false: it does not)
    command_rate_hz = 10.0 # go-to-pose's pilot commands per second
    clearance_m = 1.0      # how far a robot keeps from its teammates and their ways (0: not at all)
    clear_after_s = 0.5    # a spell of giving way ends once the way has been clear this long (events)
    lost_after_s = 3.0     # a robot without a DVL is lost after this long without a visual fix ...
    lost_sigma_m = 0.15    # ... or when more unsure of its position than this
    watch_pushes = false   # true: the accelerometer against the motion model grows the uncertainty of a
                           # robot pushed or blocked (false, the default: it grows with time alone)
    lost_give_up = 0       # a robot lost this many times on its way to one view gives it up (0: never)
    lost_hand_over = false # true: a robot lost on its way to a view hands it to a teammate with a DVL
                           # that has nothing left to do
    lost_stand_down = true # a robot still lost after flying home and sweeping there releases its tasks
                           # and holds where it is until it has a fix (false: it keeps them)
    render_samples = 4     # the images' anti-aliasing samples (0: off, about twice as fast on a CPU)
    perception_process = true  # perception and discovery in a worker process (false: inline, slower)
    water_backend = "prefer-gl"  # where the water model runs: prefer-gl, gl, cpu or auto (Simulation's)
    planner = "maptidal"   # where tasks come from: maptidal (discovered), voronoi or boustrophedon
    discovery = "map-aware"  # maptidal's discovery in the loop: map-aware (the robot's own map) or paper
    explore = true         # map-aware robots with no task fly to their map's frontier (false: they do not)
    survey_without_dvl = true  # ... robots without a DVL too (false: only those with one survey)
    survey_pitch_deg = 54.1    # a robot that can pitch pitches a look down or up as far as it pitches for
                           # a view, at most this (the camera's vertical field of view; 0: level only)
    survey_sweep_deg = 60.0    # how far a robot with a DVL sweeps either side of a look's heading ...
    survey_sweep_no_dvl_deg = 0.0  # ... and a robot without one (0: the look's own view alone)
    sweep_rate_dvl_deg_s = 39.0    # how fast a robot with a DVL turns through a survey's sweep
    retire_taken = false   # map-aware robots retire tasks the team's views taken cover (true; off by default)
    retire_repeats = false # ... and tasks whose views repeat a teammate's of lower key (true; off by default)
    explore_radius_m = 3.0 # ... within this of where each was launched (maptidal.exploration)
    inspect_region = "walls"  # what a map-aware team inspects: "walls" (the box of the evaluated walls)
                           # or "launch" (the exploration radius alone); inspect_box = [[x, y, z], [x, y, z]]
                           # states the box instead
    dense_depth = true     # map-aware robots map each keyframe's dense stereo depth (false: keypoints only)
    dense_candidates_m = 0.0  # map-aware candidates from the dense depth too, one per cell this size (0: off)
    [[mission.events]]
    time_s = 60
    kind = "fail"          # rov1 stops and falls silent
    robot = "rov1"
    [[mission.events]]
    time_s = 30
    kind = "join"          # rov2, one of the scenario's robots, parked until then, enters the mission
    robot = "rov2"
    [[mission.events]]
    time_s = 90
    kind = "outage"        # the acoustic links are down for duration_s: all, or those of two robots
    duration_s = 20
    robots = ["rov0", "rov1"]
    [[mission.events]]
    time_s = 120
    kind = "current"       # the water's current from then on, m/s in the world frame
    current = [0.1, 0.0, 0.0]

Anything wrong gives one line naming the file and the value (ValueError).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from maptidal.envs.scenario import (
    SCENARIO_DIR,
    Scenario,
    ScenarioError,
    read_scenario_file,
    scenario_from_dict,
)
from maptidal.exploration import FrontierParams
from maptidal.map_discovery import MapAwareParams
from maptidal.mission.params import MissionEvent, MissionParams, check_events

DEFAULT_MISSION = SCENARIO_DIR / "mission.toml"
MISSION_KEYS = {
    "duration_s",
    "events",
    "pose_source",
    "frame_rate_hz",
    "frame_rate_no_dvl_hz",
    "motion_model_error",
    "relocalise",
    "command_rate_hz",
    "clearance_m",
    "clear_after_s",
    "lost_after_s",
    "lost_sigma_m",
    "watch_pushes",
    "lost_give_up",
    "lost_stand_down",
    "lost_hand_over",
    "render_samples",
    "perception_process",
    "water_backend",
    "planner",
    "discovery",
    "explore",
    "survey_without_dvl",
    "survey_pitch_deg",
    "survey_sweep_deg",
    "survey_sweep_no_dvl_deg",
    "sweep_rate_dvl_deg_s",
    "explore_radius_m",
    "dense_depth",
    "dense_candidates_m",
    "retire_taken",
    "retire_repeats",
    "inspect_region",
    "inspect_box",
}
# the [mission] keys that are not plain numbers, and what they must be
SETTING_TYPES: dict[str, type] = {
    "pose_source": str,
    "water_backend": str,
    "planner": str,
    "discovery": str,
    "render_samples": int,
    "perception_process": bool,
    "relocalise": bool,
    "explore": bool,
    "survey_without_dvl": bool,
    "retire_taken": bool,
    "retire_repeats": bool,
    "lost_stand_down": bool,
    "lost_hand_over": bool,
    "watch_pushes": bool,
    "inspect_region": str,
    "inspect_box": list,
    "dense_depth": bool,
}
EVENT_KEYS = {"time_s", "kind", "robot", "current", "duration_s", "robots"}


def load_mission(path: str | Path | None = None) -> tuple[Scenario, dict]:
    """The scenario and the ``[mission]`` settings (``duration_s``, ``events`` as MissionEvents, ...)."""
    path, document = read_scenario_file(path, DEFAULT_MISSION)
    table = document.pop("mission", {})
    try:
        scenario = scenario_from_dict(document, path.parent)
    except ScenarioError as err:
        raise ValueError(f"{path}: {err}") from None
    if not isinstance(table, dict) or set(table) - MISSION_KEYS:
        raise ValueError(f"{path}: [mission] takes only {', '.join(sorted(MISSION_KEYS))}")
    settings = {key: value for key, value in table.items() if key != "events"}
    kinds = {str: "a string", int: "a whole number", bool: "true or false", list: "[[x, y, z], [x, y, z]]"}
    for key, value in settings.items():
        wanted = SETTING_TYPES.get(key)
        # TOML's true and false are Python bools, which are ints too: only a bool setting takes them
        if (wanted is bool) != isinstance(value, bool) or not isinstance(value, wanted or (int, float)):
            raise ValueError(
                f"{path}: [mission] {key} must be {kinds.get(wanted, 'a number')}, got {value!r}"
            )
    events = []
    for number, entry in enumerate(table.get("events", [])):
        if (
            not isinstance(entry, dict)
            or set(entry) - EVENT_KEYS
            or "kind" not in entry
            or "time_s" not in entry
        ):
            raise ValueError(
                f"{path}: mission event {number} needs time_s and kind, and takes only "
                f"{', '.join(sorted(EVENT_KEYS))}"
            )
        try:
            events.append(
                MissionEvent(
                    float(entry["time_s"]),
                    str(entry["kind"]),
                    str(entry.get("robot", "")),
                    tuple(float(v) for v in entry.get("current", (0.0, 0.0, 0.0))),
                    float(entry.get("duration_s", 0.0)),
                    tuple(str(name) for name in entry.get("robots", ())),
                )
            )
        except (TypeError, ValueError) as err:
            raise ValueError(f"{path}: mission event {number}: {err}") from None
    settings["events"] = tuple(events)
    if "discovery" in settings:  # MissionParams.discovery holds the paper's parameters; this is the mode
        settings["discovery_mode"] = settings.pop("discovery")
    map_settings = {
        key: settings.pop(key) for key in ("dense_depth", "dense_candidates_m") if key in settings
    }
    if map_settings:  # settings of the robots' maps (MapAwareParams)
        try:
            settings["map_aware"] = MapAwareParams(**map_settings)
        except ValueError as err:
            raise ValueError(f"{path}: [mission] {err}") from None
    if "explore_radius_m" in settings:
        try:
            settings["frontier"] = FrontierParams(explore_radius_m=float(settings.pop("explore_radius_m")))
        except ValueError as err:
            raise ValueError(f"{path}: [mission] {err}") from None
    return scenario, settings


def prepare_mission(
    path: str | Path | None = None,
    robots: int | None = None,
    duration_s: float | None = None,
    pose_source: str | None = None,
    seed: int = 0,
    planner: str | None = None,
    discovery: str | None = None,
    explore: bool | None = None,
) -> tuple[Scenario, MissionParams]:
    """The scenario and the MissionParams of a mission file, with the command line's overrides: the first
    ``robots`` robots, the duration, the front end's pose source, the planner, the discovery mode and
    whether robots explore (``maptidal run`` and ``batch``)."""
    scenario, settings = load_mission(path)
    if robots is not None:
        if not 1 <= robots <= len(scenario.robots):
            raise ValueError(f"--robots {robots}: the scenario has {len(scenario.robots)} robots")
        scenario = dataclasses.replace(scenario, robots=scenario.robots[:robots])
    if duration_s is not None:
        settings["duration_s"] = duration_s
    if pose_source is not None:
        settings["pose_source"] = pose_source
    if planner is not None:
        settings["planner"] = planner
    if discovery is not None:
        settings["discovery_mode"] = discovery
    if explore is not None:
        settings["explore"] = explore
    params = MissionParams(seed=seed, **settings)
    check_events(params.events, [r.name for r in scenario.robots])
    return scenario, params
