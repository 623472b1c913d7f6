"""The bag writer produces what rosbag2's MCAP storage (Jazzy) produces, and every
reader we promise (rosbags Reader and AnyReader, mcap + mcap_ros2, our own) reads it."""
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from geometry_msgs.msg import WrenchStamped
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.qos import QoSProfile
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from std_msgs.msg import Float64

from hill_muscle_ros.recording.bag_writer import (
    CHUNK_DURATION_S, DEFINITION_SEPARATOR, BagOutputError, BagWriter, message_definition,
    share_directory, type_description_hash)
from hill_muscle_ros.recording.reader import read_bag
from hill_muscle_ros.timebase import NS_PER_S

N_MESSAGES = 2500
DT_NS = 1_000_000          # 1 kHz


def _wrench(k: int) -> WrenchStamped:
    msg = WrenchStamped()
    msg.header.stamp.sec = k * DT_NS // NS_PER_S
    msg.header.stamp.nanosec = k * DT_NS % NS_PER_S
    msg.header.frame_id = 'muscle'
    msg.wrench.force.x = 0.25 * k
    return msg


@pytest.fixture
def bag(tmp_path):
    """A bag with a Float64 and a WrenchStamped topic, 2.5 s at 1 kHz."""
    path = tmp_path / 'bag'
    sent = {'/force': [], '/wrench': []}
    with BagWriter(path) as writer:
        writer.add_topic('/force', 'std_msgs/msg/Float64', offered_qos_profiles=[QoSProfile(depth=10)])
        writer.add_topic('/wrench', 'geometry_msgs/msg/WrenchStamped',
                         offered_qos_profiles=[QoSProfile(depth=10)])
        for k in range(N_MESSAGES):
            t_ns = k * DT_NS
            data = serialize_message(Float64(data=1.5 * k))
            writer.write('/force', data, t_ns + 7)
            sent['/force'].append((t_ns + 7, t_ns + 7, data))
            data = serialize_message(_wrench(k))
            writer.write('/wrench', data, t_ns + 11, t_ns)
            sent['/wrench'].append((t_ns + 11, t_ns, data))
    return path, sent


def _msg_text(type_name: str) -> str:
    package, *_, name = type_name.split('/')
    return (share_directory(package) / 'msg' / f'{name}.msg').read_text()


def test_definition_is_msg_file_then_each_dependency_once():
    text = message_definition('geometry_msgs/msg/WrenchStamped')
    sections = text.split('\n' + DEFINITION_SEPARATOR)
    assert sections[0] == _msg_text('geometry_msgs/msg/WrenchStamped')
    names = []
    for section in sections[1:]:
        first, body = section.split('\n', 1)
        assert first.startswith('MSG: ')
        names.append(first[len('MSG: '):])
        assert body == _msg_text(names[-1])
    assert names == ['geometry_msgs/Wrench', 'geometry_msgs/Vector3', 'std_msgs/Header',
                     'builtin_interfaces/Time']


def test_definition_of_a_primitive_only_type_has_no_dependencies():
    assert message_definition('std_msgs/msg/Float64') == _msg_text('std_msgs/msg/Float64')


def test_type_hash_is_the_shipped_rihs01():
    assert type_description_hash('std_msgs/msg/Float64').startswith('RIHS01_')


def test_bag_layout_is_rosbag2s(bag):
    path, _ = bag
    assert sorted(p.name for p in path.iterdir()) == ['bag_0.mcap', 'metadata.yaml']
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9
    assert info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == ['bag_0.mcap']
    assert info['message_count'] == 2 * N_MESSAGES
    assert info['ros_distro'] == 'jazzy'
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in info['topics_with_message_count']}
    assert counts == {'/force': N_MESSAGES, '/wrench': N_MESSAGES}


