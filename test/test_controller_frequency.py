"""The force controller modulating frequency (``modulate: frequency``): its
output, read as a fraction of ``pw_max_s``, sets the frequency of channel 1
at a fixed pulse width, sent as ``hill_muscle_interfaces/msg/Stimulation``.

Most tests run the pure core (:mod:`hill_muscle_ros.control.pi`) on a clock
the test drives; the last ones run the node as a process over DDS.
"""
from __future__ import annotations

import dataclasses
import itertools
import math
import os
import signal

import pytest

from hill_muscle_ros.control import (ControllerParams, ForceController, check_frequency_range,
                                     frequency_command)
from hill_muscle_ros.model.stimulator import stimulator_profile

FREQ = ControllerParams(modulate='frequency')
#: [s] control period of the driven clock: the node's default 100 Hz
DT_S = 0.01
#: [N] force target of the closed loop
TARGET_N = 20.0
_RUNS = itertools.count()


def test_the_default_modulates_pulse_width():
    assert ControllerParams().modulate == 'pulse_width'


def test_frequency_modulation_defaults_are_500_us_and_11_5_to_60_hz():
    p = ControllerParams()
    assert (p.pulse_width_s, p.frequency_min_hz, p.frequency_max_hz) == (500e-6, 11.5, 60.0)


def test_an_output_of_zero_is_no_stimulation():
    command = frequency_command(0.0, FREQ)
    assert (command.pulse_width_s, command.frequency_hz) == (0.0, FREQ.frequency_min_hz)


@pytest.mark.parametrize('u', [1e-6, 0.25, 0.5, 1.0])
def test_the_output_maps_linearly_onto_the_frequency_range(u):
    command = frequency_command(u * FREQ.pw_max_s, FREQ)
    want = FREQ.frequency_min_hz + u * (FREQ.frequency_max_hz - FREQ.frequency_min_hz)
    assert command.frequency_hz == pytest.approx(want, rel=1e-12)


def test_an_output_beyond_pw_max_is_frequency_max():
    assert frequency_command(2.0 * FREQ.pw_max_s, FREQ).frequency_hz == FREQ.frequency_max_hz


def test_the_command_is_channel_1_single_pulses_at_the_fixed_width_and_no_current():
    command = frequency_command(0.3 * FREQ.pw_max_s, FREQ)
    assert (command.channel, command.mode, command.pulse_width_s, command.current_a) == \
        (1, 'single', FREQ.pulse_width_s, None)


def test_the_control_law_is_the_same_in_both_modes():
    """Only what the output drives differs: the PI and its feedforward are
    untouched, so ``pulse_width`` mode gives today's pulse widths."""
    outputs = []
    for params in (ControllerParams(), FREQ):
        ctrl = ForceController(params)
        outputs.append([ctrl.update(TARGET_N, f, DT_S) for f in (0.0, 5.0, 12.0, 19.0, 22.0)])
    assert outputs[0] == outputs[1]


def test_frequency_control_holds_a_target_on_a_force_frequency_plant():
    """A plant whose force rises with frequency, F = 40 N f / (f + 20 Hz),
    through a 0.1 s lag: 20 N is f = 20 Hz. The PI alone (no feedforward)
    brings the force there on the test's clock."""
    params = dataclasses.replace(FREQ, feedforward='none')
    ctrl = ForceController(params)
    force_n, alpha = 0.0, -math.expm1(-DT_S / 0.1)
    for _ in range(round(3.0 / DT_S)):
        command = frequency_command(ctrl.update(TARGET_N, force_n, DT_S), params)
        plant_n = (40.0 * command.frequency_hz / (command.frequency_hz + 20.0)
                   if command.pulse_width_s > 0.0 else 0.0)
        force_n += (plant_n - force_n) * alpha
    assert force_n == pytest.approx(TARGET_N, rel=0.01)
    assert command.frequency_hz == pytest.approx(20.0, rel=0.01)
    assert command.pulse_width_s == params.pulse_width_s


def test_frequency_max_not_above_frequency_min_is_rejected_by_name():
    with pytest.raises(ValueError, match=r'`frequency_max_hz` must be above `frequency_min_hz` '
                                         r'\(30\.0 Hz\), got 30\.0'):
        ControllerParams(frequency_min_hz=30.0, frequency_max_hz=30.0)


def test_a_fixed_pulse_width_above_pw_max_is_rejected_in_frequency_mode():
    with pytest.raises(ValueError, match=r'`pulse_width_s` must be at most `pw_max_s` '
                                         r'\(0\.0005 s\) with modulate frequency, got 0\.0006'):
        ControllerParams(modulate='frequency', pulse_width_s=600e-6)


def test_a_fixed_pulse_width_above_pw_max_is_unused_in_pulse_width_mode():
    assert ControllerParams(pulse_width_s=600e-6).pulse_width_s == 600e-6


def test_an_unknown_modulation_is_rejected_by_name():
    with pytest.raises(ValueError, match=r'`modulate` must be one of pulse_width, frequency, '
                                         r"got 'current'"):
        ControllerParams(modulate='current')


