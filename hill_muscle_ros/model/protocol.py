"""Stimulation protocols as data: piecewise-linear knots loaded from YAML.

A protocol gives the recruitment (or the pulse width) and the MTU length
change as lists of knots ``[time_s, value]``. Between knots the value is
linear; a repeated time is a step, and the value there is that of the *last*
knot with that time (right-continuous). Before the first knot and after the
last one the nearest knot's value holds. See ``config/protocols/*.yaml``.

A protocol with ``channels`` (:class:`PulseProtocol`) gives pulse trains
instead of a level: per channel, knots of ``frequency_hz`` and
``pulse_width_s``, optionally ``current_a``, and a constant ``mode``
(doc/model.md section 10). :func:`read_protocol` loads either kind.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .muscle import DL_MT_LIMIT_M
from .params import finite_float
from .trains import (DEFAULT_BURST_INTERVAL_S, MODES, PULSES_PER_BURST, ChannelTrain, Pulse,
                     TrainState, advance)

#: Keys a protocol file may have; exactly one stimulation key is required.
STIMULATION_KEYS = ('recruitment', 'pulse_width_s')
ALLOWED_KEYS = ('name', 'duration_s', *STIMULATION_KEYS, 'dl_mt_m')
#: Topics a protocol can drive a stimulator on (the player's ``output``).
STIMULATION_OUTPUTS = ('pulse_width', 'recruitment')
#: Keys of a protocol that gives pulse trains per channel (:class:`PulseProtocol`).
PULSE_ALLOWED_KEYS = ('name', 'duration_s', 'channels', 'dl_mt_m')
#: Keys of one entry of ``channels``; ``frequency_hz`` and ``pulse_width_s`` are required.
CHANNEL_KEYS = ('frequency_hz', 'pulse_width_s', 'current_a', 'mode', 'burst_interval_s')


#: libyaml's parser when PyYAML was built with it (about 10x faster to load a
#: long protocol), else the pure-Python one; both are the *safe* loader.
_YAML_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


def commands_from_pulse_widths(pulse_widths_s, params, name: str = 'pulse_width_s'
                               ) -> np.ndarray:
    """[-] the recruitment command of every pulse width of an array: each distinct
    width through :func:`~hill_muscle_ros.model.stimulus.command_from_pulse_width`
    once (a protocol holds a few widths over thousands of samples).

    :param pulse_widths_s: [s] pulse widths (PW), any shape
    :param params: the muscle's :class:`~hill_muscle_ros.model.params.MuscleParams`
    :param name: what to call a width in the error message
    :return: [-] u, the shape of ``pulse_widths_s``
    :raises ValueError: naming a negative or non-finite width
    """
    from .stimulus import command_from_pulse_width
    values = np.asarray(pulse_widths_s, dtype=float)
    flat = values.ravel()
    if flat.size == 0:
        return np.zeros(values.shape)
    # The runs of equal samples, each width through the curve once, by a dict:
    # np.unique and np.diff cost more than the few widths of a protocol (a
    # knee run's pulse widths: 218 us with them, cold caches, by hand).
    starts = np.flatnonzero(np.concatenate(([True], flat[1:] != flat[:-1])))
    counts = np.empty_like(starts)
    counts[:-1] = starts[1:] - starts[:-1]
    counts[-1] = flat.size - starts[-1]
    widths = flat[starts].tolist()
    commands = {w: command_from_pulse_width(w, params, name) for w in dict.fromkeys(widths)}
    return np.repeat(np.array([commands[w] for w in widths]), counts).reshape(values.shape)


def safe_load_yaml(text: str):
    """Parse YAML text with the safe loader (no arbitrary Python objects).

    :raises yaml.YAMLError: on a syntax error
    """
    return yaml.load(text, Loader=_YAML_LOADER)  # noqa: S506 - a SafeLoader


class ProtocolError(ValueError):
    """A protocol file or mapping is malformed; the message says where and why."""


@dataclass(frozen=True)
class Knots:
    """Piecewise-linear, right-continuous signal given by knots.

    :param times_s: [s] knot times, non-decreasing
    :param values: knot values, in the signal's unit
    """

    times_s: np.ndarray
    values: np.ndarray

    def __call__(self, t_s: np.ndarray | float) -> np.ndarray | float:
        """Sample the signal at one time or an array of times.

        :param t_s: [s] time(s) to sample at
        :return: the value(s), same shape as ``t_s``
        """
        # np.interp is this signal: it holds the first and last values outside
        # the knots, and at a repeated time its search lands on the last knot of
        # that time, so steps are right-continuous. numpy documents xp as
        # increasing, not as non-decreasing: test_model_protocol checks the
        # repeated times against the definition (numpy 2.x). It is
        # 5x faster than the same interpolation in whole-array steps, which
        # differs from it by rounding only (5e-16 of the values' range, checked
        # on 3000 random knot sets): a limb protocol's three signals cost
        # 0.2 ms of a knee's 3.5 ms compiled run before.
        out = np.interp(np.asarray(t_s, dtype=float), self.times_s, self.values)
        return float(out) if out.ndim == 0 else out

    @property
    def breakpoints_s(self) -> np.ndarray:
        """[s] distinct knot times, where the signal may have a kink or step."""
        return np.unique(self.times_s)


@dataclass(frozen=True)
class Protocol:
    """A stimulation protocol: recruitment or pulse width, and MTU length, over time.

    :param name: human-readable name
    :param duration_s: [s] length of the protocol
    :param stimulation: recruitment [-] or pulse width [s] knots
    :param stimulation_key: ``recruitment`` or ``pulse_width_s``
    :param dl_mt_m: [m] MTU length change knots
    """

    name: str
    duration_s: float
    stimulation: Knots
    stimulation_key: str
    dl_mt_m: Knots

    def recruitment(self, t_s: np.ndarray | float, pw_max_s: float) -> np.ndarray | float:
        """Recruitment R(t) in [0, 1]; pulse widths map through ``pw_max_s``.

        :param t_s: [s] time(s)
        :param pw_max_s: [s] pulse width that recruits every unit (PW_max)
        :return: [-] R at those times
        """
        values = self.stimulation(t_s)
        if self.stimulation_key == 'pulse_width_s':
            values = np.minimum(np.asarray(values) / pw_max_s, 1.0)
            return float(values) if values.ndim == 0 else values
        return values

    def command(self, t_s: np.ndarray | float, params) -> np.ndarray | float:
        """Recruitment command u(t) in [0, 1]: pulse widths through the muscle's
        recruitment curve (:func:`~hill_muscle_ros.model.stimulus.command_from_pulse_width`),
        recruitment values as they are.

        :param t_s: [s] time(s)
        :param params: the muscle's :class:`~hill_muscle_ros.model.params.MuscleParams`
        :return: [-] u at those times
        """
        if self.stimulation_key != 'pulse_width_s' or params.recruitment_curve == 'linear':
            return self.recruitment(t_s, params.pw_max_s)
        u = commands_from_pulse_widths(self.stimulation(t_s), params)
        return float(u) if u.ndim == 0 else u

    def stimulation_command(self, t_s: float, output: str, params) -> float:
        """The value a stimulator is sent at ``t_s`` on the topic ``output``.

        ``recruitment``: the command u(t), pulse widths through the muscle's
        recruitment curve. ``pulse_width``: the protocol's own pulse widths
        (unclipped, as the stimulator would get them), or the width that gives
        R(t) on the curve (:func:`~hill_muscle_ros.model.stimulus.pulse_width_for_command`).

        :param t_s: [s] time
        :param output: ``pulse_width`` or ``recruitment``
        :param params: the muscle's :class:`~hill_muscle_ros.model.params.MuscleParams`
            (its curve fields), or, as before the curves existed, PW_max [s]
            alone for the linear curve
        :return: [-] u or [s] pulse width
        """
        from .params import MuscleParams
        from .stimulus import pulse_width_for_command
        if not isinstance(params, MuscleParams):
            params = MuscleParams(pw_max_s=params)
        if output not in STIMULATION_OUTPUTS:
            raise ValueError(f'`output` must be one of {", ".join(STIMULATION_OUTPUTS)}, '
                             f'got {output!r}')
        if output == 'recruitment':
            return float(self.command(t_s, params))
        if self.stimulation_key == 'pulse_width_s':
            return float(self.stimulation(t_s))
        return pulse_width_for_command(float(self.stimulation(t_s)), params)

    def dl_mt(self, t_s: np.ndarray | float) -> np.ndarray | float:
        """MTU length change dl_MT(t) [m]."""
        return self.dl_mt_m(t_s)

    @classmethod
    def from_mapping(cls, data: Any, source: str = '<protocol>') -> 'Protocol':
        """Validate a mapping (a parsed YAML document) and build a protocol.

        :param data: the parsed document
        :param source: the file name, for error messages
        :raises ProtocolError: naming the file, key and entry on any defect
        """
        if isinstance(data, dict) and 'channels' in data:
            _reject_level_with_channels(data, source)
            raise ProtocolError(f'{source}: `channels` gives pulse trains per channel: load it '
                                'with PulseProtocol (or read_protocol), for a muscle with '
                                '`activation_model: ding2003` (doc/model.md section 10)')
        duration_s = check_protocol_keys(data, source, ALLOWED_KEYS,
                                         ('name', 'duration_s', 'dl_mt_m'))
        given = [k for k in STIMULATION_KEYS if k in data]
        if len(given) != 1:
            raise ProtocolError(f'{source}: give exactly one of `recruitment` or '
                                f'`pulse_width_s`, got {len(given)}')
        name = data['name']
        key = given[0]
        if key == 'recruitment':
            stim = _parse_knots(data[key], source, key, 0.0, 1.0, 'in [0, 1]')
        else:
            stim = _parse_knots(data[key], source, key, 0.0, math.inf, 'non-negative')
        dl = _parse_dl_mt(data['dl_mt_m'], source)
        return cls(name=name, duration_s=duration_s, stimulation=stim,
                   stimulation_key=key, dl_mt_m=dl)

    @classmethod
    def from_yaml(cls, path: str | Path) -> 'Protocol':
        """Load and validate a protocol file.

        :param path: path to the YAML file
        :raises ProtocolError: if the file cannot be read or is malformed
        """
        path = Path(path)
        return cls.from_mapping(_read_yaml(path), source=str(path))


def _read_yaml(path: Path) -> Any:
    """The parsed document of a protocol file.

    :raises ProtocolError: if the file cannot be read or is not YAML
    """
    try:
        text = path.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as err:
        raise ProtocolError(f'{path}: cannot read protocol file: {err}') from None
    try:
        return safe_load_yaml(text)
    except yaml.YAMLError as err:
        raise ProtocolError(f'{path}: not valid YAML: {err}') from None


def check_protocol_keys(data: Any, source: str, allowed: tuple[str, ...],
                        required: tuple[str, ...]) -> float:
    """Check a parsed protocol's keys, its ``name`` and its ``duration_s``.

    :param allowed: the keys the format has
    :param required: the keys it must have (``name`` and ``duration_s`` among them)
    :return: [s] the duration
    :raises ProtocolError: naming the file and the key
    """
    if not isinstance(data, dict):
        raise ProtocolError(f'{source}: expected a mapping with keys '
                            f'{", ".join(allowed)}, got {type(data).__name__}')
    unknown = [k for k in data if k not in allowed]
    if unknown:
        raise ProtocolError(f'{source}: unknown key `{unknown[0]}` '
                            f'(allowed: {", ".join(allowed)})')
    for key in required:
        if key not in data:
            raise ProtocolError(f'{source}: missing key `{key}`')
    name = data['name']
    if not isinstance(name, str) or not name.strip():
        raise ProtocolError(f'{source}: `name` must be a non-empty string, got {name!r}')
    duration = data['duration_s']
    duration_s = (None if isinstance(duration, bool) or not isinstance(duration, (int, float))
                  else finite_float(duration))
    if duration_s is None or duration_s <= 0:
        raise ProtocolError(f'{source}: `duration_s` must be a positive finite '
                            f'number, got {duration!r}')
    return duration_s


def _parse_dl_mt(raw: Any, source: str) -> Knots:
    """The ``dl_mt_m`` knots of a protocol, each within ±:data:`DL_MT_LIMIT_M` of rest.

    :raises ProtocolError: naming the file and the entry on any defect
    """
    return _parse_knots(raw, source, 'dl_mt_m', -DL_MT_LIMIT_M, DL_MT_LIMIT_M,
                        f'within ±{DL_MT_LIMIT_M} m')


def _parse_knots(raw: Any, source: str, key: str, low: float, high: float,
                 range_text: str) -> Knots:
    """Validate a list of ``[time_s, value]`` knots."""
    if not isinstance(raw, list) or not raw:
        raise ProtocolError(f'{source}: `{key}` must be a non-empty list of '
                            f'[time_s, value] knots, got {raw!r}')
    times: list[float] = []
    values: list[float] = []
    for i, knot in enumerate(raw):
        where = f'{source}: `{key}` entry {i} ({knot!r})'
        if not isinstance(knot, (list, tuple)) or len(knot) != 2:
            raise ProtocolError(f'{where}: must be a pair [time_s, value]')
        if any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in knot):
            raise ProtocolError(f'{where}: time and value must be numbers')
        t, v = finite_float(knot[0]), finite_float(knot[1])
        if t is None or v is None:
            raise ProtocolError(f'{where}: time and value must be finite')
        if t < 0.0:
            raise ProtocolError(f'{where}: time must be >= 0, got {t!r}')
        if times and t < times[-1]:
            raise ProtocolError(f'{where}: times must not decrease '
                                f'({t!r} after {times[-1]!r})')
        if not low <= v <= high:
            raise ProtocolError(f'{where}: value must be {range_text}, got {v!r}')
        times.append(t)
        values.append(v)
    return Knots(np.array(times), np.array(values))



def _reject_level_with_channels(data: dict, source: str) -> None:
    """A protocol with ``channels`` has no top-level level stimulation."""
    level = [k for k in STIMULATION_KEYS if k in data]
    if 'channels' in data and level:
        raise ProtocolError(f'{source}: a protocol with `channels` gives its stimulation per '
                            f'channel and must not also have `{level[0]}` at the top (give '
                            '`pulse_width_s` in each channel)')


def _parse_channel(raw: Any, source: str, channel: int) -> ChannelTrain:
    """Validate one entry of ``channels`` (channel ``channel``, 1-based)."""
    where = f'{source}: channel {channel}'
    if not isinstance(raw, dict):
        raise ProtocolError(f'{where}: expected a mapping with keys {", ".join(CHANNEL_KEYS)}, '
                            f'got {type(raw).__name__}')
    unknown = [k for k in raw if k not in CHANNEL_KEYS]
    if unknown:
        raise ProtocolError(f'{where}: unknown key `{unknown[0]}` '
                            f'(allowed: {", ".join(CHANNEL_KEYS)})')
    for key in ('frequency_hz', 'pulse_width_s'):
        if key not in raw:
            raise ProtocolError(f'{where}: missing key `{key}`')
    mode = raw.get('mode', 'single')
    if not isinstance(mode, str) or mode not in MODES:
        raise ProtocolError(f'{where}: `mode` must be one of {", ".join(MODES)}, got {mode!r}')
    burst = raw.get('burst_interval_s', DEFAULT_BURST_INTERVAL_S)
    burst_s = (None if isinstance(burst, bool) or not isinstance(burst, (int, float))
               else finite_float(burst))
    if burst_s is None or burst_s <= 0.0:
        raise ProtocolError(f'{where}: `burst_interval_s` must be a positive finite number, '
                            f'got {burst!r}')
    frequency = _parse_knots(raw['frequency_hz'], where, 'frequency_hz', math.ulp(0.0),
                             math.inf, 'positive')
    pulse_width = _parse_knots(raw['pulse_width_s'], where, 'pulse_width_s', 0.0, math.inf,
                               'non-negative')
    current = (_parse_knots(raw['current_a'], where, 'current_a', 0.0, math.inf,
                            'non-negative') if 'current_a' in raw else None)
    n = PULSES_PER_BURST[mode]
    if n > 1:
        # f is linear between knots: its largest value is at a knot.
        i = int(np.argmax(frequency.values))
        f = float(frequency.values[i])
        if (n - 1) * burst_s * f >= 1.0:
            raise ProtocolError(
                f'{where}: `frequency_hz` entry {i} must stay below '
                f'{1.0 / ((n - 1) * burst_s):g} Hz for a {mode} with pulses {burst_s:g} s '
                f'apart (its bursts would overlap), got {f!r}')
    return ChannelTrain(frequency, pulse_width, current, mode, burst_s, channel)


@dataclass(frozen=True, eq=False)
class PulseProtocol:
    """A protocol of pulse trains: per channel, what its stimulator is told
    (:class:`~hill_muscle_ros.model.trains.ChannelTrain`), and the MTU length.

    :func:`~hill_muscle_ros.model.simulate.simulate` runs it on a muscle with
    ``activation_model: ding2003`` (doc/model.md section 10).

    :param name: human-readable name
    :param duration_s: [s] length of the protocol
    :param channels: channel 1, 2, ... in order
    :param dl_mt_m: [m] MTU length change knots
    """

    name: str
    duration_s: float
    channels: tuple[ChannelTrain, ...]
    dl_mt_m: Knots

    def dl_mt(self, t_s: np.ndarray | float) -> np.ndarray | float:
        """MTU length change dl_MT(t) [m]."""
        return self.dl_mt_m(t_s)

    def pulses(self) -> tuple[tuple[Pulse, ...], ...]:
        """Each channel's pulses in [0, ``duration_s``), channel 1 first
        (:func:`~hill_muscle_ros.model.trains.advance` from the start)."""
        return tuple(advance(train, TrainState(0.0), self.duration_s)[0]
                     for train in self.channels)

    @classmethod
    def from_mapping(cls, data: Any, source: str = '<protocol>') -> 'PulseProtocol':
        """Validate a mapping (a parsed YAML document) and build a pulse protocol.

        :param data: the parsed document, with ``channels``
        :param source: the file name, for error messages
        :raises ProtocolError: naming the file, the channel, the key and the entry
        """
        if isinstance(data, dict):
            _reject_level_with_channels(data, source)
        duration_s = check_protocol_keys(data, source, PULSE_ALLOWED_KEYS,
                                         ('name', 'duration_s', 'channels', 'dl_mt_m'))
        raw = data['channels']
        if not isinstance(raw, list) or not raw:
            raise ProtocolError(f'{source}: `channels` must be a non-empty list of channels '
                                f'(mappings with keys {", ".join(CHANNEL_KEYS)}), got {raw!r}')
        channels = tuple(_parse_channel(entry, source, c) for c, entry in enumerate(raw, 1))
        dl = _parse_dl_mt(data['dl_mt_m'], source)
        return cls(name=data['name'], duration_s=duration_s, channels=channels, dl_mt_m=dl)

    @classmethod
    def from_yaml(cls, path: str | Path) -> 'PulseProtocol':
        """Load and validate a pulse protocol file.

        :param path: path to the YAML file
        :raises ProtocolError: if the file cannot be read or is malformed
        """
        path = Path(path)
        return cls.from_mapping(_read_yaml(path), source=str(path))


def read_protocol(path: str | Path) -> Protocol | PulseProtocol:
    """Load a protocol file of either kind: a :class:`PulseProtocol` if it has
    ``channels``, else a :class:`Protocol`.

    :param path: path to the YAML file
    :raises ProtocolError: if the file cannot be read or is malformed
    """
    path = Path(path)
    data = _read_yaml(path)
    if isinstance(data, dict) and 'channels' in data:
        return PulseProtocol.from_mapping(data, source=str(path))
    return Protocol.from_mapping(data, source=str(path))
