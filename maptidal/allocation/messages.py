"""Binary auction messages sized for an acoustic modem.

One message is what a robot broadcasts in its transmit slot: its clock view of the team, the sequence
numbers it acknowledges, new task records, and the bid entries that changed since its neighbours last
acknowledged, and where it is. Layout (little-endian, version 2):

    header    version u8, sender u8, seq u32, n_clocks u8
    position  x/y/z int16 cm: where the sender was when it sent (-32768 x 3: unknown), so that teammates
              can keep clear of it
    clocks    n_clocks x u32   last time heard of each robot, ms + 1 (0 = never)
    acks      n_acks u8, then n_acks x (robot u8, seq u32)
    tasks     n_tasks u16, then 13-byte records: origin u8, counter u16, x/y/z int16 cm,
              azimuth and elevation as two 12-bit codes in 3 bytes, requires u8
    entries   n_entries u16, then 8-byte records: origin u8, counter u16, winner u8
              (255 = none, 254 = done), bid float32
    checksum  CRC-16/CCITT u16 of everything before it

A 2-robot, 20-task auction moves about 160 bytes of entries per full state; see `maptidal allocate`.
Anything malformed raises MessageError with a short reason; decode never returns a half-read message.
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass, field

import numpy as np

from maptidal.allocation.tasks import Task

VERSION = 2
NO_WINNER = -1
DONE = -2
_WIRE_NONE = 255
_WIRE_DONE = 254
NEVER = -1  # clock value of a robot never heard of

_HEADER = struct.Struct("<BBIB")
_POSITION = struct.Struct("<3h")
_UNKNOWN_CM = -32768
_ACK = struct.Struct("<BI")
_COUNT = struct.Struct("<H")
_CRC = struct.Struct("<H")
ENTRY_DTYPE = np.dtype([("origin", "u1"), ("counter", "<u2"), ("winner", "u1"), ("bid", "<f4")])
TASK_DTYPE = np.dtype(
    [("origin", "u1"), ("counter", "<u2"), ("pos", "<i2", (3,)), ("dir", "u1", (3,)), ("requires", "u1")]
)
assert ENTRY_DTYPE.itemsize == 8 and TASK_DTYPE.itemsize == 13


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
    position: where the sender was, or None."""

    sender: int
    seq: int
    clocks_ms: np.ndarray
    acks: list[tuple[int, int]] = field(default_factory=list)
    tasks: list[Task] = field(default_factory=list)
    keys: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    winners: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    bids: np.ndarray = field(default_factory=lambda: np.zeros(0))
    position: tuple[float, float, float] | None = None  # the sender's, m (to the cm on the wire)

    @property
    def has_content(self) -> bool:
        """True when the message carries tasks or entries, so it must be acknowledged."""
        return bool(self.tasks) or len(self.keys) > 0


def size_of(n_clocks: int, n_acks: int, n_tasks: int, n_entries: int) -> int:
    """Bytes of a message with these counts."""
    return (
        _HEADER.size
        + _POSITION.size
        + 4 * n_clocks
        + 1
        + _ACK.size * n_acks
        + 2 * _COUNT.size
        + TASK_DTYPE.itemsize * n_tasks
        + ENTRY_DTYPE.itemsize * n_entries
        + _CRC.size
    )


def _pack_direction(az: int, el: int) -> tuple[int, int, int]:
    return az & 0xFF, (az >> 8 & 0x0F) | (el & 0x0F) << 4, el >> 4 & 0xFF


def _unpack_direction(b: np.ndarray) -> tuple[int, int]:
    b0, b1, b2 = (int(v) for v in b)
    return b0 | (b1 & 0x0F) << 8, b1 >> 4 | b2 << 4


def encode(message: Message) -> bytes:
    """The wire bytes of a message."""
    clocks = np.asarray(message.clocks_ms, dtype=np.int64)
    if len(clocks) > 255 or len(message.acks) > 255:
        raise ValueError("at most 255 robots per message")
    parts = [_HEADER.pack(VERSION, message.sender, message.seq & 0xFFFFFFFF, len(clocks))]
    parts.append(_POSITION.pack(*_position_cm(message.position)))
    parts.append((clocks + 1).astype("<u4").tobytes())
    parts.append(bytes([len(message.acks)]))
    parts.extend(_ACK.pack(robot, seq & 0xFFFFFFFF) for robot, seq in message.acks)
    records = np.zeros(len(message.tasks), dtype=TASK_DTYPE)
    for row, task in zip(records, message.tasks, strict=True):
        row["origin"], row["counter"] = task.key >> 16, task.key & 0xFFFF
        row["pos"] = task.position_cm
        row["dir"] = _pack_direction(*task.direction_code)
        row["requires"] = task.requires
    parts += [_COUNT.pack(len(records)), records.tobytes()]
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
    start = _take(body, _HEADER.size, _POSITION.size)
    position_cm = _POSITION.unpack_from(body, _HEADER.size)
    position = None if position_cm == (_UNKNOWN_CM,) * 3 else tuple(v / 100.0 for v in position_cm)
    offset = _take(body, start, 4 * n_clocks)
    clocks = np.frombuffer(body, "<u4", n_clocks, start).astype(np.int64) - 1
    start = _take(body, offset, 1)
    n_acks = body[offset]
    offset = _take(body, start, _ACK.size * n_acks)
    acks = [_ACK.unpack_from(body, start + _ACK.size * i) for i in range(n_acks)]
    start = _take(body, offset, 2)
    (n_tasks,) = _COUNT.unpack_from(body, offset)
    offset = _take(body, start, TASK_DTYPE.itemsize * n_tasks)
    records = np.frombuffer(body, TASK_DTYPE, n_tasks, start)
    start = _take(body, offset, 2)
    (n_entries,) = _COUNT.unpack_from(body, offset)
    offset = _take(body, start, ENTRY_DTYPE.itemsize * n_entries)
    entries = np.frombuffer(body, ENTRY_DTYPE, n_entries, start)
    if offset != len(body):
        raise MessageError("malformed", f"{len(body) - offset} trailing bytes")
    tasks = [
        Task(
            int(r["origin"]) << 16 | int(r["counter"]),
            tuple(int(v) for v in r["pos"]),  # type: ignore[arg-type]
            _unpack_direction(r["dir"]),
            int(r["requires"]),
        )
        for r in records
    ]
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
    )
