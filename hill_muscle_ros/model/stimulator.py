"""Stimulators as profiles of limits: a command out of a device's range is an
error that names the field, the channel and the value (doc/model.md section 10).

Three profiles, as :class:`StimulatorProfile` (:func:`stimulator_profile` by name):

===========  ========  ======================  ===========  ==============================  =========
stimulator   channels  PW                      current      frequency                       bursts
===========  ========  ======================  ===========  ==============================  =========
generic      any       0 .. ``pw_max_s``       0 .. 0.2 A   0 .. 1000 Hz per channel        2-129 ms
rehastim2    8         0, or 20-500 us         0-130 mA     one for all, period 8-1025 ms   2-129 ms
p24          8         0-4095 us               0-130 mA     0.5-2000 Hz per channel         2-129 ms
===========  ========  ======================  ===========  ==============================  =========

The device numbers are read in pyScienceMode 1.1.5 (s2mLab, tag ``1.1.5``,
commit 66b8454), whose device classes check a command before it is sent:

- ``pysciencemode/channel.py``, ``Channel.check_value_param``: channel 1-8 on
  both devices; Rehastim2 amplitude 0-130 mA and pulse width 0-500 us; P24
  amplitude 0-130 mA, pulse width 0-4095 us and period 0.5-16383 ms (its
  message: frequency 0.5-2000 Hz). ``Channel.__init__`` and ``set_frequency``
  refuse a frequency per channel on the Rehastim2. The docstrings say that
  the Rehastim2 firmware raises a width below 20 us to 20 us (we reject it
  instead: no silent change) and give the P24 0-150 mA, but the checks (of
  ``Channel`` and of its ``Point``) stop at 130 mA: we keep what the code accepts.
- ``pysciencemode/utils.py``: ``check_stimulation_interval``, the Rehastim2's
  one main stimulation period for all channels, 8-1025 ms;
  ``check_inter_pulse_interval``, its interval between the pulses of a
  doublet or triplet, 2-129 ms.

The P24 has no such interval in pyScienceMode 1.1.5: ``Channel.create_doublet``
and ``create_triplet`` put a fixed 5 ms pause between biphasic pulses. Its
2-129 ms here are the Rehastim2's, kept so that the P24 accepts the same
bursts; they are not verified for the P24. The Rehastim2 sets its period in
0.5 ms steps and the pulse width in whole microseconds; the profiles check
ranges, not resolution.

A pulse width of 0 sends no pulse in this model (doc/model.md section 10);
pyScienceMode pauses a Rehastim2 channel by a zero amplitude, so a driver
should send 0 mA for it.
"""
from __future__ import annotations

import math
import operator
from dataclasses import dataclass
from typing import Any, Sequence

from .trains import DEFAULT_BURST_INTERVAL_S, MODES, PULSES_PER_BURST

#: Names of the profiles, the first the default.
STIMULATORS = ('generic', 'rehastim2', 'p24')


def _number(value: Any) -> float | None:
    """``float(value)`` for a finite real number (not a bool), else None."""
    if isinstance(value, bool):
        return None
    try:
        f = float(value)
    except (TypeError, ValueError, OverflowError):
        return None
    return f if math.isfinite(f) else None


def _channel_number(value: Any) -> int | None:
    """``value`` as an int if it is an integer (a NumPy or ROS ``uint8`` too), else None."""
    if isinstance(value, bool):
        return None
    try:
        return operator.index(value)
    except TypeError:
        return None


def _interval(text: str, values: Any, *, positive: bool = False) -> tuple[float, float]:
    """A closed interval [low, high] of finite non-negative numbers, low <= high."""
    pair = tuple(values) if isinstance(values, (tuple, list)) else ()
    nums = tuple(_number(v) for v in pair)
    if len(nums) != 2 or None in nums or nums[0] < 0.0 or nums[0] > nums[1] \
            or (positive and nums[0] <= 0.0):
        kind = 'positive' if positive else 'non-negative'
        raise ValueError(f'`{text}` must be a pair (low, high) of finite {kind} numbers, '
                         f'low <= high, got {values!r}')
    return nums


