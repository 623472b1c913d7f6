"""An example FES force controller node: closes the loop around the simulator.

Subscribes ``force_target`` [N], the simulator's ``force`` [N] and the
imposed ``length_command`` [m] (std_msgs/Float64) and publishes
``pulse_width`` [s] at ``rate_hz``, computed by
:class:`~hill_muscle_ros.control.ForceController` (feedforward plus PI with
anti-windup, clamped to [0, PW_max]). The default ``model`` feedforward
inverts a nominal muscle, declared with the simulator's parameter names (so
one ``--params-file`` configures both), at the imposed length and its rate.
With no force feedback for ``feedback_timeout_s`` it stops stimulating and
warns; on shutdown it publishes zero stimulation.

Run: ``ros2 run hill_muscle_ros force_controller`` or ``hill-muscle controller``.
"""
from __future__ import annotations

import dataclasses
import sys

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from geometry_msgs.msg import PointStamped
from std_msgs.msg import Float64

from ..control import ControllerParams, ForceController, ImposedLength
from ..model import MuscleParams
from ..model.muscle import check_dl_mt
from ._common import (OUTPUT_QOS, RELIABLE_QOS, BadInputWarner, StartupError,
                      declare_checked, field_descriptor, number_descriptor,
                      reject_unknown_overrides, run_node)

NODE_NAME = 'force_controller'
_NS_PER_S = 1e9
#: Longest time step, in control periods, that one update integrates over.
MAX_DT_PERIODS = 2.0


class ForceControllerNode(Node):
    """ROS shell around :class:`ForceController`; all control logic lives there."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        defaults = ControllerParams()
        values = {}
        for f in dataclasses.fields(ControllerParams):
            spec = f.metadata
            if spec['choices'] is not None:
                descriptor = ParameterDescriptor(
                    description=spec['description'],
                    additional_constraints=f'one of: {", ".join(spec["choices"])}')
            else:
                descriptor = number_descriptor(spec['description'], spec['unit'], spec['low'],
                                               spec['high'], read_only=f.name == 'rate_hz')
            values[f.name] = declare_checked(self, f.name, getattr(defaults, f.name), descriptor)
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
        except ValueError as err:
            raise StartupError(f'parameter {err}') from None
        reject_unknown_overrides(self)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._warner = BadInputWarner(self.get_logger())
        self._target_n = 0.0
        self._force_n: float | None = None
        self._force_stamp_ns: int | None = None
        self._last_tick_ns: int | None = None
        self._starved = False
        p = self.controller.params
        self._pub = self.create_publisher(Float64, 'pulse_width', OUTPUT_QOS)
        self._sub_target = self.create_subscription(Float64, 'force_target', self._on_target,
                                                    RELIABLE_QOS)
        self._sub_force = self.create_subscription(Float64, 'force', self._on_force,
                                                   RELIABLE_QOS)
        self._length = ImposedLength(p.length_rate_window_s, p.length_preview_s)
        self._sub_length = self.create_subscription(Float64, 'length_command',
                                                    self._on_length, RELIABLE_QOS)
        self._sub_length_stamped = self.create_subscription(
            PointStamped, 'length_command_stamped', self._on_length_stamped, RELIABLE_QOS)
        self.create_timer(1.0 / self.controller.params.rate_hz, self._on_tick)
        p = self.controller.params
        self.get_logger().info(
            f'controlling {self._sub_force.topic_name} to {self._sub_target.topic_name} on '
            f'{self._pub.topic_name} at {p.rate_hz:g} Hz: kp {p.kp_s_per_n:g} s/N, '
            f'ki {p.ki_s_per_n_s:g} s/(N s), {p.feedforward} feedforward (length from '
            f'{self._sub_length.topic_name} or {self._sub_length_stamped.topic_name}), PW_max {p.pw_max_s:g} s, feedback timeout '
            f'{p.feedback_timeout_s:g} s')

    # -- inputs ---------------------------------------------------------------

    def _on_target(self, msg: Float64) -> None:
        try:
            self._target_n = self.controller.check_target(msg.data)
        except ValueError as err:
            self._warner.warn(self._sub_target.topic_name,
                              f'ignoring {self._sub_target.topic_name} = {msg.data!r}: {err}; '
                              f'keeping {self._target_n!r} N')

    def _on_force(self, msg: Float64) -> None:
        try:
            self._force_n = self.controller.check_force(msg.data)
        except ValueError as err:
            self._warner.warn(self._sub_force.topic_name,
                              f'ignoring {self._sub_force.topic_name} = {msg.data!r}: {err}; '
                              f'keeping {self._force_n!r} N')
            return
        self._force_stamp_ns = self.get_clock().now().nanoseconds

    def _on_length(self, msg: Float64) -> None:
        try:
            dl_mt_m = check_dl_mt(msg.data, 'length_command')
        except ValueError as err:
            self._warner.warn(self._sub_length.topic_name,
                              f'ignoring {self._sub_length.topic_name} = {msg.data!r}: {err}; '
                              f'keeping {self._length.plain.dl_mt_m!r} m')
            return
        self._length.add_sample(self.get_clock().now().nanoseconds / _NS_PER_S, dl_mt_m)

    def _on_length_stamped(self, msg: PointStamped) -> None:
        stamp_s = msg.header.stamp.sec + msg.header.stamp.nanosec / _NS_PER_S
        try:
            self._length.add_knot(stamp_s, msg.point.x,
                                  self.get_clock().now().nanoseconds / _NS_PER_S)
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
        try:
            new = dataclasses.replace(self.controller.params, **changes)
            model = self.controller.model.replace(**model_changes, pw_max_s=new.pw_max_s)
        except (ValueError, TypeError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        self.controller.params, self.controller.model = new, model
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
                else min((now_ns - self._last_tick_ns) / _NS_PER_S,
                         MAX_DT_PERIODS / p.rate_hz))
        self._last_tick_ns = now_ns
        fresh = (self._force_stamp_ns is not None
                 and (now_ns - self._force_stamp_ns) / _NS_PER_S <= p.feedback_timeout_s)
        if not fresh:
            if not self._starved and self._force_stamp_ns is not None:
                self.get_logger().warning(
                    f'no force feedback for more than {p.feedback_timeout_s} s: '
                    f'stimulation stopped until it returns')
            self._starved = self._force_stamp_ns is not None
            self.controller.reset()
            self._publish(0.0)
            return
        if self._starved:
            self.get_logger().info('force feedback is back: stimulating again')
            self._starved = False
        if dt_s <= 0.0:
            return  # sim time paused or went back: nothing to integrate over
        dl_mt_m, rate = self._length.at(now_ns / _NS_PER_S)
        self._publish(self.controller.update(self._target_n, self._force_n, dt_s,
                                             dl_mt_m, rate))

    def _publish(self, pulse_width_s: float) -> None:
        self._pub.publish(Float64(data=pulse_width_s))

    def on_exit(self) -> None:
        """Leave the muscle unstimulated: a controller that stops must say 0."""
        try:
            self._publish(0.0)
        except Exception as err:  # noqa: BLE001 - the context may already be down
            self.get_logger().warning(f'could not publish zero stimulation on exit: {err}')


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run hill_muscle_ros force_controller``."""
    return run_node(ForceControllerNode, args)


if __name__ == '__main__':
    sys.exit(main())
