"""The acoustic channel: timing, range, loss, outages, TDMA and determinism."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from maptidal.comms.channel import AcousticChannel, ChannelParams, Outage

POSITIONS = {0: np.zeros(3), 1: np.array([30.0, 40.0, 0.0]), 2: np.array([300.0, 0.0, 0.0])}


def test_arrival_is_transmission_plus_propagation_plus_latency():
    channel = AcousticChannel(ChannelParams(bandwidth_bps=400, latency_s=0.25, range_m=100))
    (delivery,) = channel.transmit(0, b"x" * 50, 10.0, POSITIONS)
    assert delivery.receiver == 1
    assert delivery.arrival_s == pytest.approx(10.0 + 50 * 8 / 400 + 50.0 / 1500.0 + 0.25)


def test_out_of_range_robots_hear_nothing():
    channel = AcousticChannel(ChannelParams(range_m=100))
    receivers = [d.receiver for d in channel.transmit(0, b"hello", 0.0, POSITIONS)]
    assert receivers == [1]
    assert channel.stats.out_of_range == 1


def test_loss_rate_matches_probability():
    channel = AcousticChannel(ChannelParams(loss=0.3, seed=5, range_m=math.inf))
    pair = {0: np.zeros(3), 1: np.ones(3)}
    delivered = sum(len(channel.transmit(0, b"abc", t, pair)) for t in range(4000))
    # binomial(4000, 0.7): standard deviation 29; 5 sigma either side
    assert abs(delivered - 2800) < 145


def test_scheduled_outage_takes_one_link_down_for_its_window():
    channel = AcousticChannel(ChannelParams(outages=(Outage(10.0, 20.0, (0, 1)),), range_m=math.inf))
    assert channel.link_up(0, 1, 9.9)
    assert not channel.link_up(1, 0, 10.0)
    assert channel.link_up(0, 2, 15.0)
    assert channel.link_up(0, 1, 20.0)
    assert [d.receiver for d in channel.transmit(0, b"a", 15.0, POSITIONS)] == [2]


def test_random_outages_are_reproducible_and_end_when_told():
    params = ChannelParams(mean_up_s=20.0, mean_down_s=10.0, random_outages_until_s=500.0, seed=9)
    first, second = AcousticChannel(params), AcousticChannel(params)
    times = np.linspace(0, 600, 601)
    forward = [first.link_up(0, 1, t) for t in times]
    backward = [second.link_up(0, 1, t) for t in times[::-1]][::-1]  # queried in another order
    assert forward == backward
    down = 1 - np.mean(forward[:500])
    assert 0.15 < down < 0.55  # about 10 / (20 + 10) of the time
    assert all(forward[500:])


def test_jitter_reorders_and_same_seed_repeats_exactly():
    params = ChannelParams(jitter_s=5.0, seed=3, range_m=math.inf)
    pair = {0: np.zeros(3), 1: np.ones(3)}

    def arrivals(channel):
        return [d.arrival_s for t in np.arange(0, 20, 0.5) for d in channel.transmit(0, b"z", float(t), pair)]

    a, b = arrivals(AcousticChannel(params)), arrivals(AcousticChannel(params))
    assert a == b
    assert a != sorted(a)  # some packets overtake earlier ones


def test_tdma_slot_fits_a_full_frame_and_the_longest_hop():
    params = ChannelParams(bandwidth_bps=500, max_frame_bytes=256, range_m=150, guard_s=0.05)
    assert params.tdma_slot_s == pytest.approx(256 * 8 / 500 + 150 / 1500 + 0.05)


@pytest.mark.parametrize(
    "bad",
    [
        {"bandwidth_bps": 0},
        {"loss": 1.0},
        {"loss": -0.1},
        {"range_m": -1},
        {"jitter_s": -1},
        {"max_frame_bytes": 10},
        {"outages": (Outage(5.0, 1.0),)},
    ],
)
def test_bad_parameters_are_refused(bad):
    with pytest.raises(ValueError):
        ChannelParams(**bad)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), loss=st.floats(0.0, 0.9))
def test_channel_is_deterministic_for_a_seed(seed, loss):
    params = ChannelParams(loss=loss, seed=seed, jitter_s=1.0, range_m=math.inf)

    def run():
        channel = AcousticChannel(params)
        return [
            (d.receiver, d.arrival_s) for t in range(50) for d in channel.transmit(t % 3, b"m", t, POSITIONS)
        ]

    assert run() == run()
