"""The recorder node: records topics to a rosbag2 bag (MCAP storage).

There is no rosbag2 on PyPI; this node writes the same bag that ``ros2 bag
record -s mcap`` writes (see :mod:`hill_muscle_ros.recording.bag_writer`),
so ``ros2 bag info``, Foxglove, PlotJuggler and rosbags open it as it is.

- Parameters: ``topics`` and ``output`` (the bag directory; default
  ``runs/<UTC timestamp>``; an existing non-empty directory is an error,
  never overwritten). Each entry of ``topics`` is a topic name (resolved in
  the node's namespace), optionally followed by ``:`` and its type:
  ``force_target:std_msgs/msg/Float64`` (:func:`parse_topic_entry`; a ``:``
  cannot occur in a ROS name). Default: the simulator's inputs and
  outputs, ``stimulation`` included, without its 1 kHz state streams
  (``recruitment_state``, ``fitness``, ``activation``: give them to record
  them).
- A topic with a type (given, or one of the package's own topics,
  :data:`KNOWN_TYPES`) is subscribed at start-up, before any publisher
  exists, reliable and volatile, so a publisher that waits until the
  recorder's subscription is matched before it publishes (``ros2 topic pub
  --once -w N`` with N counting the recorder) loses nothing. A publisher
  that this subscription cannot match (best effort) is reported as an
  error, once: give such a topic by name only.
- A topic given by name only is subscribed when a publisher appears (the
  graph is polled every 20 ms), with the type and QoS the publishers offer.
  What that publisher sends before the recorder's subscription has matched
  it is not recorded: a single ``ros2 topic pub --once``, which publishes as
  soon as one other subscriber matches and exits, is usually lost.
- Messages stay serialized: the CDR bytes go to disk exactly as received.
- ``log_time`` is the receive time on the node's clock, ``publish_time``
  the header stamp where there is one. With ``use_sim_time`` it is the sim
  time in force at the DDS receive instant, from the ``/clock`` messages' own
  receive instants (:class:`~hill_muscle_ros.recording.receipt_clock.ReceiptClock`),
  not the clock read when Python takes the message.
- Each message's publisher sequence number is checked: a gap means DDS lost
  messages, and is reported with the count of messages sent vs. recorded.
- SIGINT and SIGTERM stop it cleanly: what each publisher sent before the
  stop is taken and written (:meth:`Recorder.drain`: up to
  :data:`DRAIN_TIMEOUT_S` for what DDS still has to deliver), then the
  summary and ``metadata.yaml``; a second signal cuts that wait short.
  Chunks close at least every second, so after a SIGKILL all but the last
  second can be read.

Run: ``ros2 run hill_muscle_ros recorder --ros-args -p output:=runs/my_run``
or ``hill-muscle record --ros-args ...``.
"""
from __future__ import annotations

import datetime as _dt
import importlib
import signal
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import rclpy
from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSCompatibility, QoSProfile,
                       ReliabilityPolicy, qos_check_compatible)
from rosgraph_msgs.msg import Clock as ClockMsg

from ..recording.bag_writer import BagOutputError, BagWriter, read_msg_file, split_type_name
from ..recording.receipt_clock import ReceiptClock
from ..timebase import NS_PER_S
from ._diagnostics import DiagnosticReport, NodeDiagnostics
from ._parameters import parameter_overrides
from ._process import (EXIT_FAILURE, EXIT_SUCCESS, StartupError, TeardownGuard, init_ros,
                       make_executor, process_entry)
from ._topics import (DIAGNOSTICS_TOPIC, check_qos_overrides, overridable_subscription,
                      qos_overrides_of)

NODE_NAME = 'recorder'
#: The stimulator command (hill_muscle_interfaces, built by ``make interfaces``).
STIMULATION_TOPIC = 'stimulation'
STIMULATION_TYPE = 'hill_muscle_interfaces/msg/Stimulation'

#: Every topic the simulator and the protocol player use (relative names are
#: resolved in the recorder's namespace; /clock is global by ROS convention),
#: and /diagnostics, so that a bag says whether the run was healthy (steps
#: behind, watchdog trips, losses) at the cost of a few messages a second.
#: ``stimulation`` is a command stream like ``pulse_width`` (a player's knots,
#: a controller's period): few messages, and a bag without it cannot be
#: replayed or fitted.
DEFAULT_TOPICS = ('pulse_width', 'recruitment', 'stimulation', 'length_command',
                  'length_command_stamped', 'force', 'ce_length', 'wrench', '/clock',
                  DIAGNOSTICS_TOPIC)
