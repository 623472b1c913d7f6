"""Smoke check of a built hill_muscle_interfaces: one Stimulation through DDS and CDR.

Run with the install on PYTHONPATH, AMENT_PREFIX_PATH and LD_LIBRARY_PATH (see
README.md). A publishing node sends one Stimulation to a subscribing node in the
same process over DDS (ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE as the
caller sets them), and the message is serialized with rclpy.serialization and
deserialized back. Exits 0 when both give back the message that was sent, 1
otherwise.
"""
import math
import os
import sys
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy, DurabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rclpy.utilities import get_rmw_implementation_identifier

from hill_muscle_interfaces.msg import Stimulation


def sample() -> Stimulation:
    msg = Stimulation()
    msg.header.frame_id = 'roundtrip'
    msg.header.stamp.sec = 12
    msg.header.stamp.nanosec = 345
    msg.channel = [1, 2]
    msg.mode = ['single', 'doublet']
    msg.pulse_width_s = [300e-6, 250e-6]
    msg.current_a = [0.030, 0.025]
    msg.frequency_hz = [30.0, 20.0]
    return msg


def same(a: Stimulation, b: Stimulation) -> bool:
    def close(x, y):
        return len(x) == len(y) and all(math.isclose(p, q) for p, q in zip(x, y))
    return (a.header == b.header and list(a.channel) == list(b.channel)
            and list(a.mode) == list(b.mode) and close(a.pulse_width_s, b.pulse_width_s)
            and close(a.current_a, b.current_a) and close(a.frequency_hz, b.frequency_hz))


def main() -> int:
    sent = sample()

    data = serialize_message(sent)
    back = deserialize_message(data, Stimulation)
    serial_ok = same(sent, back)
    print(f'serialization: {len(data)} bytes, round trip {"ok" if serial_ok else "FAILED"}')

    rclpy.init()
    received = []
    try:
        talker = rclpy.create_node('stimulation_talker')
        listener = rclpy.create_node('stimulation_listener')
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        listener.create_subscription(Stimulation, 'stimulation_roundtrip', received.append, qos)
        pub = talker.create_publisher(Stimulation, 'stimulation_roundtrip', qos)
        executor = SingleThreadedExecutor()
        executor.add_node(talker)
        executor.add_node(listener)
        print(f'rmw: {get_rmw_implementation_identifier()}, '
              f'ROS_DOMAIN_ID={os.environ.get("ROS_DOMAIN_ID", "0 (unset)")}')
        pub.publish(sent)
        deadline = time.monotonic() + 10.0
        while not received and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        executor.shutdown()
        talker.destroy_node()
        listener.destroy_node()
    finally:
        rclpy.shutdown()
    dds_ok = bool(received) and same(sent, received[0])
    if received:
        print(f'dds: received {received[0]}')
    print(f'dds: round trip {"ok" if dds_ok else "FAILED (nothing received in 10 s)" if not received else "FAILED (message differs)"}')
    return 0 if serial_ok and dds_ok else 1


if __name__ == '__main__':
    sys.exit(main())
