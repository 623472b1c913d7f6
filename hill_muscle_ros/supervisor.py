"""Child processes of a run: start, readiness, stop, logs. One supervisor for all.

``make demo``, ``make demo-closed-loop``, the tests (``test/ros_helpers.py``)
and the benchmarks run the package's nodes as separate processes through
this module:

- :class:`Process`: one child in a session (process group) of its own, its
  stdout and stderr in a log file (:meth:`Process.output`,
  :meth:`Process.tail`). On Linux the child gets SIGTERM if the thread that
  started it dies (``PR_SET_PDEATHSIG``), and SIGINT back at its default even
  if this process was started with it ignored (a script's ``&``), since the
  stop below relies on it.
- :meth:`Process.stop`: SIGINT (a clean stop: the nodes flush bags and
  publish their last messages), then SIGKILL of the whole process group
  after a grace period (:data:`STOP_TIMEOUT_S`).
- :class:`ProcessGroup`: starts children and stops them all, the most
  recent first, when its ``with`` block ends, whatever the reason.
- :func:`wait_until`: the one waiting loop. A condition with a deadline; a
  watched process that exits fails the wait at once with its log tail, a
  timeout quotes every watched log.
- :class:`GraphProbe`: readiness from the ROS graph, never from log text: a
  node answers its parameter service (it is up and spinning), a topic has a
  given node's publisher or subscription, a publisher of the probe has
  matched its subscribers.

rclpy is imported only when a :class:`GraphProbe` is made, so launching and
stopping processes needs no ROS environment.
"""
from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import IO, Any, Callable, Iterable, Sequence

#: [s] grace period between SIGINT and SIGKILL of the process group.
STOP_TIMEOUT_S = 10.0
#: Characters of a process log quoted in a failure message.
LOG_TAIL_CHARS = 3000
#: [s] poll period of :func:`wait_until` when it has nothing to spin.
POLL_S = 0.05
#: [s] one executor spin of a :class:`GraphProbe` while it waits.
SPIN_SLICE_S = 0.02
#: Where the package's console scripts are (``simulator``, ``recorder``, ...):
#: beside this interpreter, in the virtualenv or a colcon install.
VENV_BIN = Path(sys.executable).parent
#: The package of the node modules (``python -m hill_muscle_ros.nodes.simulator``).
NODE_PACKAGE = 'hill_muscle_ros.nodes'
#: Variables that make a child's log reach its file at once and stay plain text.
UNBUFFERED_LOG_ENV = {'PYTHONUNBUFFERED': '1', 'RCUTILS_LOGGING_BUFFERED_STREAM': '0',
                      'RCUTILS_COLORIZED_OUTPUT': '0'}
#: DDS discovery on this host only: a run never talks to another machine's nodes.
LOCALHOST_DISCOVERY = 'LOCALHOST'
#: prctl option that sends a signal to a child when its parent thread dies (Linux).
_PR_SET_PDEATHSIG = 1


class SupervisorError(RuntimeError):
    """A wait failed: a watched process exited, or the deadline passed.

    The message says what was awaited and quotes the processes' log tails.
    """


# --------------------------------------------------------------------------- commands

def ros_environment(domain_id: int | None = None, base: dict[str, str] | None = None,
                    discovery_range: str | None = LOCALHOST_DISCOVERY,
                    **extra: str) -> dict[str, str]:
    """The environment of a node process: unbuffered plain logs, discovery on this host.

    :param domain_id: ``ROS_DOMAIN_ID`` to set; ``None`` keeps the inherited one
    :param base: the environment to start from (default: this process's)
    :param discovery_range: ``ROS_AUTOMATIC_DISCOVERY_RANGE`` to set (and no
        static peers); ``None`` keeps the inherited discovery settings
    :param extra: more variables to set
    """
    env = dict(os.environ if base is None else base)
    env.update(UNBUFFERED_LOG_ENV)
    if discovery_range is not None:
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = discovery_range
        env.pop('ROS_STATIC_PEERS', None)
    if domain_id is not None:
        env['ROS_DOMAIN_ID'] = str(domain_id)
    env.update(extra)
    return env


