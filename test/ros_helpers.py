"""Helpers for tests that run ROS 2 nodes as real processes over real DDS.

No mocking: nodes run in their own processes, and the test talks to them from
a :class:`Probe`, an rclpy node in the test process with its own context.

Typical use::

    from ros_helpers import Probe, ProcessGroup, node_command

    def test_something(tmp_path):
        with ProcessGroup(tmp_path) as procs, Probe() as probe:
            sim = procs.start('sim', node_command('simulator', ns='/t1', params={'rate_hz': 200.0}))
            force = probe.record('/t1/force', Float64)
            probe.spin_until(lambda: force.messages, 'a force message', procs=[sim])

- Every process gets :func:`ros_env` (the test run's ROS_DOMAIN_ID and
  ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST from ``conftest.py``), its own
  process group, and a log file (stdout and stderr) readable with
  :meth:`NodeProcess.output`.
- A node script of the package is started as a fork of a Python that has
  imported the nodes and loaded their kernels already (``node_zygote.py``):
  the same function as the script, a process of its own, 30 % of the ROS
  tests' CPU time less. ``HILL_MUSCLE_TEST_FORK=0`` starts every node from
  its console script instead.
- :class:`ProcessGroup` stops every process it started when the ``with``
  block ends, also on failure: SIGINT, then SIGKILL of the process group after
  :data:`STOP_TIMEOUT_S`.
- Waiting is always on a condition with a deadline (:meth:`Probe.spin_until`),
  never a bare sleep; the deadlines are generous because the test machine is
  small and shared. A timeout message includes the tail of every process log,
  and a process that dies while the test waits fails the wait at once.

The processes, the waiting loop and the graph probe are those of
:mod:`hill_muscle_ros.supervisor`, which the demos and the benchmarks use
too; here a failed wait is a failed test (``AssertionError``).
"""
from __future__ import annotations

import subprocess
import time
from pathlib import Path
from typing import Any, Callable, Iterable

from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient

from hill_muscle_ros import supervisor
from hill_muscle_ros.qos import RELIABLE_QOS
from node_zygote import ZYGOTE
from hill_muscle_ros.supervisor import (LOG_TAIL_CHARS, SPIN_SLICE_S,  # noqa: F401
                                        STOP_TIMEOUT_S, VENV_BIN, GraphProbe,
                                        SupervisorError, node_command)

#: [s] default deadline of a wait: long, as the 2-core box is shared and a
#: cold Python + DDS start can take several seconds under load.
DEFAULT_TIMEOUT_S = 30.0
#: [s] how long a new service client waits for its first reply before it
#: sends the request once more (Probe.call): a local reply takes milliseconds.
FIRST_REPLY_WAIT_S = 5.0


def ros_env(**extra: str) -> dict[str, str]:
    """Environment for a node subprocess: the test's own plus unbuffered logs.

    ``conftest.py`` put ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE into
    ``os.environ``; copying it passes them on.
    """
    return supervisor.ros_environment(**extra)


def start_in_background(cmd: list[str], out_dir: Path, timeout_s: float,
                        env: dict[str, str] | None = None) -> Callable[[], Any]:
    """Start ``cmd`` (a demo, say) with its output in ``out_dir`` (files, not
    pipes: nothing reads it meanwhile); return a call that waits for it, up to
    ``timeout_s`` (then kills it), and gives its
    :class:`subprocess.CompletedProcess`. The call may be made more than once.
    """
    stdout, stderr = out_dir / 'stdout.txt', out_dir / 'stderr.txt'
    with open(stdout, 'w') as o, open(stderr, 'w') as e:
        proc = subprocess.Popen(cmd, stdout=o, stderr=e, text=True,
                                env=ros_env() if env is None else env)

    def finished() -> subprocess.CompletedProcess:
        try:
            status = proc.wait(timeout=timeout_s)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        return subprocess.CompletedProcess(cmd, status, stdout.read_text(errors='replace'),
                                           stderr.read_text(errors='replace'))
    return finished


