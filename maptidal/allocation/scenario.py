"""Auction scenario files (JSON) for `maptidal allocate`.

Shape (every key; only robots and tasks are required):

    {"robots": [{"id": "r0", "position": [x, y, z], "speed": 0.5, "capabilities": ["camera"],
                 "energy_per_m": 0.0}],
     "tasks": [{"id": "t0", "position": [x, y, z], "direction": [dx, dy, dz], "requires": ["camera"],
                "discovered_by": "r0", "time_s": 0.0}],
     "channel": {"bandwidth_bps": 500, "loss": 0.0, "range_m": 100, "latency_s": 0.0, "seed": 1,
                 "jitter_s": 0.0, "max_frame_bytes": 256, "slot_s": null, "mean_up_s": 0, "mean_down_s": 0,
                 "random_outages_until_s": null,
                 "outages": [{"start_s": 10, "end_s": 40, "robots": ["r0", "r1"]}]},
     "bundle_limit": 0, "task_value": 1000.0,
     "timing": {"failure_timeout_s": 120, "heartbeat_s": 30}, "max_time_s": 7200,
     "events": [{"time_s": 400, "kind": "fail", "robot": "r1"},
                {"time_s": 900, "kind": "join", "robot": {"id": "r9", "position": [x, y, z]}},
                {"time_s": 1600, "kind": "done", "robot": "r0", "task": "t3"}]}

An optional "about" key holds free text. A task without discovered_by is part of the mission plan
every starting robot knows; one with discovered_by appears on that robot at time_s and spreads with
the auction. bundle_limit 0 means no limit. Anything malformed raises AllocationScenarioError naming
the value.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, fields
from pathlib import Path

from maptidal.allocation.agent import AgentParams
from maptidal.allocation.auction import AuctionEvent, AuctionSimulation
from maptidal.allocation.scoring import AuctionParams, RobotProfile
from maptidal.allocation.tasks import MISSION_ORIGIN, Task, TaskError, capability_mask, task_key
from maptidal.checks import check_keys, finite_number, finite_vector, require
from maptidal.comms.channel import ChannelParams, Outage


class AllocationScenarioError(ValueError):
    """An auction scenario that cannot be run; the message names the value."""


def _req(condition: bool, message: str) -> None:
    require(condition, message, AllocationScenarioError)


@dataclass
class AllocationScenario:
    """A parsed auction scenario: the team, the tasks, the channel and the events."""

    robots: list[RobotProfile]
    tasks: list[Task]
    channel: ChannelParams
    auction: AuctionParams
    timing: AgentParams
    events: list[AuctionEvent] = field(default_factory=list)
    task_names: dict[int, str] = field(default_factory=dict)
    max_time_s: float = 7200.0

    def simulation(self) -> AuctionSimulation:
        """A fresh AuctionSimulation of this scenario."""
        return AuctionSimulation(
            self.robots, self.tasks, self.channel, self.auction, self.timing, self.events
        )


def _robot(entry, index: int, where: str) -> RobotProfile:
    _req(isinstance(entry, dict), f"{where} must be an object")
    check_keys(
        entry, {"id", "position", "speed", "capabilities", "energy_per_m"}, where, AllocationScenarioError
    )
    name = entry.get("id", f"r{index}")
    _req(isinstance(name, str) and name, f"{where}.id must be a non-empty string")
    capabilities = entry.get("capabilities", ["camera"])
    _req(isinstance(capabilities, list), f"{where}.capabilities must be a list of names")
    try:
        return RobotProfile(
            name=name,
            index=index,
            position=finite_vector(entry.get("position"), f"{where}.position", 3, AllocationScenarioError),
            speed=finite_number(entry.get("speed", 0.5), f"{where}.speed", 1e-6, AllocationScenarioError),
            capabilities=capability_mask(capabilities),
            energy_per_m=finite_number(
                entry.get("energy_per_m", 0.0), f"{where}.energy_per_m", 0.0, AllocationScenarioError
            ),
        )
    except (TaskError, ValueError) as err:
        raise AllocationScenarioError(f"{where}: {err}") from None


def _channel(table, index_of: dict[str, int]) -> ChannelParams:
    """ChannelParams from the scenario's channel object (outages name robots by id)."""
    _req(isinstance(table, dict), "channel must be an object")
    check_keys(table, {f.name for f in fields(ChannelParams)}, "channel", AllocationScenarioError)
    values = dict(table)
    outages = []
    for k, outage in enumerate(values.pop("outages", [])):
        where = f"channel.outages[{k}]"
        _req(isinstance(outage, dict), f"{where} must be an object")
        check_keys(outage, {"start_s", "end_s", "robots"}, where, AllocationScenarioError)
        pair = outage.get("robots")
        if pair is not None:
            _req(
                isinstance(pair, list) and len(pair) == 2 and all(p in index_of for p in pair),
                f"{where}.robots must name two robots",
            )
            pair = (index_of[pair[0]], index_of[pair[1]])
        start = finite_number(outage.get("start_s"), f"{where}.start_s", 0.0, AllocationScenarioError)
        end = finite_number(outage.get("end_s"), f"{where}.end_s", start, AllocationScenarioError)
        outages.append(Outage(start, end, pair))
    if values.get("random_outages_until_s", 0) is None:
        values["random_outages_until_s"] = math.inf
    for key, value in values.items():
        _req(
            value is None or (isinstance(value, int | float) and not isinstance(value, bool)),
            f"channel.{key} must be a number",
        )
    try:
        return ChannelParams(**values, outages=tuple(outages))
    except (TypeError, ValueError) as err:
        raise AllocationScenarioError(str(err)) from None


