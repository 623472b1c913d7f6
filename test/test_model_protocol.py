"""Protocols as data: knots, steps, holds, and clear errors for malformed files."""
import math

import numpy as np
import pytest
import yaml
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hill_muscle_ros.model import Knots, MuscleParams, Protocol, ProtocolError
from hill_muscle_ros.model.protocol import ALLOWED_KEYS

GOOD = {
    'name': 'test',
    'duration_s': 6.0,
    'recruitment': [[0.0, 0.5], [3.0, 0.5], [3.0, 1.0]],
    'dl_mt_m': [[0.0, 0.0], [1.0, 0.0], [2.0, 0.01], [4.0, 0.01], [5.0, 0.0]],
}


def test_values_are_linear_between_knots():
    p = Protocol.from_mapping(GOOD)
    assert p.dl_mt(1.5) == pytest.approx(0.005)
    assert p.dl_mt(4.25) == pytest.approx(0.0075)


def test_repeated_time_is_a_right_continuous_step():
    p = Protocol.from_mapping(GOOD)
    assert p.recruitment(3.0 - 1e-12, 5e-4) == 0.5
    assert p.recruitment(3.0, 5e-4) == 1.0


def test_the_last_of_several_knots_at_one_time_wins():
    data = dict(GOOD, recruitment=[[0.0, 0.1], [1.0, 0.2], [1.0, 0.9], [1.0, 0.4]])
    p = Protocol.from_mapping(data)
    assert p.recruitment(1.0, 5e-4) == 0.4
    assert p.recruitment(0.5, 5e-4) == pytest.approx(0.15)


def test_values_hold_before_the_first_and_after_the_last_knot():
    data = dict(GOOD, dl_mt_m=[[1.0, 0.002], [2.0, 0.004]])
    p = Protocol.from_mapping(data)
    assert p.dl_mt(0.0) == 0.002 and p.dl_mt(0.5) == 0.002
    assert p.dl_mt(5.0) == 0.004


def test_sampling_an_array_matches_sampling_each_time():
    p = Protocol.from_mapping(GOOD)
    t = np.linspace(-1, 7, 801)
    np.testing.assert_array_equal(p.dl_mt(t), [p.dl_mt(x) for x in t])


def test_pulse_width_protocol_maps_through_pw_max():
    data = {k: v for k, v in GOOD.items() if k != 'recruitment'}
    data['pulse_width_s'] = [[0.0, 100e-6], [1.0, 1e-3]]
    p = Protocol.from_mapping(data)
    params = MuscleParams()
    assert p.recruitment(0.0, params.pw_max_s) == pytest.approx(0.2)
    assert p.recruitment(1.0, params.pw_max_s) == 1.0


@pytest.mark.parametrize('name', ['I', 'II'])
def test_shipped_protocols_load(protocol_paths, name):
    p = Protocol.from_yaml(protocol_paths[name])
    assert p.name == f'Protocol {name}' and p.duration_s == 6.0
    assert p.dl_mt(2.0) == pytest.approx(0.010) and p.dl_mt(5.0) == 0.0


def test_shipped_protocol_I_steps_match_model_md(protocol_paths):
    p = Protocol.from_yaml(protocol_paths['I'])
    got = [p.recruitment(t, 5e-4) for t in (0.0, 2.99, 3.0, 4.99, 5.0, 6.0)]
    assert got == [1.0, 1.0, 0.5, 0.5, 1.0, 1.0]


@pytest.mark.parametrize('change, message', [
    ({'duration_s': -1.0}, '`duration_s` must be a positive finite number'),
    ({'duration_s': math.nan}, '`duration_s` must be a positive finite number'),
    ({'name': ''}, '`name` must be a non-empty string'),
    ({'recruitment': [[0.0, 0.5], [2.0, 0.5], [1.0, 1.0]]},
     r'`recruitment` entry 2 \(\[1.0, 1.0\]\): times must not decrease'),
    ({'recruitment': [[0.0, 1.5]]}, r'`recruitment` entry 0 .*value must be in \[0, 1\], got 1.5'),
    ({'recruitment': [[0.0, -0.1]]}, r'value must be in \[0, 1\], got -0.1'),
    ({'recruitment': [[0.0, math.inf]]}, 'time and value must be finite'),
    ({'recruitment': [[math.nan, 0.5]]}, 'time and value must be finite'),
    ({'recruitment': [[0.0]]}, r'entry 0 \(\[0.0\]\): must be a pair'),
    ({'recruitment': [[0.0, 'half']]}, 'time and value must be numbers'),
    ({'recruitment': []}, '`recruitment` must be a non-empty list'),
    ({'recruitment': 0.5}, '`recruitment` must be a non-empty list'),
    ({'dl_mt_m': [[0.0, 10.0]]}, r'`dl_mt_m` entry 0 .*value must be within'),
    ({'dl_mt_m': [[-1.0, 0.0]]}, 'time must be >= 0'),
    ({'pulse_width_s': [[0.0, 1e-4]]}, 'exactly one of `recruitment` or `pulse_width_s`'),
    ({'stiffness': 3}, 'unknown key `stiffness`'),
])
def test_malformed_protocol_names_the_file_key_and_entry(change, message):
    data = dict(GOOD, **change)
    with pytest.raises(ProtocolError, match=f'^my.yaml: .*{message}'):
        Protocol.from_mapping(data, source='my.yaml')


