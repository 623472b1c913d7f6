"""The recorder's pure helpers, without DDS."""
import datetime as dt
import re
import struct
from pathlib import Path

import pytest

from geometry_msgs.msg import WrenchStamped
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message

from hill_muscle_ros.nodes.recorder import (
    QUEUE_DEPTH, _TopicStats, default_output, has_header_first, header_stamp_ns,
    parse_topic_entry, request_qos)
from hill_muscle_ros.timebase import NS_PER_S


def test_default_output_is_runs_and_the_utc_start_time():
    now = dt.datetime(2025, 1, 31, 12, 3, 4, tzinfo=dt.timezone.utc)
    assert default_output(now) == Path('runs/2025-01-31T12-03-04Z')


def test_header_stamp_is_read_from_the_raw_cdr():
    msg = WrenchStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1_700_000_123, 456_789_012
    msg.header.frame_id = 'muscle'
    assert header_stamp_ns(serialize_message(msg)) == 1_700_000_123_456_789_012


def test_header_stamp_of_big_endian_cdr():
    data = b'\x00\x00\x00\x00' + struct.pack('>iI', 12, 34)
    assert header_stamp_ns(data) == 12 * NS_PER_S + 34


def test_only_types_that_start_with_a_header_are_stamped():
    assert has_header_first('geometry_msgs/msg/WrenchStamped')
    assert not has_header_first('std_msgs/msg/Float64')
    assert not has_header_first('rosgraph_msgs/msg/Clock')


def test_requested_qos_matches_every_publisher():
    reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    assert request_qos([reliable]).reliability == ReliabilityPolicy.RELIABLE
    assert request_qos([reliable, best_effort]).reliability == ReliabilityPolicy.BEST_EFFORT
    assert request_qos([latched]).durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert request_qos([latched, reliable]).durability == DurabilityPolicy.VOLATILE
    assert request_qos([]).durability == DurabilityPolicy.VOLATILE
    assert request_qos([reliable]).depth == QUEUE_DEPTH


def test_sequence_gaps_count_lost_messages():
    stats = _TopicStats('/force', stamped=False)
    assert [stats.add(s) for s in (1, 2, 5, 6, 10)] == [0, 0, 2, 0, 3]
    assert (stats.received, stats.sent, stats.lost) == (5, 10, 5)


def test_out_of_order_sequences_disable_the_check():
    stats = _TopicStats('/force', stamped=False)
    for seq in (5, 6, 1, 9):
        stats.add(seq)
    assert stats.sent is None and stats.lost == 0


@pytest.mark.parametrize('entry, expected', [
    ('force', ('force', None)),
    ('/clock', ('/clock', None)),
    ('force_target:std_msgs/msg/Float64', ('force_target', 'std_msgs/msg/Float64')),
    ('/left/wrench:geometry_msgs/WrenchStamped', ('/left/wrench',
                                                  'geometry_msgs/msg/WrenchStamped')),
])
def test_topic_entry_is_a_name_and_an_optional_type(entry, expected):
    assert parse_topic_entry(entry) == expected


@pytest.mark.parametrize('entry, needle', [
    (':std_msgs/msg/Float64', 'names no topic'),
    ('force:Float64', "got 'Float64'"),
    ('force:', "got ''"),
    ('force:std_msgs/msg/Float64:x', "got 'std_msgs/msg/Float64:x'"),
])
def test_malformed_topic_entry_is_rejected_naming_it(entry, needle):
    with pytest.raises(ValueError, match=re.escape(needle)) as err:
        parse_topic_entry(entry)
    assert repr(entry) in str(err.value)
