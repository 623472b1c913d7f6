"""/diagnostics of the package's nodes, over real DDS (and the report logic in-process).

Every node publishes one DiagnosticStatus a second on the absolute topic
``/diagnostics``, named ``<fully qualified node name>: <function>``. These
tests start each node in its own namespace, read its status from a probe,
and check the level, the message and the values against what the test made
happen: no input, a tripped watchdog, rejected messages, a stall (SIGSTOP),
a missing target or feedback, messages recorded, protocol progress.

Every node of the DDS tests starts at once, when the module's first such
test asks (:func:`nodes`), each set in a namespace of its own, and one probe
records every status from then on: the start-ups and the first report
periods pass together, and each test then takes its own nodes through its
scenario.
"""
from __future__ import annotations

import itertools
import os
import signal
import time

import pytest
import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.qos import QoSProfile
from std_msgs.msg import Float64

from hill_muscle_ros.model import Protocol
from hill_muscle_ros.nodes import recorder as recorder_mod
from hill_muscle_ros.nodes._diagnostics import (DIAGNOSTICS_PERIOD_PARAMETER, DIAGNOSTICS_PERIOD_S,
                                                DiagnosticReport)
from hill_muscle_ros.qos import QUEUE_DEPTH
from hill_muscle_ros.recording.reader import read_bag
from ros_helpers import Probe, ProcessGroup, node_command

pytestmark = pytest.mark.ros

_RUNS = itertools.count()
OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR
#: Levels in order, to compare them (the message field is a byte).
RANK = {OK: 0, WARN: 1, ERROR: 2}
#: [Hz] a step rate whose 5 ms ticks a loaded 2-core machine rarely delays
#: past the next one, so that an OK report (no catch-up) comes within the deadline.
QUIET_RATE_HZ = 200.0
#: [-] the achieved rate over a report period is the configured one to this
#: fraction: the count may lag by one tick at either end of a ~1 s period.
RATE_TOLERANCE = 0.02
#: [s] how long the simulator is stopped (SIGSTOP) to make it fall behind:
#: ten times the 0.1 s it may catch up in one tick.
STALL_S = 1.0
#: [Hz] the simulator's default step rate, which the stall test runs at.
SIM_RATE_HZ = 1000.0
#: [-] a period that caught up the stall holds at least this fraction of the
#: steps the stall missed (all of them in about ten ticks, 10-20 ms; split
#: across two periods at worst, one holds half). A late tick of normal load
#: catches up a step or two: the first status after the stop can be sent
#: before the first tick, with the catch-up of the ticks before the stop
#: (a run alone saw such a status, its longest gap 8.7 ms, in 2 of 7).
STALL_CATCH_UP_FRACTION = 0.4
#: [s] the report period of the tests whose statuses do not measure a period
#: (states, counts): five reports a second instead of one.
FAST_PERIOD_S = 0.2
FAST = {DIAGNOSTICS_PERIOD_PARAMETER: FAST_PERIOD_S}
#: The probe's reader of /diagnostics: reliable, deep enough for every
#: status of every node of the module while a test does not spin (a stall
#: test sleeps 1 s), so that none is lost (a test sums per-period counts).
DIAGNOSTICS_QOS = QoSProfile(depth=10_000)


def unique_namespace() -> str:
    """Unique even if another test run drew the same ROS_DOMAIN_ID."""
    return f'/diag_{os.getpid()}_{next(_RUNS)}'


def values(status: DiagnosticStatus) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


class Statuses:
    """The statuses of one named status on /diagnostics, as they arrive."""

    def __init__(self, probe: Probe, name: str) -> None:
        self.name = name
        self.list: list[DiagnosticStatus] = []
        #: [s] header stamps of the arrays that carried them
        self.stamps: list[float] = []
        rec = probe.record('/diagnostics', DiagnosticArray, qos=DIAGNOSTICS_QOS)
        for msg in rec.messages:
            self._on_array(msg)
        rec.add_listener(self._on_array)

    def _on_array(self, msg: DiagnosticArray) -> None:
        mine = [s for s in msg.status if s.name == self.name]
        self.list.extend(mine)
        self.stamps.extend([msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec] * len(mine))

    def first(self, predicate, start: int = 0, stamped_after_s: float | None = None):
        """The first status from index ``start`` with ``predicate(status)``, or
        None; with ``stamped_after_s`` [s] (the node's clock), only one sent after it."""
        return next((s for s, t in zip(self.list[start:], self.stamps[start:])
                     if (stamped_after_s is None or t > stamped_after_s) and predicate(s)),
                    None)


