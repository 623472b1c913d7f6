"""Helpers shared by the package's nodes (ROS side only, no model logic).

- :func:`load_engine`: the compiled model or the Python one, loaded and logged
  at start-up (the limb node, the simulator node).
- :class:`StartupError` and :func:`run_node`: the Jazzy talker ``main()``
  pattern with clean exit codes (a configuration error is one logged line and
  exit status 1, never a traceback), spun by :func:`make_executor`'s executor.
- :func:`field_descriptor`, :func:`number_descriptor`, :func:`declare_checked`
  and :func:`declare_muscle_parameters`: ROS parameters declared from the
  model's :class:`~hill_muscle_ros.model.MuscleParams` field metadata, so the
  names, units and ranges have a single source.
- :class:`BadInputWarner`: a throttled warning per topic for rejected input.
- :class:`StepSchedule`: how many fixed steps are due at a given clock reading.
- :class:`NodeDiagnostics`, :func:`overridable_publisher` and
  :func:`overridable_subscription` (last section): ``/diagnostics`` at 1 Hz and
  the standard ``qos_overrides.*`` parameters on every publisher and subscription.
- :data:`RELIABLE_QOS` and :data:`OUTPUT_QOS`: the QoS of every subscription
  and every publisher of the package.
"""
from __future__ import annotations

import atexit
import copy
import dataclasses
import faulthandler
import gc
import math
import os
import signal
import sys
import threading
import time
from array import array
from typing import Any, Callable, NoReturn

import rclpy
from rclpy.exceptions import (InvalidParameterTypeException,
                              InvalidParameterValueException)
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import InvalidQosOverridesError, QoSOverridingOptions
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange,
                                ParameterDescriptor)
from rcl_interfaces.srv import ListParameters
from rclpy.parameter import Parameter

from ..control.joint import JOINT_CONTROLLER_KEYS
from ..dds_transport import use_udp_transport
from ..model import MuscleParams
from ..model import engine as engines
from ..model.params import CURVE_FIELDS, range_constraint
from ..params_file import SIMULATOR_NODE_KEYS
# The QoS profiles live below the nodes and the recording code; re-exported here.
from ..qos import OUTPUT_HISTORY_DEPTH, OUTPUT_QOS, QUEUE_DEPTH, RELIABLE_QOS  # noqa: F401
from ..timebase import NS_PER_S

#: Exit status of a node that could not start (bad parameter, bad file).
EXIT_FAILURE = 1
#: Exit status of a node that ran to its end or was interrupted.
EXIT_SUCCESS = 0

#: [s] at most one bad-input warning per topic in this period.
BAD_INPUT_THROTTLE_S = 1.0


class StartupError(Exception):
    """A node cannot start: the message says which parameter or file and why."""


# -- engine ---------------------------------------------------------------------

#: [s] about how long the compiled kernels take to compile when numba's cache
#: has no copy (BENCHMARKS.md, "The limb and the FES muscle, compiled"), for the log.
COLD_COMPILE_S = 30.0


def load_engine(what: str, make_compiled: Callable[[], Any], make_python: Callable[[], Any],
                loaded: Callable[[], bool], logger: Any) -> Any:
    """The model a node steps: compiled when :func:`~hill_muscle_ros.model.engine.choice`
    says so, else Python; logs which, and how long loading took.

    Call it in the node's ``__init__`` before any publisher, subscription,
    service or timer: a compile (about :data:`COLD_COMPILE_S`) then happens
    before the node can be seen as started, never in a callback. A compiled
    model that cannot be loaded (numba missing, a compile error, a bad
    ``HILL_MUSCLE_ENGINE``) is not a reason to stop: the Python model computes
    the same steps (to 1e-9), so the node warns and runs it.

    :param what: the model's name in the log lines, e.g. ``limb``
    :param make_compiled: builds the compiled model (loading its kernels)
    :param make_python: builds the Python model
    :param loaded: whether the compiled kernels are loaded in this process already
    :param logger: the node's logger
    """
    try:
        wanted = engines.choice()
    except (ValueError, ImportError) as err:
        logger.warning(f'{err}: the {what} runs on the Python engine')
        return make_python()
    if wanted != engines.COMPILED:
        why = (f'{engines.ENV_VAR}={engines.PYTHON}' if engines.requested() == engines.PYTHON
               else 'numba cannot be imported')
        logger.info(f'{what} engine: python ({why})')
        return make_python()
    if not loaded():
        logger.info(f'loading the compiled {what}; if numba has no cached copy (the first '
                    'start after an install or an edit of the model) it compiles it once, '
                    f'about {COLD_COMPILE_S:g} s, and caches it for later starts')
    started_s = time.monotonic()
    compiled_before_s = engines.compile_seconds()
    try:
        model = make_compiled()
    except Exception as err:   # noqa: BLE001 -- any failure of numba: the Python model works
        logger.warning(f'the compiled {what} failed to load ({type(err).__name__}: {err}): '
                       f'the {what} runs on the Python engine')
        return make_python()
    took_s = time.monotonic() - started_s
    compiled_s = engines.compile_seconds() - compiled_before_s
    how = (f'compiled in {compiled_s:.1f} s (cached for later starts)' if compiled_s > 0.0
           else 'from numba\'s cache')
    logger.info(f'{what} engine: compiled, loaded in {took_s:.2f} s, {how}')
    return model


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