@dataclass(frozen=True)
class StimulatorProfile:
    """What one stimulator accepts.

    :param name: the profile's name, as the messages give it
    :param channel_count: [-] channels 1..count, or ``None`` for any number
    :param pulse_width_ranges_s: [s] the accepted pulse widths (PW), a union of
        closed intervals, e.g. ((0, 0), (20e-6, 500e-6)): 0, or 20-500 us
    :param current_max_a: [A] largest pulse current (I); the range is 0..max
    :param frequency_range_hz: [Hz] accepted burst frequencies (f)
    :param period_range_s: [s] the device's range of 1/f when it sets a period
        (the check is then on the period), else ``None``
    :param shared_frequency: True if one frequency holds for every channel
    :param burst_interval_range_s: [s] accepted intervals between the pulses of
        a doublet or triplet
    :raises ValueError: naming the field and the value
    """

    name: str
    channel_count: int | None
    pulse_width_ranges_s: tuple[tuple[float, float], ...]
    current_max_a: float
    frequency_range_hz: tuple[float, float]
    period_range_s: tuple[float, float] | None
    shared_frequency: bool
    burst_interval_range_s: tuple[float, float]

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(f'`name` must be a non-empty string, got {self.name!r}')
        count = self.channel_count
        if count is not None and (isinstance(count, bool) or not isinstance(count, int)
                                  or count < 1):
            raise ValueError(f'`channel_count` must be an integer >= 1 or None, got {count!r}')
        ranges = self.pulse_width_ranges_s
        if not isinstance(ranges, (tuple, list)) or not ranges:
            raise ValueError(f'`pulse_width_ranges_s` must hold at least one interval, '
                             f'got {ranges!r}')
        object.__setattr__(self, 'pulse_width_ranges_s', tuple(
            _interval('pulse_width_ranges_s', r) for r in ranges))
        current = _number(self.current_max_a)
        if current is None or current <= 0.0:
            raise ValueError(f'`current_max_a` must be positive and finite, '
                             f'got {self.current_max_a!r}')
        object.__setattr__(self, 'frequency_range_hz',
                           _interval('frequency_range_hz', self.frequency_range_hz))
        if self.period_range_s is not None:
            object.__setattr__(self, 'period_range_s',
                               _interval('period_range_s', self.period_range_s, positive=True))
        if not isinstance(self.shared_frequency, bool):
            raise ValueError(f'`shared_frequency` must be a bool, got {self.shared_frequency!r}')
        object.__setattr__(self, 'burst_interval_range_s', _interval(
            'burst_interval_range_s', self.burst_interval_range_s, positive=True))

    @property
    def pulse_width_text(self) -> str:
        """The accepted widths as the messages write them, e.g. ``0 or in [2e-05, 0.0005] s``."""
        parts = [f'{lo:g}' if lo == hi else f'in [{lo:g}, {hi:g}]'
                 for lo, hi in self.pulse_width_ranges_s]
        return ' or '.join(parts) + ' s'


#: [A] The generic profile's largest current: 0.2 A, above both devices' 130 mA.
GENERIC_CURRENT_MAX_A = 0.2
#: [Hz] The generic profile's frequencies, per channel.
GENERIC_FREQUENCY_RANGE_HZ = (0.0, 1000.0)
#: [s] Intervals between the pulses of a burst: pyScienceMode 1.1.5,
#: ``utils.check_inter_pulse_interval`` (Rehastim2), 2-129 ms.
BURST_INTERVAL_RANGE_S = (0.002, 0.129)


def generic_profile(pw_max_s: float) -> StimulatorProfile:
    """The ``generic`` stimulator: any channel, PW 0..``pw_max_s``, 0..0.2 A,
    0..1000 Hz per channel, bursts 2-129 ms apart.

    :param pw_max_s: [s] the muscle's PW_max (its ``pw_max_s``), > 0
    """
    pw_max = _number(pw_max_s)
    if pw_max is None or pw_max <= 0.0:
        raise ValueError(f'`pw_max_s` must be positive and finite, got {pw_max_s!r}')
    return StimulatorProfile('generic', None, ((0.0, pw_max),), GENERIC_CURRENT_MAX_A,
                             GENERIC_FREQUENCY_RANGE_HZ, None, False, BURST_INTERVAL_RANGE_S)


