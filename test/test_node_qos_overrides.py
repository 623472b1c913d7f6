"""ROS 2's standard QoS overrides on the package's publishers and subscriptions.

Every publisher and subscription declares the read-only parameters
``qos_overrides.<topic>.<publisher|subscription>.<history|depth|reliability>``
(rclpy's ``QoSOverridingOptions.with_default_policies()``). Without an
override each keeps exactly the profile the node asks for; with one, DDS
sees the overridden profile; a typo in a name or a value stops start-up with
one clear line.
"""
from __future__ import annotations

import itertools
import os

import pytest
import rclpy
import yaml
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, ReliabilityPolicy
from std_msgs.msg import Float64

from hill_muscle_ros.nodes._diagnostics import DIAGNOSTICS_QOS
from hill_muscle_ros.nodes._overrides import reject_unknown_overrides
from hill_muscle_ros.nodes._process import StartupError
from hill_muscle_ros.nodes._topics import (PACKAGE_TOPICS, QOS_OVERRIDES_PREFIX,
                                           overridable_publisher)
from hill_muscle_ros.nodes.force_controller import ForceControllerNode
from hill_muscle_ros.nodes.protocol_player import ProtocolPlayer
from hill_muscle_ros.nodes.simulator import STAMPED_QOS, Simulator
from hill_muscle_ros.qos import OUTPUT_QOS, RELIABLE_QOS
from hill_muscle_ros.params_file import load_muscle_params
from ros_helpers import Probe, ProcessGroup, node_command

pytestmark = [pytest.mark.ros, pytest.mark.unpaced]

_RUNS = itertools.count()
#: [-] the depth the tests override the force publisher's with.
OVERRIDE_DEPTH = 5


def unique_namespace() -> str:
    """Unique even if another test run drew the same ROS_DOMAIN_ID."""
    return f'/qos_{os.getpid()}_{next(_RUNS)}'


def params_file(tmp_path, params: dict) -> str:
    path = tmp_path / 'qos.yaml'
    path.write_text(yaml.safe_dump({'/**': {'ros__parameters': params}}))
    return str(path)


# -- over DDS -------------------------------------------------------------------


def test_params_file_makes_the_force_publisher_best_effort_and_leaves_the_others(tmp_path):
    ns = unique_namespace()
    force = f'{ns}/force'
    path = params_file(tmp_path, {
        f'qos_overrides.{force}.publisher.reliability': 'best_effort',
        f'qos_overrides.{force}.publisher.depth': OVERRIDE_DEPTH})
    with ProcessGroup(tmp_path) as procs, Probe('qos_probe') as probe:
        sim = procs.start('sim', node_command('simulator', ns=ns, params_files=[path]))
        infos = probe.spin_until(lambda: probe.node.get_publishers_info_by_topic(force),
                                 f'a publisher of {force}', procs=[sim])
        ce_infos = probe.spin_until(
            lambda: probe.node.get_publishers_info_by_topic(f'{ns}/ce_length'),
            'a publisher of ce_length', procs=[sim])
        depths = probe.get_parameters(f'{ns}/simulator', [
            f'qos_overrides.{force}.publisher.depth',
            f'qos_overrides.{ns}/ce_length.publisher.depth'], procs=[sim])
    assert [i.qos_profile.reliability for i in infos] == [ReliabilityPolicy.BEST_EFFORT]
    assert [i.qos_profile.reliability for i in ce_infos] == [ReliabilityPolicy.RELIABLE]
    # Depth is not part of DDS discovery: the parameters say what the node used.
    assert depths == {f'qos_overrides.{force}.publisher.depth': OVERRIDE_DEPTH,
                      f'qos_overrides.{ns}/ce_length.publisher.depth': OUTPUT_QOS.depth}


def test_recorder_subscription_takes_a_reliability_override(tmp_path):
    ns = unique_namespace()
    force = f'{ns}/force'
    path = params_file(tmp_path, {f'qos_overrides.{force}.subscription.reliability':
                                  'best_effort'})
    with ProcessGroup(tmp_path) as procs, Probe('qos_probe') as probe:
        rec = procs.start('rec', node_command('recorder', ns=ns, params_files=[path],
                                              params={'output': str(tmp_path / 'bag')}))
        infos = probe.spin_until(lambda: probe.node.get_subscriptions_info_by_topic(force),
                                 f'the recorder subscribed to {force}', procs=[rec])
    assert [i.qos_profile.reliability for i in infos] == [ReliabilityPolicy.BEST_EFFORT]


