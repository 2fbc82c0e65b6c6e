"""CBBA over the acoustic channel: messages, bids, the greedy and brute-force yardsticks, loss and
outages, failures, joins, discoveries and completed tasks."""

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest
from allocation_oracles import brute_force_cost, random_instance
from hypothesis import example, given, settings
from hypothesis import strategies as st
from literal_cbba import literal_cbba

from maptidal.allocation.agent import AgentParams, CBBAAgent
from maptidal.allocation.auction import AuctionEvent, AuctionSimulation
from maptidal.allocation.greedy import sequential_greedy
from maptidal.allocation.messages import (
    DONE,
    NO_WINNER,
    Message,
    MessageError,
    decode,
    encode,
    size_of,
    task_runs,
)
from maptidal.allocation.scoring import AuctionParams, PathGeometry, RobotProfile
from maptidal.allocation.tasks import Task, TaskError, capability_mask, task_key
from maptidal.comms.channel import ChannelParams, Outage

IDEAL = ChannelParams(bandwidth_bps=math.inf, range_m=math.inf)


def run(robots, tasks, channel=IDEAL, auction=None, events=(), timing=None, max_time_s=7200.0):
    simulation = AuctionSimulation(robots, tasks, channel, auction or AuctionParams(), timing, events)
    return simulation, simulation.run(max_time_s)


def assert_consistent(report):
    assert report.converged
    assert report.conflicts == 0
    assert report.disagreements == 0
    assert report.unassigned == []


# ---------------------------------------------------------------- messages
entry_st = st.tuples(
    st.integers(0, 255), st.integers(0, 0xFFFF), st.integers(-2, 249), st.floats(0, 1e6, width=32)
)


@settings(max_examples=60, deadline=None)
@given(
    sender=st.integers(0, 249),
    seq=st.integers(1, 2**32 - 1),
    clocks=st.lists(st.integers(-1, 2**31), max_size=20),
    acks=st.lists(st.tuples(st.integers(0, 249), st.integers(0, 2**32 - 1)), max_size=5),
    entries=st.lists(entry_st, max_size=30),
    n_tasks=st.integers(0, 4),
    position_cm=st.one_of(st.none(), st.tuples(*[st.integers(-32767, 32767)] * 3)),
    goal_cm=st.one_of(st.none(), st.tuples(*[st.integers(-32767, 32767)] * 3)),
    giving_way=st.booleans(),
    idle=st.booleans(),
)
def test_messages_round_trip_exactly(
    sender, seq, clocks, acks, entries, n_tasks, position_cm, goal_cm, giving_way, idle
):
    tasks = [
        Task.create(task_key(3, c), [c * 0.37, -2.5, 1.01], [1, c, -0.5], ("camera",)) for c in range(n_tasks)
    ]
    message = Message(
        sender=sender,
        seq=seq,
        clocks_ms=np.array(clocks, dtype=np.int64),
        acks=acks,
        tasks=tasks,
        keys=np.array([o << 16 | c for o, c, _, _ in entries], dtype=np.int64),
        winners=np.array([w for _, _, w, _ in entries], dtype=np.int64),
        bids=np.array([b for *_, b in entries]),
        position=None if position_cm is None else tuple(v / 100.0 for v in position_cm),
        goal=None if goal_cm is None else tuple(v / 100.0 for v in goal_cm),
        giving_way=giving_way,
        idle=idle,
    )
    data = encode(message)
    assert len(data) == size_of(len(clocks), len(acks), n_tasks, len(entries))
    assert decode(data).position == message.position  # to the centimetre, or unknown
    assert decode(data).goal == message.goal
    assert decode(data).giving_way == giving_way and decode(data).idle == idle
    back = decode(data)
    assert (back.sender, back.seq, back.acks) == (sender, seq, acks)
    assert back.clocks_ms.tolist() == clocks
    assert [(t.key, t.position_cm, t.direction_code, t.requires) for t in back.tasks] == [
        (t.key, t.position_cm, t.direction_code, t.requires) for t in tasks
    ]
    assert back.keys.tolist() == message.keys.tolist()
    assert back.winners.tolist() == message.winners.tolist()
    assert back.bids.tolist() == message.bids.tolist()


task_st = st.tuples(
    st.integers(0, 3),  # origin: few, so that runs form and break
    st.integers(0, 0xFFFF),
    st.tuples(*[st.integers(-32767, 32767)] * 3),
    st.tuples(st.integers(0, 4095), st.integers(0, 4095)),
    st.integers(0, 2),
)