def wait_status(probe, statuses, predicate, what, procs, start=0, timeout_s=30.0,
                stamped_after_s=None):
    return probe.spin_until(lambda: statuses.first(predicate, start, stamped_after_s),
                            f'{statuses.name}: {what}', timeout_s=timeout_s, procs=procs)


# -- the nodes ---------------------------------------------------------------------

#: A protocol of 1.5 s: long enough for a report while playing.
SHORT = {'name': 'short', 'duration_s': 1.5,
         'recruitment': [[0.0, 0.3], [1.5, 0.3]], 'dl_mt_m': [[0.0, 0.0], [1.5, 0.0]]}
#: Out-of-range report periods: a controller started with each must exit.
BAD_PERIODS = (0.0, 1e5)
#: The recorders of the best-effort force: without and with the subscription's override.
RECORDER_OVERRIDES = {'reliable-recorder': False, 'best-effort-recorder': True}


@pytest.fixture(scope='module')
def nodes(tmp_path_factory):
    """Every node process of the DDS tests below, started at once, each set in
    a namespace of its own, and the probe that records /diagnostics from the
    start. The player's first status is awaited here, and only then are its
    outputs subscribed, so that it reports waiting for subscribers first; it
    plays while the other tests run.

    :return: dict of ``procs``, ``probe``, ``tmp`` and, per scenario, its
        ``ns`` and processes
    """
    tmp = tmp_path_factory.mktemp('diagnostics')
    with ProcessGroup(tmp) as procs, Probe('diag_probe') as probe:
        probe.record('/diagnostics', DiagnosticArray, qos=DIAGNOSTICS_QOS)
        w = {'procs': procs, 'probe': probe, 'tmp': tmp}

        def start(key, node, name, params=None, **kwargs):
            ns = w.setdefault(key, {}).setdefault('ns', unique_namespace())
            w[key][name] = procs.start(f'{key}_{name}', node_command(
                node, ns=ns, params=params, **kwargs))

        start('quiet', 'simulator', 'sim', {'rate_hz': QUIET_RATE_HZ})
        start('watchdog', 'simulator', 'sim', {
            'rate_hz': QUIET_RATE_HZ, 'input_timeout_s': 0.2, **FAST})
        start('stall', 'simulator', 'sim', {'rate_hz': SIM_RATE_HZ})
        start('lone', 'force_controller', 'ctrl', {
            'feedback_timeout_s': STALE_TIMEOUT_S, **FAST})
        start('loop', 'simulator', 'sim', {'rate_hz': QUIET_RATE_HZ})
        start('loop', 'force_controller', 'ctrl', FAST)
        w['recorder'] = {'bag': tmp / 'recorder_bag'}
        start('recorder', 'recorder', 'rec', {'output': str(w['recorder']['bag'])})
        path = tmp / 'short.yaml'
        path.write_text(yaml.safe_dump(SHORT))
        w['player'] = {'protocol': path}
        start('player', 'protocol_player', 'player', {
            'protocol': str(path), 'rate_hz': 100.0, 'wait_for_subscribers_s': 60.0, **FAST})
        for i, period in enumerate(BAD_PERIODS):
            start(f'bad_period_{i}', 'force_controller', 'ctrl',
                  {DIAGNOSTICS_PERIOD_PARAMETER: period})
        for name, recorder_override in RECORDER_OVERRIDES.items():
            ns = w.setdefault(name, {}).setdefault('ns', unique_namespace())
            force = f'{ns}/force'
            overrides = {f'qos_overrides.{force}.publisher.reliability': 'best_effort'}
            if recorder_override:
                overrides[f'qos_overrides.{force}.subscription.reliability'] = 'best_effort'
            params = tmp / f'{name}.yaml'
            params.write_text(yaml.safe_dump({'/**': {'ros__parameters': overrides}}))
            w[name].update(force=force, params=params)
            start(name, 'recorder', 'rec', {'output': str(tmp / f'{name}_bag')},
                  params_files=[params])
        ns, player = w['player']['ns'], w['player']['player']
        st = w['player']['statuses'] = Statuses(probe, f'{ns}/protocol_player: protocol playback')
        w['player']['waiting'] = wait_status(probe, st, lambda s: True, 'a status', [player])
        probe.record(f'{ns}/pulse_width', Float64)
        probe.record(f'{ns}/length_command', Float64)
        yield w


