"""The muscle simulator node: the model core behind ROS 2 topics.

Subscribes ``pulse_width`` [s], ``recruitment`` [-], ``length_command`` [m]
(std_msgs/Float64, zero-order hold) and ``stimulation`` (a stimulator's
command per channel, ._stimulation), steps :class:`Muscle` at a fixed dt = 1 /
``rate_hz`` against the steady clock (``activation_model: ding2003``: its
channels' pulse trains, ``step_trains``), and publishes ``force`` [N],
``ce_length`` [m], ``wrench`` (geometry_msgs/WrenchStamped, force along +x),
``recruitment_state`` [-] (R), ``fitness`` [-] (the units' mean) and
``activation`` (each channel's a; these three at most at 1 kHz of the steady
clock) for every step, stamped with the step's simulated time; optionally ``/clock``.
A late tick catching up publishes every step it runs, in order, as a burst, so
a recording has no holes. When the steps run faster than 1 kHz of the steady
clock (``real_time_factor`` > 1, ``rate_hz`` > 1 kHz) the outputs of every
n-th step are published by default, on a fixed grid of simulated time, so that
they stay at 1 kHz; ``publish_every_n_steps:=1`` publishes every step there
too. A ``reset`` service (std_srvs/Trigger) returns the muscle to rest. See
doc/nodes.md for the tables.

Length commands sent ahead: ``length_command_stamped``
(geometry_msgs/PointStamped) carries dl_MT [m] in ``point.x`` (along +x of the
muscle frame, the axis of ``wrench``; ``header.frame_id`` empty or
``frame_id``) and, in ``header.stamp``, the time at which it is to be reached,
in the simulator's stamp clock (sim time from 0 with ``publish_clock``, else
the node clock at start-up plus sim time: the stamps of its own outputs). The
knots form a :class:`~hill_muscle_ros.model.CommandTrack`: each step's dl_MT
is the track's value at the step's end time, so a command that arrives before
its time acts exactly then, whatever the transport latency (at
``real_time_factor`` 10, a few ms of DDS latency would otherwise be tens of ms
of simulated time). A knot that arrives after its time is applied at the next
step, counted and reported. A plain ``length_command`` means "now": it drops
the track and holds its value, as before.

Engine: the :class:`~hill_muscle_ros.model.Muscle` runs the model's one
implementation compiled by numba when :func:`~hill_muscle_ros.model.engine.choice`
says so (numba installed, ``HILL_MUSCLE_ENGINE`` not ``python``), else the very
same functions as plain Python; both give the same steps to 1e-9. One step as
a tick makes it (``benchmarks/muscle_node_tick.py``) costs a few
microseconds compiled and 0.1-0.2 ms as plain Python. The compiled build is
loaded in ``__init__`` (:func:`._engine.load_muscle`, through
:func:`._engine.load_engine`, as the limb node's), before any publisher,
subscription, service or timer exists, never in a tick: about a second from
numba's disk cache, about 30 s when it compiles (a clean clone, or after an
edit of the model's code). The node logs which build runs and how long
loading took; a compiled build that fails to load falls back to Python with a
warning. A live parameter change rebuilds the muscle on the build already
loaded (:func:`._engine.rebuild_muscle`: nothing compiles in the callback); a node
that started on Python stays on Python.

Run: ``ros2 run hill_muscle_ros simulator --ros-args --params-file muscle.yaml``
or ``hill-muscle simulator --ros-args ...``.
"""
from __future__ import annotations

import math

import numpy as np
import rclpy
from geometry_msgs.msg import PointStamped, WrenchStamped
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMsg
from std_msgs.msg import Float64, Float64MultiArray, MultiArrayDimension
from std_srvs.srv import Trigger

from ..model import CommandTrack, MuscleParams
from ..model import engine as engines
from ..model.muscle import check_dl_mt, check_recruitment
from ..model.stimulator import ChannelCommand
from ..qos import OUTPUT_HISTORY_DEPTH, OUTPUT_QOS, RELIABLE_QOS
from ..timebase import NS_PER_S
from ..watchdog import DEFAULT_INPUT_TIMEOUT_S, INPUT_TIMEOUT_RANGE_S, watchdog_trips
from ._diagnostics import DiagnosticReport, NodeDiagnostics
from ._engine import load_muscle, rebuild_muscle  # noqa: F401 -- the node's API
from ._inputs import BadInputWarner, pulse_width_command
from ._overrides import reject_unknown_overrides
from ._parameters import (declare_checked, declare_muscle_parameters, keeps_state,
                          number_descriptor)
from ._process import StartupError, process_entry, run_node
from ._stepping import (DEFAULT_RATE_HZ, DEFAULT_REAL_TIME_FACTOR, ERROR_BEHIND_S,
                        MAX_CATCH_UP_S, MIN_TICK_PERIOD_S, RATE_HZ_RANGE, RATE_WARN_FRACTION,
                        REAL_TIME_FACTOR_RANGE, STEPS_PER_TICK_ROUNDING, StepSchedule)
