"""The protocol player, alone, with the simulator, and on sim time.

Protocol II through DDS against the offline core is test_demo's: ``make demo``
runs the same two nodes (and a recorder), and the test reads its bag back.
Every test runs its nodes in its own namespace.
"""
import math
import time

import numpy as np
import pytest
import yaml
from geometry_msgs.msg import PointStamped, WrenchStamped
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64

from hill_muscle_ros.model import MuscleParams, Protocol, ProtocolError
from rclpy.qos import QoSProfile
from ros_helpers import Probe, ProcessGroup, node_command

pytestmark = pytest.mark.ros

#: A short protocol: R steps 0.3 -> 0.7 at 0.25 s, the length ramps 0 -> 2 mm.
SHORT = {'name': 'short', 'duration_s': 0.5,
         'recruitment': [[0.0, 0.3], [0.25, 0.3], [0.25, 0.7]],
         'dl_mt_m': [[0.0, 0.0], [0.5, 0.002]]}
#: Reliable with room for 5 s of 1 kHz messages, so a busy probe loses none.
DEEP_QOS = QoSProfile(depth=5000)
#: [s] how much shorter than the protocol its sim-time span may look (the
#: span, from the first force to the end of the relaxation after the final
#: zero, is about 1.445 s for this 1 s protocol: six runs). The player's clock
#: lags the simulator's by its /clock latency x RTF. Before the player started
#: the protocol's time at the acknowledgement of its first sample, that sample
#: could arrive one writer heartbeat (0.1 s wall, 0.3 s sim) late, which
#: this margin was sized for. Still far from the wall-clock span (3 s), which
#: the upper bound keeps apart.
SIM_SPAN_TOL_S = 0.4
#: [-] real-time factor of the sim-time test
RTF = 3.0
#: [N] clearly active force (R = 0.3..0.7 gives tens of newtons)
ACTIVE_FORCE_N = 10.0
#: [N] tolerance on a force that should be exact
FORCE_TOL_N = 0.01


def _protocol_file(tmp_path, data):
    path = tmp_path / f'{data["name"]}.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


#: The protocol of the bad-protocol-file test: a recruitment above 1.
BAD_SHORT = dict(SHORT, name='bad', recruitment=[[0.0, 1.5]])


@pytest.fixture(scope='module')
def exiting_players(tmp_path_factory):
    """The players that must exit non-zero, all started at once when the
    module's first test asks (each waits out its own time, idle, while the
    tests before its own run): one without a subscriber, one with a bad
    protocol file (``bad_path``), and one short of ``min_subscribers`` on each
    output (the probe of this fixture subscribes once to each). Name -> process."""
    tmp = tmp_path_factory.mktemp('exiting_players')
    bad_path = _protocol_file(tmp, BAD_SHORT)
    with ProcessGroup(tmp) as procs, Probe('exiting_players_probe') as probe:
        ns = '/one_sub'
        probe.record(f'{ns}/pulse_width', Float64)
        probe.record(f'{ns}/length_command_stamped', PointStamped)
        players = {
            'lonely': procs.start('lonely', node_command(
                'protocol_player', ns='/lonely', params={'wait_for_subscribers_s': 0.3})),
            'bad_protocol': procs.start('bad_protocol', node_command(
                'protocol_player', params={'protocol': str(bad_path)})),
            'one_sub': procs.start('one_sub', node_command('protocol_player', ns=ns, params={
                'min_subscribers': 2, 'wait_for_subscribers_s': 2.0, 'lookahead_s': 0.05})),
            'bad_path': bad_path,
        }
        yield players


def test_player_without_subscriber_fails_clearly(exiting_players):
    player = exiting_players['lonely']
    status = player.wait()
    assert status != 0
    assert '/lonely/pulse_width has 0' in player.output()
    assert 'min_subscribers 1' in player.output()


def test_bad_protocol_file_exits_with_validator_message(exiting_players):
    with pytest.raises(ProtocolError) as expected:
        Protocol.from_yaml(exiting_players['bad_path'])
    player = exiting_players['bad_protocol']
    status = player.wait()
    assert status != 0
    assert str(expected.value) in player.output()
    assert 'Traceback' not in player.output()


#: The replay test's cases: output -> (pw_max_s, scale).
REPLAYS = {
    'recruitment': (0.0005, 1.0),
    'pulse_width': (0.001, 0.001),   # R * pw_max_s, with the player's own pw_max_s
}


