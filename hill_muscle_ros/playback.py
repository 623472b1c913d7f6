"""The protocol player's timeline, without ROS: what it sends, and when, on a
clock its caller reads (the node's, or a test's).

**Time 0 is when the protocol's first sample acts.** A subscriber acts on a
message as it arrives. One that the player has matched may not have matched
the player back yet, and a message sent then arrives with the writer's next
heartbeat (measured: 151.6 ms in the demo, about 3 s with the discovery range
unset), while the protocol's clock runs. So the player first sends the rest
state (:meth:`Playback.rest`), waits until every subscriber has acknowledged
it, and only then starts the protocol's clock, with the first sample
(:meth:`Playback.start`): each sample then leaves at its protocol time and
acts one delivery later, never before.

The rest state is zero stimulation at the protocol's starting length (its
value before time 0, as a protocol holds its first value outside its knots),
one message on each plain output: the bag of a run has them first, and the
protocol from sequence number :data:`FIRST_SAMPLE_SEQUENCE` on. With the
length sent ahead (``lookahead_s`` > 0) the stamped length topic carries no
rest state: a knot acts at its stamp, not on arrival, and the first window of
knots goes out one look-ahead before time 0.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .model import MuscleParams, Protocol
from .timebase import NS_PER_S

#: What a :class:`Send` goes on: the stimulation output (``pulse_width`` or
#: ``recruitment``), the plain length (dl_MT [m]) or the length sent ahead.
STIMULATION, LENGTH, LENGTH_STAMPED = 'stimulation', 'length_command', 'length_command_stamped'
#: Messages of the rest state on each plain output, before the protocol.
REST_MESSAGES = 1
#: The publication sequence number (from 1 per writer) of the protocol's first
#: sample on each plain output, after the rest state.
FIRST_SAMPLE_SEQUENCE = REST_MESSAGES + 1
#: Most knots sent at once for the first look-ahead window. The simulator's
#: queue for them holds 1000 (its STAMPED_QUEUE_DEPTH; a burst larger than a
#: keep-last queue loses its oldest knots), and each costs both sides some
#: 20-50 us of Python. A longer window is sent at a coarser spacing than the
#: period: the protocol's corners are always among the knots, so the
#: interpolated length is the same.
MAX_INITIAL_KNOTS = 100


@dataclass(frozen=True)
class Send:
    """One message to publish."""
    #: :data:`STIMULATION`, :data:`LENGTH` or :data:`LENGTH_STAMPED`
    topic: str
    #: the stimulation command, or dl_MT [m]
    value: float
    #: [s] the protocol time the message carries; ``None`` for the rest state
    protocol_time_s: float | None = None
    #: [ns] :data:`LENGTH_STAMPED` only: when dl_MT is to be reached, on the caller's clock
    stamp_ns: int | None = None


class Playback:
    """The protocol player's timeline on a clock of integer nanoseconds.

    The caller sends :meth:`rest` once the subscribers are matched, calls
    :meth:`start` once every subscriber has acknowledged it, then :meth:`tick`
    every ``period_s`` until :attr:`finished`; it publishes what each returns,
    in order.

    :param protocol: the protocol to play
    :param output: ``pulse_width`` or ``recruitment``: the stimulation command
    :param curve: the muscle whose recruitment curve maps R and pulse width
    :param period_s: [s] the tick period (knot spacing of the first window)
    :param lookahead_s: [s] 0 sends the plain length; > 0 stamped knots this far ahead
    """

    def __init__(self, protocol: Protocol, output: str, curve: MuscleParams,
                 period_s: float, lookahead_s: float) -> None:
        self.protocol = protocol
        self.output = output
        self.curve = curve
        self.period_s = period_s
        self.lookahead_s = lookahead_s
        self.stamped = lookahead_s > 0.0
        #: [ns] the protocol's time 0 on the caller's clock; ``None`` before :meth:`start`
        self.t0_ns: int | None = None
        #: the rest state went out (:meth:`rest`)
        self.rest_sent = False
        #: the protocol ran to its end and the final messages went out
        self.finished = False
        # [s] protocol time of the newest knot sent (stamped mode)
        self._knots_sent_to_s = -math.inf
        self._corners_s = protocol.dl_mt_m.breakpoints_s

    def protocol_time_s(self, now_ns: int) -> float:
        """[s] protocol time at ``now_ns`` (negative before time 0)."""
        return (now_ns - self.t0_ns) / NS_PER_S

    def rest(self) -> list[Send]:
        """The rest state, on every plain output: what the player sends first,
        and waits to see acknowledged before :meth:`start`."""
        self.rest_sent = True
        sends = [Send(STIMULATION, 0.0)]
        if not self.stamped:
            sends.append(Send(LENGTH, float(self.protocol.dl_mt(0.0))))
        return sends

    def start(self, now_ns: int) -> list[Send]:
        """Start the protocol's clock at ``now_ns`` (every subscriber has the
        rest state). Plain: time 0 is now, and its first sample goes now.
        Stamped: time 0 is one look-ahead from now, so that the first
        window's knots, sent now, all arrive before their time."""
        if not self.stamped:
            self.t0_ns = now_ns
            return self._samples(0.0)
        self.t0_ns = now_ns + round(self.lookahead_s * NS_PER_S)
        n = min(MAX_INITIAL_KNOTS, math.floor(self.lookahead_s / self.period_s) + 1)
        return self._knots(np.linspace(0.0, self.lookahead_s, max(n, 2)))

    def tick(self, now_ns: int) -> list[Send]:
        """The messages due at ``now_ns``: the sample at the protocol time
        (and the knots one look-ahead on); at or past the end, the protocol's
        final length and zero stimulation, and :attr:`finished` is set."""
        t_s = self.protocol_time_s(now_ns)
        sends = self._knots([t_s + self.lookahead_s]) if self.stamped else []
        if t_s < 0.0:
            return sends   # the first look-ahead window: the protocol has not started
        if t_s < self.protocol.duration_s:
            return sends + self._samples(t_s)
        end_s = float(self.protocol.duration_s)
        if not self.stamped:
            sends.append(Send(LENGTH, float(self.protocol.dl_mt(end_s)), end_s))
        sends.append(Send(STIMULATION, 0.0, t_s))
        self.finished = True
        return sends

    def _samples(self, t_s: float) -> list[Send]:
        """The protocol's plain samples at ``t_s``: the length (unless sent
        ahead), then the stimulation."""
        p = self.protocol
        sends = [] if self.stamped else [Send(LENGTH, float(p.dl_mt(t_s)), t_s)]
        sends.append(Send(STIMULATION, p.stimulation_command(t_s, self.output, self.curve),
                          t_s))
        return sends

    def _knots(self, times_s) -> list[Send]:
        """The knots at protocol times ``times_s`` not yet sent, with the
        protocol's corners among them, in time order."""
        p = self.protocol
        end_s = min(float(times_s[-1]), p.duration_s)
        corners = self._corners_s[(self._corners_s > self._knots_sent_to_s)
                                  & (self._corners_s < end_s)]
        times = np.union1d(np.append(times_s, corners), [end_s])
        times = times[(times > self._knots_sent_to_s) & (times <= end_s)]
        if len(times):
            self._knots_sent_to_s = float(times[-1])
        return [Send(LENGTH_STAMPED, dl, t, self.t0_ns + round(t * NS_PER_S))
                for t, dl in zip(times.tolist(), np.atleast_1d(p.dl_mt(times)).tolist())]
