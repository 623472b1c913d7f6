"""The command track: time-stamped dl_MT set points, interpolated like a trajectory."""
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hill_muscle_ros.model import DL_MT_LIMIT_M, CommandTrack, Knots
from hill_muscle_ros.model.command_track import MAX_KNOTS

#: [s] distinct knot times of the generated tracks, after the start time 0
_times = st.lists(st.floats(min_value=1e-3, max_value=100.0, allow_nan=False),
                  min_size=1, max_size=30, unique=True)
_values = st.floats(min_value=-DL_MT_LIMIT_M, max_value=DL_MT_LIMIT_M, allow_nan=False)


@st.composite
def _knots(draw):
    times = draw(_times)
    return [(t, draw(_values)) for t in times]


def _track(knots, start_value=0.0):
    track = CommandTrack(start_value, 0.0)
    for t, v in knots:
        assert track.add(t, v) is None
    return track


def test_value_at_is_numpy_interp_through_the_start_and_the_knots():
    knots = [(0.5, 0.01), (0.75, 0.002), (2.0, -0.003)]
    track = _track(knots, start_value=0.004)
    t = np.linspace(-1.0, 3.0, 401)
    want = np.interp(t, [0.0, 0.5, 0.75, 2.0], [0.004, 0.01, 0.002, -0.003])
    assert np.array_equal(track.value_at(t), want)
    assert track.value_at(0.6) == float(np.interp(0.6, [0.0, 0.5, 0.75], [0.004, 0.01, 0.002]))


def test_one_knot_ahead_is_a_ramp_from_the_applied_value_then_a_hold():
    track = CommandTrack(0.002, 3.0)
    track.add(4.0, 0.012)
    assert track.value_at(3.25) == pytest.approx(0.0045, abs=1e-15)
    assert track.value_at(4.0) == 0.012
    assert track.value_at(10.0) == 0.012


def test_consume_prunes_applied_knots_and_restarts_from_the_applied_value():
    track = _track([(1.0, 0.01), (2.0, 0.0), (3.0, 0.005)])
    assert track.consume(1.5) == pytest.approx(0.005, abs=1e-15)
    assert len(track) == 2 and track.consumed_s == 1.5
    # A knot replaced after consumption ramps from the applied 5 mm, not from 1 mm.
    track.add(2.0, 0.007)
    assert track.value_at(1.75) == pytest.approx(0.006, abs=1e-15)
    assert track.consume(3.0) == 0.005
    assert len(track) == 0 and track.value_at(99.0) == 0.005


def test_a_knot_at_an_existing_time_replaces_its_value():
    track = _track([(1.0, 0.01)])
    track.add(1.0, 0.02)
    times, values = track.knots
    assert list(times) == [1.0] and list(values) == [0.02]


def test_late_knot_reports_its_lateness_and_the_track_continues_as_if_in_time():
    track = _track([(1.0, 0.0), (2.0, 0.01)])
    track.consume(1.5)                   # applied 5 mm; a knot for 1.4 s was due
    late = track.add(1.4, 0.002)
    assert late == pytest.approx(0.1)
    # The line from (1.4 s, 2 mm) to (2 s, 10 mm), from the consumed time on.
    want = float(np.interp(1.8, [1.4, 2.0], [0.002, 0.01]))
    assert track.value_at(1.8) == pytest.approx(want, abs=1e-15)


def test_late_knot_with_nothing_pending_holds_its_value_from_the_next_step():
    track = CommandTrack(0.0, 2.0)
    assert track.add(1.9, 0.003) == pytest.approx(0.1)
    assert track.value_at(2.001) == 0.003
    assert track.add(2.0, 0.004) == 0.0     # exactly at the consumed time: late by 0 s


def test_late_knot_older_than_one_already_applied_is_stale():
    track = _track([(1.0, 0.01)])
    track.consume(1.2)
    assert track.add(0.5, 0.0) == pytest.approx(0.7)
    assert track.value_at(1.3) == 0.01


