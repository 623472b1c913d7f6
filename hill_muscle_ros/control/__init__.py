"""Example FES controllers (pure Python; the ROS nodes wrap them): force
control of one muscle, and joint-angle control of a limb."""
from .joint import (JOINT_CONTROLLER_KEYS, JointController, JointControllerParams, JointInputs,
                    simulate_joint_control)
from .pi import (FEEDFORWARD_CHOICES, MODULATE_CHOICES, ControllerInputs, ControllerParams,
                 ForceController, ImposedLength, LengthRate, check_frequency_range,
                 frequency_command, pulse_width_within)

__all__ = ['FEEDFORWARD_CHOICES', 'JOINT_CONTROLLER_KEYS', 'MODULATE_CHOICES',
           'ControllerInputs', 'ControllerParams', 'ForceController', 'ImposedLength',
           'JointController', 'JointControllerParams', 'JointInputs', 'LengthRate',
           'check_frequency_range', 'frequency_command', 'pulse_width_within',
           'simulate_joint_control']