@settings(max_examples=80, deadline=None)
@given(
    raw=st.lists(task_st, max_size=40, unique_by=lambda t: (t[0], t[1])),
    clustered=st.booleans(),
)
def test_task_records_in_runs_round_trip_exactly(raw, clustered):
    # clustered: consecutive counters near each other, as a robot's burst of discoveries is
    if clustered:
        raw = [(o, 100 + n, (n * 37, -n * 11, 50), d, 1) for n, (o, _, _, d, _) in enumerate(raw)]
    tasks = [Task(o << 16 | c, p, d, r) for o, c, p, d, r in raw]
    message = Message(
        1, 2, np.array([0, 5]), [], tasks, np.array([], np.int64), np.array([], np.int64), np.array([])
    )
    data = encode(message)
    back = decode(data).tasks
    key = sorted(tasks, key=lambda t: t.key)
    assert [(t.key, t.position_cm, t.direction_code, t.requires) for t in back] == [
        (t.key, t.position_cm, t.direction_code, t.requires) for t in key
    ]
    # the size: 11 bytes a run plus 8 a task, the runs counted by hand from where a run must break
    breaks = sum(
        1
        for a, b in itertools.pairwise(key)
        if b.key != a.key + 1 or b.requires != a.requires or b.key >> 16 != a.key >> 16
    )
    n_runs_at_least = (breaks + 1) if key else 0
    runs = task_runs(tasks)
    assert len(runs) >= n_runs_at_least
    assert len(data) == size_of(2, 0, len(tasks), 0, len(runs))
    assert len(data) == size_of(2, 0, 0, 0, 0) + 11 * len(runs) + 8 * len(tasks)


def _run_of(offsets_cm, requires=(1, 1, 1), counters=(0, 1, 2), origins=(0, 0, 0)):
    return [
        Task(o << 16 | c, tuple(int(v) for v in np.add((100, -200, 50), off)), (7, 9), r)
        for off, r, c, o in zip(offsets_cm, requires, counters, origins, strict=True)
    ]


@pytest.mark.parametrize(
    ("tasks", "n_runs"),
    [
        (_run_of([(0, 0, 0), (4095, -4095, 0), (-4095, 4095, 4095)]), 1),  # the offset's whole range
        (_run_of([(0, 0, 0), (4096, 0, 0), (4096, 0, 0)]), 2),  # 4096 cm from the base: a new run
        (_run_of([(0, 0, 0), (0, 0, -4096), (0, 0, 0)]), 3),
        (_run_of([(0, 0, 0)] * 3, requires=(1, 3, 3)), 2),
        (_run_of([(0, 0, 0)] * 3, counters=(0, 1, 3)), 2),  # a gap in the counters
        (_run_of([(0, 0, 0)] * 3, origins=(0, 0, 1)), 2),
        ([Task(c, (0, 0, 0), (0, 0), 1) for c in range(256)], 2),  # a run's count is a byte
    ],
)
def test_task_runs_break_where_the_format_says(tasks, n_runs):
    assert len(task_runs(tasks)) == n_runs
    message = Message(
        0, 1, np.array([0]), [], tasks, np.array([], np.int64), np.array([], np.int64), np.array([])
    )
    back = decode(encode(message)).tasks
    assert [(t.key, t.position_cm) for t in back] == [(t.key, t.position_cm) for t in tasks]


def _with_crc(body: bytes) -> bytes:
    import binascii
    import struct

    return body + struct.pack("<H", binascii.crc_hqx(body, 0xFFFF))


def test_a_task_record_with_its_spare_bit_set_or_an_empty_run_is_malformed():
    tasks = _run_of([(0, 0, 0), (5, 5, 5), (9, 9, 9)])
    message = Message(
        0, 1, np.array([0]), [], tasks, np.array([], np.int64), np.array([], np.int64), np.array([])
    )
    body = bytearray(encode(message)[:-2])
    record_end = len(body) - 2  # the entries' count (zero) follows the last record
    spare = bytearray(body)
    spare[record_end - 1] |= 0x80  # bit 63 of the last record
    with pytest.raises(MessageError, match="spare bit"):
        decode(_with_crc(bytes(spare)))
    empty = bytearray(body)
    count_at = record_end - 3 * 8 - 11 + 3  # origin u8, counter u16, then the count
    empty[count_at] = 0
    with pytest.raises(MessageError) as caught:
        decode(_with_crc(bytes(empty)))
    assert caught.value.reason == "malformed"


def _a_message() -> bytes:
    return encode(
        Message(
            1, 7, np.array([5, 9]), [(0, 3)], [], np.array([task_key(255, 0)]), np.array([1]), np.array([2.5])
        )
    )


@pytest.mark.parametrize(
    ("mangle", "reason"),
    [
        (lambda d: d[:-5], "checksum"),
        (lambda d: d[:3], "truncated"),
        (lambda d: bytes([d[0], d[1] ^ 0xFF]) + d[2:], "checksum"),
        (lambda d: b"", "truncated"),
    ],
)
def test_damaged_messages_are_rejected_with_a_reason(mangle, reason):
    with pytest.raises(MessageError) as caught:
        decode(mangle(_a_message()))
    assert caught.value.reason == reason