#: Hasomed RehaStim 2 as pyScienceMode 1.1.5 drives it (module docstring):
#: 8 channels; PW 0, or 20-500 us; 0-130 mA; one period of 8-1025 ms for all channels.
REHASTIM2 = StimulatorProfile(
    'rehastim2', 8, ((0.0, 0.0), (20e-6, 500e-6)), 0.130,
    (1.0 / 1.025, 1.0 / 0.008), (0.008, 1.025), True, BURST_INTERVAL_RANGE_S)

#: Hasomed RehaMove P24 as pyScienceMode 1.1.5 drives it (module docstring):
#: 8 channels; PW 0-4095 us; 0-130 mA; 0.5-2000 Hz per channel.
P24 = StimulatorProfile(
    'p24', 8, ((0.0, 4095e-6),), 0.130, (0.5, 2000.0), None, False, BURST_INTERVAL_RANGE_S)


def stimulator_profile(name: str, pw_max_s: float = 500e-6) -> StimulatorProfile:
    """The profile called ``name``.

    :param name: one of :data:`STIMULATORS`
    :param pw_max_s: [s] the muscle's PW_max, the ``generic`` profile's widest pulse
    :raises ValueError: for an unknown name
    """
    if name == 'generic':
        return generic_profile(pw_max_s)
    if name == 'rehastim2':
        return REHASTIM2
    if name == 'p24':
        return P24
    raise ValueError(f'`stimulator` must be one of {", ".join(STIMULATORS)}, got {name!r}')


@dataclass(frozen=True)
class ChannelCommand:
    """One channel's command, checked against a profile (:func:`check_channel_command`).

    :param channel: 1-based channel number
    :param mode: ``single``, ``doublet`` or ``triplet``
    :param pulse_width_s: [s] pulse width (PW)
    :param current_a: [A] pulse current (I), or ``None`` for the reference current
    :param frequency_hz: [Hz] burst frequency (f)
    """

    channel: int
    mode: str
    pulse_width_s: float
    current_a: float | None
    frequency_hz: float


def check_channel_command(profile: StimulatorProfile, channel: int, frequency_hz: float,
                          pulse_width_s: float, current_a: float | None, mode: str,
                          burst_interval_s: float = DEFAULT_BURST_INTERVAL_S
                          ) -> ChannelCommand:
    """Check one channel's command as the device would.

    :param profile: the stimulator
    :param channel: 1-based channel number
    :param frequency_hz: [Hz] burst frequency (f)
    :param pulse_width_s: [s] pulse width (PW)
    :param current_a: [A] pulse current (I), or ``None`` for the reference current
    :param mode: ``single``, ``doublet`` or ``triplet``
    :param burst_interval_s: [s] interval between the pulses of a burst; checked
        for a doublet or triplet only
    :return: the command, its numbers as floats
    :raises ValueError: naming the field, the channel, the stimulator and the value
    """
    on = profile.name
    count = profile.channel_count
    number = _channel_number(channel)
    if number is None or number < 1 or (count is not None and number > count):
        allowed = 'an integer >= 1' if count is None else f'in [1, {count}]'
        raise ValueError(f'`channel` must be {allowed} on {on}, got {channel!r}')
    channel = number
    where = f'of channel {channel}'
    if mode not in MODES:
        raise ValueError(f'`mode` {where} must be one of {", ".join(MODES)}, got {mode!r}')
    pw = _number(pulse_width_s)
    if pw is None or not any(lo <= pw <= hi for lo, hi in profile.pulse_width_ranges_s):
        raise ValueError(f'`pulse_width_s` {where} must be {profile.pulse_width_text} '
                         f'on {on}, got {pulse_width_s!r}')
    current = None
    if current_a is not None:
        current = _number(current_a)
        if current is None or not 0.0 <= current <= profile.current_max_a:
            raise ValueError(f'`current_a` {where} must be in [0, {profile.current_max_a:g}] '
                             f'A on {on}, got {current_a!r}')
    f = _number(frequency_hz)
    lo, hi = profile.frequency_range_hz
    if profile.period_range_s is not None:
        p_lo, p_hi = profile.period_range_s
        if f is None or f <= 0.0 or not p_lo <= 1.0 / f <= p_hi:
            raise ValueError(f'`frequency_hz` {where} must give a period in [{p_lo:g}, '
                             f'{p_hi:g}] s (f in [{lo:.6g}, {hi:.6g}] Hz) on {on}, '
                             f'got {frequency_hz!r}')
    elif f is None or not lo <= f <= hi:
        raise ValueError(f'`frequency_hz` {where} must be in [{lo:g}, {hi:g}] Hz on {on}, '
                         f'got {frequency_hz!r}')
    n = PULSES_PER_BURST[mode]
    if n > 1:
        d = _number(burst_interval_s)
        b_lo, b_hi = profile.burst_interval_range_s
        if d is None or not b_lo <= d <= b_hi:
            raise ValueError(f'`burst_interval_s` {where} must be in [{b_lo:g}, {b_hi:g}] s '
                             f'on {on}, got {burst_interval_s!r}')
        if (n - 1) * d * f >= 1.0:
            raise ValueError(f'`frequency_hz` {where} must be below {1.0 / ((n - 1) * d):g} Hz '
                             f'for a {mode} with pulses {d:g} s apart on {on} (its bursts '
                             f'would overlap), got {frequency_hz!r}')
    return ChannelCommand(channel, mode, pw, current, f)