#: Types of this package's own topics. These are subscribed at start-up,
#: before any publisher exists, so that a player or simulator started after
#: the recorder loses no message to discovery; other topics (and /clock, whose
#: publisher may be best-effort elsewhere) wait for the graph.
KNOWN_TYPES = {
    'pulse_width': 'std_msgs/msg/Float64',
    'recruitment': 'std_msgs/msg/Float64',
    # Needs the interface package (make interfaces, colcon); without it this
    # topic is left out of the defaults with a warning (Recorder.__init__).
    STIMULATION_TOPIC: STIMULATION_TYPE,
    'length_command': 'std_msgs/msg/Float64',
    'length_command_stamped': 'geometry_msgs/msg/PointStamped',
    'force': 'std_msgs/msg/Float64',
    'ce_length': 'std_msgs/msg/Float64',
    'wrench': 'geometry_msgs/msg/WrenchStamped',
    # The FES muscle's state (not in DEFAULT_TOPICS: more 1 kHz streams for
    # every run; add them to `topics` to record them). activation: each
    # channel's a, one entry per channel.
    'recruitment_state': 'std_msgs/msg/Float64',
    'fitness': 'std_msgs/msg/Float64',
    'activation': 'std_msgs/msg/Float64MultiArray',
    # The limb node's joint state (its muscles' topics sit under <muscle>/, so give their types).
    'joint_states': 'sensor_msgs/msg/JointState',
    DIAGNOSTICS_TOPIC: 'diagnostic_msgs/msg/DiagnosticArray',
}
#: Where bags go by default, one directory per run named by its UTC start time.
DEFAULT_RUNS_DIR = 'runs'
#: [s] how often the graph is polled for publishers of the wanted topics:
#: often, since a topic's first messages are lost until it is subscribed.
DISCOVERY_PERIOD_S = 0.02
#: [s] how often an open chunk is checked against its wall-time limit.
FLUSH_CHECK_PERIOD_S = 0.1
#: Messages DDS keeps for the recorder while Python is busy: 10 s at 1 kHz.
#: Reliable delivery only helps if the reader's history never overflows.
QUEUE_DEPTH = 10_000
#: [s] how often queued messages are taken from DDS and written. The
#: subscriptions are not spun by the executor: one wake-up per message costs
#: rclpy ~0.2 ms, too much for several 1 kHz topics on a small machine, so a
#: timer drains every queue in one go. Receive times come from DDS, so the
#: polling delay does not show in ``log_time`` (except with sim time).
TAKE_PERIOD_S = 0.01
#: [s] Fast DDS's default period of a reliable writer's heartbeats while a
#: reader has not acknowledged everything (``WriterTimes::heartbeatPeriod``,
#: 2.14). A reader asks for a lost sample again only when a heartbeat comes;
#: a writer that keeps publishing also sends heartbeats along with its data.
FASTDDS_HEARTBEAT_PERIOD_S = 3.0
#: [s] after a stop signal, the longest the recorder waits for a publisher's
#: stream to reach the stop (:meth:`Recorder.drain`): one heartbeat period, so
#: that even a publisher that has gone quiet has repaired a sample lost just
#: before the stop, and a margin for the request and the resend on a busy
#: machine.
DRAIN_TIMEOUT_S = FASTDDS_HEARTBEAT_PERIOD_S + 0.5
#: The sim-time source (REP 2008), global by convention.
CLOCK_TOPIC = '/clock'
#: QoS of the recorder's own ``/clock`` subscription on sim time (the
#: :class:`ReceiptClock`): best effort, so that it matches a best-effort
#: ``/clock`` publisher (rclcpp's ``ClockQoS``) as well as a reliable one, and
#: deep enough to hold every tick between two takes. Like rclpy's own
#: time-source subscription to ``/clock``, it takes no QoS override: best
#: effort already matches every publisher, and an override of the recorded
#: ``/clock`` (``qos_overrides./clock.subscription...``) stays the user's.
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=QUEUE_DEPTH,
                       reliability=ReliabilityPolicy.BEST_EFFORT)