# -- parameters -----------------------------------------------------------------


def number_descriptor(description: str, unit: str, low: float | int, high: float | int, *,
                      integer: bool = False, read_only: bool = False,
                      constraints: str = '') -> ParameterDescriptor:
    """A descriptor with the unit in the description and an inclusive range.

    :param description: what the parameter is
    :param unit: its unit, e.g. ``N/m`` (``-`` for a pure number)
    :param low: lowest accepted value
    :param high: highest accepted value
    :param integer: integer parameter (``IntegerRange``) instead of a double
    :param read_only: the parameter cannot change while the node runs
    :param constraints: extra constraints in words (``additional_constraints``)
    """
    desc = ParameterDescriptor(description=f'[{unit}] {description}', read_only=read_only,
                               additional_constraints=constraints)
    if integer:
        desc.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
    else:
        desc.floating_point_range = [FloatingPointRange(from_value=float(low),
                                                        to_value=float(high), step=0.0)]
    return desc


def field_descriptor(field: dataclasses.Field, *, read_only: bool = False,
                     note: str = '') -> ParameterDescriptor:
    """The descriptor of one :class:`MuscleParams` field, from its metadata.

    :param field: a field of :class:`MuscleParams`
    :param read_only: the parameter cannot change while the node runs
    :param note: appended to the description (e.g. what a live change does)
    """
    spec = field.metadata
    description = spec['description'] + (f' ({note})' if note else '')
    if spec['choices'] is not None:
        return ParameterDescriptor(
            description=description, read_only=read_only,
            additional_constraints=f'one of: {", ".join(spec["choices"])}')
    if field.type == 'int':
        return number_descriptor(description, spec['unit'], spec['low'], spec['high'],
                                 integer=True, read_only=read_only)
    # No floating_point_range: a ROS range is closed, so none can say "> 0"
    # (from_value 0.0 would claim 0 is accepted), and rclpy checks a range
    # before the node's callback, answering with its range text instead of
    # the model's reason. The model checks these bounds; the words say them.
    each = 'each entry ' if field.type.startswith('tuple') else ''
    return ParameterDescriptor(
        description=f'[{spec["unit"]}] {description}', read_only=read_only,
        additional_constraints=f'{each}{range_constraint(spec)} (finite)')


#: Integer types ROS gives a value written without a decimal point (``45``,
#: ``[1, 2]``), and the double types they are read as for a double parameter.
_INTEGER_AS_DOUBLE = {Parameter.Type.INTEGER: Parameter.Type.DOUBLE,
                      Parameter.Type.INTEGER_ARRAY: Parameter.Type.DOUBLE_ARRAY}


def _as_double(param: Parameter, double_type: Parameter.Type) -> Parameter:
    """``param`` (an integer or integer array) as the double type ``double_type``."""
    value = param.value
    value = float(value) if double_type == Parameter.Type.DOUBLE else [float(v) for v in value]
    return Parameter(param.name, double_type, value)


def _is_double(value: Any) -> bool:
    """Whether ``value`` declares a double or double-array parameter."""
    if isinstance(value, (list, tuple)):
        return bool(value) and all(isinstance(v, float) for v in value)
    return isinstance(value, float)


