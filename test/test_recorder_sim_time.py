"""The recorder on sim time stamps a message with the sim time in force when
DDS received it, not when the node took it.

The recorder runs in this process and is never spun: its clock (rclpy's time
source) stays at 0, as a recorder's clock stays behind while its executor
waits for a CPU. A probe publishes ``/clock`` and ``force`` in turn, each one
received before the next is sent (the recorder has taken the ``/clock``
message; the force message is acknowledged), then the recorder takes the two
force messages at once: each gets the sim time of the ``/clock`` message before
it. Read back with rosbags' AnyReader, a reader independent of the package.
"""
from __future__ import annotations

import os

import pytest
import rclpy
from rclpy.duration import Duration
from rosbags.highlevel import AnyReader
from builtin_interfaces.msg import Time
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64

from hill_muscle_ros.nodes import recorder as recorder_mod
from hill_muscle_ros.qos import RELIABLE_QOS
from hill_muscle_ros.timebase import NS_PER_S
from ros_helpers import DEFAULT_TIMEOUT_S, Probe

pytestmark = [pytest.mark.ros]

#: [s] the sim times the probe's /clock messages carry, in turn with a force message each.
SIM_TIMES_S = (1.0, 2.0, 3.5)


def test_log_time_is_the_sim_time_at_receipt_even_when_taken_later(tmp_path):
    ns = f'/simrec{os.getpid()}'
    bag = tmp_path / 'bag'
    rclpy.init(args=['--ros-args', '-p', f'output:={bag}', '-p', 'use_sim_time:=true',
                     '-p', 'topics:=[force]', '-r', f'__ns:={ns}'])
    rec = None
    try:
        rec = recorder_mod.Recorder()
        with Probe('sim_time_recorder_probe') as probe:
            clock_pub = probe.node.create_publisher(Clock, recorder_mod.CLOCK_TOPIC,
                                                    RELIABLE_QOS)
            force_pub = probe.publisher(f'{ns}/force', Float64)
            reader = '/' + recorder_mod.subscriptions_node_name(recorder_mod.NODE_NAME)
            # /clock: the recorder's time source and its own subscription.
            probe.spin_until(lambda: reader in probe.subscribers(recorder_mod.CLOCK_TOPIC)
                             and clock_pub.get_subscription_count() >= 2
                             and force_pub.get_subscription_count() >= 1,
                             "the recorder's subscriptions matched")
            for k, sim_s in enumerate(SIM_TIMES_S):
                sec, nanosec = divmod(round(sim_s * NS_PER_S), NS_PER_S)
                clock_pub.publish(Clock(clock=Time(sec=sec, nanosec=nanosec)))
                probe.spin_until(lambda: rec.take_clock() > 0,
                                 f'the recorder to receive /clock = {sim_s} s')
                force_pub.publish(Float64(data=float(k)))
                assert force_pub.wait_for_all_acked(Duration(seconds=DEFAULT_TIMEOUT_S))
            # The node's own clock never moved: the time source was not spun.
            assert rec.get_clock().now().nanoseconds == 0
            assert rec.take_all() == len(SIM_TIMES_S)
        assert rec.close() == recorder_mod.EXIT_SUCCESS
    finally:
        if rec is not None:
            rec.destroy_node()
        rclpy.try_shutdown()
    with AnyReader([bag]) as reader_:
        taken = [(timestamp, reader_.deserialize(raw, conn.msgtype).data)
                 for conn, timestamp, raw in reader_.messages()
                 if conn.topic == f'{ns}/force']
    assert taken == [(round(s * NS_PER_S), float(k)) for k, s in enumerate(SIM_TIMES_S)]
