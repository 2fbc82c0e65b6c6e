"""The robots' perception and discovery, run beside the mission's loop (issue [mission]).

Each robot's stereo frame goes to its front end (:class:`maptidal.perception.frontend.FrontEnd`), and at a
keyframe its mesh goes to discovery (:func:`maptidal.discovery.discover`) with the tasks the robot knew
when the frame was taken. The mission takes the answer for a frame at that robot's next frame, one frame
period later, as a robot's companion computer delivers its map with a latency while the vehicle flies on.
That fixed latency is what lets the work run in a process of its own on a second core
(:class:`PerceptionProcess`) and give the same mission, number for number, as running it in the mission's
own process (:class:`InlinePerception`): the answer depends only on the frame, never on when the worker
finished. One thread may submit while another takes results, for different robots (the mission's
drawing thread submits each frame as it is drawn; its loop takes the answers).
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import queue
import threading
import time
import traceback
from dataclasses import dataclass, field

import cv2
import numpy as np

from maptidal.discovery import DiscoveryInputError, DiscoveryParams, discover
from maptidal.executors import release_in_child, signals_held
from maptidal.exploration import FrontierParams, explore, explore_views
from maptidal.map_discovery import RobotMap, discover_on_map, gap_views, views_left_to_take, views_repeated
from maptidal.perception.dense import dense_points
from maptidal.perception.frontend import FrontEnd
from maptidal.perception.recording import CameraPose


@dataclass(frozen=True)
class FrameJob:
    """One robot's stereo frame and what its perception needs with it.

    ``pose`` is the pose source's camera pose (for ``vo``, the dead-reckoned pose it corrects) and
    ``dead_reckoned`` the dead-reckoned camera pose, from which the visual fix's horizontal offset is
    taken; ``existing`` holds the tasks ``(N, 6)`` the robot knew at ``time_s``."""

    robot: str
    time_s: float
    left: np.ndarray
    right: np.ndarray
    pose: CameraPose
    dead_reckoned: CameraPose
    existing: np.ndarray
    # where each teammate's last message put it, and how old that message was: rows (x, y, z, age_s);
    # map-aware discovery leaves a teammate out of the map (maptidal.map_discovery.near_teammates)
    teammates: np.ndarray | None = None
    # a robot with no task and exploring left asks for its next looks (maptidal.exploration)
    explore: ExploreRequest | None = None
    # the keys of ``existing``, which of them are done (their views taken), and which are open on the
    # robot's path: those are reviewed on its map at a keyframe, and the ones the views taken leave
    # nothing to are retired (maptidal.map_discovery.views_left_to_take)
    existing_keys: np.ndarray | None = None
    existing_done: np.ndarray | None = None
    to_review: np.ndarray | None = None
    # whether the views taken (``existing_done``) retire the tasks to review (MissionParams.retire_taken)
    review_taken: bool = True
    # which of ``existing`` may stand for a task to review of higher key, whose view repeats theirs
    # (maptidal.map_discovery.views_repeated; MissionParams.retire_repeats): None, no such review
    stand_ins: np.ndarray | None = None
    # how long since the robot's last frame its dead reckoning ran without its DVL
    # (maptidal.perception.odometry: until its next fix it is then as unsure as a robot without one)
    dvl_out_s: float = 0.0
    # how far the robot may have moved since its last frame that its motion model did not say (pushed,
    # or blocked; maptidal.perception.unmodelled): its front end grows its uncertainty by as much
    unmodelled_m: float = 0.0


@dataclass(frozen=True)
class ExploreRequest:
    """What the next-look search (:func:`maptidal.exploration.explore_views`) needs beyond the map: its
    settings, the robot's launch point (the centre of the region to explore), the places it surveyed
    already ``(M, 3)``, and the teammates whose vicinity its looks leave to them, rows ``(x, y, z, ...)``
    (None: every teammate of the job's ``teammates``)."""

    params: FrontierParams
    launch: np.ndarray
    visited: np.ndarray
    teammates: np.ndarray | None = None


@dataclass(frozen=True)
class FrameResult:
    """What a frame gave: the horizontal offset ``xy_correction`` of the visual pose from the dead
    reckoning and that pose's horizontal standard deviation ``position_sigma_m`` (both None when the
    pose source is ``dr``; with ``truth`` the offset to the true pose, and 0), the front end's count of
    visual fixes so far, the keyframe mesh's face count (0 when the frame made no keyframe, or an empty
    mesh), the new tasks ``(M, 6)`` discovery found on it, and the seconds spent in the front end and in
    discovery."""

    robot: str
    time_s: float
    xy_correction: np.ndarray | None
    position_sigma_m: float | None
    visual_updates: int
    faces: int
    new_tasks: np.ndarray
    perception_s: float
    discovery_s: float
    # map-aware discovery: how many candidates each of its rules removed (MapAwareResult.counts)
    rules: dict[str, int] | None = None
    # the robot's next looks, best first, when the job asked for them: rows (x, y, z, yaw, pitch, gain_m3,
    # utility) of the camera (maptidal.exploration.explore_views); none left: the robot has explored
    frontier: np.ndarray | None = None
    # with no look in ``frontier``: how many were left out only for being near a teammate
    held_for_teammates: int = 0
    # the keys of the reviewed tasks (FrameJob.to_review) whose views the views taken leave nothing to
    retired: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    # with no look left: views of what the map holds that no known view holds
    # (maptidal.map_discovery.gap_views)
    gap_tasks: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    # the search that gave ``frontier``, in numbers (maptidal.exploration.Exploration.summary): with no
    # look, why
    exploration: dict | None = None
    # the keys of the reviewed tasks whose views repeat those of known tasks of lower key
    repeats: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


def perceive(
    front: FrontEnd, job: FrameJob, discovery: DiscoveryParams, robot_map: RobotMap | None = None
) -> FrameResult:
    """Run ``front`` on ``job``'s frame and, at a keyframe, discovery on its mesh: the paper's
    (:func:`maptidal.discovery.discover`), or, given the robot's own ``robot_map``, the map-aware one
    (:func:`maptidal.map_discovery.discover_on_map`), after folding the keyframe into that map; and, when
    the job asks, the robot's next looks on that map (:func:`maptidal.exploration.explore_views`)."""
    start = time.perf_counter()
    record, keyframe = front.process(
        0, job.time_s, job.left, job.right, job.pose, unaided_s=job.dvl_out_s, unmodelled_m=job.unmodelled_m
    )
    correction, sigma = None, None
    if front.pose_source == "vo":
        correction = (record.pose.position - job.dead_reckoned.position)[:2]
        sigma = front.odometry.sigma_m
    elif front.pose_source == "truth":
        # an oracle localisation: the robot flies on the true pose it meshes on, a frame at a time
        correction, sigma = (record.pose.position - job.dead_reckoned.position)[:2], 0.0
    perception_s = time.perf_counter() - start
    faces, new, rules = 0, np.zeros((0, 6)), None
    retired, repeats = np.zeros(0, np.int64), np.zeros(0, np.int64)
    if keyframe is not None and len(keyframe.keyframe.mesh.faces):
        start = time.perf_counter()
        mesh = keyframe.keyframe.mesh
        faces = len(mesh.faces)
        try:
            if robot_map is None:
                new = discover(mesh.vertices, mesh.faces, existing=job.existing, params=discovery).final
            else:
                frame = keyframe.keyframe
                robot_map.add_keyframe(
                    frame.position, frame.landmark_ids, frame.landmarks, teammates=job.teammates
                )
                pose = keyframe.pose
                robot_map.carve_view(
                    pose.position, pose.rotation, front.intrinsics, mesh.vertices, mesh.faces
                )
                surface = None
                if robot_map.params.dense_depth:
                    surface = robot_map.add_surface(
                        pose.position,
                        dense_points(
                            job.left,
                            job.right,
                            front.intrinsics,
                            pose.position,
                            pose.rotation,
                            front.params.dense,
                        ),
                        teammates=job.teammates,
                    )
                found = discover_on_map(
                    robot_map,
                    mesh.vertices,
                    mesh.faces,
                    frame.position,
                    job.existing,
                    discovery,
                    teammates=job.teammates,
                    surface_points=surface,
                )
                new, rules = found.final, found.counts()
                retired, repeats = _review(robot_map, job, discovery)
        except DiscoveryInputError:
            new = np.zeros((0, 6))  # a degenerate keyframe mesh finds nothing; the mission goes on
        discovery_s = time.perf_counter() - start
    else:
        discovery_s = 0.0
    frontier, held_for_teammates, gaps, exploration = None, 0, np.zeros((0, 6)), None
    if job.explore is not None and robot_map is not None:
        start = time.perf_counter()
        request = job.explore
        near = job.teammates if request.teammates is None else request.teammates
        search = explore(robot_map, job.pose.position, request.params, request.launch, near, request.visited)
        frontier, exploration = search.views, search.summary()
        if len(frontier) == 0 and near is not None and len(near):
            # none left but near a teammate: the robot waits for it to move on, it has not explored
            alone = explore_views(
                robot_map, job.pose.position, request.params, request.launch, None, request.visited
            )
            held_for_teammates = len(alone)
        if len(frontier) == 0 and held_for_teammates == 0:
            # explored: what its map holds that no known view holds gets views of its own
            try:
                gaps = gap_views(robot_map, job.pose.position, job.existing, discovery, job.teammates).final
            except DiscoveryInputError:
                gaps = np.zeros((0, 6))
        discovery_s += time.perf_counter() - start
    return FrameResult(
        job.robot,
        job.time_s,
        correction,
        sigma,
        front.odometry.visual_updates + front.odometry.fixes,
        faces,
        new,
        perception_s,
        discovery_s,
        rules,
        frontier,
        held_for_teammates,
        retired,
        gaps,
        exploration,
        repeats,
    )


def _review(robot_map: RobotMap, job: FrameJob, discovery: DiscoveryParams) -> tuple[np.ndarray, np.ndarray]:
    """The keys of the job's tasks to review whose views the done ones leave nothing to, on the map
    (``review_taken``), and those, of the rest, whose views repeat those of its stand-ins of lower key."""
    none = np.zeros(0, np.int64)
    if job.to_review is None or job.existing_keys is None:
        return none, none
    keys = np.asarray(job.existing_keys, np.int64)
    review = np.asarray(job.to_review, bool).copy()
    if not review.any():
        return none, none
    retired = none
    done = None if job.existing_done is None else np.asarray(job.existing_done, bool)
    if job.review_taken and done is not None and done.any():
        left = views_left_to_take(robot_map, job.existing[review], job.existing[done], discovery)
        retired = keys[review][~left]
        review &= ~np.isin(keys, retired)
    repeats = none
    if job.stand_ins is not None and review.any():
        stand_ins = np.asarray(job.stand_ins, bool)
        repeated = views_repeated(
            robot_map, job.existing[review], keys[review], job.existing[stand_ins], keys[stand_ins], discovery
        )
        repeats = keys[review][repeated]
    return retired, repeats


class InlinePerception:
    """Perception in the mission's own process: each job is done when it is submitted."""

    mode = "inline"
    pid = None  # no process of its own

    def __init__(self) -> None:
        self.fronts: dict[str, FrontEnd] = {}
        self.discovery = DiscoveryParams()
        self.maps: dict[str, RobotMap] = {}
        self._results: dict[str, FrameResult] = {}
        self.wait_s = 0.0  # nothing to wait for: the work is done at submit

    def configure(
        self, fronts: dict[str, FrontEnd], discovery: DiscoveryParams, maps: dict[str, RobotMap] | None = None
    ) -> None:
        """The robots' front ends, the discovery parameters and, for map-aware discovery, each robot's own
        map, before the first job."""
        self.fronts, self.discovery, self.maps = fronts, discovery, maps or {}

    def submit(self, job: FrameJob) -> None:
        """Process ``job`` now; its result waits for :meth:`result`."""
        if job.robot in self._results:
            raise RuntimeError(f"{job.robot} already has a frame in perception")
        self._results[job.robot] = perceive(
            self.fronts[job.robot], job, self.discovery, self.maps.get(job.robot)
        )

    def pending(self, robot: str) -> bool:
        """Whether ``robot`` has a frame whose result has not been taken."""
        return robot in self._results

    def result(self, robot: str) -> FrameResult:
        """The result of ``robot``'s frame in perception."""
        return self._results.pop(robot)

    def close(self) -> None:
        """Drop any result not taken."""
        self._results.clear()


def _image_views(blocks: dict, shape: tuple[int, int, int]) -> dict[str, np.ndarray]:
    """Each robot's shared block as a ``(2, H, W, 3)`` uint8 array: its left and right images."""
    return {name: np.frombuffer(block, np.uint8).reshape(2, *shape) for name, block in blocks.items()}


def _serve(connection, blocks: dict, shape: tuple) -> None:
    """The worker process: take the front ends and discovery parameters, then run jobs in the order they
    come and send back each result (or the error). A job's images are in its robot's shared block, which
    the mission leaves alone until the result is back."""
    # Ctrl-C is the mission's to handle: it closes the pipe, and this process then ends on its own
    release_in_child()
    # one OpenCV thread: the second core is this process's, the first the mission's and its renderer's
    cv2.setNumThreads(1)
    images = _image_views(blocks, shape)
    jobs: queue.Queue = queue.Queue()

    def receive() -> None:
        # a thread that always reads, so the mission's send of a frame never waits for a busy worker
        while True:
            try:
                jobs.put(connection.recv())
            except (EOFError, OSError):  # the mission closed the link, or died
                jobs.put(None)
                return

    threading.Thread(target=receive, daemon=True).start()
    setup = jobs.get()
    if setup is None:
        return
    fronts, discovery, maps = setup
    while (job := jobs.get()) is not None:
        pair = images[job.robot]
        job = dataclasses.replace(job, left=pair[0].copy(), right=pair[1].copy())
        try:
            answer = perceive(fronts[job.robot], job, discovery, maps.get(job.robot))
        except Exception:  # sent back whole, raised in the mission
            answer = RuntimeError(
                f"perception of {job.robot}'s frame at {job.time_s:.2f} s failed:\n" + traceback.format_exc()
            )
        try:
            connection.send(answer)
        except (BrokenPipeError, OSError):
            return


class PerceptionProcess:
    """Perception in a worker process of its own (the second core), fed over a pipe, the images through a
    shared block per robot (sent through the pipe they cost the mission several ms a frame, waiting on a
    busy worker). Results come back in the order the jobs were sent; each robot has at most one frame in
    flight. ``robots`` names them and ``image_shape`` is the images' ``(H, W, 3)``. The process starts at
    once, so its imports overlap the simulator's setup; :meth:`configure` then hands it the front ends."""

    mode = "process"

    def __init__(self, robots: list[str], image_shape: tuple[int, int, int]) -> None:
        context = multiprocessing.get_context("spawn")  # no fork of a process holding GL and thread pools
        self._shape = tuple(image_shape)
        size = 2 * int(np.prod(self._shape))
        blocks = {name: context.RawArray("B", size) for name in robots}
        self._images = _image_views(blocks, self._shape)
        self._connection, child = context.Pipe()
        self._process = context.Process(
            target=_serve, args=(child, blocks, self._shape), name="maptidal-perception", daemon=True
        )
        with signals_held():  # a signal while the child reads its start-up data would give it a traceback
            self._process.start()
        child.close()
        self.pid = self._process.pid
        self._in_flight: list[str] = []
        self._results: dict[str, FrameResult] = {}
        self.wait_s = 0.0  # time the mission spent waiting for the worker

    def configure(
        self, fronts: dict[str, FrontEnd], discovery: DiscoveryParams, maps: dict[str, RobotMap] | None = None
    ) -> None:
        """Send the robots' front ends (one per robot named at the start), the discovery parameters and,
        for map-aware discovery, each robot's own map (kept and grown in the worker)."""
        if set(fronts) != set(self._images):
            raise ValueError(f"front ends for {sorted(fronts)}, but the worker serves {sorted(self._images)}")
        self._send((fronts, discovery, maps or {}))

    def submit(self, job: FrameJob) -> None:
        """Send ``job`` to the worker."""
        if job.robot in self._in_flight or job.robot in self._results:
            raise RuntimeError(f"{job.robot} already has a frame in perception")
        if job.left.shape != self._shape or job.right.shape != self._shape:
            raise ValueError(f"images of {job.left.shape} and {job.right.shape}, expected {self._shape}")
        pair = self._images[job.robot]
        pair[0], pair[1] = job.left, job.right
        self._send(dataclasses.replace(job, left=None, right=None))
        self._in_flight.append(job.robot)

    def pending(self, robot: str) -> bool:
        """Whether ``robot`` has a frame whose result has not been taken."""
        return robot in self._in_flight or robot in self._results

    def result(self, robot: str) -> FrameResult:
        """The result of ``robot``'s frame, waiting for the worker if it is not back yet."""
        start = time.perf_counter()
        while robot not in self._results:
            try:
                answer = self._connection.recv()
            except (EOFError, OSError) as error:
                raise self._exited() from error
            if isinstance(answer, Exception):
                raise answer
            self._in_flight.remove(answer.robot)
            self._results[answer.robot] = answer
        self.wait_s += time.perf_counter() - start
        return self._results.pop(robot)

    def _send(self, message) -> None:
        try:
            self._connection.send(message)
        except OSError as error:  # a broken pipe: the worker is gone
            raise self._exited() from error

    def _exited(self) -> RuntimeError:
        self._process.join(timeout=1.0)
        return RuntimeError(f"the perception worker exited (exit code {self._process.exitcode})")

    def close(self) -> None:
        """Stop the worker; results not taken are dropped."""
        self._connection.close()
        self._process.join(timeout=5.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join()


def start_perception(
    robots: list[str], image_shape: tuple[int, int, int], in_process: bool
) -> InlinePerception | PerceptionProcess:
    """A worker process for the perception of ``robots``, or the inline one when ``in_process`` is set or
    the caller is itself a daemonic process (which may not start children, as a multiprocessing pool's
    workers). Call ``configure`` on it before the first job."""
    if in_process or multiprocessing.current_process().daemon:
        return InlinePerception()
    return PerceptionProcess(robots, image_shape)
