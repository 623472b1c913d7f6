"""The protocol player node: replays a stimulation protocol over ROS 2 topics.

It waits until each of its outputs has ``min_subscribers`` subscribers (up to
``wait_for_subscribers_s``), then publishes ``length_command`` [m] and
``pulse_width`` [s] or ``recruitment`` [-] (std_msgs/Float64) at ``rate_hz``
against its own clock, which follows ``/clock`` when ``use_sim_time`` is set.
Time 0 of the protocol is when its first sample acts: the player first sends
the rest state (zero stimulation at the protocol's starting length), waits
until every subscriber has acknowledged it, and then starts the protocol's
clock with its first sample at its next tick, on a clock read after the wait
(:mod:`hill_muscle_ros.playback`, the timeline without ROS). At the end it
publishes zero stimulation and exits with status 0.

A protocol with ``channels`` (pulse trains) goes on ``stimulation``
(``hill_muscle_interfaces/msg/Stimulation``) instead, on the same clock and
handshake: one message with every channel's command at time 0 and at each
knot time of the channels' tracks, ``header.stamp`` the time it takes effect
(:class:`~hill_muscle_ros.playback.PulsePlayback`); a zero stimulation (every
channel's pulse width 0) is the rest state and the end. Every command is
checked at start-up against the ``stimulator`` parameter's profile (with
``pw_max_s`` for ``generic``); a protocol that stimulator would reject is
refused, the message naming the field, the channel, the value and the time.
``output`` applies to level protocols only.

With ``lookahead_s`` > 0 the length goes ahead of time instead: the player
publishes ``length_command_stamped`` (geometry_msgs/PointStamped, dl_MT [m]
in ``point.x``, ``header.stamp`` = when it is to be reached, on the player's
clock). The protocol starts ``lookahead_s`` after the first tick once the
rest state is acknowledged (time 0 is the stamp of the first knot; that topic
carries no rest state, as a knot acts at its stamp); before that it sends the knots covering the
first ``lookahead_s`` of the protocol, and at each tick at protocol time t the
knot for t + ``lookahead_s``, plus every corner of the protocol's dl_MT in
between, so the simulator's linear interpolation reproduces the protocol's
length exactly, however coarse the ticks. The simulator then follows the
length exactly as long as the DDS latency (times the real-time factor on sim
time) stays below ``lookahead_s``. The stimulation stays on its plain topic,
sent at its time: a recruitment step reaches the simulator one DDS latency
late (on sim time, latency x real-time factor), which shifts the force's
response to it by that much.

Run: ``ros2 run hill_muscle_ros protocol_player --ros-args -p protocol:=II``.
"""
from __future__ import annotations

import dataclasses
import math

from geometry_msgs.msg import PointStamped
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.task import Future
from rclpy.time import Time
from std_msgs.msg import Float64

from ..model import MuscleParams, ProtocolError
from ..model.params import CURVE_FIELDS
from ..model.protocol import STIMULATION_OUTPUTS, PulseProtocol, read_protocol
from ..playback import (CHANNELS, LENGTH, LENGTH_STAMPED, STIMULATION, Playback, PulsePlayback,
                        Send)
from ..qos import OUTPUT_QOS
from ..resources import BUILTIN_PROTOCOLS, find_protocol
from ..timebase import NS_PER_S
from ._diagnostics import DiagnosticReport, NodeDiagnostics
from ._overrides import reject_unknown_overrides
from ._parameters import declare_checked, field_descriptor, number_descriptor
from ._process import EXIT_FAILURE, EXIT_SUCCESS, StartupError, process_entry, run_node
from ._stimulation_send import STIMULATION_TOPIC, stimulation_message, stimulation_type
from ._topics import overridable_publisher

NODE_NAME = 'protocol_player'

OUTPUT_CHOICES = STIMULATION_OUTPUTS
DEFAULT_PROTOCOL = 'II'
DEFAULT_RATE_HZ = 1000.0
#: [Hz] same bounds as the simulator's step rate.
RATE_HZ_RANGE = (1.0, 100_000.0)
DEFAULT_WAIT_FOR_SUBSCRIBERS_S = 10.0
WAIT_RANGE_S = (0.0, 3600.0)
#: [s] how often the player checks for subscribers and for a running clock;
#: also the longest it blocks at a time waiting for the rest state's
#: acknowledgement, which it takes as soon as it comes.
POLL_PERIOD_S = 0.05
NS_PER_MS = 1_000_000
#: [s] how long the player waits, at the end, for subscribers to acknowledge
#: the last messages before it exits (reliable QoS).
ACK_TIMEOUT_S = 2.0
#: [s] 0 publishes the plain ``length_command``; up to 10 s of knots ahead.
DEFAULT_LOOKAHEAD_S = 0.0
LOOKAHEAD_RANGE_S = (0.0, 10.0)
#: Subscribers each output needs before the protocol starts (the simulator; a
#: recorder that must not miss the start makes it 2).
DEFAULT_MIN_SUBSCRIBERS = 1
MIN_SUBSCRIBERS_RANGE = (1, 100)
#: Muscle fields the player declares for a protocol with ``channels``: the
#: stimulator its commands are checked against, and the interval of the
#: muscle's doublets and triplets (the Stimulation message carries none).
PULSE_FIELDS = ('stimulator', 'burst_interval_s')



