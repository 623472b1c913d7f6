"""A node's process: start, spin, stop and exit (ROS side only, no model logic).

- :class:`StartupError`, :data:`EXIT_FAILURE` and :data:`EXIT_SUCCESS`: a
  configuration error is one logged line and exit status 1, never a traceback.
- :func:`init_ros` and :func:`run_node`: the Jazzy talker ``main()`` pattern,
  spun by :func:`make_executor`'s executor until a stop signal
  (:class:`StopSignals`, :func:`spin`).
- :func:`exit_process` and :func:`process_entry`: the console scripts' fast exit.
- :class:`TeardownGuard`: a hung middleware teardown cannot keep the process.
"""
from __future__ import annotations

import atexit
import faulthandler
import gc
import os
import signal
import sys
import threading
from typing import Any, Callable, NoReturn

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from ..dds_transport import use_udp_transport

#: Exit status of a node that could not start (bad parameter, bad file).
EXIT_FAILURE = 1
#: Exit status of a node that ran to its end or was interrupted.
EXIT_SUCCESS = 0


class StartupError(Exception):
    """A node cannot start: the message says which parameter or file and why."""


# -- executor -------------------------------------------------------------------

#: Environment variable that chooses the executor of every node run by
#: :func:`run_node`: one of :data:`EXECUTORS`.
EXECUTOR_ENV = 'HILL_MUSCLE_EXECUTOR'
#: The executors :data:`EXECUTOR_ENV` can name. ``events`` is rclpy's C++
#: EventsExecutor (``rclpy.experimental``): it has no per-wait Python
#: bookkeeping, which at 1 kHz is most of a Python node's CPU time (the
#: simulator at 1 kHz: 50 to 70 % of a core with ``single``, 15 to 25 % with
#: ``events``, BENCHMARKS.md section 4). ``single`` is rclpy's default
#: SingleThreadedExecutor, the fallback should the experimental one misbehave.
#: Known limits of the Jazzy EventsExecutor, none of which the package's nodes
#: meet: no guard conditions; a subscription callback that takes a
#: ``MessageInfo`` fails with SystemError; its ``spin()`` (see :func:`spin`).
EXECUTORS = {'events': EventsExecutor, 'single': SingleThreadedExecutor}
DEFAULT_EXECUTOR = 'events'
#: [s] longest one spin waits for work before the stop conditions are checked
#: again; a stop signal or a done future ends the wait sooner.
SPIN_TIMEOUT_S = 0.1


def make_executor(context: rclpy.context.Context | None = None) -> Any:
    """The executor chosen by :data:`EXECUTOR_ENV` (default :data:`DEFAULT_EXECUTOR`).

    :param context: the rclpy context (default: the global one)
    :raises StartupError: if the variable names no executor of :data:`EXECUTORS`
    """
    name = os.environ.get(EXECUTOR_ENV, DEFAULT_EXECUTOR)
    try:
        return EXECUTORS[name](context=context)
    except KeyError:
        raise StartupError(f'environment variable {EXECUTOR_ENV}={name!r}: expected one of '
                           f'{", ".join(EXECUTORS)}') from None


class StopSignals:
    """Takes SIGINT and SIGTERM while active (a context manager) and records the first.

    Nothing is raised: a Python signal handler runs inside whichever callback
    the executor is dispatching, and the EventsExecutor reports an exception
    out of a callback as a FATAL error with its stack. :func:`spin` checks
    :attr:`received` after every event instead. Once a signal has come, both
    are ignored, so a repeat cannot cut a node's clean-up short. The previous
    handlers come back on exit.
    """

    #: Signals that stop a node cleanly (Ctrl-C, and what process managers send).
    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        #: The first stop signal received, or ``None``.
        self.received: signal.Signals | None = None
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> 'StopSignals':
        self._previous = {sig: signal.signal(sig, self._on_signal) for sig in self.SIGNALS}
        return self

    def __exit__(self, *_exc: Any) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def _on_signal(self, signum: int, _frame: Any) -> None:
        for sig in self.SIGNALS:
            signal.signal(sig, signal.SIG_IGN)
        self.received = signal.Signals(signum)


def spin(executor: Any, stop: StopSignals, until: Any = None) -> None:
    """Spin ``executor`` until a stop signal, ``until`` is done, or the context shuts down.

    One event at a time (``spin_once``) for both executors, checking the stop
    conditions after each: the Jazzy EventsExecutor's own ``spin()`` busy-waits
    (measured: a whole core, while the simulator's 1 kHz timer ran 12 times in
    3 s) and would never look at :attr:`StopSignals.received`.

    :param executor: an executor of :data:`EXECUTORS` with the node added
    :param stop: the active :class:`StopSignals`
    :param until: a :class:`rclpy.task.Future`, or ``None`` to spin until stopped
    """
    context = executor.context
    while (stop.received is None and context.ok()
           and (until is None or not until.done())):
        executor.spin_once(timeout_sec=SPIN_TIMEOUT_S)


