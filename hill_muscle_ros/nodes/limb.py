"""The limb node: one joint moved by several muscles, behind ROS 2 topics.

The plant (the joint and its muscles) comes from the node's parameters, i.e.
a plant file given with ``--ros-args --params-file PLANT.yaml``; ROS flattens
its nested keys to dotted names (``joint.inertia_kg_m2``,
``quadriceps.f_iso_max_n``), which are read back here and validated by
:meth:`~hill_muscle_ros.model.limb.LimbPlant.from_mapping`, the same check as
the offline CLI's. A bad plant stops start-up with a message naming the key
(exit status 1).

For each muscle ``<m>`` of the plant it subscribes ``<m>/pulse_width`` [s]
(through that muscle's recruitment curve) and ``<m>/recruitment`` [-], and it
subscribes ``external_torque`` [N m] (all std_msgs/Float64, zero-order hold),
and ``<m>/stimulation`` (hill_muscle_interfaces/msg/Stimulation, checked
against that muscle's ``stimulator`` and channels as the simulator checks it,
._stimulation). A muscle with ``activation_model: ding2003`` is driven by its
channels' pulse trains (``Limb.stimulate``; ``<m>/pulse_width`` is channel 1
at its ``frequency_hz``, ``<m>/recruitment`` is refused) and publishes each
channel's activation on ``<m>/activation`` (std_msgs/Float64MultiArray).
It steps the limb (see Engine below) at dt = 1 / ``rate_hz``
against the steady clock and, for every step, publishes ``joint_states``
(sensor_msgs/JointState: the joint's name, theta [rad], omega [rad/s], and
the net muscle torque [N m] as the effort), and each muscle's ``<m>/force``
[N] (Float64) and ``<m>/wrench`` (geometry_msgs/WrenchStamped, force along +x,
frame_id the muscle's name), stamped with the step's simulated time as the
simulator stamps; optionally ``/clock``. The watchdog drops a muscle's command
to 0 (every channel's pulse width to 0) after ``input_timeout_s`` of
simulated time without a message on its inputs. A ``reset`` service (std_srvs/Trigger) returns the limb to its initial
state with every held input at 0.

Engine: the node steps a :class:`~hill_muscle_ros.model.limb.Limb` on the
compiled build of the limb's kernels when
:func:`~hill_muscle_ros.model.engine.choice` is compiled (numba installed,
``HILL_MUSCLE_ENGINE`` not ``python``), else on the very same functions as
plain Python; both give the same steps to 1e-9 rad. The compiled step is far
cheaper: one step as a tick makes it, knee preset
(``benchmarks/limb_node_tick.py``, two runs, load average 2.7): median 7.3
against 238-240 us, mean 8 against 400 us, 99th percentile 23-25 us against
6.0 ms; on the plain functions the release of the quadriceps' 1000 units
(0.49-0.50 ms a step on average) takes half of every 1 kHz tick. The compiled
build is loaded in ``__init__``,
before any publisher, subscription, service or timer exists (so before the
node can be seen as started), never in a tick: 0.8 s from numba's disk
cache, about 30 s when it compiles (a clean clone, or after an edit of the
model's code; BENCHMARKS.md, "The limb and the FES muscle, compiled"). The
node logs which engine runs and how long loading took, and that it may
compile first. If the compiled limb fails to load, it warns and steps the
Python limb. The test suite compiles the kernels once at its start
(``test/conftest.py``), ``make demo-knee`` before it starts its nodes.

Run: ``ros2 run hill_muscle_ros limb_simulator --ros-args --params-file
config/knee.yaml`` or ``hill-muscle limb --ros-args ...``.
"""
from __future__ import annotations

import math

import rclpy
from geometry_msgs.msg import WrenchStamped
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray, MultiArrayDimension
from std_srvs.srv import Trigger