def test_negative_pulse_width_is_rejected():
    data = {k: v for k, v in GOOD.items() if k != 'recruitment'}
    data['pulse_width_s'] = [[0.0, -1e-4]]
    with pytest.raises(ProtocolError, match='`pulse_width_s` entry 0 .*non-negative'):
        Protocol.from_mapping(data, source='my.yaml')


@pytest.mark.parametrize('key', ['name', 'duration_s', 'dl_mt_m'])
def test_missing_key_is_named(key):
    data = {k: v for k, v in GOOD.items() if k != key}
    with pytest.raises(ProtocolError, match=f'missing key `{key}`'):
        Protocol.from_mapping(data, source='my.yaml')


def test_yaml_syntax_error_names_the_file(tmp_path):
    path = tmp_path / 'broken.yaml'
    path.write_text('name: [unclosed\n')
    with pytest.raises(ProtocolError, match=f'^{path}: not valid YAML'):
        Protocol.from_yaml(path)


def test_missing_file_names_the_file(tmp_path):
    with pytest.raises(ProtocolError, match='nope.yaml: cannot read protocol file'):
        Protocol.from_yaml(tmp_path / 'nope.yaml')


yaml_scalars = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(),
                         st.text(max_size=5))
yaml_values = st.recursive(yaml_scalars,
                           lambda c: st.lists(c, max_size=4) | st.dictionaries(
                               st.sampled_from(ALLOWED_KEYS + ('x',)), c, max_size=4),
                           max_leaves=12)


#: A document that loads, for the pinned corner cases below to break one way each.
_VALID = {'name': 'p', 'duration_s': 1.0, 'recruitment': [[0.0, 0.5]], 'dl_mt_m': [[0.0, 0.0]]}


# 100 drawn documents (400 took 2.5 s) and the corner cases pinned, each of
# which hypothesis would otherwise have to happen upon.
@settings(max_examples=100, deadline=None)
@given(st.dictionaries(st.sampled_from(ALLOWED_KEYS + ('extra',)), yaml_values, max_size=6))
@example({})
@example(_VALID)
@example({**_VALID, 'extra': 1})
@example({**_VALID, 'pulse_width_s': [[0.0, 1e-4]]})
@example({**_VALID, 'duration_s': float('nan')})
@example({**_VALID, 'duration_s': float('inf')})
@example({**_VALID, 'duration_s': -1.0})
@example({**_VALID, 'duration_s': True})
@example({**_VALID, 'duration_s': '1.0'})
@example({**_VALID, 'duration_s': 10 ** 400})
@example({**_VALID, 'duration_s': None})
@example({**_VALID, 'name': None})
@example({**_VALID, 'name': ['p']})
@example({**_VALID, 'recruitment': []})
@example({**_VALID, 'recruitment': [0.0, 0.5]})
@example({**_VALID, 'recruitment': [[0.0]]})
@example({**_VALID, 'recruitment': [[0.0, 0.5, 1.0]]})
@example({**_VALID, 'recruitment': [[0.0, None]]})
@example({**_VALID, 'recruitment': [[None, 0.5]]})
@example({**_VALID, 'recruitment': [['a', 0.5]]})
@example({**_VALID, 'recruitment': [[0.0, float('nan')]]})
@example({**_VALID, 'recruitment': [[float('-inf'), 0.5]]})
@example({**_VALID, 'recruitment': [[1.0, 0.5], [0.0, 0.5]]})
@example({**_VALID, 'recruitment': {'x': 1}})
@example({**_VALID, 'recruitment': 0.5})
@example({**_VALID, 'dl_mt_m': [[0.0, [0.0]]]})
@example({**_VALID, 'dl_mt_m': [{'x': 0.0}]})
@example({**_VALID, 'dl_mt_m': 'abc'})
def test_any_malformed_document_gives_a_protocol_error_not_a_traceback(doc):
    try:
        Protocol.from_mapping(doc, source='fuzz.yaml')
    except ProtocolError as err:
        assert str(err).startswith('fuzz.yaml: ')