#: [s] executor wake-up period (checks the stop flag).
SPIN_PERIOD_S = 0.05
#: Start of the log line that says the recorder is subscribed and writing.
READY_MESSAGE = 'ready: recording'
#: Bytes of the CDR encapsulation header before the payload.
CDR_HEADER_BYTES = 4
#: Stamp layout at the start of a message whose first field is a std_msgs/Header:
#: int32 sec, uint32 nanosec.
_STAMP_LE = struct.Struct('<iI')
_STAMP_BE = struct.Struct('>iI')
_HEADER_TYPE_LINE = 'std_msgs/Header header'


def subscriptions_node_name(node_name: str) -> str:
    """Name of the hidden node that holds a recorder's subscriptions.

    The ROS graph shows the recorder's subscriptions under this node, e.g.
    ``_recorder_subscriptions`` for ``recorder``: a launcher waits there for
    the recorder to be subscribed.
    """
    return f'_{node_name}_subscriptions'


def _never_called(_msg: Any) -> None:
    """Subscriptions are drained by :meth:`Recorder.take_all`, never by an executor."""


def default_output(now: _dt.datetime | None = None) -> Path:
    """``runs/<UTC timestamp>``, e.g. ``runs/2025-01-31T12-00-00Z``."""
    now = now or _dt.datetime.now(_dt.timezone.utc)
    return Path(DEFAULT_RUNS_DIR) / now.strftime('%Y-%m-%dT%H-%M-%SZ')


#: Separates a topic from its type in an entry of ``topics``.
TOPIC_TYPE_SEPARATOR = ':'


def parse_topic_entry(entry: str) -> tuple[str, str | None]:
    """``(topic, type)`` of one entry of the ``topics`` parameter.

    ``force`` gives ``('force', None)``; ``force_target:std_msgs/msg/Float64``
    gives ``('force_target', 'std_msgs/msg/Float64')`` (``std_msgs/Float64``
    is accepted and written in full).

    :raises ValueError: naming the entry if the topic is empty or the type is
        not ``pkg/msg/Type``
    """
    topic, sep, type_name = entry.partition(TOPIC_TYPE_SEPARATOR)
    topic = topic.strip()
    if not topic:
        raise ValueError(f'entry {entry!r} names no topic')
    if not sep:
        return topic, None
    try:
        package, namespace, name = split_type_name(type_name.strip())
    except ValueError:
        raise ValueError(f'entry {entry!r}: the type after {TOPIC_TYPE_SEPARATOR!r} must look '
                         f'like `pkg/msg/Type`, got {type_name!r}') from None
    return topic, f'{package}/{namespace}/{name}'


def message_class(type_name: str) -> type:
    """The Python class of a ROS message type, e.g. ``std_msgs/msg/Float64``."""
    package, namespace, name = type_name.split('/')
    return getattr(importlib.import_module(f'{package}.{namespace}'), name)


def has_header_first(type_name: str) -> bool:
    """Whether the type's first field is a ``std_msgs/Header`` (its stamp leads the CDR)."""
    for line in read_msg_file(type_name).splitlines():  # the .msg source of the schema
        line = line.split('#', 1)[0].strip()
        if line:
            return ' '.join(line.split()) in (_HEADER_TYPE_LINE, 'Header header')
    return False


def header_stamp_ns(data: bytes) -> int:
    """[ns] ``header.stamp`` of a serialized message whose first field is a Header."""
    little = len(data) > 1 and data[1] & 1
    sec, nanosec = (_STAMP_LE if little else _STAMP_BE).unpack_from(data, CDR_HEADER_BYTES)
    return sec * NS_PER_S + nanosec


def request_qos(offered: list[QoSProfile]) -> QoSProfile:
    """The subscription QoS that matches every publisher, as rosbag2 adapts it.

    Reliable only if all publishers are, transient-local only if all are;
    a deep keep-last queue so DDS can hold bursts while Python writes.
    Without publishers yet (a known topic subscribed early): reliable, volatile,
    which the package's nodes offer.
    """
    reliable = all(q.reliability == ReliabilityPolicy.RELIABLE for q in offered)
    # Volatile matches every publisher; transient-local only latched ones.
    latched = bool(offered) and all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL
                                    for q in offered)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=QUEUE_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                    else DurabilityPolicy.VOLATILE))


