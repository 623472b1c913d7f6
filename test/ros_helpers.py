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
- :class:`ProcessGroup` stops every process it started when the ``with``
  block ends, also on failure: SIGINT, then SIGKILL of the process group after
  :data:`STOP_TIMEOUT_S`.
- Waiting is always on a condition with a deadline (:meth:`Probe.spin_until`),
  never a bare sleep; the deadlines are generous because the test machine is
  small and shared. A timeout message includes the tail of every process log,
  and a process that dies while the test waits fails the wait at once.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterable

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient

from hill_muscle_ros.nodes._common import RELIABLE_QOS

#: [s] default deadline of a wait: long, as the 2-core box is shared and a
#: cold Python + DDS start can take several seconds under load.
DEFAULT_TIMEOUT_S = 30.0
#: [s] grace period between SIGINT and SIGKILL when stopping a process.
STOP_TIMEOUT_S = 10.0
#: Characters of a process log quoted in a failure message.
LOG_TAIL_CHARS = 3000
#: [s] one executor spin slice while waiting.
SPIN_SLICE_S = 0.02

VENV_BIN = Path(sys.executable).parent


def ros_env(**extra: str) -> dict[str, str]:
    """Environment for a node subprocess: the test's own plus unbuffered logs.

    ``conftest.py`` put ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE into
    ``os.environ``; copying it passes them on.
    """
    env = os.environ.copy()
    env.update(PYTHONUNBUFFERED='1', RCUTILS_LOGGING_BUFFERED_STREAM='0',
               RCUTILS_COLORIZED_OUTPUT='0')
    env.update(extra)
    return env


def node_command(executable: str, *, ns: str | None = None,
                 params: dict[str, Any] | None = None,
                 params_files: Iterable[str | Path] = (),
                 extra_ros_args: Iterable[str] = (), bin_dir: Path = VENV_BIN) -> list[str]:
    """Command line for a node console script with ``--ros-args``.

    :param executable: console script name (``simulator``, ``protocol_player``, ...)
    :param ns: namespace (``-r __ns:=...``)
    :param params: ``-p name:=value`` overrides; floats keep their decimal point
    :param params_files: ``--params-file`` arguments, in order (later wins)
    :param extra_ros_args: anything else after ``--ros-args``
    :param bin_dir: where the executable lives (the venv, or a colcon install)
    """
    cmd = [str(bin_dir / executable), '--ros-args']
    for f in params_files:
        cmd += ['--params-file', str(f)]
    if ns:
        cmd += ['-r', f'__ns:={ns}']
    for name, value in (params or {}).items():
        cmd += ['-p', f'{name}:={_param_text(value)}']
    cmd += list(extra_ros_args)
    return cmd