# -- main() -------------------------------------------------------------------


#: rcl's flag for a parameters file, inside ``--ros-args``: ``--params-file FILE``.
PARAMS_FILE_FLAG = '--params-file'
_ROS_ARGS_START = '--ros-args'
_ROS_ARGS_END = '--'
#: rcl's message for a ``-p`` it cannot parse: the only error the quoting hint is for.
_OVERRIDE_RULE_ERROR = "Couldn't parse parameter override rule"


def params_file_arguments(args: list[str]) -> list[str]:
    """The files given with ``--params-file`` among the ROS arguments of ``args``.

    ROS arguments run from each ``--ros-args`` to the next ``--`` (or the end).
    """
    files = []
    inside = False
    for i, arg in enumerate(args):
        if arg == _ROS_ARGS_START:
            inside = True
        elif arg == _ROS_ARGS_END:
            inside = False
        elif inside and arg == PARAMS_FILE_FLAG and i + 1 < len(args):
            files.append(args[i + 1])
    return files


def check_params_files(args: list[str]) -> None:
    """Stop before rcl on a ``--params-file`` that is not there: rcl would say
    only "Error opening YAML file".

    :raises StartupError: naming the first missing file
    """
    for name in params_file_arguments(args):
        path = os.path.expanduser(name)
        if not os.path.exists(path):
            raise StartupError(f'cannot start: the parameters file {name} ({PARAMS_FILE_FLAG}) '
                               'does not exist')
        if not os.path.isfile(path):
            raise StartupError(f'cannot start: the parameters file {name} ({PARAMS_FILE_FLAG}) '
                               'is not a file')


def init_ros(args: list[str] | None, logger_name: str) -> tuple[bool, str | None]:
    """``rclpy.init`` for a node process, with the transport set first.

    A command line rcl cannot parse (``-p "topics:=[a, b:pkg/msg/T]"``
    unquoted, a ``--params-file`` that does not exist) is one logged line, not
    a traceback.

    :param args: command-line arguments (``None``: ``sys.argv``)
    :param logger_name: the logger of the error line
    :return: whether rclpy is initialised, and what the transport set (or ``None``)
    """
    logger = rclpy.logging.get_logger(logger_name)
    try:
        check_params_files(list(sys.argv if args is None else args))
    except StartupError as err:
        logger.error(str(err))
        return False, None
    try:
        # Before rclpy.init: the RMW reads it when it creates the participant.
        transport_note = use_udp_transport()
    except ValueError as err:
        logger.error(str(err))
        return False, None
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as err:
        # rclpy 7.1.x raises _rclpy.RCLError, a RuntimeError with no public alias.
        hint = (' (quote values that contain ":" or ",", e.g. '
                "-p 'topics:=[force, \"force_target:std_msgs/msg/Float64\"]')"
                if _OVERRIDE_RULE_ERROR in str(err) else '')
        logger.error(f'cannot start: {err}{hint}')
        return False, None
    return True, transport_note


