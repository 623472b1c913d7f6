"""The recorder node over real DDS, against a test publisher process that numbers
its messages, so that what was sent is known exactly."""
import itertools
import os
import resource
import signal
import sys
import time

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.duration import Duration
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from std_msgs.msg import Float64

from hill_muscle_ros.nodes.recorder import DRAIN_TIMEOUT_S, subscriptions_node_name
from hill_muscle_ros.recording.reader import read_bag
from hill_muscle_ros.timebase import NS_PER_S
from ros_helpers import DEFAULT_TIMEOUT_S, ProcessGroup, Probe, node_command

pytestmark = pytest.mark.ros

RATE_HZ = 1000.0
#: The simulator's three outputs and the player's two: five topics at 1 kHz.
TOPICS = ('pulse_width', 'length_command', 'force', 'ce_length', 'wrench')
NS_PER_MS = 1_000_000

#: Publishes message k (k = 0, 1, ...) on every topic at RATE_HZ: Float64 data = k,
#: WrenchStamped force.x = k stamped k ms. Starts once every topic has a
#: subscriber, prints progress, and stays alive after the last message; on
#: SIGINT it leaves the graph (a recorder then need not wait for more from it).
PUBLISHER = r'''
import sys, time
import rclpy
from rclpy.node import Node
from std_msgs.msg import Float64
from geometry_msgs.msg import WrenchStamped
rate, n, topics = float(sys.argv[1]), int(sys.argv[2]), sys.argv[3].split(',')
rclpy.init()
node = Node('numbered_publisher')
# A deep history lets reliable delivery recover the first messages when the
# recorder's reader matches this writer a little after the writer matched it.
pubs = [(t, node.create_publisher(WrenchStamped if t.endswith('wrench') else Float64, t, 1000))
        for t in topics]
while any(p.get_subscription_count() == 0 for _, p in pubs):
    time.sleep(0.01)
print('matched', flush=True)
t0 = time.monotonic()
wrench = WrenchStamped()
wrench.header.frame_id = 'muscle'
for k in range(n):
    delay = t0 + k / rate - time.monotonic()
    if delay > 0:
        time.sleep(delay)
    for t, p in pubs:
        if t.endswith('wrench'):
            wrench.header.stamp.sec, wrench.header.stamp.nanosec = divmod(k * 1000000, 1000000000)
            wrench.wrench.force.x = float(k)
            p.publish(wrench)
        else:
            p.publish(Float64(data=float(k)))
    if k % 250 == 0:
        print('published', k, flush=True)
from rclpy.duration import Duration
acked = all(p.wait_for_all_acked(Duration(seconds=10)) for _, p in pubs)
print('done', n, 'acked' if acked else 'not acked', flush=True)
try:
    while True:
        time.sleep(1.0)
except KeyboardInterrupt:
    pass
# Gone from the graph at once: a recorder stopped next does not wait for more.
node.destroy_node()
rclpy.try_shutdown()
'''


_namespaces = itertools.count()


@pytest.fixture
def ns():
    """A namespace of its own per test: other test runs on this machine may share
    the DDS domain and publish /force too."""
    return f'/rec{os.getpid()}_{next(_namespaces)}'


def publisher_cmd(n: int, ns: str, topics=TOPICS):
    names = [t if t.startswith('/') else f'{ns}/{t}' for t in topics]
    return [sys.executable, '-c', PUBLISHER, str(RATE_HZ), str(n), ','.join(names)]


def wait_for_output(procs, proc, text, timeout_s=DEFAULT_TIMEOUT_S, watch=()):
    """Wait until ``text`` appears in the log of ``proc`` (the test publisher's progress
    lines); ``proc`` or a watched process that exits fails the wait at once."""
    procs.wait_until(lambda: text in proc.output(), f'{text!r} in the log of {proc.name}',
                     timeout_s, watch=[proc, *watch])


def published_count(proc) -> int:
    """The highest progress count the publisher has printed."""
    counts = [int(line.split()[1]) for line in proc.output().splitlines()
              if line.startswith('published ')]
    return max(counts, default=-1)


def recorder_cmd(output, ns):
    return node_command('recorder', ns=ns, params={'output': str(output)})