def test_status_bits_beyond_giving_way_and_idle_are_malformed():
    body = bytearray(_a_message()[:-2])
    status_at = 7 + 12  # after the header (version, sender, seq u32, n_clocks), the position and goal
    assert body[status_at] == 0
    for bad in (0x04, 0x80, 0x07):
        body[status_at] = bad
        with pytest.raises(MessageError) as caught:
            decode(_with_crc(bytes(body)))
        assert caught.value.reason == "malformed"
    # giving way is bit 0, idle bit 1, as written on the wire
    for bits, flags in ((0x01, (True, False)), (0x02, (False, True)), (0x03, (True, True))):
        body[status_at] = bits
        decoded = decode(_with_crc(bytes(body)))
        assert (decoded.giving_way, decoded.idle) == flags


def test_wrong_version_is_rejected_even_with_a_good_checksum():
    import binascii
    import struct

    body = bytearray(_a_message()[:-2])
    body[0] = 1  # the version before positions
    data = bytes(body) + struct.pack("<H", binascii.crc_hqx(bytes(body), 0xFFFF))
    with pytest.raises(MessageError) as caught:
        decode(data)
    assert caught.value.reason == "version"


def _agent_with_tasks(index=0, n=3):
    robot = RobotProfile(f"r{index}", index, [0.0, 0.0, -1.0])
    agent = CBBAAgent(robot)
    agent.add_tasks([Task.create(task_key(255, j), [j + 1.0, 0, -1]) for j in range(n)], known_to=(0, 1))
    agent.clocks[[0, 1]] = 0
    return agent


@pytest.mark.parametrize(
    "data",
    [
        b"\x01\x02garbage",
        _a_message()[:-1],
        bytes(b ^ 0x5A if n == 10 else b for n, b in enumerate(_a_message())),  # one flipped byte
    ],
)
def test_bad_messages_leave_the_state_untouched_and_are_counted(data):
    agent = _agent_with_tasks()
    agent.build_bundle(0.0)
    before = (agent.y.copy(), agent.z.copy(), list(agent.bundle), agent.clocks.copy())
    assert not agent.receive(data, 1.0)
    assert sum(agent.stats.rejected.values()) == 1
    after = (agent.y, agent.z, agent.bundle, agent.clocks)
    assert all(np.array_equal(a, b) for a, b in zip(before, after, strict=True))


def test_replayed_and_stale_messages_are_rejected():
    sender, receiver = _agent_with_tasks(1), _agent_with_tasks(0)
    sender.build_bundle(0.0)
    first = sender.make_message(1.0)
    receiver.receive(first, 1.5)
    receiver.build_bundle(2.0)
    sender.receive(receiver.make_message(2.0), 2.5)
    second = sender.make_message(3.0)
    assert receiver.receive(second, 3.5)
    state = (receiver.y.copy(), receiver.z.copy())
    assert not receiver.receive(first, 4.0)  # an old one arriving late, or an attacker's replay
    assert not receiver.receive(second, 4.0)
    assert receiver.stats.rejected["replayed"] == 2
    assert np.array_equal(state[0], receiver.y) and np.array_equal(state[1], receiver.z)


def test_winner_outside_the_robot_range_is_malformed():
    agent = _agent_with_tasks()
    data = encode(
        Message(
            1, 1, np.array([0, 0]), [], [], np.array([task_key(255, 0)]), np.array([252]), np.array([1.0])
        )
    )
    assert not agent.receive(data, 1.0)
    assert agent.stats.rejected["malformed"] == 1


# ---------------------------------------------------------------- tasks and bids
@settings(max_examples=100, deadline=None)
@given(
    position=st.lists(st.floats(-300, 300), min_size=3, max_size=3),
    direction=st.lists(st.floats(-1, 1), min_size=3, max_size=3).filter(lambda d: np.linalg.norm(d) > 1e-3),
)
def test_quantised_poses_are_within_a_centimetre_and_half_a_degree(position, direction):
    task = Task.create(0, position, direction)
    assert np.abs(task.position - position).max() <= 0.005 + 1e-9
    unit = np.asarray(direction) / np.linalg.norm(direction)
    angle = math.degrees(math.acos(np.clip(unit @ task.direction, -1, 1)))
    assert angle < 0.5


@pytest.mark.parametrize(
    "bad",
    [
        {"position": [0, 0, float("nan")]},
        {"position": [400, 0, 0]},
        {"direction": [0, 0, 0]},
        {"requires": ["laser"]},
    ],
)
def test_bad_tasks_are_refused(bad):
    args = {"position": [1, 2, 3], "direction": [1, 0, 0], "requires": ()} | bad
    with pytest.raises(TaskError):
        Task.create(1, **args)


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 8), m=st.integers(0, 6))
def test_best_insertion_matches_trying_every_position(seed, n, m):
    rng = np.random.default_rng(seed)
    points = rng.uniform(-5, 5, size=(n + m, 3))
    geometry = PathGeometry(rng.uniform(-5, 5, 3), points)
    path = list(range(n, n + m))
    delta, position = geometry.insertion(path)
    base = geometry.path_length(path)
    for j in range(n):
        tries = [geometry.path_length(path[:p] + [j] + path[p:]) - base for p in range(m + 1)]
        assert delta[j] == pytest.approx(min(tries), abs=1e-9)
        assert tries[position[j]] == pytest.approx(min(tries), abs=1e-9)


