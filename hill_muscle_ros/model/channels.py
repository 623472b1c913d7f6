"""A ``ding2003`` muscle's channels as a stimulator drives them: each channel's
command in force, its pulse train, and the pulses sent but not yet acting
(doc/model.md section 10.5). Pure Python; :class:`~.muscle.Muscle` and
:class:`~.limb.Limb` keep one per pulse-driven muscle and hand the due
pulses to the kernels.
"""
from __future__ import annotations

import math
from typing import Iterable

from .muscle.state import TIME_TOL_S
from .params import MuscleParams
from .stimulator import ChannelCommand, check_channel_command, stimulator_profile
from .stimulus import pulse_command
from .trains import ChannelTrain, PulseTrain


def check_train_frequency(command: ChannelCommand) -> None:
    """A pulse train's bursts are 1/f apart: its frequency must be positive.

    :raises ValueError: naming the channel and the value
    """
    if not command.frequency_hz > 0.0:
        raise ValueError(f'`frequency_hz` of channel {command.channel} must be positive with '
                         f'`activation_model: ding2003` (its bursts are 1/f apart), '
                         f'got {command.frequency_hz!r}')


def steps_end_s(t_s: float, dt_s: float, n_steps: int) -> float:
    """[s] where a clock at ``t_s`` stands after ``n_steps`` steps of ``dt_s``
    added one at a time, as the kernels add them (t += dt each step).

    The channels are brought there before the steps run: ``t_s + n dt`` can
    round an ulp past the kernels' clock (0.0048 s after 24 steps of 0.2 ms
    against 0.0048000000000000004 s), and a command given then would start
    before the channels stand, and be refused.
    """
    for _ in range(n_steps):
        t_s += dt_s
    return t_s


class ChannelTrains:
    """The channels of one ``ding2003`` muscle: commands, trains, pending pulses.

    :param params: the muscle's parameters (its channels, ``stimulator``,
        ``burst_interval_s``, ``emd_s`` and the recruitment curve)
    """

    def __init__(self, params: MuscleParams) -> None:
        self.params = params
        self.profile = stimulator_profile(params.stimulator, params.pw_max_s)
        self.reset()

    def reset(self) -> None:
        """Every channel stopped, no pulse pending."""
        n = self.params.n_channels
        self.trains: list = [None] * n
        self.commands: list = [None] * n   # each channel's ChannelCommand in force
        # [s] The earliest instant each channel may send its next pulse (a train
        # from a command has constant tracks): a step before it skips the
        # channel's train (the node's 1 kHz step, most of whose steps send nothing).
        self._due: list = [math.inf] * n
        self.pending: list = []   # (instant it acts [s], 0-based channel, u), in time order

    def stimulate(self, commands: Iterable[ChannelCommand], t_s: float) -> None:
        """Command channels from ``t_s``: each channel named gets a new train (the
        schedule carries over: the next burst stays 1/f after the last), the
        others keep theirs; a channel given the command in force keeps its
        train. Every command is checked against the ``stimulator`` first;
        nothing changes if one fails.

        :raises ValueError: naming the field, channel and value, for a channel
            beyond the muscle's, a command out of the stimulator's range or a
            frequency that is not positive
        """
        n = self.params.n_channels
        trains, given = list(self.trains), list(self.commands)
        for cmd in commands:
            c = check_channel_command(self.profile, cmd.channel, cmd.frequency_hz,
                                      cmd.pulse_width_s, cmd.current_a, cmd.mode,
                                      self.params.burst_interval_s)
            if c.channel > n:
                raise ValueError(f'`channel` must be in [1, {n}] (the muscle\'s '
                                 f'channels), got {cmd.channel!r}')
            check_train_frequency(c)
            if c == given[c.channel - 1]:
                continue   # the train in force already: nothing changes
            given[c.channel - 1] = c
            trains[c.channel - 1] = PulseTrain(
                ChannelTrain(c.frequency_hz, c.pulse_width_s, c.current_a, c.mode,
                             self.params.burst_interval_s, c.channel), t_s)
        for c, (old, new) in enumerate(zip(self.trains, trains)):
            if new is not old:
                if old is not None:   # the schedule carries over, brought to now
                    self._take(c, old.pulses(old.state.time_s, t_s))
                    new.state = old.state
                self._due[c] = -math.inf
        self.trains, self.commands = trains, given

    def _take(self, c: int, pulses) -> None:
        """Queue channel ``c``'s sent ``pulses`` to act ``emd_s`` later."""
        for pulse in pulses:
            self.pending.append((pulse.time_s + self.params.emd_s, c,
                                 pulse_command(pulse.pulse_width_s, pulse.current_a,
                                               self.params)))

    def due(self, t1_s: float) -> list:
        """The pulses that act before ``t1_s`` (those sent up to then first taken
        from the trains), removed from the pending ones.

        :return: ``(instant [s], 0-based channel, u)`` in time order
        """
        taken = False
        for c, train in enumerate(self.trains):
            if train is None or self._due[c] >= t1_s:
                continue
            self._take(c, train.pulses(train.state.time_s, t1_s))
            state = train.state
            self._due[c] = (state.pending[0].time_s if state.pending
                            else state.next_burst_s if state.running else math.inf)
            taken = True
        if taken:
            self.pending.sort()
        pending = self.pending
        n = 0
        while n < len(pending) and pending[n][0] < t1_s - TIME_TOL_S:
            n += 1
        out = pending[:n]
        del pending[:n]
        return out