@dataclass
class _TopicStats:
    """What was received on one topic, and what its publisher's sequence numbers say was sent."""

    name: str
    stamped: bool
    publishers: int = 1
    received: int = 0
    first_seq: int | None = None
    last_seq: int | None = None
    lost: int = 0
    #: [ns] newest DDS source timestamp taken (the publisher's send time, system clock)
    newest_source_ns: int | None = None
    gap_events: list[tuple[int, int]] = field(default_factory=list)

    def add(self, seq: int | None) -> int:
        """Count one message; return how many were skipped before it (0 if none)."""
        self.received += 1
        if seq is None or self.publishers != 1:
            return 0
        if self.last_seq is not None and seq <= self.last_seq:
            # Out of order: another publisher joined; sequences no longer tell.
            self.publishers = 0
            return 0
        missing = 0
        if self.last_seq is not None and seq > self.last_seq + 1:
            missing = seq - self.last_seq - 1
            self.lost += missing
        if self.first_seq is None:
            self.first_seq = seq
        self.last_seq = seq
        return missing

    @property
    def sent(self) -> int | None:
        """Messages the (single) publisher sent from the first to the last one recorded."""
        if self.first_seq is None or self.publishers != 1:
            return None
        return self.last_seq - self.first_seq + 1


class Recorder(Node):
    """Records topics to a rosbag2 MCAP bag.

    :raises StartupError: if the output cannot be written (exists and is not
        empty, not writable, disk full)
    """

    NODE_NAME = NODE_NAME

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        topics = self.declare_parameter('topics', list(DEFAULT_TOPICS), ParameterDescriptor(
            type=ParameterType.PARAMETER_STRING_ARRAY, read_only=True,
            description='topics to record; relative names resolve in the node namespace'
        )).value
        output = self.declare_parameter('output', '', ParameterDescriptor(
            type=ParameterType.PARAMETER_STRING, read_only=True,
            description='bag directory (must not exist or be empty); '
                        f'default {DEFAULT_RUNS_DIR}/<UTC timestamp>')).value
        self.output = Path(output) if output else default_output()
        self._wanted = []
        known = {}
        for entry in topics:
            try:
                topic, type_name = parse_topic_entry(entry)
                if type_name is not None:
                    message_class(type_name)
                resolved = self.resolve_topic_name(topic)
            except (ValueError, ImportError, AttributeError,
                    rclpy.exceptions.InvalidTopicNameException) as err:
                raise StartupError(f'parameter `topics`: {err}') from None
            if resolved in self._wanted:
                continue
            if type_name is None and not self._importable(topic):
                continue
            self._wanted.append(resolved)
            type_name = type_name or KNOWN_TYPES.get(topic)
            if type_name is not None:
                known[resolved] = type_name
        # QoS overrides of the subscriptions (and of /diagnostics): checked
        # before the bag exists; applied on the reader node, which has no
        # arguments of its own.
        check_qos_overrides(self, list(parameter_overrides(self)), extra_topics=self._wanted)
        try:
            self._writer = BagWriter(self.output)
        except BagOutputError as err:
            raise StartupError(str(err)) from None
        self._use_sim_time = bool(self.get_parameter('use_sim_time').value)
        #: On sim time: the sim time at each DDS receive instant (see ReceiptClock).
        self._receipt_clock = ReceiptClock() if self._use_sim_time else None
        # Holds the subscriptions; never spun (see TAKE_PERIOD_S). Hidden ('_'),
        # and without global arguments so that a `__node:=` remap cannot give it
        # this node's name. Topic names given to it are already resolved.
        self._reader = rclpy.create_node(subscriptions_node_name(self.get_name()),
                                         use_global_arguments=False,
                                         start_parameter_services=False,
                                         parameter_overrides=qos_overrides_of(self))
        self._subs: dict[str, Any] = {}
        # Taken like the recorded topics, whether or not /clock is recorded too.
        self._clock_sub = (self._reader.create_subscription(ClockMsg, CLOCK_TOPIC,
                                                            _never_called, CLOCK_QOS)
                           if self._use_sim_time else None)
        self._types: dict[str, str] = {}
        self._stats: dict[str, _TopicStats] = {}
        self._warned_types: set[str] = set()
        self.failure: str = ''
        self.stop_requested = False
        #: [ns] system time of the stop request (DDS source timestamps use that clock)
        self.stop_time_ns: int | None = None
        self._drain_cut_short = False
        self._discovery = self.create_timer(DISCOVERY_PERIOD_S, self._discover)
        self._flush_timer = self.create_timer(FLUSH_CHECK_PERIOD_S, self._flush_if_due)
        self._take_timer = self.create_timer(TAKE_PERIOD_S, self.take_all)
        self._diagnostics = NodeDiagnostics(self, 'recording', self._diagnose)
        for name, type_name in known.items():
            self._subscribe(name, type_name, request_qos([]))
        self._discover()
        # Logged once the known topics are subscribed: a launcher may wait for it.
        self.get_logger().info(f'{READY_MESSAGE} {", ".join(self._wanted)} to {self.output}')

    def _importable(self, topic: str) -> bool:
        """Whether the type of one of the package's own topics can be imported.

        Not so for ``stimulation`` after a plain ``pip install .``, which
        cannot build the interface package: that topic is left out with one
        warning, as the simulator leaves out its input, rather than making
        every default recording an error. A topic given with its type is
        checked as given (an unknown type is a start-up error).
        """
        type_name = KNOWN_TYPES.get(topic)
        if type_name is None:
            return True
        try:
            message_class(type_name)
        except (ImportError, AttributeError) as err:
            self.get_logger().warning(
                f'{topic}: not recording it: its type {type_name} is not installed ({err}); '
                f'build it with `make interfaces` or colcon')
            return False
        return True

    # -- discovery ----------------------------------------------------------------

    def _discover(self) -> None:
        done = True
        for name in self._wanted:
            if name in self._stats and self._writer.has_topic(name):
                continue
            done = False
            infos = self.get_publishers_info_by_topic(name)
            if not infos:
                continue
            types = sorted({i.topic_type for i in infos})
            subscribed = self._types.get(name)
            if len(types) > 1 or (subscribed is not None and types != [subscribed]):
                if name not in self._warned_types:
                    self._warned_types.add(name)
                    self.get_logger().error(
                        f'{name}: publishers offer {", ".join(types)}, expected '
                        f'{subscribed or "one type"}; not recording it')
                continue
            if subscribed is None:
                self._subscribe(name, types[0], request_qos([i.qos_profile for i in infos]))
            elif not self._writer.has_topic(name):
                self._check_publishers_match(name, [i.qos_profile for i in infos])
        if done:
            self._discovery.cancel()

    def _subscribe(self, name: str, type_name: str, qos: QoSProfile) -> None:
        try:
            cls = message_class(type_name)
            stamped = has_header_first(type_name)
        except (ImportError, AttributeError, LookupError, ValueError) as err:
            if name not in self._warned_types:
                self._warned_types.add(name)
                self.get_logger().error(f'{name}: cannot record {type_name}: {err}')
            return
        try:
            sub = overridable_subscription(self._reader, cls, name, _never_called, qos, raw=True)
        except StartupError as err:  # values were checked at start-up: not expected
            self.get_logger().error(f'{name}: not recording it: {err}')
            return
        self._types[name] = type_name
        self._stats[name] = _TopicStats(name, stamped)
        if name == DIAGNOSTICS_TOPIC:
            self._stats[name].publishers = 0   # several writers: see _register
        self._subs[name] = sub

    def _check_publishers_match(self, name: str, offered: list[QoSProfile]) -> None:
        """Say once, as an error, that a publisher cannot match the start-up subscription.

        A best-effort publisher never matches the reliable reader subscribed
        at start-up: nothing it sends can be recorded. Subscribing again with
        its QoS would lose the start-up subscription's guarantee for the other
        publishers, so the user chooses (the topic by name only).
        """
        sub = self._subs.get(name)
        if sub is None or name in self._warned_types:
            return
        problems = [reason for compatibility, reason in
                    (qos_check_compatible(q, sub.qos_profile) for q in offered)
                    if compatibility == QoSCompatibility.ERROR]
        if problems:
            self._warned_types.add(name)
            self.get_logger().error(
                f'{name}: a publisher cannot match the subscription made at start-up '
                f'({problems[0].strip()}); nothing it sends is recorded. Give {name} '
                f'without its type to subscribe with the publishers\' QoS')

    def _register(self, name: str) -> None:
        """Add the topic to the bag at its first message, with the publishers' QoS."""
        infos = self.get_publishers_info_by_topic(name)
        self._writer.add_topic(name, self._types[name],
                               offered_qos_profiles=[i.qos_profile for i in infos])
        self._stats[name].publishers = len(infos) or 1  # graph may lag the data
        if name == DIAGNOSTICS_TOPIC:
            # Every node publishes there, this one too: the sequence numbers of
            # several writers interleave and cannot tell a loss.
            self._stats[name].publishers = 0
        self.get_logger().info(f'recording {name} ({self._types[name]}, '
                               f'{len(infos)} publisher(s))')

    # -- messages -----------------------------------------------------------------

    def take_all(self) -> int:
        """Take and write every message queued on every subscription.

        :return: the number of messages written
        """
        written = 0
        pending = []   # on sim time: recorded once /clock has been taken up to them
        for topic, sub in list(self._subs.items()):
            while not self.failure:
                # rclpy 7.1.6 has no public take on a Subscription; this is the
                # call its own executors and wait_for_message make on the handle.
                with sub.handle:
                    taken = sub.handle.take_message(sub.msg_type, True)
                if taken is None:
                    break
                if self._receipt_clock is None:
                    self._record(topic, *taken)
                    written += 1
                else:
                    pending.append((topic, *taken))
        # After the data: every /clock message received before the last one
        # taken above is taken now, so each gets the sim time in force when it
        # arrived (and with no data, the /clock queue is still kept short).
        self.take_clock()
        for topic, data, info in pending:
            if self.failure:
                break
            self._record(topic, data, info)
            written += 1
        return written

    def take_clock(self) -> int:
        """On sim time: take the ``/clock`` messages DDS has received into the
        :class:`ReceiptClock`, with their receive instants.

        :return: the number taken (0 on the system clock)
        """
        if self._clock_sub is None:
            return 0
        count = 0
        while True:
            with self._clock_sub.handle:
                taken = self._clock_sub.handle.take_message(ClockMsg, False)
            if taken is None:
                return count
            msg, info = taken
            received_ns = info.get('received_timestamp')
            if received_ns:
                self._receipt_clock.add(received_ns,
                                        msg.clock.sec * NS_PER_S + msg.clock.nanosec)
            count += 1

    def _record(self, topic: str, data: bytes, info: dict[str, Any]) -> None:
        stats = self._stats[topic]
        if not self._writer.has_topic(topic):
            self._register(topic)
        if self._receipt_clock is not None:
            received_ns = info.get('received_timestamp')
            sim_ns = self._receipt_clock.sim_ns_at(received_ns) if received_ns else None
            # Before the first /clock message: what the node's clock says (0).
            log_ns = sim_ns if sim_ns is not None else self.get_clock().now().nanoseconds
        else:
            # DDS's receive instant on the system clock, i.e. this node's clock,
            # and not delayed by how long the message waited for Python. Fast DDS
            # 2.14 stamps it when the sample becomes available to the reader: a
            # sample that waited behind a lost one gets the time of the repair.
            log_ns = info.get('received_timestamp') or self.get_clock().now().nanoseconds
        publish_ns = header_stamp_ns(data) if stats.stamped else log_ns
        seq = info.get('publication_sequence_number')
        source_ns = info.get('source_timestamp')
        if source_ns and (stats.newest_source_ns is None or source_ns > stats.newest_source_ns):
            stats.newest_source_ns = source_ns
        try:
            self._writer.write(topic, data, log_ns, publish_ns, sequence=seq or 0)
        except OSError as err:
            self._fail(f'writing {self._writer.mcap_path} failed: {err.strerror or err}')
            return
        missing = stats.add(seq)
        if missing:
            self.get_logger().warning(
                f'{topic}: {missing} message(s) lost before sequence number {seq} '
                f'({stats.lost} so far)', throttle_duration_sec=1.0)

    def _flush_if_due(self) -> None:
        if self.failure:
            return
        try:
            self._writer.flush_if_due()
        except OSError as err:
            self._fail(f'writing {self._writer.mcap_path} failed: {err.strerror or err}')

    def _fail(self, reason: str) -> None:
        """Stop recording after an I/O error; what is on disk stays readable."""
        self.failure = reason
        self.stop_requested = True
        self.get_logger().error(f'{reason}; stopping, the bag keeps what was written before')

    def _diagnose(self, report: DiagnosticReport) -> None:
        """/diagnostics: messages received, written, on disk and lost per topic;
        WARN once any message was lost (the bag has a hole); ERROR after a write
        error, or while a wanted topic cannot be recorded (a publisher of another
        type, or one the start-up subscription's QoS cannot match: logged once)."""
        report.add('bag', str(self.output))
        written, on_disk = self._writer.counts, self._writer.flushed_counts
        lost = {}
        for name in self._wanted:
            stats = self._stats.get(name)
            report.add(f'received[{name}]', stats.received if stats else 0)
            report.add(f'written[{name}]', written.get(name, 0))
            report.add(f'on_disk[{name}]', on_disk.get(name, 0))
            report.add(f'lost[{name}]', stats.lost if stats else 0)
            if stats is not None and stats.lost:
                lost[name] = stats.lost
        total_lost = sum(lost.values())
        report.add('received_total', sum(s.received for s in self._stats.values()))
        report.add('written_total', sum(written.values()))
        report.add('lost_total', total_lost)
        report.add('lost_last_period', report.delta('lost', total_lost))
        if self.failure:
            report.error(self.failure)
        if self._warned_types:
            report.error(f'not recording (all or some publishers of) '
                         f'{", ".join(sorted(self._warned_types))}: see the log')
        if total_lost:
            report.warn(f'{total_lost} message(s) lost: '
                        + ', '.join(f'{n} {k}' for n, k in lost.items()))
        report.ok(f'recording {len(written)} of {len(self._wanted)} topics to {self.output}')

    # -- stopping -----------------------------------------------------------------

    def request_stop(self, stop_ns: int | None = None) -> None:
        """Stop recording (a stop signal); a second request cuts :meth:`drain` short.

        :param stop_ns: [ns] system time of the stop signal; ``None``: now
        """
        if self.stop_requested:
            self._drain_cut_short = True
            return
        self.stop_time_ns = time.time_ns() if stop_ns is None else stop_ns
        self.stop_requested = True

    def behind_the_stop(self, stop_ns: int) -> list[str]:
        """Topics whose publisher may still have messages sent before ``stop_ns`` in flight.

        A reliable writer's samples are delivered in order: after a lost
        datagram, DDS holds everything later from that writer until the
        writer has sent it again, which it does on its next heartbeat (a
        hole of 0.1 to 0.8 s was measured at 1 kHz on a loaded machine). An
        empty queue therefore does not mean that nothing sent before the
        stop is still to come. Once a message sent at or after ``stop_ns``
        (its DDS source timestamp) has been taken, everything its publisher
        sent before has been taken or counted lost. That holds per
        publisher, so a topic is waited for only while it has exactly one
        (by the graph, and by its sequence numbers) that can match the
        subscription; with none, nothing more can come.

        :param stop_ns: [ns] system time of the stop
        """
        behind = []
        for name, stats in self._stats.items():
            if name in self._warned_types or stats.publishers != 1:
                continue
            if stats.newest_source_ns is not None and stats.newest_source_ns >= stop_ns:
                continue
            if self.count_publishers(name) == 1:
                behind.append(name)
        return behind

    def drain(self, timeout_s: float = DRAIN_TIMEOUT_S) -> None:
        """After a stop request, take and write what was sent before the stop.

        Takes until no topic is :meth:`behind_the_stop` and a pass over the
        queues finds them empty (topics with several publishers are drained
        up to that first empty pass), or until ``timeout_s``, or a second
        stop request. Publishers may still be running: what they sent after
        the stop and is taken meanwhile is written too. A topic still behind
        at the end is logged with how much before the stop its newest
        recorded message was sent: a quiet publisher, or messages that did
        not arrive in time and are not in the bag.
        """
        stop_ns = self.stop_time_ns if self.stop_time_ns is not None else time.time_ns()
        deadline = time.monotonic() + timeout_s
        while not self.failure:
            taken = self.take_all()
            behind = self.behind_the_stop(stop_ns)
            if not taken and not behind:
                return
            if time.monotonic() >= deadline or self._drain_cut_short:
                why = ('stopped at a second signal' if self._drain_cut_short
                       else f'waited {timeout_s:g} s')
                for name in behind:
                    newest = self._stats[name].newest_source_ns
                    self.get_logger().info(
                        f'{name}: nothing its publisher sent after the stop arrived ({why}); '
                        + ('nothing was received from it' if newest is None else
                           f'the newest message recorded was sent '
                           f'{(stop_ns - newest) / NS_PER_S:.3f} s before the stop')
                        + ': a quiet publisher, or what it sent since then is not in the bag')
                return
            if not taken:
                time.sleep(TAKE_PERIOD_S)

    def report(self) -> str:
        """One line per topic: received, sent (from sequence numbers), lost."""
        lines = []
        for name in self._wanted:
            stats = self._stats.get(name)
            if stats is None or not stats.received:
                lines.append(f'{name}: no message received')
                continue
            sent = stats.sent
            sent_txt = f', publisher sent {sent}' if sent is not None else ''
            if stats.first_seq is not None and stats.first_seq > 1 and stats.publishers == 1:
                sent_txt += f' (and {stats.first_seq - 1} before the recorder matched)'
            lines.append(f'{name}: {stats.received} recorded{sent_txt}, {stats.lost} lost')
        return '\n'.join(lines)

    def close(self) -> int:
        """Close the bag (summary, metadata.yaml), log the counts; return the exit status."""
        self._take_timer.cancel()
        for sub in self._subs.values():
            self._reader.destroy_subscription(sub)
        self._subs.clear()
        if self._clock_sub is not None:
            self._reader.destroy_subscription(self._clock_sub)
            self._clock_sub = None
        self._reader.destroy_node()
        try:
            self._writer.close()
        except OSError as err:
            self.failure = self.failure or f'closing {self._writer.mcap_path} failed: {err}'
        lost = sum(s.lost for s in self._stats.values())
        log = self.get_logger()
        (log.warning if lost else log.info)(
            f'bag {self.output}: {sum(self._writer.counts.values())} messages\n' + self.report())
        if self.failure:
            log.error(f'recording stopped early: {self.failure}. Complete chunks are '
                      f'readable; metadata.yaml lists what reached the disk')
            return EXIT_FAILURE
        return EXIT_SUCCESS


