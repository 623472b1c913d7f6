"""A channel's pulse train (doc/model.md section 10): when its pulses come, exactly.

Every expected time below is the rule's own formula: a run of bursts at one
frequency f that starts at t_a has its bursts at t_a + n / f, a burst's pulses
follow at m * burst_interval_s, and a train starts where the stimulation
becomes non-zero.
"""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hill_muscle_ros.model.protocol import Knots
from hill_muscle_ros.model.trains import (DEFAULT_BURST_INTERVAL_S, ChannelTrain, Pulse,
                                          PulseTrain, TrainState, advance)

PW = 300e-6


def knots(*pairs):
    """Knots from (time, value) pairs, as a protocol gives them."""
    return Knots(np.array([t for t, _ in pairs], float), np.array([v for _, v in pairs], float))


def pulses(train, t1, t0=0.0):
    return advance(train, TrainState(t0), t1)[0]


def times(found):
    return [p.time_s for p in found]


@pytest.mark.parametrize('f', [10.0, 33.0, 80.0])
def test_a_constant_train_sends_a_pulse_every_1_over_f_from_zero(f):
    found = pulses(ChannelTrain(f, PW), 1.0)
    assert times(found) == [n / f for n in range(int(f))]   # n / f < 1 s
    assert all(p.pulse_width_s == PW and p.current_a is None for p in found)


def test_a_train_starts_at_the_instant_its_stimulation_steps_on():
    found = pulses(ChannelTrain(10.0, knots((0.25, 0.0), (0.25, PW))), 1.0)
    assert times(found) == [0.25 + n / 10.0 for n in range(8)]


@pytest.mark.parametrize('mode, n_pulses', [('doublet', 2), ('triplet', 3)])
def test_a_burst_sends_its_pulses_the_burst_interval_apart(mode, n_pulses):
    found = pulses(ChannelTrain(20.0, PW, mode=mode), 0.5)
    assert times(found) == [n / 20.0 + m * DEFAULT_BURST_INTERVAL_S
                            for n in range(10) for m in range(n_pulses)]


def test_the_burst_interval_is_the_one_given():
    found = pulses(ChannelTrain(10.0, PW, mode='doublet', burst_interval_s=0.008), 0.3)
    assert times(found) == [n / 10.0 + m * 0.008 for n in range(3) for m in range(2)]


def test_the_default_burst_interval_is_5_ms():
    assert DEFAULT_BURST_INTERVAL_S == 0.005


def test_a_frequency_step_counts_from_the_burst_before_it():
    # f steps from 10 to 20 Hz at 0.25 s: the burst at 0.2 s read 10 Hz, so the
    # next comes at 0.3 s (not at 0.25 s), then every 1/20 s from there.
    found = pulses(ChannelTrain(knots((0.0, 10.0), (0.25, 10.0), (0.25, 20.0)), PW), 0.6)
    assert times(found) == [0.0, 0.1, 0.2, 3 / 10.0] + [3 / 10.0 + k / 20.0 for k in range(1, 6)]


def test_a_frequency_step_at_a_burst_is_read_by_that_burst():
    found = pulses(ChannelTrain(knots((0.0, 10.0), (0.2, 10.0), (0.2, 20.0)), PW), 0.4)
    assert times(found) == [0.0, 0.1, 2 / 10.0] + [2 / 10.0 + k / 20.0 for k in range(1, 4)]


def test_a_pulse_width_gap_ends_the_train_and_a_new_one_starts_where_it_ends():
    pw = knots((0.0, PW), (0.32, PW), (0.32, 0.0), (0.55, 0.0), (0.55, PW))
    found = pulses(ChannelTrain(10.0, pw), 1.0)
    # The old schedule would have gone on at 0.6, 0.7, ...
    assert times(found) == [0.0, 0.1, 0.2, 0.3] + [0.55 + n / 10.0 for n in range(5)]


def test_a_current_gap_ends_the_train_as_a_width_gap_does():
    current = knots((0.0, 0.03), (0.32, 0.03), (0.32, 0.0), (0.55, 0.0), (0.55, 0.05))
    found = pulses(ChannelTrain(10.0, PW, current_a=current), 1.0)
    assert times(found) == [0.0, 0.1, 0.2, 0.3] + [0.55 + n / 10.0 for n in range(5)]
    assert [p.current_a for p in found] == [0.03] * 4 + [0.05] * 5


def test_a_zero_width_sends_no_pulse():
    assert pulses(ChannelTrain(50.0, 0.0), 1.0) == ()