from ._stimulation import (Stimulation, check_message, commands_text, level_command,
                           message_text, off_commands, pulse_width_channel, pulsed, stimulating)
from ._topics import overridable_publisher, overridable_subscription

NODE_NAME = 'simulator'

# Node parameters (their names are params_file.SIMULATOR_NODE_KEYS); rate_hz,
# real_time_factor and input_timeout_s, shared with the limb node, are in
# ._stepping and ..watchdog.
DEFAULT_FRAME_ID = 'muscle'
#: [Hz] of the steady clock: by default the outputs of every n-th step are
#: published, with the smallest n that keeps them at or below this rate, i.e.
#: every step at 1 kHz and real time (and in every catch-up burst). Publishing
#: costs far more than a step (measured here: about 45 us of CPU per step with
#: one subscriber, 2 us for the model), and every subscriber pays per message
#: too: at real_time_factor 10, every step (10 kHz of /clock, force, ce_length
#: and wrench) overloaded the simulator (5.3 of 10 ksteps/s) and the recorder
#: lost half of them. ``publish_every_n_steps:=1`` asks for every step anyway.
DEFAULT_MAX_OUTPUT_RATE_HZ = 1000.0
#: [-] every step up to one output per million steps.
PUBLISH_EVERY_N_STEPS_RANGE = (1, 1_000_000)
#: Slack for the rounding of rate_hz x real_time_factor / 1 kHz to whole steps
#: (3 x 1000.0 / 1000.0 may not be exactly 3).
_STEP_RATIO_ROUNDING = 1e-9

#: /diagnostics: WARN when more steps than this were caught up in the last
#: period (steps run beyond a tick's nominal count, after a late tick): their
#: outputs went out late, as a burst.
CATCH_UP_WARN_STEPS = 0

#: Queue of ``length_command_stamped``: a sender that starts ahead sends its
#: whole look-ahead window at once (the protocol player: up to 1000 knots), and
#: a keep-last queue that overflowed would drop the oldest, i.e. the most
#: urgent, knots.
STAMPED_QUEUE_DEPTH = OUTPUT_HISTORY_DEPTH
STAMPED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=STAMPED_QUEUE_DEPTH,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
#: [s] of simulated time a stamped knot may lie ahead: an hour is longer than
#: any look-ahead, so a stamp further out is a clock mix-up (wall-clock stamps
#: sent to a simulator on sim time), not a command.
MAX_STAMP_LEAD_S = 3600.0


def default_publish_every_n_steps(rate_hz: float, real_time_factor: float) -> int:
    """The default of ``publish_every_n_steps``: see :data:`DEFAULT_MAX_OUTPUT_RATE_HZ`.

    :param rate_hz: [Hz] step rate, 1 / dt
    :param real_time_factor: [-] simulated seconds per clock second
    :return: [-] the smallest n >= 1 with rate_hz x real_time_factor / n <= 1 kHz
    """
    steps_per_output = rate_hz * real_time_factor / DEFAULT_MAX_OUTPUT_RATE_HZ
    return max(1, math.ceil(steps_per_output - _STEP_RATIO_ROUNDING))


def check_frame_id(frame_id: str) -> str:
    """Validate the ``frame_id`` parameter: a tf2 frame name.

    :raises ValueError: if it is empty (REP 103/105 frames have names) or
        starts with ``/`` (tf2 rejects such frame ids)
    """
    if not frame_id or frame_id.startswith('/'):
        raise ValueError(f'`frame_id` must be a non-empty frame name without a leading '
                         f"'/' (tf2 convention), got {frame_id!r}")
    return frame_id