def accept_integers_for_doubles(node: Node) -> None:
    """Let a live change (``ros2 param set``) give an integer to a double
    parameter, as the parameters file and ``-p`` may (:func:`declare_checked`):
    ``45`` is read as ``45.0``, ``[1, 2]`` as ``[1.0, 2.0]``. Once per node.
    """
    if getattr(node, '_hill_muscle_integers_as_doubles', False):
        return

    def to_doubles(params: list[Parameter]) -> list[Parameter]:
        out = []
        for p in params:
            double_type = _INTEGER_AS_DOUBLE.get(p.type_)
            if double_type is not None and node.has_parameter(p.name) \
                    and node.describe_parameter(p.name).type == double_type.value:
                p = _as_double(p, double_type)
            out.append(p)
        return out

    node.add_pre_set_parameters_callback(to_doubles)
    node._hill_muscle_integers_as_doubles = True   # noqa: SLF001 - our own mark


def declare_checked(node: Node, name: str, default: Any,
                    descriptor: ParameterDescriptor) -> Any:
    """Declare a parameter; turn a bad override into a :class:`StartupError`.

    rclpy raises on a wrong type or an out-of-range value from
    ``--params-file`` or ``-p``; the error names the parameter and the value.
    An integer for a double parameter (``f_iso_max_n: 45``) is read as a
    double (``45.0``), as the offline CLI reads the same file, at start-up and
    in a live change (:func:`accept_integers_for_doubles`).

    :return: the parameter's value (override or default)
    """
    accept_integers_for_doubles(node)
    given = parameter_overrides(node).get(name)  # only to quote it
    value = given.value if given is not None else default
    try:
        double_type = _INTEGER_AS_DOUBLE.get(given.type_) if given is not None else None
        if double_type is not None and _is_double(default):
            return node.declare_parameter(name, _as_double(given, double_type).value,
                                          descriptor, ignore_override=True).value
        return node.declare_parameter(name, default, descriptor).value
    except InvalidParameterTypeException:
        raise StartupError(
            f'parameter `{name}`: got {value!r} ({type(value).__name__}), expected a '
            f'{type(default).__name__} like {default!r}') from None
    except InvalidParameterValueException as err:
        # rclpy 7.1.6 keeps the descriptor's reason only inside the message,
        # 'Invalid parameter value (v) for parameter. Reason: <reason>: <name>',
        # with no attribute for it; without that marker the whole message is quoted.
        reason = str(err).split('Reason: ', 1)[-1]
        raise StartupError(f'parameter `{name}` = {value!r} rejected: {reason}') from None


#: What a live change of a muscle parameter does (doc/nodes.md, "Simulator parameters").
#: The recruitment curve (``pw_max_s`` and the curve's fields) only maps pulse
#: widths to the command in the node, so it can change with the state kept.
LIVE_KEEPS_STATE = CURVE_FIELDS
#: The model core builds its step from the other parameters once, when the
#: muscle is made, so a live change rebuilds the muscle at rest.
LIVE_RESETS = tuple(n for n in MuscleParams.field_names() if n not in LIVE_KEEPS_STATE)


def declare_muscle_parameters(node: Node) -> MuscleParams:
    """Declare one ROS parameter per :class:`MuscleParams` field and build it.

    Defaults are the paper's values; overrides come from ``--params-file`` or
    ``-p``. All are live: see :data:`LIVE_KEEPS_STATE` and :data:`LIVE_RESETS`.

    :raises StartupError: naming the parameter and value if any is invalid
    """
    defaults = MuscleParams()
    values = {}
    for f in dataclasses.fields(MuscleParams):
        note = ('live, state kept' if f.name in LIVE_KEEPS_STATE
                else 'live, a change resets the muscle to rest')
        values[f.name] = declare_checked(node, f.name, getattr(defaults, f.name),
                                         field_descriptor(f, note=note))
    try:
        return MuscleParams(**values)
    except ValueError as err:
        raise StartupError(f'parameter {err}') from None


#: Parameters of this package's nodes other than the muscle's and the
#: controller's fields. A shared ``/**`` section of a params file may carry any
#: of them, so a node passes over the other nodes' names.
OTHER_NODE_PARAMETERS = frozenset((
    *SIMULATOR_NODE_KEYS,                                   # simulator
    'protocol', 'output', 'wait_for_subscribers_s',         # protocol_player
    'lookahead_s', 'min_subscribers',
    'topics',                                               # recorder (and `output`)
    *JOINT_CONTROLLER_KEYS,                                 # joint_controller
))