from ..model import engine as engines
from ..model.limb import TORQUE_LIMIT_N_M, Limb, LimbPlant, kernels as limb_kernels
from ..model.muscle import check_recruitment
from ..model.stimulator import ChannelCommand
from ..qos import OUTPUT_QOS, RELIABLE_QOS
from ..timebase import NS_PER_S
from ..watchdog import DEFAULT_INPUT_TIMEOUT_S, INPUT_TIMEOUT_RANGE_S, watchdog_trips
from ._diagnostics import DiagnosticReport, NodeDiagnostics
from ._engine import load_engine
from ._inputs import BadInputWarner, pulse_width_command
from ._overrides import LIMB_NODE_PARAMETERS, declare_plant, plant_values, require_muscles
from ._parameters import declare_checked, number_descriptor, parameter_overrides
from ._process import StartupError, process_entry, run_node
from ._stepping import (DEFAULT_RATE_HZ, DEFAULT_REAL_TIME_FACTOR, ERROR_BEHIND_S,
                        MAX_CATCH_UP_S, MIN_TICK_PERIOD_S, RATE_HZ_RANGE, RATE_WARN_FRACTION,
                        REAL_TIME_FACTOR_RANGE, STEPS_PER_TICK_ROUNDING, StepSchedule)
from ._stimulation import (Stimulation, check_message, commands_text, level_command,
                           message_text, off_commands, pulse_width_channel, pulsed, stimulating)
from ._topics import (QOS_OVERRIDES_PREFIX, check_qos_overrides, overridable_publisher,
                      overridable_subscription)

NODE_NAME = 'limb'


def load_limb(plant: LimbPlant, logger) -> Limb:
    """The limb the node steps: on the compiled build when
    :func:`~hill_muscle_ros.model.engine.choice` says so, else on the plain
    functions; logs which, and how long loading took (:func:`._engine.load_engine`).

    :param plant: the joint and its muscles
    :param logger: the node's logger
    """
    return load_engine('limb', lambda: Limb(plant, build=engines.COMPILED),
                       lambda: Limb(plant, build=engines.PYTHON), limb_kernels.loaded, logger)