@pytest.fixture(scope='module')
def short_replays(tmp_path_factory):
    """The SHORT protocol played to its end by a player per :data:`REPLAYS`
    case and by one with ``lookahead_s`` (:func:`_lookahead_run`), all at once,
    each in a namespace of its own: name -> its player and recordings."""
    tmp = tmp_path_factory.mktemp('short_replays')
    path = _protocol_file(tmp, SHORT)
    protocol = Protocol.from_yaml(path)
    runs = {}
    with ProcessGroup(tmp) as procs, Probe('short_replays_probe') as probe:
        for output, (pw_max_s, _) in REPLAYS.items():
            ns = f'/replay_{output}'
            run = runs[output] = {'stim': probe.record(f'{ns}/{output}', Float64),
                                  'length': probe.record(f'{ns}/length_command', Float64)}
            run['player'] = procs.start(f'player_{output}', node_command(
                'protocol_player', ns=ns, params={
                    'protocol': str(path), 'output': output, 'rate_hz': 100.0,
                    'pw_max_s': pw_max_s}))
        runs['lookahead'] = _lookahead_run(procs, probe, path)
        players = [run['player'] for run in runs.values()]
        probe.spin_until(lambda: all(p.returncode is not None for p in players),
                         'the players to exit')
        # Their exits say nothing of what the probe has taken yet: wait for the
        # final zero and the protocol's last length, and the lookahead's knot
        # at the protocol's end.
        final_length_m = protocol.dl_mt(protocol.duration_s)
        for output in REPLAYS:
            stim, length = runs[output]['stim'], runs[output]['length']
            probe.spin_until(lambda: _ends_with(stim, 0.0) and _ends_with(length, final_length_m),
                             'the final zero stimulation and the final length')
        knots = runs['lookahead']['knots']
        probe.spin_until(lambda: len(knots.messages) > 1 and (
            _stamp_ns(knots.messages[-1].header.stamp)
            - _stamp_ns(knots.messages[0].header.stamp)) / 1e9 >= protocol.duration_s - 1e-9,
            "the knot at the protocol's end")
    return runs


@pytest.mark.parametrize('output', list(REPLAYS))
def test_player_replays_protocol_then_sends_zero(short_replays, output):
    pw_max_s, scale = REPLAYS[output]
    protocol = Protocol.from_mapping(SHORT)
    run = short_replays[output]
    stim, length, player = run['stim'], run['length'], run['player']
    assert player.returncode == 0, player.describe()
    values = np.array([m.data for m in stim.messages])
    # The rest state first, then the protocol from its time 0.
    assert values[0] == 0.0 and length.messages[0].data == protocol.dl_mt(0.0)
    assert values[1] == pytest.approx(protocol.recruitment(0.0, pw_max_s) * scale)
    assert values[-1] == 0.0
    allowed = {0.0, *(r * scale for r in protocol.stimulation.values)}
    assert all(any(math.isclose(v, a) for a in allowed) for v in values)
    assert length.messages[-1].data == pytest.approx(protocol.dl_mt(protocol.duration_s))


#: Polls of the player (every 50 ms) that must see the rest state
#: unacknowledged, and so not start the protocol.
UNACKED_POLLS = 5


@pytest.fixture
def player_in_process(tmp_path):
    """A ProtocolPlayer in this process (rclpy's default context), spun in a
    thread, whose outputs report acknowledgement only when the test says so:
    ``(player, acked, polls)``, ``acked`` an Event, ``polls`` a list holding
    the count of acknowledgement checks."""
    import threading

    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from hill_muscle_ros.nodes.protocol_player import ProtocolPlayer

    path = _protocol_file(tmp_path, SHORT)
    rclpy.init(args=['--ros-args', '-r', '__ns:=/handshake', '-p', f'protocol:={path}',
                     '-p', 'output:=recruitment', '-p', 'rate_hz:=100.0'])
    player = ProtocolPlayer()
    acked, polls = threading.Event(), [0]

    def wait_for_all_acked(timeout):
        polls[0] += 1
        return acked.is_set()

    for pub in (player._pub_stim, player._pub_dl):
        pub.wait_for_all_acked = wait_for_all_acked
    executor = SingleThreadedExecutor()
    executor.add_node(player)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        yield player, acked, polls
    finally:
        executor.shutdown()
        player.destroy_node()
        rclpy.try_shutdown()
        spinner.join(timeout=5.0)