def run_node(node_factory: Callable[[], Node], args: list[str] | None = None) -> int:
    """Create a node and spin it, following the Jazzy talker demo's ``main()``.

    If the node has a ``done`` attribute (an :class:`rclpy.task.Future`) the
    node is spun until it completes and its result is the exit status;
    otherwise it spins until Ctrl-C or an external shutdown (exit status 0).

    :param node_factory: builds the node; may raise :class:`StartupError`
    :param args: command-line arguments for ``rclpy.init`` (``--ros-args ...``);
        ``None`` means ``sys.argv``
    :return: the process exit status

    SIGINT and SIGTERM are taken here (:class:`StopSignals`) rather than by
    rclpy: rclpy's handlers shut the context down before ``finally`` runs, and
    a node's ``on_exit`` (the controller and the player publish zero
    stimulation there) could no longer publish. The first one ends the spin;
    the handlers are restored before the context shuts down.

    The executor is :func:`make_executor`'s (``HILL_MUSCLE_EXECUTOR``). On
    Fast DDS the node's participant uses UDP only
    (:func:`~hill_muscle_ros.dds_transport.use_udp_transport`,
    ``HILL_MUSCLE_DDS_TRANSPORT``): shared memory stalled the simulator for
    333 ms whenever a process such as ``ros2 param get`` joined the graph.
    """
    logger_name = getattr(node_factory, 'NODE_NAME', 'node')
    started, transport_note = init_ros(args, logger_name)
    if not started:
        return EXIT_FAILURE
    node = None
    executor = None
    status = EXIT_SUCCESS
    with StopSignals() as stop:
        try:
            node = node_factory()
            # Everything start-up made (rclpy, NumPy, the loaded kernels:
            # 131,000 objects in the limb node) is frozen out of the
            # collector's full passes, which would otherwise walk all of it
            # inside a tick: 52 ms a pass there, 15 ms before the kernels.
            # Without a collection first: that would hold the first tick.
            gc.freeze()
            if transport_note is not None:
                node.get_logger().info(transport_note)
            executor = make_executor()
            executor.add_node(node)
            done = getattr(node, 'done', None)
            spin(executor, stop, done)
            if done is not None and done.done():
                status = int(done.result())
        except StartupError as err:
            # One clear line instead of a traceback: the user made a config error.
            rclpy.logging.get_logger(getattr(node_factory, 'NODE_NAME', 'node')).error(str(err))
            status = EXIT_FAILURE
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            if node is not None:
                on_exit = getattr(node, 'on_exit', None)
                if on_exit is not None:
                    on_exit()
            # on_exit has done the node's last work: a hung middleware teardown
            # must not keep the process.
            guard = TeardownGuard(status)
            if executor is not None:
                # Before the node goes: the EventsExecutor holds callbacks on its entities.
                executor.shutdown()
            if node is not None:
                node.destroy_node()
    rclpy.try_shutdown()
    guard.stop()
    return status


def exit_process(status: int) -> NoReturn:
    """End a node's process with ``status`` once :func:`run_node` (or the
    recorder's ``main``) has returned: the node's work is saved and rclpy is
    shut down, its logging included.

    Python's exit handlers run and the standard streams are flushed; what is
    skipped are the C and C++ exit handlers, among them Fast DDS's
    ``DomainParticipantFactory`` destructor, which sleeps 100 ms
    (libfastrtps 2.14 of the Jazzy wheels, seen with gdb on a simulator's
    exit): two thirds of the 0.15 s from Ctrl-C to a simulator's exit. Only
    the console scripts end this way (:func:`process_entry`); ``main()`` still
    returns its status to a caller in the same process.

    ``atexit._run_exitfuncs`` is CPython's own call at exit; the ``atexit``
    module has no public one (Python 3.11).
    """
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass   # closed or gone (a closed pipe): nothing more to say there
    os._exit(status)


def process_entry(main: Callable[[], int]) -> Callable[[], NoReturn]:
    """A node's console script: ``main()``, then :func:`exit_process` with its status."""
    def entry() -> NoReturn:
        exit_process(main())
    entry.__doc__ = f'Console script: {main.__module__}.main(), then exit_process.'
    return entry


#: [s] the middleware's teardown (executor, node, context) may take this long
#: after a node's last work is done. A fresh-clone test run saw a recorder
#: that had closed its bag (every message written, its summary logged) still
#: running 30 s after SIGINT, somewhere in this teardown; a stopped node that
#: keeps running holds the user's terminal and a launch file's shutdown.
TEARDOWN_TIMEOUT_S = 5.0
#: [s] if the guard's own thread cannot run (the hung call holds the GIL),
#: faulthandler's C watchdog dumps every thread and exits with status 1 this
#: much later.
TEARDOWN_LAST_RESORT_S = 2.0


class TeardownGuard:
    """From construction until :meth:`stop`: if that takes more than
    :data:`TEARDOWN_TIMEOUT_S`, print every thread's stack and exit with
    ``status``, skipping the rest of the teardown (``os._exit``).

    Only for the end of a node's life, once its work is saved.

    :param status: the exit status to give if the teardown hangs
    """

    def __init__(self, status: int) -> None:
        self.status = status
        self._timer = threading.Timer(TEARDOWN_TIMEOUT_S, self._expire)
        self._timer.daemon = True
        faulthandler.dump_traceback_later(TEARDOWN_TIMEOUT_S + TEARDOWN_LAST_RESORT_S,
                                          exit=True)
        self._timer.start()

    def _expire(self) -> None:
        print(f'teardown of the ROS node did not finish in {TEARDOWN_TIMEOUT_S:g} s after its '
              f'work was saved; exiting with status {self.status} without it. Where each '
              f'thread was:', file=sys.stderr, flush=True)
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
        sys.stderr.flush()
        os._exit(self.status)

    def stop(self) -> None:
        """The teardown finished: nothing more to guard."""
        self._timer.cancel()
        faulthandler.cancel_dump_traceback_later()