def test_bid_warping_keeps_bundle_bids_from_rising_although_raw_scores_rise():
    # two tasks in a row away from the robot: the second is cheap once the first is in the path
    robot = RobotProfile("r0", 0, [0.0, 0.0, 0.0], speed=0.5)
    agent = CBBAAgent(robot, AuctionParams(task_value=30.0))
    agent.add_tasks([Task.create(1, [10.0, 0, 0]), Task.create(2, [10.5, 0, 0])])
    agent.build_bundle()
    assert [agent.tasks[j].key for j in agent.bundle] == [1, 2]
    assert agent.bundle_bids[0] == pytest.approx(30.0 - 10.0 / 0.5)
    # the raw score of the second task, 30 - 0.5 / 0.5 = 29, exceeds the first bid: not DMG; warped to 10
    assert agent.bundle_bids[1] == agent.bundle_bids[0]


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n_robots=st.integers(1, 4), n_tasks=st.integers(1, 15))
def test_bundle_bids_never_increase(seed, n_robots, n_tasks):
    robots, tasks = random_instance(n_robots, n_tasks, seed, heterogeneous=True)
    simulation, _ = run(robots, tasks)
    for agent in simulation.agents.values():
        assert all(a >= b for a, b in zip(agent.bundle_bids, agent.bundle_bids[1:], strict=False))


# ---------------------------------------------------------------- yardsticks
@pytest.mark.parametrize(("n_robots", "n_tasks"), [(2, 20), (3, 7), (5, 50), (10, 100)])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_converged_assignment_equals_sequential_greedy(n_robots, n_tasks, seed):
    robots, tasks = random_instance(n_robots, n_tasks, seed)
    _, report = run(robots, tasks)
    assert_consistent(report)
    greedy = sequential_greedy(robots, tasks, AuctionParams())
    assert report.paths == greedy.paths


@pytest.mark.parametrize("seed", range(4))
def test_greedy_equality_holds_for_heterogeneous_teams_with_a_bundle_limit(seed):
    robots, tasks = random_instance(4, 24, seed, heterogeneous=True)
    auction = AuctionParams(bundle_limit=5)
    _, report = run(robots, tasks, ChannelParams(seed=seed), auction)
    assert report.converged and report.conflicts == 0 and report.disagreements == 0
    greedy = sequential_greedy(robots, tasks, auction)
    assert report.paths == greedy.paths
    assert all(len(p) <= 5 for p in report.paths.values())
    needs_tool = {t.key for t in tasks if t.requires & capability_mask(["tool"])}
    for index, path in report.paths.items():
        if not robots[index].capabilities & capability_mask(["tool"]):
            assert not needs_tool & set(path)


@pytest.mark.parametrize("seed", range(3))
def test_literal_cbba_reaches_the_same_assignment(seed):
    robots, tasks = random_instance(4, 14, seed)
    paths, _ = literal_cbba(robots, tasks)
    _, report = run(robots, tasks)
    assert report.paths == paths


def test_path_quality_against_brute_force_on_3_robots_and_7_tasks():
    ratios = []
    for seed in range(8):
        robots, tasks = random_instance(3, 7, seed)
        _, report = run(robots, tasks)
        cost = sum(r.cost_per_m * report.lengths[r.index] for r in robots)
        ratios.append(cost / brute_force_cost(robots, tasks))
    assert min(ratios) >= 1 - 1e-9  # nothing beats the optimum
    assert np.mean(ratios) <= 1.15, ratios  # measured: mean 1.03, worst 1.12 over 12 seeds
    print(f"CBBA / brute-force travel cost: {np.round(ratios, 3).tolist()}")


# ---------------------------------------------------------------- traffic
def test_two_robots_twenty_tasks_converge_under_one_kilobyte():
    robots, tasks = random_instance(2, 20, 11)
    _, report = run(robots, tasks, ChannelParams(bandwidth_bps=500))
    assert_consistent(report)
    assert report.bytes < 1000, report.bytes


def test_only_changes_are_sent():
    robots, tasks = random_instance(3, 12, 4)
    simulation, report = run(robots, tasks, ChannelParams())
    full_state = size_of(3, 0, 0, 12)
    # after the first exchange, later messages carry deltas and acks, not the full table
    later = [n for t, _, n in report.transmissions[3:]]
    assert later and max(later) < full_state
    # a quiet team sends nothing but heartbeats
    agent = simulation.agents[0]
    assert agent.make_message(report.end_time_s + 0.1) is None
    heartbeat = agent.make_message(report.end_time_s + agent.params.heartbeat_s + 1)
    assert heartbeat is not None and decode(heartbeat).keys.size == 0