def test_the_protocol_starts_only_once_every_subscriber_has_the_rest_state(
        player_in_process):
    # A subscriber matched on the player's side may not yet have matched back:
    # what the player sends then reaches it only with the next heartbeat, so
    # the rest state goes first and the protocol waits for its acknowledgement.
    player, acked, polls = player_in_process
    protocol = Protocol.from_mapping(SHORT)
    with Probe() as probe:
        stim = probe.record('/handshake/recruitment', Float64)
        probe.record('/handshake/length_command', Float64)
        probe.wait_for_messages(stim)
        assert stim.messages[0].data == 0.0
        seen = polls[0]
        probe.spin_until(lambda: polls[0] >= seen + UNACKED_POLLS
                         or player._playback.t0_ns is not None,
                         f'{UNACKED_POLLS} more polls of the player, or its start')
        assert player._playback.t0_ns is None, 'the protocol started without an acknowledgement'
        assert len(stim.messages) == 1
        acked_at_s = time.monotonic()
        acked.set()
        probe.spin_until(player.done.done, 'the player to finish')
        probe.spin_until(lambda: _ends_with(stim, 0.0), 'the final zero stimulation')
    assert player.done.result() == 0
    assert len(stim.messages) > 2
    assert stim.times_s[1] >= acked_at_s
    assert stim.messages[1].data == pytest.approx(protocol.recruitment(0.0, 1.0))
    assert stim.messages[-1].data == 0.0


def test_player_on_sim_time_follows_published_clock(tmp_path):
    """A simulator 3x faster than the wall clock drives a use_sim_time player.

    The player's run is timed in sim time by its effect on the simulator:
    from the first step with force (the first message arrived) to the step
    where force falls to the parallel spring's alone (the final zero
    stimulation). On sim time that is the protocol's 1 s; on the wall clock
    it would be 3 s.
    """
    protocol = dict(SHORT, duration_s=1.0)
    path = _protocol_file(tmp_path, protocol)
    final_pe_force_n = MuscleParams().k_pe_n_per_m * protocol['dl_mt_m'][-1][1]
    ns = '/simtime'
    # /clock is one per graph: remapped, so no other test's time source can interfere.
    clock_topic = f'{ns}/clock'
    remap = ['-r', f'/clock:={clock_topic}']
    with ProcessGroup(tmp_path) as procs, Probe() as probe:
        clock = probe.record(clock_topic, Clock, qos=DEEP_QOS)
        wrench = probe.record(f'{ns}/wrench', WrenchStamped, qos=DEEP_QOS)
        started_s = time.monotonic()
        sim = procs.start('sim', node_command('simulator', ns=ns, params={
            'publish_clock': True, 'real_time_factor': RTF, 'rate_hz': 200.0},
            extra_ros_args=remap))
        probe.wait_for_messages(wrench, procs=[sim])
        player = procs.start('player', node_command('protocol_player', ns=ns, params={
            'protocol': str(path), 'output': 'recruitment', 'rate_hz': 100.0,
            'use_sim_time': True}, extra_ros_args=remap))
        probe.spin_until(lambda: player.returncode is not None, 'the player to finish',
                         procs=[sim])
        assert player.returncode == 0, player.describe()
        # The player's exit says nothing of what the probe has taken yet: wait
        # until the force has fallen to the parallel spring's alone.
        probe.spin_until(lambda: _sim_span(wrench, final_pe_force_n) is not None,
                         'the force to fall to the parallel spring\'s after the final zero',
                         procs=[sim])
    clock_s = np.array([_sec(m.clock) for m in clock.messages])
    stamps_s = np.array([_sec(w.header.stamp) for w in wrench.messages])
    # Sim time starts at 0 with the simulator: it cannot be ahead of 3x the
    # time since the process started (wall-clock stamps would be ~1.8e9 s).
    assert 0.0 < clock_s[0] <= RTF * (clock.times_s[0] - started_s)
    # Outputs are stamped with the published sim time: the same instants as
    # /clock (the probe may lose some of either when the machine is busy).
    assert np.isin(stamps_s, clock_s).any()
    assert 0.0 < stamps_s.min() and stamps_s.max() <= RTF * (time.monotonic() - started_s)
    start, end = _sim_span(wrench, final_pe_force_n)
    # Latency and stalls of the player add a little sim time (x RTF); the
    # bound halfway to the wall-clock span keeps the two cases apart.
    span_s = stamps_s[end] - stamps_s[start]
    assert protocol['duration_s'] - SIM_SPAN_TOL_S <= span_s
    assert span_s < 0.5 * (1.0 + RTF) * protocol['duration_s']


def _sec(stamp):
    return stamp.sec + stamp.nanosec * 1e-9


def _ends_with(rec, value):
    """Whether the last message of ``rec`` carries ``value`` (as pytest.approx
    would say: to 1e-6 relative, 1e-12 absolute)."""
    return bool(rec.messages) and math.isclose(rec.messages[-1].data, value,
                                               rel_tol=1e-6, abs_tol=1e-12)


