"""Protocols with ``channels`` (doc/model.md section 10): pulse trains per channel
as knots, clear errors that name the file, the channel and the key, and the
shipped files' pulses as their comments claim."""
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hill_muscle_ros.model import Protocol, ProtocolError
from hill_muscle_ros.model.protocol import (CHANNEL_KEYS, PULSE_ALLOWED_KEYS, PulseProtocol,
                                            read_protocol)
from hill_muscle_ros.model.trains import ChannelTrain

#: The example of doc/model.md section 10: a doublet train for 1 s.
EXAMPLE = {
    'name': 'doublet vs constant',
    'duration_s': 2.0,
    'channels': [{'frequency_hz': [[0.0, 14.3]],
                  'pulse_width_s': [[0.0, 0.0002], [1.0, 0.0002], [1.0, 0.0]],
                  'mode': 'doublet'}],
    'dl_mt_m': [[0.0, 0.0]],
}


def channel(**changes):
    return dict(EXAMPLE['channels'][0], **changes)


def test_the_example_gives_doublets_at_14_3_hz_for_one_second():
    protocol = PulseProtocol.from_mapping(EXAMPLE)
    (pulses,) = protocol.pulses()
    assert [p.time_s for p in pulses] == [n / 14.3 + m * 0.005 for n in range(15)
                                          for m in range(2)]   # n / 14.3 < 1 s
    assert {p.pulse_width_s for p in pulses} == {0.0002}


def test_each_channel_is_a_train_numbered_from_1():
    data = dict(EXAMPLE, channels=[channel(), channel(mode='single', current_a=[[0.0, 0.03]])])
    protocol = PulseProtocol.from_mapping(data)
    assert [c.channel for c in protocol.channels] == [1, 2]
    assert all(isinstance(c, ChannelTrain) for c in protocol.channels)
    assert protocol.channels[1].current_a(0.5) == 0.03


def test_mode_and_burst_interval_have_defaults():
    data = dict(EXAMPLE, channels=[{'frequency_hz': [[0.0, 20.0]],
                                    'pulse_width_s': [[0.0, 0.0002]]}])
    (train,) = PulseProtocol.from_mapping(data).channels
    assert (train.mode, train.burst_interval_s, train.current_a) == ('single', 0.005, None)


def test_the_burst_interval_can_be_given():
    data = dict(EXAMPLE, channels=[channel(burst_interval_s=0.01)])
    (pulses,) = PulseProtocol.from_mapping(data).pulses()
    assert pulses[1].time_s - pulses[0].time_s == 0.01


@pytest.mark.parametrize('key', ['pulse_width_s', 'recruitment'])
def test_a_level_at_the_top_is_rejected_beside_channels(key):
    data = dict(EXAMPLE, **{key: [[0.0, 0.0001]]})
    message = (f'^my.yaml: a protocol with `channels` gives its stimulation per channel and '
               f'must not also have `{key}` at the top')
    with pytest.raises(ProtocolError, match=message):
        PulseProtocol.from_mapping(data, source='my.yaml')
    with pytest.raises(ProtocolError, match=message):
        Protocol.from_mapping(data, source='my.yaml')


def test_a_level_protocol_loader_sends_a_channels_file_to_the_pulse_loader():
    with pytest.raises(ProtocolError, match='^my.yaml: `channels` gives pulse trains per channel: '
                                            'load it with PulseProtocol'):
        Protocol.from_mapping(EXAMPLE, source='my.yaml')


@pytest.mark.parametrize('change, message', [
    ({'frequency_hz': [[0.0, 0.0]]}, r'channel 1: `frequency_hz` entry 0 \(\[0.0, 0.0\]\): '
                                     r'value must be positive, got 0.0'),
    ({'frequency_hz': [[0.0, 250.0]]}, r'channel 1: `frequency_hz` entry 0 must stay below '
                                       r'200 Hz for a doublet'),
    ({'pulse_width_s': [[0.0, -1e-4]]}, r'channel 1: `pulse_width_s` entry 0 .*non-negative'),
    ({'pulse_width_s': [[1.0, 1e-4], [0.5, 0.0]]}, r'channel 1: `pulse_width_s` entry 1 '
                                                   r'.*times must not decrease'),
    ({'current_a': [[0.0, -0.01]]}, r'channel 1: `current_a` entry 0 .*non-negative'),
    ({'current_a': 0.03}, r'channel 1: `current_a` must be a non-empty list'),
    ({'mode': 'quadruplet'}, r"channel 1: `mode` must be one of single, doublet, triplet, "
                             r"got 'quadruplet'"),
    ({'mode': ['doublet']}, r'channel 1: `mode` must be one of'),
    ({'burst_interval_s': 0}, r'channel 1: `burst_interval_s` must be a positive finite number'),
    ({'burst_interval_s': [[0.0, 0.005]]}, r'channel 1: `burst_interval_s` must be a positive'),
    ({'pw': [[0.0, 1e-4]]}, r'channel 1: unknown key `pw` \(allowed: frequency_hz, '),
])
def test_a_malformed_channel_names_the_file_channel_key_and_entry(change, message):
    data = dict(EXAMPLE, channels=[channel(), channel(**change)])
    message = message.replace('channel 1', 'channel 2')
    with pytest.raises(ProtocolError, match=f'^my.yaml: {message}'):
        PulseProtocol.from_mapping(data, source='my.yaml')