def test_frames_respect_the_modem_limit():
    robots, tasks = random_instance(3, 60, 2)
    channel = ChannelParams(bandwidth_bps=800, max_frame_bytes=128)
    _, report = run(robots, tasks, channel)
    assert_consistent(report)
    assert report.max_message_bytes <= 128


# ---------------------------------------------------------------- loss, outages, dynamics
@settings(max_examples=20, deadline=None)
@given(
    seed=st.integers(0, 100_000),
    n_robots=st.integers(2, 5),
    n_tasks=st.integers(1, 20),
    outages=st.lists(st.tuples(st.floats(0, 300), st.floats(5, 120), st.booleans()), max_size=3),
    mean_up=st.floats(10, 60),
    mean_down=st.floats(5, 40),
    jitter=st.floats(0, 3),
)
def test_lossy_intermittent_links_still_converge_once_healthy(
    seed, n_robots, n_tasks, outages, mean_up, mean_down, jitter
):
    robots, tasks = random_instance(n_robots, n_tasks, seed)
    channel = ChannelParams(
        loss=0.3,
        seed=seed,
        jitter_s=jitter,
        mean_up_s=mean_up,
        mean_down_s=mean_down,
        random_outages_until_s=400.0,
        outages=tuple(Outage(s, s + d, None if everyone else (0, 1)) for s, d, everyone in outages),
    )
    _, report = run(robots, tasks, channel, max_time_s=20_000)
    assert_consistent(report)
    held = [k for path in report.paths.values() for k in path]
    assert sorted(held) == sorted(t.key for t in tasks)  # each task held exactly once


def test_failed_robot_tasks_are_reassigned_within_bounded_exchanges():
    robots, tasks = random_instance(4, 24, 5)
    timing = AgentParams(failure_timeout_s=60.0, heartbeat_s=20.0)
    _, before = run(robots, tasks, ChannelParams(), timing=timing)
    victim = max(before.paths, key=lambda i: len(before.paths[i]))
    fail_at = before.end_time_s + 10.0
    simulation, report = run(
        robots, tasks, ChannelParams(), events=[AuctionEvent(fail_at, "fail", robot=victim)], timing=timing
    )
    assert_consistent(report)
    assert victim not in report.paths
    assert sorted(k for p in report.paths.values() for k in p) == sorted(t.key for t in tasks)
    survivors = [r for r in robots if r.index != victim]
    assert report.paths == sequential_greedy(survivors, tasks, AuctionParams()).paths
    # exchanges after the survivors notice: each released task costs at most a few broadcasts
    noticed = fail_at + timing.failure_timeout_s
    after = [t for t, _, _ in report.transmissions if t >= noticed]
    released = len(before.paths[victim])
    cycles = (report.sim_time_s - noticed) / (simulation.channel.params.tdma_slot_s * len(robots))
    assert len(after) <= 2 * len(survivors) * (released + 2), (len(after), released)
    assert cycles <= released + 2


def test_joining_robot_learns_the_tasks_and_takes_its_share():
    robots, tasks = random_instance(3, 18, 8)
    newcomer = RobotProfile("r9", 3, [10.0, 5.0, -1.5])
    _, report = run(robots, tasks, ChannelParams(), events=[AuctionEvent(200.0, "join", profile=newcomer)])
    assert_consistent(report)
    assert report.paths[3]
    assert report.paths == sequential_greedy([*robots, newcomer], tasks, AuctionParams()).paths


def test_discovered_tasks_spread_and_are_allocated():
    robots, tasks = random_instance(3, 6, 9)
    found = [Task.create(task_key(1, c), [2.0 + c, 3.0, -1.0], [0, 1, 0]) for c in range(4)]
    events = [AuctionEvent(100.0 + 30 * c, "discover", robot=1, task=t) for c, t in enumerate(found)]
    simulation, report = run(robots, tasks, ChannelParams(loss=0.2, seed=2), events=events)
    assert_consistent(report)
    for agent in simulation.agents.values():
        assert {t.key for t in found} <= {t.key for t in agent.tasks}
    assert report.paths == sequential_greedy(robots, [*tasks, *found], AuctionParams()).paths


def test_completed_task_leaves_the_auction_everywhere():
    robots, tasks = random_instance(3, 10, 1)
    _, before = run(robots, tasks, ChannelParams())
    holder = next(i for i, p in before.paths.items() if p)
    finished = before.paths[holder][0]
    events = [AuctionEvent(before.end_time_s + 5, "done", robot=holder, task_key=finished)]
    simulation, report = run(robots, tasks, ChannelParams(loss=0.2, seed=4), events=events)
    assert_consistent(report)
    assert all(finished not in p for p in report.paths.values())
    assert all(a.winners()[finished] == DONE for a in simulation.agents.values())