def main(args: list[str] | None = None) -> int:
    """Entry point: ``recorder [--ros-args ...]``; returns the exit status.

    rclpy's own signal handlers would shut the context down at once and drop
    what DDS has delivered but the node has not yet written. This node takes
    SIGINT and SIGTERM itself, stops, drains, and closes the bag.
    """
    node = None
    executor = None
    status = EXIT_SUCCESS
    #: [ns] system times of the stop signals that came before the node existed
    early_stops: list[int] = []

    def request_stop(signum: int, _frame: Any) -> None:
        if node is not None:
            node.request_stop()
        else:
            # Not raised: a signal that lands inside the constructor, once the
            # bag is open and DDS may have acknowledged messages to the new
            # subscriptions, would leave the bag unclosed and those messages
            # unwritten (a fresh clone's run: exit 0, a bag of only its header).
            early_stops.append(time.time_ns())

    previous = {s: signal.signal(s, request_stop) for s in (signal.SIGINT, signal.SIGTERM)}

    def restore_handlers() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    started, transport_note = init_ros(args, NODE_NAME)
    if not started:
        restore_handlers()
        return EXIT_FAILURE
    try:
        # The nodes' executor (EventsExecutor by default): the recorder wakes
        # about 180 times a second on its timers even with nothing to record,
        # and each wake of the SingleThreadedExecutor rebuilds its wait set in
        # Python (idle: 0.08-0.09 CPU-s a second with it, 0.04 with events).
        executor = make_executor()
        node = Recorder()
        for stop_ns in early_stops:
            node.request_stop(stop_ns)
        if transport_note is not None:
            node.get_logger().info(transport_note)
        executor.add_node(node)
        while not node.stop_requested and rclpy.ok():
            executor.spin_once(timeout_sec=SPIN_PERIOD_S)
        node.drain()
    except StartupError as err:
        rclpy.logging.get_logger(NODE_NAME).error(str(err))
        status = EXIT_FAILURE
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            status = node.close()
        # The bag is closed: a hung middleware teardown must not keep the process.
        guard = TeardownGuard(status)
        if executor is not None:
            # Before the node goes: the EventsExecutor holds callbacks on its entities.
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        restore_handlers()
        rclpy.try_shutdown()
        guard.stop()
    return status


#: The console script (setup.py): main(), then the process ends at once.
process_main = process_entry(main)


if __name__ == '__main__':
    process_main()