class RecordingLogger:
    """Stands in for a node's logger: records what it would log, by level
    (``('info', text)``, ``('warning', text)``)."""

    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def info(self, text: str) -> None:
        self.lines.append(('info', text))

    def warning(self, text: str) -> None:
        self.lines.append(('warning', text))


class NodeProcess(supervisor.Process):
    """One node process with its output in a log file (:class:`hill_muscle_ros.supervisor.Process`).

    A wait that fails is a failed test: :meth:`wait` raises ``AssertionError``.
    """

    def _spawn(self, env, preexec_fn):
        # A node script of the package is forked from the node zygote (node_zygote.py).
        if ZYGOTE.forkable(self.cmd, env, preexec_fn):
            return ZYGOTE.start(self.cmd, env, self.log_path)
        return super()._spawn(env, preexec_fn)

    def wait(self, timeout_s: float = DEFAULT_TIMEOUT_S) -> int:
        """Wait for the process to exit on its own; fail the test on timeout."""
        try:
            return super().wait(timeout_s)
        except SupervisorError as err:
            raise AssertionError(str(err)) from None


class ProcessGroup(supervisor.ProcessGroup):
    """Starts node processes and stops them all when the ``with`` block ends.

    SIGINT, then SIGKILL of each process group after :data:`STOP_TIMEOUT_S`.

    :param log_dir: directory for the log files (e.g. pytest's ``tmp_path``)
    """

    process_class = NodeProcess

    def __init__(self, log_dir: Path) -> None:
        super().__init__(log_dir, env=ros_env())

    def wait_until(self, condition: Callable[[], Any], what: str,
                   timeout_s: float = DEFAULT_TIMEOUT_S,
                   watch: Iterable[NodeProcess] | None = None, step=None) -> Any:
        """Wait for ``condition`` (no ROS spinning); a watched process that exits fails
        the test at once with its log tail (default: every process of the group)."""
        try:
            return super().wait_until(condition, what, timeout_s, watch, step)
        except SupervisorError as err:
            raise AssertionError(str(err)) from None


class Recording:
    """Messages received on one topic, with their arrival times.

    :ivar messages: the messages, in arrival order
    :ivar times_s: [s] ``time.monotonic()`` at each arrival
    """

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.messages: list[Any] = []
        self.times_s: list[float] = []
        self._listeners: list[Callable[[Any], None]] = []

    def _on_message(self, msg: Any) -> None:
        self.messages.append(msg)
        self.times_s.append(time.monotonic())
        for listener in self._listeners:
            listener(msg)

    def add_listener(self, listener: Callable[[Any], None]) -> None:
        """Also call ``listener(msg)`` for every message from now on."""
        self._listeners.append(listener)

    def mark(self) -> int:
        """Index of the next message: use with :meth:`since`."""
        return len(self.messages)

    def since(self, mark: int) -> list[Any]:
        """Messages received after :meth:`mark` returned ``mark``."""
        return self.messages[mark:]

    def data_since(self, mark: int) -> list[float]:
        """``msg.data`` of the messages since ``mark`` (std_msgs/Float64 etc.)."""
        return [m.data for m in self.messages[mark:]]


