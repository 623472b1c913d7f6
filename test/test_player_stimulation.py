"""The protocol player with a ``channels:`` protocol: one
``hill_muscle_interfaces/msg/Stimulation`` for every channel at time 0 and at
each knot time, checked against a stimulator.

Most tests run the player's timeline (:class:`hill_muscle_ros.playback.PulsePlayback`)
on a clock the test drives, over the model of one reliable DDS link that
``test_playback.py`` uses (the subscriber matches the player back a heartbeat
late); the last two run the node as a process.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from std_msgs.msg import Float64

from hill_muscle_ros.model import MuscleParams
from hill_muscle_ros.model.protocol import PulseProtocol
from hill_muscle_ros.model.stimulator import ChannelCommand
from hill_muscle_ros.playback import (CHANNELS, LENGTH, LENGTH_STAMPED, PulsePlayback, Send,
                                      stimulation_times_s)
from hill_muscle_ros.timebase import NS_PER_S

#: Channel 1: 200 us single pulses, its frequency ramping 20 -> 40 Hz over
#: 0.2 s, off from 0.3 s. Channel 2: off, then 300 us doublets at 30 Hz from 0.1 s.
#: The length ramps 1 -> 2 mm.
TWO_CHANNELS = {
    'name': 'two channels', 'duration_s': 0.5,
    'channels': [
        {'frequency_hz': [[0.0, 20.0], [0.2, 40.0]],
         'pulse_width_s': [[0.0, 0.0002], [0.3, 0.0002], [0.3, 0.0]]},
        {'frequency_hz': [[0.0, 30.0]], 'mode': 'doublet',
         'pulse_width_s': [[0.0, 0.0], [0.1, 0.0], [0.1, 0.0003]]},
    ],
    'dl_mt_m': [[0.0, 0.001], [0.5, 0.002]]}
#: [s] the protocol's knot times before its end, time 0 first
KNOT_TIMES_S = [0.0, 0.1, 0.2, 0.3]
#: Each channel's (pulse width [s], frequency [Hz]) at each of KNOT_TIMES_S,
#: read off TWO_CHANNELS by hand (channel 1's frequency is linear between its knots).
EXPECTED = {0.0: [(0.0002, 20.0), (0.0, 30.0)],
            0.1: [(0.0002, 30.0), (0.0003, 30.0)],
            0.2: [(0.0002, 40.0), (0.0003, 30.0)],
            0.3: [(0.0, 40.0), (0.0003, 30.0)]}
MODES = ['single', 'doublet']
#: [ns] when the subscriber matches the player back (test_playback.py's case)
MATCHED_BACK_NS = 151_600_000
#: [ns] one delivery, and one acknowledgement back
LATENCY_NS = 1_000_000
#: [ns] the player's step while it waits for the acknowledgement
WAIT_STEP_NS = 1_000_000
#: [s] tick period: 0.1 s is a multiple of it, 0.03 s is not
PERIOD_S = 0.01
#: [s] look-ahead of the stamped length
LOOKAHEAD_S = 0.05


class Link:
    """A reliable link to one subscriber, on the test's clock: what is sent
    before the subscriber matches back arrives then, later messages one
    latency after they leave."""

    def __init__(self) -> None:
        #: (arrival [ns], when it was sent [ns], the message), in send order
        self.delivered: list[tuple[int, int, Send]] = []

    def send(self, now_ns: int, sends: list[Send]) -> None:
        for send in sends:
            self.delivered.append((max(now_ns, MATCHED_BACK_NS) + LATENCY_NS, now_ns, send))

    def all_acked(self, now_ns: int) -> bool:
        return all(arrival + LATENCY_NS <= now_ns for arrival, _, _ in self.delivered)

    def on(self, topic: str) -> list[tuple[int, int, Send]]:
        return [d for d in self.delivered if d[2].topic == topic]


def _protocol(data: dict = TWO_CHANNELS) -> PulseProtocol:
    return PulseProtocol.from_mapping(data, source='two.yaml')


def _play(data: dict = TWO_CHANNELS, period_s: float = PERIOD_S, lookahead_s: float = 0.0,
          params: MuscleParams | None = None) -> tuple[PulsePlayback, Link]:
    """Play as the node does: the rest state at 0, the protocol once it is
    acknowledged, then a tick every period until the end."""
    playback = PulsePlayback(_protocol(data), params, period_s, lookahead_s)
    link = Link()
    now_ns = 0
    link.send(now_ns, playback.rest())
    while not link.all_acked(now_ns):
        now_ns += WAIT_STEP_NS
    link.send(now_ns, playback.start(now_ns))
    period_ns = round(period_s * NS_PER_S)
    while not playback.finished:
        now_ns += period_ns
        link.send(now_ns, playback.tick(now_ns))
    return playback, link


def _protocol_commands(link: Link) -> list[Send]:
    """The commands of the protocol's knot times: not the rest state, not the final zero."""
    commands = [send for _, _, send in link.on(CHANNELS) if send.protocol_time_s is not None]
    return commands[:-1]