@pytest.mark.parametrize('key, value, expected', [
    ('{ns}/force.publisher.reliabilty', 'best_effort',
     'unknown parameter `qos_overrides.{ns}/force.publisher.reliabilty` (got \'best_effort\'): '
     'a QoS override is `qos_overrides.<topic>.<publisher|subscription>.'
     '<history|depth|reliability>`'),
    ('{ns}/forc.publisher.depth', 3,
     'unknown parameter `qos_overrides.{ns}/forc.publisher.depth` (got 3): `{ns}/forc` is '
     'none of the package\'s topics here'),
    ('{ns}/force.publisher.reliability', 'bestest',
     'parameter `qos_overrides.{ns}/force.publisher.reliability` = \'bestest\' rejected: '
     'expected one of system_default, reliable, best_effort, best_available'),
    ('{ns}/force.publisher.depth', 0,
     'parameter `qos_overrides.{ns}/force.publisher.depth` = 0 rejected: the depth must be an '
     'integer of at least 1'),
], ids=['policy-typo', 'topic-typo', 'bad-reliability', 'zero-depth'])
def test_bad_qos_override_stops_start_up_with_one_clear_line(tmp_path, key, value, expected):
    ns = unique_namespace()
    path = params_file(tmp_path, {QOS_OVERRIDES_PREFIX + key.format(ns=ns): value})
    with ProcessGroup(tmp_path) as procs:
        sim = procs.start('sim', node_command('simulator', ns=ns, params_files=[path]))
        status = sim.wait()
    log = sim.output()
    assert status == 1, log
    assert expected.format(ns=ns) in log
    assert 'Traceback' not in log


# -- in process: the defaults and the names ----------------------------------------


@pytest.fixture
def ros_args():
    """rclpy's default context, initialised with the given arguments (shut down after)."""
    def init(*args):
        rclpy.init(args=['--ros-args', *args])
    yield init
    rclpy.try_shutdown()


#: Topics rclpy itself publishes on for every node (not the package's).
RCLPY_TOPICS = ('/parameter_events', '/rosout')


def qos_of(node) -> dict[tuple[str, str], object]:
    """(topic, kind) -> QoS profile of every publisher and subscription the node made."""
    entities = {(p.topic_name, 'publisher'): p.qos_profile for p in node.publishers}
    entities.update({(s.topic_name, 'subscription'): s.qos_profile for s in node.subscriptions})
    return {key: qos for key, qos in entities.items() if key[0] not in RCLPY_TOPICS}


def declared_qos_topics(node) -> set[str]:
    names = node.list_parameters([], 0).names
    return {n[len(QOS_OVERRIDES_PREFIX):].rsplit('.', 2)[0] for n in names
            if n.startswith(QOS_OVERRIDES_PREFIX)}


def assert_profile(actual, expected, what):
    for policy in ('history', 'depth', 'reliability', 'durability'):
        assert getattr(actual, policy) == getattr(expected, policy), (what, policy)


def test_without_overrides_the_simulator_keeps_its_profiles(ros_args):
    ros_args('-r', '__ns:=/q', '-p', 'publish_clock:=true')
    node = Simulator()
    try:
        entities = qos_of(node)
        for topic in ('force', 'ce_length', 'wrench', 'recruitment_state', 'fitness'):
            assert_profile(entities[(f'/q/{topic}', 'publisher')], OUTPUT_QOS, topic)
        assert_profile(entities[('/clock', 'publisher')], OUTPUT_QOS, '/clock')
        assert_profile(entities[('/diagnostics', 'publisher')], DIAGNOSTICS_QOS, 'diag')
        for topic in ('pulse_width', 'recruitment', 'length_command'):
            assert_profile(entities[(f'/q/{topic}', 'subscription')], RELIABLE_QOS, topic)
        assert_profile(entities[('/q/length_command_stamped', 'subscription')], STAMPED_QOS,
                       'stamped')
        assert declared_qos_topics(node) == {t for t, _ in entities}
    finally:
        node.destroy_node()