def node_command(executable: str, *, ns: str | None = None,
                 params: dict[str, Any] | None = None,
                 params_files: Iterable[str | Path] = (),
                 extra_ros_args: Iterable[str] = (),
                 bin_dir: Path | None = VENV_BIN) -> list[str]:
    """Command line of a node of the package with ``--ros-args``.

    :param executable: console script name (``simulator``, ``protocol_player``,
        ``recorder``, ``force_controller``), also its module's name in
        :data:`NODE_PACKAGE`
    :param ns: namespace (``-r __ns:=...``)
    :param params: ``-p name:=value`` overrides; floats keep their decimal point
    :param params_files: ``--params-file`` arguments, in order (later wins)
    :param extra_ros_args: anything else after ``--ros-args``
    :param bin_dir: where the console script lives (the venv, or a colcon
        install); ``None``: run the module with this interpreter
        (``python -m``), which works wherever the package can be imported
    """
    program = ([sys.executable, '-m', f'{NODE_PACKAGE}.{executable}'] if bin_dir is None
               else [str(bin_dir / executable)])
    cmd = [*program, '--ros-args']
    for f in params_files:
        cmd += ['--params-file', str(f)]
    if ns:
        cmd += ['-r', f'__ns:={ns}']
    for name, value in (params or {}).items():
        cmd += ['-p', f'{name}:={param_text(value)}']
    cmd += list(extra_ros_args)
    return cmd


def param_text(value: Any) -> str:
    """A ``-p`` value that ROS parses back to the same type.

    Floats keep a decimal point (ROS reads ``1e-05`` as a string and ``2`` as
    an integer); lists are YAML flow sequences.
    """
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        text = repr(value)
        return text if '.' in text else f'{value:.12f}'.rstrip('0')
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(f'"{v}"' if isinstance(v, str) else param_text(v)
                               for v in value) + ']'
    return str(value)


# --------------------------------------------------------------------------- processes

def _child_setup(then: Callable[[], None] | None) -> Callable[[], None]:
    def setup() -> None:  # runs in the child between fork and exec
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        try:
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
        except (OSError, AttributeError):
            pass  # not Linux: the ProcessGroup's stop still ends the children
        if then is not None:
            then()
    return setup


#: Depth of the :func:`_deferring_stops` blocks the main thread is in.
_critical_depth = 0
#: A stop signal that arrived inside such a block, raised at its end.
_deferred_stop: str | None = None


@contextlib.contextmanager
def _deferring_stops():
    """A block in which :class:`StopSignals` raises nothing; a stop signal that
    arrives inside it is raised as :class:`KeyboardInterrupt` as the block ends.

    ``subprocess.Popen`` takes a lock of its own to reap a child and releases
    it in a ``finally``. An exception raised by a signal handler between the
    lock's acquisition and that ``try`` leaves the lock held for good: every
    later ``poll()`` says "running" and ``wait()`` blocks forever. That hung
    ``make demo`` after Ctrl-C in about one run of 15 here (the demo's stack:
    ``Process.kill`` in ``Popen.wait``, the player already a zombie). Every
    call of :class:`Process` into its ``Popen`` is such a block.
    """
    global _critical_depth, _deferred_stop
    _critical_depth += 1
    try:
        yield
    finally:
        _critical_depth -= 1
        if _critical_depth == 0 and _deferred_stop is not None:
            name, _deferred_stop = _deferred_stop, None
            raise KeyboardInterrupt(name)