@pytest.mark.parametrize('key', ['frequency_hz', 'pulse_width_s'])
def test_a_channel_without_its_frequency_or_width_is_named(key):
    data = dict(EXAMPLE, channels=[{k: v for k, v in channel().items() if k != key}])
    with pytest.raises(ProtocolError, match=f'^my.yaml: channel 1: missing key `{key}`'):
        PulseProtocol.from_mapping(data, source='my.yaml')


@pytest.mark.parametrize('raw', [[], {}, 'all', None, [5]])
def test_channels_must_be_a_list_of_mappings(raw):
    with pytest.raises(ProtocolError, match='^my.yaml: (`channels` must be a non-empty list'
                                            '|channel 1: expected a mapping)'):
        PulseProtocol.from_mapping(dict(EXAMPLE, channels=raw), source='my.yaml')


@pytest.mark.parametrize('key', ['name', 'duration_s', 'channels', 'dl_mt_m'])
def test_a_missing_top_level_key_is_named(key):
    data = {k: v for k, v in EXAMPLE.items() if k != key}
    with pytest.raises(ProtocolError, match=f'missing key `{key}`'):
        PulseProtocol.from_mapping(data, source='my.yaml')


def test_a_pulse_file_is_read_as_either_kind(tmp_path):
    path = tmp_path / 'doublet.yaml'
    path.write_text('name: doublet\nduration_s: 1.0\nchannels:\n'
                    '  - {frequency_hz: [[0.0, 10.0]], pulse_width_s: [[0.0, 0.0002]]}\n'
                    'dl_mt_m: [[0.0, 0.0]]\n')
    assert isinstance(PulseProtocol.from_yaml(path), PulseProtocol)
    assert isinstance(read_protocol(path), PulseProtocol)


def test_a_level_file_is_still_a_protocol(protocol_paths):
    assert isinstance(read_protocol(protocol_paths['I']), Protocol)


def test_a_missing_pulse_file_names_the_file(tmp_path):
    with pytest.raises(ProtocolError, match='nope.yaml: cannot read protocol file'):
        PulseProtocol.from_yaml(tmp_path / 'nope.yaml')


yaml_scalars = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(),
                         st.text(max_size=5))
yaml_values = st.recursive(
    yaml_scalars, lambda c: st.lists(c, max_size=4) | st.dictionaries(
        st.sampled_from(PULSE_ALLOWED_KEYS + CHANNEL_KEYS + ('x',)), c, max_size=4),
    max_leaves=12)


#: A document that loads, for the pinned corner cases below to break one way each.
_CHANNEL = {'frequency_hz': [[0.0, 20.0]], 'pulse_width_s': [[0.0, 2e-4]]}
_VALID = {'name': 'p', 'duration_s': 1.0, 'channels': [_CHANNEL], 'dl_mt_m': [[0.0, 0.0]]}


# 100 drawn documents (400 took 2.2 s) and the corner cases pinned, each of
# which hypothesis would otherwise have to happen upon.
@settings(max_examples=100, deadline=None)
@given(st.dictionaries(st.sampled_from(PULSE_ALLOWED_KEYS + ('recruitment', 'extra')),
                       yaml_values, max_size=6))
@example({})
@example(_VALID)
@example({**_VALID, 'extra': 1})
@example({**_VALID, 'recruitment': [[0.0, 0.5]]})
@example({**_VALID, 'duration_s': float('nan')})
@example({**_VALID, 'duration_s': -1.0})
@example({**_VALID, 'duration_s': True})
@example({**_VALID, 'duration_s': 10 ** 400})
@example({**_VALID, 'channels': []})
@example({**_VALID, 'channels': None})
@example({**_VALID, 'channels': [None]})
@example({**_VALID, 'channels': [[0.0, 1.0]]})
@example({**_VALID, 'channels': {'frequency_hz': [[0.0, 20.0]]}})
@example({**_VALID, 'channels': [{'frequency_hz': [[0.0, 20.0]]}]})
@example({**_VALID, 'channels': [{**_CHANNEL, 'x': 1}]})
@example({**_VALID, 'channels': [{**_CHANNEL, 'frequency_hz': [[0.0, float('inf')]]}]})
@example({**_VALID, 'channels': [{**_CHANNEL, 'frequency_hz': [[0.0, -20.0]]}]})
@example({**_VALID, 'channels': [{**_CHANNEL, 'pulse_width_s': [[0.0, None]]}]})
@example({**_VALID, 'channels': [{**_CHANNEL, 'pulse_width_s': [[0.0]]}]})
@example({**_VALID, 'channels': [{**_CHANNEL, 'current_a': [[0.0, -1.0]]}]})
@example({**_VALID, 'channels': [{**_CHANNEL, 'current_a': 'x'}]})
@example({**_VALID, 'channels': [{**_CHANNEL, 'mode': 5}]})
@example({**_VALID, 'channels': [{**_CHANNEL, 'mode': 'quadruplet'}]})
@example({**_VALID, 'channels': [{**_CHANNEL, 'mode': 'doublet', 'burst_interval_s': -1.0}]})
@example({**_VALID, 'channels': [{**_CHANNEL, 'burst_interval_s': [0.005]}]})
@example({**_VALID, 'dl_mt_m': [[0.0, float('nan')]]})
@example({**_VALID, 'dl_mt_m': {'x': 0.0}})
def test_any_malformed_document_gives_a_protocol_error_not_a_traceback(doc):
    try:
        PulseProtocol.from_mapping(doc, source='fuzz.yaml')
    except ProtocolError as err:
        assert str(err).startswith('fuzz.yaml: ')