class ProtocolPlayer(Node):
    """Publishes a protocol's stimulation and length commands, then exits.

    ``done`` completes with the exit status.

    :raises StartupError: on a bad parameter or protocol file
    """

    NODE_NAME = NODE_NAME

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        spec = declare_checked(self, 'protocol', DEFAULT_PROTOCOL, ParameterDescriptor(
            description=f'protocol: {", ".join(BUILTIN_PROTOCOLS)} (in any case) or a path to '
                        'a protocol YAML file', read_only=True))
        rate_hz = declare_checked(self, 'rate_hz', DEFAULT_RATE_HZ, number_descriptor(
            'publish rate', 'Hz', *RATE_HZ_RANGE, read_only=True))
        self._output = declare_checked(self, 'output', OUTPUT_CHOICES[0], ParameterDescriptor(
            description='stimulation topic to publish', read_only=True,
            additional_constraints=f'one of: {", ".join(OUTPUT_CHOICES)}'))
        self._wait_s = declare_checked(
            self, 'wait_for_subscribers_s', DEFAULT_WAIT_FOR_SUBSCRIBERS_S, number_descriptor(
                'how long to wait for a subscriber on the outputs before failing', 's',
                *WAIT_RANGE_S, read_only=True))
        self._lookahead_s = declare_checked(
            self, 'lookahead_s', DEFAULT_LOOKAHEAD_S, number_descriptor(
                'send dl_MT this far ahead as length_command_stamped (the protocol starts '
                'this much later); 0 publishes the plain length_command', 's',
                *LOOKAHEAD_RANGE_S, read_only=True))
        self._min_subscribers = declare_checked(
            self, 'min_subscribers', DEFAULT_MIN_SUBSCRIBERS, number_descriptor(
                'subscribers every output needs before the protocol starts', '-',
                *MIN_SUBSCRIBERS_RANGE, integer=True, read_only=True))
        # The recruitment curve of the muscle it drives: a `recruitment` output
        # sends the command u = curve(PW), a `pulse_width` output of a
        # recruitment protocol the width that gives u.
        fields = {f.name: f for f in dataclasses.fields(MuscleParams)}
        defaults = MuscleParams()
        curve = {name: declare_checked(self, name, getattr(defaults, name), field_descriptor(
            fields[name], read_only=True, note='the recruitment curve between pulse width '
            'and recruitment command')) for name in CURVE_FIELDS}
        pulse_fields = {name: declare_checked(
            self, name, getattr(defaults, name), field_descriptor(
                fields[name], read_only=True, note='checks the commands of a protocol with '
                'channels; give the simulator\'s value')) for name in PULSE_FIELDS}
        reject_unknown_overrides(self)
        if not math.isfinite(self._lookahead_s):
            raise StartupError(f'parameter `lookahead_s` must be finite, got '
                               f'{self._lookahead_s!r}')
        if self._output not in OUTPUT_CHOICES:
            raise StartupError(f'parameter `output` must be one of '
                               f'{", ".join(OUTPUT_CHOICES)}, got {self._output!r}')
        self._period_s = 1.0 / rate_hz
        try:
            self._curve = MuscleParams(**curve, **pulse_fields)
            path = find_protocol(spec)
            self._protocol = read_protocol(path)
            #: True for a protocol with ``channels``: pulse trains on ``stimulation``
            self.pulsed = isinstance(self._protocol, PulseProtocol)
            if self.pulsed:
                # Fail now, not mid-run: every command is checked against the stimulator.
                self._playback = PulsePlayback(self._protocol, self._curve, self._period_s,
                                               self._lookahead_s, source=str(path))
            else:
                # Fail now, not mid-run: every knot of the protocol maps on the curve.
                for t_s in self._protocol.stimulation.times_s:
                    self._protocol.stimulation_command(float(t_s), self._output, self._curve)
                self._playback = Playback(self._protocol, self._output, self._curve,
                                          self._period_s, self._lookahead_s)
        except (ValueError, ProtocolError) as err:
            raise StartupError(str(err)) from None

        if self.pulsed:
            self._pub_stim = overridable_publisher(self, stimulation_type(), STIMULATION_TOPIC,
                                                   OUTPUT_QOS)
        else:
            self._pub_stim = overridable_publisher(self, Float64, self._output, OUTPUT_QOS)
        self._stamped = self._lookahead_s > 0.0
        self._pub_dl = (overridable_publisher(self, PointStamped, 'length_command_stamped',
                                              OUTPUT_QOS)
                        if self._stamped
                        else overridable_publisher(self, Float64, 'length_command', OUTPUT_QOS))
        self.done = Future()
        self._failure = ''       # why the player gave up, if it did
        # Waiting is in wall time: the sim clock may not run yet.
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._wait_deadline_ns = (self._steady.now().nanoseconds
                                  + round(self._wait_s * NS_PER_S))
        self._rest_sent_ns = 0   # [ns] steady clock: when the rest state went out
        self._poll = self.create_timer(POLL_PERIOD_S, self._on_poll, clock=self._steady)
        self._timer = None
        self._diagnostics = NodeDiagnostics(self, 'protocol playback', self._diagnose)
        ahead = (f', length {self._lookahead_s:g} s ahead' if self._stamped else '')
        trains = (f' ({len(self._protocol.channels)} channel(s), {len(self._playback.times_s)} '
                  f'commands checked against {self._playback.profile.name})'
                  if self.pulsed else '')
        self.get_logger().info(
            f'{self._protocol.name} ({self._protocol.duration_s:g} s) on '
            f'{self._pub_stim.topic_name}{trains} and {self._pub_dl.topic_name}{ahead}; '
            f'waiting up to {self._wait_s:g} s for {self._min_subscribers} subscriber(s) on '
            'each')

    def _on_poll(self) -> None:
        """Start once every output is matched and the clock runs; else time out."""
        counts = {p.topic_name: p.get_subscription_count() for p in (self._pub_stim, self._pub_dl)}
        matched = all(n >= self._min_subscribers for n in counts.values())
        # With use_sim_time the clock reads 0 until the first /clock message.
        clock_running = self.get_clock().now().nanoseconds > 0
        if matched and clock_running:
            if not self._playback.rest_sent:
                self._send(self._playback.rest())
                self._rest_sent_ns = self._steady.now().nanoseconds
            if self._rest_acked():
                self._poll.cancel()
                self._start()
                return
        if self._steady.now().nanoseconds > self._wait_deadline_ns:
            self._poll.cancel()
            short = [f'{topic} has {n}' for topic, n in counts.items()
                     if n < self._min_subscribers]
            if short:
                what = (f'too few subscribers ({", ".join(short)} of min_subscribers '
                        f'{self._min_subscribers})')
            elif not clock_running:
                what = 'no /clock message (use_sim_time is set)'
            else:
                what = ('the rest state not acknowledged by every subscriber '
                        f'({", ".join(p.topic_name for p in self._unacked())})')
            self.get_logger().error(f'{what} after {self._wait_s:g} s '
                                    '(wait_for_subscribers_s): is the simulator (and any '
                                    'recorder) running, in the same namespace and '
                                    'ROS_DOMAIN_ID?')
            self._failure = f'{what} after {self._wait_s:g} s (wait_for_subscribers_s)'
            self._diagnostics.publish_final()   # the last status: the node exits now
            self.done.set_result(EXIT_FAILURE)

    def _unacked(self) -> list:
        """The outputs whose sent messages some matched subscriber has not yet
        acknowledged (a best-effort subscriber never holds one back)."""
        return [pub for pub in (self._pub_stim, self._pub_dl)
                if not pub.wait_for_all_acked(Duration())]

    def _rest_acked(self) -> bool:
        """Whether every subscriber has the rest state; waits for it up to
        :data:`POLL_PERIOD_S`, so that the protocol starts as soon as it is.

        A subscriber counts as matched as soon as this side has discovered it,
        which can be before it has discovered this side; a message sent then
        reaches it only with the writer's next heartbeat. Starting the
        protocol once the rest state is acknowledged keeps that delay out of
        the protocol (:mod:`hill_muscle_ros.playback`).
        """
        slice_ = Duration(nanoseconds=round(POLL_PERIOD_S * NS_PER_S))
        return all(pub.wait_for_all_acked(slice_) for pub in (self._pub_stim, self._pub_dl))

    def _diagnose(self, report: DiagnosticReport) -> None:
        """/diagnostics: waiting for subscribers, playing (protocol time and
        fraction done), done, or failed (ERROR)."""
        p = self._protocol
        report.add('protocol', p.name)
        report.add('duration_s', float(p.duration_s))
        report.add('output', self._pub_stim.topic_name)
        report.add('lookahead_s', float(self._lookahead_s))
        report.add('min_subscribers', self._min_subscribers)
        for pub in (self._pub_stim, self._pub_dl):
            report.add(f'subscribers[{pub.topic_name}]', pub.get_subscription_count())
        playback = self._playback
        if playback.t0_ns is None:
            t_s = 0.0
        elif playback.finished:
            t_s = float(p.duration_s)
        else:
            t_s = playback.protocol_time_s(self.get_clock().now().nanoseconds)
        report.add('protocol_time_s', t_s)
        report.add('progress', min(max(t_s / p.duration_s, 0.0), 1.0) if p.duration_s > 0 else 1.0)
        if self._failure:
            report.add('state', 'failed')
            report.error(self._failure)
        elif playback.finished:
            report.add('state', 'done')
            report.ok(f'{p.name} done: zero stimulation sent')
        elif playback.t0_ns is None and playback.rest_sent:
            report.add('state', 'waiting for acknowledgement')
            report.ok('waiting for every subscriber to acknowledge the rest state')
        elif playback.t0_ns is None:
            report.add('state', 'waiting for subscribers')
            report.ok(f'waiting for {self._min_subscribers} subscriber(s) on each output '
                      '(and a running clock)')
        elif t_s < 0.0:
            report.add('state', 'sending length ahead')
            report.ok(f'{p.name} starts in {-t_s:.3f} s (lookahead_s)')
        else:
            report.add('state', 'playing')
            report.ok(f'playing {p.name}: {t_s:.3f} of {p.duration_s:g} s')

    def _start(self) -> None:
        # How long the handshake took says whether acknowledgements are quick
        # (a slow one once delayed the protocol by a Fast DDS heartbeat period).
        acked_ms = (self._steady.now().nanoseconds - self._rest_sent_ns) / NS_PER_MS
        self.get_logger().info(f'{self._protocol.name} starts: every subscriber acknowledged '
                               f'the rest state {acked_ms:.1f} ms after it was sent')
        # Time 0 is the first tick of the node's own clock, not now: with
        # use_sim_time, the clock is the last /clock this node took, and while
        # this callback waited for the acknowledgement it took none (under load
        # 0.54 s of waiting left it 1.8 s of sim time behind, and the protocol
        # was "done" at its first tick). The tick timer fires on a fresh clock.
        self._timer = self.create_timer(self._period_s, self._on_tick)

    def _send(self, sends: list[Send]) -> None:
        """Publish the playback's messages, in order."""
        for send in sends:
            if send.topic == STIMULATION:
                self._pub_stim.publish(Float64(data=float(send.value)))
            elif send.topic == CHANNELS:
                stamp_ns = (send.stamp_ns if send.stamp_ns is not None
                            else self.get_clock().now().nanoseconds)
                self._pub_stim.publish(stimulation_message(send.value, stamp_ns))
            elif send.topic == LENGTH:
                self._pub_dl.publish(Float64(data=float(send.value)))
            else:
                assert send.topic == LENGTH_STAMPED, send.topic
                msg = PointStamped()
                msg.header.stamp = Time(nanoseconds=send.stamp_ns).to_msg()
                msg.point.x = float(send.value)
                self._pub_dl.publish(msg)

    def _on_tick(self) -> None:
        # The node's own clock, so that with use_sim_time it follows /clock.
        now_ns = self.get_clock().now().nanoseconds
        if self._playback.t0_ns is None:
            self._send(self._playback.start(now_ns))
            # The ticks from time 0 on, as a timer made now schedules them: on
            # the first timer's grid a late first tick put the next ones a
            # little before whole periods of protocol time.
            self._timer.cancel()
            self._timer = self.create_timer(self._period_s, self._on_tick)
            return
        self._send(self._playback.tick(now_ns))
        if not self._playback.finished:
            return
        self._timer.cancel()
        timeout = Duration(seconds=ACK_TIMEOUT_S)
        acked = all(pub.wait_for_all_acked(timeout) for pub in (self._pub_stim, self._pub_dl))
        self.get_logger().info(
            f'{self._protocol.name} done at t = {self._playback.protocol_time_s(now_ns):.3f} s; '
            'zero stimulation sent' + ('' if acked else ' (not acknowledged by every subscriber)'))
        self._diagnostics.publish_final()   # the last status: the node exits now
        self.done.set_result(EXIT_SUCCESS)


def main(args: list[str] | None = None) -> int:
    """Entry point: ``protocol_player [--ros-args ...]``; returns the exit status."""
    return run_node(ProtocolPlayer, args)


#: The console script (setup.py): main(), then the process ends at once.
process_main = process_entry(main)


if __name__ == '__main__':
    process_main()
