"""The recorder records the pulse model's topics: ``stimulation``
(hill_muscle_interfaces/msg/Stimulation, by default) and ``activation``
(std_msgs/Float64MultiArray, when named), and its bags carry their message
definitions, so that a reader that knows nothing of this package decodes them.

Over real DDS, one run shared by the module: a ding2003 simulator with four
channels, a test publisher process that numbers its Stimulation messages
(``header.frame_id`` = k; channel, mode, width and frequency change with k),
a recorder with the default topics (stopped with SIGINT once everything was
acknowledged) and one named ``recorder_named`` that records ``stimulation``
and ``activation`` (stopped with SIGTERM while both streams still flow). The
bags are read back with rosbags, the custom type registered from the ``.msg``
text as a user would.
"""
import os
import re
import signal
import sys

import pytest
import rclpy
import yaml
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from conftest import REPO
from hill_muscle_ros.nodes import recorder as recorder_mod
from ros_helpers import ProcessGroup, node_command

pytestmark = pytest.mark.ros

STIMULATION_TYPE = 'hill_muscle_interfaces/msg/Stimulation'
ACTIVATION_TYPE = 'std_msgs/msg/Float64MultiArray'
#: The message definition as a user has it: the interface package's source.
STIMULATION_MSG = REPO / 'hill_muscle_interfaces' / 'msg' / 'Stimulation.msg'
CHANNELS = 4
#: Stimulation messages and their rate: a command stream, as a controller's.
N_MESSAGES = 600
RATE_HZ = 200.0
#: The named recorder is stopped once this many messages were published.
SIGTERM_AFTER = 300
MODES = ('single', 'doublet', 'triplet')


def expected_message(k: int) -> dict:
    """The fields of message k, as the publisher below builds it."""
    return {'frame_id': str(k), 'channel': [k % CHANNELS + 1], 'mode': [MODES[k % 3]],
            'pulse_width_s': [1e-4 + 1e-6 * (k % 100)], 'current_a': [],
            'frequency_hz': [20.0 + k % 30]}


#: Publishes message k = 0 .. n-1 at the given rate once ``subscribers``
#: subscriptions have matched, printing its progress; 'done n acked' once
#: every reader acknowledged everything; then stays in the graph until SIGINT.
PUBLISHER = r'''
import sys, time
import rclpy
from rclpy.duration import Duration
from hill_muscle_interfaces.msg import Stimulation
topic, rate, n, subscribers = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
MODES = ('single', 'doublet', 'triplet')
rclpy.init()
node = rclpy.create_node('stimulation_publisher')
pub = node.create_publisher(Stimulation, topic, 1000)
while pub.get_subscription_count() < subscribers:
    time.sleep(0.01)
print('matched', flush=True)
t0 = time.monotonic()
for k in range(n):
    delay = t0 + k / rate - time.monotonic()
    if delay > 0:
        time.sleep(delay)
    msg = Stimulation(channel=[k % 4 + 1], mode=[MODES[k % 3]],
                      pulse_width_s=[1e-4 + 1e-6 * (k % 100)], current_a=[],
                      frequency_hz=[20.0 + k % 30])
    msg.header.frame_id = str(k)
    pub.publish(msg)
    if k % 50 == 0:
        print('published', k, flush=True)
acked = pub.wait_for_all_acked(Duration(seconds=30))
print('done', n, 'acked' if acked else 'not acked', flush=True)
try:
    while True:
        time.sleep(1.0)
except KeyboardInterrupt:
    pass
node.destroy_node()
rclpy.try_shutdown()
'''


def published_count(proc) -> int:
    """The highest progress count the publisher has printed."""
    return max((int(line.split()[1]) for line in proc.output().splitlines()
                if line.startswith('published ')), default=-1)


def user_typestore():
    """A rosbags typestore with Stimulation registered from its .msg text."""
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(STIMULATION_MSG.read_text(encoding='utf-8'),
                                      STIMULATION_TYPE))
    return store