def declare_spec_fields(node: Node, cls: type, read_only: tuple[str, ...] = ()) -> dict:
    """Declare every field of a controller's parameter dataclass, with a
    descriptor from its metadata (unit, range or choices), and return the values.

    :param cls: a frozen dataclass whose fields carry ``_spec`` metadata
    :param read_only: the fields that cannot change while the node runs
    :raises StartupError: on a bad override (:func:`declare_checked`)
    """
    defaults = cls()
    values = {}
    for f in dataclasses.fields(cls):
        spec = f.metadata
        if spec['choices'] is not None:
            descriptor = ParameterDescriptor(
                description=spec['description'],
                additional_constraints=f'one of: {", ".join(spec["choices"])}')
        else:
            descriptor = number_descriptor(spec['description'], spec['unit'], spec['low'],
                                           spec['high'], read_only=f.name in read_only)
        values[f.name] = declare_checked(node, f.name, getattr(defaults, f.name), descriptor)
    return values


def plant_values(overrides: dict[str, Parameter], own: tuple[str, ...] = ()
                 ) -> dict[str, object]:
    """The plant's entries among a node's parameter overrides, by dotted name.

    The node's own parameters (``own``), the other nodes' of the package (one
    ``/**`` section may configure them all) and QoS overrides are left out;
    everything else belongs to the plant, which rejects what it does not know.

    :param overrides: the node's overrides by name (:func:`parameter_overrides`)
    :param own: the node's own parameter names
    :return: name to Python value; ROS arrays as lists
    """
    values = {}
    for name, param in overrides.items():
        if (name in own or name in OTHER_NODE_PARAMETERS
                or name.startswith(QOS_OVERRIDES_PREFIX)):
            continue
        value = param.value
        values[name] = list(value) if isinstance(value, (array, tuple)) else value
    return values


def declare_plant(node: Node, values: dict[str, object]) -> None:
    """Declare a plant's parameters read-only, so ``ros2 param`` shows them.

    :raises StartupError: naming a parameter ROS cannot hold
    """
    for name in sorted(values):
        try:
            node.declare_parameter(name, values[name], ParameterDescriptor(
                description='plant parameter (read-only)', read_only=True))
        except (InvalidParameterTypeException, InvalidParameterValueException,
                TypeError) as err:
            raise StartupError(f'plant parameter `{name}` = {values[name]!r}: '
                               f'{err}') from None


def parameter_overrides(node: Node) -> dict[str, Parameter]:
    """The overrides the node was started with (``--params-file``, ``-p``), by name.

    rclpy 7.1.6 has no public accessor for them: ``Node`` keeps them in
    ``_parameter_overrides`` (and the rcl getter is on its private
    ``_rclpy`` node handle). This is the one place that reads that attribute;
    ``test_node_common.py`` pins what it returns, so an rclpy that changes
    it fails there. A copy is returned.
    """
    return dict(node._parameter_overrides)  # noqa: SLF001 - no public API in rclpy 7.1.6


def declared_parameter_names(node: Node) -> list[str]:
    """Every parameter the node has declared, sorted (public ``Node.list_parameters``)."""
    return sorted(node.list_parameters([], ListParameters.Request.DEPTH_RECURSIVE).names)


def reject_unknown_overrides(node: Node) -> None:
    """Stop start-up on an override that no node of this package has.

    Such a key is a typo (``k_se`` for ``k_se_n_per_m``): running on would
    silently use the default in its place. Keys of this package's other nodes
    are passed over, since one ``/**`` section may configure them all.

    :raises StartupError: naming the first unknown parameter and its value
    """
    from ..control import ControllerParams  # the controller's field names

    declared = declared_parameter_names(node)
    known = (set(declared)
             | set(MuscleParams.field_names())
             | {f.name for f in dataclasses.fields(ControllerParams)}
             | OTHER_NODE_PARAMETERS
             | {DIAGNOSTICS_PERIOD_PARAMETER})   # NodeDiagnostics declares it
    overrides = parameter_overrides(node)
    unknown = sorted(set(overrides) - known)
    # QoS overrides are declared with the publishers, after this check: their
    # names and values are checked against the package's topics instead.
    check_qos_overrides(node, unknown)
    unknown = [n for n in unknown if not n.startswith(QOS_OVERRIDES_PREFIX)]
    if unknown:
        name = unknown[0]
        raise StartupError(
            f'unknown parameter `{name}` (got {overrides[name].value!r}); '
            f'this node has: {", ".join(declared)}')


