"""An example FES joint-angle controller node: closes the loop around the limb.

Subscribes ``angle_target`` (std_msgs/Float64, rad) and ``joint_states``
(sensor_msgs/JointState, the plant's joint by name) and publishes each
muscle's ``<muscle>/pulse_width`` [s] at ``control_rate_hz``, computed by
:class:`~hill_muscle_ros.control.joint.JointController` (model feedforward
plus PID with anti-windup, allocated to the extensors or the flexors). The
plant file that configures the limb node configures this one too
(``--params-file``): it is the controller's model of the limb.

It acts only on inputs it has received
(:class:`~hill_muscle_ros.control.joint.JointInputs`): it publishes zero
stimulation, and integrates nothing, until both an ``angle_target`` and a
joint state have arrived; again whenever the joint state is older than
``feedback_timeout_s`` (or, with ``target_timeout_s`` > 0, the target is
older than that), with one log line per transition. A control period without
a new joint state holds the last pulse widths. On shutdown it publishes zero
stimulation and waits for it to be acknowledged.

Run: ``ros2 run hill_muscle_ros joint_controller --ros-args --params-file
config/knee.yaml`` or ``hill-muscle joint-controller --ros-args ...``.
"""
from __future__ import annotations

import dataclasses

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from ..control.joint import JointController, JointControllerParams, JointInputs
from ..model.limb import LimbPlant
from ..qos import OUTPUT_QOS, RELIABLE_QOS
from ..timebase import NS_PER_S
from ._diagnostics import DiagnosticReport, NodeDiagnostics
from ._inputs import BadInputWarner
from ._overrides import LIMB_NODE_PARAMETERS, declare_plant, plant_values, require_muscles
from ._parameters import declare_spec_fields, parameter_overrides
from ._process import StartupError, process_entry, run_node
from ._topics import (FINAL_ACK_TIMEOUT_S, QOS_OVERRIDES_PREFIX, check_qos_overrides,
                      overridable_publisher, overridable_subscription, publish_last)

NODE_NAME = 'joint_controller'
#: Longest time step, in control periods, that one update integrates over.
MAX_DT_PERIODS = 2.0