class Simulator(Node):
    """ROS 2 shell around :class:`~hill_muscle_ros.model.Muscle` (:func:`._engine.load_muscle`).

    :raises StartupError: on an invalid parameter at start-up
    """

    NODE_NAME = NODE_NAME

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        params = declare_muscle_parameters(self)
        rate_hz = declare_checked(self, 'rate_hz', DEFAULT_RATE_HZ, number_descriptor(
            'step rate, dt = 1 / rate_hz', 'Hz', *RATE_HZ_RANGE, read_only=True))
        rtf = declare_checked(self, 'real_time_factor', DEFAULT_REAL_TIME_FACTOR,
                              number_descriptor('simulated seconds per clock second', '-',
                                                *REAL_TIME_FACTOR_RANGE, read_only=True))
        self._input_timeout_s = declare_checked(
            self, 'input_timeout_s', DEFAULT_INPUT_TIMEOUT_S, number_descriptor(
                'stimulation watchdog: R (every channel\'s pulse width) drops to 0 after this '
                'long without a pulse_width, recruitment or stimulation message; 0 disables',
                's', *INPUT_TIMEOUT_RANGE_S))
        self._frame_id = declare_checked(self, 'frame_id', DEFAULT_FRAME_ID, ParameterDescriptor(
            description='frame_id of the wrench output',
            additional_constraints="non-empty, without a leading '/'"))
        self._publish_clock = declare_checked(self, 'publish_clock', False, ParameterDescriptor(
            description='publish /clock (sim time from 0) and stamp outputs with it',
            read_only=True))
        for name, value in (('rate_hz', rate_hz), ('real_time_factor', rtf)):
            if not math.isfinite(value):
                raise StartupError(f'parameter `{name}` must be finite, got {value!r}')
        self._publish_every = declare_checked(
            self, 'publish_every_n_steps', default_publish_every_n_steps(rate_hz, rtf),
            number_descriptor(
                'publish the outputs (and /clock) of every n-th step, stamped with its '
                'simulated time: 1 publishes every step; default: the smallest n that '
                f'keeps them at or below {DEFAULT_MAX_OUTPUT_RATE_HZ:g} Hz of the steady '
                'clock (rate_hz x real_time_factor / 1000, rounded up)', '-',
                *PUBLISH_EVERY_N_STEPS_RANGE, integer=True, read_only=True))
        # recruitment_state and fitness change at the pace of activation and
        # fatigue (tens of ms and more): they keep to the default grid, at most
        # 1 kHz of the steady clock, even when publish_every_n_steps asks for
        # every step; at real_time_factor 10 they would otherwise add 20,000
        # messages a second to the force, length and wrench streams.
        self._state_every = max(self._publish_every,
                                default_publish_every_n_steps(rate_hz, rtf))
        try:
            check_frame_id(self._frame_id)
        except ValueError as err:
            raise StartupError(f'parameter {err}') from None
        reject_unknown_overrides(self)

        self._params = params        # current MuscleParams (pw_max_s may differ from the muscle's)
        # Made before any publisher, subscription, service or timer: a compile
        # (about 30 s) happens before the node can be seen as started, never in a tick.
        self._muscle = load_muscle(params, self.get_logger())
        #: Whether the node steps the compiled FES muscle (a rebuild keeps to it).
        self._compiled = self._muscle.build == engines.COMPILED
        self._rate_hz = rate_hz
        self._dt_s = 1.0 / rate_hz
        # [-] held recruitment command u (zero-order hold): a `recruitment`
        # message as it is, a `pulse_width` through the recruitment curve. In
        # the paper's model u is R; with delay and activation R follows it.
        self._recruitment = 0.0
        # ding2003: each channel's last good command (the muscle's trains hold it).
        self._pulsed = pulsed(params)
        self._held: dict[int, ChannelCommand] = {}
        self._dl_mt_m = 0.0          # [m] held dl_MT
        self._last_stim_t_s = 0.0    # [s] sim time of the last stimulation message
        self._watchdog_tripped = False
        self._bad_input = BadInputWarner(self.get_logger())
        # dl_MT knots sent ahead; the track drives the steps while it is active
        # (made below, once the subscription gives the topic's full name).
        self._track_active = False
        self._late_warner = BadInputWarner(self.get_logger())
        self._late_knots = 0
        self._worst_late_s = 0.0

        self._pub_force = overridable_publisher(self, Float64, 'force', OUTPUT_QOS)
        self._pub_ce_length = overridable_publisher(self, Float64, 'ce_length', OUTPUT_QOS)
        self._pub_wrench = overridable_publisher(self, WrenchStamped, 'wrench', OUTPUT_QOS)
        self._pub_r_state = overridable_publisher(self, Float64, 'recruitment_state',
                                                  OUTPUT_QOS)
        self._pub_fitness = overridable_publisher(self, Float64, 'fitness', OUTPUT_QOS)
        self._pub_activation = overridable_publisher(self, Float64MultiArray, 'activation',
                                                     OUTPUT_QOS)
        self._r_state_msg = Float64()
        self._fitness_msg = Float64()
        self._activation_msg = Float64MultiArray()
        self._set_activation_layout()
        # One message per output, refilled every tick: building them anew
        # each tick cost more CPU than the model step (profiled for the benchmarks).
        self._force_msg = Float64()
        self._ce_length_msg = Float64()
        self._wrench_msg = WrenchStamped()
        self._wrench_msg.header.frame_id = self._frame_id
        self._clock_msg = ClockMsg()
        # /clock is absolute by ROS convention: one time source per graph.
        self._pub_clock = (overridable_publisher(self, ClockMsg, '/clock', OUTPUT_QOS)
                           if self._publish_clock else None)
        self._sub_pw = overridable_subscription(self, Float64, 'pulse_width',
                                                self._on_pulse_width, RELIABLE_QOS)
        self._sub_r = overridable_subscription(self, Float64, 'recruitment',
                                               self._on_recruitment, RELIABLE_QOS)
        self._sub_dl = overridable_subscription(self, Float64, 'length_command',
                                                self._on_length_command, RELIABLE_QOS)
        self._sub_dl_stamped = overridable_subscription(
            self, PointStamped, 'length_command_stamped', self._on_length_command_stamped,
            STAMPED_QOS)
        self._track = CommandTrack(name=self._sub_dl_stamped.topic_name)
        if Stimulation is not None:
            self._sub_stim = overridable_subscription(self, Stimulation, 'stimulation',
                                                      self._on_stimulation, RELIABLE_QOS)
        else:   # pragma: no cover - the test venv has the interface package
            self._sub_stim = None
            self.get_logger().warning(
                'hill_muscle_interfaces is not installed: no `stimulation` input (build it '
                'with `make interfaces` or colcon; pulse_width and recruitment work)')
        self.create_service(Trigger, 'reset', self._on_reset)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        # Stamps without publish_clock: the node clock at start + simulated time.
        self._stamp_origin_ns = 0 if self._publish_clock else self.get_clock().now().nanoseconds
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._schedule = StepSchedule(rate_hz, rtf, self._steady.now().nanoseconds)
        self._max_steps_per_tick = max(1, math.ceil(MAX_CATCH_UP_S * rtf * rate_hz))
        tick_s = max(MIN_TICK_PERIOD_S, self._dt_s / rtf)
        self._timer = self.create_timer(tick_s, self._on_tick, clock=self._steady)
        # Diagnostics: a tick nominally runs this many steps; more is catching up.
        self._real_time_factor = rtf
        self._steps_per_tick = max(1, math.ceil(tick_s * rate_hz * rtf
                                                - STEPS_PER_TICK_ROUNDING))
        self._late_ticks = 0        # ticks that ran more steps than _steps_per_tick
        self._catch_up_steps = 0    # the steps they ran beyond it
        self._stim_messages = 0     # pulse_width, recruitment and stimulation messages taken
        self._error_behind_steps = max(1, math.ceil(ERROR_BEHIND_S * rtf * rate_hz))
        self._diagnostics = NodeDiagnostics(self, 'muscle simulation', self._diagnose)
        self.get_logger().info(
            f'{params.units}/{params.length} muscle, {rate_hz:g} Hz, activation '
            f'{params.activation_model} ({params.n_channels} channel(s), stimulator '
            f'{params.stimulator}), real_time_factor '
            f'{rtf:g}, publish_clock {self._publish_clock}, watchdog '
            f'{self._input_timeout_s:g} s, outputs of every '
            f'{"step" if self._publish_every == 1 else f"{self._publish_every}th step"}')

    # -- time -------------------------------------------------------------------

    @property
    def sim_time_s(self) -> float:
        """[s] simulated time, from the step count (no accumulated rounding)."""
        return self._schedule.steps_done / self._rate_hz

    def _on_tick(self) -> None:
        due = self._schedule.due(self._steady.now().nanoseconds)
        if due == 0:
            return
        # Knots that arrived since the last tick act in the steps run now.
        self._take_stamped()
        n = min(due, self._max_steps_per_tick)
        if n > self._steps_per_tick:   # a late tick catching up (for /diagnostics)
            self._late_ticks += 1
            self._catch_up_steps += n - self._steps_per_tick
        if n < due:
            self.get_logger().warning(
                f'{due} steps due after a stall or overload: running {n} now and the rest '
                f'on the next ticks; if this repeats, lower rate_hz ({self._rate_hz:g}) or '
                'real_time_factor',
                throttle_duration_sec=1.0)
        if self._track_active:
            # Each step reaches the track's value at its own end time.
            steps = self._schedule.steps_done + np.arange(1, n + 1)
            if not self._run_steps(self._track.value_at(steps / self._rate_hz).tolist()):
                return
            self._dl_mt_m = self._track.consume(self.sim_time_s)
            if not len(self._track):
                self._track_active = False   # the last value holds, as a plain command
        else:
            # The length command is spread evenly over the steps this tick runs
            # (a first-order hold from where the last step ended): with
            # real_time_factor > 1, or when catching up, one tick runs many
            # steps, and holding the newest command for all of them would turn
            # a ramp into a staircase. With one step per tick this is the
            # plain step.
            dl_start, dl_end = self._muscle.dl_mt_m, self._dl_mt_m
            dls = [dl_start + (dl_end - dl_start) * (i / n) for i in range(1, n)]
            dls.append(dl_end)
            self._run_steps(dls)

    def _run_steps(self, dls: list[float]) -> bool:
        """Run one step per dl_MT value and publish each step's outputs.

        Each step is published, stamped with its own simulated time, so a
        tick that runs several (catching up, or by design at a real-time
        factor > 1) sends them as a burst and a recording has no holes. With
        ``publish_every_n_steps`` n > 1, only the steps whose count is a
        multiple of n are published.

        :param dls: [m] dl_MT at the end of each step, in order
        :return: ``False`` if a step's output was not finite (the muscle was
            reset and the remaining values dropped)
        """
        step = self._muscle.step
        # ding2003: the channels' trains drive the muscle, pulses exact in time.
        step_trains = self._muscle.step_trains if self._pulsed else None
        schedule = self._schedule
        publish = self._publish
        watchdog = self._watchdog
        isfinite = math.isfinite
        dt_s = self._dt_s
        every = self._publish_every
        state_every = self._state_every
        for dl in dls:
            watchdog()
            out = (step_trains(dl, dt_s) if step_trains is not None
                   else step(self._recruitment, dl, dt_s))
            schedule.steps_done += 1
            force_n, l_ce_m = out.force_n, out.l_ce_m
            if not (isfinite(force_n) and isfinite(l_ce_m)):
                # Cannot happen with validated inputs and parameters; if it
                # does, never publish it: report and return to rest.
                self.get_logger().error(
                    f'non-finite output (force {force_n!r} N, l_ce {l_ce_m!r} m) '
                    f'with R {self._recruitment!r}, dl_mt {dl!r} m: resetting',
                    throttle_duration_sec=1.0)
                self._reset_to_rest()
                return False
            # Steps on a fixed grid of simulated time, whatever the tick phase.
            if not schedule.steps_done % every:
                publish(force_n, l_ce_m)
                if not schedule.steps_done % state_every:
                    self._publish_state(out.recruitment, out.mean_fitness)
        return True

    def _publish(self, force_n: float, l_ce_m: float) -> None:
        """Publish the outputs of the step just run, stamped with its end time."""
        sim_ns = round(self._schedule.steps_done * NS_PER_S / self._rate_hz)
        sec, nanosec = divmod(self._stamp_origin_ns + sim_ns, NS_PER_S)
        wrench = self._wrench_msg
        stamp = wrench.header.stamp
        stamp.sec = sec
        stamp.nanosec = nanosec
        # An output no subscription has matched is not converted and written:
        # DDS would deliver it to no one (volatile durability), and at 1 kHz
        # the writes were a third of an idle simulator's CPU (0.20 -> 0.14 of
        # a core without them).
        if self._pub_clock is not None and self._pub_clock.get_subscription_count():
            self._clock_msg.clock = stamp
            self._pub_clock.publish(self._clock_msg)
        if self._pub_force.get_subscription_count():
            self._force_msg.data = force_n
            self._pub_force.publish(self._force_msg)
        if self._pub_ce_length.get_subscription_count():
            self._ce_length_msg.data = l_ce_m
            self._pub_ce_length.publish(self._ce_length_msg)
        if self._pub_wrench.get_subscription_count():
            wrench.wrench.force.x = force_n
            self._pub_wrench.publish(wrench)

    def _publish_state(self, recruitment: float, fitness: float) -> None:
        """Publish R, the mean fitness and each channel's activation of the step
        just run (first_order: one channel, whose activation is R)."""
        # As in _publish: only the outputs some subscription has matched.
        if self._pub_r_state.get_subscription_count():
            self._r_state_msg.data = recruitment
            self._pub_r_state.publish(self._r_state_msg)
        if self._pub_fitness.get_subscription_count():
            self._fitness_msg.data = fitness
            self._pub_fitness.publish(self._fitness_msg)
        if self._pub_activation.get_subscription_count():
            self._activation_msg.data = (self._muscle.activation.tolist() if self._pulsed
                                         else [recruitment])
            self._pub_activation.publish(self._activation_msg)

    def _set_activation_layout(self) -> None:
        """``activation``'s layout: one dimension, ``channel``, of the muscle's channels."""
        c = self._params.n_channels
        self._activation_msg.layout.dim = [MultiArrayDimension(label='channel', size=c,
                                                               stride=c)]

    def _watchdog(self) -> None:
        """Stimulation watchdog: R (ding2003: every channel's pulse width) -> 0
        when the controller has gone quiet."""
        on = stimulating(self._held) if self._pulsed else self._recruitment > 0.0
        if watchdog_trips(self.sim_time_s, self._last_stim_t_s, self._input_timeout_s, on):
            if self._pulsed:
                what = f'{commands_text(self._held)} -> every channel\'s pulse width 0'
                off = off_commands(self._held, self._params.n_channels, self._params)
                self._muscle.stimulate(off)
                self._held = {c.channel: c for c in off}
            else:
                what = f'recruitment {self._recruitment:g} -> 0'
                self._recruitment = 0.0
            self.get_logger().warning(
                f'no pulse_width or recruitment message for {self._input_timeout_s:g} s '
                f'(nor stimulation; input_timeout_s): {what} until the next one')
            self._watchdog_tripped = True

    # -- inputs -----------------------------------------------------------------

    def _stimulation_taken(self, what: str) -> None:
        """Count a good stimulation message (any input topic) for the watchdog."""
        self._stim_messages += 1
        self._last_stim_t_s = self.sim_time_s
        if self._watchdog_tripped:
            self._watchdog_tripped = False
            self.get_logger().info(f'stimulation back: {what}')

    def _set_stimulation(self, recruitment: float) -> None:
        self._recruitment = recruitment
        self._stimulation_taken(f'recruitment {recruitment:g}')

    def _stimulate(self, commands: tuple[ChannelCommand, ...]) -> None:
        """ding2003: the channels' new commands to the muscle's trains."""
        self._muscle.stimulate(commands)
        self._held.update((c.channel, c) for c in commands)
        self._stimulation_taken(commands_text(self._held))

    def _kept(self) -> str:
        """The inputs a rejected message leaves as they are, for its warning."""
        stim = (commands_text(self._held) if self._pulsed
                else f'recruitment {self._recruitment:g}')
        return f'{stim}, length_command {self._dl_mt_m:g} m'

    def _reject(self, topic: str, value, err: Exception) -> None:
        """Warn (throttled per topic) that ``value`` on ``topic`` was ignored.

        :param topic: the subscription's fully qualified topic name
        :param value: the value as the line quotes it (a ``str`` as it is)
        :param err: the reason, which names the topic (or field) and the value too
        """
        shown = value if isinstance(value, str) else repr(value)
        self._bad_input.warn(topic, f'ignoring {topic} = {shown}: {err}; keeping {self._kept()}')

    def _on_pulse_width(self, msg: Float64) -> None:
        topic = self._sub_pw.topic_name
        try:
            r = pulse_width_command(msg.data, self._params, topic)
            command = pulse_width_channel(msg.data, self._params) if self._pulsed else None
        except ValueError as err:
            self._reject(topic, msg.data, err)
            return
        if command is None:
            self._set_stimulation(r)
            return
        # Channel 1, single pulses at frequency_hz (the muscle's own parameter).
        self._muscle.set_pulse_width(command.pulse_width_s)
        self._held[1] = command
        self._stimulation_taken(commands_text(self._held))

    def _on_recruitment(self, msg: Float64) -> None:
        topic = self._sub_r.topic_name
        try:
            r = check_recruitment(msg.data, topic)
            if self._pulsed:
                raise ValueError(f'`{topic}` is a level command, which a muscle with '
                                 '`activation_model: ding2003` does not take: send '
                                 'pulse_width (channel 1 at frequency_hz) or stimulation')
        except ValueError as err:
            self._reject(topic, msg.data, err)
            return
        self._set_stimulation(r)

    def _on_stimulation(self, msg) -> None:
        """A stimulator's command for some channels (hill_muscle_interfaces/msg/Stimulation).

        Checked as a whole (._stimulation.check_message): a rejected message
        changes no channel. ding2003: each named channel's train is replaced;
        first_order: channel 1's pulse width acts as a pulse_width message.
        """
        topic = self._sub_stim.topic_name
        try:
            commands = check_message(msg, self._params, self._params.n_channels, self._held)
        except ValueError as err:
            self._reject(topic, message_text(msg), err)
            return
        if self._pulsed:
            self._stimulate(commands)
            return
        u = level_command(commands, self._params)
        self._set_stimulation(self._recruitment if u is None else u)

    def _on_length_command(self, msg: Float64) -> None:
        topic = self._sub_dl.topic_name
        try:
            self._dl_mt_m = check_dl_mt(msg.data, topic)
        except ValueError as err:
            self._reject(topic, msg.data, err)
            return
        self._track_active = False   # "now" overrides any knots sent ahead

    def _on_length_command_stamped(self, msg: PointStamped) -> None:
        self._add_knot(msg)
        self._take_stamped()

    def _take_stamped(self) -> None:
        """Add every knot queued on ``length_command_stamped`` to the track.

        The executor hands a subscription one message per wait, and each wait
        costs as much as the message: a sender's burst of knots ahead (the
        player's first window) would trickle in over hundreds of waits, and
        on sim time behind the steps they are for. Taking the whole queue at
        once keeps up with any burst.
        """
        sub = self._sub_dl_stamped
        while True:
            with sub.handle:
                taken = sub.handle.take_message(sub.msg_type, sub.raw)
            if taken is None:
                return
            self._add_knot(taken[0])

    def _add_knot(self, msg: PointStamped) -> None:
        topic = self._sub_dl_stamped.topic_name
        stamp = msg.header.stamp
        value = msg.point.x
        try:
            sim_s = self._stamp_to_sim_s(stamp.sec, stamp.nanosec)
            frame = msg.header.frame_id
            if frame not in ('', self._frame_id):
                raise ValueError(f'`header.frame_id` must be empty or {self._frame_id!r} '
                                 f'(frame_id), got {frame!r}')
            if not self._track_active:
                # Start from where the muscle is commanded to be now.
                self._track.clear(self.sim_time_s, self._dl_mt_m)
            late_s = self._track.add(sim_s, value)
        except ValueError as err:
            self._bad_input.warn(topic, f'ignoring {topic} = {value!r} stamped '
                                        f'{stamp.sec}.{stamp.nanosec:09d} s: {err}; keeping '
                                        f'length_command {self._dl_mt_m:g} m')
            return
        self._track_active = True
        if late_s is not None:
            self._late_knots += 1
            self._worst_late_s = max(self._worst_late_s, late_s)
            self._late_warner.warn(
                topic, f'{topic}: knot {value:g} m stamped {stamp.sec}.{stamp.nanosec:09d} s '
                       f'arrived {late_s * 1e3:.1f} ms of simulated time late (simulated time '
                       f'{self.sim_time_s:.3f} s): applied at the next step; send knots '
                       'earlier, e.g. a larger lookahead_s on the protocol player '
                       f'({self._late_knots} late so far)')

    def _stamp_to_sim_s(self, sec: int, nanosec: int) -> float:
        """[s] the simulated time of a header stamp in this node's stamp clock.

        :raises ValueError: on an unset (zero) stamp, a nanosec field out of
            range, or a stamp more than :data:`MAX_STAMP_LEAD_S` ahead
        """
        if not 0 <= nanosec < NS_PER_S:
            raise ValueError(f'`header.stamp.nanosec` must be in [0, 1e9), got {nanosec!r}')
        if sec == 0 and nanosec == 0:
            raise ValueError('`header.stamp` is 0 (unset): stamp the time dl_MT is to be '
                             'reached')
        sim_s = (sec * NS_PER_S + nanosec - self._stamp_origin_ns) / NS_PER_S
        if sim_s - self.sim_time_s > MAX_STAMP_LEAD_S:
            clock = ('sim time from 0 (publish_clock)' if self._publish_clock
                     else 'the node clock at start-up + sim time')
            raise ValueError(f'`header.stamp` is {sim_s - self.sim_time_s:.6g} s ahead of '
                             f'simulated time {self.sim_time_s:.3f} s, more than '
                             f'{MAX_STAMP_LEAD_S:g} s: stamps are in this node\'s clock, '
                             f'{clock}')
        return sim_s

    # -- reset ------------------------------------------------------------------

    def _reset_to_rest(self) -> None:
        """Rest state, empty memory, and the held inputs back to rest too.

        The held inputs are cleared so that rest really is rest: the next
        input message applies from there. Simulated time keeps running.
        """
        self._muscle.reset()
        self._recruitment = 0.0
        self._held = {}
        self._dl_mt_m = 0.0
        self._track_active = False   # knots sent ahead are dropped too
        self._watchdog_tripped = False

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self._reset_to_rest()
        response.success = True
        response.message = (f'muscle at rest at t = {self.sim_time_s:.3f} s: memory cleared, '
                            'recruitment 0, length_command 0')
        self.get_logger().info(response.message)
        return response

    # -- parameters -------------------------------------------------------------

    def _candidate(self, parameters: list[Parameter]) -> MuscleParams:
        changes = {p.name: p.value for p in parameters if p.name in MuscleParams.field_names()}
        return self._params.replace(**changes) if changes else self._params

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """Accept a change only if the model accepts it; the reason names the value."""
        try:
            self._candidate(parameters)
        except (ValueError, TypeError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        for p in parameters:
            if p.name == 'input_timeout_s' and not math.isfinite(p.value):
                return SetParametersResult(
                    successful=False, reason=f'`input_timeout_s` must be finite, got {p.value!r}')
            if p.name == 'frame_id':
                try:
                    check_frame_id(p.value)
                except ValueError as err:
                    return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        old = self._params
        new = self._candidate(parameters)
        for p in parameters:
            if p.name == 'input_timeout_s':
                self._input_timeout_s = p.value
            elif p.name == 'frame_id':
                self._frame_id = p.value
                self._wrench_msg.header.frame_id = p.value
        if new == old:
            return
        self._params = new
        changed = [n for n in MuscleParams.field_names() if getattr(new, n) != getattr(old, n)]
        if not all(keeps_state(n, old) and keeps_state(n, new) for n in changed):
            # Never compiles here (rebuild_muscle): at most the arrays of the
            # loaded compiled muscle are built anew.
            self._muscle = rebuild_muscle(new, self._compiled, self.get_logger())
            self._compiled = self._muscle.build == engines.COMPILED
            self._pulsed = pulsed(new)
            self._set_activation_layout()
            self._reset_to_rest()
            self.get_logger().info(f'{", ".join(changed)} changed: muscle rebuilt at rest '
                                   f'(engine: {"compiled" if self._compiled else "python"})')
        else:
            self.get_logger().info(f'{", ".join(changed)} changed, state kept')

    def _diagnose(self, report: DiagnosticReport) -> None:
        """/diagnostics: step rate, late ticks, catch-up, steps behind, longest
        tick gap, watchdog and rejected inputs; levels in RATE_WARN_FRACTION,
        CATCH_UP_WARN_STEPS and ERROR_BEHIND_S."""
        s = self._schedule
        behind = max(0, s.target(self._steady.now().nanoseconds) - s.steps_done)
        steps = report.delta('steps', s.steps_done)
        target_hz = self._rate_hz * self._real_time_factor
        achieved_hz = steps / report.period_s if report.period_s > 0.0 else 0.0
        late = report.delta('late_ticks', self._late_ticks)
        catch_up = report.delta('catch_up_steps', self._catch_up_steps)
        bad = report.delta('bad_inputs', self._bad_input.total)
        gap_s = s.max_tick_gap_s
        stimulated = self._stim_messages > 0
        report.add('rate_hz', self._rate_hz)
        report.add('real_time_factor', self._real_time_factor)
        report.add('target_step_rate_hz', target_hz)
        report.add('achieved_step_rate_hz', achieved_hz)
        report.add('period_s', report.period_s)
        report.add('sim_time_s', self.sim_time_s)
        report.add('steps_done', s.steps_done)
        report.add('steps_behind', behind)
        report.add('steps_behind_error_above', self._error_behind_steps)
        report.add('late_ticks_total', self._late_ticks)
        report.add('late_ticks_last_period', late)
        report.add('catch_up_steps_total', self._catch_up_steps)
        report.add('catch_up_steps_last_period', catch_up)
        report.add('max_tick_gap_s', gap_s)
        report.add('watchdog_tripped', self._watchdog_tripped)
        report.add('input_timeout_s', self._input_timeout_s)
        report.add('recruitment', self._recruitment)
        report.add('activation_model', self._params.activation_model)
        if self._pulsed:
            report.add('channels', commands_text(self._held))
            for c, a in enumerate(self._muscle.activation.tolist(), 1):
                report.add(f'activation[{c}]', a)
        out = self._muscle.outputs()
        report.add('recruitment_state', out.recruitment)
        report.add('mean_fitness', out.mean_fitness)
        report.add('stimulation_received', stimulated)
        report.add('stimulation_age_s', self.sim_time_s - self._last_stim_t_s if stimulated
                   else None)
        report.add('late_length_knots_total', self._late_knots)
        report.add('bad_inputs_total', self._bad_input.total)
        report.add('bad_inputs_last_period', bad)
        for topic, count in sorted(self._bad_input.counts.items()):
            report.add(f'bad_inputs[{topic}]', count)
        if behind > self._error_behind_steps:
            report.error(f'{behind} steps behind the clock, more than {ERROR_BEHIND_S:g} s '
                         f'worth: not keeping up with rate_hz x '
                         f'real_time_factor = {target_hz:g} steps/s')
        if steps < RATE_WARN_FRACTION * target_hz * report.period_s - self._steps_per_tick:
            report.warn(f'{achieved_hz:.1f} steps/s in the last {report.period_s:.2f} s, below '
                        f'{RATE_WARN_FRACTION:.0%} of {target_hz:g}')
        if catch_up > CATCH_UP_WARN_STEPS:
            report.warn(f'{catch_up} steps caught up in {late} late tick(s) in the last '
                        f'{report.period_s:.2f} s')
        if self._watchdog_tripped:
            report.warn(f'stimulation watchdog tripped: no pulse_width or recruitment, nor '
                        f'stimulation, for {self._input_timeout_s:g} s (input_timeout_s), '
                        + ('every channel off' if self._pulsed else 'recruitment 0'))
        if bad:
            report.warn(f'{bad} input message(s) rejected in the last {report.period_s:.2f} s')
        report.ok(f'stepping at {achieved_hz:.1f} steps/s of {target_hz:g}'
                  + ('' if stimulated else '; no pulse_width or recruitment received yet, '
                                           'nor stimulation'))

    def on_exit(self) -> None:
        """Log the run's timing statistics (achieved rate, drift, late ticks, longest tick gap)."""
        s = self._schedule
        elapsed_s = (self._steady.now().nanoseconds - s.start_ns) / NS_PER_S
        behind = s.target(self._steady.now().nanoseconds) - s.steps_done
        # Not the node logger: after Ctrl-C its /rosout publisher is gone. Its
        # name is the node logger's (rcl's form of the fully qualified name,
        # e.g. left_leg.quad for /left_leg/quad) + .stats, so two nodes named
        # alike in different namespaces stay apart, and the node's log level
        # (--log-level left_leg.quad:=warn) applies to it too.
        rclpy.logging.get_logger(f'{self.get_logger().name}.stats').info(
            f'ran {s.steps_done} steps in {elapsed_s:.3f} s of steady time '
            f'({s.steps_done / elapsed_s if elapsed_s > 0 else 0.0:.1f} steps/s), '
            f'{s.ticks} ticks, {s.late_ticks} late, {behind} steps behind at exit, '
            f'longest gap between ticks {s.max_tick_gap_s * 1e3:.1f} ms (ended at steady '
            f'time {(s.max_tick_gap_end_ns or 0) / NS_PER_S:.6f} s), '
            f'{self._late_knots} late length_command_stamped knots '
            f'(worst {self._worst_late_s * 1e3:.1f} ms of simulated time)')


def main(args: list[str] | None = None) -> int:
    """Entry point: ``simulator [--ros-args ...]``; returns the exit status."""
    return run_node(Simulator, args)


#: The console script (setup.py): main(), then the process ends at once.
process_main = process_entry(main)


if __name__ == '__main__':
    process_main()