def _values(commands: tuple[ChannelCommand, ...]) -> list[tuple[float, float]]:
    return [(c.pulse_width_s, c.frequency_hz) for c in commands]


def _close(got: list[tuple[float, float]], want: list[tuple[float, float]]) -> bool:
    return len(got) == len(want) and all(
        math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-15)
        for pair_got, pair_want in zip(got, want) for a, b in zip(pair_got, pair_want))


def test_the_commands_go_at_time_zero_and_at_each_knot_time():
    _, link = _play()
    assert [send.protocol_time_s for send in _protocol_commands(link)] == KNOT_TIMES_S
    assert stimulation_times_s(_protocol()).tolist() == KNOT_TIMES_S


def test_each_command_holds_every_channel_read_from_its_tracks_at_its_time():
    _, link = _play()
    for send in _protocol_commands(link):
        assert [c.channel for c in send.value] == [1, 2]
        assert [c.mode for c in send.value] == MODES
        assert _close(_values(send.value), EXPECTED[send.protocol_time_s]), send


def test_time_zero_is_when_the_first_command_acts_after_the_acknowledged_rest_state():
    playback, link = _play()
    rest = [arrival for arrival, _, send in link.delivered if send.protocol_time_s is None]
    first_arrival, _, first = next(d for d in link.on(CHANNELS)
                                   if d[2].protocol_time_s is not None)
    assert playback.t0_ns >= max(rest) + LATENCY_NS
    assert first.protocol_time_s == 0.0 and first_arrival - playback.t0_ns == LATENCY_NS


def test_no_command_leaves_before_its_time():
    playback, link = _play()
    early = [(sent_ns, send) for _, sent_ns, send in link.on(CHANNELS)
             if send.protocol_time_s is not None
             and sent_ns < playback.t0_ns + round(send.protocol_time_s * NS_PER_S)]
    assert not early, early


def test_each_command_is_stamped_with_its_knot_time_on_the_players_clock():
    playback, link = _play()
    stamps = [send.stamp_ns - playback.t0_ns for send in _protocol_commands(link)]
    assert stamps == [round(t * NS_PER_S) for t in KNOT_TIMES_S]


def test_knot_times_a_tick_passes_over_go_out_at_that_tick_in_time_order():
    # 0.25 s ticks pass over 0.1 and 0.2 (and 0.3 before the end).
    playback, link = _play(period_s=0.25)
    sent = [(sent_ns - playback.t0_ns, send.protocol_time_s)
            for _, sent_ns, send in link.on(CHANNELS) if send.protocol_time_s is not None]
    assert [t for _, t in sent[:-1]] == KNOT_TIMES_S
    assert [ns for ns, t in sent if t in (0.1, 0.2)] == [round(0.25 * NS_PER_S)] * 2


def test_the_rest_state_is_a_zero_stimulation_on_every_channel_at_the_starting_length():
    playback = PulsePlayback(_protocol(), None, PERIOD_S, 0.0)
    stim, length = playback.rest()
    assert (stim.topic, length) == (CHANNELS, Send(LENGTH, TWO_CHANNELS['dl_mt_m'][0][1]))
    assert [c.pulse_width_s for c in stim.value] == [0.0, 0.0]
    assert [c.mode for c in stim.value] == MODES


@pytest.mark.parametrize('lookahead_s', [0.0, LOOKAHEAD_S], ids=['plain', 'stamped'])
def test_the_protocol_ends_with_a_zero_stimulation_on_every_channel(lookahead_s):
    _, link = _play(lookahead_s=lookahead_s)
    last = link.delivered[-1][2]
    assert last.topic == CHANNELS and last.protocol_time_s >= TWO_CHANNELS['duration_s']
    assert [c.pulse_width_s for c in last.value] == [0.0, 0.0]