def test_mcap_records_are_rosbag2s(bag):
    path, _ = bag
    with open(path / 'bag_0.mcap', 'rb') as f:
        reader = make_reader(f)
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        schemas = {s.name: s for s in summary.schemas.values()}
        assert {s.encoding for s in schemas.values()} == {'ros2msg'}
        assert schemas['geometry_msgs/msg/WrenchStamped'].data.decode() == \
            message_definition('geometry_msgs/msg/WrenchStamped')
        for channel in summary.channels.values():
            assert channel.message_encoding == 'cdr'
            qos = yaml.safe_load(channel.metadata['offered_qos_profiles'])
            assert qos[0]['reliability'] == 'reliable'
            assert qos[0]['history'] == 'keep_last'
            assert channel.metadata['topic_type_hash'].startswith('RIHS01_')
        records = [m for m in reader.iter_metadata() if m.name == 'rosbag2']
        assert len(records) == 1
        serialized = yaml.safe_load(records[0].metadata['serialized_metadata'])
        assert serialized['message_count'] == 2 * N_MESSAGES


def test_chunks_span_at_most_one_second(bag):
    path, _ = bag
    with open(path / 'bag_0.mcap', 'rb') as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) >= 3
    assert all(c.message_end_time - c.message_start_time < NS_PER_S for c in chunks)


def test_rosbags_reader_returns_bytes_and_times_exactly(bag):
    path, sent = bag
    got = {'/force': [], '/wrench': []}
    with Reader(path) as reader:
        assert {c.topic: c.msgcount for c in reader.connections} == \
            {'/force': N_MESSAGES, '/wrench': N_MESSAGES}
        for connection, timestamp, raw in reader.messages():
            got[connection.topic].append((timestamp, bytes(raw)))
    for topic in sent:
        assert got[topic] == [(log, data) for log, _, data in sent[topic]]


@pytest.mark.parametrize('typestore', [None, get_typestore(Stores.ROS2_JAZZY)],
                         ids=['definitions-from-bag', 'jazzy-typestore'])
