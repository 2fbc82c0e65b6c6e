"""The CBBA conflict table, one test per row, and the vectorised resolution against a literal
transcription (tests/bench/literal_cbba.py) on random states."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from literal_cbba import literal_action

from maptidal.allocation.consensus import LEAVE, RESET, UPDATE, resolve

RECV, K, M, N = 0, 1, 2, 3  # receiver i, sender k, two other robots
NOBODY = -1
ACTION = {"leave": LEAVE, "update": UPDATE, "reset": RESET}


def act(z_k, y_k, z_i, y_i, s_k=None, s_i=None) -> int:
    """Resolve one task: sender K thinks (z_k, y_k), receiver RECV thinks (z_i, y_i)."""
    clocks_i = np.zeros(8, dtype=np.int64)
    clocks_k = np.zeros(8, dtype=np.int64)
    for robot, t in (s_i or {}).items():
        clocks_i[robot] = t
    for robot, t in (s_k or {}).items():
        clocks_k[robot] = t
    out = resolve(
        RECV, K, np.array([z_i]), np.array([y_i]), np.array([z_k]), np.array([y_k]), clocks_i, clocks_k
    )
    return int(out[0])


NEWER_M = ({M: 5}, {M: 3})  # (s_k, s_i): the sender heard of m more recently
OLDER_M = ({M: 3}, {M: 5})
NEWER_N = ({N: 5}, {N: 3})


# sender thinks k
def test_k_i_update_if_higher():
    assert act(K, 5.0, RECV, 4.0) == UPDATE
    assert act(K, 4.0, RECV, 5.0) == LEAVE


def test_k_i_tie_goes_to_lower_index():
    assert act(K, 5.0, RECV, 5.0) == LEAVE  # receiver 0 beats sender 1 on a tie


def test_k_k_update():
    assert act(K, 3.0, K, 4.0) == UPDATE


def test_k_m_update_if_newer_or_higher():
    assert act(K, 3.0, M, 4.0, *NEWER_M) == UPDATE
    assert act(K, 5.0, M, 4.0, *OLDER_M) == UPDATE
    assert act(K, 3.0, M, 4.0, *OLDER_M) == LEAVE


def test_k_none_update():
    assert act(K, 3.0, NOBODY, 0.0) == UPDATE


# sender thinks i
def test_i_i_leave():
    assert act(RECV, 3.0, RECV, 4.0) == LEAVE


def test_i_k_reset():
    assert act(RECV, 3.0, K, 4.0) == RESET


def test_i_m_reset_if_newer():
    assert act(RECV, 3.0, M, 4.0, *NEWER_M) == RESET
    assert act(RECV, 3.0, M, 4.0, *OLDER_M) == LEAVE


def test_i_none_leave():
    assert act(RECV, 3.0, NOBODY, 0.0) == LEAVE


# sender thinks m
def test_m_i_update_if_newer_and_higher():
    assert act(M, 5.0, RECV, 4.0, *NEWER_M) == UPDATE
    assert act(M, 3.0, RECV, 4.0, *NEWER_M) == LEAVE
    assert act(M, 5.0, RECV, 4.0, *OLDER_M) == LEAVE


def test_m_k_update_if_newer_else_reset():
    assert act(M, 3.0, K, 4.0, *NEWER_M) == UPDATE
    assert act(M, 3.0, K, 4.0, *OLDER_M) == RESET


def test_m_m_update_if_newer():
    assert act(M, 3.0, M, 4.0, *NEWER_M) == UPDATE
    assert act(M, 3.0, M, 4.0, *OLDER_M) == LEAVE


def test_m_n_update_if_both_newer():
    s_k, s_i = {M: 5, N: 5}, {M: 3, N: 3}
    assert act(M, 3.0, N, 4.0, s_k, s_i) == UPDATE


def test_m_n_update_if_m_newer_and_higher():
    s_k, s_i = {M: 5, N: 3}, {M: 3, N: 5}
    assert act(M, 5.0, N, 4.0, s_k, s_i) == UPDATE
    assert act(M, 3.0, N, 4.0, s_k, s_i) == LEAVE


def test_m_n_reset_if_n_newer_and_m_older():
    # the case public ports got wrong: reset, not update
    s_k, s_i = {M: 3, N: 5}, {M: 5, N: 3}
    assert act(M, 5.0, N, 4.0, s_k, s_i) == RESET


def test_m_n_otherwise_leave():
    s_k, s_i = {M: 4, N: 4}, {M: 4, N: 4}
    assert act(M, 5.0, N, 4.0, s_k, s_i) == LEAVE


def test_m_none_update_if_newer():
    assert act(M, 3.0, NOBODY, 0.0, *NEWER_M) == UPDATE
    assert act(M, 3.0, NOBODY, 0.0, *OLDER_M) == LEAVE


# sender thinks nobody
def test_none_i_leave():
    assert act(NOBODY, 0.0, RECV, 4.0) == LEAVE


def test_none_k_update():
    assert act(NOBODY, 0.0, K, 4.0) == UPDATE


def test_none_m_update_if_newer():
    assert act(NOBODY, 0.0, M, 4.0, *NEWER_M) == UPDATE
    assert act(NOBODY, 0.0, M, 4.0, *OLDER_M) == LEAVE


def test_none_none_leave():
    assert act(NOBODY, 0.0, NOBODY, 0.0) == LEAVE


winner = st.sampled_from([NOBODY, 0, 1, 2, 3, 4])
bid = st.sampled_from([0.0, 1.0, 2.0, 3.0])
clock = st.integers(0, 3)


@settings(max_examples=300, deadline=None)
@given(
    receiver=st.integers(0, 4),
    sender=st.integers(0, 4),
    entries=st.lists(st.tuples(winner, bid, winner, bid), min_size=1, max_size=12),
    clocks_i=st.lists(clock, min_size=5, max_size=5),
    clocks_k=st.lists(clock, min_size=5, max_size=5),
)
def test_vectorised_table_matches_literal_transcription(receiver, sender, entries, clocks_i, clocks_k):
    if receiver == sender:
        sender = (sender + 1) % 5
    z_i, y_i, z_k, y_k = (np.array(column) for column in zip(*entries, strict=True))
    s_i = np.array(clocks_i + [0] * 3, dtype=np.int64)
    s_k = np.array(clocks_k + [0] * 3, dtype=np.int64)
    got = resolve(receiver, sender, z_i, y_i.astype(float), z_k, y_k.astype(float), s_i, s_k)
    for n, (zi, yi, zk, yk) in enumerate(entries):
        lit = literal_action(
            receiver,
            sender,
            None if zi < 0 else zi,
            yi,
            None if zk < 0 else zk,
            yk,
            dict(enumerate(clocks_i)),
            dict(enumerate(clocks_k)),
        )
        assert got[n] == ACTION[lit], (receiver, sender, entries[n], clocks_i, clocks_k)


@pytest.mark.parametrize("z", [NOBODY, RECV, K, M])
def test_identical_views_never_change_anything(z):
    """The agent skips entries both sides agree on; every row must agree with that shortcut."""
    y = 0.0 if z == NOBODY else 3.0
    for s_k, s_i in (NEWER_M, OLDER_M, NEWER_N):
        assert act(z, y, z, y, s_k, s_i) in (LEAVE, UPDATE)