#: [s] how long a node that stops waits for its subscribers to acknowledge
#: its last messages (reliable QoS). Without a wait, a zero stimulation
#: published on exit could die with the process (rmw_fastrtps publishes
#: asynchronously; 2 of 4 controller stops lost it on a loaded machine).
#: Fast DDS readers acknowledge on the writer's heartbeat, every 3 s by
#: default, so the wait often ends by this timeout, not by the
#: acknowledgement: its job is to keep the writer alive until the message
#: is out.
FINAL_ACK_TIMEOUT_S = 1.0


def publish_last(publishers_and_messages, timeout_s: float = FINAL_ACK_TIMEOUT_S) -> bool:
    """Publish each message and wait until every subscriber acknowledged it.

    :param publishers_and_messages: (publisher, message) pairs
    :param timeout_s: [s] longest wait, for all of them together
    :return: whether every publisher's messages were acknowledged in time
    """
    pairs = list(publishers_and_messages)
    for pub, msg in pairs:
        pub.publish(msg)
    deadline = time.monotonic() + timeout_s   # one wait for all, not one each
    acked = True
    for pub, _ in pairs:
        left = max(deadline - time.monotonic(), 0.0)
        acked = pub.wait_for_all_acked(Duration(seconds=left)) and acked
    return acked


# -- bad input ------------------------------------------------------------------


class BadInputWarner:
    """A warning per topic, at most once per ``period_s``, counting the rest.

    rclpy's ``throttle_duration_sec`` throttles per call site, so one helper
    line would let one noisy topic hide another; this keys on the topic.

    :param logger: the node's logger
    :param period_s: [s] shortest interval between two warnings of one topic
    """

    def __init__(self, logger, period_s: float = BAD_INPUT_THROTTLE_S) -> None:
        self._logger = logger
        self._period_s = period_s
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        #: Rejected inputs per topic, logged or not (reported on /diagnostics).
        self.counts: dict[str, int] = {}

    @property
    def total(self) -> int:
        """Rejected inputs on every topic."""
        return sum(self.counts.values())

    def warn(self, topic: str, message: str) -> bool:
        """Count a rejected input on ``topic``; log ``message`` unless one was
        logged less than a period ago.

        :return: whether it was logged
        """
        self.counts[topic] = self.counts.get(topic, 0) + 1
        now = time.monotonic()
        last = self._last.get(topic)
        if last is not None and now - last < self._period_s:
            self._suppressed[topic] = self._suppressed.get(topic, 0) + 1
            return False
        skipped = self._suppressed.pop(topic, 0)
        suffix = f' ({skipped} more since the last warning)' if skipped else ''
        self._logger.warning(message + suffix)
        self._last[topic] = now
        return True


# -- fixed-step schedule ----------------------------------------------------------


class StepSchedule:
    """Whole steps due since a start instant, with no accumulated drift.

    The step count is always recomputed from the elapsed time,
    ``floor(elapsed * real_time_factor * rate_hz)``, never accumulated tick by
    tick, so simulated time cannot drift from the clock it follows.

    :param rate_hz: [Hz] step rate, 1 / dt
    :param real_time_factor: [-] simulated seconds per clock second
    :param start_ns: [ns] clock reading at simulated time 0
    """

    def __init__(self, rate_hz: float, real_time_factor: float, start_ns: int) -> None:
        self.steps_per_ns = rate_hz * real_time_factor / NS_PER_S
        self.start_ns = start_ns
        self.steps_done = 0
        self.late_ticks = 0
        self.ticks = 0
        #: [s] longest clock interval between two consecutive :meth:`due`
        #: calls: the longest time the node's tick did not run (0 before the
        #: second tick). Start-up before the first tick is not counted.
        self.max_tick_gap_s = 0.0
        #: [ns] clock reading at the end of that longest gap (``None`` before
        #: the second tick): to tell, afterwards, what else happened then.
        self.max_tick_gap_end_ns: int | None = None
        self._last_due_ns: int | None = None

    def target(self, now_ns: int) -> int:
        """Steps that should have been run by ``now_ns``."""
        return math.floor((now_ns - self.start_ns) * self.steps_per_ns)

    def due(self, now_ns: int) -> int:
        """Steps to run now; counts the tick, a late tick if more than one, and the gap."""
        n = max(0, self.target(now_ns) - self.steps_done)
        if self._last_due_ns is not None:
            gap_s = (now_ns - self._last_due_ns) / NS_PER_S
            if self.max_tick_gap_end_ns is None or gap_s > self.max_tick_gap_s:
                self.max_tick_gap_s = gap_s
                self.max_tick_gap_end_ns = now_ns
        self._last_due_ns = now_ns
        self.ticks += 1
        if n > 1:
            self.late_ticks += 1
        return n