def stop(proc, sig, timeout_s=DEFAULT_TIMEOUT_S):
    proc.popen.send_signal(sig)
    return proc.wait(timeout_s)


@pytest.fixture(scope='module')
def side_runs(tmp_path_factory):
    """Recorders that wait, idle, while :func:`full_run` records, each in a
    namespace of its own: one stopped with SIGINT beside a quiet publisher (it
    waits the drain timeout), and three that must refuse to start (a non-empty
    output, an unwritable one, a typed topic of an unknown type). The probe
    keeps the quiet publisher in the graph for the module's life.

    :return: name -> dict of ``proc``, ``ns``, ``bag`` and what the test needs
    """
    tmp = tmp_path_factory.mktemp('side_runs')
    base = f'/rec{os.getpid()}_side'
    with ProcessGroup(tmp) as procs, Probe('quiet_publisher_probe') as probe:
        runs = {}
        non_empty = tmp / 'non_empty_bag'
        non_empty.mkdir()
        (non_empty / 'old_run.mcap').write_bytes(b'precious')
        runs['non_empty'] = {'bag': non_empty, 'proc': procs.start(
            'non_empty', recorder_cmd(non_empty, f'{base}_non_empty'))}
        blocker = tmp / 'a_file'
        blocker.write_text('')
        runs['unwritable'] = {'proc': procs.start(
            'unwritable', recorder_cmd(blocker / 'bag', f'{base}_unwritable'))}
        unknown_bag = tmp / 'unknown_type_bag'
        runs['unknown_type'] = {'bag': unknown_bag, 'proc': _recorder_with_topics(
            procs, unknown_bag, f'{base}_unknown_type', ['extra:no_such_msgs/msg/Nothing'],
            name='unknown_type')}
        # The quiet publisher: one message acknowledged, then silence, then the stop.
        ns, bag = f'{base}_quiet', tmp / 'quiet_bag'
        rec = _recorder_with_topics(procs, bag, ns, ['extra:std_msgs/msg/Float64'],
                                    name='quiet')
        probe.publish_when_matched(f'{ns}/extra', Float64(data=7.0), procs=[rec])
        assert probe.publisher(f'{ns}/extra', Float64).wait_for_all_acked(
            Duration(seconds=DEFAULT_TIMEOUT_S))
        rec.popen.send_signal(signal.SIGINT)
        runs['quiet'] = {'ns': ns, 'bag': bag, 'proc': rec}
        yield runs


@pytest.fixture(scope='module')
def full_run(tmp_path_factory, side_runs):
    """3 s of five 1 kHz topics, recorded, then the recorder stopped with SIGINT
    (while the :func:`side_runs` wait)."""
    tmp = tmp_path_factory.mktemp('full_run')
    n = 3000
    bag = tmp / 'bag'
    ns = f'/rec{os.getpid()}_full'
    with ProcessGroup(tmp) as procs:
        rec = procs.start('recorder', recorder_cmd(bag, ns))
        pub = procs.start('publisher', publisher_cmd(n, ns))
        # 'done' comes after every message was acknowledged by the recorder's reader.
        wait_for_output(procs, pub, f'done {n}', timeout_s=60, watch=[rec])
        # Every message is acknowledged: the publisher goes, so that the
        # recorder need not wait for more from it (a quiet publisher).
        assert pub.stop() == 0, pub.output()
        status = stop(rec, signal.SIGINT)
    return bag, n, status, rec.output(), ns


def test_recorder_exits_zero_on_sigint(full_run):
    _, _, status, log, _ = full_run
    assert status == 0, log


def test_every_message_sent_at_1khz_is_recorded(full_run):
    bag, n, _, log, ns = full_run
    data = read_bag(bag)
    # /diagnostics is recorded by default too (the recorder's own reports among them).
    counts = {t: c for t, c in data.counts().items() if t != '/diagnostics'}
    assert counts == {f'{ns}/{t}': n for t in TOPICS}, log
    for topic in TOPICS:
        assert list(data.topic(f'{ns}/{topic}').values()) == [float(k) for k in range(n)]


def test_recorder_reports_sent_against_recorded(full_run):
    _, n, _, log, ns = full_run
    for topic in TOPICS:
        assert f'{ns}/{topic}: {n} recorded, publisher sent {n}, 0 lost' in log


