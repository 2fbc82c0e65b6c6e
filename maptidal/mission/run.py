"""The closed-loop Map-TIDAL mission (issue [mission]; the paper's Fig. 2 in our world): robots see, map,
discover tasks, auction them over the acoustic channel, fly to them and inspect them.

Each live robot's go-to-pose controller flies its current activity on its own estimate, streaming pilot
commands at ``command_rate_hz`` (10 Hz) to the robot's flight mode, which runs every control period (the
scenario's, 50 Hz) as the physics steps. The estimate is the robot's dead reckoning (DVL, or without one
the motion model), its horizontal position corrected by its front end (``vo``: visual odometry and
relocalisation against its own map, weighed against the dead reckoning). A robot without a DVL that has
had no visual fix for ``lost_after_s``, or is unsure of its position past ``lost_sigma_m``, goes back, on
its dead reckoning, to where it explored from, turns to the heading it explored along, the view its map
knows best, and sweeps it, rather than chase a goal it cannot tell it has reached; still lost after
that, it stands down (``lost_stand_down``): it releases its tasks and holds where it is until it has a
fix again. Every
``1 / frame_rate_hz`` seconds each robot renders its stereo pair and its front end
(:mod:`maptidal.perception.frontend`) tracks, fuses and, at a keyframe, meshes; discovery
(:func:`maptidal.discovery.discover`) runs on the mesh with every task the robot knows as existing tasks,
and each new task it can reach is minted into its CBBA agent. That work runs in a process of its own
beside the loop (:mod:`maptidal.mission.perception`), and the mission takes a frame's answer (the visual
fix and the new tasks) at the robot's next frame: a one-frame latency, the same whether the worker runs
apart or inline, so the mission does not depend on which. The agents
(:class:`maptidal.allocation.auction.AuctionSimulation`) exchange only their binary messages over the
acoustic channel, in TDMA slots, in step with the physics. A robot explores first (a yaw sweep where it
starts), then flies the first task on its CBBA path, pitching into the view where it can, holds it for
``dwell_s`` with its camera, by its own estimate, within ``position_tolerance_m`` and
``direction_tolerance_deg`` of the view, captures an image and marks the task done, which spreads over
the channel too. The capture is judged on the true camera pose (:mod:`maptidal.mission.verification`):
only verified views are scored. A view it cannot pitch to is declined, with the reason in the log.

A robot that times out on a task gives it up (:meth:`maptidal.allocation.agent.CBBAAgent.give_up`): it
leaves its bundle, so a teammate can win it. With ``lost_hand_over``, a robot without a DVL lost on its
way to a view hands the view over so to a teammate with a DVL that said it had nothing left to do,
once it has been lost on its way there as long as the hand-over takes. The mission ends when every
robot has explored and every task is done or given up by every live robot (a robot standing down is
not waited for), or at ``duration_s``.
Scripted events: a robot failing (it stops and falls silent; CBBA releases its tasks after the agents'
failure timeout) and a current. Outputs go to the output folder as the mission runs
(:mod:`maptidal.mission.outputs`).
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from maptidal.allocation.auction import AuctionEvent, AuctionSimulation
from maptidal.allocation.messages import DONE
from maptidal.allocation.scoring import AuctionParams, RobotProfile
from maptidal.allocation.tasks import Task
from maptidal.camera import StereoCameraParams
from maptidal.comms.channel import Outage
from maptidal.controllers.estimation import rotation_from_rpy
from maptidal.controllers.flight_modes import lean_stick
from maptidal.controllers.pose import PoseController
from maptidal.controllers.trajectory import MotionLimits, PoseReference, PoseTrajectory, Route
from maptidal.envs.rendering import describe_renderer
from maptidal.envs.scenario import Scenario, load_scenario
from maptidal.envs.simulation import Simulation
from maptidal.envs.world import camera_offsets
from maptidal.evaluation.coverage import CoverageModel, CoverageParams, SeenVoxels
from maptidal.exploration import FrontierParams
from maptidal.map_discovery import RobotMap
from maptidal.mission.capture import camera_pose_from_body
from maptidal.mission.clearance import waiting_point
from maptidal.mission.outputs import MissionWriter, survey_outcomes
from maptidal.mission.params import (
    MissionEvent,
    MissionParams,
    check_events,
    check_rates,
)
from maptidal.mission.perception import ExploreRequest, FrameJob, FrameResult, start_perception
from maptidal.mission.plan import box_corners, inspection_box, plan_tasks, reachable
from maptidal.mission.routes import survey_route, sweep_legs
from maptidal.mission.sharing import sharing_table, tasks_lost
from maptidal.mission.time_use import TimeUse, occupation
from maptidal.mission.verification import check_view, pitch_to_fly, view_pitch
from maptidal.mission.video import MissionVideo
from maptidal.perception.dense import DenseDepthParams
from maptidal.perception.frontend import FrontEnd, FrontEndParams
from maptidal.perception.odometry import OdometryParams
from maptidal.perception.recording import CameraIntrinsics, rotation_from_quaternion
from maptidal.perception.relocalisation import RelocalisationParams
from maptidal.perception.unmodelled import UnmodelledMotion, UnmodelledMotionParams
from maptidal.tank import tank_config_to_dict


@dataclass
class _Robot:
    """One robot's mission state."""

    name: str
    index: int
    controller: PoseController
    left_offset: np.ndarray
    centre: np.ndarray
    activity: str = "explore"  # explore (its first sweep), fly, survey, idle, waiting, failed
    route: Route | None = None
    goal: PoseReference | None = None  # where the route to the current task ends
    view: tuple[np.ndarray, np.ndarray] | None = None  # the current task's viewpoint and direction
    max_pitch_deg: float = 0.0  # the most it pitches for a view (0: it cannot pitch)
    claimed: int = 0  # tasks it said were done
    verified: int = 0  # of those, the ones whose true view was within tolerance
    route_start_s: float = 0.0
    task_key: int | None = None
    task_started_s: float = 0.0
    within_since_s: float | None = None
    # where its estimate last moved stall_move_m from, and when (MissionParams.stall_s)
    still_at: tuple[np.ndarray, float] | None = None
    explored: bool = False  # its first sweep made and, when exploring, no look left worth a trip
    skipped: set = field(default_factory=set)
    # the tasks on its path that its latest review found the views taken cover ("taken";
    # MissionParams.retire_taken) or repeats of tasks of lower key ("repeat"; retire_repeats), and why:
    # retired when it comes to them
    covered: dict = field(default_factory=dict)
    # exploration (MissionParams.explore): its latest next looks and the time of the frame they were
    # worked out on; its surveys, each its look (where it stood), its span and the tasks found on its
    # frames (:func:`maptidal.mission.outputs.survey_outcomes`); when its last survey ended (a look from
    # an older frame is stale: it was worked out before that survey's views)
    frontier: np.ndarray | None = None
    frontier_frame_s: float = -math.inf
    frontier_held: int = 0  # with no look left: how many were left out for being near a teammate
    # the search that gave ``frontier`` in numbers (maptidal.exploration.Exploration.summary), and, once
    # it has explored, when and why (the search that found no look), for its event and mission.json
    frontier_summary: dict | None = None
    explored_why: dict | None = None
    survey_log: list = field(default_factory=list)
    time_use: TimeUse = field(default_factory=TimeUse)  # where its mission time went
    survey_ended_s: float = -math.inf
    has_dvl: bool = True
    # seconds since its last frame that its estimator ran without its DVL (no beam in range: a teammate
    # beneath it, say), for its front end (maptidal.perception.odometry)
    dvl_out_s: float = 0.0
    # its accelerometer against its motion model (MissionParams.watch_pushes): how far it may have moved
    # unseen since its last frame
    unmodelled: UnmodelledMotion = field(default_factory=UnmodelledMotion)
    frame_every_s: float = 1.0
    next_frame_s: float = 0.0
    xy_correction: np.ndarray = field(default_factory=lambda: np.zeros(2))
    fixes_seen: int = 0
    last_fix_s: float = 0.0
    lost: bool = False
    # what made it lost: "no_fix" or "uncertain" (MissionParams.lost_after_s, lost_sigma_m)
    lost_why: str = ""
    task_losses: int = 0  # how many times it was lost on its way to its current task
    position_sigma_m: float = 0.0  # its front end's horizontal standard deviation, as of the last frame
    home_position: np.ndarray = field(default_factory=lambda: np.zeros(3))  # where it explored from
    home_yaw: float = 0.0  # the heading it explored along (its map lies that way)
    recovery: Route | None = None  # its way back home when lost, flown from lost_since_s
    lost_since_s: float = 0.0
    lost_at_s: float = 0.0  # when it was last found lost
    yielding: bool = False  # holding its reference out of a teammate's clearance
    # in a spell of giving way (its events and time use): from its first yielding until its way has
    # been clear for clear_after_s (MissionParams), since clear_since_s
    giving_way: bool = False
    clear_since_s: float | None = None
    referenced_s: float | None = (
        None  # when its reference was last worked out (its route pauses while yielding)
    )
    launch: tuple[np.ndarray, float] | None = None  # a joining robot's parking pose (position, yaw)
    last_left: np.ndarray | None = None  # the latest left image, for the video's inset
    visual_updates: int = 0  # the front end's visual fixes, as of the latest frame result taken
    failed_at_s: float | None = None  # when a scripted failure took it

    @property
    def active(self) -> bool:
        """In the mission now: neither waiting to join nor failed."""
        return self.activity not in ("waiting", "failed")

    @property
    def surveyed(self) -> list[np.ndarray]:
        """The places it surveyed (each survey's look), in order."""
        return [entry["look"] for entry in self.survey_log]