def test_the_length_goes_every_tick_as_for_a_level_protocol():
    playback, link = _play()
    samples = [send for _, _, send in link.on(LENGTH) if send.protocol_time_s is not None]
    times = np.array([send.protocol_time_s for send in samples])
    assert np.allclose(np.diff(times[:-1]), PERIOD_S)
    assert all(math.isclose(send.value, playback.protocol.dl_mt(send.protocol_time_s))
               for send in samples)


def test_with_lookahead_the_length_goes_ahead_and_the_commands_at_their_time():
    playback, link = _play(lookahead_s=LOOKAHEAD_S)
    assert link.on(LENGTH_STAMPED) and not link.on(LENGTH)
    assert [send.protocol_time_s for send in _protocol_commands(link)] == KNOT_TIMES_S


def test_current_is_none_on_every_channel_when_the_protocol_gives_none():
    _, link = _play()
    assert {c.current_a for _, _, send in link.on(CHANNELS) for c in send.value} == {None}


def test_currents_given_on_every_channel_are_sent_and_zero_at_the_end():
    data = dict(TWO_CHANNELS, channels=[
        dict(TWO_CHANNELS['channels'][0], current_a=[[0.0, 0.03]]),
        dict(TWO_CHANNELS['channels'][1], current_a=[[0.0, 0.02], [0.2, 0.04]])])
    _, link = _play(data)
    by_time = {send.protocol_time_s: [c.current_a for c in send.value]
               for send in _protocol_commands(link)}
    assert by_time[0.1] == pytest.approx([0.03, 0.03])
    assert [c.current_a for c in link.delivered[-1][2].value] == [0.0, 0.0]


@pytest.mark.parametrize('params, channel, value, pattern', [
    # 600 us, wider than the generic stimulator's pw_max_s
    (MuscleParams(), 1, 0.0006, r'`pulse_width_s` of channel 1 must be in \[0, 0\.0005\] s '
                                r'on generic, got 0\.0006'),
    (MuscleParams(stimulator='p24'), 2, 3000.0,
     r'`frequency_hz` of channel 2 must be in \[0\.5, 2000\] Hz on p24, got 3000\.0'),
    (MuscleParams(stimulator='rehastim2'), 2, 25.0,
     r'`frequency_hz` must be the same on every channel on rehastim2'),
], ids=['generic-pulse-width', 'p24-frequency', 'rehastim2-shared-frequency'])
def test_a_protocol_the_stimulator_would_reject_is_refused_naming_field_channel_value(
        params, channel, value, pattern):
    data = yaml.safe_load(yaml.safe_dump(TWO_CHANNELS))
    key = 'pulse_width_s' if value < 1.0 else 'frequency_hz'
    entry = data['channels'][channel - 1]
    entry[key] = [[0.0, value]]
    if channel == 2 and key == 'frequency_hz':
        entry['mode'] = 'single'   # a doublet at 3 kHz is refused when the protocol is read
    with pytest.raises(ValueError, match=pattern) as refused:
        PulsePlayback(_protocol(data), params, PERIOD_S, 0.0, source='two.yaml')
    assert str(refused.value).startswith('two.yaml: the command at t = 0 s: ')


def test_without_muscle_params_the_generic_profile_checks():
    assert PulsePlayback(_protocol(), None, PERIOD_S, 0.0).profile.name == 'generic'


def test_currents_on_some_channels_only_are_refused():
    data = dict(TWO_CHANNELS, channels=[
        dict(TWO_CHANNELS['channels'][0], current_a=[[0.0, 0.03]]),
        TWO_CHANNELS['channels'][1]])
    with pytest.raises(ValueError, match=r'`current_a` must be given on every channel or on '
                                         r'none .* channel\(s\) 1 and not on 2'):
        PulsePlayback(_protocol(data), None, PERIOD_S, 0.0)


def test_a_doublet_with_a_burst_interval_other_than_the_muscles_is_refused():
    data = dict(TWO_CHANNELS, channels=[
        TWO_CHANNELS['channels'][0], dict(TWO_CHANNELS['channels'][1], burst_interval_s=0.01)])
    with pytest.raises(ValueError, match=r'`burst_interval_s` of channel 2 must be the '
                                         r'muscle\'s `burst_interval_s` 0\.005 s .* got 0\.01'):
        PulsePlayback(_protocol(data), MuscleParams(), PERIOD_S, 0.0)


