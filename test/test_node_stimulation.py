"""The ``stimulation`` input (hill_muscle_interfaces/msg/Stimulation) and the
``activation`` output of the simulator and limb nodes.

Three layers, cheapest first:

- the checks of a message (hill_muscle_ros.nodes._stimulation), no ROS;
- the nodes' callbacks and steps in this process (a Simulator or LimbNode
  made in rclpy's default context, its callbacks called as the executor would
  call them, no DDS traffic), against the model stepped offline;
- over real DDS: one ding2003 simulator with two channels on a RehaStim 2
  (``/stim``, 200 Hz, watchdog off), shared by the module, and a limb node
  whose quadriceps has two channels.
"""
import math
import os
import subprocess
import sys

import pytest
import rclpy
import yaml
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import Trigger

from conftest import REPO
from hill_muscle_interfaces.msg import Stimulation
from hill_muscle_ros.model import Muscle, MuscleParams
from hill_muscle_ros.model.equations import equivalent_pulse_width
from hill_muscle_ros.model.limb import Limb
from hill_muscle_ros.model.stimulator import ChannelCommand
from hill_muscle_ros.model.stimulus import command_from_pulse_width
from hill_muscle_ros.nodes import _stimulation
from hill_muscle_ros.nodes._inputs import BadInputWarner
from hill_muscle_ros.nodes.limb import LimbNode
from hill_muscle_ros.nodes.simulator import Simulator
from hill_muscle_ros.supervisor import param_text
from ros_helpers import Probe, ProcessGroup, RecordingLogger, node_command

pytestmark = pytest.mark.ros

#: Two channels of Ding's pulse model on a RehaStim 2 (8 channels, 20-500 us, 0-130 mA).
DING = {'activation_model': 'ding2003', 'channel_fractions': [0.5, 0.5],
        'stimulator': 'rehastim2'}
DING_PARAMS = MuscleParams(**dict(DING, channel_fractions=(0.5, 0.5)))
FIRST_ORDER = MuscleParams(stimulator='rehastim2')
#: [s], [Hz] a good command: both channels, 300 us single pulses at 30 Hz.
GOOD_PW_S = 300e-6
GOOD_F_HZ = 30.0


def stimulation(channel=(1, 2), mode=None, pulse_width_s=None, current_a=(),
                frequency_hz=None) -> Stimulation:
    """A message; by default the good command on every channel named."""
    n = len(channel)
    return Stimulation(channel=list(channel), mode=list(mode or ['single'] * n),
                       pulse_width_s=list(pulse_width_s or [GOOD_PW_S] * n),
                       current_a=list(current_a),
                       frequency_hz=list(frequency_hz or [GOOD_F_HZ] * n))


#: Messages a RehaStim 2 refuses, each with what its rejection must say.
BAD_MESSAGES = {
    'unequal arrays': (stimulation(pulse_width_s=[GOOD_PW_S]),
                       'the arrays of a stimulation command must have equal lengths '
                       '(`current_a` may be empty), got channel 2, mode 2, pulse_width_s 1, '
                       'frequency_hz 2, current_a 0'),
    '600 us': (stimulation(pulse_width_s=[GOOD_PW_S, 600e-6]),
               '`pulse_width_s` of channel 2 must be 0 or in [2e-05, 0.0005] s on rehastim2, '
               'got 0.0006'),
    '140 mA': (stimulation(current_a=[0.140, 0.020]),
               '`current_a` of channel 1 must be in [0, 0.13] A on rehastim2, got 0.14'),
}


# -- the checks, no ROS ----------------------------------------------------------


@pytest.mark.parametrize('case', sorted(BAD_MESSAGES))
def test_a_message_a_rehastim2_refuses_is_rejected_naming_the_field_channel_and_value(case):
    msg, reason = BAD_MESSAGES[case]
    with pytest.raises(ValueError) as err:
        _stimulation.check_message(msg, DING_PARAMS, 2)
    assert str(err.value) == reason


def test_a_channel_beyond_the_muscles_is_rejected():
    with pytest.raises(ValueError, match=r"`channel` must be in \[1, 2\] \(the muscle's "
                                         r'channels, `channel_fractions`\), got 3'):
        _stimulation.check_message(stimulation(channel=(1, 3)), DING_PARAMS, 2)