def test_recorded_bytes_are_the_published_cdr(full_run):
    bag, n, _, _, ns = full_run
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic == f'{ns}/force']
        raw = [bytes(data) for _, _, data in reader.messages(connections=conns)]
    assert raw == [serialize_message(Float64(data=float(k))) for k in range(n)]


def test_publish_time_is_the_header_stamp_and_log_time_the_receive_time(full_run):
    bag, n, _, _, ns = full_run
    wrench = read_bag(bag).topic(f'{ns}/wrench')
    assert list(wrench.publish_time_ns) == [k * NS_PER_MS for k in range(n)]
    force = read_bag(bag).topic(f'{ns}/force')
    # Float64 has no header: publish time is the receive time, in wall-clock ns.
    np.testing.assert_array_equal(force.publish_time_ns, force.log_time_ns)
    assert abs(force.log_time_ns[-1] / NS_PER_S - time.time()) < 3600
    assert np.all(np.diff(force.log_time_ns) >= 0)


def test_live_bag_opens_with_anyreader(full_run):
    bag, n, _, _, ns = full_run
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == f'{ns}/wrench']
        values = [reader.deserialize(raw, c.msgtype).wrench.force.x
                  for c, _, raw in reader.messages(connections=conns)]
    assert values == [float(k) for k in range(n)]


def test_live_bag_opens_with_mcap_ros2(full_run):
    bag, n, _, _, ns = full_run
    with open(bag / 'bag_0.mcap', 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == 'ros2'
        values = [d.data for *_, d in
                  reader.iter_decoded_messages(topics=[f'{ns}/pulse_width'])]
    assert values == [float(k) for k in range(n)]


def test_channels_carry_the_publishers_qos(full_run):
    bag, _, _, _, ns = full_run
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    for topic in info['topics_with_message_count']:
        qos = topic['topic_metadata']['offered_qos_profiles']
        # One profile per publisher: the run's topics have one each; /diagnostics
        # has every node that reported during the run (the side_runs' recorders too).
        if topic['topic_metadata']['name'].startswith(f'{ns}/'):
            assert len(qos) == 1, topic
        assert qos and all(q['reliability'] == 'reliable' for q in qos), topic


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_stop_signal_mid_run_leaves_a_complete_bag_without_holes(tmp_path, sig, ns):
    bag = tmp_path / 'bag'
    with ProcessGroup(tmp_path) as procs:
        rec = procs.start('recorder', recorder_cmd(bag, ns))
        pub = procs.start('publisher', publisher_cmd(60_000, ns))
        wait_for_output(procs, pub, 'published 1500', timeout_s=60, watch=[rec])
        sent_before_signal = published_count(pub)
        status = stop(rec, sig)
    assert status == 0, rec.output()
    data = read_bag(bag)
    assert data.complete
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['message_count'] == sum(data.counts().values())
    for topic in TOPICS:
        values = data.topic(f'{ns}/{topic}').values()
        # Every message from the first up to the stop is there, none skipped,
        # including those published before the signal was sent.
        assert len(values) >= sent_before_signal + 1
        assert list(values) == [float(k) for k in range(len(values))]


def test_sigkill_leaves_the_closed_chunks_readable(tmp_path, ns):
    bag = tmp_path / 'bag'
    with ProcessGroup(tmp_path) as procs:
        rec = procs.start('recorder', recorder_cmd(bag, ns))
        pub = procs.start('publisher', publisher_cmd(60_000, ns))
        wait_for_output(procs, pub, 'published 3000', timeout_s=60, watch=[rec])
        rec.popen.send_signal(signal.SIGKILL)
        rec.wait()
    assert not (bag / 'metadata.yaml').exists()
    data = read_bag(bag)
    assert not data.complete
    for topic in TOPICS:
        values = data.topic(f'{ns}/{topic}').values()
        # Chunks close at least every second: of 3 s, at least 1 s is on disk.
        assert len(values) >= RATE_HZ, topic
        assert list(values) == [float(k) for k in range(len(values))]


def test_non_empty_output_is_refused_and_left_alone(side_runs):
    bag, rec = side_runs['non_empty']['bag'], side_runs['non_empty']['proc']
    status = rec.wait()
    assert status != 0
    assert 'not empty' in rec.output()
    assert [p.name for p in bag.iterdir()] == ['old_run.mcap']
    assert (bag / 'old_run.mcap').read_bytes() == b'precious'


def test_unwritable_output_is_a_clear_start_up_error(side_runs):
    rec = side_runs['unwritable']['proc']
    status = rec.wait()
    assert status != 0
    assert 'cannot create bag directory' in rec.output()
    assert 'Traceback' not in rec.output()


#: [B] the recorder's largest file: a full disk after about two chunks.
FILE_SIZE_LIMIT = 400_000


def _limit_file_size():
    # Python ignores SIGXFSZ, so writes past the limit fail with EFBIG (an OSError),
    # as they would with ENOSPC on a full disk.
    resource.setrlimit(resource.RLIMIT_FSIZE, (FILE_SIZE_LIMIT, FILE_SIZE_LIMIT))


def test_write_error_mid_run_stops_cleanly_keeping_what_was_written(tmp_path, ns):
    bag = tmp_path / 'bag'
    with ProcessGroup(tmp_path) as procs:
        rec = procs.start('recorder', recorder_cmd(bag, ns), preexec_fn=_limit_file_size)
        procs.start('publisher', publisher_cmd(60_000, ns))
        status = rec.wait(timeout_s=120)
    output = (tmp_path / 'recorder.log').read_text()
    assert status != 0, output
    assert 'stopping' in output and 'Traceback' not in output
    data = read_bag(bag)
    force = data.topic(f'{ns}/force').values()
    assert len(force) > 0
    assert list(force) == [float(k) for k in range(len(force))]
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in info['topics_with_message_count']}
    assert counts == data.counts()