def _sim_span(wrench, final_pe_force_n):
    """Indices of the first force and of the step where, after a clearly
    active force, it has fallen to the parallel spring's alone; None until
    both were received."""
    f = np.array([w.wrench.force.x for w in wrench.messages])
    if not np.any(f > 0.0):
        return None
    start = int(np.argmax(f > 0.0))
    if not np.any(f[start:] > ACTIVE_FORCE_N):
        return None
    active = start + int(np.argmax(f[start:] > ACTIVE_FORCE_N))
    fallen = np.abs(f[active:] - final_pe_force_n) < FORCE_TOL_N
    if not np.any(fallen):
        return None
    return start, active + int(np.argmax(fallen))



#: [s] look-ahead of the stamped-length tests: 10 periods at 100 Hz
LOOKAHEAD_S = 0.1
PLAYER_RATE_HZ = 100.0


def _stamp_ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _lookahead_run(procs, probe, path):
    """A player of ``path`` with ``lookahead_s``, started, its outputs recorded
    (played with the replays: :func:`short_replays`)."""
    ns = '/lookahead'
    run = {'knots': probe.record(f'{ns}/length_command_stamped', PointStamped, qos=DEEP_QOS),
           'stim': probe.record(f'{ns}/recruitment', Float64, qos=DEEP_QOS),
           'plain': probe.record(f'{ns}/length_command', Float64)}
    run['player'] = procs.start('player_lookahead', node_command('protocol_player', ns=ns, params={
        'protocol': str(path), 'output': 'recruitment', 'rate_hz': PLAYER_RATE_HZ,
        'lookahead_s': LOOKAHEAD_S}))
    return run


def test_player_with_lookahead_sends_the_protocol_length_ahead_as_stamped_knots(short_replays):
    protocol = Protocol.from_mapping(SHORT)
    run = short_replays['lookahead']
    knots, stim, plain, player = run['knots'], run['stim'], run['plain'], run['player']
    assert player.returncode == 0, player.describe()
    assert not plain.messages
    stamps = np.array([_stamp_ns(m.header.stamp) for m in knots.messages])
    t0 = stamps[0]
    tau = (stamps - t0) / 1e9
    values = np.array([m.point.x for m in knots.messages])
    # Protocol time 0 is the first knot; each knot is the protocol at its stamp.
    assert np.all(np.diff(stamps) > 0)
    assert tau[-1] == pytest.approx(protocol.duration_s, abs=1e-9)
    np.testing.assert_allclose(values, protocol.dl_mt(tau), rtol=0.0, atol=1e-15)
    # Every corner of the protocol's length is a knot, so interpolating the
    # knots is the protocol exactly.
    for corner in protocol.dl_mt_m.breakpoints_s:
        assert np.min(np.abs(tau - corner)) < 1e-9, corner
    # The rest state, then the whole first window before the protocol's first stimulation.
    assert stim.messages[0].data == 0.0
    first_stim_s = stim.times_s[1]
    sent_before = tau[np.array(knots.times_s) < first_stim_s]
    assert sent_before.max() >= LOOKAHEAD_S - 1e-9
    assert np.all(np.diff(sent_before) <= 1.0 / PLAYER_RATE_HZ + 1e-9)


def test_player_waits_for_min_subscribers_on_every_output(tmp_path):
    path = _protocol_file(tmp_path, SHORT)
    ns = '/two_subs'
    with ProcessGroup(tmp_path) as procs, Probe() as probe:
        stim = probe.record(f'{ns}/recruitment', Float64, qos=DEEP_QOS)
        probe.record(f'{ns}/length_command', Float64)
        player = procs.start('player', node_command('protocol_player', ns=ns, params={
            'protocol': str(path), 'output': 'recruitment', 'rate_hz': PLAYER_RATE_HZ,
            'min_subscribers': 2, 'wait_for_subscribers_s': 60.0}))
        probe.spin_until(lambda: 'waiting up to' in player.output(), 'the player to wait',
                         procs=[player])
        # A second subscription on each output, as a recorder would add.
        second = [probe.node.create_subscription(Float64, f'{ns}/{topic}', lambda _m: None,
                                                 DEEP_QOS)
                  for topic in ('recruitment', 'length_command')]
        added_s = time.monotonic()
        probe.spin_until(lambda: player.returncode is not None, 'the player to exit')
    assert second and player.returncode == 0, player.describe()
    assert stim.messages and min(stim.times_s) > added_s


def test_player_timeout_names_the_topic_and_the_subscriber_counts(exiting_players):
    ns = '/one_sub'
    player = exiting_players['one_sub']
    assert player.wait(timeout_s=60.0) != 0
    log = player.output()
    assert f'{ns}/pulse_width has 1' in log
    assert f'{ns}/length_command_stamped has 1' in log
    assert 'of min_subscribers 2' in log