def done_with(*procs):
    """Stop the node processes a scenario is done with (SIGINT; the group
    reaps them), so that they load the machine no longer."""
    for proc in procs:
        if proc.returncode is None:
            proc.send_signal(signal.SIGINT)


# -- simulator -------------------------------------------------------------------


def test_simulator_watchdog_trip_is_a_warning(nodes):
    probe, ns, sim = nodes['probe'], nodes['watchdog']['ns'], nodes['watchdog']['sim']
    st = Statuses(probe, f'{ns}/simulator: muscle simulation')
    probe.publish_when_matched(f'{ns}/recruitment', Float64(data=0.5), procs=[sim])
    status = wait_status(probe, st, lambda s: values(s)['watchdog_tripped'] == 'true',
                         'the watchdog tripped', [sim])
    done_with(sim)
    assert status.level in (WARN, ERROR)
    assert 'watchdog tripped' in status.message
    v = values(status)
    assert v['stimulation_received'] == 'true' and v['recruitment'] == '0'
    assert float(v['stimulation_age_s']) > 0.2


# -- recorders of a best-effort force (early: their four nodes then stop) -----------


@pytest.fixture(scope='module')
def best_effort_force_runs(nodes):
    """A simulator whose force is best effort (a publisher QoS override), recorded
    by a recorder without and by one with the matching subscription override
    (started with :func:`nodes`): both pairs at once, each in a namespace of its
    own. Each recorder's status once the simulator's wrench is recorded and
    either the force too or an error: name -> (force topic, status)."""
    probe, procs = nodes['probe'], nodes['procs']
    runs = {}
    for name in RECORDER_OVERRIDES:
        ns, rec = nodes[name]['ns'], nodes[name]['rec']
        runs[name] = (ns, nodes[name]['force'], nodes[name]['params'], rec,
                      Statuses(probe, f'{ns}/recorder: recording'))
    sims = {}
    for name, (ns, _, params, rec, st) in runs.items():
        wait_status(probe, st, lambda s: True, 'a status', [rec])
        sims[name] = procs.start(f'sim_{name}', node_command(
            'simulator', ns=ns, params_files=[params], params={'rate_hz': QUIET_RATE_HZ}))
    statuses = {}
    for name, (ns, force, _, rec, st) in runs.items():
        # The simulator's wrench is reliable either way: once it is recorded,
        # so is a matched force.
        statuses[name] = (force, wait_status(
            probe, st, lambda s: int(values(s)[f'received[{ns}/wrench]']) > 0
            and (s.level == ERROR or int(values(s)[f'received[{force}]']) > 0),
            'wrench and force recorded, or an error', [rec, sims[name]]))
    done_with(*sims.values(), *(nodes[name]['rec'] for name in RECORDER_OVERRIDES))
    return statuses


@pytest.mark.parametrize('recorder', list(RECORDER_OVERRIDES))
def test_recorder_of_a_best_effort_force_needs_the_matching_override(best_effort_force_runs,
                                                                     recorder):
    """A best-effort /force never matches the recorder's reliable start-up
    subscription (an ERROR naming it); the subscription override makes it record."""
    force, status = best_effort_force_runs[recorder]
    if RECORDER_OVERRIDES[recorder]:
        # Recorded; best effort may lose some (then a WARN), never an ERROR.
        assert status.level != ERROR, status.message
        assert int(values(status)[f'received[{force}]']) > 0
    else:
        assert status.level == ERROR
        assert f'not recording (all or some publishers of) {force}' in status.message
        assert values(status)[f'received[{force}]'] == '0'