def test_a_done_task_stays_done_when_a_peer_that_has_not_heard_still_bids_on_it():
    """Found by the closed-loop mission: a robot marked a task done, then a message from a peer that had
    not heard yet, with no DONE entry in it but a bid on that task (the peer's view: robot 0 wins at
    2.5, or the peer itself wins), made the robot take the task back and inspect it again."""
    for winner in (0, 1):
        mine = _agent_with_tasks(0)
        mine.build_bundle(0.0)
        key = mine.tasks[mine.bundle[0]].key
        assert mine.mark_done(key, 1.0)
        stale = Message(
            1, 1, np.array([900, 1500]), [], [], np.array([key]), np.array([winner]), np.array([9.5])
        )
        assert mine.receive(encode(stale), 2.0)
        mine.build_bundle(2.5)
        assert mine.winners()[key] == DONE and key not in mine.path_keys(), winner


def test_unreachable_capability_is_reported_infeasible_not_unassigned():
    robots, tasks = random_instance(2, 5, 3)
    tasks[0] = replace(tasks[0], requires=capability_mask(["sonar"]))
    _, report = run(robots, tasks)
    assert report.infeasible == [tasks[0].key]
    assert report.unassigned == [] and report.conflicts == 0


def test_runs_are_deterministic_for_a_seed():
    robots, tasks = random_instance(4, 15, 6)
    channel = ChannelParams(
        loss=0.3, seed=12, jitter_s=2.0, mean_up_s=30, mean_down_s=10, random_outages_until_s=200
    )
    first, second = run(robots, tasks, channel)[1], run(robots, tasks, channel)[1]
    assert first.transmissions == second.transmissions
    assert first.paths == second.paths


def test_no_winner_is_never_robot_zero():
    agent = _agent_with_tasks(index=1)
    assert NO_WINNER != 0 and (agent.z == NO_WINNER).all()


def test_multi_hop_chain_relays_tasks_and_liveness():
    """Robots in a line, each hearing only its neighbours: tasks found at one end reach the other end,
    and relayed clocks keep robots that never hear each other directly from declaring each other failed."""
    robots = [RobotProfile(f"r{i}", i, [80.0 * i, 0.0, -2.0]) for i in range(4)]
    tasks = [Task.create(task_key(255, j), [80.0 * (j % 4) + 3.0 + j, 2.0, -2.0]) for j in range(8)]
    found = Task.create(task_key(0, 0), [-5.0, 0.0, -2.0])
    events = [AuctionEvent(700.0, "discover", robot=0, task=found)]
    channel = ChannelParams(range_m=100.0, bandwidth_bps=500, loss=0.1, seed=3)
    simulation, report = run(robots, tasks, channel, events=events, timing=AgentParams(120.0, 30.0))
    assert_consistent(report)
    assert all(not agent.failed for agent in simulation.agents.values())
    assert found.key in {t.key for t in simulation.agents[3].tasks}
    assert report.paths == sequential_greedy(robots, [*tasks, found], AuctionParams()).paths


def test_each_robot_keeps_what_its_neighbours_last_bid():
    # three robots 10 m apart, each with three tasks next to it: each wins its own
    robots = [RobotProfile(f"r{i}", i, [10.0 * i, 0.0, -1.0]) for i in range(3)]
    tasks = [Task.create(task_key(255, j), [10.0 * (j % 3) + 0.3 * j, 1.0, -1.0]) for j in range(9)]
    simulation, report = run(robots, tasks, ChannelParams())
    agent = simulation.agents[0]
    for peer in (1, 2):
        assert len(report.paths[peer]) == 3
        said = agent.neighbour_bids(peer)
        for key in report.paths[peer]:
            winner, bid, heard_s = said[key]
            assert winner == peer and bid > 0 and 0 < heard_s <= report.end_time_s


event_st = st.tuples(
    st.floats(0, 600), st.sampled_from(["fail", "join", "discover", "done"]), st.integers(0, 10**6)
)


