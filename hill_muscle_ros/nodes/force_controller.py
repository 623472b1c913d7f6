"""An example FES force controller node: closes the loop around the simulator.

Subscribes ``force_target`` [N], the simulator's ``force`` [N] and the
imposed ``length_command`` [m] (std_msgs/Float64) and publishes
``pulse_width`` [s] at ``rate_hz``, computed by
:class:`~hill_muscle_ros.control.ForceController` (feedforward plus PI with
anti-windup, clamped to [0, PW_max]). The default ``model`` feedforward
inverts a nominal muscle, declared with the simulator's parameter names (so
one ``--params-file`` configures both), at the imposed length and its rate.

It acts only on inputs it has received (:class:`~hill_muscle_ros.control.ControllerInputs`):
it publishes zero stimulation, and integrates nothing, until both a
``force_target`` and a ``force`` message have arrived; again whenever the
force is older than ``feedback_timeout_s`` (or, with ``target_timeout_s`` >
0, the target is older than that), with one warning per transition. A
control period without a new force sample holds the last pulse width. On
shutdown it publishes zero stimulation.

With ``modulate: frequency`` it publishes ``stimulation``
(``hill_muscle_interfaces/msg/Stimulation``) instead of ``pulse_width``:
channel 1, single pulses of the fixed width ``pulse_width_s``, at the frequency
the controller's output gives in [``frequency_min_hz``, ``frequency_max_hz``]
(:func:`~hill_muscle_ros.control.frequency_command`; an output of 0, and zero
stimulation, is pulse width 0). The range is checked at start-up, and on a
live change, against the ``stimulator`` of the nominal muscle.

Run: ``ros2 run hill_muscle_ros force_controller`` or ``hill-muscle controller``.
"""
from __future__ import annotations

import dataclasses

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from geometry_msgs.msg import PointStamped
from std_msgs.msg import Float64

from ..control import (ControllerInputs, ControllerParams, ForceController, ImposedLength,
                       check_frequency_range, frequency_command)
from ..model import MuscleParams
from ..model.muscle import check_dl_mt
from ..model.stimulator import stimulator_profile
from ..qos import OUTPUT_QOS, RELIABLE_QOS
from ..timebase import NS_PER_S
from ._diagnostics import DiagnosticReport, NodeDiagnostics
from ._inputs import BadInputWarner
from ._overrides import reject_unknown_overrides
from ._parameters import declare_checked, declare_spec_fields, field_descriptor
from ._process import StartupError, process_entry, run_node
from ._stimulation_send import STIMULATION_TOPIC, stimulation_message, stimulation_type
from ._topics import (FINAL_ACK_TIMEOUT_S, overridable_publisher, overridable_subscription,
                      publish_last)

NODE_NAME = 'force_controller'
#: Longest time step, in control periods, that one update integrates over.
MAX_DT_PERIODS = 2.0
#: The parameter that cannot change while the node runs although its
#: descriptor (a choice) does not say read-only: it chooses the output topic.
MODULATE = 'modulate'