# -- the shipped files -----------------------------------------------------------------------

PROTOCOLS = 'config/protocols/'


def shipped(name, repo):
    return read_protocol(repo / PROTOCOLS / name)


@pytest.fixture(scope='module')
def repo():
    from pathlib import Path
    return Path(__file__).resolve().parents[1]


@pytest.mark.parametrize('name, f, pw, per_train', [
    ('kesar2006_11hz_600us.yaml', 11.5, 600e-6, 4),
    ('kesar2006_30hz_150us.yaml', 30.0, 150e-6, 9),
    ('kesar2006_60hz_131us.yaml', 60.0, 131e-6, 18),
])
def test_kesars_protocols_send_300_ms_trains_once_a_second_for_180_s(repo, name, f, pw,
                                                                     per_train):
    protocol = shipped(name, repo)
    (pulses,) = protocol.pulses()
    assert protocol.duration_s == 180.0
    # Train k starts at k s; its pulses at k + n / f, inside [k, k + 0.3 s).
    assert [p.time_s for p in pulses] == [k + n / f for k in range(180)
                                          for n in range(per_train)]
    assert all(n / f < 0.3 for n in range(per_train)) and per_train / f >= 0.3
    assert {(p.pulse_width_s, p.current_a) for p in pulses} == {(pw, None)}


def test_the_catchlike_cft_sends_six_pulses_70_ms_apart_every_0_8_s(repo):
    (pulses,) = shipped('catchlike_cft.yaml', repo).pulses()
    f = 1.0 / 0.070
    assert [p.time_s for p in pulses] == [round(0.8 * k, 9) + n / f for k in range(180)
                                          for n in range(6)]
    assert {p.pulse_width_s for p in pulses} == {200e-6}


def test_the_catchlike_vft_is_the_cft_opened_by_a_5_ms_doublet(repo):
    (pulses,) = shipped('catchlike_vft.yaml', repo).pulses()
    f = 1.0 / 0.070
    expected = []
    for k in range(180):
        start = round(0.8 * k, 9)
        second = start + 1 / 200.0          # 200 Hz read at the first burst
        expected += [start, second] + [second + m / f for m in range(1, 5)]
    assert [p.time_s for p in pulses] == expected
    assert {p.pulse_width_s for p in pulses} == {200e-6}


def test_sdss_four_channels_fire_in_turn_at_the_one_channels_total_rate(repo):
    (one,) = shipped('sdss_one_channel.yaml', repo).pulses()
    four = shipped('sdss_four_channels.yaml', repo).pulses()
    assert [p.time_s for p in one] == [2.0 * k + n / 40.0 for k in range(90) for n in range(40)]
    for c, pulses in enumerate(four):
        # Channel c + 1 starts a quarter period (25 ms) after channel c.
        assert [p.time_s for p in pulses] == [round(2.0 * k + 0.025 * c, 9) + n / 10.0
                                              for k in range(90) for n in range(10)]
    assert sum(len(p) for p in four) == len(one)
    merged = np.sort([p.time_s for pulses in four for p in pulses])
    assert np.allclose(merged, [p.time_s for p in one], rtol=0, atol=1e-12)
    assert {p.pulse_width_s for pulses in four for p in pulses} == {300e-6}


@pytest.mark.parametrize('name', ['kesar2006_11hz_600us.yaml', 'kesar2006_30hz_150us.yaml',
                                  'kesar2006_60hz_131us.yaml', 'catchlike_cft.yaml',
                                  'catchlike_vft.yaml', 'sdss_one_channel.yaml',
                                  'sdss_four_channels.yaml'])
def test_each_shipped_pulse_protocol_parses_isometric(repo, name):
    protocol = PulseProtocol.from_yaml(repo / PROTOCOLS / name)
    assert protocol.dl_mt(np.array([0.0, protocol.duration_s])).tolist() == [0.0, 0.0]