def decoded(bag, topic, store=None):
    """``[(log time ns, message)]`` of one topic: with ``store``, raw bytes read
    with rosbags' Reader and decoded by it; without, by AnyReader from the bag's
    own definitions."""
    if store is not None:
        with Reader(bag) as reader:
            conns = [c for c in reader.connections if c.topic == topic]
            return [(t, store.deserialize_cdr(raw, c.msgtype))
                    for c, t, raw in reader.messages(connections=conns)]
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        return [(t, reader.deserialize(raw, c.msgtype))
                for c, t, raw in reader.messages(connections=conns)]


def fields(msg) -> dict:
    return {'frame_id': msg.header.frame_id, 'channel': [int(c) for c in msg.channel],
            'mode': list(msg.mode), 'pulse_width_s': [float(v) for v in msg.pulse_width_s],
            'current_a': [float(v) for v in msg.current_a],
            'frequency_hz': [float(v) for v in msg.frequency_hz]}


@pytest.fixture(scope='module')
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp('recorder_stimulation')
    ns = f'/recstim{os.getpid()}'
    params = tmp / 'ding.yaml'
    params.write_text(yaml.safe_dump({'/**': {'ros__parameters': {
        'activation_model': 'ding2003', 'channel_fractions': [1.0 / CHANNELS] * CHANNELS,
        'input_timeout_s': 0.0}}}))
    bags = {'default': tmp / 'default', 'named': tmp / 'named'}
    with ProcessGroup(tmp) as procs:
        sim = procs.start('simulator', node_command('simulator', ns=ns, params_files=[params]))
        rec = procs.start('recorder', node_command('recorder', ns=ns,
                                                   params={'output': str(bags['default'])}))
        named = procs.start('recorder_named', node_command(
            'recorder', ns=ns, params={'output': str(bags['named']),
                                       'topics': ['stimulation', 'activation']},
            extra_ros_args=['-r', '__node:=recorder_named']))
        everyone = [sim, rec, named]
        # The named recorder writes activation from its first message on: the
        # muscle at rest before the first stimulation.
        procs.wait_until(lambda: f'recording {ns}/activation' in named.output(),
                         'the named recorder to record activation', watch=everyone)
        # Three subscribers (simulator and both recorders) matched the
        # publisher; 'done' says every one of them acknowledged every message.
        pub = procs.start('publisher', [sys.executable, '-c', PUBLISHER, f'{ns}/stimulation',
                                        str(RATE_HZ), str(N_MESSAGES), '3'])
        procs.wait_until(lambda: published_count(pub) >= SIGTERM_AFTER,
                         f'{SIGTERM_AFTER} messages published', timeout_s=60,
                         watch=[*everyone, pub])
        sent_before_sigterm = published_count(pub)
        named.popen.send_signal(signal.SIGTERM)
        named_status = named.wait()
        procs.wait_until(lambda: f'done {N_MESSAGES}' in pub.output(), 'the publisher done',
                         timeout_s=60, watch=[sim, rec, pub])
        # Gone from the graph: the default recorder need not wait for more from it.
        assert pub.stop() == 0, pub.output()
        rec.popen.send_signal(signal.SIGINT)
        status = rec.wait()
    return {'ns': ns, 'bags': bags, 'status': status, 'log': rec.output(),
            'named_status': named_status, 'named_log': named.output(),
            'sent_before_sigterm': sent_before_sigterm, 'pub_log': pub.output()}


def test_stimulation_is_recorded_by_default_and_activation_is_not():
    assert 'stimulation' in recorder_mod.DEFAULT_TOPICS
    assert 'activation' not in recorder_mod.DEFAULT_TOPICS
    assert recorder_mod.KNOWN_TYPES['stimulation'] == STIMULATION_TYPE
    assert recorder_mod.KNOWN_TYPES['activation'] == ACTIVATION_TYPE


def test_the_shipped_recorder_file_lists_the_default_topics():
    config = yaml.safe_load((REPO / 'config' / 'recorder.yaml').read_text(encoding='utf-8'))
    assert config['/**']['ros__parameters']['topics'] == list(recorder_mod.DEFAULT_TOPICS)


