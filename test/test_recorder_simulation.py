"""A live run of the real nodes (simulator, protocol player, recorder: three
processes over DDS), recorded, read back with every promised reader,
cross-checked against the offline core, and fitted: ``hill-muscle fit``
recovers the simulator's non-default muscle parameters from the bag.

The simulator runs the :data:`TRUTH` muscle (the defaults are 45 N, 10 kN/m
and 10 N), against which the offline core is run too. What the recorder
writes (every topic, the gaps it reports, the same wrenches a probe got, the
player's inputs exactly, every reader agreeing) is checked on one live run of
:data:`BRIEF_PROTOCOL` (``live_run``), whatever the machine does meanwhile.
That the recorded force is the offline core's at the end of each second, and
that the fit recovers the parameters, hold only for a run the machine did not
hold up just before a sample time: claims on the live run's timing, on
Protocol II (``timed_live_run``, ``make check-realtime``).

The player sends the length ahead, stamped (``lookahead_s``, as the demo
does), and the simulator reaches each length at its stamp. On the plain
``length_command`` the simulator acts on the newest value it has received,
one DDS delivery late: mid-ramp (1.95 s, 10 mm/s) the force follows the
length's velocity, and a CI run whose length reached the simulator ~45 ms
late, with no stall of any process, read 0.59 N below the offline force.
That is the latency of a plain topic, which no recording can undo; the
stamped knots take it out of the comparison.

What DDS timing does to the fit's inputs, and so its tolerances:

- The length is exact as long as every knot arrives before its stamp. The
  player sends it ahead as stamped knots (``lookahead_s``), the simulator
  reaches each knot at its stamp, and the fit interpolates the same knots at
  the same stamps.
- The stimulation is not. It goes on the plain ``pulse_width`` topic at its
  time; the simulator applies a message from the first step of its next tick,
  while the bag stamps it with the recorder's receive time. In two recorded
  runs the three changes (onset, the step at 3 s, the release)
  acted -4/-5/-1 ms and -2/-1/-13 ms from their stamps. One step off leaves a
  residual as large as the force's jump there (40 N at the release), and the
  plain fit of those two bags missed ``fv_a_n`` by 4.1 % and 9.2 %, since the
  Hill constant shows only while the CE moves, right after the changes.
  ``--edge-search`` moves each change to the step that best explains the force
  (within ±:data:`EDGE_SEARCH_S`), so that error is gone: the second run's
  aligned fit is exact (residual RMS 4e-6 N).
- What remains is a knot that arrives after its stamp, under load: in the first
  run 2 of 3347 knots came 15 ms late at the start of the ramp, the simulator's
  length was up to 0.29 mm off the knots for a few ms (read back from its force
  and CE length), and the aligned fit gave ``f_iso_max_n`` 0.04 %,
  ``k_se_n_per_m`` 0.59 % and ``fv_a_n`` 0.83 % off. The tolerances allow
  about three times that; they stay well inside the distance the fit travels
  (the defaults are 13 %, 25 % and 23 % off). That run's player sent the knots
  0.1 s ahead (the demo's look-ahead); this module sends them
  :data:`LOOKAHEAD_S` ahead, so a knot is late only if DDS takes longer than
  that to deliver it, and the fit sees the length the simulator ran. The
  simulator's exit line (late knots, longest tick gap) is quoted on failure.
"""
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from std_msgs.msg import Float64

from hill_muscle_ros.model import MuscleParams, Protocol, simulate
from hill_muscle_ros.params_file import load_muscle_params
from hill_muscle_ros.recording.analysis import (SIMULATOR_LAG_LIMIT_S, live_force_at,
                                                protocol_start_ns, simulator_lag_s,
                                                summary_times)
from hill_muscle_ros.recording.reader import read_bag
from hill_muscle_ros.timebase import NS_PER_S
from live_run import record_live_run, wait_until_recording
from ros_helpers import ProcessGroup, Probe, node_command
from stall_watch import repeat_only_on_external_stall

pytestmark = pytest.mark.ros

#: [N] agreement asked of the recorded force with the offline simulation.
FORCE_TOLERANCE_N = 0.5
TOPICS = ('pulse_width', 'length_command_stamped', 'force', 'ce_length', 'wrench')
MESSAGE_TYPES = {'wrench': 'geometry_msgs/msg/WrenchStamped',
                 'length_command_stamped': 'geometry_msgs/msg/PointStamped'}


