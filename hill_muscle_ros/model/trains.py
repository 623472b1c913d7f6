"""A channel's pulse train: when a stimulator sends its pulses (doc/model.md section 10).

A stimulator does not send a level: it sends pulses, each with a time, a width
PW [s] and a current I [A]. A channel's *train* is given by its frequency f
[Hz], its pulse width, its current (optional: without one, the pulses carry
``None`` and the muscle reads its reference current) and its mode:
``single``, ``doublet`` or ``triplet``, one, two or three pulses per *burst*,
``burst_interval_s`` apart (default 5 ms: the catch-like doublet of
Binder-Macleod's trains; Bickel et al. 2004 space the opening pulses of their
variable-frequency trains 5 ms apart).

The rules, each exact in time (no step quantisation: a caller that
integrates across pulses splits its step at each one):

- The channel *stimulates* while PW > 0 and, if a current is given, I > 0.
- A train starts with a burst at the instant its stimulation becomes non-zero
  (and at the start, if it is non-zero there). PW = 0 or I = 0 sends no pulse,
  and a stimulation back to non-zero starts a new train at that instant.
- The next burst comes 1/f after the previous one, f read at the previous
  burst. A run of bursts at one frequency is timed from its first burst,
  t_n = t_a + n / f, so a constant train has no drift from summed periods.
- A burst's pulses all carry the PW and I read at its first pulse (a
  stimulator takes one command per burst); a stimulation that becomes zero
  cuts the rest of the burst.

The inputs are tracks: a number (held) or knots, any object with the arrays
``times_s`` and ``values`` of :class:`~hill_muscle_ros.model.protocol.Knots`
(linear between knots, right-continuous at a repeated time, held outside).
PW and I are non-negative, so the stimulation can only switch at a knot time
of PW or I: on each open interval between two of them a track is linear, and
it is zero there only if both ends are. The train therefore walks those knot
times, never a sampled grid.

:func:`advance` is the pure core: a :class:`TrainState` and the interval
[state.time_s, t1) in, the pulses and the next state out. :class:`PulseTrain`
keeps the state and answers step by step; consecutive calls give exactly the
pulses of one call over the whole interval.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

#: Modes of a train and the pulses of one burst in each.
MODES = ('single', 'doublet', 'triplet')
PULSES_PER_BURST = {'single': 1, 'doublet': 2, 'triplet': 3}
#: [s] Default interval between the pulses of a burst (doublet or triplet): 5 ms,
#: the opening interval of Bickel et al.'s (2004) catch-like trains of the
#: quadriceps (doc/model.md section 10).
DEFAULT_BURST_INTERVAL_S = 0.005


class Pulse(NamedTuple):
    """One pulse as a stimulator sends it.

    :param time_s: [s] when it is sent
    :param pulse_width_s: [s] its width (PW), > 0
    :param current_a: [A] its current (I), > 0, or ``None``: the reference current
    """

    time_s: float
    pulse_width_s: float
    current_a: float | None


#: The knot time of a held number's track (never written to).
_ZERO_TIME = np.zeros(1)
_ZERO_TIME.flags.writeable = False


def _track(value: Any, name: str, channel: int) -> tuple[np.ndarray, np.ndarray]:
    """(times, values) of a track given as a number or as knots."""
    times = getattr(value, 'times_s', None)
    values = getattr(value, 'values', None)
    if times is None or values is None:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f'`{name}` of channel {channel} must be a number or knots '
                             f'(times_s, values), got {value!r}')
        if math.isfinite(value) and value >= 0.0:
            # A held number (a stimulator's command): the checks below hold
            # already; a node builds one per channel for each message it takes.
            return _ZERO_TIME, np.array((float(value),))
        times, values = (0.0,), (value,)
    times = np.asarray(times, dtype=float).ravel()
    values = np.asarray(values, dtype=float).ravel()
    if times.size == 0 or times.size != values.size:
        raise ValueError(f'`{name}` of channel {channel} must have as many times as values, '
                         f'at least one, got {times.size} and {values.size}')
    if not (np.all(np.isfinite(times)) and np.all(np.isfinite(values))):
        raise ValueError(f'`{name}` of channel {channel} must be finite, got '
                         f'times {times.tolist()} and values {values.tolist()}')
    if np.any(np.diff(times) < 0.0):
        raise ValueError(f'`{name}` of channel {channel}: knot times must not decrease, '
                         f'got {times.tolist()}')
    if np.any(values < 0.0):
        raise ValueError(f'`{name}` of channel {channel} must be non-negative, '
                         f'got {values.min()!r}')
    return times, values


def _at(track: tuple[np.ndarray, np.ndarray], t_s: float) -> float:
    """The track's value at ``t_s`` (the last knot of a repeated time: right-continuous)."""
    return float(np.interp(t_s, track[0], track[1]))


