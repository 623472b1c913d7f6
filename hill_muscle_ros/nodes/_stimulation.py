"""The simulator's ``stimulation`` input: one stimulator command for every
channel (hill_muscle_interfaces/msg/Stimulation), checked as the device would.

- :data:`Stimulation`: the message type, or ``None`` where the interface
  package is not installed (a plain ``pip install .`` cannot build it: the
  node then runs without the topic and says so).
- :func:`check_message`: a message to the channels' commands, checked against
  the muscle's stimulator profile (``stimulator``, ``pw_max_s``) and its
  channels; the error names the field, the channel and the value.
- :func:`level_command`: channel 1 of a command as the level command u of a
  ``first_order`` muscle (what a ``pulse_width`` message gives).
- :func:`pulse_width_channel`: a ``pulse_width`` message as channel 1's
  command on a ``ding2003`` muscle, at ``frequency_hz``.
- :func:`off_commands`, :func:`stimulating`, :func:`commands_text` and
  :func:`message_text`: the watchdog's zero command and the log lines.

No rclpy here: the node glues these to its topics, and the tests call them
directly. (The nodes that send ``stimulation`` use ._stimulation_send.)
"""
from __future__ import annotations

from typing import Any, Iterable, Mapping

from ..model import MuscleParams
from ..model.params import PULSED_MODEL
from ..model.channels import check_train_frequency
from ..model.stimulator import (ChannelCommand, check_channel_command, check_stimulation,
                                stimulator_profile)
from ..model.stimulus import pulse_command

try:   # built by `make interfaces` or colcon; absent from a plain `pip install .`
    from hill_muscle_interfaces.msg import Stimulation
except ImportError:   # pragma: no cover - the test venv has it
    Stimulation = None

#: The message's arrays, in its order.
FIELDS = ('channel', 'mode', 'pulse_width_s', 'current_a', 'frequency_hz')


def pulsed(params: MuscleParams) -> bool:
    """Whether the muscle takes pulse trains per channel (``activation_model: ding2003``)."""
    return params.activation_model == PULSED_MODEL


def message_text(msg: Any) -> str:
    """A ``Stimulation`` message as the log lines quote it: its five arrays."""
    parts = []
    for name in FIELDS:
        values = list(getattr(msg, name))
        if name == 'mode':
            parts.append(f'{name} [{", ".join(repr(v) for v in values)}]')
        else:
            parts.append(f'{name} [{", ".join(f"{v:g}" for v in values)}]')
    return '{' + ', '.join(parts) + '}'


def check_message(msg: Any, params: MuscleParams, n_channels: int,
                  held: Mapping[int, ChannelCommand] | None = None) -> tuple[ChannelCommand, ...]:
    """The channels' commands of a ``Stimulation`` message, checked as the
    stimulator ``params.stimulator`` would and against the muscle's channels.

    :param msg: the message (any object with its five arrays)
    :param params: the muscle's parameters (``stimulator``, ``pw_max_s``,
        ``burst_interval_s``, ``activation_model``)
    :param n_channels: [-] the muscle's channels; a higher channel is rejected
    :param held: the commands the channels hold now, by channel: on a
        stimulator with one frequency for all channels, a channel that
        stimulates and is not in the message must have the message's frequency
    :return: the commands, in the message's order
    :raises ValueError: naming the field, the channel and the value (or the
        arrays' lengths)
    """
    profile = stimulator_profile(params.stimulator, params.pw_max_s)
    commands = check_stimulation(profile, msg.channel, msg.mode, msg.pulse_width_s,
                                 msg.current_a, msg.frequency_hz, params.burst_interval_s)
    for c in commands:
        if c.channel > n_channels:
            raise ValueError(f'`channel` must be in [1, {n_channels}] (the muscle\'s channels, '
                             f'`channel_fractions`), got {c.channel}')
        if pulsed(params):
            check_train_frequency(c)
    if profile.shared_frequency and commands and held:
        named = {c.channel for c in commands}
        f = commands[0].frequency_hz
        for other in held.values():
            if other.channel not in named and _on(other) and other.frequency_hz != f:
                raise ValueError(
                    f'`frequency_hz` must be the same on every channel on {profile.name} (one '
                    f'stimulation period for all channels): channel {other.channel} holds '
                    f'{other.frequency_hz:g} Hz, got {f:g} Hz on channel '
                    f'{commands[0].channel}')
    return commands


def pulse_width_channel(pulse_width_s: float, params: MuscleParams) -> ChannelCommand:
    """A ``pulse_width`` message as the command of channel 1 on a ``ding2003``
    muscle: single pulses at ``frequency_hz``, the reference current; checked
    against the stimulator as a ``stimulation`` message would be.

    :param pulse_width_s: [s] the width (already checked finite and non-negative)
    :param params: the muscle's parameters
    :raises ValueError: naming the field, the channel and the value
    """
    profile = stimulator_profile(params.stimulator, params.pw_max_s)
    return check_channel_command(profile, 1, params.frequency_hz, pulse_width_s, None,
                                 'single', params.burst_interval_s)


def level_command(commands: Iterable[ChannelCommand], params: MuscleParams) -> float | None:
    """Channel 1 of a command as the level command u of a ``first_order`` muscle.

    Its pulse width goes through the recruitment curve as a ``pulse_width``
    message does; with a current, first to the width that recruits as many
    units at ``current_ref_a`` (the strength-duration law,
    :func:`~hill_muscle_ros.model.stimulus.pulse_command`). Mode and
    frequency do not act on a level: they are checked, then ignored.

    :return: [-] u in [0, 1], or ``None`` if channel 1 is not in the command
    """
    for c in commands:
        if c.channel == 1:
            return pulse_command(c.pulse_width_s, c.current_a, params)
    return None


def _on(command: ChannelCommand) -> bool:
    """Whether a channel's command sends pulses: PW > 0 and (no current or I > 0)."""
    return command.pulse_width_s > 0.0 and (command.current_a is None or command.current_a > 0.0)


def stimulating(held: Mapping[int, ChannelCommand]) -> bool:
    """Whether any held channel's command sends pulses (the watchdog's "R > 0")."""
    return any(_on(c) for c in held.values())


def off_commands(held: Mapping[int, ChannelCommand], n_channels: int,
                 params: MuscleParams) -> tuple[ChannelCommand, ...]:
    """Every channel at pulse width 0 (the watchdog's command), each keeping
    its mode and frequency (``frequency_hz`` for a channel never commanded)."""
    out = []
    for channel in range(1, n_channels + 1):
        c = held.get(channel)
        out.append(ChannelCommand(channel, c.mode if c else 'single', 0.0, None,
                                  c.frequency_hz if c else params.frequency_hz))
    return tuple(out)


def commands_text(held: Mapping[int, ChannelCommand]) -> str:
    """The held commands as the log lines give them, e.g.
    ``channel 1: single 0.0003 s at 30 Hz, channel 2: off``."""
    if not held:
        return 'every channel off'
    parts = []
    for channel in sorted(held):
        c = held[channel]
        if not _on(c):
            parts.append(f'channel {channel}: off')
            continue
        current = '' if c.current_a is None else f' {c.current_a:g} A'
        parts.append(f'channel {channel}: {c.mode} {c.pulse_width_s:g} s{current} at '
                     f'{c.frequency_hz:g} Hz')
    return ', '.join(parts)