#: The simulated subject (the defaults are 45 N, 10 kN/m and 10 N): as in test_fit.
TRUTH = {'f_iso_max_n': 52.0, 'k_se_n_per_m': 8000.0, 'fv_a_n': 13.0}
#: [s] the window of the fit's --edge-search. Moves of 13 ms were seen on an
#: idle machine; with a compiler busy on the other core a fresh-clone run saw
#: -16 ms and two moves at the edge of a 30 ms window (the fit then missed
#: ``f_iso_max_n`` by 0.8 %). The simulator itself catches up at most 0.1 s of
#: clock time per tick; a recorder that falls further behind than that is
#: overloaded, which its diagnostics report.
EDGE_SEARCH_S = 0.1
#: [s] the player's look-ahead of the length knots. A reliable sample that UDP
#: dropped comes again on the writer's next heartbeat (0.1 s here), and a
#: Python process on a busy 2-core machine can be descheduled for tens of ms:
#: 1 s is ten heartbeats. It costs a start one look-ahead later, nothing else.
LOOKAHEAD_S = 1.0
#: Relative tolerance of each fitted estimate: about three times the errors of
#: the aligned fit of the run with late knots (0.04 %, 0.59 %, 0.83 %).
FIT_TOLERANCE = {'f_iso_max_n': 0.002, 'k_se_n_per_m': 0.02, 'fv_a_n': 0.025}

#: A live run is repeated (at most this many times in all) when the machine
#: demonstrably disturbed it (the stall watcher measured it), so that it is
#: no fair test of the recording:
#: DDS discovery so slow that the simulator missed the player's start (the
#: player starts on its first subscriber), or the player or the simulator
#: stalled just before a sample time (a 100 ms stall during a ramp moves the
#: force by ~2 N). Which happened is in the failure message.
MAX_ATTEMPTS = 3
#: [s] longest pause between two of the player's (1 kHz) or the simulator's
#: messages, in the :data:`SAMPLE_WINDOW_S` before a sample time, that still
#: counts as an undisturbed run (during a ramp, ~0.4 N of force).
STALL_LIMIT_S = 0.03
#: [s] the force at a sample time depends on the inputs of this long before it.
SAMPLE_WINDOW_S = 0.2
#: Forces (1 kHz) the probe receives after the recorder subscribed, before the
#: sim-time recorder stops: several times the 100 of /clock and force the bag must hold.
SIM_TIME_RECORDED_MSGS = 500
#: [s] Protocol II lasts 6 s.
PROTOCOL_DURATION_S = 6.0
#: Protocol II in 2 s, for what the recorder writes: R = 0.5 then 1.0, the
#: stretch to 10 mm and back (its ramps 20 mm/s), 2000 steps of every output.
BRIEF_PROTOCOL = {'name': 'Protocol II in 2 s', 'duration_s': 2.0,
                  'recruitment': [[0.0, 0.5], [1.0, 0.5], [1.0, 1.0]],
                  'dl_mt_m': [[0.0, 0.0], [0.25, 0.0], [0.75, 0.010], [1.25, 0.010],
                              [1.75, 0.0]]}


def _one_live_run(tmp, ns, protocol_file):
    return {**record_live_run(tmp, ns, protocol_file, sim_params=TRUTH,
                              lookahead_s=LOOKAHEAD_S), 'ns': ns}


def bag_of(run):
    """The run's bag, read back (:func:`read_bag`) once for every test of the module:
    read_bag decodes each of its ~34k messages in Python, 0.4-0.6 CPU-s a read,
    and nine reads of the same bag were about 4 of the module's CPU-s."""
    if 'bag_data' not in run:
        run['bag_data'] = read_bag(run['bag'])
    return run['bag_data']


def simulator_statistics(log: str) -> str:
    """The simulator's exit line (steps, tick gaps, late knots), or a note that it is missing."""
    lines = [line for line in log.splitlines() if 'late length_command_stamped knots' in line]
    return lines[-1] if lines else f'(no exit statistics in the simulator log: {log[-500:]!r})'