@settings(max_examples=100, deadline=None)
@given(st.text(max_size=200))
@example('')
@example('- 1\n- 2\n')
@example('name: [unclosed\n')
@example('\x00')
@example('duration_s: .nan\n')
@example('name: p\nduration_s: 1.0\nrecruitment: [[0.0, 0.5]]\ndl_mt_m: [[0.0, 0.0]]\n')
def test_any_text_file_gives_a_protocol_error_or_a_protocol(tmp_path_factory, text):
    path = tmp_path_factory.mktemp('fuzz') / 'p.yaml'
    path.write_text(text, encoding='utf-8')
    try:
        Protocol.from_yaml(path)
    except ProtocolError as err:
        assert str(path) in str(err)


def test_round_trip_through_yaml_text(tmp_path):
    path = tmp_path / 'p.yaml'
    path.write_text(yaml.safe_dump(GOOD))
    assert Protocol.from_yaml(path).recruitment(3.0, 5e-4) == 1.0


@pytest.mark.parametrize('change', [{'duration_s': 10 ** 400},
                                    {'dl_mt_m': [[0.0, 10 ** 400]]},
                                    {'recruitment': [[10 ** 400, 0.5]]}])
def test_integer_too_large_for_a_float_is_not_finite(change):
    with pytest.raises(ProtocolError, match='finite'):
        Protocol.from_mapping(dict(GOOD, **change), source='my.yaml')


def test_stimulation_command_on_each_output():
    p = Protocol.from_mapping(GOOD)
    assert p.stimulation_command(3.0, 'recruitment', 5e-4) == 1.0
    assert p.stimulation_command(0.0, 'pulse_width', 5e-4) == pytest.approx(0.5 * 5e-4)
    own = {k: v for k, v in GOOD.items() if k != 'recruitment'}
    own['pulse_width_s'] = [[0.0, 2e-3]]  # the protocol's own width, sent unclipped
    assert Protocol.from_mapping(own).stimulation_command(0.0, 'pulse_width', 5e-4) == 2e-3
    with pytest.raises(ValueError, match="`output` must be one of pulse_width, recruitment"):
        p.stimulation_command(0.0, 'current', 5e-4)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 20), st.floats(-1.0, 1.0)), min_size=1, max_size=8))
@example([(0, 0.5)])
@example([(3, 0.5), (3, -1.0)])
@example([(0, 0.0), (2, 1.0), (2, -1.0), (2, 0.25), (5, 0.0)])
@example([(20, 1.0), (0, -1.0), (20, 0.0), (0, 1.0)])
@example([(1, 0.0), (2, 0.0), (3, 0.0)])
@example([(0, -0.0), (1, 5e-324)])
def test_knots_with_repeated_times_are_linear_pieces_joined_by_right_continuous_steps(knots):
    """The signal by its definition, knot by knot: at a knot time the last knot of
    that time, just before it the limit along the piece from the knot before, and
    between knots the straight line; the first and last values outside."""
    knots = sorted(knots, key=lambda k: k[0])   # stable: the given order within a time
    times = np.array([t * 0.25 for t, _ in knots])
    values = np.array([v for _, v in knots])
    signal = Knots(times, values)
    tol = 1e-12
    for t in np.unique(times):
        assert signal(t) == values[times == t][-1]
    assert signal(times[0] - 1.0) == values[0] and signal(times[-1] + 1.0) == values[-1]
    for k in range(len(times) - 1):
        t0, t1 = times[k], times[k + 1]
        if t1 == t0:
            continue
        # the piece from the last knot at t0 to the first knot at t1
        v0, v1 = values[k], values[k + 1]
        for frac in (0.25, 0.5, 0.999999):
            t = t0 + frac * (t1 - t0)
            assert abs(signal(t) - (v0 + (t - t0) / (t1 - t0) * (v1 - v0))) <= tol
        np.testing.assert_allclose(signal(np.array([t0 + 0.5 * (t1 - t0)])),
                                   [v0 + 0.5 * (v1 - v0)], rtol=0, atol=tol)