def test_a_zero_current_sends_no_pulse():
    assert pulses(ChannelTrain(50.0, PW, current_a=0.0), 1.0) == ()


def test_a_ramp_from_zero_starts_the_train_at_its_foot_with_an_empty_burst():
    # PW is 0 at 0.2 s and positive after: the train starts at 0.2 s, where the
    # burst has no width, so the first pulse is 1/f later.
    found = pulses(ChannelTrain(10.0, knots((0.2, 0.0), (0.6, PW))), 0.75)
    assert times(found) == [0.2 + n / 10.0 for n in range(1, 6)]
    assert found[0].pulse_width_s == pytest.approx(PW / 4)


def test_a_width_that_touches_zero_for_an_instant_restarts_the_train_there():
    pw = knots((0.0, PW), (0.4, PW), (0.45, 0.0), (0.5, PW))
    found = pulses(ChannelTrain(10.0, pw), 0.8)
    assert times(found) == [0.0, 0.1, 0.2, 0.3, 0.4] + [0.45 + n / 10.0 for n in (1, 2, 3)]


def test_a_stimulation_that_stops_cuts_the_rest_of_a_burst():
    pw = knots((0.0, PW), (0.107, PW), (0.107, 0.0))
    found = pulses(ChannelTrain(10.0, pw, mode='triplet'), 0.5)
    assert times(found) == [0.0, 0.005, 0.01, 0.1, 0.1 + 0.005]


def test_a_bursts_pulses_carry_the_width_read_at_its_first_pulse():
    pw = knots((0.0, 100e-6), (0.002, 100e-6), (0.002, 200e-6))
    found = pulses(ChannelTrain(10.0, pw, mode='doublet'), 0.05)
    assert found == (Pulse(0.0, 100e-6, None), Pulse(0.005, 100e-6, None))


def test_a_burst_that_spans_two_steps_sends_its_second_pulse_in_the_second():
    train = PulseTrain(ChannelTrain(10.0, PW, mode='doublet'))
    assert train.pulses(0.0, 0.002) == (Pulse(0.0, PW, None),)
    assert train.pulses(0.002, 0.01) == (Pulse(0.005, PW, None),)


def test_a_train_is_off_before_its_start():
    found = PulseTrain(ChannelTrain(10.0, PW), start_s=0.35).pulses(0.35, 0.6)
    assert times(found) == [0.35 + n / 10.0 for n in range(3)]


def test_a_new_command_keeps_the_schedule_of_the_running_train():
    train = PulseTrain(ChannelTrain(10.0, PW))
    first = train.pulses(0.0, 0.25)
    train.train = ChannelTrain(20.0, 2 * PW)
    second = train.pulses(0.25, 0.5)
    # The burst at 0.2 s read 10 Hz: the next is at 0.3 s, then 20 Hz.
    assert times(first) == [0.0, 0.1, 0.2]
    assert times(second) == [3 / 10.0] + [3 / 10.0 + k / 20.0 for k in (1, 2, 3)]
    assert {p.pulse_width_s for p in second} == {2 * PW}


#: A train with everything at once: a doublet, a frequency step and ramp, a
#: width gap, a current that ramps and pauses.
BUSY = ChannelTrain(
    knots((0.0, 12.0), (0.4, 12.0), (0.4, 35.0), (1.1, 60.0), (1.6, 25.0)),
    knots((0.0, 0.0), (0.03, 0.0), (0.03, PW), (0.7, PW), (0.7, 0.0), (0.81, 0.0),
          (0.81, 200e-6), (1.3, 400e-6), (1.45, 0.0), (1.5, 350e-6)),
    current_a=knots((0.0, 0.04), (0.95, 0.04), (0.95, 0.0), (1.0, 0.0), (1.0, 0.02),
                    (1.7, 0.06)),
    mode='doublet', burst_interval_s=0.004, channel=3)


def step_by_step(train, cuts):
    pulse_train, found, t0 = PulseTrain(train), [], 0.0
    for t1 in cuts:
        found.extend(pulse_train.pulses(t0, t1))
        t0 = t1
    return tuple(found)


@pytest.mark.parametrize('step_s', [0.001, 0.004, 0.005, 0.1, 0.37])
def test_steps_of_any_length_give_the_pulses_of_one_call(step_s):
    cuts = [float(t) for t in np.arange(1, int(2.0 / step_s) + 1) * step_s] + [2.0]
    assert step_by_step(BUSY, cuts) == pulses(BUSY, 2.0)