def test_a_nan_pulse_width_is_rejected_naming_channel_and_value():
    with pytest.raises(ValueError, match='`pulse_width_s` of channel 2 .* got nan'):
        _stimulation.check_message(stimulation(pulse_width_s=[GOOD_PW_S, math.nan]),
                                   DING_PARAMS, 2)


def test_a_pulsed_muscle_rejects_a_zero_frequency():
    with pytest.raises(ValueError, match='`frequency_hz` of channel 1 must be positive'):
        _stimulation.check_message(stimulation(channel=(1,), frequency_hz=[0.0]),
                                   MuscleParams(activation_model='ding2003'), 1)


def test_on_a_shared_frequency_a_new_frequency_must_match_the_channels_that_stimulate():
    held = {2: ChannelCommand(2, 'single', GOOD_PW_S, None, GOOD_F_HZ)}
    with pytest.raises(ValueError, match='channel 2 holds 30 Hz, got 40 Hz on channel 1'):
        _stimulation.check_message(stimulation(channel=(1,), frequency_hz=[40.0]),
                                   DING_PARAMS, 2, held)
    # A channel that is off holds no period.
    held = {2: ChannelCommand(2, 'single', 0.0, None, GOOD_F_HZ)}
    assert _stimulation.check_message(stimulation(channel=(1,), frequency_hz=[40.0]),
                                      DING_PARAMS, 2, held)[0].frequency_hz == 40.0


def test_a_good_message_gives_each_channels_command_in_si_units():
    commands = _stimulation.check_message(stimulation(current_a=[0.03, 0.04]), DING_PARAMS, 2)
    assert commands == (ChannelCommand(1, 'single', GOOD_PW_S, 0.03, GOOD_F_HZ),
                        ChannelCommand(2, 'single', GOOD_PW_S, 0.04, GOOD_F_HZ))


def test_first_order_takes_channel_1s_pulse_width_through_the_curve():
    commands = _stimulation.check_message(stimulation(channel=(1,)), FIRST_ORDER, 1)
    assert _stimulation.level_command(commands, FIRST_ORDER) == \
        command_from_pulse_width(GOOD_PW_S, FIRST_ORDER)


def test_first_order_takes_a_current_as_its_equivalent_width():
    commands = _stimulation.check_message(stimulation(channel=(1,), current_a=[0.02]),
                                          FIRST_ORDER, 1)
    pw_eq = equivalent_pulse_width(GOOD_PW_S, 0.02, FIRST_ORDER.current_ref_a,
                                   FIRST_ORDER.chronaxie_s)
    assert _stimulation.level_command(commands, FIRST_ORDER) == \
        command_from_pulse_width(pw_eq, FIRST_ORDER)


def test_the_watchdogs_command_sets_every_channel_to_zero_pulse_width():
    held = {1: ChannelCommand(1, 'doublet', GOOD_PW_S, 0.03, 20.0)}
    off = _stimulation.off_commands(held, 2, DING_PARAMS)
    assert off == (ChannelCommand(1, 'doublet', 0.0, None, 20.0),
                   ChannelCommand(2, 'single', 0.0, None, DING_PARAMS.frequency_hz))
    assert _stimulation.stimulating(held)
    assert not _stimulation.stimulating({c.channel: c for c in off})


# -- the node's logic in this process, no DDS traffic ------------------------------

_RUNS = iter(range(1_000_000))


def _as_if_heard(node):
    """Every output of ``node`` as if a subscription had matched it: a node
    writes only those (the others would reach no one), and these tests read
    the messages it writes, with no subscriber in this process."""
    for pub in node.publishers:
        pub.get_subscription_count = lambda: 1
    return node


@pytest.fixture
def make_node():
    """``make_node(**params)``: a Simulator in rclpy's default context with those
    parameters (unique namespace, watchdog off unless given); destroyed after."""
    nodes = []

    def make(**params):
        params.setdefault('input_timeout_s', 0.0)
        args = ['--ros-args', '-r', f'__ns:=/stim_{os.getpid()}_{next(_RUNS)}']
        for name, value in params.items():
            args += ['-p', f'{name}:={param_text(value)}']
        rclpy.init(args=args)
        node = _as_if_heard(Simulator())
        node._bad_input = BadInputWarner(RecordingLogger())   # its lines, to read them
        nodes.append(node)
        return node

    yield make
    for node in nodes:
        node.destroy_node()
    rclpy.try_shutdown()


