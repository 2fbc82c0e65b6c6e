"""The closed-loop mission's settings (:class:`MissionParams`, every ``[mission]`` key of a scenario file),
its scripted events (:class:`MissionEvent`) and the checks that refuse a bad one with a line naming the
problem: what :mod:`maptidal.mission.run` flies, and what :mod:`maptidal.mission.config` reads."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from maptidal.allocation.agent import AgentParams
from maptidal.camera import OAKD_VFOV_DEG
from maptidal.comms.channel import ChannelParams
from maptidal.discovery import DiscoveryParams
from maptidal.envs.rendering import check_render_samples
from maptidal.envs.scenario import check_current
from maptidal.envs.simulation import check_water_backend
from maptidal.exploration import FrontierParams
from maptidal.map_discovery import MapAwareParams, check_box
from maptidal.perception.frontend import POSE_SOURCES
from maptidal.perception.keyframing import KeyframeParams

EVENT_KINDS = ("fail", "join", "outage", "current")


@dataclass(frozen=True)
class MissionEvent:
    """A scripted event at ``time_s``:

    - ``fail``: ``robot`` stops and falls silent;
    - ``join``: ``robot`` (one of the scenario's robots, parked at its start pose until then) enters the
      mission: its estimator starts at its launch pose, it explores, and its CBBA agent joins the auction;
    - ``outage``: the acoustic links are down for ``duration_s``, all of them, or only the link between
      the two ``robots`` named;
    - ``current``: the water's current becomes ``current`` m/s (world frame)."""

    time_s: float
    kind: str
    robot: str = ""
    current: tuple[float, float, float] = (0.0, 0.0, 0.0)
    duration_s: float = 0.0
    robots: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in EVENT_KINDS:
            raise ValueError(f"unknown mission event {self.kind!r}; known: {', '.join(EVENT_KINDS)}")
        if not (math.isfinite(self.time_s) and self.time_s >= 0):
            raise ValueError(f"a mission event's time must be finite and >= 0, got {self.time_s!r}")
        if self.kind in ("fail", "join") and not self.robot:
            raise ValueError(f"a {self.kind} event names its robot")
        if self.kind == "outage":
            if not (math.isfinite(self.duration_s) and self.duration_s > 0):
                raise ValueError(f"an outage lasts a positive duration_s, got {self.duration_s!r}")
            if len(self.robots) not in (0, 2) or len(set(self.robots)) != len(self.robots):
                raise ValueError(f"an outage takes down all links, or the link of two robots: {self.robots}")


MAX_DURATION_S = 86400.0  # a day of simulated time: longer than any battery a BlueROV2 carries
# where a mission's tasks come from (MissionParams.planner), and the baselines' viewpoints
PLANNERS = ("maptidal", "voronoi", "boustrophedon")
# how the "maptidal" planner discovers tasks in the loop: "paper", the paper's Algorithms 1-3 on each
# keyframe's mesh, its tasks then checked against the tank model's free water; "map-aware", on the robot's
# own fused map with its own free space (maptidal.map_discovery), reading no tank model
DISCOVERY_MODES = ("paper", "map-aware")


@dataclass(frozen=True)
class MissionParams:
    """How the mission runs (module docstring). Images are rendered at ``image_size`` (width, height) with
    the OAK-D's field of view, smaller than the front end's default to keep the mission fast."""

    # a cap: the mission ends when its work is done (``_finished``). The work of the default mission, by
    # estimate: the first sweep (27 s); some ten looks at the frontier between two robots, each a flight
    # of up to 6 m at 0.25 m/s and a sweep (45 s each, 225 s a robot); some ten tasks of about 20 s
    # (100 s a robot): some 350 s. Twice that, rounded, so that a mission that does its work ends on its
    # own, and one that does not is stopped before it runs on for long
    duration_s: float = 600.0
    frame_rate_hz: float = 1.0
    # go-to-pose runs on the companion computer and streams its pilot commands at 10 Hz, ArduSub's usual
    # rate (its pilot failsafe, FS_PILOT_TIMEOUT, waits 3 s; docs/references.md); the flight mode inside
    # the autopilot runs every control period
    command_rate_hz: float = 10.0
    # the frame rate of a robot without a DVL, whose visual odometry corrects its model-aided dead
    # reckoning: in session 9, before the motion model, 2 Hz kept more tracks alive but did not make it
    # localise well enough and cost a third of the real-time factor
    frame_rate_no_dvl_hz: float = 1.0
    lost_after_s: float = 3.0  # a robot without a DVL and without a visual fix this long is lost
    # ... and so is one whose front end holds its horizontal position to be more uncertain (standard
    # deviation) than a task's position tolerance (position_tolerance_m, 15 cm): it could not tell it
    # is at a viewpoint, and a little farther on relocalisation no longer finds its anchors (some 30 cm,
    # 120 px at 1 m: maptidal.perception.relocalisation), so it goes back to where its map is surest
    lost_sigma_m: float = 0.15
    # the robots' accelerometers watch their motion models (maptidal.perception.unmodelled): a push, or a
    # wall that stops a robot while its model flies on, grows the front end's uncertainty by as far as
    # the robot may have moved unseen, so that it counts as lost and is found again. Off by default: on
    # the default tank (seeds 0-9) it changed neither the finish nor the walls uninspected beyond the
    # seeds' noise, and the robots touched more (21 robot-seconds against 9; it over-counts in long
    # contact: docs/mission.md, "Without a DVL")
    watch_pushes: bool = False
    # a robot lost this many times on its way to one view gives the view up (a "gave_up" event), so
    # that a teammate that can hold its position there wins it: once may be a turn to open water on the
    # way; twice, the way to that view holds nothing the robot's map can fix on, and each time it flies
    # home and back, until the task timeout. 0, the default: never. At 2 it cut the default tank's
    # timeouts from 163 s a mission to 18 s, but on variant A the robots met more, three missions of ten
    # with minutes of contact (docs/mission.md, "Without a DVL")
    lost_give_up: int = 0
    # a robot lost on its way to a view hands the view over to a teammate with a DVL (a team knows its
    # robots' sensors) that last said, within peer_fresh_s, that it had nothing left to do, once the time
    # it has been lost on the way to that view reaches what the hand-over costs: a TDMA cycle for the
    # news to reach the teammate and the teammate's flight to the view (the break-even rule of renting
    # against buying, which never pays more than twice the better choice made in hindsight). It gives
    # the view up (a "handed_over" event) and the teammate, which never loses its position, wins it. In
    # the default tank's missions the robot with the DVL first ran out of work 13 to 183 s before the
    # end, while its teammate, lost again and again on its way to its last views, flew home and back to
    # each until it found a fix there or timed out. Off by default: within the seeds' noise on every
    # tank, and the teammate, sent where the lost robot was bound, met it more (docs/mission.md,
    # "Without a DVL")
    lost_hand_over: bool = False
    # a robot still lost when its recovery (home, and the sweep there) is over stands down: it has tried
    # the view its map knows best and found no fix there, so its estimate is off by more than
    # relocalisation reaches, and it cannot tell when it reaches any view or look. It releases its
    # tasks to its teammates, bids on none, and holds where it is, sweeping its camera there, rather
    # than fly on an estimate that far off through the water its teammates work in; with a fix again it
    # bids again (a "stood_down" event, then "resumed"). False: it keeps its tasks and tries each until
    # the task timeout, flying home and back. In session 32's missions a robot lost for good held its
    # tasks, and timed out on one after another, for up to 200 s (docs/mission.md, "Without a DVL")
    lost_stand_down: bool = True
    # keeping clear of teammates, on where their last message said they were: two Heavy hulls (0.457 x
    # 0.575 m, Blue Robotics' technical details) touch below 0.73 m centre to centre at worst; 1 m leaves
    # the rest for the estimates' error. A robot gives way to every teammate heard from in the last
    # peer_fresh_s, except a teammate of a higher index whose last message said it was giving way itself:
    # both sides watch (a robot flying onto one that holds at a viewpoint pushes it off, and its DVL reads
    # the other's hull), and two robots never wait on each other for longer than a message takes
    clearance_m: float = 1.0
    peer_fresh_s: float = 30.0
    # a spell of giving way ends once the robot's way has stayed clear this long: one backing out of a
    # teammate that comes on towards it is clear, then inside the ball again, every few control periods
    # (in session 43's missions a third of the spells began within 0.3 s of the last one's end); the
    # event log and the time use count such a spell once. Its flight is the same either way
    clear_after_s: float = 0.5
    image_size: tuple[int, int] = (320, 200)
    # the images' multisample anti-aliasing (Simulation's render_samples): 4, MuJoCo's default, stands
    # for the lens's blur; 0 halves the render time on Mesa's CPU rasteriser (docs/mission.md)
    render_samples: int = 4
    # where the water model runs (Simulation's water_backend): the shader where it can run, also on a CPU
    # rasteriser, where beside the physics it made the mission about 15 % faster than the CPU model
    water_backend: str = "prefer-gl"
    # the robots' perception and discovery in a worker process on a second core (False: in the mission's
    # own process, on its drawing thread: 1.1 to 1.3 times slower on 2 cores, with the same results)
    perception_process: bool = True
    pose_source: str = "vo"
    # how far off the robots' estimators' motion models are
    # (maptidal.controllers.estimation.MotionModel.perturbed;
    # a robot without a DVL dead-reckons on one): 0, the simulator's own coefficients
    motion_model_error: float = 0.0
    # a robot without a DVL relocalises against its own map (maptidal.perception.relocalisation); False
    # leaves it on visual odometry and its motion model alone, for comparison
    relocalise: bool = True
    explore_yaw_deg: float = 60.0
    yaw_rate_deg_s: float = 12.0
    speed_m_s: float = 0.25
    dwell_s: float = 1.0
    task_timeout_s: float = 60.0
    # a robot whose route to a task has ended, that is not at the viewpoint and that has not moved
    # stall_move_m on its own estimate for stall_s, is pressed against something it cannot see (a thin
    # rail, a teammate) and gives the task up: go-to-pose closes the last 15 cm in a few seconds when
    # nothing is in the way, and a robot pushing on for the whole task timeout collided for up to a
    # minute a task (docs/mission.md, "Exploring the map's frontier"). 0 turns it off
    stall_s: float = 10.0
    stall_move_m: float = 0.05
    # a task is held, and judged, within these of its viewpoint and viewing direction (in full, pitch
    # included: maptidal.mission.verification)
    position_tolerance_m: float = 0.15
    direction_tolerance_deg: float = 10.0
    # the most a robot that can pitch (the Heavy) pitches in STABILIZE for a view: our choice; there the
    # Heavy's restoring moment, 134 N x 4.9 cm x sin 45 = 4.6 N m (assets/bluerov2/README.md), takes a
    # fifth of its some 21 N m of pitch authority. A robot that cannot pitch holds level
    max_pitch_deg: float = 45.0
    snapshot_every_s: float = 10.0
    channel: ChannelParams = field(default_factory=ChannelParams)
    agent: AgentParams = field(default_factory=lambda: AgentParams(failure_timeout_s=40.0, heartbeat_s=10.0))
    discovery: DiscoveryParams = field(default_factory=DiscoveryParams)
    # a keyframe at every 1 Hz frame, the 1 to 2 Hz. Until session 12 it was one per 25 cm or
    # 20 deg, at most one a second and one every 4 s while the view stood still (0.26 to 0.34 Hz), on the
    # reasoning that a hovering robot's keyframes add tasks only from the mesh noise; over seeds 0 to 4
    # the two did about as well (35.4 to 36.4 against 36.8 tasks done a mission, mean; 14.3 to 17.0 against
    # 15.3 % of the walls uninspected, seeds ranging 4 to 29 %), none inspected twice (docs/mission.md)
    keyframes: KeyframeParams = field(
        default_factory=lambda: KeyframeParams(min_interval_s=1.0, max_interval_s=1.0)
    )
    events: tuple[MissionEvent, ...] = ()
    seed: int = 0
    # --video: an MP4 from a camera behind the team, each robot's latest view inset; two frames per
    # simulated second, played at 20 fps (ten times real time)
    video: bool = False
    # the PNG plots at the end (top view, timeline, coverage against time, histogram, views per voxel,
    # localisation): some 3 s of matplotlib a mission; --no-plots leaves them out (a batch of many seeds
    # draws its own figures), and `maptidal report` draws them later from the folder
    plots: bool = True
    video_size: tuple[int, int] = (640, 400)
    video_frames_per_sim_s: float = 2.0
    video_playback_fps: float = 20.0
    # where the tasks come from (PLANNERS): "maptidal", discovered from the robots' own meshes as they
    # fly; "voronoi" or "boustrophedon", the paper's baselines, whose viewpoints are given a priori from
    # the tank model, as the baselines require, and known to every robot from the start (a mission plan)
    planner: str = "maptidal"
    # DISCOVERY_MODES. The default is "map-aware", decided before it was measured, on this reasoning: a
    # robot in the water has no tank model, and "paper" keeps its tasks only where the tank model says the
    # water is free, so the loop would rest on knowledge the method claims not to need; the map-aware mode
    # uses only what the robot sensed. `maptidal discover` stays paper-exact either way
    discovery_mode: str = "map-aware"
    map_aware: MapAwareParams = field(default_factory=MapAwareParams)
    # a map-aware robot with no task left flies to its own map's frontier and looks there, within
    # frontier.explore_radius_m of where it was launched (maptidal.exploration); it has explored when
    # no look is worth a trip. Only with the maptidal planner and map-aware discovery: the paper's
    # discovery finds tasks enough to keep its robots flying, and a baseline's plan is fixed
    explore: bool = True
    # whether a robot without a DVL surveys its map's frontier too. A survey turns the camera to open
    # water, where such a robot loses its fix (lost 115 s a mission on the default tank, against 29 s in
    # the boustrophedon's missions). False leaves the frontier to the robots with a DVL: on seeds 0-9 the
    # missions ended 31 to 53 s sooner on the default tank and variants A and B, with 0.5 to 1.9 points
    # more of the walls uninspected (docs/mission.md, "Exploring the map's frontier"); the surveys
    # are what find the tasks, so it stays on
    survey_without_dvl: bool = True
    # a robot with a DVL that can pitch may pitch a look down or up by as much as it pitches for a view
    # (its max_pitch_deg, 45 deg for the Heavy), up to this: the OAK-D's vertical field of view, so that
    # a pitched view still overlaps the level one and the three leave no gap in elevation. A level camera
    # standing a metre up saw the foot of a shallow tank's walls only at a grazing angle, and the robots
    # declared themselves explored with a fifth of the walls unseen (maptidal.exploration, "Pitched
    # looks"). A robot without a DVL looks level: it holds its position by visual fixes on the walls it
    # mapped looking level, and pitched at the bare floor or the surface it lost them (a tank 1.6 m deep,
    # seeds 0-9: in the eight missions where it flew a pitched look it was lost for up to 179 s and ended
    # 0.4 to 1 m off in five; in the two where it did not, lost 5 s and a few cm off). 0: level looks only
    survey_pitch_deg: float = OAKD_VFOV_DEG
    # how far a survey sweeps its camera either side of its look's heading: a robot with a DVL as far as
    # its first sweep (explore_yaw_deg), so that a look's side views map what the look's own view only
    # grazed; a robot without one not at all (0: it takes the look's own view, and plans its next look on
    # the map that view updated). Its visual odometry fails on most frames while it turns (docs/mission.md,
    # "Without a DVL"), and a sweep at each look was 20 s of such turning. With sweep_rate_dvl_deg_s,
    # against both robots sweeping 60 deg at 12 deg/s (seeds 0-9, paired): finish -30, -2, -68 and -12 s
    # on the default tank and variants A, B and C, -37 s on D (held out), the walls uninspected within
    # the seeds' noise on each. Neither robot sweeping was quicker still, but on variant C (1.6 m deep),
    # where a single pitched look's sweep found the foot of the end wall, it left 11 % of the walls
    # uninspected against 4.6 % (docs/mission.md, "Exploring the map's frontier")
    survey_sweep_deg: float = 60.0
    survey_sweep_no_dvl_deg: float = 0.0
    # how fast a robot with a DVL turns through a survey's sweep (one without turns at yaw_rate_deg_s,
    # for its visual odometry): the camera turns half its field of view (78.5 deg) between two frames at
    # 1 Hz, so that each frame shares half its view with the one before and the sweep's frames leave no
    # gap. The DVL, not the images, holds its position. The first sweep, where the team starts, stays at
    # yaw_rate_deg_s for every planner: turning it this fast too set the robot with the DVL off 14 s
    # before its teammate, and the boustrophedon's lanes on variant B then brought the two together (the
    # walls uninspected +7.4 points [+1.1, +13.7], seeds 0-9, paired)
    sweep_rate_dvl_deg_s: float = 39.0
    frontier: FrontierParams = field(default_factory=FrontierParams)
    # a map-aware robot retires a task on its path whose view the views the team has taken since leave
    # nothing to, on its map now (maptidal.map_discovery.views_left_to_take): rule 5 judged it on the
    # views known and the map held when it was found. Off by default: on the map, with no occlusion, the
    # views taken claim more than their images show. With it on (and the box to inspect) 1 to 2 tasks a
    # mission were retired, and their planned views, scored offline with those taken, leave 3.0 % of
    # variant A's walls uninspected instead of 4.5 % (seeds 0-9; docs/mission.md, "Retiring a task")
    retire_taken: bool = False
    # a map-aware robot retires a task on its path whose view repeats that of a teammate's task of lower
    # key (maptidal.map_discovery, "A repeat of a task found first is retired"): rule 5, applied once the
    # robot has heard of tasks its teammates found before they heard of its own. Reasoned to be on, it was
    # measured off: 2.3 to 3.6 tasks a mission were retired, and the walls left uninspected rose on the
    # default tank by +2.5 points [+0.7, +4.4] and on variant C by +2.8 [+0.3, +5.3], with no finish
    # sooner beyond the seeds' noise (seeds 0-9, paired; docs/mission.md, "Retiring a repeat")
    retire_repeats: bool = False
    # the region a map-aware team is sent to inspect, beyond the exploration radius about each launch:
    # "walls", the box the tank's evaluated walls lie in (the job as the coverage evaluation scores it,
    # and as the baselines are given it, wall by wall; the paper's robots were tested in that region,
    # Sec. IV.B), or "launch", the exploration radius alone. ``inspect_box`` (lowest and highest
    # corners) states the box instead. Only the box is given: never a wall, free water or a way. With
    # the radius alone the robots of the default tank inspected 3 m of side wall beyond the evaluated
    # half metre, and 35 to 50 % of their views looked at walls nobody scores (seeds 0-9, session 30)
    inspect_region: str = "walls"
    inspect_box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None

    @property
    def exploring(self) -> bool:
        """Whether robots explore their map's frontier (``explore``, with map-aware discovery)."""
        return self.explore and self.planner == "maptidal" and self.discovery_mode == "map-aware"

    @property
    def reviewing(self) -> bool:
        """Whether robots review the tasks on their paths, to retire those the views taken cover
        (``retire_taken``) or that repeat a task of lower key (``retire_repeats``); map-aware discovery."""
        asked = self.retire_taken or self.retire_repeats
        return asked and self.planner == "maptidal" and self.discovery_mode == "map-aware"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.duration_s) and 0 < self.duration_s <= MAX_DURATION_S):
            raise ValueError(
                f"duration must be positive and at most {MAX_DURATION_S:g} s (a day), got {self.duration_s!r}"
            )
        late = [e for e in self.events if e.time_s > self.duration_s]
        if late:
            raise ValueError(
                f"a {late[0].kind} event at {late[0].time_s:g} s falls after the mission's end "
                f"({self.duration_s:g} s)"
            )
        if self.pose_source not in POSE_SOURCES:
            raise ValueError(f"pose source must be one of {POSE_SOURCES}, got {self.pose_source!r}")
        if self.planner not in PLANNERS:
            raise ValueError(f"planner must be one of {PLANNERS}, got {self.planner!r}")
        if self.discovery_mode not in DISCOVERY_MODES:
            raise ValueError(f"discovery must be one of {DISCOVERY_MODES}, got {self.discovery_mode!r}")
        if not (
            self.frame_rate_hz > 0
            and self.frame_rate_no_dvl_hz > 0
            and self.command_rate_hz > 0
            and self.dwell_s >= 0
            and self.task_timeout_s > 0
        ):
            raise ValueError(
                "frame_rate_hz, frame_rate_no_dvl_hz, command_rate_hz and task_timeout_s must be positive, "
                "dwell_s >= 0"
            )
        if not (
            math.isfinite(self.position_tolerance_m)
            and self.position_tolerance_m > 0
            and 0 < self.direction_tolerance_deg < 180
            and 0 <= self.max_pitch_deg <= 80
        ):
            raise ValueError(
                "position_tolerance_m must be positive, direction_tolerance_deg in (0, 180) and "
                f"max_pitch_deg in [0, 80]; got {self.position_tolerance_m!r}, "
                f"{self.direction_tolerance_deg!r}, {self.max_pitch_deg!r}"
            )
        if not (
            isinstance(self.survey_pitch_deg, int | float)
            and math.isfinite(self.survey_pitch_deg)
            and 0 <= self.survey_pitch_deg <= 80
        ):
            raise ValueError(f"survey_pitch_deg must be in [0, 80], got {self.survey_pitch_deg!r}")
        for name in ("survey_sweep_deg", "survey_sweep_no_dvl_deg"):
            width = getattr(self, name)
            if not (isinstance(width, int | float) and math.isfinite(width) and 0 <= width < 90):
                # a sweep crosses twice its width in one turn, which must go the short way
                raise ValueError(f"{name} must be in [0, 90), got {width!r}")
        if not (
            isinstance(self.sweep_rate_dvl_deg_s, int | float)
            and math.isfinite(self.sweep_rate_dvl_deg_s)
            and self.sweep_rate_dvl_deg_s > 0
        ):
            raise ValueError(f"sweep_rate_dvl_deg_s must be positive, got {self.sweep_rate_dvl_deg_s!r}")
        if not (math.isfinite(self.motion_model_error) and 0 <= self.motion_model_error < 1):
            raise ValueError(f"motion_model_error must be in [0, 1), got {self.motion_model_error!r}")
        if not (
            isinstance(self.clear_after_s, int | float)
            and math.isfinite(self.clear_after_s)
            and self.clear_after_s >= 0
        ):
            raise ValueError(f"clear_after_s must be a number of seconds >= 0, got {self.clear_after_s!r}")
        if not (math.isfinite(self.lost_after_s) and self.lost_after_s > 0):
            raise ValueError(f"lost_after_s must be positive, got {self.lost_after_s!r}")
        if not (math.isfinite(self.lost_sigma_m) and self.lost_sigma_m > 0):
            raise ValueError(f"lost_sigma_m must be positive, got {self.lost_sigma_m!r}")
        if not (isinstance(self.lost_give_up, int) and self.lost_give_up >= 0):
            raise ValueError(f"lost_give_up must be a whole number >= 0, got {self.lost_give_up!r}")
        if not isinstance(self.lost_hand_over, bool):
            raise ValueError(f"lost_hand_over must be true or false, got {self.lost_hand_over!r}")
        if not (math.isfinite(self.stall_s) and self.stall_s >= 0 and math.isfinite(self.stall_move_m)):
            raise ValueError(f"stall_s must be finite and >= 0, stall_move_m finite; got {self.stall_s!r}")
        if not (math.isfinite(self.clearance_m) and self.clearance_m >= 0):
            raise ValueError(f"clearance_m must be finite and >= 0, got {self.clearance_m!r}")
        if not (0 < self.explore_yaw_deg < 90 and 0 < self.yaw_rate_deg_s < math.inf):
            # a sweep crosses twice explore_yaw_deg in one turn, which must go the short way
            raise ValueError(
                f"explore_yaw_deg must be in (0, 90) and yaw_rate_deg_s positive; got "
                f"{self.explore_yaw_deg!r}, {self.yaw_rate_deg_s!r}"
            )
        if self.inspect_region not in INSPECT_REGIONS:
            raise ValueError(
                f"inspect_region must be one of {', '.join(INSPECT_REGIONS)}, got {self.inspect_region!r}"
            )
        if self.inspect_box is not None:
            check_box(self.inspect_box, "inspect_box")
        check_render_samples(self.render_samples)
        check_water_backend(self.water_backend)
        if self.video and not (
            min(self.video_size) >= 16 and self.video_frames_per_sim_s > 0 and self.video_playback_fps > 0
        ):
            raise ValueError("a video needs a size of at least 16 x 16 and positive frame rates")


