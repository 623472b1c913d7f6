"""Stimulator profiles (doc/model.md section 10): a command out of the device's
range is an error naming the field, the channel, the device and the value.

The device limits are those read in pyScienceMode 1.1.5 (the module's docstring
says where); the tests check each limit on both sides of its edge.
"""
import math

import numpy as np
import pytest

from hill_muscle_ros.model.stimulator import (P24, REHASTIM2, STIMULATORS, ChannelCommand,
                                              StimulatorProfile, check_channel_command,
                                              check_stimulation, generic_profile,
                                              stimulator_profile)

GENERIC = generic_profile(500e-6)


def command(profile, channel=1, frequency_hz=30.0, pulse_width_s=300e-6, current_a=None,
            mode='single', burst_interval_s=0.005):
    return check_channel_command(profile, channel, frequency_hz, pulse_width_s, current_a,
                                 mode, burst_interval_s)


def test_the_profiles_are_the_three_of_the_table():
    assert STIMULATORS == ('generic', 'rehastim2', 'p24')
    assert stimulator_profile('rehastim2') is REHASTIM2
    assert stimulator_profile('p24') is P24
    assert stimulator_profile('generic', pw_max_s=400e-6) == generic_profile(400e-6)


def test_an_unknown_stimulator_names_the_choices():
    with pytest.raises(ValueError, match='`stimulator` must be one of generic, rehastim2, p24, '
                                         "got 'rehastim3'"):
        stimulator_profile('rehastim3')


def test_a_good_command_comes_back_as_floats():
    assert command(REHASTIM2, 3, 25, 200e-6, 0.05, 'doublet') == ChannelCommand(
        3, 'doublet', 200e-6, 0.05, 25.0)


# -- channels ------------------------------------------------------------------------


@pytest.mark.parametrize('profile', [REHASTIM2, P24])
def test_the_devices_have_channels_1_to_8(profile):
    assert command(profile, channel=1).channel == 1
    assert command(profile, channel=8).channel == 8
    for bad in (0, 9):
        with pytest.raises(ValueError, match=f'`channel` must be in \\[1, 8\\] on {profile.name}, '
                                             f'got {bad}'):
            command(profile, channel=bad)


def test_the_generic_stimulator_has_any_channel_from_1():
    assert command(GENERIC, channel=200).channel == 200
    with pytest.raises(ValueError, match='`channel` must be an integer >= 1 on generic, got 0'):
        command(GENERIC, channel=0)


def test_a_channel_number_from_an_unsigned_byte_array_is_an_integer():
    assert command(REHASTIM2, channel=np.uint8(2)).channel == 2


@pytest.mark.parametrize('bad', [1.0, True, '1', None])
def test_a_channel_that_is_not_an_integer_is_rejected(bad):
    with pytest.raises(ValueError, match='`channel` must be in'):
        command(REHASTIM2, channel=bad)


# -- pulse width ----------------------------------------------------------------------


@pytest.mark.parametrize('pw', [0.0, 20e-6, 300e-6, 500e-6])
def test_the_rehastim2_takes_a_zero_width_or_20_to_500_us(pw):
    assert command(REHASTIM2, pulse_width_s=pw).pulse_width_s == pw


@pytest.mark.parametrize('pw', [1e-6, 19e-6, 501e-6, -1e-6])
def test_the_rehastim2_rejects_other_widths_naming_field_channel_and_value(pw):
    with pytest.raises(ValueError, match=(f'^`pulse_width_s` of channel 2 must be 0 or in '
                                          f'\\[2e-05, 0.0005\\] s on rehastim2, got {pw!r}$')):
        command(REHASTIM2, channel=2, pulse_width_s=pw)


def test_the_p24_takes_widths_up_to_4095_us():
    assert command(P24, pulse_width_s=4095e-6).pulse_width_s == 4095e-6
    with pytest.raises(ValueError, match=r'`pulse_width_s` of channel 1 must be in '
                                         r'\[0, 0.004095\] s on p24, got 0.0041'):
        command(P24, pulse_width_s=0.0041)


def test_the_generic_stimulator_takes_widths_up_to_the_muscles_pw_max():
    assert command(GENERIC, pulse_width_s=500e-6).pulse_width_s == 500e-6
    with pytest.raises(ValueError, match=r'^`pulse_width_s` of channel 2 must be in '
                                         r'\[0, 0.0005\] s on generic, got 0.0007$'):
        command(GENERIC, channel=2, pulse_width_s=0.0007)
    assert command(generic_profile(800e-6), pulse_width_s=0.0007).pulse_width_s == 0.0007


@pytest.mark.parametrize('bad', [math.nan, math.inf, 'wide', None])
def test_a_width_that_is_not_a_finite_number_is_rejected(bad):
    with pytest.raises(ValueError, match='`pulse_width_s` of channel 1 must be'):
        command(GENERIC, pulse_width_s=bad)