def test_simulator_stall_is_an_error_then_a_catch_up_warning(nodes):
    probe, ns, sim = nodes['probe'], nodes['stall']['ns'], nodes['stall']['sim']
    st = Statuses(probe, f'{ns}/simulator: muscle simulation')
    wait_status(probe, st, lambda s: True, 'a first status', [sim])
    # Statuses sent before the stop can still be queued unread (a load stall
    # before it once gave one a 0.46 s catch-up): only the ones stamped after
    # the stop (the node's clock is the system clock) are the stall's.
    stopped_wall_s = time.time()
    stopped_at = time.monotonic()
    os.kill(sim.popen.pid, signal.SIGSTOP)
    try:
        time.sleep(STALL_S)   # the fault: the process gets no CPU this long
    finally:
        os.kill(sim.popen.pid, signal.SIGCONT)
    stalled_s = time.monotonic() - stopped_at
    error = wait_status(probe, st, lambda s: s.level == ERROR, 'an ERROR', [sim],
                        stamped_after_s=stopped_wall_s)
    stall_steps = STALL_CATCH_UP_FRACTION * stalled_s * SIM_RATE_HZ
    caught_up = wait_status(
        probe, st, lambda s: int(values(s)['catch_up_steps_last_period']) >= stall_steps,
        f'the stall caught up (at least {stall_steps:.0f} steps in a period)', [sim],
        stamped_after_s=stopped_wall_s)
    done_with(sim)
    v = values(error)
    assert int(v['steps_behind']) > int(v['steps_behind_error_above']) == 100
    assert 'steps behind the clock' in error.message
    assert RANK[caught_up.level] >= RANK[WARN]
    assert 'caught up' in caught_up.message
    # The tick could not run while the process was stopped (SIGSTOP lands at
    # once; the slack is for the signal delivery against the test's clock).
    assert float(values(caught_up)['max_tick_gap_s']) >= 0.9 * stalled_s


# -- force controller -------------------------------------------------------------


#: [s] the lone controller's ``feedback_timeout_s``: its one force message goes
#: stale after this long.
STALE_TIMEOUT_S = 0.2


@pytest.fixture(scope='module')
def lone_controller(nodes):
    """One force controller without a simulator (report period
    :data:`FAST_PERIOD_S`, ``feedback_timeout_s`` :data:`STALE_TIMEOUT_S`),
    taken through its states by the probe, each state's test judging its
    status: its first status (no target yet); six statuses, with no input (the
    report period); then a force_target (no feedback yet); then one force
    message, which goes stale.

    :return: ``ns``, ``first``, ``stamps`` (of the statuses before any input),
        ``no_feedback`` and ``stale`` (statuses)
    """
    probe, ns, ctrl = nodes['probe'], nodes['lone']['ns'], nodes['lone']['ctrl']
    st = Statuses(probe, f'{ns}/force_controller: force control')
    first = wait_status(probe, st, lambda s: True, 'a status', [ctrl])
    probe.spin_until(lambda: len(st.list) >= 6, '6 statuses', procs=[ctrl])
    stamps = list(st.stamps)
    probe.publish_when_matched(f'{ns}/force_target', Float64(data=10.0), procs=[ctrl])
    no_feedback = wait_status(probe, st, lambda s: values(s)['target_received'] == 'true',
                              'the target received', [ctrl])
    probe.publish_when_matched(f'{ns}/force', Float64(data=1.0), procs=[ctrl])
    stale = wait_status(probe, st, lambda s: values(s)['state'] == 'force feedback stale',
                        'stale feedback', [ctrl])
    done_with(ctrl)
    return {'ns': ns, 'first': first, 'stamps': stamps, 'no_feedback': no_feedback,
            'stale': stale}


def test_controller_without_target_reports_idle_ok(lone_controller):
    ns, status = lone_controller['ns'], lone_controller['first']
    v = values(status)
    assert status.level == OK and status.hardware_id == f'{ns}/force_controller'
    assert v['state'] == 'no force_target received yet'
    assert v['target_received'] == 'false' and v['target_n'] == ''
    assert v['stimulating'] == 'false' and v['pulse_width_s'] == '0'
    assert 'idle' in status.message


def test_controller_with_a_target_but_no_feedback_warns(lone_controller):
    status = lone_controller['no_feedback']
    v = values(status)
    assert status.level == WARN
    assert v['state'] == 'no force feedback received yet' and v['target_n'] == '10'
    assert v['feedback_received'] == 'false' and v['stimulating'] == 'false'


def test_controller_stale_feedback_warns_with_its_age(lone_controller):
    status = lone_controller['stale']
    v = values(status)
    assert status.level == WARN
    assert float(v['feedback_age_s']) > STALE_TIMEOUT_S == float(v['feedback_timeout_s'])
    assert v['force_n'] == '1' and v['stimulating'] == 'false'
    assert 'feedback_timeout_s' in status.message