def _steps(node, n):
    """Run ``n`` steps of the node at dl_MT = 0, as its tick does."""
    assert node._run_steps([0.0] * n)


#: A fresh process (no kernel called yet) builds the simulator's ding2003
#: muscle as the node does, then prints how many compiled versions of its two
#: read-out kernels numba has loaded.
READ_OUTS_PROCESS = (
    'from hill_muscle_ros.model import MuscleParams\n'
    'from hill_muscle_ros.model.muscle import kernels\n'
    'from hill_muscle_ros.nodes._engine import load_muscle\n'
    'from ros_helpers import RecordingLogger\n'
    'load_muscle(MuscleParams(activation_model="ding2003", channel_fractions=(0.5, 0.5)),\n'
    '            RecordingLogger())\n'
    'k = kernels.compiled()\n'
    'print(len(k.muscle_outputs.signatures), len(k.ding_activation.signatures))\n')


def test_the_read_outs_kernels_load_at_start_up_not_in_a_callback():
    """numba loads a kernel without a given signature at its first call: the
    first /diagnostics report of a ding2003 simulator held its tick 11.5 ms."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(REPO / 'test'), os.environ.get('PYTHONPATH', '')]))
    out = subprocess.run([sys.executable, '-c', READ_OUTS_PROCESS], env=env, cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert [int(n) for n in out.stdout.split()] == [1, 1], out.stdout


def test_an_output_no_subscription_matched_is_not_written(make_node):
    """DDS would deliver it to no one; at 1 kHz those writes were a third of an
    idle simulator's CPU. One that is heard is written at every step."""
    node = make_node()
    written = {}
    for pub in node.publishers:
        heard = pub.topic_name.endswith('/force')
        pub.get_subscription_count = (lambda heard=heard: int(heard))
        pub.publish = (lambda msg, topic=pub.topic_name:
                       written.__setitem__(topic, written.get(topic, 0) + 1))
    _steps(node, 3)
    assert written == {node.resolve_topic_name('force'): 3}


def _warnings(node):
    return [text for level, text in node._bad_input._logger.lines if level == 'warning']


def test_a_first_order_node_takes_stimulation_as_it_takes_pulse_width(make_node):
    node = make_node()
    node._on_pulse_width(Float64(data=GOOD_PW_S))
    from_pulse_width = node._recruitment
    node._on_pulse_width(Float64(data=0.0))
    node._on_stimulation(stimulation(channel=(1,)))
    assert node._recruitment == from_pulse_width == GOOD_PW_S / MuscleParams().pw_max_s


def test_a_rejected_message_keeps_the_last_good_command_with_one_line(make_node):
    node = make_node(stimulator='rehastim2')
    node._on_stimulation(stimulation(channel=(1,)))
    good = node._recruitment
    node._on_stimulation(stimulation(channel=(1,), pulse_width_s=[600e-6]))
    assert node._recruitment == good
    topic = node._sub_stim.topic_name
    assert _warnings(node) == [
        f"ignoring {topic} = {{channel [1], mode ['single'], pulse_width_s [0.0006], "
        'current_a [], frequency_hz [30]}: `pulse_width_s` of channel 1 must be 0 or in '
        '[2e-05, 0.0005] s on rehastim2, got 0.0006; keeping recruitment 0.6, '
        'length_command 0 m']


def test_a_first_order_node_has_one_channel(make_node):
    node = make_node()
    node._on_stimulation(stimulation(channel=(1, 2)))
    assert node._recruitment == 0.0
    assert 'got 2' in _warnings(node)[0]


def test_rejected_messages_are_throttled_per_topic_and_counted(make_node):
    node = make_node(stimulator='rehastim2')
    for _ in range(3):
        node._on_stimulation(BAD_MESSAGES['600 us'][0])
    assert len(_warnings(node)) == 1
    assert node._bad_input.counts == {node._sub_stim.topic_name: 3}


def test_a_first_order_node_publishes_r_as_its_one_activation(make_node):
    node = make_node()
    node._on_stimulation(stimulation(channel=(1,)))
    _steps(node, 1)
    msg = node._activation_msg
    assert list(msg.data) == [node._muscle.recruitment] == [0.6]
    assert [(d.label, d.size) for d in msg.layout.dim] == [('channel', 1)]