# -- current --------------------------------------------------------------------------


@pytest.mark.parametrize('profile, max_a', [(GENERIC, 0.2), (REHASTIM2, 0.130), (P24, 0.130)])
def test_the_current_goes_from_0_to_the_devices_largest(profile, max_a):
    assert command(profile, current_a=0.0).current_a == 0.0
    assert command(profile, current_a=max_a).current_a == max_a
    for bad in (max_a * 1.01, -0.001):
        with pytest.raises(ValueError, match=f'`current_a` of channel 1 must be in \\[0, '
                                             f'{max_a:g}\\] A on {profile.name}, got {bad!r}'):
            command(profile, current_a=bad)


def test_no_current_means_the_reference_current():
    assert command(REHASTIM2, current_a=None).current_a is None


# -- frequency ------------------------------------------------------------------------


@pytest.mark.parametrize('f', [125.0, 1 / 1.025, 30.0])
def test_the_rehastim2_takes_periods_of_8_to_1025_ms(f):
    assert command(REHASTIM2, frequency_hz=f).frequency_hz == f


@pytest.mark.parametrize('f', [126.0, 0.9, 0.0, -5.0, math.nan])
def test_the_rehastim2_rejects_other_periods(f):
    with pytest.raises(ValueError, match=r'`frequency_hz` of channel 1 must give a period in '
                                         r'\[0.008, 1.025\] s .* on rehastim2'):
        command(REHASTIM2, frequency_hz=f)


def test_the_p24_takes_0_5_to_2000_hz():
    assert command(P24, frequency_hz=0.5).frequency_hz == 0.5
    assert command(P24, frequency_hz=2000.0).frequency_hz == 2000.0
    for bad in (0.4, 2001.0):
        with pytest.raises(ValueError, match=r'`frequency_hz` of channel 1 must be in '
                                             r'\[0.5, 2000\] Hz on p24'):
            command(P24, frequency_hz=bad)


def test_the_generic_stimulator_takes_0_to_1000_hz():
    assert command(GENERIC, frequency_hz=0.0).frequency_hz == 0.0
    assert command(GENERIC, frequency_hz=1000.0).frequency_hz == 1000.0
    with pytest.raises(ValueError, match=r'must be in \[0, 1000\] Hz on generic, got 1000.5'):
        command(GENERIC, frequency_hz=1000.5)


# -- modes and bursts -----------------------------------------------------------------


def test_a_mode_must_be_single_doublet_or_triplet():
    with pytest.raises(ValueError, match="`mode` of channel 1 must be one of single, doublet, "
                                         "triplet, got 'burst'"):
        command(GENERIC, mode='burst')


@pytest.mark.parametrize('profile', [GENERIC, REHASTIM2, P24])
def test_a_burst_interval_goes_from_2_to_129_ms(profile):
    for d in (0.002, 0.129):
        command(profile, frequency_hz=5.0, mode='doublet', burst_interval_s=d)
    for bad in (0.0019, 0.1291):
        with pytest.raises(ValueError, match=r'`burst_interval_s` of channel 1 must be in '
                                             r'\[0.002, 0.129\] s'):
            command(profile, frequency_hz=5.0, mode='doublet', burst_interval_s=bad)


def test_a_single_pulse_has_no_burst_interval_to_check():
    assert command(REHASTIM2, mode='single', burst_interval_s=1.0).mode == 'single'


def test_bursts_must_fit_in_their_period():
    # A triplet 5 ms apart spans 10 ms: below 100 Hz it fits.
    assert command(REHASTIM2, frequency_hz=99.0, mode='triplet').frequency_hz == 99.0
    with pytest.raises(ValueError, match=r'`frequency_hz` of channel 1 must be below 100 Hz '
                                         r'for a triplet with pulses 0.005 s apart on rehastim2 '
                                         r'\(its bursts would overlap\), got 100.0'):
        command(REHASTIM2, frequency_hz=100.0, mode='triplet')


# -- a command for several channels -------------------------------------------------------


def test_parallel_arrays_give_one_command_per_entry_in_their_order():
    got = check_stimulation(P24, [3, 1], ['single', 'doublet'], [200e-6, 100e-6],
                            [0.02, 0.03], [20.0, 40.0])
    assert got == (ChannelCommand(3, 'single', 200e-6, 0.02, 20.0),
                   ChannelCommand(1, 'doublet', 100e-6, 0.03, 40.0))


def test_an_empty_current_array_means_the_reference_current_on_every_channel():
    got = check_stimulation(P24, [1, 2], ['single'] * 2, [200e-6] * 2, [], [20.0, 30.0])
    assert [c.current_a for c in got] == [None, None]