@pytest.mark.parametrize('node_class', [ForceControllerNode, ProtocolPlayer],
                         ids=['controller', 'player'])
def test_without_overrides_controller_and_player_keep_their_profiles(ros_args, node_class):
    ros_args('-r', '__ns:=/q')
    node = node_class()
    try:
        for (topic, kind), qos in qos_of(node).items():
            expected = (DIAGNOSTICS_QOS if topic == '/diagnostics'
                        else OUTPUT_QOS if kind == 'publisher' else RELIABLE_QOS)
            assert_profile(qos, expected, topic)
    finally:
        node.destroy_node()


@pytest.mark.parametrize('node_class', [Simulator, ForceControllerNode, ProtocolPlayer],
                         ids=['simulator', 'controller', 'player'])
def test_every_topic_a_node_declares_overrides_for_is_one_a_params_file_may_name(
        ros_args, node_class):
    ros_args('-r', '__ns:=/q', '-r', 'force:=left_force')
    node = node_class()
    try:
        accepted = {node.resolve_topic_name(t) for t in PACKAGE_TOPICS}
        assert declared_qos_topics(node) <= accepted
    finally:
        node.destroy_node()


def test_a_shared_section_may_override_another_nodes_subscription(ros_args):
    # The controller subscribes to force; the simulator, which publishes it, passes over.
    ros_args('-p', 'qos_overrides./force.subscription.depth:=50')
    node = Simulator()
    try:
        reject_unknown_overrides(node)
        assert_profile(qos_of(node)[('/force', 'publisher')], OUTPUT_QOS, 'force')
    finally:
        node.destroy_node()


def test_an_override_leaves_the_shared_profile_alone():
    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    node = rclpy.create_node('qos_unit', context=context, parameter_overrides=[
        Parameter('qos_overrides./force.publisher.reliability', value='best_effort'),
        Parameter('qos_overrides./force.publisher.history', value='keep_all')])
    before = (OUTPUT_QOS.reliability, OUTPUT_QOS.history, OUTPUT_QOS.depth)
    try:
        pub = overridable_publisher(node, Float64, '/force', OUTPUT_QOS)
        other = overridable_publisher(node, Float64, '/ce_length', OUTPUT_QOS)
        assert pub.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
        assert pub.qos_profile.history == HistoryPolicy.KEEP_ALL
        assert (OUTPUT_QOS.reliability, OUTPUT_QOS.history, OUTPUT_QOS.depth) == before
        assert_profile(other.qos_profile, OUTPUT_QOS, 'ce_length')
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_startup_error_is_raised_in_process_for_a_bad_value(ros_args):
    ros_args('-p', 'qos_overrides./force.publisher.history:=keep_everything')
    with pytest.raises(StartupError, match='expected one of system_default, keep_last, '
                                           'keep_all'):
        Simulator()


#: The example of the documentation: a shared section that makes the
#: simulator's force best effort and deepens the recorder's queue for it.
EXAMPLE_PARAMS = """
/**:
  ros__parameters:
    qos_overrides:
      /force:
        publisher:
          reliability: best_effort
          depth: 10
        subscription:
          reliability: best_effort
    k_se_n_per_m: 10000.0
"""


def test_offline_cli_reads_a_params_file_with_qos_overrides(tmp_path):
    path = tmp_path / 'muscle.yaml'
    path.write_text(EXAMPLE_PARAMS + "    qos_overrides./wrench.publisher.depth: 100\n")
    params, node = load_muscle_params(path)
    assert params.k_se_n_per_m == 10000.0 and node == {}


def test_the_documented_example_is_accepted_by_the_simulator(ros_args, tmp_path):
    path = tmp_path / 'muscle.yaml'
    path.write_text(EXAMPLE_PARAMS)
    ros_args('--params-file', str(path))
    node = Simulator()
    try:
        qos = qos_of(node)[('/force', 'publisher')]
        assert (qos.reliability, qos.depth) == (ReliabilityPolicy.BEST_EFFORT, 10)
    finally:
        node.destroy_node()