def test_topics_resolve_in_the_namespace_and_unknown_types_are_discovered(tmp_path, ns):
    bag = tmp_path / 'bag'
    n = 500
    elsewhere = f'{ns}_elsewhere'
    with ProcessGroup(tmp_path) as procs:
        rec = procs.start('recorder', node_command(
            'recorder', ns=f'{ns}/left', params={'output': str(bag)},
            extra_ros_args=['-p', f'topics:=[force, {elsewhere}]']))
        pub = procs.start('publisher', publisher_cmd(n, ns, topics=(
            f'{ns}/left/force', elsewhere)))
        wait_for_output(procs, pub, f'done {n}', timeout_s=60, watch=[rec])
        assert pub.stop() == 0, pub.output()   # acknowledged: see full_run
        assert stop(rec, signal.SIGINT) == 0
    assert read_bag(bag).counts() == {f'{ns}/left/force': n, elsewhere: n}


def _recorder_with_topics(procs, bag, ns, topics, name='recorder'):
    return procs.start(name, node_command(
        'recorder', ns=ns, params={'output': str(bag), 'topics': topics}))


def test_single_message_on_a_typed_topic_is_recorded(tmp_path, ns):
    """A topic named with its type is subscribed before any publisher exists, so a
    single publish after the recorder's subscription matched (as ``ros2 topic pub
    --once -w``) is in the bag."""
    bag = tmp_path / 'bag'
    with ProcessGroup(tmp_path) as procs, Probe('typed_topic_probe') as probe:
        rec = _recorder_with_topics(procs, bag, ns, ['extra:std_msgs/msg/Float64'])
        probe.wait_for_endpoints(f'{ns}/extra', subscriber='/' + subscriptions_node_name(
            'recorder'), timeout_s=DEFAULT_TIMEOUT_S, watch=[rec])
        assert probe.publishers(f'{ns}/extra') == []   # subscribed with no publisher
        pub = probe.publisher(f'{ns}/extra', Float64)
        probe.spin_until(lambda: pub.get_subscription_count() == 1,
                         "the recorder's subscription matched", procs=[rec])
        pub.publish(Float64(data=42.0))
        assert pub.wait_for_all_acked(Duration(seconds=DEFAULT_TIMEOUT_S))
        probe.retire(f'{ns}/extra')   # gone: the recorder need not wait for more
        assert stop(rec, signal.SIGINT) == 0, rec.output()
    assert list(read_bag(bag).topic(f'{ns}/extra').values()) == [42.0]