@pytest.mark.parametrize('name', ['kesar2006_11hz_600us', 'kesar2006_30hz_150us',
                                  'kesar2006_60hz_131us', 'catchlike_cft', 'catchlike_vft',
                                  'sdss_one_channel', 'sdss_four_channels'])
def test_the_shipped_channel_protocols_pass_the_generic_stimulator_of_the_fes_preset(
        protocol_paths, name):
    """config/fes_quadriceps.yaml's pw_max_s (600 us) admits Kesar's widest pulse."""
    path = protocol_paths['I'].parent / f'{name}.yaml'
    protocol = PulseProtocol.from_yaml(path)
    playback = PulsePlayback(protocol, MuscleParams(pw_max_s=0.0006), 0.001, 0.0)
    assert playback.times_s[0] == 0.0 and playback.times_s[-1] < protocol.duration_s


# -- the node, as a process -----------------------------------------------------


def _protocol_file(tmp_path, data=TWO_CHANNELS):
    path = tmp_path / 'two_channels.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


def _stamp_ns(stamp) -> int:
    return stamp.sec * NS_PER_S + stamp.nanosec


def _is_zero(msg) -> bool:
    return bool(msg.pulse_width_s) and all(pw == 0.0 for pw in msg.pulse_width_s)


@pytest.mark.ros
def test_player_node_sends_the_rest_state_each_knot_command_then_zero_on_stimulation(tmp_path):
    from hill_muscle_interfaces.msg import Stimulation
    from rclpy.qos import QoSProfile
    from ros_helpers import Probe, ProcessGroup, node_command

    path = _protocol_file(tmp_path)
    ns = '/pulse_player'
    with ProcessGroup(tmp_path) as procs, Probe() as probe:
        stim = probe.record(f'{ns}/stimulation', Stimulation, qos=QoSProfile(depth=1000))
        length = probe.record(f'{ns}/length_command', Float64, qos=QoSProfile(depth=1000))
        player = procs.start('player', node_command('protocol_player', ns=ns, params={
            'protocol': str(path), 'rate_hz': 100.0}))
        probe.spin_until(lambda: player.returncode is not None, 'the player to exit')
        # Its exit says nothing of what the probe has taken yet: wait for the
        # final zero (the rest state is a zero too: two of them).
        probe.spin_until(lambda: len(stim.messages) > 2 and _is_zero(stim.messages[-1]),
                         'the final zero stimulation')
    assert player.returncode == 0, player.describe()
    messages = stim.messages
    assert _is_zero(messages[0]) and _is_zero(messages[-1])
    commands = messages[1:-1]
    t0_ns = _stamp_ns(commands[0].header.stamp)
    assert [(_stamp_ns(m.header.stamp) - t0_ns) / NS_PER_S for m in commands] == \
        pytest.approx(KNOT_TIMES_S, abs=1e-9)
    for t_s, msg in zip(KNOT_TIMES_S, commands):
        assert list(msg.channel) == [1, 2] and list(msg.mode) == MODES
        assert len(msg.current_a) == 0
        assert _close(list(zip(msg.pulse_width_s, msg.frequency_hz)), EXPECTED[t_s]), (t_s, msg)
    assert length.messages[0].data == TWO_CHANNELS['dl_mt_m'][0][1]
    assert length.messages[-1].data == pytest.approx(TWO_CHANNELS['dl_mt_m'][-1][1])
    assert 'commands checked against generic' in player.output()


@pytest.mark.ros
def test_player_node_refuses_a_protocol_the_stimulator_would_reject(tmp_path):
    from ros_helpers import ProcessGroup, node_command

    data = yaml.safe_load(yaml.safe_dump(TWO_CHANNELS))
    data['channels'][0]['pulse_width_s'] = [[0.0, 0.0006]]
    path = _protocol_file(tmp_path, data)
    with ProcessGroup(tmp_path) as procs:
        player = procs.start('player', node_command('protocol_player', params={
            'protocol': str(path), 'stimulator': 'rehastim2'}))
        status = player.wait()
    assert status != 0
    log = player.output()
    assert (f'{path}: the command at t = 0 s: `pulse_width_s` of channel 1 must be 0 or in '
            '[2e-05, 0.0005] s on rehastim2, got 0.0006') in log
    assert 'Traceback' not in log
