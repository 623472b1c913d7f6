"""The simulator's ``stimulation`` input (hill_muscle_interfaces/msg/Stimulation)
and its ``activation`` output.

Three layers, cheapest first:

- the checks of a message (hill_muscle_ros.nodes._stimulation), no ROS;
- the node's callbacks and steps in this process (a Simulator made in
  rclpy's default context, its callbacks called as the executor would call
  them, no DDS traffic);
- one ding2003 simulator with two channels on a RehaStim 2 over real DDS
  (``/stim``, 200 Hz, watchdog off), shared by the module.
"""
import math
import os

import pytest
import rclpy
import yaml
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import Trigger

from hill_muscle_interfaces.msg import Stimulation
from hill_muscle_ros.model import MuscleParams
from hill_muscle_ros.model.equations import equivalent_pulse_width
from hill_muscle_ros.model.stimulator import ChannelCommand
from hill_muscle_ros.model.stimulus import command_from_pulse_width
from hill_muscle_ros.nodes import _stimulation
from hill_muscle_ros.nodes._inputs import BadInputWarner
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
        node = Simulator()
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