#: The recorder's console script, but a SIGINT comes at the end of its node's
#: construction (its subscriptions made, its bag open), once the file named by
#: argv[1] exists: a Ctrl-C that lands while the recorder starts. The rest of
#: argv is the recorder's ``--ros-args``.
SIGNALLED_WHILE_STARTING = r'''
import signal, sys, time
from pathlib import Path
from hill_muscle_ros.nodes import recorder
go = Path(sys.argv[1])
class Recorder(recorder.Recorder):
    def __init__(self):
        super().__init__()
        while not go.exists():   # polled: the test makes it once its message is acknowledged
            time.sleep(0.01)
        signal.raise_signal(signal.SIGINT)
recorder.Recorder = Recorder
sys.argv = [sys.argv[0], *sys.argv[2:]]
recorder.process_main()
'''


def test_a_stop_signal_while_the_recorder_starts_still_writes_what_it_received(tmp_path, ns):
    """A message that DDS delivered to a recorder still inside its start-up is
    in the bag, and the bag is closed, when Ctrl-C comes before the start-up
    ends (a fresh clone's run: exit 0 and a bag of only its header)."""
    bag, go = tmp_path / 'bag', tmp_path / 'go'
    ros_args = node_command('recorder', ns=ns, params={'output': str(bag),
                                                        'topics': ['force']})[1:]
    with ProcessGroup(tmp_path) as procs, Probe('start_signal_probe') as probe:
        rec = procs.start('recorder', [sys.executable, '-c', SIGNALLED_WHILE_STARTING,
                                       str(go), *ros_args])
        probe.publish_when_matched(f'{ns}/force', Float64(data=3.0), procs=[rec])
        probe.retire(f'{ns}/force')   # acknowledged by the recorder's reader, and gone
        go.touch()
        assert rec.wait() == 0, rec.output()
    assert list(read_bag(bag).topic(f'{ns}/force').values()) == [3.0], rec.output()


def test_a_quiet_publisher_is_waited_for_then_named_as_the_stop_closes_the_bag(side_runs):
    """A publisher still in the graph but silent since before the stop may
    have a lost message that DDS repairs on its next heartbeat: the recorder
    waits the drain timeout for it, then closes the bag (exit 0) and names the
    topic and how long before the stop its newest message was sent."""
    run = side_runs['quiet']   # started, its message acknowledged, then SIGINT (side_runs)
    ns, bag, rec = run['ns'], run['bag'], run['proc']
    assert rec.wait() == 0, rec.output()
    line = (f'{ns}/extra: nothing its publisher sent after the stop arrived '
            f'(waited {DRAIN_TIMEOUT_S:g} s); the newest message recorded was sent ')
    assert line in rec.output(), rec.output()
    assert list(read_bag(bag).topic(f'{ns}/extra').values()) == [7.0]


def test_best_effort_publisher_on_a_typed_topic_is_reported_by_name(tmp_path, ns):
    """A best-effort publisher can never match the reliable subscription made at
    start-up: the recorder says so, naming the topic, instead of recording nothing
    silently."""
    best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    with ProcessGroup(tmp_path) as procs, Probe('best_effort_probe') as probe:
        rec = _recorder_with_topics(procs, tmp_path / 'bag', ns, ['extra:std_msgs/msg/Float64'])
        probe.node.create_publisher(Float64, f'{ns}/extra', best_effort)
        procs.wait_until(lambda: 'cannot match' in rec.output(), 'the recorder to report it')
        assert stop(rec, signal.SIGINT) == 0, rec.output()
    report = [line for line in rec.output().splitlines() if 'cannot match' in line]
    assert len(report) == 1, rec.output()
    assert f'{ns}/extra' in report[0] and 'without its type' in report[0]


def test_typed_topic_with_an_unknown_type_is_a_clear_start_up_error(side_runs):
    rec = side_runs['unknown_type']['proc']
    status = rec.wait()
    assert status != 0
    assert 'parameter `topics`' in rec.output() and 'no_such_msgs' in rec.output()
    assert 'Traceback' not in rec.output()
    assert not side_runs['unknown_type']['bag'].exists()