def test_the_watchdog_takes_stimulation_as_an_input(make_node):
    node = make_node(input_timeout_s=0.01)   # 10 steps at 1 kHz
    node._on_stimulation(stimulation(channel=(1,)))
    _steps(node, 10)
    assert node._recruitment == 0.6 and not node._watchdog_tripped
    node._on_stimulation(stimulation(channel=(1,)))   # keeps it alive
    _steps(node, 10)
    assert node._recruitment == 0.6
    _steps(node, 2)
    assert node._recruitment == 0.0 and node._watchdog_tripped


def test_the_pulse_parameters_are_declared_with_descriptors(make_node):
    node = make_node()
    stimulator = node.describe_parameter('stimulator')
    assert stimulator.type == rclpy.Parameter.Type.STRING.value
    assert stimulator.additional_constraints == 'one of: generic, rehastim2, p24'
    assert 'generic, rehastim2 or p24' in stimulator.description
    assert node.describe_parameter('activation_model').additional_constraints == \
        'one of: first_order, ding2003'
    fractions = node.describe_parameter('channel_fractions')
    assert fractions.type == rclpy.Parameter.Type.DOUBLE_ARRAY.value
    assert fractions.additional_constraints == 'each entry >= 0 and <= 1e+12 (finite)'
    assert node.describe_parameter('frequency_hz').description.startswith('[Hz] ')
    assert 'state kept' in node.describe_parameter('stimulator').description


def _offline(node, commands, n):
    """[N] the forces of ``n`` steps of a muscle like the node's, given ``commands``
    at t = 0 and stepped by its trains at the node's dt, offline."""
    muscle = Muscle(node._params, build=node._muscle.build)
    muscle.stimulate(commands)
    return [muscle.step_trains(0.0, node._dt_s).force_n for _ in range(n)]


def _node_forces(node, n):
    forces = []
    for _ in range(n):
        _steps(node, 1)
        forces.append(node._force_msg.data)
    return forces


def test_a_ding2003_node_steps_its_muscle_by_the_channels_trains(make_node):
    node = make_node(**DING)
    msg = stimulation()
    node._on_stimulation(msg)
    forces = _node_forces(node, 300)
    assert forces == _offline(node, _stimulation.check_message(msg, DING_PARAMS, 2), 300)
    assert max(forces) > 1.0
    assert list(node._activation_msg.data) == node._muscle.activation.tolist()
    assert len(node._activation_msg.data) == 2 and min(node._activation_msg.data) > 0.0


def test_a_rejected_message_leaves_every_channels_train_as_it_was(make_node):
    node = make_node(**DING)
    good = stimulation()
    node._on_stimulation(good)
    forces = _node_forces(node, 100)
    for msg, _ in BAD_MESSAGES.values():
        node._on_stimulation(msg)
    forces += _node_forces(node, 200)
    assert forces == _offline(node, _stimulation.check_message(good, DING_PARAMS, 2), 300)
    assert node._bad_input.total == len(BAD_MESSAGES)


def test_with_ding2003_pulse_width_is_channel_1_at_frequency_hz(make_node):
    node = make_node(**DING, frequency_hz=20.0)
    node._on_pulse_width(Float64(data=GOOD_PW_S))
    assert node._held == {1: ChannelCommand(1, 'single', GOOD_PW_S, None, 20.0)}
    forces = _node_forces(node, 300)
    assert forces == _offline(node, [ChannelCommand(1, 'single', GOOD_PW_S, None, 20.0)], 300)
    a1, a2 = node._activation_msg.data
    assert a1 > 0.0 and a2 == 0.0


def test_with_ding2003_pulse_width_is_checked_against_the_stimulator(make_node):
    node = make_node(**DING)
    node._on_pulse_width(Float64(data=600e-6))
    assert node._held == {}
    assert '`pulse_width_s` of channel 1 must be 0 or in [2e-05, 0.0005] s on rehastim2, ' \
           'got 0.0006' in _warnings(node)[0]


def test_with_ding2003_recruitment_is_refused(make_node):
    node = make_node(**DING)
    node._on_recruitment(Float64(data=0.5))
    assert node._recruitment == 0.0 and not node._stim_messages
    assert 'does not take: send pulse_width (channel 1 at frequency_hz) or stimulation' \
        in _warnings(node)[0]