@settings(max_examples=25, deadline=None)
@example(  # a robot joins after a task is done; the entry saying so reached it before the task's record
    seed=2,
    n_robots=2,
    n_tasks=2,
    raw_events=[(0.0, "done", 0), (1.0, "join", 0)],
    loss=0.3125,
    bundle_limit=0,
)
@given(
    seed=st.integers(0, 100_000),
    n_robots=st.integers(2, 5),
    n_tasks=st.integers(2, 20),
    raw_events=st.lists(event_st, min_size=1, max_size=5),
    loss=st.floats(0, 0.4),
    bundle_limit=st.sampled_from([0, 3, 6]),
)
def test_random_failures_joins_discoveries_and_completions_end_consistent(
    seed, n_robots, n_tasks, raw_events, loss, bundle_limit
):
    """Mixed dynamics over a lossy, intermittent channel (this test found a value that changed and
    changed back while unacknowledged being taken as already held by a peer, and, in session 11, an
    ack crediting a joiner with a done entry it had dropped for want of the task's record)."""
    robots, tasks = random_instance(n_robots, n_tasks, seed, heterogeneous=seed % 2 == 0)
    events, next_index, counters = [], n_robots, {}
    for time_s, kind, pick in raw_events:
        robot = pick % n_robots
        if kind == "fail":
            events.append(AuctionEvent(time_s, "fail", robot=robot))
        elif kind == "join":
            where = np.random.default_rng(pick).uniform([0, 0, -3], [20, 10, 0])
            kit = capability_mask(["camera", "tool"])
            profile = RobotProfile(f"j{next_index}", next_index, where, capabilities=kit)
            events.append(AuctionEvent(time_s, "join", profile=profile))
            next_index += 1
        elif kind == "discover":
            counters[robot] = counters.get(robot, -1) + 1
            where = np.random.default_rng(pick).uniform([0, 0, -3], [20, 10, 0])
            events.append(
                AuctionEvent(
                    time_s, "discover", robot=robot, task=Task.create(task_key(robot, counters[robot]), where)
                )
            )
        else:
            events.append(AuctionEvent(time_s, "done", robot=robot, task_key=tasks[pick % n_tasks].key))
    channel = ChannelParams(
        loss=loss, seed=seed, jitter_s=1.0, mean_up_s=40, mean_down_s=10, random_outages_until_s=700
    )
    auction = AuctionParams(bundle_limit=bundle_limit)
    _, report = run(robots, tasks, channel, auction, events, AgentParams(90.0, 30.0), max_time_s=30_000)
    assert report.converged and report.conflicts == 0 and report.disagreements == 0
    held = [k for path in report.paths.values() for k in path]
    assert len(held) == len(set(held))
    if bundle_limit == 0 and report.alive:
        assert report.unassigned == []


def test_a_value_that_returns_to_its_old_value_before_an_ack_is_still_sent():
    """Robot 2 tells robot 0 it holds two tasks, then loses the first to robot 3, which releases the
    second back to 'nobody' (the value robot 0 had before). Robot 0 never acknowledged the first
    message, so robot 2 cannot assume robot 0 still has 'nobody'; it must send the release."""
    tasks = [Task.create(task_key(255, 0), [1.0, 0, 0]), Task.create(task_key(255, 1), [2.0, 0, 0])]
    robots = {i: RobotProfile(f"r{i}", i, [0.0, 0.0, 0.0]) for i in (0, 2)}
    agents = {i: CBBAAgent(r) for i, r in robots.items()}
    for agent in agents.values():
        agent.add_tasks(tasks, known_to=(0, 2, 3))
        agent.clocks[[0, 2, 3]] = 0
    holder, listener = agents[2], agents[0]
    holder.build_bundle(1.0)
    assert [holder.tasks[j].key for j in holder.bundle] == [tasks[0].key, tasks[1].key]
    listener.receive(holder.make_message(1.0), 1.1)
    assert listener.winners()[tasks[1].key] == 2
    outbid = Message(
        3, 1, np.array([0, 0, 0, 2000]), [], [], np.array([tasks[0].key]), np.array([3]), np.array([5000.0])
    )
    holder.receive(encode(outbid), 2.0)
    assert holder.winners()[tasks[1].key] == NO_WINNER  # released after losing the first entry
    update = holder.make_message(3.0)
    assert tasks[1].key in decode(update).keys.tolist()
    listener.receive(update, 3.1)
    assert listener.winners()[tasks[1].key] != 2


def test_a_task_only_a_failed_robot_knew_is_reported_lost_not_unassigned():
    robots, tasks = random_instance(3, 4, 2)
    secret = Task.create(task_key(2, 0), [5.0, 5.0, -1.0])
    events = [AuctionEvent(0.0, "fail", robot=2), AuctionEvent(0.0, "discover", robot=2, task=secret)]
    _, report = run(robots, tasks, ChannelParams(), events=sorted(events, key=lambda e: e.kind))
    assert report.lost == [secret.key]
    assert report.unassigned == [] and report.conflicts == 0


@pytest.mark.parametrize("seed", [3, 8, 21])
def test_a_task_given_up_passes_to_another_robot_as_if_its_holder_could_not_do_it(seed):
    """give_up: robot 0 stops bidding on the first task of its path mid-mission. The team settles on the
    allocation the sequential greedy gives when that task needs a tool robot 0 lacks, and robot 0 never
    takes the task again."""
    robots, tasks = random_instance(3, 12, seed)
    simulation = AuctionSimulation(robots, tasks, IDEAL, AuctionParams())
    simulation.advance_to(400.0)
    quitter = simulation.agents[0]
    key = quitter.path_keys()[0]
    assert quitter.give_up(key, 400.0) and not quitter.give_up(key, 401.0)
    simulation.advance_to(1200.0)
    report = simulation.report(converged=True)
    assert report.conflicts == 0 and report.disagreements == 0
    assert key not in report.paths[0] and any(key in path for path in report.paths.values())
    # the reference: the same team, with the given-up task needing a tool only robots 1 and 2 carry
    tool = capability_mask(["camera", "tool"])
    equipped = [replace(r, capabilities=tool) if r.index else r for r in robots]
    changed = [replace(t, requires=tool) if t.key == key else t for t in tasks]
    assert report.paths == sequential_greedy(equipped, changed, AuctionParams()).paths


