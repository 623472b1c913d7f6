"""A node's status on ``/diagnostics``, once a second (ROS side only, no model logic).

/diagnostics is the ROS convention diagnostic_aggregator and
rqt_runtime_monitor read. diagnostic_updater is not on PyPI;
:class:`NodeDiagnostics` (with :class:`DiagnosticReport`) is the small part
of it this package needs.
"""
from __future__ import annotations

import time
from typing import Any, Callable

from rclpy.node import Node
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ._parameters import declare_checked, number_descriptor
from ._topics import DIAGNOSTICS_TOPIC, overridable_publisher

#: [s] one DiagnosticArray per node per second, diagnostic_updater's default period.
DIAGNOSTICS_PERIOD_S = 1.0
#: The parameter that sets the period, named as diagnostic_updater names it
#: (``diagnostic_updater.period``, C++ and Python), so that one params file
#: sets it for nodes of either kind.
DIAGNOSTICS_PERIOD_PARAMETER = 'diagnostic_updater.period'
#: [s] the range accepted for it: at most 20 reports a second, since each is a
#: DiagnosticArray per node on one shared topic (and a report period shorter
#: than a few steps says little about a step rate); at least one an hour.
DIAGNOSTICS_PERIOD_RANGE_S = (0.05, 3600.0)
#: Reliable, volatile, keep-last 10: 10 s of a node's reports at 1 Hz, so a
#: recorder or aggregator that is descheduled for a moment still gets each one.
DIAGNOSTICS_HISTORY_DEPTH = 10
DIAGNOSTICS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DIAGNOSTICS_HISTORY_DEPTH,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)

#: [s] how long a node's last status waits for its subscribers' acknowledgement.
DIAGNOSTICS_ACK_TIMEOUT_S = 1.0


class DiagnosticReport:
    """What one status says, filled in by a node's check each period.

    Conditions raise the level (OK < WARN < ERROR); the status message lists
    them worst first, so the first words say why the level is what it is.

    :param period_s: [s] of steady time since the previous report
    :param previous: the totals of the previous report, by key (see :meth:`delta`)
    """

    _LEVELS = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR)

    def __init__(self, period_s: float, previous: dict[str, float]) -> None:
        self.period_s = period_s
        self.values: list[KeyValue] = []
        self._rank = 0
        self._messages: list[tuple[int, str]] = []
        self._previous = previous

    def add(self, key: str, value: Any) -> None:
        """One value: floats to 6 significant digits, booleans as true/false, None as ''."""
        if isinstance(value, bool):
            text = 'true' if value else 'false'
        elif isinstance(value, float):
            text = f'{value:.6g}'
        else:
            text = '' if value is None else str(value)
        self.values.append(KeyValue(key=key, value=text))

    def delta(self, key: str, total: float) -> float:
        """``total`` minus its value at the previous report (0 before the first)."""
        change = total - self._previous.get(key, 0)
        self._previous[key] = total
        return change

    def ok(self, message: str) -> None:
        """A normal condition, said only when nothing is worse."""
        self._messages.append((0, message))

    def warn(self, message: str) -> None:
        """A condition that degrades the node's output."""
        self._raise(1, message)

    def error(self, message: str) -> None:
        """A condition under which the node does not do its job."""
        self._raise(2, message)

    def _raise(self, rank: int, message: str) -> None:
        self._rank = max(self._rank, rank)
        self._messages.append((rank, message))

    @property
    def level(self) -> bytes:
        """``DiagnosticStatus.OK``, ``WARN`` or ``ERROR``."""
        return self._LEVELS[self._rank]

    @property
    def message(self) -> str:
        """The conditions of the worst level, then the others, joined by '; '."""
        ordered = sorted(self._messages, key=lambda rm: -rm[0])
        shown = [m for r, m in ordered if r > 0 or self._rank == 0]
        return '; '.join(shown) or 'OK'


class NodeDiagnostics:
    """Publishes one DiagnosticStatus of a node on ``/diagnostics`` every period.

    ``name`` is ``<fully qualified node name>: <function>`` (the node-prefixed
    names diagnostic_updater gives), ``hardware_id`` the node's fully qualified
    name. ``check(report)`` fills a :class:`DiagnosticReport` each period; an
    exception in it is reported as an ERROR status and logged, never raised
    into the executor. The timer runs on the steady clock, so a node on sim
    time reports also while ``/clock`` stands still; the header stamp is the
    node's clock.

    :param node: the node reported on
    :param function: what the node does, e.g. ``muscle simulation``
    :param check: fills the report
    :param period_s: [s] reporting period; None: the node's parameter
        :data:`DIAGNOSTICS_PERIOD_PARAMETER` (declared here, default
        :data:`DIAGNOSTICS_PERIOD_S`)
    :raises StartupError: if that parameter is out of range or not a float
    """

    def __init__(self, node: Node, function: str, check: Callable[[DiagnosticReport], None],
                 period_s: float | None = None) -> None:
        if period_s is None:
            period_s = declare_checked(node, DIAGNOSTICS_PERIOD_PARAMETER, DIAGNOSTICS_PERIOD_S,
                                       number_descriptor(
                                           f'period of this node\'s status on '
                                           f'{DIAGNOSTICS_TOPIC}', 's',
                                           *DIAGNOSTICS_PERIOD_RANGE_S, read_only=True))
        self._node = node
        self._check = check
        fqn = node.get_fully_qualified_name()
        self.name = f'{fqn}: {function}'
        self.hardware_id = fqn
        self._previous: dict[str, float] = {}
        self._last_s = time.monotonic()
        self._failed = False
        self._pub = overridable_publisher(node, DiagnosticArray, DIAGNOSTICS_TOPIC,
                                          DIAGNOSTICS_QOS)
        self._timer = node.create_timer(period_s, self.publish,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    def report(self) -> DiagnosticReport:
        """Run the check over the period since the previous report."""
        now_s = time.monotonic()
        report = DiagnosticReport(now_s - self._last_s, self._previous)
        self._last_s = now_s
        try:
            self._check(report)
        except Exception as err:  # noqa: BLE001 - a bad check must not stop the node
            if not self._failed:
                self._node.get_logger().error(f'diagnostics check failed: {err!r}')
            self._failed = True
            report.error(f'diagnostics check failed: {err!r}')
        return report

    def publish(self) -> None:
        """Publish the status now (the timer calls this every period)."""
        report = self.report()
        msg = DiagnosticArray()
        msg.header.stamp = self._node.get_clock().now().to_msg()
        msg.status = [DiagnosticStatus(level=report.level, name=self.name,
                                       message=report.message, hardware_id=self.hardware_id,
                                       values=report.values)]
        self._pub.publish(msg)

    def publish_final(self, timeout_s: float = DIAGNOSTICS_ACK_TIMEOUT_S) -> bool:
        """Publish the status now and wait (at most ``timeout_s``) until every
        subscriber acknowledged it: the last status of a node about to exit.

        :return: whether every subscriber acknowledged it in time
        """
        self.publish()
        return self._pub.wait_for_all_acked(Duration(seconds=timeout_s))