def test_with_ding2003_the_watchdog_turns_every_channel_off(make_node):
    node = make_node(**DING, input_timeout_s=0.05)   # 50 steps at 1 kHz
    msg = stimulation()
    node._on_stimulation(msg)
    forces = _node_forces(node, 51)
    assert not node._watchdog_tripped
    forces += _node_forces(node, 1000)   # trips before the 52nd step
    assert node._watchdog_tripped
    assert [c.pulse_width_s for c in node._held.values()] == [0.0, 0.0]
    # The muscle given the good command, then pulse width 0 on both channels.
    muscle = Muscle(node._params, build=node._muscle.build)
    muscle.stimulate(_stimulation.check_message(msg, DING_PARAMS, 2))
    offline = [muscle.step_trains(0.0, node._dt_s).force_n for _ in range(51)]
    muscle.stimulate([ChannelCommand(c, 'single', 0.0, None, GOOD_F_HZ) for c in (1, 2)])
    offline += [muscle.step_trains(0.0, node._dt_s).force_n for _ in range(1000)]
    assert forces == offline
    assert max(node._muscle.activation) < 0.01   # no pulse for a second
    # The next message brings it back.
    node._on_stimulation(stimulation(channel=(2,)))
    assert not node._watchdog_tripped and node._held[2].pulse_width_s == GOOD_PW_S


def test_a_reset_stops_every_channel(make_node):
    node = make_node(**DING)
    node._on_stimulation(stimulation())
    _steps(node, 50)
    node._on_reset(Trigger.Request(), Trigger.Response())
    assert node._held == {}
    assert _node_forces(node, 100) == [0.0] * 100


# -- over DDS ---------------------------------------------------------------------

NS = '/stim'
RATE_HZ = 200.0
#: Steps of 1 / RATE_HZ: 1.5 s for the force to settle under a command, then
#: 0.5 s (15 pulses at 30 Hz) of its ripple as the reference band.
SETTLE_STEPS = 300
BAND_STEPS = 100
#: [-] the force under a kept command stays within its band, this much wider.
BAND_TOL = 0.05


@pytest.fixture(scope='module')
def shared(tmp_path_factory):
    """A ding2003 simulator with two channels on a RehaStim 2, and a probe."""
    tmp = tmp_path_factory.mktemp('stimulation')
    params = tmp / 'ding.yaml'
    params.write_text(yaml.safe_dump({'/**': {'ros__parameters': dict(
        DING, rate_hz=RATE_HZ, input_timeout_s=0.0)}}))
    with ProcessGroup(tmp) as procs, Probe('stimulation_probe') as probe:
        sim = procs.start('ding', node_command('simulator', ns=NS, params_files=[params]))
        recs = {'force': probe.record(f'{NS}/force', Float64),
                'activation': probe.record(f'{NS}/activation', Float64MultiArray)}
        for rec in recs.values():   # the simulator's publishers seen from here
            probe.wait_for_messages(rec, procs=[sim])
        yield {'probe': probe, 'sim': sim, 'recs': recs}


@pytest.fixture(scope='module')
def stimulated(shared):
    """The shared simulator reset, then given the good command on both channels
    (sent once the simulator's subscription is matched), and the band of its
    settled force: (low, high) [N]. Once for the module: the tests after it
    send only messages that must be rejected, so the good command holds, and
    each checks the force against this band from its own mark on (a message
    taken by mistake fails the test that sent it and every one after)."""
    probe, sim, force = shared['probe'], shared['sim'], shared['recs']['force']
    assert probe.call(Trigger, f'{NS}/reset', Trigger.Request(), procs=[sim]).success
    probe.wait_for_value(force, lambda f: f == 0.0, 'zero force at rest', mark=force.mark(),
                         procs=[sim])
    probe.publish_when_matched(f'{NS}/stimulation', stimulation(), procs=[sim])
    start = probe.wait_for_value(force, lambda f: f > 1.0, 'the force rising',
                                 mark=force.mark(), procs=[sim])
    settled = probe.wait_for_messages(force, SETTLE_STEPS, mark=start, procs=[sim])
    band = [m.data for m in settled[-BAND_STEPS:]]
    return dict(shared, band=(min(band), max(band)))


def test_a_two_channel_stimulation_drives_the_force_and_both_activations(stimulated):
    probe, sim, activation = stimulated['probe'], stimulated['sim'], \
        stimulated['recs']['activation']
    low, high = stimulated['band']
    assert low > 1.0
    msgs = probe.wait_for_messages(activation, BAND_STEPS, mark=activation.mark(), procs=[sim])
    assert all(len(m.data) == 2 for m in msgs)
    assert all(min(m.data) > 0.0 for m in msgs)
    assert [(d.label, d.size) for d in msgs[-1].layout.dim] == [('channel', 2)]


