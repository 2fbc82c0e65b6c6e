"""Binary auction messages sized for an acoustic modem.

One message is what a robot broadcasts in its transmit slot: its clock view of the team, the sequence
numbers it acknowledges, new task records, and the bid entries that changed since its neighbours last
acknowledged, where it is and where it is bound. Layout (little-endian, version 6):

    header    version u8, sender u8, seq u32, n_clocks u8
    position  x/y/z int16 cm: where the sender was when it sent (-32768 x 3: unknown), so that teammates
              can keep clear of it
    goal      x/y/z int16 cm: where the sender was bound when it sent (-32768 x 3: nowhere, it holds
              where it is), so that teammates can keep clear of its way too
    status    u8 flags: bit 0 set while the sender gives way to a teammate (so that the teammate need
              not give way to it, and two robots never wait on each other); bit 1 set while it has
              nothing left to do (it gives way to every teammate, and none waits on it); the other
              bits are zero
    clocks    n_clocks x u32   last time heard of each robot, ms + 1 (0 = never)
    acks      n_acks u8, then n_acks x (robot u8, seq u32)
    tasks     n_runs u16, then runs of task records: a run is the tasks of one origin with consecutive
              counters and the same requires mask, within 40.95 m of its first task on every axis:
              origin u8, first counter u16, count u8, requires u8, base x/y/z int16 cm (11 bytes),
              then count 8-byte records, each a little-endian u64 holding dx, dy, dz (13-bit two's
              complement cm from the base) and the 12-bit azimuth and elevation codes (bit 63 zero)
    entries   n_entries u16, then 8-byte records: origin u8, counter u16, winner u8
              (255 = none, 254 = done), bid float32
    checksum  CRC-16/CCITT u16 of everything before it

A 2-robot, 20-task auction moves about 160 bytes of entries per full state; see `maptidal allocate`.
Version 2 sent every task as a 13-byte record of its own; version 3's runs carry a robot's burst of
discoveries at 8 bytes a task (plus 11 a run), which is what lets a robot share what it found before it
can fail with it (issue [truthful-loop]: at 500 bit/s a robot finds tasks faster than 13-byte records leave).
Version 4 added the status byte: with positions heard 4 to 12 s late at 500 bit/s, only a robot told
that a teammate gives way can safely not give way itself (maptidal.mission.run's keep-clear rule).
Version 5 added the idle bit: a robot that had finished parked where it was, and a teammate whose way
lay through it waited on it for the rest of the mission.
Version 6 added the goal: a teammate heard 10 s ago may have flown 2.5 m since, and the robot that kept
clear of where it had been flew into it on its way (two robots in contact for minutes in a mission).
Anything malformed raises MessageError with a short reason; decode never returns a half-read message.
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass, field

import numpy as np

from maptidal.allocation.tasks import Task

VERSION = 6
NO_WINNER = -1
DONE = -2
_WIRE_NONE = 255
_WIRE_DONE = 254
NEVER = -1  # clock value of a robot never heard of

_HEADER = struct.Struct("<BBIB")
_POSITION = struct.Struct("<3h")
_STATUS = struct.Struct("<B")
_GIVING_WAY = 0x01
_IDLE = 0x02  # the sender has nothing left to do: it gives way to every teammate
_UNKNOWN_CM = -32768
_ACK = struct.Struct("<BI")
_COUNT = struct.Struct("<H")
_CRC = struct.Struct("<H")
ENTRY_DTYPE = np.dtype([("origin", "u1"), ("counter", "<u2"), ("winner", "u1"), ("bid", "<f4")])
RUN_DTYPE = np.dtype(
    [("origin", "u1"), ("counter", "<u2"), ("count", "u1"), ("requires", "u1"), ("base", "<i2", (3,))]
)
RECORD_BYTES = 8
assert ENTRY_DTYPE.itemsize == 8 and RUN_DTYPE.itemsize == 11
_OFFSET_BITS = 13
_OFFSET_LIMIT = (1 << (_OFFSET_BITS - 1)) - 1  # 4095 cm: how far a run's tasks lie from its base


class MessageError(ValueError):
    """A message that cannot be decoded; `reason` is one of checksum, truncated, version, malformed."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


@dataclass
class Message:
    """A decoded auction message.

    clocks_ms: int64 per robot index (NEVER = -1); acks: (robot, seq) pairs; keys/winners/bids: the bid
    entries (winner NO_WINNER or DONE for the special codes; bids as float64 holding float32 values);
    position: where the sender was, or None; goal: where it was bound, or None; giving_way: the sender
    was giving way to a teammate; idle: the sender had nothing left to do (it then gives way to every
    teammate, and none waits on it)."""

    sender: int
    seq: int
    clocks_ms: np.ndarray
    acks: list[tuple[int, int]] = field(default_factory=list)
    tasks: list[Task] = field(default_factory=list)
    keys: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    winners: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    bids: np.ndarray = field(default_factory=lambda: np.zeros(0))
    position: tuple[float, float, float] | None = None  # the sender's, m (to the cm on the wire)
    goal: tuple[float, float, float] | None = None  # where the sender was bound, m (to the cm)
    giving_way: bool = False
    idle: bool = False

    @property
    def has_content(self) -> bool:
        """True when the message carries tasks or entries, so it must be acknowledged."""
        return bool(self.tasks) or len(self.keys) > 0


