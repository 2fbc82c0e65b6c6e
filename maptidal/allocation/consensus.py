"""CBBA conflict resolution: what a receiver does with one sender's view of a set of tasks.

This is the table of Choi, Brunet & How (2009), Table 1, as listed in docs/references.md. i is
the receiver, k the sender, m and n any other robots. `table_action` states the table one row at a time;
`resolve` applies it to many tasks at once through a lookup built from `table_action`. Winners are robot
indices, NO_WINNER (-1) for none. Bid ties go to the lower robot index wherever the table compares bids.
"""

from __future__ import annotations

import functools

import numpy as np

LEAVE, UPDATE, RESET = 0, 1, 2

# who the sender thinks wins: itself (k), the receiver (i), another robot (m), nobody
SENDER_K, SENDER_I, SENDER_M, SENDER_NONE = range(4)
# who the receiver thinks wins: itself (i), the sender (k), the sender's m, a different robot n, nobody
RECEIVER_I, RECEIVER_K, RECEIVER_M, RECEIVER_N, RECEIVER_NONE = range(5)


def table_action(
    sender: int, receiver: int, newer_m: bool, newer_n: bool, older_m: bool, higher: bool
) -> int:
    """One row of the CBBA table.

    newer_m: s_k[m] > s_i[m] for the sender's winner m (or, in rows where only the receiver names an
    other robot, for that robot); newer_n: the same for the receiver's other robot n; older_m:
    s_i[m] > s_k[m]; higher: the sender's bid beats the receiver's."""
    if sender == SENDER_K:
        if receiver == RECEIVER_I:
            return UPDATE if higher else LEAVE
        if receiver in (RECEIVER_K, RECEIVER_NONE):
            return UPDATE
        return UPDATE if newer_n or higher else LEAVE  # receiver thinks m: s_k[m] > s_i[m] or higher bid
    if sender == SENDER_I:
        if receiver == RECEIVER_K:
            return RESET
        if receiver in (RECEIVER_M, RECEIVER_N):
            return RESET if newer_n else LEAVE
        return LEAVE  # i|i and i|none
    if sender == SENDER_M:
        if receiver == RECEIVER_I:
            return UPDATE if newer_m and higher else LEAVE
        if receiver == RECEIVER_K:
            return UPDATE if newer_m else RESET
        if receiver in (RECEIVER_M, RECEIVER_NONE):
            return UPDATE if newer_m else LEAVE
        if newer_m and newer_n:  # m | n
            return UPDATE
        if newer_m and higher:
            return UPDATE
        if newer_n and older_m:
            return RESET
        return LEAVE
    # the sender thinks nobody wins
    if receiver == RECEIVER_K:
        return UPDATE
    if receiver in (RECEIVER_M, RECEIVER_N):
        return UPDATE if newer_n else LEAVE
    return LEAVE  # none|i and none|none


def _lookup() -> np.ndarray:
    table = np.zeros((4, 5, 16), dtype=np.int8)
    for s in range(4):
        for r in range(5):
            for bits in range(16):
                flags = [bool(bits >> b & 1) for b in range(4)]
                table[s, r, bits] = table_action(s, r, *flags)
    return table


_TABLE = _lookup()


def outbids(bid_a: np.ndarray, robot_a: np.ndarray, bid_b: np.ndarray, robot_b: np.ndarray) -> np.ndarray:
    """Whether bid_a by robot_a beats bid_b by robot_b: a higher bid, or an equal bid by a lower index."""
    return (bid_a > bid_b) | ((bid_a == bid_b) & (robot_a < robot_b))


def resolve(
    receiver: int,
    sender: int,
    z_receiver: np.ndarray,
    y_receiver: np.ndarray,
    z_sender: np.ndarray,
    y_sender: np.ndarray,
    clocks_receiver: np.ndarray,
    clocks_sender: np.ndarray,
) -> np.ndarray:
    """The action (LEAVE, UPDATE or RESET) for each task, from both sides' winners, bids and clocks.

    clocks_*: per robot index, the time each side last heard of that robot (s_i and s_k in the paper);
    both arrays must cover every robot index that appears as a winner."""
    zi, zk = np.asarray(z_receiver), np.asarray(z_sender)
    # index -1 (nobody) reads the last element; rows where a side names nobody never use that flag
    newer = clocks_sender > clocks_receiver
    older = clocks_receiver > clocks_sender
    newer_m, older_m, newer_n = newer[zk], older[zk], newer[zi]
    higher = outbids(y_sender, zk, y_receiver, zi)
    sender_lookup, receiver_lookup = _class_lookups(receiver, sender, len(clocks_sender))
    sender_class = sender_lookup[zk]
    receiver_class = receiver_lookup[zi]
    receiver_class[(receiver_class == RECEIVER_N) & (zi == zk)] = RECEIVER_M
    bits = newer_m.astype(np.int64) | newer_n << 1 | older_m << 2 | higher << 3
    return _TABLE[sender_class, receiver_class, bits]


@functools.lru_cache(maxsize=4096)
def _class_lookups(receiver: int, sender: int, n_robots: int) -> tuple[np.ndarray, np.ndarray]:
    """Winner index -> sender class and receiver class (the last element stands for nobody, -1)."""
    sender_lookup = np.full(n_robots + 1, SENDER_M, dtype=np.int64)
    sender_lookup[[sender, receiver, -1]] = SENDER_K, SENDER_I, SENDER_NONE
    receiver_lookup = np.full(n_robots + 1, RECEIVER_N, dtype=np.int64)
    receiver_lookup[[receiver, sender, -1]] = RECEIVER_I, RECEIVER_K, RECEIVER_NONE
    sender_lookup.flags.writeable = receiver_lookup.flags.writeable = False
    return sender_lookup, receiver_lookup