def _rejection_line(shared, msg, reason, log_start):
    """Send ``msg`` until the simulator logs its rejection; return that line.

    Warnings are throttled per topic (1 s): an earlier message may hold this
    second's, so the message is sent again until its own line appears.
    """
    probe, sim = shared['probe'], shared['sim']
    pub = probe.publisher(f'{NS}/stimulation', Stimulation)

    def line():
        found = [ln for ln in sim.output()[log_start:].splitlines() if reason in ln]
        if not found:
            pub.publish(msg)
        return found[0] if found else None

    return probe.spin_until(line, f'the warning {reason!r}', procs=[sim])


@pytest.mark.parametrize('case', sorted(BAD_MESSAGES))
def test_a_rejected_message_is_one_clear_line_and_the_force_keeps_the_last_good_command(
        stimulated, case):
    msg, reason = BAD_MESSAGES[case]
    probe, sim, force = stimulated['probe'], stimulated['sim'], stimulated['recs']['force']
    line = _rejection_line(stimulated, msg, reason, len(sim.output()))
    assert f'ignoring {NS}/stimulation = {_stimulation.message_text(msg)}: {reason}; keeping ' \
           'channel 1: single 0.0003 s at 30 Hz, channel 2: single 0.0003 s at 30 Hz' in line
    after = [m.data for m in probe.wait_for_messages(force, BAND_STEPS, mark=force.mark(),
                                                     procs=[sim])]
    low, high = stimulated['band']
    assert low * (1.0 - BAND_TOL) <= min(after) and max(after) <= high * (1.0 + BAND_TOL), \
        (min(after), max(after), stimulated['band'])


# -- the limb node: a ding2003 quadriceps with two channels -----------------------

KNEE_YAML = REPO / 'config' / 'knee.yaml'


def _ding_knee(path):
    """config/knee.yaml with the quadriceps on Ding's pulse model, two channels
    on a RehaStim 2 (no first-order time constants); the hamstrings as they are."""
    text = yaml.safe_load(KNEE_YAML.read_text())
    section = text['/**']['ros__parameters']
    section['quadriceps'].update(activation_model='ding2003', channel_fractions=[0.5, 0.5],
                                 stimulator='rehastim2', tau_act_s=0.0, tau_deact_s=0.0)
    path.write_text(yaml.safe_dump(text))
    return path


@pytest.fixture
def make_limb(tmp_path):
    """``make_limb(**params)``: a LimbNode on the ding2003 knee in rclpy's default
    context (unique namespace, watchdog off unless given); destroyed after."""
    nodes = []
    plant = _ding_knee(tmp_path / 'ding_knee.yaml')

    def make(**params):
        params.setdefault('input_timeout_s', 0.0)
        args = ['--ros-args', '--params-file', str(plant),
                '-r', f'__ns:=/stim_{os.getpid()}_{next(_RUNS)}']
        for name, value in params.items():
            args += ['-p', f'{name}:={param_text(value)}']
        rclpy.init(args=args)
        node = _as_if_heard(LimbNode())
        node._bad_input = BadInputWarner(RecordingLogger())
        nodes.append(node)
        return node

    yield make
    for node in nodes:
        node.destroy_node()
    rclpy.try_shutdown()


def _limb_angles(node, n):
    angles = []
    for _ in range(n):
        assert node._run_steps(1)
        angles.append(node._joint_msg.position[0])
    return angles


def _offline_limb_angles(node, commands, n, off_after=None):
    """[rad] ``n`` steps of the node's plant, offline, the quadriceps given
    ``commands`` at t = 0 (and every channel off after ``off_after`` steps)."""
    limb = Limb(node._plant, build=node._limb.build)
    limb.stimulate('quadriceps', commands)
    angles = []
    for k in range(n):
        if k == off_after:
            limb.stimulate('quadriceps', [ChannelCommand(c, 'single', 0.0, None, GOOD_F_HZ)
                                          for c in (1, 2)])
        angles.append(limb.step([0.0, 0.0], 0.0, node._dt_s).theta_rad)
    return angles