def check_stimulation(profile: StimulatorProfile, channel: Sequence[int], mode: Sequence[str],
                      pulse_width_s: Sequence[float], current_a: Sequence[float],
                      frequency_hz: Sequence[float],
                      burst_interval_s: float = DEFAULT_BURST_INTERVAL_S
                      ) -> tuple[ChannelCommand, ...]:
    """Check a command for several channels, as parallel arrays (the fields of
    the ``Stimulation`` message): entry k commands channel ``channel[k]``.

    :param profile: the stimulator
    :param channel: 1-based channel numbers, each at most once
    :param mode: ``single``, ``doublet`` or ``triplet`` per entry
    :param pulse_width_s: [s] PW per entry
    :param current_a: [A] I per entry, or empty for the reference current on every channel
    :param frequency_hz: [Hz] f per entry; one value on a stimulator with a shared frequency
    :param burst_interval_s: [s] interval between the pulses of a burst
    :return: the channels' commands, in the order given
    :raises ValueError: for arrays of unequal length (naming the lengths), a
        repeated or out-of-range channel, a channel's command out of range
        (:func:`check_channel_command`), or different frequencies on a
        stimulator that has one for all channels
    """
    arrays = {'channel': channel, 'mode': mode, 'pulse_width_s': pulse_width_s,
              'frequency_hz': frequency_hz, 'current_a': current_a}
    lengths = {}
    for key, values in arrays.items():
        try:
            lengths[key] = len(values)
        except TypeError:
            raise ValueError(f'`{key}` must be an array, got {values!r}') from None
    n = lengths['channel']
    if any(lengths[k] != n for k in ('mode', 'pulse_width_s', 'frequency_hz')) \
            or lengths['current_a'] not in (0, n):
        given = ', '.join(f'{k} {v}' for k, v in lengths.items())
        raise ValueError(f'the arrays of a stimulation command must have equal lengths '
                         f'(`current_a` may be empty), got {given}')
    seen: dict[int, int] = {}
    for k, c in enumerate(channel):
        number = _channel_number(c)
        if number in seen:
            raise ValueError(f'`channel` {number} is given twice (entries {seen[number]} and '
                             f'{k}) on {profile.name}')
        if number is not None:
            seen[number] = k
    commands = tuple(
        check_channel_command(profile, channel[k], frequency_hz[k], pulse_width_s[k],
                              current_a[k] if lengths['current_a'] else None, mode[k],
                              burst_interval_s)
        for k in range(n))
    if profile.shared_frequency and commands:
        first = commands[0]
        for other in commands[1:]:
            if other.frequency_hz != first.frequency_hz:
                raise ValueError(
                    f'`frequency_hz` must be the same on every channel on {profile.name} '
                    f'(one stimulation period for all channels), got {first.frequency_hz:g} '
                    f'Hz on channel {first.channel} and {other.frequency_hz:g} Hz on '
                    f'channel {other.channel}')
    return commands
