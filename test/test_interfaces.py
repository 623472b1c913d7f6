"""The message package hill_muscle_interfaces, built from the ROS 2 wheels by
`make interfaces` (hill_muscle_interfaces/build.sh), imports in the venv with no
environment variable and carries a multi-channel stimulation command."""
from rclpy.serialization import deserialize_message, serialize_message

from hill_muscle_interfaces.msg import Stimulation

#: The fields of msg/Stimulation.msg, in order, with their ROS types.
FIELDS = {
    'header': 'std_msgs/Header',
    'channel': 'sequence<uint8>',
    'mode': 'sequence<string>',
    'pulse_width_s': 'sequence<double>',
    'current_a': 'sequence<double>',
    'frequency_hz': 'sequence<double>',
}


def test_stimulation_has_the_fields_of_the_specification_in_order():
    assert Stimulation.get_fields_and_field_types() == FIELDS
    assert list(Stimulation.get_fields_and_field_types()) == list(FIELDS)


def test_a_four_channel_command_survives_serialization():
    msg = Stimulation()
    msg.header.frame_id = 'quadriceps'
    msg.channel = [1, 2, 3, 4]
    msg.mode = ['single', 'doublet', 'triplet', 'single']
    msg.pulse_width_s = [0.0002, 0.00015, 0.000131, 0.0]
    msg.current_a = [0.05, 0.05, 0.06, 0.0]
    msg.frequency_hz = [11.5, 30.0, 60.0, 20.0]
    back = deserialize_message(serialize_message(msg), Stimulation)
    assert back == msg
    assert list(back.channel) == [1, 2, 3, 4]
    assert list(back.frequency_hz) == [11.5, 30.0, 60.0, 20.0]


def test_the_current_may_be_left_empty_for_the_reference_current():
    msg = Stimulation(channel=[1], mode=['single'], pulse_width_s=[0.0003], frequency_hz=[30.0])
    back = deserialize_message(serialize_message(msg), Stimulation)
    assert len(back.current_a) == 0 and list(back.pulse_width_s) == [0.0003]