def test_controller_in_the_loop_reports_ok_and_stimulating(nodes):
    probe, ns = nodes['probe'], nodes['loop']['ns']
    sim, ctrl = nodes['loop']['sim'], nodes['loop']['ctrl']
    st = Statuses(probe, f'{ns}/force_controller: force control')
    probe.publish_when_matched(f'{ns}/force_target', Float64(data=10.0),
                               procs=[sim, ctrl])
    # Ready (target and feedback both received) comes a control tick before
    # the first pulse width: the force sample that arrived before the target
    # is not used again, so a status made in between is ready and not yet
    # stimulating (a plain user's make test saw one).
    status = wait_status(probe, st, lambda s: values(s)['state'] == 'ready'
                         and values(s)['stimulating'] == 'true', 'the loop closed',
                         [sim, ctrl])
    done_with(sim, ctrl)
    v = values(status)
    assert status.level == OK
    assert 0.0 < float(v['pulse_width_s']) and 'controlling' in status.message


# -- recorder -----------------------------------------------------------------------


def test_recorder_reports_counts_per_topic_and_records_diagnostics(nodes):
    probe, ns = nodes['probe'], nodes['recorder']['ns']
    bag, rec = nodes['recorder']['bag'], nodes['recorder']['rec']
    n = QUEUE_DEPTH   # the probe's keep-last queue: none is dropped before it is acknowledged
    st = Statuses(probe, f'{ns}/recorder: recording')
    for k in range(n):
        probe.publish_when_matched(f'{ns}/force', Float64(data=float(k)), procs=[rec])
    status = wait_status(probe, st, lambda s: values(s)[f'written[{ns}/force]'] == str(n),
                         f'{n} written', [rec])
    # The recorder records every node's /diagnostics by default, its own too.
    wait_status(probe, st, lambda s: int(values(s)['received[/diagnostics]']) > 0,
                '/diagnostics recorded', [rec])
    probe.retire(f'{ns}/force')   # else the recorder waits for more of it
    assert rec.stop() == 0
    v = values(status)
    assert status.level == OK and v['bag'] == str(bag)
    assert v[f'received[{ns}/force]'] == str(n) and v[f'lost[{ns}/force]'] == '0'
    assert v['lost_total'] == '0'
    assert read_bag(bag).counts()['/diagnostics'] >= 1


@pytest.fixture
def recorder_in_process(tmp_path):
    """A Recorder node in this process, on rclpy's default context (the probes
    have contexts of their own)."""
    rclpy.init(args=['--ros-args', '-p', f'output:={tmp_path / "bag"}',
                     '-r', f'__ns:={unique_namespace()}'])
    node = None
    try:
        node = recorder_mod.Recorder()
        yield node
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()


def test_recorder_loss_is_a_warning_naming_the_topic(recorder_in_process):
    rec = recorder_in_process
    force = rec.resolve_topic_name('force')
    stats = rec._stats[force]
    for seq in (1, 2, 6):            # 3, 4 and 5 never arrived
        stats.add(seq)
    report = rec._diagnostics.report()
    v = values(DiagnosticStatus(values=report.values))
    assert report.level == WARN
    assert report.message.startswith(f'3 message(s) lost: {force} 3')
    assert v[f'lost[{force}]'] == '3' and v['lost_total'] == '3'


# -- protocol player ------------------------------------------------------------------

def test_player_reports_waiting_then_progress_then_done(nodes):
    """The player of :func:`nodes`: its first status (awaited before its outputs
    had subscribers), then its statuses while it plays, recorded meanwhile."""
    probe, ns, player = nodes['probe'], nodes['player']['ns'], nodes['player']['player']
    duration_s = Protocol.from_yaml(nodes['player']['protocol']).duration_s
    st, waiting = nodes['player']['statuses'], nodes['player']['waiting']
    playing = wait_status(probe, st, lambda s: values(s)['state'] == 'playing',
                          'playing', [player])
    done = wait_status(probe, st, lambda s: values(s)['state'] == 'done', 'done', [player])
    assert player.wait() == 0
    assert waiting.level == OK and values(waiting)['state'] == 'waiting for subscribers'
    assert values(waiting)[f'subscribers[{ns}/pulse_width]'] == '0'
    v = values(playing)
    t_s = float(v['protocol_time_s'])
    assert playing.level == OK and 0.0 <= t_s < duration_s
    assert float(v['progress']) == pytest.approx(t_s / duration_s, abs=1e-5)
    assert done.level == OK and values(done)['progress'] == '1'