# == diagnostics and QoS overrides ===============================================
# /diagnostics (the ROS convention diagnostic_aggregator and rqt_runtime_monitor
# read) and the standard ``qos_overrides.<topic>.<publisher|subscription>.<policy>``
# parameters on every publisher and subscription. diagnostic_updater is not on
# PyPI; :class:`NodeDiagnostics` is the small part of it this package needs.

#: Absolute by ROS convention: one diagnostics topic per graph.
DIAGNOSTICS_TOPIC = '/diagnostics'
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

#: Every parameter of a QoS override starts with this (rclpy's naming).
QOS_OVERRIDES_PREFIX = 'qos_overrides.'
#: The entity kinds of ``qos_overrides.<topic>.<kind>.<policy>``.
QOS_OVERRIDE_KINDS = ('publisher', 'subscription')
#: The policies a user may override on the package's publishers and
#: subscriptions: rclpy's default set (history, depth, reliability). Durability
#: stays volatile: a late joiner must not be sent old commands.
QOS_OVERRIDE_POLICIES = tuple(p.name.lower() for p in
                              QoSOverridingOptions.with_default_policies().policy_kinds)
#: Accepted values of the enum policies (rclpy maps the names to its enums;
#: ``unknown`` is not a profile anyone can ask for).
QOS_POLICY_VALUES = {
    'history': tuple(m.lower() for m in HistoryPolicy.__members__ if m != 'UNKNOWN'),
    'reliability': tuple(m.lower() for m in ReliabilityPolicy.__members__ if m != 'UNKNOWN'),
}
#: Topics of the package's nodes, as they name them (relative names resolve in
#: a node's namespace and through its remappings): a QoS override of any of
#: them is valid in a shared ``/**`` section, as other nodes' parameters are.
PACKAGE_TOPICS = ('pulse_width', 'recruitment', 'length_command', 'length_command_stamped',
                  'force', 'ce_length', 'wrench', 'recruitment_state', 'fitness',
                  'force_target', '/clock', DIAGNOSTICS_TOPIC)


def _qos_override_parts(name: str) -> tuple[str, str, str] | None:
    """``(topic, kind, policy)`` of ``qos_overrides.<topic>.<kind>.<policy>``, else ``None``.

    ROS names have no dots, so the last two dots split the kind and the policy off.
    """
    parts = name[len(QOS_OVERRIDES_PREFIX):].rsplit('.', 2)
    return tuple(parts) if len(parts) == 3 else None


def check_qos_override(name: str, value: Any, topics: Any) -> None:
    """Validate one ``qos_overrides.*`` override: its name, then its value.

    :param name: the parameter name, ``qos_overrides.<topic>.<kind>.<policy>``
    :param value: its value from the params file or ``-p``
    :param topics: the resolved topic names an override may name
    :raises StartupError: naming the parameter, the value and what is accepted
    """
    form = (f'a QoS override is `qos_overrides.<topic>.<{"|".join(QOS_OVERRIDE_KINDS)}>'
            f'.<{"|".join(QOS_OVERRIDE_POLICIES)}>`')
    parts = _qos_override_parts(name)
    if parts is None:
        raise StartupError(f'unknown parameter `{name}` (got {value!r}): {form}')
    topic, kind, policy = parts
    if kind not in QOS_OVERRIDE_KINDS or policy not in QOS_OVERRIDE_POLICIES:
        raise StartupError(f'unknown parameter `{name}` (got {value!r}): {form}')
    if topic not in topics:
        raise StartupError(f'unknown parameter `{name}` (got {value!r}): `{topic}` is none of '
                           f'the package\'s topics here ({", ".join(sorted(topics))}); a QoS '
                           'override names the topic resolved (namespace included)')
    if policy == 'depth':
        # bool is an int in Python; a depth of true is a typo, not 1.
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            raise StartupError(f'parameter `{name}` = {value!r} rejected: the depth must be an '
                               'integer of at least 1')
    elif not isinstance(value, str) or value not in QOS_POLICY_VALUES[policy]:
        raise StartupError(f'parameter `{name}` = {value!r} rejected: expected one of '
                           f'{", ".join(QOS_POLICY_VALUES[policy])}')