def size_of(n_clocks: int, n_acks: int, n_tasks: int, n_entries: int, n_runs: int | None = None) -> int:
    """Bytes of a message with these counts; the tasks in ``n_runs`` runs (default: one, if any; see
    :func:`task_runs` for how many a list of tasks takes)."""
    runs = min(n_tasks, 1) if n_runs is None else n_runs
    return (
        _HEADER.size
        + 2 * _POSITION.size
        + _STATUS.size
        + 4 * n_clocks
        + 1
        + _ACK.size * n_acks
        + 2 * _COUNT.size
        + RUN_DTYPE.itemsize * runs
        + RECORD_BYTES * n_tasks
        + ENTRY_DTYPE.itemsize * n_entries
        + _CRC.size
    )


def task_runs(tasks: list[Task]) -> list[list[Task]]:
    """The runs a message packs ``tasks`` into, in key order: one origin, consecutive counters, one
    requires mask, at most 255 tasks, each within 40.95 m of the run's first task on every axis."""
    runs: list[list[Task]] = []
    for task in sorted(tasks, key=lambda t: t.key):
        if runs:
            run = runs[-1]
            first, last = run[0], run[-1]
            if (
                task.key == last.key + 1
                and task.key >> 16 == first.key >> 16
                and task.requires == first.requires
                and len(run) < 255
                and all(
                    abs(a - b) <= _OFFSET_LIMIT
                    for a, b in zip(task.position_cm, first.position_cm, strict=True)
                )
            ):
                run.append(task)
                continue
        runs.append([task])
    return runs


def _pack_record(task: Task, base: tuple[int, int, int]) -> int:
    mask = (1 << _OFFSET_BITS) - 1
    word = 0
    for axis, (value, origin) in enumerate(zip(task.position_cm, base, strict=True)):
        word |= ((value - origin) & mask) << (_OFFSET_BITS * axis)
    az, el = task.direction_code
    return word | az << (3 * _OFFSET_BITS) | el << (3 * _OFFSET_BITS + 12)


def _unpack_record(word: int, base: tuple[int, int, int]) -> tuple[tuple[int, int, int], tuple[int, int]]:
    mask = (1 << _OFFSET_BITS) - 1
    position = []
    for axis in range(3):
        offset = word >> (_OFFSET_BITS * axis) & mask
        offset -= (1 << _OFFSET_BITS) if offset > _OFFSET_LIMIT else 0
        position.append(base[axis] + offset)
    az = word >> (3 * _OFFSET_BITS) & 0xFFF
    el = word >> (3 * _OFFSET_BITS + 12) & 0xFFF
    return tuple(position), (az, el)  # type: ignore[return-value]


def encode(message: Message) -> bytes:
    """The wire bytes of a message."""
    clocks = np.asarray(message.clocks_ms, dtype=np.int64)
    if len(clocks) > 255 or len(message.acks) > 255:
        raise ValueError("at most 255 robots per message")
    parts = [_HEADER.pack(VERSION, message.sender, message.seq & 0xFFFFFFFF, len(clocks))]
    parts.append(_POSITION.pack(*_position_cm(message.position)))
    parts.append(_POSITION.pack(*_position_cm(message.goal)))
    parts.append(_STATUS.pack((_GIVING_WAY if message.giving_way else 0) | (_IDLE if message.idle else 0)))
    parts.append((clocks + 1).astype("<u4").tobytes())
    parts.append(bytes([len(message.acks)]))
    parts.extend(_ACK.pack(robot, seq & 0xFFFFFFFF) for robot, seq in message.acks)
    runs = task_runs(message.tasks)
    parts.append(_COUNT.pack(len(runs)))
    for run in runs:
        head = np.zeros(1, dtype=RUN_DTYPE)
        head["origin"], head["counter"], head["count"] = run[0].key >> 16, run[0].key & 0xFFFF, len(run)
        head["requires"], head["base"] = run[0].requires, run[0].position_cm
        words = np.array([_pack_record(t, run[0].position_cm) for t in run], dtype="<u8")
        parts += [head.tobytes(), words.tobytes()]
    entries = np.zeros(len(message.keys), dtype=ENTRY_DTYPE)
    keys = np.asarray(message.keys, dtype=np.int64)
    entries["origin"], entries["counter"] = keys >> 16, keys & 0xFFFF
    winners = np.asarray(message.winners, dtype=np.int64)
    entries["winner"] = np.where(
        winners == NO_WINNER, _WIRE_NONE, np.where(winners == DONE, _WIRE_DONE, winners)
    )
    entries["bid"] = message.bids
    parts += [_COUNT.pack(len(entries)), entries.tobytes()]
    body = b"".join(parts)
    return body + _CRC.pack(binascii.crc_hqx(body, 0xFFFF))