class Probe(GraphProbe):
    """An rclpy node in the test process, in its own context.

    Records topics, publishes, calls services and sets parameters of the
    nodes under test; tells readiness from the graph
    (:class:`hill_muscle_ros.supervisor.GraphProbe`). Use it as a context
    manager so that it shuts down.

    :param name: node name
    :param executor: ``single`` where a subscription's callback takes the
        ``MessageInfo`` (see :attr:`GraphProbe.PROBE_EXECUTORS`)
    """

    def __init__(self, name: str = 'test_probe', executor: str = 'events') -> None:
        super().__init__(name, executor=executor)
        self._recordings: dict[str, Recording] = {}
        self._publishers: dict[str, Any] = {}
        self._parameter_clients: dict[str, AsyncParameterClient] = {}
        self._service_clients: dict[tuple[type, str], Any] = {}

    # -- waiting ----------------------------------------------------------------

    def spin_until(self, condition: Callable[[], Any], what: str,
                   timeout_s: float = DEFAULT_TIMEOUT_S,
                   procs: Iterable[NodeProcess] = ()) -> Any:
        """Spin until ``condition()`` is truthy; return its value.

        :param condition: checked after every spin slice
        :param what: what is awaited, for the failure message
        :param timeout_s: [s] deadline
        :param procs: processes that must stay alive meanwhile; their logs
            are quoted if the wait fails
        :raises AssertionError: on timeout or at once if one of ``procs`` exits
        """
        try:
            return super().spin_until(condition, what, timeout_s, procs)
        except SupervisorError as err:
            raise AssertionError(str(err)) from None

    def spin_for(self, duration_s: float) -> None:
        """Keep receiving for ``duration_s`` (to collect messages, not to sync)."""
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            self.spin_once()

    def wait_for_messages(self, rec: Recording, count: int = 1, *, mark: int = 0,
                          timeout_s: float = DEFAULT_TIMEOUT_S,
                          procs: Iterable[NodeProcess] = ()) -> list[Any]:
        """Wait for ``count`` messages on ``rec`` after ``mark``; return them."""
        return self.spin_until(lambda: len(rec.since(mark)) >= count and rec.since(mark),
                               f'{count} message(s) on {rec.topic}', timeout_s, procs)

    def wait_for_value(self, rec: Recording, predicate: Callable[[float], bool], what: str, *,
                       mark: int = 0, timeout_s: float = DEFAULT_TIMEOUT_S,
                       procs: Iterable[NodeProcess] = ()) -> int:
        """Wait until a message after ``mark`` has ``predicate(msg.data)``.

        :return: the index of that message in ``rec.messages``
        """
        def found():
            for i in range(mark, len(rec.messages)):
                if predicate(rec.messages[i].data):
                    return i + 1  # truthy even for index 0
            return 0
        def describe():
            return f'{rec.topic}: {what} (last values: {rec.data_since(len(rec.messages) - 5)})'
        try:
            return self.spin_until(found, f'{rec.topic}: {what}', timeout_s, procs) - 1
        except AssertionError as err:
            raise AssertionError(f'{describe()}\n{err}') from None

    # -- topics -----------------------------------------------------------------

    def record(self, topic: str, msg_type: type, qos=RELIABLE_QOS) -> Recording:
        """Subscribe to ``topic`` (once) and record what arrives."""
        if topic not in self._recordings:
            rec = Recording(topic)
            self.node.create_subscription(msg_type, topic, rec._on_message, qos)
            self._recordings[topic] = rec
        return self._recordings[topic]

    def publisher(self, topic: str, msg_type: type):
        """A reliable publisher on ``topic`` (created once)."""
        if topic not in self._publishers:
            self._publishers[topic] = self.node.create_publisher(msg_type, topic, RELIABLE_QOS)
        return self._publishers[topic]

    def retire(self, topic: str, timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
        """Retire the publisher on ``topic`` (:meth:`GraphProbe.retire_publisher`):
        before a recorder stops, so that it does not wait for more from a
        publisher that has gone quiet."""
        self.retire_publisher(self._publishers.pop(topic), timeout_s)

    def publish_when_matched(self, topic: str, msg: Any, *, subscribers: int = 1,
                             timeout_s: float = DEFAULT_TIMEOUT_S,
                             procs: Iterable[NodeProcess] = ()) -> None:
        """Publish once ``subscribers`` subscriptions are matched (name every
        node that listens: one matched subscriber says nothing of the others),
        so the message is not lost."""
        pub = self.publisher(topic, type(msg))
        self.spin_until(lambda: pub.get_subscription_count() >= subscribers,
                        f'{subscribers} subscriber(s) on {topic}', timeout_s, procs)
        pub.publish(msg)

    # -- services and parameters ------------------------------------------------

    def call(self, srv_type: type, name: str, request: Any, *,
             timeout_s: float = DEFAULT_TIMEOUT_S, procs: Iterable[NodeProcess] = ()) -> Any:
        """Call a service once it is available; return the response.

        One client per service for the probe's life: ``service_is_ready``
        says the server reads the client's requests, not that the server's
        reply writer has matched the client's reply reader, so a new client's
        first reply can be sent to nobody and is then lost for good (a reset
        that ran, whose reply never came, twice in fresh-clone runs). A first
        call without a reply after :data:`FIRST_REPLY_WAIT_S` is sent once
        more, saying so; every later call goes over matched endpoints.
        """
        client = self._service_clients.get((srv_type, name))
        first = client is None
        if first:
            client = self._service_clients[(srv_type, name)] = self.node.create_client(
                srv_type, name)
        self.spin_until(client.service_is_ready, f'service {name}', timeout_s, procs)
        future = client.call_async(request)
        if first:
            deadline = time.monotonic() + FIRST_REPLY_WAIT_S
            self.spin_until(lambda: future.done() or time.monotonic() > deadline,
                            f'first response of {name}', timeout_s, procs)
            if not future.done():
                print(f'\nno reply from {name} {FIRST_REPLY_WAIT_S:g} s after a new '
                      'client\'s first request: sent once more', flush=True)
                future = client.call_async(request)
        self.spin_until(future.done, f'response of {name}', timeout_s, procs)
        return future.result()

    def _parameter_client(self, node_name: str, timeout_s: float,
                          procs: Iterable[NodeProcess]) -> AsyncParameterClient:
        """One parameter client per remote node, kept for the probe's life, once
        its services are ready.

        A new client per call raced each time: ready means that this side has
        matched the services, not that the service's response writer has
        matched this client's reader yet. rmw_fastrtps waits 100 ms for that
        match before it sends a response and drops the response after
        (ros2/rmw_fastrtps#390 and #467): a get_parameters waited 30 s for
        one beside three other ROS test modules. A client kept after its
        first answer has that behind it for each service it has called."""
        client = self._parameter_clients.get(node_name)
        if client is None:
            client = self._parameter_clients[node_name] = AsyncParameterClient(
                self.node, node_name)
        self.spin_until(lambda: client.services_are_ready(), f'parameter services of {node_name}',
                        timeout_s, procs)
        return client

    def set_parameters(self, node_name: str, parameters: dict[str, Any], *,
                       timeout_s: float = DEFAULT_TIMEOUT_S,
                       procs: Iterable[NodeProcess] = ()) -> list[Any]:
        """Set parameters of a remote node through its parameter services.

        :param node_name: fully qualified node name, e.g. ``/left/simulator``
        :return: one ``SetParametersResult`` per parameter (``successful``, ``reason``)
        """
        client = self._parameter_client(node_name, timeout_s, procs)
        future = client.set_parameters([Parameter(n, value=v) for n, v in parameters.items()])
        self.spin_until(future.done, f'set_parameters on {node_name}', timeout_s, procs)
        return list(future.result().results)

    def get_parameters(self, node_name: str, names: list[str], *,
                       timeout_s: float = DEFAULT_TIMEOUT_S,
                       procs: Iterable[NodeProcess] = ()) -> dict[str, Any]:
        """Read parameters of a remote node; return name to Python value."""
        client = self._parameter_client(node_name, timeout_s, procs)
        future = client.get_parameters(names)
        self.spin_until(future.done, f'get_parameters on {node_name}', timeout_s, procs)
        return {n: parameter_value_to_python(v)
                for n, v in zip(names, future.result().values)}