def _can_pitch(vehicle) -> bool:
    """Whether the vehicle's thrusters can pitch it either way (the Heavy's can; the standard frame's
    cannot)."""
    authority = vehicle.controller_model().authority
    return min(authority[0][4], authority[1][4]) > 0


def _drawing_thread() -> ThreadPoolExecutor:
    """The thread the mission's cameras are drawn on."""
    return ThreadPoolExecutor(1, thread_name_prefix="maptidal-gl")


class _SameThread:
    """An executor that runs each call at once on the caller's thread (the mission's drawing where GL
    contexts may not move off the main thread)."""

    def submit(self, fn, /, *args, **kwargs) -> Future:
        """Run ``fn`` now; a Future with its result, or its exception."""
        future: Future = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as error:  # the caller sees it at .result(), as with a thread
            future.set_exception(error)
        return future

    def shutdown(self, wait: bool = True) -> None:
        """Nothing to stop."""


class Mission:
    """A closed-loop mission in a scenario (module docstring); :meth:`run` flies it."""

    def __init__(self, scenario: Scenario | str | None, params: MissionParams, out_dir) -> None:
        self.params = params
        self.scenario = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        check_rates(params, self.scenario.control_period_s)
        names = [r.name for r in self.scenario.robots]
        index_of = {name: k for k, name in enumerate(names)}
        joins = check_events(params.events, names)
        outages = tuple(
            Outage(
                e.time_s,
                e.time_s + e.duration_s,
                tuple(index_of[n] for n in e.robots) if e.robots else None,  # type: ignore[arg-type]
            )
            for e in params.events
            if e.kind == "outage"
        )
        # a baseline's plan: a tank it cannot plan is refused before any thread or process starts
        self._planned: list[Task] = []
        self.plan_summary: dict = {}
        if params.planner != "maptidal":
            standoff = params.discovery.standoff
            self._planned, self.plan_summary = plan_tasks(params.planner, self.scenario.tank, standoff)
        width, height = params.image_size
        # the perception worker first, so that its start overlaps the simulator's
        self.perception = start_perception(
            names, (height, width, 3), in_process=not params.perception_process
        )
        try:
            self._build(params, joins, outages, out_dir)
        except BaseException:
            # a mission that cannot start leaves no worker process, nor a thread, behind
            self.perception.close()
            if hasattr(self, "_gl"):
                self._gl.shutdown()
            raise

    def _build(self, params: MissionParams, joins: dict, outages: tuple, out_dir) -> None:
        """The simulator, the robots, the auction and the outputs (``__init__``'s work past the checks)."""
        width, height = params.image_size
        self.sim = Simulation(
            self.scenario,
            camera=StereoCameraParams(width=width, height=height),
            flight_mode="stabilize",
            render_samples=params.render_samples,
            water_backend=params.water_backend,
            motion_model_error=params.motion_model_error,
        )
        self.sim.reset(seed=params.seed)
        k = np.array(self.sim.intrinsics()["K"])
        self.intrinsics = CameraIntrinsics(
            width,
            height,
            float(k[0, 0]),
            float(k[1, 1]),
            float(k[0, 2]),
            float(k[1, 2]),
            self.sim.camera.baseline_m,
        )
        self.robots: dict[str, _Robot] = {}
        self.robots_by_index: dict[int, _Robot] = {}
        profiles, joining = [], []
        fronts: dict[str, FrontEnd] = {}  # each robot's front end, handed to the perception worker
        launches: dict[str, np.ndarray] = {}  # where each starts (or parks), its estimator's origin
        water = self.scenario.water
        camera_noise = water.noise_sigma if water.enabled else 0.0  # per colour channel, 8-bit levels
        for index, spec in enumerate(self.scenario.robots):
            truth = self.sim.ground_truth(spec.name)
            launches[spec.name] = np.asarray(truth["position"], float)
            profile = RobotProfile(spec.name, index, launches[spec.name], speed=params.speed_m_s)
            if spec.name in joins:
                joining.append(AuctionEvent(joins[spec.name], "join", profile=profile))
            else:
                profiles.append(profile)
            fronts[spec.name] = FrontEnd(
                self.intrinsics,
                params.pose_source,
                FrontEndParams(
                    keyframes=params.keyframes,
                    odometry=OdometryParams(has_dvl="dvl" in spec.sensors),
                    relocalisation=RelocalisationParams(enabled=params.relocalise),
                    # the camera's noise, as a calibration gives it, sets the dense depth's texture test
                    dense=DenseDepthParams(pixel_noise_sigma=camera_noise),
                ),
            )
            self.robots[spec.name] = _Robot(
                spec.name,
                index,
                PoseController(spec.vehicle.controller_model(), hold_roll_pitch=False),
                camera_offsets(spec.vehicle, self.sim.camera)["left"],
                np.asarray(spec.vehicle.sensors.camera_position, float),
                has_dvl="dvl" in spec.sensors,
                # STABILIZE holds a pitch only on a frame with pitch authority (the Heavy)
                max_pitch_deg=params.max_pitch_deg
                if spec.vehicle.controller_model().authority[0][4] > 0
                else 0.0,
            )
            robot = self.robots[spec.name]
            self.robots_by_index[index] = robot
            model = self.sim.motion_model(spec.name)
            if model is not None:  # the glide after a push, as the robot's own model slows it
                robot.unmodelled = UnmodelledMotion(UnmodelledMotionParams.for_model(model))
            rate = params.frame_rate_hz if robot.has_dvl else params.frame_rate_no_dvl_hz
            robot.frame_every_s = 1.0 / rate
            # the robots' cameras are not synchronised: their frames fall evenly through the frame
            # period, which also spreads the drawing on the GL thread
            robot.next_frame_s = robot.frame_every_s * index / len(self.scenario.robots)
            if spec.name in joins:
                robot.activity = "waiting"
                robot.launch = (launches[spec.name], float(truth["rpy"][2]))
        channel = dataclasses.replace(params.channel, outages=params.channel.outages + outages)
        self.auction = AuctionSimulation(profiles, [], channel, AuctionParams(), params.agent, events=joining)
        self.writer = MissionWriter(out_dir)
        maps, self.explore_params = None, params.frontier
        if params.discovery_mode == "map-aware" and params.planner == "maptidal":
            # the surface's height is the depth sensor's datum, the one the robots' estimators place
            # their depth with; nothing else of the tank is given
            # the steepest view any of them can fly: its pitch for a view plus the tolerance a view is
            # judged by (a robot declines a steeper one)
            steepest = max(r.max_pitch_deg for r in self.robots.values()) + params.direction_tolerance_deg
            map_params = dataclasses.replace(
                params.map_aware, surface_z=self.scenario.tank.height, max_view_pitch_deg=min(steepest, 90.0)
            )
            # each robot inspects the region it explores: within the exploration radius of its launch,
            # and in the box it was sent to inspect
            box = inspection_box(params, self.scenario.tank)
            region_box = None if box is None else box_corners(box)
            maps = {
                name: RobotMap(
                    dataclasses.replace(
                        map_params,
                        region_centre=tuple(float(c) for c in launches[name]),
                        region_radius_m=params.frontier.explore_radius_m,
                        region_box=region_box,
                    )
                )
                for name in fronts
            }
            # it explores the box and the water its views stand in: the standoff and the clearance
            # they keep from the walls around it; a look is worth what it reveals of the box, grown as
            # rule 1 grows it, where the structure lies
            if box is not None:
                reach = params.discovery.standoff + map_params.clearance_m
                grown = box_corners([box[0] - reach, box[1] + reach])
                tolerance = map_params.plane_tolerance_m
                counted = box_corners([box[0] - tolerance, box[1] + tolerance])
                self.explore_params = dataclasses.replace(
                    params.frontier, explore_box=grown, gain_box=counted
                )
        self.perception.configure(fronts, params.discovery, maps)
        # the robots' cameras render on a thread of their own, beside the physics (MuJoCo lets go of
        # Python's lock while it draws): the renderer, and its GL context, are made there, and every draw
        # of this simulation's cameras happens there. The loop takes a snapshot of the scene at the frame's
        # moment (Simulation.stereo_snapshot), so the images do not depend on when the thread draws them.
        # GLFW makes its contexts on the main thread only, so under MUJOCO_GL=glfw the loop draws itself
        self._gl = _SameThread() if os.environ.get("MUJOCO_GL") == "glfw" else _drawing_thread()
        self.renderer_description = self._gl.submit(self._make_renderer).result()
        self._frames_render_s = 0.0  # the GL thread's time drawing the frames perception takes
        self._waited_s = 0.0  # the loop's time waiting for a frame's drawing and its answer
        self._frames: dict[str, Future] = {}  # each robot's frame being drawn and handed to perception
        self._captures: list[Future] = []  # task images being drawn and written on the GL thread
        self.tasks: dict[int, dict] = {}  # key -> record (the mission's own ledger, for the outputs)
        self.timing = dict.fromkeys(
            ("physics", "rendering", "perception", "discovery", "allocation", "control"), 0.0
        )
        self.captured: list[np.ndarray] = []  # the true camera viewpoints where images were captured
        self.captured_at: list[float] = []  # when each was captured (s)
        self.inspections: dict[int, int] = {}  # task key -> images captured of it
        self.video = MissionVideo(self, params) if params.video else None
        # what the captured views have inspected so far (occlusion on), for the progress bar and snapshots
        self.seen = SeenVoxels(CoverageModel.from_tank(self.scenario.tank, CoverageParams(occlusion=True)))

    # ----- helpers ------------------------------------------------------------------------------
    @property
    def drawing(self) -> ThreadPoolExecutor | _SameThread:
        """The executor every drawing of the mission runs on, one at a time (the cameras, the captures,
        the video): a thread of its own, or the caller's where GL contexts may not move off it."""
        return self._gl

    def _limits(self) -> MotionLimits:
        rate = math.radians(self.params.yaw_rate_deg_s)
        return MotionLimits(
            max_speed=self.params.speed_m_s, max_accel=0.1, max_yaw_rate=rate, max_yaw_accel=rate
        )

    def _sweep_limits(self, robot: _Robot) -> MotionLimits:
        """The limits of ``robot``'s survey sweeps: one with a DVL turns at ``sweep_rate_dvl_deg_s``."""
        if not robot.has_dvl:
            return self._limits()
        rate = math.radians(self.params.sweep_rate_dvl_deg_s)
        return dataclasses.replace(self._limits(), max_yaw_rate=rate, max_yaw_accel=rate)

    def _sweep(self, position: np.ndarray, yaw: float) -> list[PoseTrajectory]:
        """The exploration's yaw sweep at ``position``, facing ``yaw`` (``sweep_legs``)."""
        return sweep_legs(position, yaw, math.radians(self.params.explore_yaw_deg), self._limits())

    def _start_exploring(self, robot: _Robot, now: float) -> None:
        estimate = self._estimate(robot)
        here, yaw = estimate.position.copy(), estimate.yaw
        robot.home_position, robot.home_yaw = here.copy(), yaw
        robot.route = Route(self._sweep(here, yaw))
        robot.route_start_s = now

    def _reference(self, robot: _Robot, now: float):
        if robot.yielding and robot.referenced_s is not None:
            # a robot giving way pauses its route, and takes it up where it left off: resumed on the
            # clock, the reference would leap ahead, and the robot rush at full thrust to catch it up
            paused = now - robot.referenced_s
            robot.route_start_s += paused
            if robot.lost:
                robot.lost_since_s += paused
        robot.referenced_s = now
        reference = robot.route.at(now - robot.route_start_s)
        if robot.activity == "fly" and robot.goal is not None and robot.goal.pitch:
            # pitch into the view as the route closes in on it, and be there on arrival
            share = min(1.0, (now - robot.route_start_s) / max(robot.route.duration, 1e-9))
            reference = dataclasses.replace(reference, pitch=robot.goal.pitch * share)
        elif robot.activity == "survey" and robot.survey_log and robot.survey_log[-1]["pitch"]:
            # a pitched look: pitch on the way to it, and hold the pitch through the sweep there
            approach = robot.route.legs[0].duration
            share = min(1.0, (now - robot.route_start_s) / max(approach, 1e-9))
            reference = dataclasses.replace(reference, pitch=robot.survey_log[-1]["pitch"] * share)
        if self._lost(robot, now):
            # no horizontal position for a while (no DVL, no visual fix): do not chase a goal the robot
            # cannot tell it has reached (that flies it away at full speed); go where a fix is likely, on
            # the dead reckoning, which holds for the few seconds this takes (``_lost``)
            if now - robot.lost_since_s > robot.recovery.duration:
                self._stand_down(robot, now)  # home, swept, and still lost: it stands down
                self._start_recovery(robot, now)  # ... and sweeps again
            reference = robot.recovery.at(now - robot.lost_since_s)
        return self._keep_clear(robot, reference, now)

    def _stand_down(self, robot: _Robot, now: float) -> None:
        """``robot``, still lost after its recovery, stands down (``lost_stand_down``): its agent releases
        its tasks and bids on none, and it leaves the task or the look it was flying to, which it may
        survey again once it has a fix."""
        if not self.params.lost_stand_down or not self.auction.agents[robot.index].stand_down(now):
            return
        left = robot.activity
        if left == "survey":
            robot.survey_log.pop()
            robot.survey_ended_s, robot.frontier = now, None
        if left in ("fly", "survey"):
            robot.activity = "idle"
        lost_s = round(now - robot.lost_at_s, 2)
        self.writer.event(now, "stood_down", robot=robot.name, left=left, lost_s=lost_s)

    def _start_recovery(self, robot: _Robot, now: float) -> None:
        """A lost robot's way back (``_lost``): on its dead reckoning to where it explored from, turning
        to the heading it explored along, the view its map knows best; then the exploration's yaw sweep
        there, in case that view is bare (its estimate may be off, and the robot facing a blank wall).
        A robot standing down (``_stand_down``) went home once and found no fix there: its estimate is
        off by more than that way could mend, and flying on it would take it where it does not know,
        through the water its teammates work in. It holds where it is and sweeps there."""
        estimate = self._estimate(robot)
        robot.lost_since_s = now
        if self._standing_down(robot):
            robot.recovery = Route(self._sweep(estimate.position.copy(), estimate.yaw))
            return
        home, yaw = robot.home_position, robot.home_yaw
        way_home = PoseTrajectory(estimate.position.copy(), estimate.yaw, home, yaw, self._limits())
        robot.recovery = Route([way_home, *self._sweep(home, yaw)])

    def _count_dvl_dropouts(self, elapsed_s: float) -> None:
        """Add ``elapsed_s`` (the control period just flown) to the DVL-less time of each robot whose DVL
        gave no velocity in it (a beam out of its range: the floor or a teammate right beneath it). Its
        next frame hands that time to its front end, which is then as unsure as a robot without a DVL
        until its next fix (:mod:`maptidal.perception.odometry`)."""
        for robot in self.robots.values():
            if robot.active and robot.has_dvl:
                dvl = self.sim.latest_readings(robot.name).get("dvl")
                if dvl is not None and not dvl["valid"]:
                    robot.dvl_out_s += elapsed_s

    def _watch_pushes(self, elapsed_s: float) -> None:
        """Fold the control period just flown (``elapsed_s``) into each robot's watch on its motion model
        (:class:`maptidal.perception.unmodelled.UnmodelledMotion`): its accelerometer's period mean against
        the velocity its estimator gave, where that came from the model (no DVL, or none in range)."""
        for robot in self.robots.values():
            if not robot.active:
                continue
            readings = self.sim.latest_readings(robot.name)
            imu = readings.get("imu")
            if imu is None:
                continue
            dvl = readings.get("dvl")
            modelled = dvl is None or not dvl["valid"]
            estimate = self.sim.estimate(robot.name)
            pushes = robot.unmodelled.pushes
            robot.unmodelled.update(
                imu.get("accel_mean", imu["accel"]),
                imu["gyro"],
                float(estimate.rpy[0]),
                float(estimate.rpy[1]),
                estimate.velocity_body,
                elapsed_s,
                modelled,
            )
            if robot.unmodelled.pushes != pushes:
                self.writer.event(self.sim.time, "pushed", robot=robot.name)

    def _count_time_use(self, now: float, elapsed_s: float) -> None:
        """Give the control period just flown (``elapsed_s``, ending at ``now``) to each robot's
        occupation in it (:mod:`maptidal.mission.time_use`)."""
        for robot in self.robots.values():
            kind = occupation(robot.activity, robot.lost, robot.giving_way, robot.explored)
            robot.time_use.add(now, elapsed_s, kind)

    def _teammates_heard(self, robot: _Robot, now: float, busy_only: bool = False) -> np.ndarray:
        """Rows ``(x, y, z, age_s)``: where each teammate's last message put it, and how long ago; with
        ``busy_only``, only the teammates whose last message did not say they had nothing left to do."""
        agent = self.auction.agents[robot.index]
        rows = [
            [*np.asarray(position, float)[:3], now - heard_s]
            for peer, (position, heard_s) in agent.peer_positions.items()
            if not (busy_only and agent.peer_idle.get(peer, False))
        ]
        return np.array(rows, float).reshape(-1, 4)

    def _keep_clear(self, robot: _Robot, reference: PoseReference, now: float) -> PoseReference:
        """The reference held where the robot's straight way to it would enter the ``clearance_m``
        ball about a teammate it gives way to (MissionParams), or the capsule about that teammate's way
        to where its last message said it was bound, as far as it can have flown since
        (``_teammate_way``), on its own side; a robot inside such a ball that is not leaving it backs out
        horizontally, at its own depth (:func:`maptidal.mission.clearance.waiting_point`).
        It waits there until the teammate's next message says it has gone.

        Whom it gives way to: every teammate heard from lately, but one of a higher index only while that
        one's last message did not say it was giving way. A robot waiting on a lower-indexed teammate says
        so in its next message, and the other then goes on: two robots never wait on each other for
        longer than that, and the lower index keeps the right of way. A robot with nothing left to do
        (explored, no task) says so too, and gives way to every teammate, and none waits on it: it
        backs out of the way of one that comes to it. Otherwise a robot that had finished could hold a
        teammate's way, or the place its teammate has to go, for the rest of the mission."""
        agent = self.auction.agents[robot.index]
        agent.idle = robot.activity == "idle" and robot.explored
        agent.goal = self._bound_for(robot)
        peers = [
            (peer, position)
            for peer, (position, heard_s) in agent.peer_positions.items()
            if now - heard_s <= self.params.peer_fresh_s
            and (
                agent.idle
                or (
                    not agent.peer_idle.get(peer, False)
                    and (peer < robot.index or not agent.peer_giving_way.get(peer, False))
                )
            )
        ]
        stop = None
        if peers and self.params.clearance_m > 0:  # 0 turns keeping clear off
            shapes = [self._teammate_way(agent, peer, position, now) for peer, position in peers]
            here = self._estimate(robot).position
            stop = waiting_point(here, reference.position, shapes, self.params.clearance_m)
        agent.giving_way = robot.yielding = stop is not None
        self._log_giving_way(robot, None if stop is None else peers[stop[1]][0], now)
        if stop is None:
            return reference
        return PoseReference(stop[0], np.zeros(3), np.zeros(3), reference.yaw, reference.yaw_rate)

    def _log_giving_way(self, robot: _Robot, blocking: int | None, now: float) -> None:
        """The ``yielding`` event when a spell of giving way begins (``blocking``: the teammate's index,
        None while the way is clear), and ``clear`` once the way has stayed clear for ``clear_after_s``
        (MissionParams): a spell broken for less is one spell."""
        if blocking is not None:
            robot.clear_since_s = None
            if not robot.giving_way:
                robot.giving_way = True
                self.writer.event(now, "yielding", robot=robot.name, to=self.robots_by_index[blocking].name)
            return
        if not robot.giving_way:
            return
        if robot.clear_since_s is None:
            robot.clear_since_s = now
        if now - robot.clear_since_s >= self.params.clear_after_s:
            robot.giving_way, robot.clear_since_s = False, None
            self.writer.event(now, "clear", robot=robot.name)

    def _bound_for(self, robot: _Robot) -> np.ndarray | None:
        """Where the robot is bound, for its messages: the end of the route it flies (its way home when
        lost), or None when it holds where it is (idle)."""
        route = robot.recovery if robot.lost else robot.route
        if route is None or (robot.activity == "idle" and not robot.lost):
            return None
        return np.asarray(route.at(route.duration).position, float)

    def _teammate_way(self, agent, peer: int, position: np.ndarray, now: float) -> np.ndarray:
        """Where a teammate may be (:mod:`maptidal.mission.clearance`): the segment from where its last
        message put it towards where that message said it was bound, as far as it can have flown since
        (``speed_m_s``, the routes' top speed, times the message's age), or its position alone."""
        goal = agent.peer_goals.get(peer)
        position = np.asarray(position, float)
        if goal is None:
            return position
        heard_s = agent.peer_positions[peer][1]
        reach = self.params.speed_m_s * max(now - heard_s, 0.0)
        to_goal = np.asarray(goal, float) - position
        distance = float(np.linalg.norm(to_goal))
        if distance < 1e-9 or reach <= 0.0:
            return position
        return np.stack([position, position + min(1.0, reach / distance) * to_goal])

    def _lost(self, robot: _Robot, now: float) -> bool:
        """A robot without a DVL whose front end has had no visual fix for ``lost_after_s``, or whose
        position it holds to be more than ``lost_sigma_m`` uncertain. One lost for want of a fix is found
        again at its next fix, if that leaves it no more uncertain than ``lost_sigma_m``; one lost for its
        uncertainty once it has a fix and is half as uncertain (so that it does not flicker between the
        two). The hysteresis goes with the cause: a robot that lost its fix while sure of its position
        (8 cm in the default mission) would otherwise wait for many fixes to halve a limit it never
        passed."""
        if robot.has_dvl or self.params.pose_source != "vo":
            return False
        updates = robot.visual_updates
        if updates != robot.fixes_seen:
            robot.fixes_seen, robot.last_fix_s = updates, now
        unfixed = now - robot.last_fix_s > self.params.lost_after_s
        halved = robot.lost and robot.lost_why == "uncertain"
        limit = self.params.lost_sigma_m * (0.5 if halved else 1.0)
        lost = unfixed or robot.position_sigma_m > limit
        if lost != robot.lost:
            robot.lost = lost
            if lost:
                robot.lost_why = "no_fix" if unfixed else "uncertain"
                robot.lost_at_s = now
                robot.task_losses += robot.activity == "fly"
                robot.controller.reset_horizontal()
                # go back to where it explored from, the view its map knows best (its anchors there were
                # made first, and surest), and turn to the heading it explored along: a robot staring at a
                # bare patch of wall close up, or backing off step by step, never finds a fix
                self._start_recovery(robot, now)

            if lost:  # say why: no fix for a while, or a fix too unsure
                self.writer.event(
                    now,
                    "position_lost",
                    robot=robot.name,
                    why=robot.lost_why,
                    sigma_m=round(float(robot.position_sigma_m), 3),
                    unfixed_s=round(now - robot.last_fix_s, 2),
                )
            else:
                self.writer.event(now, "position_regained", robot=robot.name)
                if self.auction.agents[robot.index].resume(now):
                    self.writer.event(now, "resumed", robot=robot.name)
        return lost

    def _estimate(self, robot: _Robot):
        """What the robot flies on: its dead reckoning, with the horizontal position corrected by its front
        end (visual odometry and relocalisation, weighed against the DVL or the motion model) when the pose
        source is ``vo``, or set to the truth when it is ``truth`` (an oracle localisation): the pose it
        meshes on. The offset is refreshed at every frame; between frames the dead reckoning carries it.
        With ``dr``, and without a DVL, the robot flies blind."""
        estimate = self.sim.estimate(robot.name)
        if not robot.xy_correction.any():
            return estimate
        corrected = dataclasses.replace(estimate, position=estimate.position.copy())
        corrected.position[:2] += robot.xy_correction
        return corrected

    def _camera_pose(self, robot: _Robot, source: str):
        if source == "truth":
            truth = self.sim.ground_truth(robot.name)
            return camera_pose_from_body(
                truth["position"], rotation_from_quaternion(truth["quaternion"]), robot.left_offset
            )
        estimate = self.sim.estimate(robot.name)  # the raw dead reckoning: the front end corrects it itself
        return camera_pose_from_body(estimate.position, rotation_from_rpy(*estimate.rpy), robot.left_offset)

    # ----- the loop -------------------------------------------------------------------------------
    def run(self, progress: Callable[[float, int, int, float, float], None] | None = None) -> dict:
        """Fly the mission; returns the final ``mission.json`` document. ``progress(now_s, found, done,
        duration_s, inspected_pct)`` is called once a simulated second."""
        try:
            return self._run(progress)
        finally:
            # whatever ended the mission: the worker process goes, the video is left playable, and the
            # renderer goes, on its own thread
            if self.video is not None:
                self.video.abandon()
            self.perception.close()
            self._gl.submit(self.sim.close).result()
            self._gl.shutdown()

    def _run(self, progress: Callable[[float, int, int, float, float], None] | None) -> dict:
        p = self.params
        period = self.scenario.control_period_s
        # the go-to-pose controller's rate: a whole number of control periods
        command_every = period * max(1, round(1.0 / (p.command_rate_hz * period)))
        next_command = 0.0
        frame_every = 1.0 / p.frame_rate_hz
        next_frame, next_snapshot, next_check = 0.0, p.snapshot_every_s, 0.0
        events = sorted(p.events, key=lambda e: e.time_s)
        wall_start = time.perf_counter()
        for robot in self.robots.values():
            if robot.active:
                self._start_exploring(robot, 0.0)
        waiting = [r.name for r in self.robots.values() if not r.active]
        self.writer.event(
            0.0,
            "start",
            robots=list(self.robots),
            pose_source=p.pose_source,
            waiting=waiting,
            perception={"mode": self.perception.mode, "pid": self.perception.pid},
            # the tank flown in, so that `maptidal report` rebuilds the report on it
            tank=tank_config_to_dict(self.scenario.tank.config),
        )
        if self._planned:
            self._add_plan(0.0)
        now = 0.0
        finished = False
        while now < p.duration_s - 1e-9:
            while events and events[0].time_s <= now:
                self._apply(events.pop(0), now)
            start = time.perf_counter()
            commands = {}
            command_due = now >= next_command - 1e-9
            if command_due:
                next_command += command_every
            for robot in self.robots.values():
                if robot.active and command_due:
                    # between commands the simulator holds each robot's last one, as ArduSub holds the
                    # last pilot input it was streamed
                    reference = self._reference(robot, now)
                    command = robot.controller.update(self._estimate(robot), reference, command_every)
                    if reference.pitch:
                        # STABILIZE holds the lean its pitch stick asks for (pilot pitch: nose up +)
                        command = command.copy()
                        command[4] = lean_stick(-reference.pitch, self.sim.mode_params)
                    commands[robot.name] = command
                elif robot.activity == "waiting":
                    self.sim.place(robot.name, robot.launch[0], robot.launch[1])  # parked, at rest
                elif robot.activity == "failed":
                    commands[robot.name] = np.zeros(6)
            self.timing["control"] += time.perf_counter() - start
            start = time.perf_counter()
            before = now
            self.sim.step(commands)
            self.timing["physics"] += time.perf_counter() - start
            now = self.sim.time
            self._count_dvl_dropouts(now - before)
            if p.watch_pushes:
                self._watch_pushes(now - before)
            self._count_time_use(now, now - before)
            for robot in self.robots.values():
                if robot.active:
                    self._advance_activity(robot, now)
            start = time.perf_counter()
            for robot in self.robots.values():
                if robot.active:
                    self.auction.agents[robot.index].set_position(self._estimate(robot).position)
            self.auction.advance_to(now)
            self.timing["allocation"] += time.perf_counter() - start
            for robot in self.robots.values():
                if robot.active and now >= robot.next_frame_s - 1e-9:
                    robot.next_frame_s += robot.frame_every_s
                    self._see(robot, now)
            if self.video is not None:
                start = time.perf_counter()
                self.video.frame_due(now)
                self.timing["rendering"] += time.perf_counter() - start
            if now >= next_frame - 1e-9:
                next_frame += frame_every
                self.writer.trajectory(now, {r.name: self._poses(r) for r in self.robots.values()})
            if now >= next_snapshot:
                next_snapshot += p.snapshot_every_s
                self._write_snapshot(now, time.perf_counter() - wall_start)
            if now >= next_check - 1e-9:  # once a second: the end, and the progress bar
                next_check += 1.0
                if progress is not None:
                    done = sum(1 for t in self.tasks.values() if t["completed"])
                    progress(now, len(self.tasks), done, p.duration_s, self.inspected_pct())
                if self._finished():
                    finished = True
                    break
        self.writer.event(now, "end", finished=finished, ending=self.ending(now, finished))
        return self._write_final(now, wall_start, finished)

    def _write_snapshot(self, now: float, wall_s: float) -> None:
        """Replace ``mission.json`` with the mission as of now, once the task images it names are on disk."""
        self._settle_captures()
        self.writer.snapshot(self.document(now, wall_s, finished=False))

    def _write_final(self, now: float, wall_start: float, finished: bool) -> dict:
        """The final ``mission.json``, plots and report, once every task image is on disk."""
        self._settle_captures()
        if self.video is not None:
            self.video.close()
        document = self.document(now, time.perf_counter() - wall_start, finished=finished)
        if self.video is not None:
            document["video"] = {"file": self.video.path.name, "frames": self.video.frames}
        self.writer.finish(
            document, self.captured_views(), np.array(self.captured_at), self.scenario.tank, self.params.plots
        )
        return document

    def _poses(self, robot: _Robot) -> dict:
        truth = self.sim.ground_truth(robot.name)
        estimate = self._estimate(robot)
        return {"truth": truth["position"], "estimate": estimate.position.tolist(), "yaw": truth["rpy"][2]}

    def _apply(self, event: MissionEvent, now: float) -> None:
        if event.kind == "fail":
            robot = self.robots[event.robot]
            robot.activity, robot.failed_at_s = "failed", now
            self.auction.agents[robot.index].alive = False
            self.writer.event(now, "fail", robot=robot.name)
        elif event.kind == "join":
            robot = self.robots[event.robot]
            if robot.activity != "waiting":
                return
            self.sim.place(robot.name, robot.launch[0], robot.launch[1])  # its estimator starts here
            robot.activity, robot.next_frame_s = "explore", now
            self._start_exploring(robot, now)
            self.auction.apply_events_due(now)  # its CBBA agent joins: the auction's own join event
            if self._planned:  # it dives with the mission plan, as its teammates did
                self.auction.agents[robot.index].add_tasks(self._planned, now_s=now)
            self.writer.event(now, "join", robot=robot.name)
        elif event.kind == "outage":
            # the channel carries it (ChannelParams.outages, set up at construction); logged for the record
            self.writer.event(now, "outage", duration_s=event.duration_s, robots=list(event.robots) or "all")
        elif event.kind == "current":
            self.sim.set_current(event.current)
            self.writer.event(now, "current", current=list(event.current))

    def _make_renderer(self) -> str:
        # on the GL thread: the renderer's context is made, and stays current, there
        self.sim.water_backend  # noqa: B018 - makes the renderer now, not in the first frame's time
        return describe_renderer(self.sim.model, self.sim.camera.height, self.sim.camera.width)

    def _draw_capture(self, snapshot, name: str) -> None:
        # on the GL thread: draw a task's image and write it (OpenCV lets go of Python's lock meanwhile)
        left, _ = self.sim.render_snapshot(snapshot)
        self.writer.image(name, left)

    def _settle_captures(self) -> None:
        """Wait until every task image asked for so far is on disk (before a mission.json names them);
        an error drawing or writing one is raised here."""
        start = time.perf_counter()
        captures, self._captures = self._captures, []
        for capture in captures:
            capture.result()
        self._waited_s += time.perf_counter() - start

    def _draw_frame(self, snapshot, job: FrameJob) -> np.ndarray:
        # on the GL thread: draw the frame's snapshot and hand the pair to perception
        start = time.perf_counter()
        left, right = self.sim.render_snapshot(snapshot)
        self._frames_render_s += time.perf_counter() - start
        self.perception.submit(dataclasses.replace(job, left=left, right=right))
        return left

    def _see(self, robot: _Robot, now: float) -> None:
        """Take the robot's previous frame's answer from perception, then snapshot this frame, to be
        drawn on the GL thread and sent to perception with the tasks the robot knows now."""
        previous = self._frames.pop(robot.name, None)
        if previous is not None:
            start = time.perf_counter()
            robot.last_left = previous.result()  # drawn and sent by now, almost always
            result = self.perception.result(robot.name)
            self._waited_s += time.perf_counter() - start
            self._use_frame_result(robot, result, now)
        start = time.perf_counter()
        snapshot = self.sim.stereo_snapshot(robot.name)
        self.timing["rendering"] += time.perf_counter() - start
        base = "truth" if self.params.pose_source == "truth" else "dr"
        agent = self.auction.agents[robot.index]
        known = agent.tasks
        existing = np.zeros((len(known), 6))
        if known:
            existing[:, :3] = [t.position for t in known]
            existing[:, 3:] = [t.direction for t in known]
        review = {}
        if self.params.reviewing:
            keys = agent.keys.copy()
            done = agent.z == DONE
            path = np.isin(keys, agent.path_keys()) & ~np.isin(keys, list(robot.skipped)) & ~done
            review = {
                "existing_keys": keys,
                "existing_done": done,
                "to_review": path,
                "review_taken": self.params.retire_taken,
                # a task this robot gave up stands for no other: its view may never be taken
                "stand_ins": ~np.isin(keys, list(robot.skipped)) if self.params.retire_repeats else None,
            }
        job = FrameJob(
            robot.name,
            now,
            None,
            None,
            self._camera_pose(robot, base),
            self._camera_pose(robot, "dr"),
            existing,
            self._teammates_heard(robot, now),
            self._explore_request(robot, now),
            dvl_out_s=robot.dvl_out_s,
            unmodelled_m=robot.unmodelled.take(),
            **review,
        )
        robot.dvl_out_s = 0.0
        self._frames[robot.name] = self._gl.submit(self._draw_frame, snapshot, job)

    def _explore_request(self, robot: _Robot, now: float) -> ExploreRequest | None:
        """The robot's ask for its next looks: only when exploring is on and left to do, and the robot
        is idle (it has no task to fly). Its looks leave a teammate's vicinity to it, but not a teammate
        whose last message said it had nothing left to do: that one will not move on, and gives way to
        a robot that comes to it (``_keep_clear``), so waiting for it would wait for nothing."""
        if not self.params.exploring or robot.explored or robot.activity != "idle":
            return None
        visited = np.array(robot.surveyed, float).reshape(-1, 3)
        busy = self._teammates_heard(robot, now, busy_only=True)
        return ExploreRequest(self._look_params(robot), robot.home_position.copy(), visited, busy)

    def _look_params(self, robot: _Robot) -> FrontierParams:
        """The exploration's settings for ``robot``: level looks, and, for a robot with a DVL, looks
        pitched down and up as far as it pitches for a view (its ``max_pitch_deg``), at most
        ``survey_pitch_deg``."""
        pitch = min(self.params.survey_pitch_deg, robot.max_pitch_deg) if robot.has_dvl else 0.0
        pitches = (0.0, pitch, -pitch) if pitch > 0 else (0.0,)
        return dataclasses.replace(self.explore_params, pitches_deg=pitches)

    def _add_plan(self, now: float) -> None:
        """Give every robot the planner's tasks, as a mission plan each was loaded with, and log them."""
        everyone = tuple(self.auction.agents)  # the robots that start the mission
        for agent in self.auction.agents.values():
            agent.add_tasks(self._planned, known_to=everyone, now_s=now)
        for task in self._planned:
            self._ledger(task, "plan", now)
        planner, summary = self.params.planner, self.plan_summary
        self.writer.event(now, "planned", planner=planner, tasks=len(self._planned), **summary)

    def _ledger(self, task: Task, found_by: str, now: float) -> None:
        """Enter a task in the mission's own ledger (``mission.json``'s tasks)."""
        self.tasks[task.key] = {
            "id": task.key,
            "position": task.position.tolist(),
            "direction": task.direction.tolist(),
            "found_by": found_by,
            "found_at_s": round(now, 3),
            "assigned_to": None,
            "completed": False,
            "completion_time": None,
            "image": None,
        }

    def _use_frame_result(self, robot: _Robot, result: FrameResult, now: float) -> None:
        """A frame's answer, one frame period after it was taken: the visual fix to fly on, and the new
        tasks the robot can reach, minted into its CBBA agent."""
        self.timing["perception"] += result.perception_s
        self.timing["discovery"] += result.discovery_s
        if result.xy_correction is not None:
            # the visual pose of the camera, back to the body: the horizontal offset to fly on
            robot.xy_correction = result.xy_correction
            robot.position_sigma_m = result.position_sigma_m
        robot.visual_updates = result.visual_updates
        if result.frontier is not None:
            robot.frontier, robot.frontier_frame_s = result.frontier, result.time_s
            robot.frontier_held = result.held_for_teammates
            robot.frontier_summary = result.exploration
        if result.faces:  # a keyframe: its review stands for the path as it was then
            robot.covered = {int(key): "taken" for key in result.retired}
            robot.covered.update({int(key): "repeat" for key in result.repeats})
        if self.params.planner != "maptidal":
            return  # a baseline's tasks are planned, not discovered: the frames serve localisation only
        if len(result.gap_tasks):  # explored: views of what its map holds that no known view holds
            self._mint(robot, result.gap_tasks, now, result.time_s, gap=True)
        if result.faces == 0:
            return
        start = time.perf_counter()
        new = result.new_tasks
        if self.params.discovery_mode == "map-aware":
            keep = np.ones(len(new), bool)  # checked on the robot's own map, in its perception
        else:
            keep = reachable(self.scenario.tank, new, self.params.discovery.standoff)
        self._mint(robot, new[keep], now, result.time_s)
        self.writer.event(
            now,
            "keyframe",
            robot=robot.name,
            faces=result.faces,
            new_tasks=len(new),
            reachable=int(keep.sum()),
            frame_s=round(result.time_s, 3),
            **({"rules": result.rules} if result.rules is not None else {}),
        )
        self.timing["allocation"] += time.perf_counter() - start

    def _mint(self, robot: _Robot, rows: np.ndarray, now: float, frame_s: float, gap: bool = False) -> None:
        """Mint task rows ``(N, 6)`` the robot found into its CBBA agent, the ledger and the event log
        (``gap``: views of its map's gaps, :func:`maptidal.map_discovery.gap_views`)."""
        agent = self.auction.agents[robot.index]
        for survey in robot.survey_log:
            if survey["start_s"] <= frame_s <= (survey["end_s"] if survey["end_s"] is not None else now):
                survey["tasks"] += len(rows)  # found on a frame the survey took
        for row in rows:
            task = agent.discover_task(row[:3], row[3:], now_s=now)
            self._ledger(task, robot.name, now)
            self.writer.event(
                now,
                "discovered",
                robot=robot.name,
                task=task.key,
                position=task.position.tolist(),
                direction=task.direction.tolist(),
                frame_s=round(frame_s, 3),
                **({"gap": True} if gap else {}),
            )

    def _advance_activity(self, robot: _Robot, now: float) -> None:
        agent = self.auction.agents[robot.index]
        if robot.activity == "explore":
            if now - robot.route_start_s >= robot.route.duration:
                robot.activity = "idle"
                robot.survey_ended_s = now  # its next looks are worked out on the sweep's views
                if not self.params.exploring:
                    self._has_explored(robot, now, {"why": "not exploring: its first sweep only"})
            return
        if robot.activity == "survey":
            timed_out = now - robot.task_started_s > self.params.task_timeout_s
            if now - robot.route_start_s >= robot.route.duration or timed_out:
                robot.activity = "idle"
                robot.survey_ended_s, robot.frontier = now, None
                robot.survey_log[-1].update(end_s=now, timed_out=timed_out)
                self.writer.event(now, "surveyed", robot=robot.name, timed_out=timed_out)
            return
        if robot.activity == "idle":
            if agent.standing_down:
                return  # lost: it recovers, and flies to no task or look (``_stand_down``)
            key = next((k for k in agent.path_keys() if k not in robot.skipped and agent.is_open(k)), None)
            if key is None:
                self._explore(robot, now)
                return
            if key in robot.covered:
                self._retire(robot, key, now)
                return
            task = next(t for t in agent.tasks if t.key == key)
            needed = view_pitch(task.direction)
            pitch = pitch_to_fly(needed, robot.max_pitch_deg, self.params.direction_tolerance_deg)
            if pitch is None:  # the camera cannot be pointed along the view: give it up, and say why
                reason = (
                    f"the view needs {math.degrees(needed):.0f} deg of pitch; {robot.name} pitches at most "
                    f"{robot.max_pitch_deg:g} deg (tolerance {self.params.direction_tolerance_deg:g} deg)"
                )
                self._give_up(robot, key, now, "declined", reason=reason)
                return
            estimate = self._estimate(robot)
            yaw = math.atan2(task.direction[1], task.direction[0])
            goal = task.position - rotation_from_rpy(0.0, pitch, yaw) @ robot.centre
            robot.route = Route(
                [PoseTrajectory(estimate.position.copy(), estimate.yaw, goal, yaw, self._limits())]
            )
            robot.goal = dataclasses.replace(robot.route.at(robot.route.duration), pitch=pitch)
            robot.view = (np.asarray(task.position, float), np.asarray(task.direction, float))
            robot.route_start_s, robot.task_started_s, robot.task_key = now, now, key
            robot.within_since_s, robot.still_at, robot.task_losses = None, None, 0
            robot.activity = "fly"
            self.tasks.get(key, {})["assigned_to"] = robot.name
            self.writer.event(now, "flying", robot=robot.name, task=key)
            return
        if robot.activity == "fly":
            key = robot.task_key
            if not agent.is_open(key) or key not in agent.path_keys():
                robot.activity = "idle"  # done by another robot, or re-allocated
                self.writer.event(now, "released", robot=robot.name, task=key)
                return
            if key in robot.covered:
                self._retire(robot, key, now)
                return
            # the robot's own check, on its estimate: its camera at the viewpoint, looking along the view
            estimate = self._estimate(robot)
            rotation = rotation_from_rpy(*estimate.rpy)
            believed = check_view(
                estimate.position + rotation @ robot.centre,
                rotation[:, 0],
                *robot.view,
                self.params.position_tolerance_m,
                self.params.direction_tolerance_deg,
            )
            arrived = now - robot.route_start_s >= robot.route.duration
            if arrived and believed.verified:
                robot.within_since_s = robot.within_since_s if robot.within_since_s is not None else now
                if now - robot.within_since_s >= self.params.dwell_s:
                    self._capture(robot, key, now)
            else:
                robot.within_since_s = None
            if self._stalled(robot, estimate.position, arrived and not believed.verified, now):
                self._give_up(robot, key, now, "stalled", still_s=self.params.stall_s)
            elif 0 < self.params.lost_give_up <= robot.task_losses:
                self._give_up(robot, key, now, "gave_up", lost=robot.task_losses)
            elif robot.lost and (taker := self._taker(robot, agent, now)) is not None:
                self._give_up(
                    robot,
                    key,
                    now,
                    "handed_over",
                    to=self.robots_by_index[taker].name,
                    lost_s=round(self._lost_on_the_way_s(robot, now), 2),
                )
            elif now - robot.task_started_s > self.params.task_timeout_s:
                self._give_up(robot, key, now, "timeout")

    def _taker(self, robot: _Robot, agent, now: float) -> int | None:
        """The teammate that ``robot``, lost on its way to its view, hands the view to
        (``lost_hand_over``), or None: one with a DVL whose last message, at most ``peer_fresh_s`` old,
        said it had nothing left to do, and for which the hand-over (a TDMA cycle, then its flight to the
        view from where it was heard, at ``speed_m_s``) costs no more than the time ``robot`` has been
        lost on its way there. Only a teammate with a DVL: one without may be standing down, lost
        itself, and it says it is idle then too, but bids on nothing."""
        if not self.params.lost_hand_over:
            return None
        cycle_s = self.auction.channel.params.tdma_slot_s * len(self.auction.order)
        lost_s = self._lost_on_the_way_s(robot, now)
        view = robot.view[0]
        for peer, idle in sorted(agent.peer_idle.items()):
            heard = agent.peer_positions.get(peer)
            if not (idle and heard is not None and self.robots_by_index[peer].has_dvl):
                continue
            position, heard_s = heard
            flight_s = float(np.linalg.norm(view - position)) / self.params.speed_m_s
            if now - heard_s <= self.params.peer_fresh_s and lost_s >= cycle_s + flight_s:
                return peer
        return None

    def _lost_on_the_way_s(self, robot: _Robot, now: float) -> float:
        """How long ``robot`` has been lost, all told, since it set off for its current view."""
        return robot.time_use.seconds_since("lost", robot.task_started_s, now)

    def _retire(self, robot: _Robot, key: int, now: float) -> None:
        """``robot`` retires task ``key``, which the views the team has taken cover on its map
        (``retire_taken``) or which repeats a task of lower key (``retire_repeats``): done in the
        auction, so that no teammate flies it, with no image; the ledger and a ``retired`` event say so,
        and why ("taken" or "repeat")."""
        self.auction.agents[robot.index].mark_done(key, now)
        why = robot.covered.pop(key, "taken")
        robot.activity = "idle"
        record = self.tasks.setdefault(key, {"id": key})
        record.update(retired=True, retired_by=robot.name, retired_at_s=round(now, 3), retired_why=why)
        self.writer.event(now, "retired", robot=robot.name, task=key, why=why)

    def _give_up(self, robot: _Robot, key: int, now: float, why: str, **fields) -> None:
        """``robot`` gives task ``key`` up for good: it leaves the robot's bundle, so a teammate can win
        it, and the robot is idle; the event ``why`` (declined, stalled, gave_up, timeout) says so."""
        robot.skipped.add(key)
        self.auction.agents[robot.index].give_up(key, now)
        robot.activity = "idle"
        self.writer.event(now, why, robot=robot.name, task=key, **fields)

    def _stalled(self, robot: _Robot, position: np.ndarray, short_of_goal: bool, now: float) -> bool:
        """Whether a robot whose route has ended short of its goal has not moved ``stall_move_m`` for
        ``stall_s`` (MissionParams). A robot giving way to a teammate, or lost, is waiting, not stalled."""
        if not short_of_goal or robot.yielding or robot.lost or self.params.stall_s <= 0:
            robot.still_at = None
            return False
        if robot.still_at is None or np.linalg.norm(position - robot.still_at[0]) > self.params.stall_move_m:
            robot.still_at = (np.array(position, float), now)
            return False
        return now - robot.still_at[1] >= self.params.stall_s

    def _explore(self, robot: _Robot, now: float) -> None:
        """An idle robot with no task: fly to its best next look (``frontier``, worked out on a frame taken
        since its last survey ended) and sweep its camera there as at the start; with no look left worth a
        trip, it has explored. Looks left out only for being near a teammate are waited for, up to
        ``task_timeout_s`` after its last survey (or sweep) ended. A robot without a DVL has explored
        after its first sweep when ``survey_without_dvl`` is off."""
        if not self.params.exploring or robot.explored:
            return
        if not robot.has_dvl and not self.params.survey_without_dvl:
            # the frontier is its teammates' (survey_without_dvl)
            self._has_explored(
                robot, now, {"why": "no DVL: its teammates explore"}, surveys=0, without_dvl=True
            )
            return
        if robot.frontier is None or robot.frontier_frame_s < robot.survey_ended_s:
            return  # its next looks are on their way (``_explore_request``)
        if len(robot.frontier) == 0:
            if robot.frontier_held and now - robot.survey_ended_s <= self.params.task_timeout_s:
                robot.frontier = None  # its looks are by a teammate: wait for it to move on, and ask again
                return
            why = dict(robot.frontier_summary or {})
            if why:
                why["min_gain_m3"] = self._look_params(robot).min_gain_m3
            self._has_explored(robot, now, why, surveys=len(robot.surveyed))
            return
        x, y, z, yaw, pitch, gain, _ = robot.frontier[0]
        look = np.array([x, y, z])  # where the vehicle's centre stands for the look
        estimate = self._estimate(robot)
        width = self.params.survey_sweep_deg if robot.has_dvl else self.params.survey_sweep_no_dvl_deg
        robot.route = survey_route(
            estimate.position.copy(),
            estimate.yaw,
            look,
            yaw,
            math.radians(width),
            self._limits(),
            self._sweep_limits(robot),
        )
        robot.goal, robot.view = None, None
        robot.route_start_s, robot.task_started_s = now, now
        robot.survey_log.append(
            {
                "look": look,
                "pitch": float(pitch),
                "start_s": now,
                "end_s": None,
                "timed_out": False,
                "tasks": 0,
            }
        )
        robot.activity = "survey"
        self.writer.event(
            now,
            "surveying",
            robot=robot.name,
            look=[round(float(v), 3) for v in look],
            yaw_deg=round(math.degrees(yaw), 1),
            pitch_deg=round(math.degrees(pitch), 1),
            gain_m3=round(float(gain), 3),
        )

    def _has_explored(self, robot: _Robot, now: float, why: dict, **fields) -> None:
        """``robot`` has explored: ``why`` (the reason, and the numbers of the search that found no look)
        goes to its ``explored_why`` (mission.json) and, with ``fields``, to its ``explored`` event."""
        robot.explored = True
        robot.explored_why = {"t": round(now, 3), **why}
        self.writer.event(now, "explored", robot=robot.name, **fields, **why)

    def _capture(self, robot: _Robot, key: int, now: float) -> None:
        # the image of this moment, drawn and written on the GL thread while the physics steps on
        name = f"task_{key}_{robot.name}.png"
        self._captures.append(self._gl.submit(self._draw_capture, self.sim.stereo_snapshot(robot.name), name))
        image = self.writer.image_path(name)
        truth = self._camera_pose(robot, "truth")
        # the evaluation's judgement, on the true pose of the camera pair's centre (the robot never sees it)
        body = self.sim.ground_truth(robot.name)
        rotation = rotation_from_quaternion(body["quaternion"])
        judged = check_view(
            np.asarray(body["position"]) + rotation @ robot.centre,
            rotation[:, 0],
            *robot.view,
            self.params.position_tolerance_m,
            self.params.direction_tolerance_deg,
        )
        view = np.r_[truth.position, truth.forward]
        if judged.verified:  # only views that show the task are scored
            self.captured.append(view)
            self.captured_at.append(now)
            self.seen.look(view)
        robot.claimed += 1
        robot.verified += int(judged.verified)
        self.inspections[key] = self.inspections.get(key, 0) + 1
        self.auction.agents[robot.index].mark_done(key, now)
        record = self.tasks.setdefault(key, {"id": key})
        record.update(
            completed=True,
            verified=judged.verified,
            completion_time=round(now, 3),
            image=image,
            assigned_to=robot.name,
        )
        self.writer.event(
            now,
            "done",
            robot=robot.name,
            task=key,
            image=image,
            view=view.tolist(),
            verified=judged.verified,
            position_error_m=round(judged.position_error_m, 4),
            direction_error_deg=round(judged.direction_error_deg, 2),
        )
        robot.activity = "idle"

    def _finished(self) -> bool:
        if any(r.activity == "waiting" for r in self.robots.values()):
            return False
        # a robot standing down (lost) can do nothing of what is left; the others are judged
        able = [r for r in self.robots.values() if r.active and not self._standing_down(r)]
        if not able or not all(r.explored for r in able):
            return False
        open_tasks, known = self._open_tasks(able)
        return known > 0 and open_tasks == 0

    def _standing_down(self, robot: _Robot) -> bool:
        """Whether ``robot`` stands down, lost (``_stand_down``)."""
        return self.auction.agents[robot.index].standing_down

    def _open_tasks(self, alive: list[_Robot]) -> tuple[int, int]:
        """How many of the tasks the live robots know are neither done nor given up, and how many they
        know. A task is out of the team's reach when every live robot has tried it and given up."""
        views = [self.auction.agents[r.index] for r in alive]
        known = np.unique(np.concatenate([a.keys for a in views]))
        done = np.concatenate([a.keys[a.z == DONE] for a in views])
        skipped = np.array(sorted(set.intersection(*(r.skipped for r in alive))), np.int64)
        return int((~np.isin(known, np.r_[done, skipped])).sum()), len(known)

    def ending(self, now: float, finished: bool) -> str:
        """How the mission ended, in one sentence: when it finished its work, or what was left at the
        ``duration_s`` cap (tasks neither done nor given up, robots still exploring or waiting, none
        alive)."""
        alive = [r for r in self.robots.values() if r.active]
        lost = [r.name for r in alive if self._standing_down(r)]
        if finished:
            return (
                f"finished at {now:.1f} s: every robot explored and every known task was done or given up"
                + (f" ({', '.join(lost)} lost, standing down)" if lost else "")
            )
        if not alive:
            return f"stopped at {now:.1f} s: no robot was alive"
        open_tasks, known = self._open_tasks(alive)
        reasons = [f"{open_tasks} of {known} known tasks neither done nor given up"]
        exploring = [r.name for r in alive if not r.explored]
        if exploring:
            reasons.append(f"{', '.join(exploring)} still exploring")
        waiting = [r.name for r in self.robots.values() if r.activity == "waiting"]
        if waiting:
            reasons.append(f"{', '.join(waiting)} not yet launched")
        if lost:
            reasons.append(f"{', '.join(lost)} lost, standing down")
        return f"not finished at the {now:.1f} s cap: " + "; ".join(reasons)

    def inspected_pct(self) -> float:
        """The share of the walls' voxels the captured views have seen so far, occlusion on (%)."""
        return 100.0 * float(self.seen.seen.mean())

    def captured_views(self) -> np.ndarray:
        """The true camera viewpoints ``(N, 6)`` of the verified task images (the ones scored)."""
        return np.array(self.captured).reshape(-1, 6)

    def _sharing(self) -> dict:
        """How fast each robot's discoveries reached a teammate, and what each failed robot's
        discoveries came to (:mod:`maptidal.mission.sharing`)."""
        learned = {
            r.name: self.auction.agents[r.index].learned_s
            for r in self.robots.values()
            if r.index in self.auction.agents
        }
        failed = {r.name: r.failed_at_s for r in self.robots.values() if r.failed_at_s is not None}
        tasks = list(self.tasks.values())
        return {
            "sharing": sharing_table(tasks, learned, failed),
            "tasks_lost": tasks_lost(
                tasks, learned, failed, self.params.position_tolerance_m, self.params.direction_tolerance_deg
            ),
        }

    def document(self, now: float, wall_s: float, finished: bool) -> dict:
        """The ``mission.json`` document as of now."""
        stats = self.auction.channel.stats
        conflicts = self.auction.report(converged=False).conflicts  # tasks in two live bundles now
        return {
            "planner": self.params.planner,
            "discovery": self.params.discovery_mode,
            # a baseline's plan: its viewpoints, and those out of the robots' reach, left out at the start
            **({"plan": self.plan_summary} if self._planned else {}),
            "finished": finished,
            "ending": self.ending(now, finished),
            "realtime_factor": now / wall_s if wall_s > 0 else None,
            "sim_time_s": now,
            "wall_time_s": wall_s,
            "robots": {r.name: r.activity for r in self.robots.values()},
            "inspected_pct": self.inspected_pct(),
            # each robot's distance travelled, thruster energy and time in contact, on the simulated truth
            "odometry": {
                name: {
                    "path_m": odometry.path_m,
                    "thruster_energy_j": odometry.thruster_energy_j,
                    "contact_s": odometry.contact_s,
                }
                for name in self.robots
                for odometry in (self.sim.odometry(name),)
            },
            # claimed: the robot said the task was done; verified: its true view was within tolerance
            "done_by_robot": {
                r.name: {"claimed": r.claimed, "verified": r.verified} for r in self.robots.values()
            },
            # the places each robot flew to to look at its map's frontier (MissionParams.explore)
            "surveys": {r.name: len(r.surveyed) for r in self.robots.values()},
            # how many of them found a task on their frames, and the seconds of those that found none
            "survey_outcomes": {r.name: survey_outcomes(r.survey_log, now) for r in self.robots.values()},
            # when each robot stopped exploring, and why: the numbers of its last search for a look
            "explored": {r.name: r.explored_why for r in self.robots.values()},
            # where each robot's time went: seconds per occupation, and its spans (time_use)
            "time_use": {r.name: r.time_use.as_dict(now) for r in self.robots.values()},
            "comms": {
                "messages": stats.transmissions,
                "bytes": stats.bytes,
                "delivered": stats.delivered,
                "lost": stats.lost,
                "out_of_range": stats.out_of_range,
                "link_down": stats.link_down,
                "half_duplex": stats.half_duplex,
            },
            "allocation_conflicts": conflicts,
            # captures of a task already captured (by this robot or another): what a conflict costs
            "duplicate_inspections": sum(n - 1 for n in self.inspections.values()),
            "tasks": sorted(self.tasks.values(), key=lambda t: t["id"]),
            **self._sharing(),
            # each stage's own time, wherever it ran; "parallel" says what ran beside the loop
            "timing": {**self.timing, "rendering": self.timing["rendering"] + self._frames_render_s},
            "parallel": {
                "perception": self.perception.mode,  # "process": a worker process; "inline": the GL thread
                "beside_the_loop_s": {
                    "rendering": self._frames_render_s,  # the frames perception takes, on the GL thread
                    "perception": self.timing["perception"],
                    "discovery": self.timing["discovery"],
                },
                "loop_waited_s": self._waited_s,  # for a frame's drawing and its answer
            },
            "renderer": self.renderer_description,
        }