def test_every_stimulation_message_is_in_the_default_bag_as_sent(run):
    assert run['status'] == 0, run['log']
    assert 'acked' in run['pub_log'] and 'not acked' not in run['pub_log'], run['pub_log']
    messages = decoded(run['bags']['default'], f'{run["ns"]}/stimulation', user_typestore())
    assert [fields(m) for _, m in messages] == [expected_message(k) for k in range(N_MESSAGES)]


def test_the_recorder_counts_the_stimulation_sent_against_recorded(run):
    line = f'{run["ns"]}/stimulation: {N_MESSAGES} recorded, publisher sent {N_MESSAGES}, 0 lost'
    assert line in run['log'], run['log']


def test_the_default_bag_has_no_activation(run):
    with Reader(run['bags']['default']) as reader:
        topics = {c.topic for c in reader.connections}
    assert f'{run["ns"]}/stimulation' in topics
    assert f'{run["ns"]}/activation' not in topics


def test_a_reader_without_the_package_decodes_stimulation_from_the_bags_definition(run):
    """AnyReader builds its types from the definitions stored in the bag."""
    ns = run['ns']
    own = decoded(run['bags']['default'], f'{ns}/stimulation')
    assert [fields(m) for _, m in own] == [expected_message(k) for k in range(N_MESSAGES)]
    with Reader(run['bags']['default']) as reader:
        [conn] = [c for c in reader.connections if c.topic == f'{ns}/stimulation']
        assert conn.msgtype == STIMULATION_TYPE
        assert conn.ext.serialization_format == 'cdr'


def test_sigterm_mid_stream_keeps_every_stimulation_message_up_to_the_signal(run):
    assert run['named_status'] == 0, run['named_log']
    messages = decoded(run['bags']['named'], f'{run["ns"]}/stimulation', user_typestore())
    frames = [int(m.header.frame_id) for _, m in messages]
    assert len(frames) >= run['sent_before_sigterm'] + 1
    assert frames == list(range(len(frames)))
    assert len(frames) < N_MESSAGES   # the stream still flowed at the signal


def test_sigterm_mid_stream_loses_no_activation_sample(run):
    ns = run['ns']
    match = re.search(rf'{re.escape(ns)}/activation: (\d+) recorded, publisher sent (\d+)'
                      r'(?: \(and \d+ before the recorder matched\))?, (\d+) lost',
                      run['named_log'])
    assert match is not None, run['named_log']
    recorded, sent, lost = map(int, match.groups())
    assert recorded == sent and lost == 0
    assert len(decoded(run['bags']['named'], f'{ns}/activation')) == recorded


def test_recorded_activation_has_every_channel_from_rest_to_stimulated(run):
    samples = [m for _, m in decoded(run['bags']['named'], f'{run["ns"]}/activation')]
    assert all(len(m.data) == CHANNELS for m in samples)
    assert [(d.label, d.size) for d in samples[-1].layout.dim] == [('channel', CHANNELS)]
    assert list(samples[0].data) == [0.0] * CHANNELS   # recorded from before the first pulse
    assert min(samples[-1].data) > 0.0                 # every channel commanded by then


def test_without_the_interface_package_stimulation_is_left_out_with_a_warning(
        tmp_path, monkeypatch, capfd):
    """A plain ``pip install .`` cannot build hill_muscle_interfaces: the default
    recording goes on without ``stimulation`` and says so, rather than failing."""
    monkeypatch.setitem(recorder_mod.KNOWN_TYPES, 'stimulation',
                        'no_such_interfaces/msg/Stimulation')
    ns = f'/recstim_missing{os.getpid()}'
    rclpy.init(args=['--ros-args', '-p', f'output:={tmp_path / "bag"}', '-r', f'__ns:={ns}'])
    rec = None
    try:
        rec = recorder_mod.Recorder()
        report = rec.report()
        assert rec.close() == recorder_mod.EXIT_SUCCESS
    finally:
        if rec is not None:
            rec.destroy_node()
        rclpy.try_shutdown()
    assert f'{ns}/stimulation' not in report
    assert f'{ns}/pulse_width: no message received' in report
    err = capfd.readouterr().err
    assert 'stimulation: not recording it: its type no_such_interfaces/msg/Stimulation' in err