def _param_text(value: Any) -> str:
    """A ``-p`` value that ROS parses back to the same type."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        text = repr(value)
        # ROS reads `1e-05` as a string: a double needs its decimal point.
        return text if '.' in text else f'{value:.12f}'.rstrip('0')
    return str(value)


class NodeProcess:
    """One node process with its output in a log file.

    :param name: short name for messages and the log file
    :param cmd: command line
    :param log_path: file that receives stdout and stderr
    :param env: environment (default :func:`ros_env`)
    """

    def __init__(self, name: str, cmd: list[str], log_path: Path,
                 env: dict[str, str] | None = None) -> None:
        self.name = name
        self.cmd = cmd
        self.log_path = log_path
        self._log = open(log_path, 'wb')
        # Own session: a SIGKILL of its group cannot reach the test runner.
        self.popen = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT,
                                      env=env if env is not None else ros_env(),
                                      start_new_session=True)

    @property
    def returncode(self) -> int | None:
        """Exit status, or ``None`` while running."""
        return self.popen.poll()

    def output(self) -> str:
        """Everything the process has written so far."""
        return self.log_path.read_text(encoding='utf-8', errors='replace')

    def wait(self, timeout_s: float = DEFAULT_TIMEOUT_S) -> int:
        """Wait for the process to exit on its own; fail the test on timeout."""
        try:
            return self.popen.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            raise AssertionError(f'{self.name} still running after {timeout_s:g} s:\n'
                                 f'{self.output()[-LOG_TAIL_CHARS:]}') from None

    def stop(self, timeout_s: float = STOP_TIMEOUT_S) -> int:
        """SIGINT (a clean shutdown), then SIGKILL of its process group."""
        if self.popen.poll() is None:
            try:
                self.popen.send_signal(signal.SIGINT)
                self.popen.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                try:
                    os.killpg(self.popen.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                self.popen.wait()
        self._log.close()
        return self.popen.returncode

    def describe(self) -> str:
        """Name, status and log tail, for failure messages."""
        status = 'running' if self.returncode is None else f'exited {self.returncode}'
        return (f'--- {self.name} ({status}): {" ".join(self.cmd)}\n'
                f'{self.output()[-LOG_TAIL_CHARS:]}')


class ProcessGroup:
    """Starts node processes and stops them all when the ``with`` block ends.

    :param log_dir: directory for the log files (e.g. pytest's ``tmp_path``)
    """

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = Path(log_dir)
        self.processes: list[NodeProcess] = []

    def start(self, name: str, cmd: list[str], env: dict[str, str] | None = None) -> NodeProcess:
        """Start a process; it is stopped when the group closes."""
        proc = NodeProcess(name, cmd, self.log_dir / f'{name}.log', env)
        self.processes.append(proc)
        return proc

    def stop_all(self) -> None:
        """Stop every process, the most recently started first."""
        for proc in reversed(self.processes):
            proc.stop()

    def __enter__(self) -> 'ProcessGroup':
        return self

    def __exit__(self, *exc_info) -> None:
        self.stop_all()


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


class Probe:
    """An rclpy node in the test process, in its own context.

    Records topics, publishes, calls services and sets parameters of the
    nodes under test. Use it as a context manager so that it shuts down.

    :param name: node name
    """

    def __init__(self, name: str = 'test_probe') -> None:
        self.context = rclpy.Context()
        rclpy.init(args=[], context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._recordings: dict[str, Recording] = {}
        self._publishers: dict[str, Any] = {}

    def close(self) -> None:
        """Destroy the node and shut its context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> 'Probe':
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

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
        :raises AssertionError: on timeout or if one of ``procs`` exits
        """
        procs = list(procs)
        deadline = time.monotonic() + timeout_s
        while True:
            value = condition()
            if value:
                return value
            dead = [p for p in procs if p.returncode is not None]
            if dead or time.monotonic() > deadline:
                reason = (f'{", ".join(p.name for p in dead)} exited' if dead
                          else f'timed out after {timeout_s:g} s')
                logs = '\n'.join(p.describe() for p in procs)
                raise AssertionError(f'waiting for {what}: {reason}\n{logs}')
            self.executor.spin_once(timeout_sec=SPIN_SLICE_S)

    def spin_for(self, duration_s: float) -> None:
        """Keep receiving for ``duration_s`` (to collect messages, not to sync)."""
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=SPIN_SLICE_S)

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

    def publish_when_matched(self, topic: str, msg: Any, *,
                             timeout_s: float = DEFAULT_TIMEOUT_S,
                             procs: Iterable[NodeProcess] = ()) -> None:
        """Publish once a subscriber is matched, so the message is not lost."""
        pub = self.publisher(topic, type(msg))
        self.spin_until(lambda: pub.get_subscription_count() > 0,
                        f'a subscriber on {topic}', timeout_s, procs)
        pub.publish(msg)

    # -- services and parameters ------------------------------------------------

    def call(self, srv_type: type, name: str, request: Any, *,
             timeout_s: float = DEFAULT_TIMEOUT_S, procs: Iterable[NodeProcess] = ()) -> Any:
        """Call a service once it is available; return the response."""
        client = self.node.create_client(srv_type, name)
        try:
            self.spin_until(client.service_is_ready, f'service {name}', timeout_s, procs)
            future = client.call_async(request)
            self.spin_until(future.done, f'response of {name}', timeout_s, procs)
            return future.result()
        finally:
            self.node.destroy_client(client)

    def set_parameters(self, node_name: str, parameters: dict[str, Any], *,
                       timeout_s: float = DEFAULT_TIMEOUT_S,
                       procs: Iterable[NodeProcess] = ()) -> list[Any]:
        """Set parameters of a remote node through its parameter services.

        :param node_name: fully qualified node name, e.g. ``/left/simulator``
        :return: one ``SetParametersResult`` per parameter (``successful``, ``reason``)
        """
        client = AsyncParameterClient(self.node, node_name)
        self.spin_until(lambda: client.services_are_ready(), f'parameter services of {node_name}',
                        timeout_s, procs)
        future = client.set_parameters([Parameter(n, value=v) for n, v in parameters.items()])
        self.spin_until(future.done, f'set_parameters on {node_name}', timeout_s, procs)
        return list(future.result().results)

    def get_parameters(self, node_name: str, names: list[str], *,
                       timeout_s: float = DEFAULT_TIMEOUT_S,
                       procs: Iterable[NodeProcess] = ()) -> dict[str, Any]:
        """Read parameters of a remote node; return name to Python value."""
        client = AsyncParameterClient(self.node, node_name)
        self.spin_until(lambda: client.services_are_ready(), f'parameter services of {node_name}',
                        timeout_s, procs)
        future = client.get_parameters(names)
        self.spin_until(future.done, f'get_parameters on {node_name}', timeout_s, procs)
        return {n: parameter_value_to_python(v)
                for n, v in zip(names, future.result().values)}