# -- the quiet simulator (late: its first periods, while every node starts,
# catch up late ticks, and its OK report is the first without) ---------------


#: NaN recruitment messages the quiet simulator is sent.
N_BAD = 3


@pytest.fixture(scope='module')
def quiet_simulator(nodes):
    """One simulator at :data:`QUIET_RATE_HZ` with the default report period:
    its first OK status, with no input yet; then :data:`N_BAD` NaN recruitment
    messages, and every status up to the one that counts them all.

    :return: ``ns``, ``ok`` (status), ``statuses`` (all, in order)
    """
    probe, ns, sim = nodes['probe'], nodes['quiet']['ns'], nodes['quiet']['sim']
    st = Statuses(probe, f'{ns}/simulator: muscle simulation')
    ok = wait_status(probe, st, lambda s: s.level == OK, 'an OK status', [sim])
    for _ in range(N_BAD):
        probe.publish_when_matched(f'{ns}/recruitment', Float64(data=float('nan')),
                                   procs=[sim])
    key = f'bad_inputs[{ns}/recruitment]'
    wait_status(probe, st, lambda s: values(s).get(key) == str(N_BAD),
                f'{N_BAD} rejected', [sim])
    done_with(sim)
    return {'ns': ns, 'ok': ok, 'statuses': list(st.list)}


def test_simulator_without_input_reports_ok_at_its_step_rate(quiet_simulator):
    ns, status = quiet_simulator['ns'], quiet_simulator['ok']
    v = values(status)
    assert status.hardware_id == f'{ns}/simulator'
    assert float(v['achieved_step_rate_hz']) == pytest.approx(QUIET_RATE_HZ,
                                                              rel=RATE_TOLERANCE)
    assert float(v['target_step_rate_hz']) == QUIET_RATE_HZ
    assert v['stimulation_received'] == 'false' and v['stimulation_age_s'] == ''
    assert v['watchdog_tripped'] == 'false' and v['recruitment'] == '0'
    assert v['catch_up_steps_last_period'] == '0' and v['bad_inputs_total'] == '0'
    assert 'no pulse_width or recruitment received yet' in status.message


def test_simulator_counts_rejected_input_per_topic_and_warns_in_that_period(quiet_simulator):
    statuses = quiet_simulator['statuses']
    per_period = [int(values(s)['bad_inputs_last_period']) for s in statuses]
    assert sum(per_period) == N_BAD
    for status, n in zip(statuses, per_period):
        if n:
            assert RANK[status.level] >= RANK[WARN], status
            assert f'{n} input message(s) rejected' in status.message


# -- the period ---------------------------------------------------------------------


def test_diagnostic_updater_period_sets_the_time_between_reports(lone_controller):
    """``diagnostic_updater.period`` (diagnostic_updater's name) 0.2 s: reports come
    about five a second, where the default period gives one."""
    stamps = lone_controller['stamps']
    assert len(stamps) >= 6
    gaps = sorted(b - a for a, b in zip(stamps, stamps[1:]))
    median = gaps[len(gaps) // 2]
    assert 0.5 * FAST_PERIOD_S < median < 0.5 * (FAST_PERIOD_S + DIAGNOSTICS_PERIOD_S), gaps


@pytest.mark.parametrize('period', BAD_PERIODS)
def test_diagnostic_updater_period_out_of_range_stops_start_up_naming_it(nodes, period):
    ctrl = nodes[f'bad_period_{BAD_PERIODS.index(period)}']['ctrl']
    status = ctrl.wait()
    assert status != 0
    assert f'parameter `{DIAGNOSTICS_PERIOD_PARAMETER}` = {period!r} rejected' in ctrl.output()


# -- the report itself ------------------------------------------------------------------


def test_report_message_puts_the_worst_condition_first():
    report = DiagnosticReport(DIAGNOSTICS_PERIOD_S, {})
    report.ok('fine')
    report.warn('degraded')
    report.error('broken')
    assert report.level == ERROR
    assert report.message == 'broken; degraded'


def test_report_delta_is_the_change_since_the_previous_report():
    previous = {}
    assert DiagnosticReport(1.0, previous).delta('n', 5) == 5
    assert DiagnosticReport(1.0, previous).delta('n', 7) == 2