def _disturbance(run) -> str:
    """How the machine disturbed the live run, or '' if it did not."""
    if run['status'] != 0:
        return ''  # a recorder failure is never retried
    bag = bag_of(run)
    lag = simulator_lag_s(bag)
    if lag is not None and lag > SIMULATOR_LAG_LIMIT_S:
        return f'the simulator matched the player {lag:.3f} s late'
    t0 = protocol_start_ns(bag)

    def longest_pause_s(times_ns):
        """Longest pause ending in the window before a sample time."""
        t = (np.asarray(times_ns) - t0) / NS_PER_S
        gaps = np.diff(t)
        near = np.zeros(len(gaps), dtype=bool)
        for sample in summary_times(PROTOCOL_DURATION_S):
            near |= (t[1:] > sample - SAMPLE_WINDOW_S) & (t[:-1] < sample)
        return float(gaps[near].max()) if near.any() else float('inf')

    player = longest_pause_s(bag.topic('pulse_width').log_time_ns)
    if player > STALL_LIMIT_S:
        return f'the player paused {player:.3f} s'
    sim = longest_pause_s(bag.topic('wrench').stamps_ns())
    if sim > STALL_LIMIT_S:
        return f'the simulator skipped {sim:.3f} s of steps'
    return ''


def offline_force_misses(run, protocol_file) -> list[tuple[float, float, float]]:
    """(t [s], live [N], offline [N]) at each end of a second where the recorded
    force is :data:`FORCE_TOLERANCE_N` or more off the offline core's."""
    protocol = Protocol.from_yaml(protocol_file)
    offline = simulate(protocol, MuscleParams().replace(**TRUTH), 1000.0)
    times = summary_times(protocol.duration_s)
    live = live_force_at(bag_of(run), times)
    expected = [float(offline.force_n[offline.at(t)]) for t in times]
    print(f'live - offline at {times} s: {np.subtract(live, expected)} N')  # measured
    return [(t, f, e) for t, f, e in zip(times, live, expected)
            if not abs(f - e) < FORCE_TOLERANCE_N]