def test_a_limb_nodes_ding2003_muscle_is_driven_by_its_channels_trains(make_limb):
    node = make_limb()
    msg = stimulation()
    node._on_stimulation(0, msg)
    angles = _limb_angles(node, 500)
    quad = node._plant.muscles[0].params
    assert angles == _offline_limb_angles(node, _stimulation.check_message(msg, quad, 2), 500)
    assert angles[-1] > math.radians(5.0)   # the knee extends
    assert len(node._activation_msgs[0].data) == 2 and min(node._activation_msgs[0].data) > 0
    assert node._pub_activation[1] is None   # the first_order hamstrings have no channels


def test_a_limb_nodes_rejected_message_leaves_the_trains_as_they_were(make_limb):
    node = make_limb()
    good = stimulation()
    node._on_stimulation(0, good)
    angles = _limb_angles(node, 100)
    for bad, reason in BAD_MESSAGES.values():
        node._on_stimulation(0, bad)
    angles += _limb_angles(node, 200)
    quad = node._plant.muscles[0].params
    assert angles == _offline_limb_angles(node, _stimulation.check_message(good, quad, 2), 300)
    topic = node._sub_stim[0].topic_name
    assert _warnings(node) == [
        f'ignoring {topic} = {_stimulation.message_text(BAD_MESSAGES["unequal arrays"][0])}: '
        f'{BAD_MESSAGES["unequal arrays"][1]}; keeping channel 1: single 0.0003 s at 30 Hz, '
        'channel 2: single 0.0003 s at 30 Hz']   # the other two within the throttle second


def test_a_limb_nodes_pulse_width_is_channel_1_of_a_ding2003_muscle(make_limb):
    node = make_limb()
    node._on_pulse_width(0, Float64(data=GOOD_PW_S))
    quad = node._plant.muscles[0].params
    assert node._held[0] == {1: ChannelCommand(1, 'single', GOOD_PW_S, None, quad.frequency_hz)}
    node._on_recruitment(0, Float64(data=0.5))
    assert 'does not take' in _warnings(node)[0]


def test_a_limb_nodes_first_order_muscle_takes_stimulation_as_pulse_width(make_limb):
    node = make_limb()
    node._on_pulse_width(1, Float64(data=GOOD_PW_S))
    from_pulse_width = node._commands[1]
    node._on_pulse_width(1, Float64(data=0.0))
    node._on_stimulation(1, stimulation(channel=(1,), pulse_width_s=[GOOD_PW_S]))
    assert node._commands[1] == from_pulse_width > 0.0


def test_a_limb_nodes_watchdog_turns_a_quiet_muscles_channels_off(make_limb):
    node = make_limb(input_timeout_s=0.05)
    msg = stimulation()
    node._on_stimulation(0, msg)
    angles = _limb_angles(node, 300)   # trips before the 52nd step
    assert node._watchdog_tripped == [True, False]
    assert [c.pulse_width_s for c in node._held[0].values()] == [0.0, 0.0]
    quad = node._plant.muscles[0].params
    assert angles == _offline_limb_angles(node, _stimulation.check_message(msg, quad, 2), 300,
                                          off_after=51)


def test_over_dds_a_limb_muscles_stimulation_extends_the_knee_with_two_activations(
        shared, tmp_path):
    probe = shared['probe']
    ns = '/stim_knee'
    overrides = tmp_path / 'overrides.yaml'
    overrides.write_text(yaml.safe_dump({'/**': {'ros__parameters': {
        'rate_hz': RATE_HZ, 'input_timeout_s': 0.0}}}))
    joint = probe.record(f'{ns}/joint_states', JointState)
    activation = probe.record(f'{ns}/quadriceps/activation', Float64MultiArray)
    with ProcessGroup(tmp_path) as procs:
        node = procs.start('knee', node_command('limb_simulator', ns=ns, params_files=[
            _ding_knee(tmp_path / 'ding_knee.yaml'), overrides]))
        probe.wait_for_messages(joint, procs=[node])
        probe.publish_when_matched(f'{ns}/quadriceps/stimulation', stimulation(), procs=[node])
        probe.spin_until(lambda: any(m.position[0] > math.radians(5.0) for m in joint.messages),
                         'the knee extended past 5 deg', procs=[node])
        msgs = probe.wait_for_messages(activation, BAND_STEPS, procs=[node])
    assert all(len(m.data) == 2 for m in msgs)
    assert min(msgs[-1].data) > 0.0