@pytest.mark.parametrize('arrays, lengths', [
    (([1, 2], ['single'], [1e-4, 1e-4], [], [20.0, 20.0]),
     'channel 2, mode 1, pulse_width_s 2, frequency_hz 2, current_a 0'),
    (([1, 2], ['single'] * 2, [1e-4, 1e-4], [0.02], [20.0, 20.0]),
     'channel 2, mode 2, pulse_width_s 2, frequency_hz 2, current_a 1'),
    (([1], ['single'], [1e-4], [], [20.0, 30.0]),
     'channel 1, mode 1, pulse_width_s 1, frequency_hz 2, current_a 0'),
])
def test_arrays_of_unequal_length_are_rejected_naming_the_lengths(arrays, lengths):
    with pytest.raises(ValueError, match=f'must have equal lengths .* got {lengths}$'):
        check_stimulation(P24, *arrays)


def test_a_channel_given_twice_is_rejected_naming_both_entries():
    with pytest.raises(ValueError, match='`channel` 2 is given twice \\(entries 0 and 2\\) on p24'):
        check_stimulation(P24, [2, 1, 2], ['single'] * 3, [1e-4] * 3, [], [20.0] * 3)


def test_an_out_of_range_channel_in_an_array_is_rejected():
    with pytest.raises(ValueError, match=r'`channel` must be in \[1, 8\] on rehastim2, got 9'):
        check_stimulation(REHASTIM2, [1, 9], ['single'] * 2, [1e-4] * 2, [], [20.0] * 2)


def test_a_channel_out_of_range_is_named_in_the_array():
    with pytest.raises(ValueError, match='`pulse_width_s` of channel 5 must be'):
        check_stimulation(REHASTIM2, [1, 5], ['single'] * 2, [1e-4, 7e-4], [], [20.0] * 2)


def test_the_rehastim2_has_one_frequency_for_all_channels():
    with pytest.raises(ValueError, match=r'`frequency_hz` must be the same on every channel on '
                                         r'rehastim2 \(one stimulation period for all channels\), '
                                         r'got 30 Hz on channel 1 and 40 Hz on channel 3'):
        check_stimulation(REHASTIM2, [1, 3], ['single'] * 2, [1e-4] * 2, [], [30.0, 40.0])
    assert len(check_stimulation(REHASTIM2, [1, 3], ['single'] * 2, [1e-4] * 2, [],
                                 [30.0, 30.0])) == 2


def test_the_p24_has_a_frequency_per_channel():
    got = check_stimulation(P24, [1, 3], ['single'] * 2, [1e-4] * 2, [], [30.0, 40.0])
    assert [c.frequency_hz for c in got] == [30.0, 40.0]


def test_an_empty_command_commands_no_channel():
    assert check_stimulation(REHASTIM2, [], [], [], [], []) == ()


def test_arrays_must_be_arrays():
    with pytest.raises(ValueError, match='`frequency_hz` must be an array, got 30.0'):
        check_stimulation(P24, [1], ['single'], [1e-4], [], 30.0)


# -- profiles are validated -----------------------------------------------------------------


@pytest.mark.parametrize('changes, message', [
    ({'name': ''}, '`name` must be a non-empty string'),
    ({'channel_count': 0}, '`channel_count` must be an integer >= 1 or None, got 0'),
    ({'pulse_width_ranges_s': ()}, '`pulse_width_ranges_s` must hold at least one interval'),
    ({'pulse_width_ranges_s': ((5e-4, 1e-4),)}, '`pulse_width_ranges_s` must be a pair'),
    ({'current_max_a': 0.0}, '`current_max_a` must be positive and finite, got 0.0'),
    ({'frequency_range_hz': (10.0, math.inf)}, '`frequency_range_hz` must be a pair'),
    ({'period_range_s': (0.0, 1.0)}, '`period_range_s` must be a pair .* positive'),
    ({'shared_frequency': 1}, '`shared_frequency` must be a bool, got 1'),
    ({'burst_interval_range_s': (-1.0, 0.1)}, '`burst_interval_range_s` must be a pair'),
])
def test_a_malformed_profile_names_the_field(changes, message):
    fields = dict(name='x', channel_count=4, pulse_width_ranges_s=((0.0, 1e-3),),
                  current_max_a=0.1, frequency_range_hz=(1.0, 100.0), period_range_s=None,
                  shared_frequency=False, burst_interval_range_s=(0.002, 0.129))
    with pytest.raises(ValueError, match=message):
        StimulatorProfile(**dict(fields, **changes))


def test_the_generic_profile_needs_a_positive_pw_max():
    with pytest.raises(ValueError, match='`pw_max_s` must be positive and finite, got 0.0'):
        generic_profile(0.0)