def test_steps_that_end_on_pulses_and_knots_give_the_pulses_of_one_call():
    whole = pulses(BUSY, 2.0)
    cuts = sorted({p.time_s for p in whole} | set(BUSY.pulse_width_s.times_s.tolist())
                  | set(BUSY.current_a.times_s.tolist()) | {2.0})
    assert step_by_step(BUSY, [t for t in cuts if t > 0.0]) == whole


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0.0, 2.0, allow_nan=False), max_size=40))
def test_any_cut_of_the_interval_gives_the_pulses_of_one_call(cuts):
    assert step_by_step(BUSY, sorted(set(cuts) | {2.0})) == pulses(BUSY, 2.0)


def test_the_busy_train_exercises_what_it_claims():
    found = pulses(BUSY, 2.0)
    gaps = np.diff(times(found))
    assert min(gaps) == pytest.approx(0.004)                 # doublets
    assert {p.current_a for p in found} >= {0.04}            # currents carried
    assert not any(0.7 <= p.time_s < 0.81 for p in found)    # the width gap
    assert not any(0.95 <= p.time_s < 1.0 for p in found)    # the current gap
    assert 1.0 in times(found)                               # and the train after it


def test_a_train_must_continue_where_it_stands():
    train = PulseTrain(ChannelTrain(10.0, PW, channel=2))
    train.pulses(0.0, 0.2)
    with pytest.raises(ValueError, match=r"`t0_s` must be where channel 2's train stands, "
                                         r'0.2 s, got 0.3'):
        train.pulses(0.3, 0.4)


def test_an_interval_that_ends_before_it_starts_is_rejected():
    with pytest.raises(ValueError, match='`t1_s` must be finite and >= 0.5'):
        advance(ChannelTrain(10.0, PW), TrainState(0.5), 0.4)


def test_an_empty_interval_has_no_pulse():
    assert pulses(ChannelTrain(10.0, PW), 0.0) == ()


def test_a_burst_that_reads_no_frequency_is_an_error_naming_channel_and_time():
    train = ChannelTrain(knots((0.0, 10.0), (0.15, 10.0), (0.15, 0.0)), PW, channel=4)
    with pytest.raises(ValueError, match=r'`frequency_hz` of channel 4 must be positive where '
                                         r'a burst reads it, got 0.0 at t = 0.2 s'):
        pulses(train, 1.0)


def test_a_zero_frequency_without_stimulation_is_no_error():
    assert pulses(ChannelTrain(0.0, 0.0), 1.0) == ()


def test_bursts_that_would_overlap_are_an_error():
    with pytest.raises(ValueError, match=r'`frequency_hz` of channel 1 must be below 100 Hz '
                                         r'for a triplet .* got 120.0 at t = 0.0 s'):
        pulses(ChannelTrain(120.0, PW, mode='triplet'), 1.0)


@pytest.mark.parametrize('kwargs, message', [
    ({'mode': 'quadruplet'}, "`mode` of channel 1 must be one of single, doublet, triplet"),
    ({'burst_interval_s': 0.0}, '`burst_interval_s` of channel 1 must be positive'),
    ({'burst_interval_s': math.nan}, '`burst_interval_s` of channel 1 must be positive'),
    ({'pulse_width_s': -1e-4}, '`pulse_width_s` of channel 1 must be non-negative'),
    ({'current_a': -0.01}, '`current_a` of channel 1 must be non-negative'),
    ({'frequency_hz': 'fast'}, '`frequency_hz` of channel 1 must be a number or knots'),
    ({'frequency_hz': math.inf}, '`frequency_hz` of channel 1 must be finite'),
    ({'channel': 0}, '`channel` must be an integer >= 1, got 0'),
    ({'channel': True}, '`channel` must be an integer >= 1, got True'),
])
def test_a_malformed_train_names_the_field_and_channel(kwargs, message):
    args = dict({'frequency_hz': 10.0, 'pulse_width_s': PW}, **kwargs)
    with pytest.raises(ValueError, match=message):
        ChannelTrain(**args)


def test_knots_whose_times_decrease_are_rejected():
    bad = Knots(np.array([0.0, 1.0, 0.5]), np.array([PW, PW, PW]))
    with pytest.raises(ValueError, match='`pulse_width_s` of channel 1: knot times must not '
                                         'decrease'):
        ChannelTrain(10.0, bad)