def _left_of(track: tuple[np.ndarray, np.ndarray], t_s: float) -> float:
    """The track's limit from the left at ``t_s`` (the first knot of a repeated time)."""
    times, values = track
    i = int(np.searchsorted(times, t_s, side='left'))
    if i < times.size and times[i] == t_s:
        return float(values[i])   # the linear piece before t_s ends there
    return _at(track, t_s)


@dataclass(frozen=True, eq=False)
class ChannelTrain:
    """What one channel is told to send: its tracks and its mode.

    :param frequency_hz: [Hz] burst frequency (f), a number or knots; >= 0, and
        > 0 wherever a burst reads it
    :param pulse_width_s: [s] pulse width (PW), a number or knots, >= 0
    :param current_a: [A] pulse current (I), a number or knots, >= 0, or ``None``
        for the muscle's reference current
    :param mode: ``single``, ``doublet`` or ``triplet``
    :param burst_interval_s: [s] interval between the pulses of a burst, > 0
    :param channel: 1-based channel number, for the messages
    :raises ValueError: naming the field, the channel and the value
    """

    frequency_hz: Any
    pulse_width_s: Any
    current_a: Any = None
    mode: str = 'single'
    burst_interval_s: float = DEFAULT_BURST_INTERVAL_S
    channel: int = 1
    _f: tuple = field(init=False, repr=False, compare=False)
    _pw: tuple = field(init=False, repr=False, compare=False)
    _i: tuple | None = field(init=False, repr=False, compare=False)
    _knot_times: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if isinstance(self.channel, bool) or not isinstance(self.channel, int) \
                or self.channel < 1:
            raise ValueError(f'`channel` must be an integer >= 1, got {self.channel!r}')
        c = self.channel
        if self.mode not in MODES:
            raise ValueError(f'`mode` of channel {c} must be one of {", ".join(MODES)}, '
                             f'got {self.mode!r}')
        d = self.burst_interval_s
        if isinstance(d, bool) or not isinstance(d, (int, float)) or not math.isfinite(d) \
                or d <= 0.0:
            raise ValueError(f'`burst_interval_s` of channel {c} must be positive and finite, '
                             f'got {d!r}')
        pw = _track(self.pulse_width_s, 'pulse_width_s', c)
        current = None if self.current_a is None else _track(self.current_a, 'current_a', c)
        object.__setattr__(self, '_f', _track(self.frequency_hz, 'frequency_hz', c))
        object.__setattr__(self, '_pw', pw)
        object.__setattr__(self, '_i', current)
        if pw[0] is _ZERO_TIME and (current is None or current[0] is _ZERO_TIME):
            knots = _ZERO_TIME
        else:
            knots = np.unique(pw[0] if current is None else np.concatenate((pw[0], current[0])))
        object.__setattr__(self, '_knot_times', knots)

    @property
    def pulses_per_burst(self) -> int:
        """[-] 1, 2 or 3: the pulses of one burst in this mode."""
        return PULSES_PER_BURST[self.mode]

    def frequency_at(self, t_s: float) -> float:
        """[Hz] f of the track at ``t_s`` (what a burst there reads)."""
        return _at(self._f, t_s)

    def stimulating(self, t_s: float) -> bool:
        """True if the channel stimulates at ``t_s``: PW > 0 and (no current or I > 0)."""
        return _at(self._pw, t_s) > 0.0 and (self._i is None or _at(self._i, t_s) > 0.0)

    def _stimulating_between(self, a_s: float, b_s: float) -> bool:
        """True if it stimulates on the open interval (a, b), which holds no knot time
        of PW or I: a non-negative linear piece is zero inside only if both ends are."""
        def on(track):
            return _at(track, a_s) > 0.0 or _left_of(track, b_s) > 0.0
        return on(self._pw) and (self._i is None or on(self._i))

    def _burst(self, t_s: float) -> tuple[float, tuple[Pulse, ...]]:
        """[Hz] f read at a burst at ``t_s``, and the burst's pulses (none if it
        does not stimulate there)."""
        f = _at(self._f, t_s)
        if not f > 0.0:
            raise ValueError(f'`frequency_hz` of channel {self.channel} must be positive '
                             f'where a burst reads it, got {f!r} at t = {t_s!r} s')
        n = self.pulses_per_burst
        if (n - 1) * self.burst_interval_s * f >= 1.0:
            raise ValueError(
                f'`frequency_hz` of channel {self.channel} must be below '
                f'{1.0 / ((n - 1) * self.burst_interval_s):g} Hz for a {self.mode} with '
                f'pulses {self.burst_interval_s:g} s apart (its bursts would overlap), got '
                f'{f!r} at t = {t_s!r} s')
        if not self.stimulating(t_s):
            return f, ()
        pw = _at(self._pw, t_s)
        current = None if self._i is None else _at(self._i, t_s)
        return f, tuple(Pulse(t_s + m * self.burst_interval_s, pw, current) for m in range(n))


