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

**Pulse trains.** A protocol with ``channels``
(:class:`~hill_muscle_ros.model.protocol.PulseProtocol`) is played by
:class:`PulsePlayback` on the same clock and handshake: its stimulation is
one command for every channel (:data:`CHANNELS`, the
``hill_muscle_interfaces/msg/Stimulation`` message) at time 0 and at each
knot time of the channels' tracks, each read from the tracks at that time
and checked against a stimulator
(:func:`~hill_muscle_ros.model.stimulator.check_stimulation`); the rest state
and the end are a zero stimulation (every channel's pulse width 0). The
length goes as for a level protocol.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .model import MuscleParams, Protocol
from .model.protocol import PulseProtocol
from .model.stimulator import (ChannelCommand, StimulatorProfile, check_stimulation,
                               stimulator_profile)
from .timebase import NS_PER_S

#: What a :class:`Send` goes on: the stimulation output (``pulse_width`` or
#: ``recruitment``), the plain length (dl_MT [m]) or the length sent ahead.
STIMULATION, LENGTH, LENGTH_STAMPED = 'stimulation', 'length_command', 'length_command_stamped'
#: What a :class:`Send` of a pulse protocol's stimulation goes on: every
#: channel's command, one ``hill_muscle_interfaces/msg/Stimulation`` on the
#: topic ``stimulation`` (:class:`PulsePlayback`).
CHANNELS = 'channels'
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
    #: :data:`STIMULATION`, :data:`LENGTH`, :data:`LENGTH_STAMPED` or :data:`CHANNELS`
    topic: str
    #: the stimulation command, dl_MT [m], or (:data:`CHANNELS`) every
    #: channel's :class:`~hill_muscle_ros.model.stimulator.ChannelCommand`, channel 1 first
    value: float | tuple[ChannelCommand, ...]
    #: [s] the protocol time the message carries; ``None`` for the rest state
    protocol_time_s: float | None = None
    #: [ns] on the caller's clock: :data:`LENGTH_STAMPED`, when dl_MT is to be
    #: reached; :data:`CHANNELS`, when the command takes effect (the protocol
    #: time it was read at); ``None``: now
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


def pulse_profile(params: MuscleParams | None) -> StimulatorProfile:
    """The stimulator a pulse protocol's commands are checked against.

    :param params: the muscle the player drives (its ``stimulator`` and, for
        the ``generic`` profile, its ``pw_max_s``); ``None``: the ``generic``
        profile with the default PW_max
    """
    if params is None:
        return stimulator_profile('generic')
    return stimulator_profile(params.stimulator, params.pw_max_s)


def _track_at(track, t_s: float) -> float:
    """A channel track's value at ``t_s``: knots (linear between, the last knot
    of a repeated time, held outside: :class:`~hill_muscle_ros.model.protocol.Knots`)
    or a number."""
    times = getattr(track, 'times_s', None)
    if times is None:
        return float(track)
    return float(np.interp(t_s, times, track.values))


def _track_times(track) -> np.ndarray:
    """[s] A channel track's knot times (none for a number)."""
    return np.asarray(getattr(track, 'times_s', ()), dtype=float)


def stimulation_times_s(protocol: PulseProtocol) -> np.ndarray:
    """[s] When a pulse protocol's stimulation commands go: time 0 and every
    distinct knot time of the channels' ``frequency_hz``, ``pulse_width_s``
    and ``current_a`` in (0, ``duration_s``), in order.

    :param protocol: the pulse protocol
    """
    times = [np.zeros(1)]
    for train in protocol.channels:
        for track in (train.frequency_hz, train.pulse_width_s, train.current_a):
            if track is not None:
                times.append(_track_times(track))
    knots = np.unique(np.concatenate(times))
    return knots[(knots >= 0.0) & (knots < protocol.duration_s)]


def channel_commands(protocol: PulseProtocol, t_s: float, profile: StimulatorProfile,
                     burst_interval_s: float, zero: bool = False
                     ) -> tuple[ChannelCommand, ...]:
    """Every channel's command at ``t_s``, read from its tracks and checked as
    the stimulator would (:func:`~hill_muscle_ros.model.stimulator.check_stimulation`).

    :param protocol: the pulse protocol
    :param t_s: [s] protocol time
    :param profile: the stimulator
    :param burst_interval_s: [s] the interval between the pulses of a burst
        the receiving muscle uses (the message carries none)
    :param zero: a zero stimulation instead: every channel's pulse width 0 (and
        its current 0 where the protocol gives currents), mode and frequency as at ``t_s``
    :return: the commands, channel 1 first; ``current_a`` ``None`` on every
        channel when the protocol gives no current
    :raises ValueError: naming the field, the channel, the stimulator and the value
    """
    trains = protocol.channels
    with_current = trains[0].current_a is not None
    pulse_widths = [0.0 if zero else _track_at(c.pulse_width_s, t_s) for c in trains]
    currents = ([0.0 if zero else _track_at(c.current_a, t_s) for c in trains]
                if with_current else [])
    return check_stimulation(profile, [c.channel for c in trains], [c.mode for c in trains],
                             pulse_widths, currents,
                             [_track_at(c.frequency_hz, t_s) for c in trains],
                             burst_interval_s)


class PulsePlayback(Playback):
    """The protocol player's timeline for a pulse protocol (``channels``).

    The same clock, handshake and length as :class:`Playback`; the
    stimulation is :data:`CHANNELS`: every channel's command at time 0 and at
    each of :func:`stimulation_times_s`, sent at the first tick at or after
    that time and stamped with it; a knot time a tick passed over goes out at
    that tick, in order. The rest state and the end send a zero stimulation.
    Every command the protocol can send is checked when the playback is made,
    so a protocol the stimulator would reject is refused before it starts.

    :param protocol: the pulse protocol to play
    :param params: the muscle it drives: ``stimulator`` and ``pw_max_s`` give
        the profile (:func:`pulse_profile`), ``burst_interval_s`` the
        interval of its doublets and triplets; ``None``: the ``generic``
        profile and the default interval
    :param period_s: [s] the tick period (knot spacing of the first length window)
    :param lookahead_s: [s] 0 sends the plain length; > 0 stamped knots this far ahead
    :param source: what to call the protocol in messages (its file)
    :raises ValueError: naming the field, the channel, the value and the time
        of the first command the stimulator would reject; a protocol that gives
        ``current_a`` on some channels only, or a doublet or triplet whose
        ``burst_interval_s`` is not the muscle's (the message carries neither)
    """

    def __init__(self, protocol: PulseProtocol, params: MuscleParams | None,
                 period_s: float, lookahead_s: float, source: str | None = None) -> None:
        curve = params if params is not None else MuscleParams()
        super().__init__(protocol, CHANNELS, curve, period_s, lookahead_s)
        self.profile = pulse_profile(params)
        #: [s] the interval of the muscle's doublets and triplets
        self.burst_interval_s = curve.burst_interval_s
        #: [s] the protocol times of the commands, time 0 first
        self.times_s = stimulation_times_s(protocol)
        self._next = 0   # index into times_s of the next command to send
        self._check(source if source is not None else repr(protocol.name), params)

    def _check(self, source: str, params: MuscleParams | None) -> None:
        """Refuse a protocol the message cannot carry or the stimulator would reject."""
        trains = self.protocol.channels
        given = [c.channel for c in trains if c.current_a is not None]
        if given and len(given) != len(trains):
            missing = [c.channel for c in trains if c.current_a is None]
            raise ValueError(
                f'{source}: `current_a` must be given on every channel or on none (a '
                f'Stimulation message carries a current for all its channels or none), got '
                f'it on channel(s) {", ".join(map(str, given))} and not on '
                f'{", ".join(map(str, missing))}')
        for c in trains:
            if c.pulses_per_burst > 1 and c.burst_interval_s != self.burst_interval_s:
                raise ValueError(
                    f'{source}: `burst_interval_s` of channel {c.channel} must be the '
                    f'muscle\'s `burst_interval_s` {self.burst_interval_s:g} s for a {c.mode} '
                    '(a Stimulation message carries no burst interval: the simulator uses '
                    f'its own), got {c.burst_interval_s!r}')
        which = ('' if params is None else
                 f' (the player\'s `stimulator` {params.stimulator}'
                 + (f', `pw_max_s` {params.pw_max_s:g} s' if params.stimulator == 'generic'
                    else '') + ': give the simulator\'s)')
        end_s = float(self.protocol.duration_s)
        checks = [(t, False) for t in self.times_s.tolist()] + [(0.0, True), (end_s, True)]
        for t_s, zero in checks:
            try:
                channel_commands(self.protocol, t_s, self.profile, self.burst_interval_s, zero)
            except ValueError as err:
                what = 'the zero stimulation' if zero else 'the command'
                raise ValueError(f'{source}: {what} at t = {t_s:g} s: {err}{which}') from None

    def rest(self) -> list[Send]:
        """The rest state: zero stimulation (with each channel's mode and
        frequency at time 0) and, unless sent ahead, the starting length."""
        self.rest_sent = True
        sends = [Send(CHANNELS, self._commands(0.0, zero=True))]
        if not self.stamped:
            sends.append(Send(LENGTH, float(self.protocol.dl_mt(0.0))))
        return sends

    def tick(self, now_ns: int) -> list[Send]:
        """The messages due at ``now_ns``: the length sample (or the knots one
        look-ahead on) and the commands whose time has come; at or past the
        end, the final length, the commands not yet sent and a zero
        stimulation, and :attr:`finished` is set."""
        t_s = self.protocol_time_s(now_ns)
        end_s = float(self.protocol.duration_s)
        if t_s < end_s:
            return super().tick(now_ns)
        sends = self._knots([t_s + self.lookahead_s]) if self.stamped else []
        if not self.stamped:
            sends.append(Send(LENGTH, float(self.protocol.dl_mt(end_s)), end_s))
        sends.extend(self._due(end_s))
        sends.append(Send(CHANNELS, self._commands(end_s, zero=True), t_s, now_ns))
        self.finished = True
        return sends

    def _samples(self, t_s: float) -> list[Send]:
        """The length at ``t_s`` (unless sent ahead), then the commands due by then."""
        sends = [] if self.stamped else [Send(LENGTH, float(self.protocol.dl_mt(t_s)), t_s)]
        return sends + self._due(t_s, inclusive=True)

    def _due(self, t_s: float, inclusive: bool = False) -> list[Send]:
        """The commands not yet sent whose time is before ``t_s`` (or at it),
        each stamped with its own time."""
        times = self.times_s
        stop = int(np.searchsorted(times, t_s, side='right' if inclusive else 'left'))
        sends = [Send(CHANNELS, self._commands(k), k, self.t0_ns + round(k * NS_PER_S))
                 for k in times[self._next:stop].tolist()]
        self._next = max(self._next, stop)
        return sends

    def _commands(self, t_s: float, zero: bool = False) -> tuple[ChannelCommand, ...]:
        """Every channel's command at ``t_s`` (checked: :func:`channel_commands`)."""
        return channel_commands(self.protocol, t_s, self.profile, self.burst_interval_s, zero)