class StopSignals:
    """How a demo (a plain Python program that starts nodes) is stopped.

    SIGINT, SIGTERM and SIGHUP raise :class:`KeyboardInterrupt` at once, so
    that every ``finally`` on the way out stops the children and closes the
    bag; SIGINT is taken even if it was inherited ignored (a program started
    in the background by a shell). The signal is also remembered in
    :attr:`received`: a ``KeyboardInterrupt`` raised while the main thread is
    inside rclpy's C extension comes out of it as another exception (pybind11
    turns it into ``RuntimeError: Unable to convert call argument ...``), and
    the demo must treat that as the interrupt it is, not as its own error.
    Inside a call of :class:`Process` into ``subprocess.Popen`` (and while a
    :class:`ProcessGroup` stops its processes) the interrupt waits for the
    call to end (:func:`_deferring_stops`).
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

    def __init__(self) -> None:
        #: the number of the first stop signal received, or None
        self.received: int | None = None
        for sig in self.SIGNALS:
            signal.signal(sig, self._on_signal)

    def _on_signal(self, signum, _frame) -> None:
        global _deferred_stop
        if self.received is None:
            self.received = signum
        if _critical_depth > 0:
            _deferred_stop = signal.Signals(signum).name   # raised as the block ends
            return
        raise KeyboardInterrupt(signal.Signals(signum).name)


class Process:
    """One child process in its own session, logging to a file.

    :param name: short name for messages
    :param cmd: command line
    :param log_path: file that receives stdout and stderr
    :param env: environment (default :func:`ros_environment`)
    :param preexec_fn: also run in the child before exec (e.g. a resource limit)
    """

    def __init__(self, name: str, cmd: Sequence[str], log_path: Path,
                 env: dict[str, str] | None = None,
                 preexec_fn: Callable[[], None] | None = None) -> None:
        self.name = name
        self.cmd = list(cmd)
        self.log_path = Path(log_path)
        self._log: IO[bytes] = open(self.log_path, 'wb')
        try:
            # Own session: a SIGKILL of its group cannot reach this process.
            # No stop signal inside Popen (see _deferring_stops); ProcessGroup.start
            # defers it further, until the process is in the group.
            with _deferring_stops():
                self.popen = self._spawn(env if env is not None else ros_environment(),
                                         preexec_fn)
        except BaseException:
            self._log.close()
            raise

    def _spawn(self, env: dict[str, str], preexec_fn: Callable[[], None] | None):
        """Start the child; return its ``subprocess.Popen`` (a subclass may start it
        otherwise and return an object with the same ``pid``, ``poll``, ``wait`` and
        ``send_signal``)."""
        return subprocess.Popen(self.cmd, stdout=self._log, stderr=subprocess.STDOUT, env=env,
                                start_new_session=True, preexec_fn=_child_setup(preexec_fn))

    @property
    def pid(self) -> int:
        return self.popen.pid

    @property
    def returncode(self) -> int | None:
        """Exit status, or ``None`` while running."""
        with _deferring_stops():
            return self.popen.poll()

    def output(self) -> str:
        """Everything the process has written so far."""
        return self.log_path.read_text(encoding='utf-8', errors='replace')

    def tail(self, chars: int = LOG_TAIL_CHARS) -> str:
        """The end of the log."""
        return self.output()[-chars:]

    def describe(self) -> str:
        """Name, status, command and log tail, for failure messages."""
        status = 'running' if self.returncode is None else f'exited {self.returncode}'
        return f'--- {self.name} ({status}): {" ".join(self.cmd)}\n{self.tail()}'

    def send_signal(self, sig: int) -> None:
        """Send ``sig`` to the process (not its group), if it still runs."""
        with _deferring_stops():
            if self.popen.poll() is None:
                self.popen.send_signal(sig)

    def wait(self, timeout_s: float) -> int:
        """Wait for the process to exit on its own; return its status.

        :raises SupervisorError: if it still runs after ``timeout_s``, with its log
        """
        try:
            with _deferring_stops():
                return self.popen.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            raise SupervisorError(f'{self.name} still running after {timeout_s:g} s\n'
                                  f'{self.describe()}') from None

    def stop(self, grace_s: float = STOP_TIMEOUT_S) -> int:
        """SIGINT (a clean stop), then SIGKILL of the process group after ``grace_s``.

        Also kills what the process left behind in its group. Safe to call twice.

        :return: the exit status
        """
        with _deferring_stops():
            if self.popen.poll() is None:
                try:
                    self.popen.send_signal(signal.SIGINT)
                    self.popen.wait(timeout=grace_s)
                except subprocess.TimeoutExpired:
                    self.kill()
            self._log.close()
            return self.popen.returncode

    def kill(self) -> None:
        """SIGKILL of the whole process group, and reap the process."""
        with _deferring_stops():
            try:
                os.killpg(self.popen.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.popen.wait()


def wait_until(condition: Callable[[], Any], what: str, timeout_s: float,
               watch: Iterable[Process] = (),
               step: Callable[[], None] | None = None) -> Any:
    """Wait until ``condition()`` is truthy; return its value.

    :param condition: checked before every step
    :param what: what is awaited, for the failure message
    :param timeout_s: [s] deadline
    :param watch: processes that must stay alive meanwhile; their logs are
        quoted if the wait fails
    :param step: one slice of work between checks (e.g. an executor's
        ``spin_once``); default: sleep :data:`POLL_S`
    :raises SupervisorError: at once if a watched process exits, or on timeout
    """
    watch = list(watch)
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        dead = [p for p in watch if p.returncode is not None]
        if dead or time.monotonic() > deadline:
            reason = (f'{", ".join(f"{p.name} exited ({p.returncode})" for p in dead)}'
                      if dead else f'timed out after {timeout_s:g} s')
            logs = '\n'.join(p.describe() for p in watch)
            raise SupervisorError(f'waiting for {what}: {reason}\n{logs}')
        if step is None:
            time.sleep(POLL_S)
        else:
            step()


class ProcessGroup:
    """Starts processes and stops them all when the ``with`` block ends.

    :param log_dir: directory of the log files (``<name>.log``)
    :param env: default environment of the processes (default :func:`ros_environment`)
    :param grace_s: [s] SIGINT-to-SIGKILL grace period of :meth:`stop_all`
    """

    #: The class of the processes :meth:`start` makes (a subclass may refine it).
    process_class: type[Process] = Process

    def __init__(self, log_dir: str | os.PathLike, env: dict[str, str] | None = None,
                 grace_s: float = STOP_TIMEOUT_S) -> None:
        self.log_dir = Path(log_dir)
        self.env = env
        self.grace_s = grace_s
        self.processes: list[Process] = []

    def start(self, name: str, cmd: Sequence[str], env: dict[str, str] | None = None,
              preexec_fn: Callable[[], None] | None = None) -> Process:
        """Start a process logging to ``<log_dir>/<name>.log``; it stops with the group.

        A stop signal that arrives while it starts is raised once it is in the
        group, so that the group's stop reaches it."""
        with _deferring_stops():
            proc = self.process_class(name, cmd, self.log_dir / f'{name}.log',
                                      env if env is not None else self.env, preexec_fn)
            self.processes.append(proc)
        return proc

    def wait_until(self, condition: Callable[[], Any], what: str, timeout_s: float,
                   watch: Iterable[Process] | None = None,
                   step: Callable[[], None] | None = None) -> Any:
        """:func:`wait_until`, watching every process of the group by default."""
        return wait_until(condition, what, timeout_s,
                          self.processes if watch is None else watch, step)

    def check_alive(self, watch: Iterable[Process] | None = None) -> None:
        """Raise if a process (default: any of the group) has exited.

        :raises SupervisorError: naming it, with its log tail
        """
        for proc in self.processes if watch is None else watch:
            if proc.returncode is not None:
                raise SupervisorError(f'{proc.name} exited ({proc.returncode})\n'
                                      f'{proc.describe()}')

    def stop_all(self) -> None:
        """Stop every process, the most recently started first.

        A stop signal that arrives meanwhile is raised once all are stopped.
        """
        with _deferring_stops():
            for proc in reversed(self.processes):
                proc.stop(self.grace_s)

    def __enter__(self) -> 'ProcessGroup':
        return self

    def __exit__(self, *exc_info: Any) -> None:
        self.stop_all()