class JointControllerNode(Node):
    """ROS shell around :class:`JointController`; all control logic lives there.

    :raises StartupError: on an invalid parameter or plant at start-up
    """

    NODE_NAME = NODE_NAME

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        values = declare_spec_fields(self, JointControllerParams, read_only=('control_rate_hz',))
        overrides = parameter_overrides(self)
        # A shared plant file carries the limb node's parameters too.
        plant = plant_values(overrides, tuple(values) + LIMB_NODE_PARAMETERS)
        try:
            params = JointControllerParams(**values)
            self._plant = LimbPlant.from_mapping(plant, source='plant parameters')
            require_muscles(self._plant)
            self.controller = JointController(self._plant, params)
        except ValueError as err:
            raise StartupError(str(err)) from None
        declare_plant(self, plant)
        names = [m.name for m in self._plant.muscles]
        check_qos_overrides(self, [n for n in overrides if n.startswith(QOS_OVERRIDES_PREFIX)],
                            {self.resolve_topic_name(t)
                             for t in ['angle_target', 'joint_states',
                                       *(f'{n}/pulse_width' for n in names)]})
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._joint = self._plant.joint.name
        self._names = names
        self._warner = BadInputWarner(self.get_logger())
        self.inputs = JointInputs(params.feedback_timeout_s, params.target_timeout_s)
        #: JointInputs.state of the last tick: a change is logged once.
        self.input_state = JointInputs.NO_TARGET
        self._last_tick_ns: int | None = None
        #: [s] the pulse widths last published, in the plant's order
        self.pulse_widths_s = [0.0] * len(names)
        self._pubs = [overridable_publisher(self, Float64, f'{n}/pulse_width', OUTPUT_QOS)
                      for n in names]
        self._sub_target = overridable_subscription(self, Float64, 'angle_target',
                                                    self._on_target, RELIABLE_QOS)
        self._sub_joint = overridable_subscription(self, JointState, 'joint_states',
                                                   self._on_joint_states, RELIABLE_QOS)
        self.create_timer(1.0 / params.control_rate_hz, self._on_tick)
        self._diagnostics = NodeDiagnostics(self, 'joint control', self._diagnose)
        self.get_logger().info(
            f'controlling {self._joint} on {self._sub_joint.topic_name} to '
            f'{self._sub_target.topic_name} with {", ".join(names)} at '
            f'{params.control_rate_hz:g} Hz: kp {params.kp_n_m_per_rad:g} N m/rad, ki '
            f'{params.ki_n_m_per_rad_s:g} N m/(rad s), kd {params.kd_n_m_s_per_rad:g} N m s/rad, '
            f'{params.feedforward} feedforward, feedback timeout {params.feedback_timeout_s:g} s')

    # -- inputs -----------------------------------------------------------------

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds / NS_PER_S

    def _on_target(self, msg: Float64) -> None:
        topic = self._sub_target.topic_name
        try:
            target = JointController.check_angle(msg.data, topic)
        except ValueError as err:
            self._warner.warn(topic, f'ignoring {topic} = {msg.data!r}: {err}; keeping '
                                     f'{self.inputs.target_rad!r} rad')
            return
        self.inputs.set_target(target, self._now_s())

    def _on_joint_states(self, msg: JointState) -> None:
        topic = self._sub_joint.topic_name
        try:
            if self._joint not in msg.name:
                raise ValueError(f'no joint {self._joint!r} in `name` {list(msg.name)!r}')
            i = list(msg.name).index(self._joint)
            # JointState's arrays match its names (or are empty): with more
            # positions than names, which one is the joint's is anyone's guess.
            if not len(msg.name) == len(msg.position) == len(msg.velocity):
                raise ValueError(f'{self._joint!r} needs a position and a velocity, one per '
                                 f'name, got '
                                 f'{len(msg.position)} position(s) and {len(msg.velocity)} '
                                 f'velocity(ies) for {len(msg.name)} name(s)')
            theta = JointController.check_angle(msg.position[i], f'{topic}.position')
            omega = JointController.check_velocity(msg.velocity[i], f'{topic}.velocity')
        except ValueError as err:
            self._warner.warn(topic, f'ignoring {topic}: {err}; keeping angle '
                                     f'{self.inputs.theta_rad!r} rad')
            return
        self.inputs.set_joint_state(theta, omega, self._now_s())

    def _on_set_parameters(self, params) -> SetParametersResult:
        """Gains change live; a bad value is rejected by name, nothing changes."""
        changes = {p.name: p.value for p in params
                   if p.name in JointControllerParams.__dataclass_fields__}
        if not changes:
            return SetParametersResult(successful=True)
        try:
            new = dataclasses.replace(self.controller.params, **changes)
        except (ValueError, TypeError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        self.controller.params = new
        self.inputs.feedback_timeout_s = new.feedback_timeout_s
        self.inputs.target_timeout_s = new.target_timeout_s
        return SetParametersResult(successful=True)

    # -- output -----------------------------------------------------------------

    def _on_tick(self) -> None:
        now_ns = self.get_clock().now().nanoseconds
        p = self.controller.params
        # After a stall of this process the state read now says nothing about
        # the gap: integrate over at most a couple of periods.
        dt_s = (1.0 / p.control_rate_hz if self._last_tick_ns is None
                else min((now_ns - self._last_tick_ns) / NS_PER_S,
                         MAX_DT_PERIODS / p.control_rate_hz))
        self._last_tick_ns = now_ns
        state = self.inputs.state(now_ns / NS_PER_S)
        self._log_transition(state, p)
        self.input_state = state
        if state != JointInputs.READY:
            # Nothing made up: no stimulation and no integral on inputs never heard.
            self.controller.reset()
            self.inputs.take_new_force()
            self._publish([0.0] * len(self._names))
            return
        if dt_s <= 0.0 or not self.inputs.take_new_force():
            # Sim time paused, or no new joint state since the last period: hold.
            self._publish(self.pulse_widths_s)
            return
        self._publish(self.controller.update(self.inputs.target_rad, self.inputs.theta_rad,
                                             self.inputs.omega_rad_per_s, dt_s))

    def _publish(self, widths: list[float]) -> None:
        self.pulse_widths_s = list(widths)
        for pub, w in zip(self._pubs, widths):
            pub.publish(Float64(data=w))

    def _diagnose(self, report: DiagnosticReport) -> None:
        """/diagnostics: input state, ages against timeouts, pulse widths, rejected inputs."""
        p = self.controller.params
        inputs = self.inputs
        now_s = self._now_s()
        state = inputs.state(now_s)
        report.add('state', state)
        report.add('target_rad', inputs.target_rad)
        report.add('target_age_s', None if inputs.target_t_s is None
                   else now_s - inputs.target_t_s)
        report.add('theta_rad', inputs.theta_rad)
        report.add('feedback_age_s', None if inputs.force_t_s is None
                   else now_s - inputs.force_t_s)
        report.add('feedback_timeout_s', p.feedback_timeout_s)
        report.add('torque_n_m', self.controller.torque_n_m)
        report.add('integral_n_m', self.controller.integral_n_m)
        for name, w in zip(self._names, self.pulse_widths_s):
            report.add(f'pulse_width_s[{name}]', w)
        bad = report.delta('bad_inputs', self._warner.total)
        report.add('bad_inputs_total', self._warner.total)
        for topic, n in sorted(self._warner.counts.items()):
            report.add(f'bad_inputs[{topic}]', n)
        if state == JointInputs.READY:
            report.ok(f'controlling {self._joint}: target {inputs.target_rad:.4g} rad, angle '
                      f'{inputs.theta_rad:.4g} rad')
        elif state in (JointInputs.NO_TARGET, JointInputs.NO_FEEDBACK):
            report.ok(f'idle: {state}, zero stimulation')
        else:
            report.warn(f'{state}: zero stimulation')
        if bad:
            report.warn(f'{bad} input message(s) rejected in the last '
                        f'{report.period_s:.1f} s')

    def _log_transition(self, state: str, p: JointControllerParams) -> None:
        """One log line when the input state changes."""
        if state == self.input_state:
            return
        log = self.get_logger()
        if state == JointInputs.STALE_FEEDBACK:
            log.warning(f'no {self._sub_joint.topic_name} for more than '
                        f'{p.feedback_timeout_s:g} s (feedback_timeout_s): stimulation stopped '
                        'until it returns')
        elif state == JointInputs.STALE_TARGET:
            log.warning(f'no {self._sub_target.topic_name} for more than '
                        f'{p.target_timeout_s:g} s (target_timeout_s): stimulation stopped '
                        'until the next target')
        elif state == JointInputs.READY:
            # Not "stimulating": a joint state used up while waiting for the
            # target is not used again, so the outputs stay 0 until the next.
            log.info(f'target {self.inputs.target_rad:.4g} rad and joint state received: '
                     'controlling (each new joint state updates the pulse widths)')
        else:
            log.info(f'not stimulating: {state}')

    def on_exit(self) -> None:
        """Leave the muscles unstimulated: a controller that stops must say 0."""
        try:
            self.pulse_widths_s = [0.0] * len(self._names)
            if not publish_last([(pub, Float64(data=0.0)) for pub in self._pubs]):
                self.get_logger().debug('zero stimulation on exit not acknowledged within '
                                        f'{FINAL_ACK_TIMEOUT_S:g} s')
        except Exception as err:  # noqa: BLE001 - the context may already be down
            self.get_logger().warning(f'could not publish zero stimulation on exit: {err}')


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run hill_muscle_ros joint_controller``."""
    return run_node(JointControllerNode, args)


#: The console script (setup.py): main(), then the process ends at once.
process_main = process_entry(main)


if __name__ == '__main__':
    process_main()