@pytest.mark.parametrize("seed", range(3))
def test_a_robot_standing_down_leaves_its_tasks_to_the_team_until_it_resumes(seed):
    """stand_down: robot 0 releases every task and bids on none. The team settles on the allocation the
    sequential greedy gives robots 1 and 2 alone; robot 0, resumed, takes its share again, and the team
    settles on the sequential greedy of all three."""
    robots, tasks = random_instance(3, 12, seed)
    simulation = AuctionSimulation(robots, tasks, IDEAL, AuctionParams())
    simulation.advance_to(400.0)
    lost = simulation.agents[0]
    assert lost.path_keys() and lost.stand_down(400.0) and not lost.stand_down(401.0)
    assert lost.path_keys() == [] and not (lost.z == 0).any()
    simulation.advance_to(1200.0)
    report = simulation.report(converged=True)
    assert report.conflicts == 0 and report.disagreements == 0 and report.paths[0] == []
    others = sequential_greedy([r for r in robots if r.index], tasks, AuctionParams())
    assert {k: v for k, v in report.paths.items() if k} == others.paths
    assert lost.resume(1200.0) and not lost.resume(1201.0)
    simulation.advance_to(2000.0)
    report = simulation.report(converged=True)
    assert report.conflicts == 0 and report.disagreements == 0 and report.paths[0]
    assert report.paths == sequential_greedy(robots, tasks, AuctionParams()).paths


def test_an_agent_learns_where_its_teammates_are_from_their_messages():
    from maptidal.allocation.agent import CBBAAgent
    from maptidal.allocation.scoring import RobotProfile

    a = CBBAAgent(RobotProfile("a", 0, np.array([0.0, 0.0, 1.0])))
    b = CBBAAgent(RobotProfile("b", 1, np.array([2.0, -1.5, 0.8])))
    assert b.receive(a.make_message(1.0), 1.2) and 0 in b.peer_positions
    position, heard = b.peer_positions[0]
    np.testing.assert_allclose(position, [0.0, 0.0, 1.0])
    assert heard == 1.2
    a.set_position([0.5, 0.25, 1.0])
    later = 1.0 + a.params.heartbeat_s  # a heartbeat: nothing else to say
    assert b.receive(a.make_message(later), later + 0.3)
    np.testing.assert_allclose(b.peer_positions[0][0], [0.5, 0.25, 1.0])
    assert b.peer_positions[0][1] == later + 0.3


def test_a_full_message_carries_the_done_tasks_then_the_path_in_flying_order():
    robots, tasks = random_instance(2, 30, 5)
    agent = CBBAAgent(robots[0])
    peer = CBBAAgent(robots[1])
    agent.add_tasks(tasks)
    peer.add_tasks(tasks)
    peer.receive(agent.make_message(0.0), 0.1)  # the peer is heard of, so entries are owed to it
    agent.receive(peer.make_message(0.2), 0.3)
    agent.build_bundle(1.0)
    assert len(agent.path_keys()) >= 3
    done = agent.path_keys()[-1]
    agent.mark_done(done, 2.0)
    path = agent.path_keys()
    # room for the header, one clock and three entries: what goes first is what matters most
    data = agent.make_message(3.0, capacity_bytes=size_of(2, 1, 0, 3))
    sent = decode(data).keys.tolist()
    assert sent == [done, path[0], path[1]]


def test_a_robot_tells_its_teammates_where_it_is_bound_when_that_changes():
    """Its goal goes in every message; a new goal (or one moved past ``goal_news_m``) is news, sent at
    the next slot even with nothing else to say; a small move waits for the next heartbeat."""
    robots, _ = random_instance(2, 0, 1)
    agent, peer = CBBAAgent(robots[0]), CBBAAgent(robots[1])
    assert peer.receive(agent.make_message(0.0), 0.1)
    assert peer.peer_goals[agent.index] is None  # holding where it is
    assert agent.make_message(1.0) is None  # nothing to say, heartbeat not due
    agent.goal = np.array([1.0, 2.0, 0.5])
    data = agent.make_message(2.0)
    assert data is not None and decode(data).goal == (1.0, 2.0, 0.5)
    assert peer.receive(data, 2.1)
    np.testing.assert_allclose(peer.peer_goals[agent.index], [1.0, 2.0, 0.5])
    agent.goal = np.array([1.3, 2.0, 0.5])  # 0.3 m on: not news
    assert agent.make_message(3.0) is None
    agent.goal = np.array([2.0, 2.0, 0.5])  # 1 m from the goal last sent: news
    assert decode(agent.make_message(4.0)).goal == (2.0, 2.0, 0.5)
    agent.goal = None  # stopped: news
    data = agent.make_message(5.0)
    assert data is not None and decode(data).goal is None
    assert peer.receive(data, 5.1) and peer.peer_goals[agent.index] is None