def scenario_from_dict(document) -> AllocationScenario:
    """Build and validate an AllocationScenario from a parsed JSON document."""
    _req(isinstance(document, dict), "an auction scenario must be a JSON object")
    allowed = {"robots", "tasks", "channel", "bundle_limit", "task_value", "timing", "max_time_s", "events"}
    allowed.add("about")  # free text describing the scenario
    check_keys(document, allowed, "the scenario", AllocationScenarioError)
    robots_doc, tasks_doc = document.get("robots"), document.get("tasks", [])
    _req(isinstance(robots_doc, list) and robots_doc, "robots must be a non-empty list")
    _req(isinstance(tasks_doc, list), "tasks must be a list")
    events_doc = document.get("events", [])
    _req(isinstance(events_doc, list), "events must be a list")
    joiners = [e.get("robot") for e in events_doc if isinstance(e, dict) and e.get("kind") == "join"]
    robots = [_robot(entry, k, f"robots[{k}]") for k, entry in enumerate(robots_doc)]
    joined = [_robot(entry, len(robots) + k, f"join event robot {k}") for k, entry in enumerate(joiners)]
    _req(len(robots) + len(joined) <= 250, "at most 250 robots")
    index_of = {r.name: r.index for r in (*robots, *joined)}
    _req(len(index_of) == len(robots) + len(joined), "robot ids must be unique")

    tasks, events, task_names, key_of = [], [], {}, {}
    counters: dict[int, int] = {}
    for k, entry in enumerate(tasks_doc):
        where = f"tasks[{k}]"
        _req(isinstance(entry, dict), f"{where} must be an object")
        check_keys(
            entry,
            {"id", "position", "direction", "requires", "discovered_by", "time_s"},
            where,
            AllocationScenarioError,
        )
        name = entry.get("id", f"t{k}")
        _req(
            isinstance(name, str) and name and name not in key_of,
            f"{where}.id must be a unique non-empty string",
        )
        origin = MISSION_ORIGIN
        if "discovered_by" in entry:
            _req(
                entry["discovered_by"] in index_of,
                f"{where}.discovered_by names no robot: {entry['discovered_by']!r}",
            )
            origin = index_of[entry["discovered_by"]]
        counters[origin] = counters.get(origin, -1) + 1
        requires = entry.get("requires", [])
        _req(isinstance(requires, list), f"{where}.requires must be a list of names")
        try:
            task = Task.create(
                task_key(origin, counters[origin]),
                finite_vector(entry.get("position"), f"{where}.position", 3, AllocationScenarioError),
                finite_vector(
                    entry.get("direction", [1.0, 0.0, 0.0]), f"{where}.direction", 3, AllocationScenarioError
                ),
                requires,
                name,
            )
        except TaskError as err:
            raise AllocationScenarioError(f"{where}: {err}") from None
        key_of[name], task_names[task.key] = task.key, name
        if origin == MISSION_ORIGIN:
            tasks.append(task)
        else:
            time_s = finite_number(entry.get("time_s", 0.0), f"{where}.time_s", 0.0, AllocationScenarioError)
            events.append(AuctionEvent(time_s, "discover", robot=origin, task=task))

    joined_iter = iter(joined)
    for k, entry in enumerate(events_doc):
        where = f"events[{k}]"
        _req(isinstance(entry, dict), f"{where} must be an object")
        check_keys(entry, {"time_s", "kind", "robot", "task"}, where, AllocationScenarioError)
        time_s = finite_number(entry.get("time_s"), f"{where}.time_s", 0.0, AllocationScenarioError)
        kind = entry.get("kind")
        if kind == "join":
            events.append(AuctionEvent(time_s, "join", profile=next(joined_iter)))
            continue
        _req(kind in ("fail", "done"), f"{where}.kind must be fail, join or done, got {kind!r}")
        _req(entry.get("robot") in index_of, f"{where}.robot names no robot: {entry.get('robot')!r}")
        robot = index_of[entry["robot"]]
        if kind == "fail":
            events.append(AuctionEvent(time_s, "fail", robot=robot))
        else:
            _req(entry.get("task") in key_of, f"{where}.task names no task: {entry.get('task')!r}")
            events.append(AuctionEvent(time_s, "done", robot=robot, task_key=key_of[entry["task"]]))

    channel = _channel(document.get("channel", {}), index_of)
    try:
        auction = AuctionParams(
            task_value=document.get("task_value", AuctionParams.task_value),
            bundle_limit=document.get("bundle_limit", 0),
        )
        timing = AgentParams(**document.get("timing", {}))
    except (TypeError, ValueError) as err:
        raise AllocationScenarioError(str(err)) from None
    _req(isinstance(auction.bundle_limit, int), "bundle_limit must be an integer (0 = no limit)")
    max_time = finite_number(document.get("max_time_s", 7200.0), "max_time_s", 1e-3, AllocationScenarioError)
    return AllocationScenario(
        robots=robots,
        tasks=tasks,
        channel=channel,
        auction=auction,
        timing=timing,
        events=events,
        task_names=task_names,
        max_time_s=max_time,
    )


def load_scenario(path: str | Path) -> AllocationScenario:
    """Read and validate an auction scenario JSON file."""
    path = Path(path)
    _req(path.is_file(), f"no such scenario file: {path}")
    try:
        document = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise AllocationScenarioError(f"{path}: not valid JSON ({err})") from None
    return scenario_from_dict(document)