def test_anyreader_decodes_values_exactly(bag, typestore):
    path, _ = bag
    forces, wrenches = [], []
    with AnyReader([path], default_typestore=typestore) as reader:
        for connection, _, raw in reader.messages():
            msg = reader.deserialize(raw, connection.msgtype)
            if connection.topic == '/force':
                forces.append(msg.data)
            else:
                wrenches.append((msg.header.stamp.sec, msg.header.stamp.nanosec,
                                 msg.header.frame_id, msg.wrench.force.x))
    assert forces == [1.5 * k for k in range(N_MESSAGES)]
    assert wrenches == [(k * DT_NS // NS_PER_S, k * DT_NS % NS_PER_S, 'muscle', 0.25 * k)
                        for k in range(N_MESSAGES)]


def test_mcap_ros2_decoder_gives_log_and_publish_times(bag):
    path, sent = bag
    with open(path / 'bag_0.mcap', 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        got = [(m.log_time, m.publish_time, d.wrench.force.x)
               for _, _, m, d in reader.iter_decoded_messages(topics=['/wrench'],
                                                              log_time_order=False)]
    assert got == [(log, pub, 0.25 * k) for k, (log, pub, _) in enumerate(sent['/wrench'])]


def test_own_reader_gives_values_and_stamps(bag):
    path, _ = bag
    data = read_bag(path)
    assert data.complete
    assert data.counts() == {'/force': N_MESSAGES, '/wrench': N_MESSAGES}
    assert list(data.topic('force').values()) == [1.5 * k for k in range(N_MESSAGES)]
    assert list(data.topic('wrench').stamps_ns()) == [k * DT_NS for k in range(N_MESSAGES)]


def test_non_empty_output_directory_is_refused_and_left_alone(tmp_path):
    (tmp_path / 'keep.txt').write_text('precious')
    with pytest.raises(BagOutputError, match='not empty'):
        BagWriter(tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == ['keep.txt']


def test_empty_existing_directory_is_used(tmp_path):
    with BagWriter(tmp_path) as writer:
        writer.add_topic('/force', 'std_msgs/msg/Float64')
    assert (tmp_path / f'{tmp_path.name}_0.mcap').exists()


def test_uncreatable_output_is_a_clear_error(tmp_path):
    blocker = tmp_path / 'a_file'
    blocker.write_text('')
    with pytest.raises(BagOutputError, match='cannot create bag directory'):
        BagWriter(blocker / 'bag')


def test_too_little_free_space_is_refused_at_start(tmp_path):
    with pytest.raises(BagOutputError, match='free'):
        BagWriter(tmp_path / 'bag', min_free_bytes=2 ** 62)


_CRASH_SCRIPT = """
import os, sys
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64
from hill_muscle_ros.recording.bag_writer import BagWriter
w = BagWriter(sys.argv[1])
w.add_topic('/force', 'std_msgs/msg/Float64')
for k in range(2500):          # 2.5 s of log time: 2 closed chunks, 1 open
    w.write('/force', serialize_message(Float64(data=float(k))), k * 1_000_000)
os._exit(9)                    # no close, no summary: as after SIGKILL
"""


def test_closed_chunks_survive_a_crash(tmp_path):
    path = tmp_path / 'bag'
    subprocess.run([sys.executable, '-c', _CRASH_SCRIPT, str(path)], check=False, timeout=120)
    assert not (path / 'metadata.yaml').exists()
    data = read_bag(path)
    assert not data.complete
    values = list(data.topic('force').values())
    assert values == [float(k) for k in range(2000)]


class _FailingFile:
    """A file whose writes fail once ``limit`` bytes are written (a full disk)."""

    def __init__(self, real, limit):
        self._real, self._left = real, limit

    def write(self, data):
        if len(data) > self._left:
            self._left = 0  # a full disk stays full
            raise OSError(28, 'No space left on device')
        self._left -= len(data)
        return self._real.write(data)

    def __getattr__(self, name):
        return getattr(self._real, name)


def test_disk_full_mid_run_raises_and_keeps_closed_chunks(tmp_path, monkeypatch):
    path = tmp_path / 'bag'
    writer = BagWriter(path)
    writer.add_topic('/force', 'std_msgs/msg/Float64')
    writer._file = _FailingFile(writer._file, 150_000)  # noqa: SLF001 - inject the fault
    monkeypatch.setattr(writer._writer, '_Writer__stream', writer._file)  # noqa: SLF001
    with pytest.raises(OSError):
        for k in range(10_000):
            writer.write('/force', serialize_message(Float64(data=float(k))), k * 1_000_000)
    with pytest.raises(OSError):
        writer.close()
    flushed = writer.flushed_counts['/force']
    assert flushed > 0
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['message_count'] == flushed
    assert list(read_bag(path).topic('force').values()) == [float(k) for k in range(flushed)]


def test_reader_needs_no_ros_environment(bag):
    path, _ = bag
    env = {k: v for k, v in os.environ.items() if not k.startswith(('AMENT', 'ROS'))}
    code = ('import sys; from hill_muscle_ros.recording.reader import read_bag; '
            'print(read_bag(sys.argv[1]).counts()["/force"])')
    out = subprocess.run([sys.executable, '-c', code, str(path)], env=env, check=True,
                         capture_output=True, text=True, timeout=120).stdout
    assert int(out) == N_MESSAGES


class _FakeClock:
    """[s] a monotonic clock the test advances by hand."""

    def __init__(self):
        self.now_s = 0.0

    def __call__(self):
        return self.now_s


def test_a_quiet_topic_reaches_the_disk_after_a_chunk_of_wall_time(tmp_path):
    # One message, then silence: its chunk closes after CHUNK_DURATION_S of wall
    # time whatever the log times (what a reader of a killed recording gets).
    clock = _FakeClock()
    writer = BagWriter(tmp_path / 'bag', wall_clock=clock)
    writer.add_topic('/force', 'std_msgs/msg/Float64')
    writer.write('/force', serialize_message(Float64(data=1.0)), 5 * NS_PER_S)
    clock.now_s = 0.999 * CHUNK_DURATION_S
    writer.flush_if_due()
    assert writer.flushed_counts == {'/force': 0}
    clock.now_s = CHUNK_DURATION_S
    writer.flush_if_due()
    assert writer.flushed_counts == {'/force': 1}
    assert list(read_bag(tmp_path / 'bag').topic('force').values()) == [1.0]
    writer.close()