def check_qos_overrides(node: Node, names: Any, extra_topics: Any = ()) -> None:
    """Validate the node's ``qos_overrides.*`` overrides among ``names``.

    An override may name any of :data:`PACKAGE_TOPICS` as this node resolves
    it (one ``/**`` section may configure every node), any of ``extra_topics``
    (resolved names), or any topic of a QoS parameter the node has declared.

    :raises StartupError: on the first invalid one (see :func:`check_qos_override`)
    """
    topics = {node.resolve_topic_name(t) for t in PACKAGE_TOPICS} | set(extra_topics)
    for declared in declared_parameter_names(node):
        if declared.startswith(QOS_OVERRIDES_PREFIX):
            topics.add(_qos_override_parts(declared)[0])
    overrides = parameter_overrides(node)
    for name in sorted(names):
        if name.startswith(QOS_OVERRIDES_PREFIX):
            check_qos_override(name, overrides[name].value, topics)


def qos_overrides_of(node: Node) -> list[Parameter]:
    """The node's ``qos_overrides.*`` overrides, e.g. to hand to a helper node."""
    return [p for n, p in parameter_overrides(node).items() if n.startswith(QOS_OVERRIDES_PREFIX)]


def overridable_qos(qos: QoSProfile) -> tuple[QoSProfile, QoSOverridingOptions]:
    """A copy of ``qos`` and the options that let rclpy override it.

    rclpy writes the overrides into the profile it is given, so a shared
    profile (:data:`OUTPUT_QOS`) must never be passed itself: one override
    would change every later publisher of the process.
    """
    return copy.copy(qos), QoSOverridingOptions.with_default_policies()


def _created_with_overrides(create: Callable[..., Any], node: Node, topic: str,
                            *args: Any, **kwargs: Any) -> Any:
    """Run ``create`` and turn rclpy's errors on a bad override into a :class:`StartupError`.

    :func:`check_qos_overrides` has normally caught them at start-up already.
    """
    try:
        return create(*args, **kwargs)
    except (InvalidQosOverridesError, InvalidParameterTypeException,
            InvalidParameterValueException, RuntimeError) as err:
        raise StartupError(f'QoS override of `{node.resolve_topic_name(topic)}` rejected: '
                           f'{err}') from None


def overridable_publisher(node: Node, msg_type: Any, topic: str, qos: QoSProfile,
                          **kwargs: Any) -> Any:
    """``node.create_publisher`` with ``qos`` as the default and the standard overrides.

    Declares ``qos_overrides.<topic>.publisher.{history,depth,reliability}``
    (read-only) with ``qos``'s values; ``--params-file`` or ``-p`` may set them.

    :raises StartupError: on an invalid override value
    """
    profile, options = overridable_qos(qos)
    return _created_with_overrides(node.create_publisher, node, topic, msg_type, topic,
                                   profile, qos_overriding_options=options, **kwargs)


def overridable_subscription(node: Node, msg_type: Any, topic: str, callback: Callable,
                             qos: QoSProfile, **kwargs: Any) -> Any:
    """``node.create_subscription`` with ``qos`` as the default and the standard overrides.

    Declares ``qos_overrides.<topic>.subscription.{history,depth,reliability}``.

    :raises StartupError: on an invalid override value
    """
    profile, options = overridable_qos(qos)
    return _created_with_overrides(node.create_subscription, node, topic, msg_type, topic,
                                   callback, profile, qos_overriding_options=options, **kwargs)


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