class ForceControllerNode(Node):
    """ROS shell around :class:`ForceController`; all control logic lives there."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        values = declare_spec_fields(self, ControllerParams, read_only=('rate_hz',))
        # The nominal muscle of the model feedforward, under the simulator's
        # names; pw_max_s is the controller's own (the same stimulator).
        model_defaults, model_values = MuscleParams(), {}
        for f in dataclasses.fields(MuscleParams):
            if f.name != 'pw_max_s':
                model_values[f.name] = declare_checked(
                    self, f.name, getattr(model_defaults, f.name),
                    field_descriptor(f, note='nominal muscle of the model feedforward'))
        try:
            params = ControllerParams(**values)
            model = MuscleParams(**model_values, pw_max_s=params.pw_max_s)
            self.controller = ForceController(params, model)
            #: True with ``modulate: frequency``: Stimulation on ``stimulation``
            self.frequency_mode = params.modulate == 'frequency'
            if self.frequency_mode:
                check_frequency_range(params, stimulator_profile(model.stimulator,
                                                                 params.pw_max_s))
        except ValueError as err:
            raise StartupError(f'parameter {err}') from None
        reject_unknown_overrides(self)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._warner = BadInputWarner(self.get_logger())
        p = self.controller.params
        self.inputs = ControllerInputs(p.feedback_timeout_s, p.target_timeout_s)
        #: ControllerInputs.state of the last tick: a change is logged once.
        self.input_state = ControllerInputs.NO_TARGET
        self._last_tick_ns: int | None = None
        #: [s] the controller's output last published: the pulse width, or with
        #: ``modulate: frequency`` what :attr:`command` was made from
        self.pulse_width_s = 0.0
        #: ``modulate: frequency``: channel 1's command last published
        self.command = frequency_command(0.0, p) if self.frequency_mode else None
        if self.frequency_mode:
            self._pub = overridable_publisher(self, stimulation_type(), STIMULATION_TOPIC,
                                              OUTPUT_QOS)
        else:
            self._pub = overridable_publisher(self, Float64, 'pulse_width', OUTPUT_QOS)
        self._sub_target = overridable_subscription(self, Float64, 'force_target',
                                                    self._on_target, RELIABLE_QOS)
        self._sub_force = overridable_subscription(self, Float64, 'force', self._on_force,
                                                   RELIABLE_QOS)
        self._length = ImposedLength(p.length_rate_window_s, p.length_preview_s)
        self._sub_length = overridable_subscription(self, Float64, 'length_command',
                                                    self._on_length, RELIABLE_QOS)
        self._sub_length_stamped = overridable_subscription(
            self, PointStamped, 'length_command_stamped', self._on_length_stamped, RELIABLE_QOS)
        self.create_timer(1.0 / self.controller.params.rate_hz, self._on_tick)
        self._diagnostics = NodeDiagnostics(self, 'force control', self._diagnose)
        p = self.controller.params
        modulated = (f' (frequency modulation: channel 1 at {p.pulse_width_s:g} s, '
                     f'{p.frequency_min_hz:g}-{p.frequency_max_hz:g} Hz, checked against '
                     f'{self.controller.model.stimulator})' if self.frequency_mode else '')
        self.get_logger().info(
            f'controlling {self._sub_force.topic_name} to {self._sub_target.topic_name} on '
            f'{self._pub.topic_name}{modulated} at {p.rate_hz:g} Hz: kp {p.kp_s_per_n:g} s/N, '
            f'ki {p.ki_s_per_n_s:g} s/(N s), {p.feedforward} feedforward (length from '
            f'{self._sub_length.topic_name} or {self._sub_length_stamped.topic_name}), PW_max {p.pw_max_s:g} s, feedback timeout '
            f'{p.feedback_timeout_s:g} s')

    # -- inputs ---------------------------------------------------------------

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds / NS_PER_S

    def _on_target(self, msg: Float64) -> None:
        try:
            target_n = self.controller.check_target(msg.data)
        except ValueError as err:
            self._warner.warn(self._sub_target.topic_name,
                              f'ignoring {self._sub_target.topic_name} = {msg.data!r}: {err}; '
                              f'keeping {self.inputs.target_n!r} N')
            return
        self.inputs.set_target(target_n, self._now_s())

    def _on_force(self, msg: Float64) -> None:
        try:
            force_n = self.controller.check_force(msg.data)
        except ValueError as err:
            self._warner.warn(self._sub_force.topic_name,
                              f'ignoring {self._sub_force.topic_name} = {msg.data!r}: {err}; '
                              f'keeping {self.inputs.force_n!r} N')
            return
        self.inputs.set_force(force_n, self._now_s())

    def _on_length(self, msg: Float64) -> None:
        try:
            dl_mt_m = check_dl_mt(msg.data, 'length_command')
        except ValueError as err:
            self._warner.warn(self._sub_length.topic_name,
                              f'ignoring {self._sub_length.topic_name} = {msg.data!r}: {err}; '
                              f'keeping {self._length.plain.dl_mt_m!r} m')
            return
        self._length.add_sample(self.get_clock().now().nanoseconds / NS_PER_S, dl_mt_m)

    def _on_length_stamped(self, msg: PointStamped) -> None:
        stamp_s = msg.header.stamp.sec + msg.header.stamp.nanosec / NS_PER_S
        try:
            self._length.add_knot(stamp_s, msg.point.x,
                                  self.get_clock().now().nanoseconds / NS_PER_S)
        except ValueError as err:
            topic = self._sub_length_stamped.topic_name
            self._warner.warn(topic, f'ignoring {topic} = {msg.point.x!r} at {stamp_s!r} s: '
                                     f'{err}; keeping {self._length.plain.dl_mt_m!r} m')

    def _on_set_parameters(self, params) -> SetParametersResult:
        """Gains and the nominal muscle change live; a bad value is rejected by name."""
        changes = {p.name: p.value for p in params
                   if p.name in ControllerParams.__dataclass_fields__}
        model_changes = {p.name: p.value for p in params
                         if p.name in MuscleParams.field_names() and p.name != 'pw_max_s'}
        if not (changes or model_changes):
            return SetParametersResult(successful=True)
        if changes.get(MODULATE, self.controller.params.modulate) != \
                self.controller.params.modulate:
            return SetParametersResult(successful=False, reason=(
                f'`{MODULATE}` is read-only: it chooses the output topic at start-up '
                f'({self._pub.topic_name}); restart the node to change it'))
        try:
            new = dataclasses.replace(self.controller.params, **changes)
            model = self.controller.model.replace(**model_changes, pw_max_s=new.pw_max_s)
            if self.frequency_mode:
                check_frequency_range(new, stimulator_profile(model.stimulator, new.pw_max_s))
        except (ValueError, TypeError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        self.controller.params, self.controller.model = new, model
        self.inputs.feedback_timeout_s = new.feedback_timeout_s
        self.inputs.target_timeout_s = new.target_timeout_s
        self._length.plain.window_s = new.length_rate_window_s
        self._length.preview_s = new.length_preview_s
        return SetParametersResult(successful=True)

    # -- output -----------------------------------------------------------------

    def _on_tick(self) -> None:
        now_ns = self.get_clock().now().nanoseconds
        p = self.controller.params
        # After a stall of this process the force read now says nothing about
        # the gap: integrate over at most a couple of periods, not the whole gap.
        dt_s = (1.0 / p.rate_hz if self._last_tick_ns is None
                else min((now_ns - self._last_tick_ns) / NS_PER_S,
                         MAX_DT_PERIODS / p.rate_hz))
        self._last_tick_ns = now_ns
        now_s = now_ns / NS_PER_S
        state = self.inputs.state(now_s)
        self._log_transition(state, p)
        self.input_state = state
        if state != ControllerInputs.READY:
            # Nothing made up: no stimulation and no integral on inputs never heard.
            self.controller.reset()
            self.inputs.take_new_force()
            self._publish(0.0)
            return
        if dt_s <= 0.0 or not self.inputs.take_new_force():
            # Sim time paused, or no new force since the last period (a plant
            # briefly late): hold, rather than integrate the old error again.
            self._publish(self.pulse_width_s)
            return
        dl_mt_m, rate = self._length.at(now_s)
        self._publish(self.controller.update(self.inputs.target_n, self.inputs.force_n, dt_s,
                                             dl_mt_m, rate))

    def _diagnose(self, report: DiagnosticReport) -> None:
        """/diagnostics: the input state, the ages of target and feedback against
        their timeouts, the pulse width sent and the inputs rejected. OK while
        stimulating or idle without a target; WARN when a target is set but the
        feedback is missing or stale, when the target went stale, or when inputs
        were rejected in the last period."""
        p = self.controller.params
        inputs = self.inputs
        now_s = self._now_s()
        state = inputs.state(now_s)
        target_age_s = None if inputs.target_t_s is None else now_s - inputs.target_t_s
        feedback_age_s = None if inputs.force_t_s is None else now_s - inputs.force_t_s
        report.add('state', state)
        report.add('target_received', inputs.target_n is not None)
        report.add('target_n', inputs.target_n)
        report.add('target_age_s', target_age_s)
        report.add('target_timeout_s', p.target_timeout_s)
        report.add('feedback_received', inputs.force_t_s is not None)
        report.add('force_n', inputs.force_n)
        report.add('feedback_age_s', feedback_age_s)
        report.add('feedback_timeout_s', p.feedback_timeout_s)
        report.add('pulse_width_s', self.pulse_width_s)
        report.add('stimulating', self.pulse_width_s > 0.0)
        if self.frequency_mode:
            report.add('modulate', p.modulate)
            report.add('frequency_hz', self.command.frequency_hz)
        bad_period = report.delta('bad_inputs', self._warner.total)
        report.add('bad_inputs_total', self._warner.total)
        report.add('bad_inputs_last_period', bad_period)
        for topic, n in sorted(self._warner.counts.items()):
            report.add(f'bad_inputs[{topic}]', n)
        if state == ControllerInputs.READY and self.frequency_mode:
            report.ok(f'controlling: target {inputs.target_n:g} N, force {inputs.force_n:g} N, '
                      f'channel 1 at {self.command.pulse_width_s:g} s, '
                      f'{self.command.frequency_hz:g} Hz')
        elif state == ControllerInputs.READY:
            report.ok(f'controlling: target {inputs.target_n:g} N, force {inputs.force_n:g} N, '
                      f'pulse_width {self.pulse_width_s:g} s')
        elif state == ControllerInputs.NO_TARGET:
            report.ok(f'idle: no {self._sub_target.topic_name} received yet, zero stimulation')
        elif state == ControllerInputs.STALE_FEEDBACK:
            report.warn(f'force feedback on {self._sub_force.topic_name} is {feedback_age_s:.3g} '
                        f's old (feedback_timeout_s {p.feedback_timeout_s:g} s): zero stimulation')
        elif state == ControllerInputs.STALE_TARGET:
            report.warn(f'{self._sub_target.topic_name} is {target_age_s:.3g} s old '
                        f'(target_timeout_s {p.target_timeout_s:g} s): zero stimulation')
        else:
            report.warn(f'{state} on {self._sub_force.topic_name}: zero stimulation')
        if bad_period:
            report.warn(f'{bad_period} input message(s) rejected in the last '
                        f'{report.period_s:.1f} s')

    #: What returned, by the stale state it ends.
    _BACK = {ControllerInputs.STALE_FEEDBACK: 'force feedback',
             ControllerInputs.STALE_TARGET: 'force_target'}

    def _log_transition(self, state: str, p: ControllerParams) -> None:
        """One log line when the input state changes."""
        if state == self.input_state:
            return
        log = self.get_logger()
        if state == ControllerInputs.STALE_FEEDBACK:
            log.warning(f'no force feedback on {self._sub_force.topic_name} for more than '
                        f'{p.feedback_timeout_s:g} s (feedback_timeout_s): stimulation stopped '
                        'until it returns')
        elif state == ControllerInputs.STALE_TARGET:
            log.warning(f'no {self._sub_target.topic_name} for more than '
                        f'{p.target_timeout_s:g} s (target_timeout_s): stimulation stopped '
                        'until the next target')
        elif state == ControllerInputs.READY and self.input_state in self._BACK:
            log.info(f'{self._BACK[self.input_state]} is back: stimulating again')
        elif state == ControllerInputs.READY:
            # Not "stimulating": a force sample used up while waiting for the
            # target is not used again, so the output stays 0 until the next.
            log.info(f'target {self.inputs.target_n:g} N and force feedback received: '
                     'controlling (each new force sample updates the pulse width)')
        else:
            log.info(f'not stimulating: {state}')

    def _publish(self, pulse_width_s: float) -> None:
        self.pulse_width_s = pulse_width_s
        if self.frequency_mode:
            self._pub.publish(self._stimulation(pulse_width_s))
            return
        self._pub.publish(Float64(data=pulse_width_s))

    def _stimulation(self, output_s: float):
        """``modulate: frequency``: the Stimulation for the controller's output
        ``output_s`` [s] (:func:`frequency_command`), stamped now; kept as :attr:`command`."""
        self.command = frequency_command(output_s, self.controller.params)
        return stimulation_message((self.command,), self.get_clock().now().nanoseconds)

    def on_exit(self) -> None:
        """Leave the muscle unstimulated: a controller that stops must say 0."""
        try:
            self.pulse_width_s = 0.0
            zero = self._stimulation(0.0) if self.frequency_mode else Float64(data=0.0)
            if not publish_last([(self._pub, zero)]):
                self.get_logger().debug('zero stimulation on exit not acknowledged within '
                                        f'{FINAL_ACK_TIMEOUT_S:g} s on {self._pub.topic_name}')
        except Exception as err:  # noqa: BLE001 - the context may already be down
            self.get_logger().warning(f'could not publish zero stimulation on exit: {err}')


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run hill_muscle_ros force_controller``."""
    return run_node(ForceControllerNode, args)


#: The console script (setup.py): main(), then the process ends at once.
process_main = process_entry(main)


if __name__ == '__main__':
    process_main()