def test_a_frequency_range_the_stimulator_rejects_is_refused_naming_the_parameter():
    params = dataclasses.replace(FREQ, frequency_max_hz=200.0)   # period 5 ms < 8 ms
    with pytest.raises(ValueError, match=r'`frequency_max_hz` 200\.0 Hz is refused by the '
                                         r'stimulator: `frequency_hz` of channel 1 must give '
                                         r'a period in \[0\.008, 1\.025\] s .* on rehastim2, '
                                         r'got 200\.0'):
        check_frequency_range(params, stimulator_profile('rehastim2'))


def test_a_fixed_pulse_width_the_stimulator_rejects_is_refused_naming_it():
    params = dataclasses.replace(FREQ, pulse_width_s=10e-6)   # the RehaStim 2: 0 or 20-500 us
    with pytest.raises(ValueError, match=r'`pulse_width_s` 1e-05 s is refused by the '
                                         r'stimulator: `pulse_width_s` of channel 1 must be 0 '
                                         r'or in \[2e-05, 0\.0005\] s on rehastim2'):
        check_frequency_range(params, stimulator_profile('rehastim2'))


def test_the_default_range_passes_every_stimulator():
    for name in ('generic', 'rehastim2', 'p24'):
        check_frequency_range(FREQ, stimulator_profile(name, FREQ.pw_max_s))


# -- the node, as a process -----------------------------------------------------


def _namespace() -> str:
    """Unique even if another test run drew the same ROS_DOMAIN_ID."""
    return f'/ctrl_freq_{os.getpid()}_{next(_RUNS)}'


@pytest.fixture
def frequency_controller(tmp_path):
    """A controller in frequency mode, stimulating against a fake force of 0 N:
    ``(probe, proc, stimulation recording, namespace)``."""
    from hill_muscle_interfaces.msg import Stimulation
    from rclpy.duration import Duration
    from std_msgs.msg import Float64

    from ros_helpers import Probe, ProcessGroup, node_command

    ns = _namespace()
    with ProcessGroup(tmp_path) as procs, Probe('ctrl_freq_probe') as probe:
        proc = procs.start('controller', node_command(
            'force_controller', ns=ns, params={'modulate': 'frequency',
                                               'feedback_timeout_s': 30.0}))
        stim = probe.record(f'{ns}/stimulation', Stimulation)
        force_pub = probe.publisher(f'{ns}/force', Float64)
        target_pub = probe.publisher(f'{ns}/force_target', Float64)
        # Discovery both ways: the controller's subscriptions match the
        # probe's writers, and its stimulation writer reaches the probe.
        probe.spin_until(lambda: (force_pub.get_subscription_count() > 0
                                  and target_pub.get_subscription_count() > 0
                                  and stim.messages),
                         'discovery both ways', procs=[proc])
        target_pub.publish(Float64(data=TARGET_N))
        probe.spin_until(lambda: target_pub.wait_for_all_acked(Duration(seconds=0)),
                         'the controller to acknowledge the target', procs=[proc])
        force_pub.publish(Float64(data=0.0))
        yield probe, proc, stim, ns


def _stimulating(msg) -> bool:
    return bool(msg.pulse_width_s) and msg.pulse_width_s[0] > 0.0


@pytest.mark.ros
def test_frequency_mode_sends_channel_1_at_the_fixed_width_on_stimulation_only(
        frequency_controller):
    probe, proc, stim, ns = frequency_controller
    probe.spin_until(lambda: any(_stimulating(m) for m in stim.messages), 'stimulation',
                     procs=[proc])
    zeros_before = stim.messages[:next(i for i, m in enumerate(stim.messages)
                                       if _stimulating(m))]
    on = [m for m in stim.messages if _stimulating(m)]
    assert zeros_before and all(list(m.pulse_width_s) == [0.0] for m in zeros_before)
    for msg in on:
        assert (list(msg.channel), list(msg.mode), list(msg.pulse_width_s),
                len(msg.current_a)) == ([1], ['single'], [FREQ.pulse_width_s], 0)
        assert FREQ.frequency_min_hz < msg.frequency_hz[0] <= FREQ.frequency_max_hz
    assert probe.node.count_publishers(f'{ns}/pulse_width') == 0


@pytest.mark.ros
def test_frequency_mode_sends_zero_stimulation_last_on_stop(frequency_controller):
    probe, proc, stim, _ = frequency_controller
    probe.spin_until(lambda: any(_stimulating(m) for m in stim.messages), 'stimulation',
                     procs=[proc])
    signalled = len(stim.messages)
    proc.popen.send_signal(signal.SIGINT)
    probe.spin_until(lambda: proc.returncode is not None, 'the controller to exit')
    # The exit says nothing of what the probe has taken yet: wait for the zero.
    probe.spin_until(lambda: any(not _stimulating(m) for m in stim.messages[signalled:]),
                     'the zero stimulation')
    assert list(stim.messages[-1].pulse_width_s) == [0.0]


@pytest.mark.ros
def test_a_frequency_range_the_stimulator_rejects_stops_the_node_naming_it(tmp_path):
    from ros_helpers import ProcessGroup, node_command

    with ProcessGroup(tmp_path) as procs:
        proc = procs.start('controller', node_command('force_controller', params={
            'modulate': 'frequency', 'frequency_max_hz': 200.0, 'stimulator': 'rehastim2'}))
        status = proc.wait()
    log = proc.output()
    assert status != 0
    assert ('parameter `frequency_max_hz` 200.0 Hz is refused by the stimulator: '
            '`frequency_hz` of channel 1 must give a period') in log
    assert 'Traceback' not in log
