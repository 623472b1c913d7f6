"""The bag reader gives a sensor_msgs/JointState's first position as its value.

The limb node publishes its one joint's angle as ``position[0]`` of
``joint_states``; ``make demo-knee`` plots it from the bag through
:meth:`~hill_muscle_ros.recording.reader.TopicData.values`.
"""
import pytest
from rclpy.qos import QoSProfile
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from hill_muscle_ros.recording.bag_writer import BagWriter
from hill_muscle_ros.recording.reader import read_bag
from hill_muscle_ros.timebase import NS_PER_S

TOPIC = '/joint_states'
TYPE = 'sensor_msgs/msg/JointState'
#: [ns] 1 kHz, the limb node's step rate
DT_NS = 1_000_000
ANGLES_RAD = [0.0, 0.125, -0.25, 1.5]


def _state(k: int, position: list[float]) -> JointState:
    msg = JointState()
    msg.header.stamp.sec = k * DT_NS // NS_PER_S
    msg.header.stamp.nanosec = k * DT_NS % NS_PER_S
    msg.name = ['knee'] if position else []
    msg.position = position
    msg.velocity = [2.0 * p for p in position]
    return msg


def _bag(path, positions: list[list[float]]):
    with BagWriter(path) as writer:
        writer.add_topic(TOPIC, TYPE, offered_qos_profiles=[QoSProfile(depth=10)])
        for k, position in enumerate(positions):
            writer.write(TOPIC, serialize_message(_state(k, position)), k * DT_NS + 5, k * DT_NS)
    return read_bag(path).topic('joint_states')


def test_joint_state_value_is_the_first_position_and_stamps_are_the_headers(tmp_path):
    topic = _bag(tmp_path / 'bag', [[a] for a in ANGLES_RAD])
    assert topic.type == TYPE
    assert list(topic.values()) == ANGLES_RAD
    assert list(topic.stamps_ns()) == [k * DT_NS for k in range(len(ANGLES_RAD))]


def test_joint_state_without_a_position_is_an_error_naming_the_topic_and_message(tmp_path):
    topic = _bag(tmp_path / 'bag', [[0.5], []])
    with pytest.raises(ValueError, match=r'/joint_states: message 1 has no position'):
        topic.values()
