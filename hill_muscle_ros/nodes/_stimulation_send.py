"""The ``stimulation`` topic on a sending node: the
``hill_muscle_interfaces/msg/Stimulation`` message from checked channel commands.

The message package is imported when a node first needs it, so that the nodes
that send only the plain ``pulse_width`` or ``recruitment`` topics run without it.
"""
from __future__ import annotations

from typing import Any, Sequence

from rclpy.time import Time

from ..model.stimulator import ChannelCommand
from ._process import StartupError

#: The topic of the message (relative: it resolves in the node's namespace).
STIMULATION_TOPIC = 'stimulation'


def stimulation_type() -> type:
    """The ``Stimulation`` message class.

    :raises StartupError: naming the package and how to build it, if it is not installed
    """
    try:
        from hill_muscle_interfaces.msg import Stimulation
    except ImportError as err:
        raise StartupError(
            f'the message package hill_muscle_interfaces is not installed ({err}): build it '
            'with `make interfaces` (here) or `colcon build` (a ROS 2 workspace)') from None
    return Stimulation


def stimulation_message(commands: Sequence[ChannelCommand], stamp_ns: int) -> Any:
    """One ``Stimulation`` message for checked channel commands.

    :param commands: the channels' commands, in the order to send
        (:func:`~hill_muscle_ros.model.stimulator.check_stimulation`'s)
    :param stamp_ns: [ns] ``header.stamp``: when the command takes effect, on the
        sender's clock
    :return: the message; ``current_a`` is empty when no command gives a current
        (every channel then uses its muscle's ``current_ref_a``)
    :raises ValueError: for commands of which some give a current and some do not
    """
    msg = stimulation_type()()
    msg.header.stamp = Time(nanoseconds=stamp_ns).to_msg()
    msg.channel = [c.channel for c in commands]
    msg.mode = [c.mode for c in commands]
    msg.pulse_width_s = [float(c.pulse_width_s) for c in commands]
    currents = [c.current_a for c in commands]
    if all(i is None for i in currents):
        msg.current_a = []
    elif any(i is None for i in currents):
        raise ValueError('`current_a` must be given for every channel of a Stimulation or for '
                         f'none, got {currents!r}')
    else:
        msg.current_a = [float(i) for i in currents]
    msg.frequency_hz = [float(c.frequency_hz) for c in commands]
    return msg