class LimbNode(Node):
    """ROS 2 shell around :class:`~hill_muscle_ros.model.limb.Limb` on either build
    of its kernels (:func:`load_limb`).

    :raises StartupError: on an invalid parameter or plant at start-up
    """

    NODE_NAME = NODE_NAME

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        rate_hz = declare_checked(self, 'rate_hz', DEFAULT_RATE_HZ, number_descriptor(
            'step rate, dt = 1 / rate_hz', 'Hz', *RATE_HZ_RANGE, read_only=True))
        rtf = declare_checked(self, 'real_time_factor', DEFAULT_REAL_TIME_FACTOR,
                              number_descriptor('simulated seconds per clock second', '-',
                                                *REAL_TIME_FACTOR_RANGE, read_only=True))
        self._input_timeout_s = declare_checked(
            self, 'input_timeout_s', DEFAULT_INPUT_TIMEOUT_S, number_descriptor(
                "stimulation watchdog: a muscle's command (every channel's pulse width) drops "
                'to 0 after this long without a pulse_width, recruitment or stimulation '
                'message for it; 0 disables', 's',
                *INPUT_TIMEOUT_RANGE_S))
        self._publish_clock = declare_checked(self, 'publish_clock', False, ParameterDescriptor(
            description='publish /clock (sim time from 0) and stamp outputs with it',
            read_only=True))
        for name, value in (('rate_hz', rate_hz), ('real_time_factor', rtf),
                            ('input_timeout_s', self._input_timeout_s)):
            if not math.isfinite(value):
                raise StartupError(f'parameter `{name}` must be finite, got {value!r}')

        overrides = parameter_overrides(self)
        values = plant_values(overrides, LIMB_NODE_PARAMETERS)
        try:
            self._plant = LimbPlant.from_mapping(values, source='plant parameters')
        except ValueError as err:
            raise StartupError(str(err)) from None
        require_muscles(self._plant)
        declare_plant(self, values)
        names = [m.name for m in self._plant.muscles]
        topics = ['external_torque', 'joint_states']
        for n in names:
            topics += [f'{n}/pulse_width', f'{n}/recruitment', f'{n}/stimulation', f'{n}/force',
                       f'{n}/wrench', f'{n}/activation']
        check_qos_overrides(self, [n for n in overrides if n.startswith(QOS_OVERRIDES_PREFIX)],
                            {self.resolve_topic_name(t) for t in topics})

        # Built before any publisher, subscription, service or timer: a compile
        # (about 30 s) happens before the node can be seen as started, never in a tick.
        self._limb = load_limb(self._plant, self.get_logger())
        self._rate_hz = rate_hz
        self._dt_s = 1.0 / rate_hz
        self._names = names
        # Held inputs (zero-order hold): each muscle's recruitment command u
        # [-] (a pulse width through its curve) and the external torque [N m].
        self._commands = [0.0] * len(names)
        # ding2003 muscles: each channel's last good command (the limb's trains
        # hold it); their entry of _commands stays 0 (the limb does not read it).
        self._params = [m.params for m in self._plant.muscles]
        self._pulsed = [pulsed(p) for p in self._params]
        self._held: list[dict[int, ChannelCommand]] = [{} for _ in names]
        self._external_torque_n_m = 0.0
        self._last_stim_t_s = [0.0] * len(names)   # [s] sim time of each muscle's last input
        self._watchdog_tripped = [False] * len(names)
        self._stim_messages = 0
        self._bad_input = BadInputWarner(self.get_logger())
        self._resets_on_error = 0

        self._pub_joint = overridable_publisher(self, JointState, 'joint_states', OUTPUT_QOS)
        self._joint_msg = JointState()
        self._joint_msg.name = [self._plant.joint.name]
        self._pub_force = [overridable_publisher(self, Float64, f'{n}/force', OUTPUT_QOS)
                           for n in names]
        self._pub_wrench = [overridable_publisher(self, WrenchStamped, f'{n}/wrench', OUTPUT_QOS)
                            for n in names]
        self._force_msgs = [Float64() for _ in names]
        self._wrench_msgs = [WrenchStamped() for _ in names]
        for n, msg in zip(names, self._wrench_msgs):
            msg.header.frame_id = n   # the muscle's own frame, its line of action along +x
        self._clock_msg = ClockMsg()
        self._pub_clock = (overridable_publisher(self, ClockMsg, '/clock', OUTPUT_QOS)
                           if self._publish_clock else None)
        # Each channel's activation of the ding2003 muscles, every step.
        self._pub_activation = [
            overridable_publisher(self, Float64MultiArray, f'{n}/activation', OUTPUT_QOS)
            if p else None for n, p in zip(names, self._pulsed)]
        self._activation_msgs = [Float64MultiArray() for _ in names]
        for msg, params in zip(self._activation_msgs, self._params):
            c = params.n_channels
            msg.layout.dim = [MultiArrayDimension(label='channel', size=c, stride=c)]
        self._sub_pw, self._sub_r, self._sub_stim = [], [], []
        for i, n in enumerate(names):
            self._sub_pw.append(overridable_subscription(
                self, Float64, f'{n}/pulse_width',
                lambda msg, i=i: self._on_pulse_width(i, msg), RELIABLE_QOS))
            self._sub_r.append(overridable_subscription(
                self, Float64, f'{n}/recruitment',
                lambda msg, i=i: self._on_recruitment(i, msg), RELIABLE_QOS))
            if Stimulation is not None:
                self._sub_stim.append(overridable_subscription(
                    self, Stimulation, f'{n}/stimulation',
                    lambda msg, i=i: self._on_stimulation(i, msg), RELIABLE_QOS))
        if Stimulation is None:   # pragma: no cover - the test venv has the interface package
            self.get_logger().warning(
                'hill_muscle_interfaces is not installed: no `<muscle>/stimulation` input '
                '(build it with `make interfaces` or colcon; pulse_width and recruitment work)')
        self._sub_tau = overridable_subscription(self, Float64, 'external_torque',
                                                 self._on_external_torque, RELIABLE_QOS)
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
        self._real_time_factor = rtf
        self._steps_per_tick = max(1, math.ceil(tick_s * rate_hz * rtf
                                                - STEPS_PER_TICK_ROUNDING))
        self._error_behind_steps = max(1, math.ceil(ERROR_BEHIND_S * rtf * rate_hz))
        self._diagnostics = NodeDiagnostics(self, 'limb simulation', self._diagnose)
        self.get_logger().info(
            f'{self._plant.joint.name} with {", ".join(names)}, '
            f'{rate_hz:g} Hz, real_time_factor {rtf:g}, publish_clock {self._publish_clock}, '
            f'watchdog {self._input_timeout_s:g} s')

    # -- time and steps ---------------------------------------------------------

    @property
    def sim_time_s(self) -> float:
        """[s] simulated time, from the step count (no accumulated rounding)."""
        return self._schedule.steps_done / self._rate_hz

    def _on_tick(self) -> None:
        due = self._schedule.due(self._steady.now().nanoseconds)
        if due == 0:
            return
        n = min(due, self._max_steps_per_tick)
        if n < due:
            self.get_logger().warning(
                f'{due} steps due after a stall or overload: running {n} now and the rest '
                f'on the next ticks; if this repeats, lower rate_hz ({self._rate_hz:g}) or '
                'real_time_factor', throttle_duration_sec=1.0)
        self._run_steps(n)

    def _run_steps(self, n: int) -> bool:
        """Run ``n`` steps with the held inputs, publishing each one.

        :return: ``False`` if a step failed (the limb was reset and the rest dropped)
        """
        step = self._limb.step
        for _ in range(n):
            self._watchdog()
            try:
                out = step(self._commands, self._external_torque_n_m, self._dt_s)
            except ValueError as err:
                # The inputs were validated, so this is the joint driven out of
                # the muscles' range (e.g. by a huge external torque): never
                # publish it, report it and return to rest.
                self._resets_on_error += 1
                self.get_logger().error(f'{err}: resetting the limb to its initial state '
                                        'with every input at 0', throttle_duration_sec=1.0)
                self._reset_to_rest()
                return False
            self._schedule.steps_done += 1
            if not (math.isfinite(out.theta_rad) and math.isfinite(out.omega_rad_per_s)):
                self._resets_on_error += 1
                self.get_logger().error(
                    f'non-finite state (theta {out.theta_rad!r} rad, omega '
                    f'{out.omega_rad_per_s!r} rad/s): resetting', throttle_duration_sec=1.0)
                self._reset_to_rest()
                return False
            self._publish(out)
        return True

    def _publish(self, out) -> None:
        """Publish the outputs of the step just run, stamped with its end time."""
        sim_ns = round(self._schedule.steps_done * NS_PER_S / self._rate_hz)
        sec, nanosec = divmod(self._stamp_origin_ns + sim_ns, NS_PER_S)
        joint = self._joint_msg
        stamp = joint.header.stamp
        stamp.sec = sec
        stamp.nanosec = nanosec
        # An output no subscription has matched is not converted and written:
        # DDS would deliver it to no one (volatile durability), as in the simulator.
        if self._pub_clock is not None and self._pub_clock.get_subscription_count():
            self._clock_msg.clock = stamp
            self._pub_clock.publish(self._clock_msg)
        if self._pub_joint.get_subscription_count():
            joint.position = [out.theta_rad]
            joint.velocity = [out.omega_rad_per_s]
            joint.effort = [out.muscle_torque_n_m]
            self._pub_joint.publish(joint)
        for i, force_n in enumerate(out.force_n):
            if self._pub_force[i].get_subscription_count():
                msg = self._force_msgs[i]
                msg.data = force_n
                self._pub_force[i].publish(msg)
            if self._pub_wrench[i].get_subscription_count():
                wrench = self._wrench_msgs[i]
                wrench.header.stamp = stamp
                wrench.wrench.force.x = force_n
                self._pub_wrench[i].publish(wrench)
            if self._pulsed[i] and self._pub_activation[i].get_subscription_count():
                activation = self._activation_msgs[i]
                activation.data = self._limb.activation(i).tolist()
                self._pub_activation[i].publish(activation)

    def _watchdog(self) -> None:
        """Stimulation watchdog, per muscle: u (every channel's pulse width) -> 0
        when its inputs have gone quiet."""
        now_s = self.sim_time_s
        for i, u in enumerate(self._commands):
            on = stimulating(self._held[i]) if self._pulsed[i] else u > 0.0
            if watchdog_trips(now_s, self._last_stim_t_s[i], self._input_timeout_s, on):
                if self._pulsed[i]:
                    what = f'{commands_text(self._held[i])} -> every channel\'s pulse width 0'
                    off = off_commands(self._held[i], self._params[i].n_channels,
                                       self._params[i])
                    self._limb.stimulate(i, off)
                    self._held[i] = {c.channel: c for c in off}
                else:
                    what = f'command {u:g} -> 0'
                    self._commands[i] = 0.0
                self.get_logger().warning(
                    f'no {self._names[i]}/pulse_width or recruitment message for '
                    f'{self._input_timeout_s:g} s (nor stimulation; input_timeout_s): {what} '
                    'until the next one')
                self._watchdog_tripped[i] = True

    # -- inputs -----------------------------------------------------------------

    def _taken(self, i: int, what: str) -> None:
        """Count a good stimulation message of muscle ``i`` for its watchdog."""
        self._stim_messages += 1
        self._last_stim_t_s[i] = self.sim_time_s
        if self._watchdog_tripped[i]:
            self._watchdog_tripped[i] = False
            self.get_logger().info(f'{self._names[i]} stimulation back: {what}')

    def _set_command(self, i: int, u: float) -> None:
        self._commands[i] = u
        self._taken(i, f'command {u:g}')

    def _stimulate(self, i: int, commands) -> None:
        """A ding2003 muscle's channels' new commands to the limb's trains."""
        self._limb.stimulate(i, commands)
        self._held[i].update((c.channel, c) for c in commands)
        self._taken(i, commands_text(self._held[i]))

    def _kept(self, i: int) -> str:
        """Muscle ``i``'s stimulation a rejected message leaves, for its warning."""
        return (commands_text(self._held[i]) if self._pulsed[i]
                else f'command {self._commands[i]:g}')

    def _reject(self, topic: str, value, err: Exception, kept: str) -> None:
        """Warn (throttled per topic) that ``value`` on ``topic`` was ignored
        (``value`` quoted as it is if a ``str``)."""
        shown = value if isinstance(value, str) else repr(value)
        self._bad_input.warn(topic, f'ignoring {topic} = {shown}: {err}; keeping {kept}')

    def _on_pulse_width(self, i: int, msg: Float64) -> None:
        topic = self._sub_pw[i].topic_name
        params = self._params[i]
        try:
            u = pulse_width_command(msg.data, params, topic)
            command = pulse_width_channel(msg.data, params) if self._pulsed[i] else None
        except ValueError as err:
            self._reject(topic, msg.data, err, self._kept(i))
            return
        if command is None:
            self._set_command(i, u)
        else:   # channel 1, single pulses at the muscle's frequency_hz
            self._stimulate(i, (command,))

    def _on_recruitment(self, i: int, msg: Float64) -> None:
        topic = self._sub_r[i].topic_name
        try:
            u = check_recruitment(msg.data, topic)
            if self._pulsed[i]:
                raise ValueError(f'`{topic}` is a level command, which a muscle with '
                                 '`activation_model: ding2003` does not take: send '
                                 'pulse_width (channel 1 at frequency_hz) or stimulation')
        except ValueError as err:
            self._reject(topic, msg.data, err, self._kept(i))
            return
        self._set_command(i, u)

    def _on_stimulation(self, i: int, msg) -> None:
        """A stimulator's command for some of muscle ``i``'s channels, checked as
        a whole (._stimulation.check_message): a rejected message changes nothing."""
        topic = self._sub_stim[i].topic_name
        params = self._params[i]
        try:
            commands = check_message(msg, params, params.n_channels, self._held[i])
        except ValueError as err:
            self._reject(topic, message_text(msg), err, self._kept(i))
            return
        if self._pulsed[i]:
            self._stimulate(i, commands)
            return
        u = level_command(commands, params)
        self._set_command(i, self._commands[i] if u is None else u)

    def _on_external_torque(self, msg: Float64) -> None:
        topic = self._sub_tau.topic_name
        tau = msg.data
        if not abs(tau) <= TORQUE_LIMIT_N_M:   # also false for NaN
            self._reject(topic, tau, ValueError(
                f'`{topic}` must be finite and within ±{TORQUE_LIMIT_N_M:g} N m'),
                f'external torque {self._external_torque_n_m:g} N m')
            return
        self._external_torque_n_m = tau

    # -- reset ------------------------------------------------------------------

    def _reset_to_rest(self) -> None:
        """Initial state, and every held input back to 0; simulated time runs on."""
        self._limb.reset()
        self._commands = [0.0] * len(self._names)
        self._held = [{} for _ in self._names]
        self._external_torque_n_m = 0.0
        self._watchdog_tripped = [False] * len(self._names)

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self._reset_to_rest()
        response.success = True
        response.message = (f'{self._plant.joint.name} at its initial state at t = '
                             f'{self.sim_time_s:.3f} s: commands 0, external torque 0')
        self.get_logger().info(response.message)
        return response

    # -- parameters -------------------------------------------------------------

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        for p in parameters:
            if p.name == 'input_timeout_s' and not math.isfinite(p.value):
                return SetParametersResult(
                    successful=False, reason=f'`input_timeout_s` must be finite, got {p.value!r}')
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        for p in parameters:
            if p.name == 'input_timeout_s':
                self._input_timeout_s = p.value

    def _diagnose(self, report: DiagnosticReport) -> None:
        """/diagnostics: step rate, steps behind, watchdog, held inputs, rejected inputs."""
        s = self._schedule
        behind = max(0, s.target(self._steady.now().nanoseconds) - s.steps_done)
        steps = report.delta('steps', s.steps_done)
        target_hz = self._rate_hz * self._real_time_factor
        achieved_hz = steps / report.period_s if report.period_s > 0.0 else 0.0
        bad = report.delta('bad_inputs', self._bad_input.total)
        report.add('rate_hz', self._rate_hz)
        report.add('real_time_factor', self._real_time_factor)
        report.add('target_step_rate_hz', target_hz)
        report.add('achieved_step_rate_hz', achieved_hz)
        report.add('sim_time_s', self.sim_time_s)
        report.add('steps_done', s.steps_done)
        report.add('steps_behind', behind)
        report.add('late_ticks_total', s.late_ticks)
        report.add('max_tick_gap_s', s.max_tick_gap_s)
        report.add('input_timeout_s', self._input_timeout_s)
        report.add('theta_rad', self._limb.theta_rad)
        report.add('external_torque_n_m', self._external_torque_n_m)
        for i, (name, u, tripped) in enumerate(zip(self._names, self._commands,
                                                   self._watchdog_tripped)):
            report.add(f'command[{name}]', commands_text(self._held[i]) if self._pulsed[i]
                       else u)
            report.add(f'watchdog_tripped[{name}]', tripped)
        report.add('resets_on_error_total', self._resets_on_error)
        report.add('bad_inputs_total', self._bad_input.total)
        for topic, count in sorted(self._bad_input.counts.items()):
            report.add(f'bad_inputs[{topic}]', count)
        if behind > self._error_behind_steps:
            report.error(f'{behind} steps behind the clock, more than {ERROR_BEHIND_S:g} s '
                         f'worth: not keeping up with {target_hz:g} steps/s')
        if steps < RATE_WARN_FRACTION * target_hz * report.period_s - self._steps_per_tick:
            report.warn(f'{achieved_hz:.1f} steps/s in the last {report.period_s:.2f} s, below '
                        f'{RATE_WARN_FRACTION:.0%} of {target_hz:g}')
        if any(self._watchdog_tripped):
            tripped = [n for n, t in zip(self._names, self._watchdog_tripped) if t]
            report.warn(f'stimulation watchdog tripped for {", ".join(tripped)}: command 0 '
                        '(every channel off)')
        if bad:
            report.warn(f'{bad} input message(s) rejected in the last {report.period_s:.2f} s')
        report.ok(f'stepping at {achieved_hz:.1f} steps/s of {target_hz:g}')

    def on_exit(self) -> None:
        """Log the run's timing statistics."""
        s = self._schedule
        elapsed_s = (self._steady.now().nanoseconds - s.start_ns) / NS_PER_S
        rclpy.logging.get_logger(f'{self.get_logger().name}.stats').info(
            f'ran {s.steps_done} steps in {elapsed_s:.3f} s of steady time, {s.ticks} ticks, '
            f'{s.late_ticks} late, longest gap between ticks {s.max_tick_gap_s * 1e3:.1f} ms, '
            f'{self._resets_on_error} resets on error')


def main(args: list[str] | None = None) -> int:
    """Entry point: ``limb_simulator [--ros-args ...]``; returns the exit status."""
    return run_node(LimbNode, args)


#: The console script (setup.py): main(), then the process ends at once.
process_main = process_entry(main)


if __name__ == '__main__':
    process_main()