def start_fit(run) -> None:
    """Start ``hill-muscle fit --edge-search`` of the run's bag in a process of its
    own, once per run; :func:`fit_of` collects it. The fixture starts it as soon
    as the run is judged, so that it computes while the next tests wait on DDS."""
    if 'fit' not in run:
        out_file = run['bag'].parent / 'fitted.yaml'
        proc = subprocess.Popen(
            [sys.executable, '-m', 'hill_muscle_ros.tools.cli', 'fit', '--bag', str(run['bag']),
             '--fit', ','.join(TRUTH), '--edge-search', str(EDGE_SEARCH_S),
             '--out', str(out_file)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        run['fit'] = (proc, out_file)


def fit_of(run) -> dict:
    """``hill-muscle fit --edge-search`` of the run's bag, once per run: ``status``,
    ``out``, ``err`` and ``fitted`` (the parameters, or None)."""
    start_fit(run)
    if isinstance(run['fit'], tuple):
        proc, out_file = run['fit']
        out, err = proc.communicate()
        status = proc.returncode
        run['fit'] = {'status': status, 'out': out, 'err': err,
                      'fitted': load_muscle_params(out_file)[0] if status == 0 else None}
    return run['fit']


def fit_misses(run) -> list[str]:
    """The fitted parameters outside :data:`FIT_TOLERANCE` (all, if the fit failed)."""
    fit = fit_of(run)
    if fit['fitted'] is None:
        return list(TRUTH)
    return [name for name, truth in TRUTH.items()
            if getattr(fit['fitted'], name) != pytest.approx(truth, rel=FIT_TOLERANCE[name])]


@pytest.fixture(scope='module')
def live_run(tmp_path_factory):
    """:data:`BRIEF_PROTOCOL` over DDS to the :data:`TRUTH` muscle, recorded; a
    probe in the test records the wrench too."""
    tmp = tmp_path_factory.mktemp('live_brief')
    protocol_file = tmp / 'protocol.yaml'
    protocol_file.write_text(yaml.safe_dump(BRIEF_PROTOCOL))
    return _one_live_run(tmp, f'/live{os.getpid()}_brief', protocol_file)


@pytest.fixture(scope='module')
def timed_live_run(tmp_path_factory, protocol_paths, stall_watcher):
    """Protocol II over DDS to the :data:`TRUTH` muscle, recorded, and its fit
    started; a probe in the test records the wrench too.

    A disturbed run (see :func:`_disturbance`) is repeated only when the stall
    watcher measured the machine leaving it unscheduled during that run, and
    only if the disturbance shows: a run that the machine demonstrably
    disturbed but whose force still matches the offline core's at every end
    of a second, and whose fit still recovers every parameter, is kept. A
    disturbance with no stall measured fails, as before.
    """
    attempts = iter(range(MAX_ATTEMPTS))

    def one_run():
        attempt = next(attempts)
        tmp = tmp_path_factory.mktemp(f'live{attempt}')
        started_s = time.monotonic()
        run = _one_live_run(tmp, f'/live{os.getpid()}_{attempt}', protocol_paths['II'])
        run['stalled'] = bool(stall_watcher.stalls(started_s, time.monotonic()))
        return run

    def judge(run):
        disturbance = _disturbance(run)
        if (disturbance and run['stalled']
                and not offline_force_misses(run, protocol_paths['II'])
                and not fit_misses(run)):
            print(f'\nkept a live run disturbed by a measured stall ({disturbance}): '
                  f'every timing claim holds on it')
            return None
        return disturbance or None

    run = repeat_only_on_external_stall(one_run, judge, stall_watcher, MAX_ATTEMPTS)
    start_fit(run)
    yield run
    if isinstance(run['fit'], tuple):  # the fit test did not run
        run['fit'][0].kill()
        run['fit'][0].communicate()


def test_recorder_stops_cleanly_after_a_live_run(live_run):
    assert live_run['status'] == 0, live_run['log']
    assert bag_of(live_run).complete


def test_sim_time_run_logs_in_sim_time(tmp_path):
    """With the simulator as the clock, the recorder's log_time is sim time too."""
    ns = f'/simtime{os.getpid()}'
    bag = tmp_path / 'bag'
    with ProcessGroup(tmp_path) as procs, Probe('simtime_probe') as probe:
        seen = probe.record(f'{ns}/force', Float64)
        sim = procs.start('simulator', node_command('simulator', ns=ns,
                                                    params={'publish_clock': True}))
        rec = procs.start('recorder', node_command(
            'recorder', ns=ns, params={'output': str(bag), 'use_sim_time': True}))
        wait_until_recording(probe, ns, [sim, rec])
        probe.wait_for_messages(seen, SIM_TIME_RECORDED_MSGS, mark=seen.mark(),
                                procs=[sim, rec], timeout_s=60)
        rec.popen.send_signal(signal.SIGINT)
        assert rec.wait() == 0, rec.output()
    data = read_bag(bag)
    clock = data.topic('/clock').values()
    force = data.topic(f'{ns}/force')
    assert len(clock) > 100 and force.count > 100
    # Sim time starts at 0 with the simulator; the wall clock is ~1.7e9 s.
    log_s = force.log_time_ns / NS_PER_S
    assert 0.0 <= log_s.min() and log_s.max() <= clock.max() + 1.0
    wrench = data.topic(f'{ns}/wrench')
    assert wrench.stamps_ns().max() / NS_PER_S <= clock.max() + 1e-9


def test_live_bag_has_every_topic_of_both_nodes(live_run):
    ns = live_run['ns']
    with Reader(live_run['bag']) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
    # Every node also reports on /diagnostics, which the recorder records by default.
    assert types == {**{f'{ns}/{t}': MESSAGE_TYPES.get(t, 'std_msgs/msg/Float64')
                        for t in TOPICS},
                     '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray'}


def test_every_gap_in_sequence_numbers_is_reported(live_run):
    """The bag stores each publisher's sequence numbers; a gap there is a message
    DDS never delivered, and the recorder's report counts exactly those."""
    bag = bag_of(live_run)
    for topic in TOPICS:
        name = f'{live_run["ns"]}/{topic}'
        seq = bag.topic(name).sequence
        assert len(seq) > 1000, topic
        assert np.all(np.diff(seq) >= 1), topic
        gaps = int(np.sum(np.diff(seq) - 1))
        sent = int(seq[-1] - seq[0] + 1)
        summary = [line for line in live_run['log'].splitlines()
                   if line.startswith(f'{name}: ') and ' recorded' in line]
        assert len(summary) == 1, live_run['log']
        assert summary[0].startswith(f'{name}: {len(seq)} recorded, publisher sent {sent}')
        assert summary[0].endswith(f', {gaps} lost')


def test_recorded_wrenches_are_those_another_subscriber_received(live_run):
    bag = bag_of(live_run)
    wrench = bag.topic(f'{live_run["ns"]}/wrench')
    recorded = {int(s): f for s, f in zip(wrench.stamps_ns(), wrench.values())}
    probe = [(m.header.stamp.sec * NS_PER_S + m.header.stamp.nanosec, m.wrench.force.x)
             for m in live_run['probe_wrenches']]
    first, last = min(recorded), max(recorded)
    window = [(s, f) for s, f in probe if first <= s <= last]
    assert len(window) > 1000
    # Same stamp, same force; a message only the probe got was one DDS never
    # delivered to the recorder, and is among those the recorder reports lost.
    assert all(f == recorded[s] for s, f in window if s in recorded)
    missing = sum(1 for s, _ in window if s not in recorded)
    reported = int(np.sum(np.diff(wrench.sequence) - 1))
    assert missing <= reported


def test_player_inputs_come_back_exactly(live_run):
    bag = bag_of(live_run)
    pw_max = MuscleParams().pw_max_s
    pulse = bag.topic(f'{live_run["ns"]}/pulse_width').values()
    # The rest state (zero), then the protocol's R = 0.5, then 1.0, and zero stimulation at the end.
    assert set(np.unique(pulse)) == {0.0, 0.5 * pw_max, pw_max}
    assert pulse[0] == 0.0 and pulse[1] == 0.5 * pw_max and pulse[-1] == 0.0
    length = bag.topic(f'{live_run["ns"]}/length_command_stamped').values()
    assert length.min() == 0.0 and length.max() == 0.010


def test_readers_agree_on_the_live_bag(live_run):
    bag_dir, ns = live_run['bag'], live_run['ns']
    ours = bag_of(live_run).topic(f'{ns}/force').values()
    with Reader(bag_dir) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts == bag_of(live_run).counts()
    with AnyReader([bag_dir]) as reader:
        conns = [c for c in reader.connections if c.topic == f'{ns}/force']
        any_values = [reader.deserialize(raw, c.msgtype).data
                      for c, _, raw in reader.messages(connections=conns)]
    with open(bag_dir / 'bag_0.mcap', 'rb') as f:
        mcap_values = [d.data for *_, d in make_reader(
            f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=[f'{ns}/force'], log_time_order=False)]
    assert list(ours) == any_values == mcap_values


@pytest.mark.realtime
def test_recorded_force_matches_offline_at_the_end_of_each_second(timed_live_run,
                                                                   protocol_paths,
                                                                   realtime_claim):
    misses = offline_force_misses(timed_live_run, protocol_paths['II'])
    realtime_claim('live run, recorded: force vs offline at the end of each second',
                   f'{len(misses)} of 6 off', f'< {FORCE_TOLERANCE_N:g} N each')
    assert not misses, misses


@pytest.mark.realtime
def test_fit_recovers_the_simulator_parameters_from_a_live_bag(timed_live_run,
                                                               realtime_claim):
    assert timed_live_run['status'] == 0, timed_live_run['log']
    fit = fit_of(timed_live_run)
    assert fit['status'] == 0, fit['err']
    moves = next(line for line in fit['out'].splitlines()
                 if 'stimulation changes moved by' in line)
    statistics = simulator_statistics(timed_live_run['sim_log'])
    worst = max(abs(getattr(fit['fitted'], name) / truth - 1.0) / FIT_TOLERANCE[name]
                for name, truth in TRUTH.items())
    realtime_claim('live run, recorded: fit of f_iso, k_se, fv_a',
                   f'{worst:.2f} of each tolerance', '<= 1')
    for name, truth in TRUTH.items():
        assert getattr(fit['fitted'], name) == pytest.approx(truth, rel=FIT_TOLERANCE[name]), (
            name, moves, statistics, fit['out'])
