"""The protocol player node: replays a stimulation protocol over ROS 2 topics.

It waits until its outputs have a subscriber (up to
``wait_for_subscribers_s``), then publishes ``length_command`` [m] and
``pulse_width`` [s] or ``recruitment`` [-] (std_msgs/Float64) at ``rate_hz``
against its own clock, which follows ``/clock`` when ``use_sim_time`` is set.
At the end it publishes zero stimulation and exits with status 0.

Run: ``ros2 run hill_muscle_ros protocol_player --ros-args -p protocol:=II``.
"""
from __future__ import annotations

import dataclasses
import sys

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.task import Future
from std_msgs.msg import Float64

from ..model import MuscleParams, Protocol, ProtocolError
from ..model.protocol import STIMULATION_OUTPUTS
from ..resources import BUILTIN_PROTOCOLS, protocol_path
from ._common import (EXIT_FAILURE, EXIT_SUCCESS, OUTPUT_QOS,
                      StartupError, declare_checked, field_descriptor,
                      number_descriptor, reject_unknown_overrides, run_node)

NODE_NAME = 'protocol_player'

OUTPUT_CHOICES = STIMULATION_OUTPUTS
DEFAULT_PROTOCOL = 'II'
DEFAULT_RATE_HZ = 1000.0
#: [Hz] same bounds as the simulator's step rate.
RATE_HZ_RANGE = (1.0, 100_000.0)
DEFAULT_WAIT_FOR_SUBSCRIBERS_S = 10.0
WAIT_RANGE_S = (0.0, 3600.0)
#: [s] how often the player checks for subscribers and for a running clock.
POLL_PERIOD_S = 0.05
#: [s] how long the player waits, at the end, for subscribers to acknowledge
#: the last messages before it exits (reliable QoS).
ACK_TIMEOUT_S = 2.0

_NS_PER_S = 1_000_000_000


class ProtocolPlayer(Node):
    """Publishes a protocol's stimulation and length commands, then exits.

    ``done`` completes with the exit status.

    :raises StartupError: on a bad parameter or protocol file
    """

    NODE_NAME = NODE_NAME

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        spec = declare_checked(self, 'protocol', DEFAULT_PROTOCOL, ParameterDescriptor(
            description=f'protocol: {", ".join(BUILTIN_PROTOCOLS)} or a path to a protocol '
                        'YAML file', read_only=True))
        rate_hz = declare_checked(self, 'rate_hz', DEFAULT_RATE_HZ, number_descriptor(
            'publish rate', 'Hz', *RATE_HZ_RANGE, read_only=True))
        self._output = declare_checked(self, 'output', OUTPUT_CHOICES[0], ParameterDescriptor(
            description='stimulation topic to publish', read_only=True,
            additional_constraints=f'one of: {", ".join(OUTPUT_CHOICES)}'))
        self._wait_s = declare_checked(
            self, 'wait_for_subscribers_s', DEFAULT_WAIT_FOR_SUBSCRIBERS_S, number_descriptor(
                'how long to wait for a subscriber on the outputs before failing', 's',
                *WAIT_RANGE_S, read_only=True))
        pw_field = {f.name: f for f in dataclasses.fields(MuscleParams)}['pw_max_s']
        self._pw_max_s = declare_checked(
            self, 'pw_max_s', MuscleParams().pw_max_s, field_descriptor(
                pw_field, read_only=True, note='to turn recruitment into pulse width'))
        reject_unknown_overrides(self)
        if self._output not in OUTPUT_CHOICES:
            raise StartupError(f'parameter `output` must be one of '
                               f'{", ".join(OUTPUT_CHOICES)}, got {self._output!r}')
        try:
            MuscleParams(pw_max_s=self._pw_max_s)
            self._protocol = Protocol.from_yaml(protocol_path(spec))
        except (ValueError, ProtocolError) as err:
            raise StartupError(str(err)) from None

        self._pub_stim = self.create_publisher(Float64, self._output, OUTPUT_QOS)
        self._pub_dl = self.create_publisher(Float64, 'length_command', OUTPUT_QOS)
        self.done = Future()
        self._period_s = 1.0 / rate_hz
        self._t0 = None
        # Waiting is in wall time: the sim clock may not run yet.
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._wait_deadline_ns = (self._steady.now().nanoseconds
                                  + round(self._wait_s * _NS_PER_S))
        self._poll = self.create_timer(POLL_PERIOD_S, self._on_poll, clock=self._steady)
        self._timer = None
        self.get_logger().info(
            f'{self._protocol.name} ({self._protocol.duration_s:g} s) on '
            f'{self._pub_stim.topic_name} and {self._pub_dl.topic_name}; waiting up to '
            f'{self._wait_s:g} s for subscribers')

    def _on_poll(self) -> None:
        """Start once both outputs are matched and the clock runs; else time out."""
        matched = (self._pub_stim.get_subscription_count() > 0
                   and self._pub_dl.get_subscription_count() > 0)
        # With use_sim_time the clock reads 0 until the first /clock message.
        clock_running = self.get_clock().now().nanoseconds > 0
        if matched and clock_running:
            self._poll.cancel()
            self._t0 = self.get_clock().now()
            # The node's own clock, so that with use_sim_time it follows /clock.
            self._timer = self.create_timer(self._period_s, self._on_tick)
            self._publish(0.0)
            return
        if self._steady.now().nanoseconds > self._wait_deadline_ns:
            self._poll.cancel()
            missing = [p.topic_name for p in (self._pub_stim, self._pub_dl)
                       if p.get_subscription_count() == 0]
            what = (f'no subscriber on {", ".join(missing)}' if missing
                    else 'no /clock message (use_sim_time is set)')
            self.get_logger().error(f'{what} after {self._wait_s:g} s '
                                    '(wait_for_subscribers_s): is the simulator running, '
                                    'in the same namespace and ROS_DOMAIN_ID?')
            self.done.set_result(EXIT_FAILURE)

    def _publish(self, t_s: float) -> None:
        p = self._protocol
        self._pub_dl.publish(Float64(data=float(p.dl_mt(t_s))))
        self._pub_stim.publish(Float64(data=p.stimulation_command(t_s, self._output,
                                                                  self._pw_max_s)))

    def _on_tick(self) -> None:
        t_s = (self.get_clock().now() - self._t0).nanoseconds / _NS_PER_S
        if t_s < self._protocol.duration_s:
            self._publish(t_s)
            return
        self._timer.cancel()
        self._pub_dl.publish(Float64(data=float(self._protocol.dl_mt(self._protocol.duration_s))))
        self._pub_stim.publish(Float64(data=0.0))
        timeout = Duration(seconds=ACK_TIMEOUT_S)
        acked = all(pub.wait_for_all_acked(timeout) for pub in (self._pub_stim, self._pub_dl))
        self.get_logger().info(
            f'{self._protocol.name} done at t = {t_s:.3f} s; zero stimulation sent'
            + ('' if acked else ' (not acknowledged by every subscriber)'))
        self.done.set_result(EXIT_SUCCESS)


def main(args: list[str] | None = None) -> int:
    """Entry point: ``protocol_player [--ros-args ...]``; returns the exit status."""
    return run_node(ProtocolPlayer, args)


if __name__ == '__main__':
    sys.exit(main())