INSPECT_REGIONS = ("walls", "launch")


def check_rates(params: MissionParams, control_period_s: float) -> None:
    """Refuse frame and command rates faster than the scenario's control period: the loop runs once a
    control period, so a faster rate would only repeat the same frame or command (and a frame rate of
    1e9 would have the loop draw its cameras at every period, silently)."""
    fastest = 1.0 / control_period_s
    for name in ("frame_rate_hz", "frame_rate_no_dvl_hz", "command_rate_hz"):
        value = getattr(params, name)
        if value > fastest * (1 + 1e-9):
            raise ValueError(
                f"{name} = {value:g} Hz is faster than the control period allows ({fastest:g} Hz, one every "
                f"{control_period_s:g} s)"
            )


def check_events(events: tuple[MissionEvent, ...], names: list[str]) -> dict[str, float]:
    """Check scripted events against the scenario's robots (ValueError naming the problem); returns the
    join time of each robot that joins later."""
    for event in events:
        if event.kind == "current":
            check_current(event.current, f"the current event at {event.time_s:g} s")
        for name in (event.robot, *event.robots) if event.kind != "current" else ():
            if name and name not in names:
                raise ValueError(f"a {event.kind} event names {name!r}; the robots are {', '.join(names)}")
    joins = {e.robot: e.time_s for e in events if e.kind == "join"}
    if len(joins) != sum(1 for e in events if e.kind == "join"):
        raise ValueError("a robot joins once")
    if len(joins) == len(names):
        raise ValueError("every robot joins later: at least one must start the mission")
    for event in events:
        if event.kind == "fail" and event.robot in joins and event.time_s < joins[event.robot]:
            raise ValueError(f"{event.robot} fails at {event.time_s} s, before it joins")
    return joins