@dataclass(frozen=True)
class TrainState:
    """Where a train stands at ``time_s``: all :func:`advance` needs to go on.

    :param time_s: [s] the end of the pulses given so far
    :param running: True if the channel stimulated just before ``time_s`` (a
        train is running); False before the start
    :param anchor_s: [s] the first burst of the current run at one frequency (t_a)
    :param anchor_hz: [Hz] that run's frequency (0 before its first burst)
    :param count: [-] bursts of the run so far (n); the next is at t_a + n / f,
        or at t_a itself while n = 0
    :param pending: the rest of a burst that started before ``time_s``
    """

    time_s: float
    running: bool = False
    anchor_s: float = 0.0
    anchor_hz: float = 0.0
    count: int = 0
    pending: tuple[Pulse, ...] = ()

    @property
    def next_burst_s(self) -> float:
        """[s] When the running train's next burst comes."""
        if self.count == 0:
            return self.anchor_s
        return self.anchor_s + self.count / self.anchor_hz


def advance(train: ChannelTrain, state: TrainState,
            t1_s: float) -> tuple[tuple[Pulse, ...], TrainState]:
    """The pulses of ``train`` in [state.time_s, t1), and the state at t1.

    ``train`` may differ from the one the state came from (a new command): the
    schedule carries over, a burst already started keeps its values.

    :param train: the channel's tracks and mode
    :param state: the state at the start of the interval
    :param t1_s: [s] end of the interval (excluded), >= state.time_s
    :return: the pulses in time order, and the state at ``t1_s``
    :raises ValueError: for an interval that ends before it starts, or a burst
        that reads a frequency <= 0 or so high that bursts overlap (naming the
        channel, the value and the time)
    """
    t0 = state.time_s
    if not (math.isfinite(t1_s) and t1_s >= t0):
        raise ValueError(f'`t1_s` must be finite and >= {t0!r} s (where channel '
                         f'{train.channel} stands), got {t1_s!r}')
    if t1_s == t0:
        return (), state
    out: list[Pulse] = []
    running, pending = state.running, state.pending
    anchor_s, anchor_hz, count = state.anchor_s, state.anchor_hz, state.count
    knots = train._knot_times
    inner = knots[np.searchsorted(knots, t0, side='right'):np.searchsorted(knots, t1_s)]
    points = [t0, *inner.tolist()]
    for j, b in enumerate(points):
        end = points[j + 1] if j + 1 < len(points) else t1_s
        on_at = train.stimulating(b)
        on_after = on_at or train._stimulating_between(b, end)
        if not on_after:
            running, pending, count = False, (), 0   # the train stops (or stays off)
            continue
        if not (running and on_at):
            # Stimulation becomes non-zero at b (or dips to zero at b alone):
            # a new train, its first burst at b.
            pending, anchor_s, anchor_hz, count = (), b, 0.0, 0
        running = True
        out.extend(p for p in pending if p.time_s < end)
        pending = tuple(p for p in pending if p.time_s >= end)
        tb = anchor_s if count == 0 else anchor_s + count / anchor_hz
        while tb < end:
            f, burst = train._burst(tb)
            out.extend(p for p in burst if p.time_s < end)
            pending = tuple(p for p in burst if p.time_s >= end)
            if count > 0 and f == anchor_hz:
                count += 1
            else:
                anchor_s, anchor_hz, count = tb, f, 1
            tb = anchor_s + count / anchor_hz
    return tuple(out), TrainState(t1_s, running, anchor_s, anchor_hz, count, pending)


class PulseTrain:
    """One channel's train, step by step: :meth:`pulses` answers [t0, t1) for
    consecutive intervals, exactly as one call over their union would.

    :param train: the channel's tracks and mode (:attr:`train` may be replaced
        between calls to change the command; the schedule carries over)
    :param start_s: [s] where the train starts; the channel is off before
    """

    def __init__(self, train: ChannelTrain, start_s: float = 0.0) -> None:
        if isinstance(start_s, bool) or not isinstance(start_s, (int, float)) \
                or not math.isfinite(start_s):
            raise ValueError(f'`start_s` must be a finite number, got {start_s!r}')
        self.train = train
        self.state = TrainState(float(start_s))

    def pulses(self, t0_s: float, t1_s: float) -> tuple[Pulse, ...]:
        """The pulses in [t0, t1), t0 where the previous call ended (or the start).

        :param t0_s: [s] start of the interval, = :attr:`state`.time_s
        :param t1_s: [s] end of the interval (excluded), >= t0
        :raises ValueError: if t0 does not continue the train, or as :func:`advance`
        """
        if t0_s != self.state.time_s:
            raise ValueError(f'`t0_s` must be where channel {self.train.channel}\'s train '
                             f'stands, {self.state.time_s!r} s, got {t0_s!r}')
        found, self.state = advance(self.train, self.state, t1_s)
        return found
