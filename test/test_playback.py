"""The protocol player's timeline (:mod:`hill_muscle_ros.playback`) on a clock
the test drives, over a model of one reliable DDS link: no ROS, no DDS.

The link is the measured case of a late handshake: the player has matched the subscriber, but
the subscriber matches the player back only a heartbeat later, so what is sent
before arrives then; later messages arrive one latency after they leave, and
the player sees a message acknowledged one latency after it arrived.
"""
from __future__ import annotations

import math

import pytest

from hill_muscle_ros.model import MuscleParams, Protocol
from hill_muscle_ros.playback import (FIRST_SAMPLE_SEQUENCE, LENGTH, LENGTH_STAMPED,
                                      STIMULATION, Playback, Send)
from hill_muscle_ros.timebase import NS_PER_S

#: R steps 0.3 -> 0.7 at 0.25 s, the length ramps 0 -> 2 mm from 1 mm.
SHORT = {'name': 'short', 'duration_s': 0.5,
         'recruitment': [[0.0, 0.3], [0.25, 0.3], [0.25, 0.7]],
         'dl_mt_m': [[0.0, 0.001], [0.5, 0.002]]}
#: [ns] when the subscriber matches the player back: the demo's measured
#: acknowledgement before the heartbeat fix (151.6 ms).
MATCHED_BACK_NS = 151_600_000
#: [ns] one delivery, and one acknowledgement back
LATENCY_NS = 1_000_000
#: [ns] the player's step while it waits for the acknowledgement
WAIT_STEP_NS = 1_000_000
#: [s] tick period of the player
PERIOD_S = 0.01
#: [s] look-ahead of the stamped length
LOOKAHEAD_S = 0.05


class Link:
    """A reliable link to one subscriber, on the test's clock."""

    def __init__(self) -> None:
        #: (arrival [ns], sequence number on its topic, the message), in send order
        self.delivered: list[tuple[int, int, Send]] = []
        self._sent: dict[str, int] = {}

    def send(self, now_ns: int, sends: list[Send]) -> None:
        for send in sends:
            self._sent[send.topic] = self._sent.get(send.topic, 0) + 1
            arrival_ns = max(now_ns, MATCHED_BACK_NS) + LATENCY_NS
            self.delivered.append((arrival_ns, self._sent[send.topic], send))

    def all_acked(self, now_ns: int) -> bool:
        return all(arrival + LATENCY_NS <= now_ns for arrival, _, _ in self.delivered)


def _play(lookahead_s: float) -> tuple[Playback, Link]:
    """Play SHORT as the node does: the rest state once matched (at 0), the
    protocol once it is acknowledged, then a tick every period."""
    playback = Playback(Protocol.from_mapping(SHORT), 'recruitment', MuscleParams(),
                        PERIOD_S, lookahead_s)
    link = Link()
    now_ns = 0
    link.send(now_ns, playback.rest())
    while not link.all_acked(now_ns):
        now_ns += WAIT_STEP_NS
    link.send(now_ns, playback.start(now_ns))
    period_ns = round(PERIOD_S * NS_PER_S)
    while not playback.finished:
        now_ns += period_ns
        link.send(now_ns, playback.tick(now_ns))
    return playback, link


def _acts_at_ns(arrival_ns: int, send: Send) -> int:
    """A plain message acts when it arrives; a stamped knot at its stamp."""
    return send.stamp_ns if send.topic == LENGTH_STAMPED else arrival_ns


@pytest.mark.parametrize('lookahead_s', [0.0, LOOKAHEAD_S], ids=['plain', 'stamped'])
def test_no_protocol_sample_acts_before_its_time_when_the_subscriber_matches_back_late(
        lookahead_s):
    playback, link = _play(lookahead_s)
    samples = [(arrival, send) for arrival, _, send in link.delivered
               if send.protocol_time_s is not None]
    early = [(send, _acts_at_ns(arrival, send) - playback.t0_ns) for arrival, send in samples
             if _acts_at_ns(arrival, send) < playback.t0_ns + round(send.protocol_time_s
                                                                    * NS_PER_S)]
    assert samples and not early, early[:3]


@pytest.mark.parametrize('lookahead_s', [0.0, LOOKAHEAD_S], ids=['plain', 'stamped'])
def test_the_protocol_starts_only_after_the_rest_state_is_acknowledged(lookahead_s):
    playback, link = _play(lookahead_s)
    rest = [arrival for arrival, _, send in link.delivered if send.protocol_time_s is None]
    assert rest and playback.t0_ns >= max(rest) + LATENCY_NS


def test_time_zero_is_when_the_first_stimulation_sample_acts():
    playback, link = _play(0.0)
    [first] = [(arrival, send) for arrival, seq, send in link.delivered
               if send.topic == STIMULATION and seq == FIRST_SAMPLE_SEQUENCE]
    arrival_ns, send = first
    assert send.protocol_time_s == 0.0
    assert arrival_ns - playback.t0_ns == LATENCY_NS


def test_rest_state_is_zero_stimulation_at_the_protocols_starting_length():
    playback = Playback(Protocol.from_mapping(SHORT), 'pulse_width', MuscleParams(),
                        PERIOD_S, 0.0)
    assert playback.rest() == [Send(STIMULATION, 0.0), Send(LENGTH, SHORT['dl_mt_m'][0][1])]


def test_stamped_length_carries_no_rest_state_and_its_first_knot_is_time_zero():
    playback, link = _play(LOOKAHEAD_S)
    knots = [send for _, _, send in link.delivered if send.topic == LENGTH_STAMPED]
    assert knots[0].protocol_time_s == 0.0 and knots[0].stamp_ns == playback.t0_ns
    assert not [send for _, _, send in link.delivered if send.topic == LENGTH]


@pytest.mark.parametrize('lookahead_s', [0.0, LOOKAHEAD_S], ids=['plain', 'stamped'])
def test_the_protocol_ends_with_zero_stimulation_at_its_duration(lookahead_s):
    playback, link = _play(lookahead_s)
    last = link.delivered[-1][2]
    assert (last.topic, last.value) == (STIMULATION, 0.0)
    assert last.protocol_time_s >= SHORT['duration_s']
    final_length_m = [send.value for _, _, send in link.delivered
                      if send.topic in (LENGTH, LENGTH_STAMPED)][-1]
    assert math.isclose(final_length_m, SHORT['dl_mt_m'][-1][1])