def _position_cm(position) -> tuple[int, int, int]:
    if position is None:
        return (_UNKNOWN_CM,) * 3
    values = np.asarray(position, float).reshape(3)
    if not np.isfinite(values).all():
        return (_UNKNOWN_CM,) * 3
    return tuple(int(v) for v in np.clip(np.round(values * 100.0), -32767, 32767))  # type: ignore[return-value]


def _position_m(position_cm: tuple[int, int, int]) -> tuple[float, float, float] | None:
    if position_cm == (_UNKNOWN_CM,) * 3:
        return None
    return tuple(v / 100.0 for v in position_cm)  # type: ignore[return-value]


def _take(data: bytes, offset: int, size: int) -> int:
    if offset + size > len(data):
        raise MessageError("truncated", f"needs {offset + size} bytes, has {len(data)}")
    return offset + size


def decode(data: bytes) -> Message:
    """Parse wire bytes; raises MessageError (checksum, truncated, version or malformed)."""
    if len(data) < _HEADER.size + _CRC.size:
        raise MessageError("truncated", f"{len(data)} bytes")
    body, (crc,) = data[:-2], _CRC.unpack(data[-2:])
    if binascii.crc_hqx(body, 0xFFFF) != crc:
        raise MessageError("checksum")
    version, sender, seq, n_clocks = _HEADER.unpack_from(body, 0)
    if version != VERSION:
        raise MessageError("version", f"got {version}, speak {VERSION}")
    start = _take(body, _HEADER.size, 2 * _POSITION.size + _STATUS.size)
    position, goal = (
        _position_m(_POSITION.unpack_from(body, _HEADER.size + at)) for at in (0, _POSITION.size)
    )
    (status,) = _STATUS.unpack_from(body, _HEADER.size + 2 * _POSITION.size)
    if status & ~(_GIVING_WAY | _IDLE):
        raise MessageError("malformed", f"status bits {status:#04x}")
    offset = _take(body, start, 4 * n_clocks)
    clocks = np.frombuffer(body, "<u4", n_clocks, start).astype(np.int64) - 1
    start = _take(body, offset, 1)
    n_acks = body[offset]
    offset = _take(body, start, _ACK.size * n_acks)
    acks = [_ACK.unpack_from(body, start + _ACK.size * i) for i in range(n_acks)]
    offset = _take(body, offset, 2)
    (n_runs,) = _COUNT.unpack_from(body, offset - 2)
    tasks = []
    for _ in range(n_runs):
        start, offset = offset, _take(body, offset, RUN_DTYPE.itemsize)
        head = np.frombuffer(body, RUN_DTYPE, 1, start)[0]
        count, origin, first = int(head["count"]), int(head["origin"]), int(head["counter"])
        if count == 0 or first + count > 0x10000:
            raise MessageError("malformed", f"a run of {count} tasks from counter {first}")
        base = tuple(int(v) for v in head["base"])
        start, offset = offset, _take(body, offset, RECORD_BYTES * count)
        for n, word in enumerate(np.frombuffer(body, "<u8", count, start).tolist()):
            if word >> 63:
                raise MessageError("malformed", "task record's spare bit set")
            record_cm, direction = _unpack_record(int(word), base)  # type: ignore[arg-type]
            if any(abs(v) > 32767 for v in record_cm):
                raise MessageError("malformed", "task position out of range")
            tasks.append(Task(origin << 16 | (first + n), record_cm, direction, int(head["requires"])))
    start = _take(body, offset, 2)
    (n_entries,) = _COUNT.unpack_from(body, offset)
    offset = _take(body, start, ENTRY_DTYPE.itemsize * n_entries)
    entries = np.frombuffer(body, ENTRY_DTYPE, n_entries, start)
    if offset != len(body):
        raise MessageError("malformed", f"{len(body) - offset} trailing bytes")
    wire = entries["winner"].astype(np.int64)
    winners = np.where(wire == _WIRE_NONE, NO_WINNER, np.where(wire == _WIRE_DONE, DONE, wire))
    bids = entries["bid"].astype(np.float64)
    if not np.isfinite(bids).all() or (bids < 0).any():
        raise MessageError("malformed", "bid not a finite non-negative number")
    if any(d[1] > 4095 for d in (t.direction_code for t in tasks)):
        raise MessageError("malformed", "direction code out of range")
    return Message(
        sender=sender,
        seq=seq,
        clocks_ms=clocks,
        acks=[(int(a), int(s)) for a, s in acks],
        tasks=tasks,
        keys=entries["origin"].astype(np.int64) << 16 | entries["counter"].astype(np.int64),
        winners=winners,
        bids=bids,
        position=position,  # type: ignore[arg-type]
        goal=goal,  # type: ignore[arg-type]
        giving_way=bool(status & _GIVING_WAY),
        idle=bool(status & _IDLE),
    )