@given(_knots(), st.randoms(use_true_random=False))
def test_out_of_order_insertion_gives_the_same_track_as_sorted(knots, rnd):
    shuffled = list(knots)
    rnd.shuffle(shuffled)
    a, b = _track(sorted(knots)), _track(shuffled)
    assert all(np.array_equal(x, y) for x, y in zip(a.knots, b.knots))
    t = np.linspace(-1.0, 101.0, 257)
    assert np.array_equal(a.value_at(t), b.value_at(t))


@given(_knots(), _values, st.lists(st.floats(-10.0, 110.0), min_size=1, max_size=20))
def test_value_is_within_the_range_of_the_start_and_knot_values(knots, start, times):
    track = _track(knots, start)
    values = [start, *(v for _, v in knots)]
    got = track.value_at(np.array(times))
    assert np.all(got >= min(values)) and np.all(got <= max(values))


@given(_knots(), _values)
def test_a_piecewise_linear_protocol_is_reproduced_exactly_at_its_knots(knots, start):
    knots = sorted(knots)
    protocol = Knots(np.array([0.0, *(t for t, _ in knots)]),
                     np.array([start, *(v for _, v in knots)]))
    track = _track(knots, start)
    times = protocol.times_s
    assert np.array_equal(track.value_at(times), protocol(times))
    # Consumed step by step (as a simulator does), the values stay the protocol's.
    for t in times[1:]:
        assert track.consume(t) == protocol(t)
    mid = 0.5 * (times[:-1] + times[1:])
    assert np.allclose(_track(knots, start).value_at(mid), protocol(mid), rtol=0.0,
                       atol=1e-15)


@pytest.mark.parametrize('t, value, needle', [
    (math.nan, 0.0, '`t_s` must be finite, got nan'),
    (math.inf, 0.0, '`t_s` must be finite, got inf'),
    (1.0, math.nan, '`dl_mt_m` must be finite and within ±1.0 m of rest, got nan'),
    (1.0, -math.inf, 'got -inf'),
    (1.0, 1.5, 'got 1.5'),
])
def test_bad_knot_is_rejected_by_name_and_changes_nothing(t, value, needle):
    track = _track([(1.0, 0.01)])
    with pytest.raises(ValueError, match=needle):
        track.add(t, value)
    times, values = track.knots
    assert list(times) == [1.0] and list(values) == [0.01]


def test_the_value_name_in_errors_is_the_one_given():
    track = CommandTrack(name='length_command_stamped')
    with pytest.raises(ValueError, match='`length_command_stamped` must be finite'):
        track.add(1.0, math.nan)


def test_full_track_rejects_the_next_knot_naming_it():
    track = CommandTrack(max_knots=3)
    for t in (1.0, 2.0, 3.0):
        track.add(t, 0.001)
    with pytest.raises(ValueError, match=r'`dl_mt_m` = 0.002 at t = 4.0 s: .* 3 pending knots'):
        track.add(4.0, 0.002)
    track.add(3.0, 0.004)   # replacing a knot does not grow the track
    assert len(track) == 3


def test_default_bound_is_the_named_constant():
    track = CommandTrack()
    track._times = list(np.arange(1, MAX_KNOTS + 1, dtype=float))  # noqa: SLF001 - fill fast
    track._values = [0.0] * MAX_KNOTS  # noqa: SLF001
    with pytest.raises(ValueError, match=f'{MAX_KNOTS} pending knots'):
        track.add(MAX_KNOTS + 1.0, 0.0)


def test_consuming_backwards_is_rejected():
    track = CommandTrack(0.0, 2.0)
    with pytest.raises(ValueError, match='`t_s` must not be before the consumed time 2.0 s'):
        track.consume(1.0)


@pytest.mark.parametrize('max_knots', [0, -1, 2.5])
def test_bad_bound_is_rejected(max_knots):
    with pytest.raises(ValueError, match='`max_knots` must be a positive integer'):
        CommandTrack(max_knots=max_knots)


def test_clear_drops_pending_knots_and_holds_the_given_value():
    track = _track([(1.0, 0.01), (2.0, 0.02)])
    track.clear(0.5, 0.003)
    assert len(track) == 0 and track.consumed_s == 0.5
    assert track.value_at(5.0) == 0.003