# --------------------------------------------------------------------------- readiness

class GraphProbe:
    """An rclpy node in a context of its own that tells readiness from the ROS graph.

    Its participant is set up as the nodes' are
    (:func:`~hill_muscle_ros.dds_transport.use_udp_transport`, which sets this
    process's environment: build a node's environment before the probe to
    hand it the user's).

    :param name: node name
    :param namespace: node namespace (relative topic names resolve in it)
    :param domain_id: ``ROS_DOMAIN_ID`` of the graph (default: the environment's)
    :param executor: one of :data:`PROBE_EXECUTORS`
    """

    #: What spins the probe. ``events`` is rclpy's C++ EventsExecutor
    #: (``rclpy.experimental``), as the package's nodes use: recording one
    #: 1 kHz topic it took 0.50-0.52 CPU-s in 5 s, against 1.41-1.66 CPU-s
    #: with ``single``, rclpy's SingleThreadedExecutor (measured by hand, a
    #: probe beside the simulator node). ``single`` is for a subscription whose
    #: callback takes the ``MessageInfo`` too: the Jazzy EventsExecutor raises
    #: ``SystemError: null argument to internal routine`` on its first message.
    PROBE_EXECUTORS = ('events', 'single')

    def __init__(self, name: str = 'graph_probe', namespace: str | None = None,
                 domain_id: int | None = None, executor: str = 'events') -> None:
        if executor not in self.PROBE_EXECUTORS:
            raise ValueError(f'`executor` must be one of {", ".join(self.PROBE_EXECUTORS)}, '
                             f'got {executor!r}')
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.experimental import EventsExecutor

        from .dds_transport import use_udp_transport

        # The probe's participant set up as the nodes' are (UDP only, and
        # their heartbeat): with Fast DDS's 3 s heartbeat an acknowledgement
        # waits for the next one, and the knee demo's stop waited 2.95 s in
        # retire_publisher while its three nodes ran on.
        use_udp_transport()
        self.context = rclpy.Context()
        rclpy.init(args=[], context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node(name, namespace=namespace, context=self.context)
        executor_class = EventsExecutor if executor == 'events' else SingleThreadedExecutor
        self.executor = executor_class(context=self.context)
        self.executor.add_node(self.node)

    def close(self) -> None:
        """Destroy the node and shut its context down."""
        import rclpy
        # Before the node goes: the EventsExecutor holds callbacks on its entities.
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> 'GraphProbe':
        return self

    def __exit__(self, *exc_info: Any) -> None:
        self.close()

    def spin_once(self, timeout_s: float = SPIN_SLICE_S) -> None:
        """Handle at most one callback, waiting up to ``timeout_s`` for one."""
        self.executor.spin_once(timeout_sec=timeout_s)

    def spin_until(self, condition: Callable[[], Any], what: str, timeout_s: float,
                   watch: Iterable[Process] = ()) -> Any:
        """:func:`wait_until`, spinning the probe between checks."""
        return wait_until(condition, what, timeout_s, watch, self.spin_once)

    def retire_publisher(self, publisher: Any, timeout_s: float) -> None:
        """Destroy ``publisher`` once its matched subscriptions have acknowledged
        what it sent, and spin until the graph no longer counts it.

        A recorder stopped while a publisher it records is still in the graph
        waits up to its drain timeout (3.5 s) for more from that publisher
        (``nodes.recorder.Recorder.drain``); one that is gone it need not wait
        for. With the EventsExecutor, destroying a publisher takes effect only
        at the executor's next spins: it still counted, and the recorder
        waited, when the stop came right after ``destroy_publisher`` (checked
        by hand: gone after two spins).

        :param publisher: a publisher of :attr:`node`
        :param timeout_s: [s] bound on each of the two waits
        :raises SupervisorError: if a wait times out
        """
        from rclpy.duration import Duration
        topic = publisher.topic_name
        if not publisher.wait_for_all_acked(Duration(seconds=timeout_s)):
            raise SupervisorError(f'{topic}: the subscriptions did not acknowledge what '
                                  f'was published within {timeout_s:g} s')
        before = self.node.count_publishers(topic)
        self.node.destroy_publisher(publisher)
        self.spin_until(lambda: self.node.count_publishers(topic) < before,
                        f'{topic}: the destroyed publisher gone from the graph', timeout_s)

    # -- graph conditions ---------------------------------------------------------

    def _endpoint_nodes(self, infos) -> list[str]:
        return [(i.node_namespace.rstrip('/') + '/' + i.node_name) for i in infos]

    def publishers(self, topic: str) -> list[str]:
        """Fully qualified names of the nodes publishing ``topic``."""
        name = self.node.resolve_topic_name(topic)
        return self._endpoint_nodes(self.node.get_publishers_info_by_topic(name))

    def subscribers(self, topic: str) -> list[str]:
        """Fully qualified names of the nodes subscribed to ``topic``."""
        name = self.node.resolve_topic_name(topic)
        return self._endpoint_nodes(self.node.get_subscriptions_info_by_topic(name))

    def wait_for_endpoints(self, topic: str, *, publisher: str | None = None,
                           subscriber: str | None = None, timeout_s: float,
                           watch: Iterable[Process] = ()) -> None:
        """Wait until the graph shows ``publisher`` publishing and/or ``subscriber``
        subscribed to ``topic`` (fully qualified node names)."""
        def present() -> bool:
            return ((publisher is None or publisher in self.publishers(topic))
                    and (subscriber is None or subscriber in self.subscribers(topic)))
        who = ' and '.join(f'{role} {n}' for role, n in (('publisher', publisher),
                                                         ('subscriber', subscriber)) if n)
        self.spin_until(present, f'{who} on {topic} in the graph', timeout_s, watch)

    def wait_until_serving(self, node_name: str, timeout_s: float,
                           watch: Iterable[Process] = ()) -> None:
        """Wait until the node answers a call to its ``list_parameters`` service.

        Every rclpy node offers that service from its creation, but answers only
        once its constructor has returned and its executor spins: the node has
        created its publishers and subscriptions and is running.

        :param node_name: fully qualified node name, e.g. ``/recorder``
        """
        from rcl_interfaces.srv import ListParameters

        deadline = time.monotonic() + timeout_s
        client = self.node.create_client(ListParameters,
                                         node_name.rstrip('/') + '/list_parameters')
        try:
            self.spin_until(client.service_is_ready, f'the service of {node_name}',
                            timeout_s, watch)
            future = client.call_async(ListParameters.Request())
            self.spin_until(future.done, f'{node_name} to answer its service',
                            max(0.0, deadline - time.monotonic()), watch)
        finally:
            self.node.destroy_client(client)
