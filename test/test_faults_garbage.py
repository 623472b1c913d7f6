"""Fault case 3: garbage on every input topic.

What must hold, for the simulator's ``pulse_width``, ``recruitment`` and
``length_command`` and the controller's ``force_target``, ``force`` and
``length_command``, when
they receive NaN, +-inf, huge values, negative values, and bursts that
alternate good and bad values (ending on a bad one):

- every output stays finite (simulator: force, ce_length, wrench;
  controller: pulse width, also within [0, PW_max]);
- bad values are logged, throttled: a warning names the topic and the value,
  at most one per topic per second plus one (the rest are counted);
- the last good value is used: the simulator ends at the steady state the
  offline core reaches with the last good inputs; the controller, fed a
  force equal to its target at a held length, keeps sending exactly the
  feedforward pulse width for that length (any accepted bad value would move
  its output, its length estimate or its integral).
"""
from __future__ import annotations

import itertools
import math
import os
import re
import time

import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped
from std_msgs.msg import Float64

from hill_muscle_ros.control import ControllerParams, ForceController
from hill_muscle_ros.model import Muscle, MuscleParams
from hill_muscle_ros.model.muscle import MuscleOutputs
from ros_helpers import Probe, ProcessGroup, node_command

# Pacing keeps the node's keep-last-10 queue from dropping a bad value only
# while no other test loads the machine (publish_acked): that every bad value
# is warned or counted is a realtime claim, on runs of its own paced
# PACE_S apart; the rest is behaviour, on runs sent as fast as the probe can.
pytestmark = [pytest.mark.faults, pytest.mark.ros]

_RUNS = itertools.count()
RATE_HZ = 1000.0
DT_S = 1.0 / RATE_HZ
PW_MAX_S = MuscleParams().pw_max_s
HUGE = 1e300
STRETCH_M = 0.004
PW_FIRST_S = 2e-4
#: The good value inside the bursts differs from the first, so that "last good
#: value" is told apart from "first value kept".
PW_LAST_S = 3e-4
#: Alternating good/bad messages per burst.
BURST = 200
#: [s] the simulator needs to reach its steady state (many CE time constants):
#: offline, 1.5 s after the step to PW_LAST the force is 2e-8 N from its final
#: value (1e-5 N after 1 s).
SETTLE_S = 1.5
#: [N] agreement with the offline steady state (DDS timing does not matter there).
STEADY_TOL_N = 1e-6
#: The throttle period of the nodes' bad-input warnings (BadInputWarner).
THROTTLE_S = 1.0
#: [s] between two messages to one node, in the runs of the realtime claims;
#: the behaviour's runs send unpaced (a dropped value changes none of them).
PACE_S = 0.005
#: The suffix with which a warning counts those suppressed before it.
MORE = re.compile(r'\((\d+) more since the last warning\)')

BAD = {
    'pulse_width': [math.nan, math.inf, -math.inf, HUGE, -HUGE, -1e-4, 0.5],
    'recruitment': [math.nan, math.inf, -math.inf, HUGE, -HUGE, -0.5, 1.5],
    'length_command': [math.nan, math.inf, -math.inf, HUGE, -HUGE, -5.0, 5.0],
    'force_target': [math.nan, math.inf, -math.inf, HUGE, -HUGE, -10.0],
    'force': [math.nan, math.inf, -math.inf, HUGE, -HUGE],
}


def wait_sim_time(probe, wrench, duration_s: float, proc) -> None:
    """Spin until ``duration_s`` more of simulated time (wrench stamps) has passed."""
    sim_time_after(probe, wrench, duration_s, proc)()


def sim_time_after(probe, wrench, duration_s: float, proc):
    """A wait, for later, until ``duration_s`` of simulated time (wrench stamps)
    has passed from now."""
    def now_s():
        stamp = wrench.messages[-1].header.stamp
        return stamp.sec + stamp.nanosec * 1e-9
    probe.wait_for_messages(wrench, procs=[proc])
    end = now_s() + duration_s
    return lambda: probe.spin_until(lambda: now_s() >= end, f'{duration_s} s of simulated time',
                                    procs=[proc])


def offline_steady_force() -> float:
    """Stretch at R = 0, recruit at PW_FIRST, then raise to PW_LAST, as the test does.

    Each hold is one ``run_array`` of the same kernel the node's ``step`` runs,
    to the same last bit: 6000 ``step`` calls from Python were 0.7 CPU-s."""
    muscle = Muscle(MuscleParams())
    muscle.step(0.0, STRETCH_M, DT_S)
    steps = round(2 * SETTLE_S * RATE_HZ)
    for pw in (PW_FIRST_S, PW_LAST_S):
        muscle.set_pulse_width(pw)
        rows = muscle.run_array(np.full(steps, muscle.recruitment), np.full(steps, STRETCH_M),
                                DT_S)
    return float(rows[-1, MuscleOutputs._fields.index('force_n')])


def publish_acked(probe, pub, value: float, pace_s: float) -> None:
    """Publish, then keep receiving for ``pace_s`` [s].

    Pacing keeps the node's keep-last-10 queue from dropping messages (it
    would take a 10-message stall of the node), so that every bad value sent
    is one the node saw. (``Publisher.wait_for_all_acked`` would be exact,
    but it can block far beyond its timeout in this rclpy.)
    """
    pub.publish(Float64(data=value))
    probe.spin_for(pace_s)


def send_garbage(probe, pub, bad_values, good_value, pace_s: float) -> int:
    """Each bad value, then a burst alternating good and bad, ending bad.

    :return: how many bad values were sent
    """
    sent = 0
    for value in bad_values:
        publish_acked(probe, pub, value, pace_s)
        sent += 1
    for i in range(BURST):
        bad = i % 2 == 1
        publish_acked(probe, pub, bad_values[i // 2 % len(bad_values)] if bad else good_value,
                      pace_s)
        sent += bad
    publish_acked(probe, pub, bad_values[0], pace_s)
    return sent + 1


def warnings_for(log: str, topic: str) -> list[str]:
    return [line for line in log.splitlines()
            if '[WARN]' in line and f'ignoring {topic} = ' in line]


#: A node's warning line: ``[WARN] [seconds.nanoseconds] [name]: ...``.
WARN_TIME = re.compile(r'^\[WARN\] \[(\d+\.\d+)\]')
#: [s] beyond a throttle period after a topic's last warning (system clock, as
#: the log's stamps) before its flush value is sent: the node's own period runs
#: on its monotonic clock, from when it took the value.
FLUSH_MARGIN_S = 0.05


def flush_throttled_counts(probe, proc, pubs, bad) -> dict[str, int]:
    """A throttle period after each topic's last warning, one more bad value on
    it: its warning carries the count of those suppressed since the last one.

    The period is counted from the warning in the node's log, not from the
    last value sent: the node may take a burst's first value a while after
    the probe sent it (unpaced, a few ms to tens of ms), and a flush within
    its period would be counted, not warned.

    :return: the bad values sent here, per topic (1 each)
    """
    for topic, pub in pubs.items():
        lines = probe.spin_until(lambda: warnings_for(proc.output(), pub.topic_name),
                                 f'a first warning on {pub.topic_name}', procs=[proc])
        before = len(lines)
        last_s = float(WARN_TIME.match(lines[-1]).group(1))
        probe.spin_for(last_s + THROTTLE_S + FLUSH_MARGIN_S - time.time())
        publish_acked(probe, pub, bad[topic][0], 0.0)
        probe.spin_until(lambda: len(warnings_for(proc.output(), pub.topic_name)) > before,
                         f'the warning on {pub.topic_name}', procs=[proc])
    return {topic: 1 for topic in pubs}


def accounted(lines: list[str]) -> int:
    """Bad values the log accounts for: one per line plus the "(N more ...)" counts."""
    return len(lines) + sum(int(m) for line in lines for m in MORE.findall(line))


def assert_logged_throttled(log: str, topic: str, bad_values: list[float], sent: int,
                            elapsed_s: float) -> None:
    """A warning names the topic and a bad value sent, at most one a throttle
    period, and no more bad values are counted than were sent.

    Which bad value the first warning names is the first the node took from
    its keep-last queue: on a loaded machine the queue may have overflowed
    before (that every value is warned or counted is a real-time claim,
    :func:`assert_every_bad_value_accounted`)."""
    lines = warnings_for(log, topic)
    assert lines, f'no warning for {topic}'
    named = f'ignoring {topic} = '
    first = lines[0].split(named, 1)[1].split(':', 1)[0]
    assert first in {repr(v) for v in bad_values}, lines[0]
    assert len(lines) <= elapsed_s / THROTTLE_S + 1, lines
    assert accounted(lines) <= sent, lines


def assert_every_bad_value_accounted(run: dict, realtime_claim) -> None:
    """Every bad value sent is in the log, warned or counted: a claim on the
    pacing (:func:`publish_acked`) keeping the node's keep-last queue from
    overflowing, which holds only while the machine gives the node a CPU
    within a few of :data:`PACE_S`."""
    for topic, sent in run['sent'].items():
        seen = accounted(warnings_for(run['log'], f"{run['ns']}/{topic}"))
        realtime_claim(f'{run["node"]}: bad values on {topic} warned or counted, paced '
                       f'{PACE_S * 1e3:g} ms apart', f'{seen} of {sent}', f'{sent} of {sent}')
    for topic, sent in run['sent'].items():
        lines = warnings_for(run['log'], f"{run['ns']}/{topic}")
        assert accounted(lines) == sent, lines


#: [s] the controller's ``feedback_timeout_s`` in its garbage test: the
#: probe's 20 ms force timer runs only while the test process gets a CPU, and a
#: stall past the default 0.5 s would rightly make the controller hold zero.
#: This test is about garbage, not the timeout (test_controller_node has those).
CONTROLLER_FEEDBACK_TIMEOUT_S = 30.0


def garbage_runs(tmp_path_factory, pace_s: float) -> dict:
    """The simulator and the controller, each fed garbage on every input (checked
    as it runs), and their logs: ``{'simulator': ..., 'controller': ...}``.

    :param pace_s: [s] between two messages to one node (0: unpaced)

    Both nodes start together. The controller takes its garbage while the
    simulator settles at its first pulse width (the pacing is per node: one
    node's messages are :data:`PACE_S` apart), then the simulator takes its own.
    """
    tmp_path = tmp_path_factory.mktemp('garbage')
    ns = f'/garbage_{os.getpid()}_{next(_RUNS)}'
    ctrl_ns = f'/garbage_ctrl_{os.getpid()}_{next(_RUNS)}'
    target_n = 10.0
    # The controller's defaults: model feedforward with the default muscle.
    expected_pw = ForceController(ControllerParams(), MuscleParams()).feedforward(
        target_n, target_n, STRETCH_M, 0.0)
    with ProcessGroup(tmp_path) as procs, Probe('garbage_probe') as probe:
        sim = procs.start('simulator', node_command('simulator', ns=ns, params={
            'rate_hz': RATE_HZ, 'input_timeout_s': 0.0}))
        ctrl = procs.start('controller', node_command(
            'force_controller', ns=ctrl_ns,
            params={'feedback_timeout_s': CONTROLLER_FEEDBACK_TIMEOUT_S}))
        force = probe.record(f'{ns}/force', Float64)
        ce_length = probe.record(f'{ns}/ce_length', Float64)
        wrench = probe.record(f'{ns}/wrench', WrenchStamped)
        pubs = {t: probe.publisher(f'{ns}/{t}', Float64)
                for t in ('pulse_width', 'recruitment', 'length_command')}
        pw = probe.record(f'{ctrl_ns}/pulse_width', Float64)
        ctrl_pubs = {t: probe.publisher(f'{ctrl_ns}/{t}', Float64)
                     for t in ('force_target', 'force', 'length_command')}
        probe.spin_until(lambda: all(p.get_subscription_count() for p in pubs.values()),
                         'the simulator to subscribe', procs=[sim, ctrl])
        # Stretch first, at R = 0, so that the units are recruited at a known length.
        pubs['length_command'].publish(Float64(data=STRETCH_M))
        l_stretched = MuscleParams().l_rest_m + STRETCH_M
        probe.wait_for_value(ce_length, lambda v: abs(v - l_stretched) < 1e-12, 'stretch',
                             procs=[sim, ctrl])
        pubs['pulse_width'].publish(Float64(data=PW_FIRST_S))
        probe.wait_for_value(force, lambda v: v > MuscleParams().k_pe_n_per_m * STRETCH_M + 1.0,
                             'stimulation', mark=force.mark(), procs=[sim, ctrl])
        settled = sim_time_after(probe, wrench, 2 * SETTLE_S, sim)  # steady before the garbage

        # The controller's garbage, while the simulator settles.
        probe.spin_until(lambda: all(p.get_subscription_count() for p in ctrl_pubs.values()),
                         'the controller to subscribe', procs=[sim, ctrl])
        # The probe plays a muscle that holds exactly the target: zero error.
        feedback = probe.node.create_timer(0.02, lambda: ctrl_pubs['force'].publish(
            Float64(data=target_n)))
        ctrl_pubs['force_target'].publish(Float64(data=target_n))
        probe.wait_for_value(pw, lambda v: v > 0.0, 'stimulation', procs=[sim, ctrl])
        start = time.monotonic()
        good = {'force_target': target_n, 'force': target_n, 'length_command': STRETCH_M}
        ctrl_sent = {topic: send_garbage(probe, pub, BAD[topic], good[topic], pace_s)
                     for topic, pub in ctrl_pubs.items()}
        for topic, n in flush_throttled_counts(probe, ctrl, ctrl_pubs, BAD).items():
            ctrl_sent[topic] += n
        mark = pw.mark()
        probe.wait_for_messages(pw, 50, mark=mark, procs=[sim, ctrl])
        feedback.cancel()
        ctrl_elapsed = time.monotonic() - start
        ctrl_log = ctrl.output()
        assert ctrl.returncode is None
        stimulating = [v for v in pw.data_since(0) if v > 0.0]
        after = pw.data_since(mark)

        # The simulator's garbage, once it has settled.
        settled()
        start = time.monotonic()
        good = {'pulse_width': PW_LAST_S, 'recruitment': PW_LAST_S / PW_MAX_S,
                'length_command': STRETCH_M}
        sent = {topic: send_garbage(probe, pub, BAD[topic], good[topic], pace_s)
                for topic, pub in pubs.items()}
        for topic, n in flush_throttled_counts(probe, sim, pubs, BAD).items():
            sent[topic] += n
        # The recruitment last changed at the first good PW_LAST, more than the
        # recruitment and length bursts and the flush (over 2 s) ago: SETTLE_S
        # more is plenty (it was 2 SETTLE_S, 1.5 s of wall time more to record).
        wait_sim_time(probe, wrench, SETTLE_S, sim)
        elapsed = time.monotonic() - start
        log = sim.output()
        assert sim.returncode is None
        values = np.array(force.data_since(0) + ce_length.data_since(0))
        final = force.messages[-1].data

    assert np.all(np.isfinite(values))
    expected = offline_steady_force()
    print(f'\nMEASURED garbage (simulator, {elapsed:.1f} s): final force {final:.6f} N, '
          f'offline {expected:.6f} N; '
          + ', '.join(f'{t}: {len(warnings_for(log, f"{ns}/{t}"))} warning line(s) for '
                      f'{sent[t]} bad values' for t in pubs))
    for topic in pubs:
        assert_logged_throttled(log, f'{ns}/{topic}', BAD[topic], sent[topic], elapsed)
    assert all(math.isfinite(v) and 0.0 <= v <= PW_MAX_S for v in pw.data_since(0))
    print(f'\nMEASURED garbage (controller, {ctrl_elapsed:.1f} s): {len(stimulating)} pulse '
          f'widths while stimulating, all {set(stimulating)} s; feedforward {expected_pw} s; '
          + ', '.join(f'{t}: {len(warnings_for(ctrl_log, f"{ctrl_ns}/{t}"))} warning line(s) '
                      f'for {ctrl_sent[t]} bad values' for t in ctrl_pubs))
    for topic in ctrl_pubs:
        assert_logged_throttled(ctrl_log, f'{ctrl_ns}/{topic}', BAD[topic], ctrl_sent[topic],
                                ctrl_elapsed)
    return {'simulator': {'node': 'simulator', 'ns': ns, 'log': log, 'sent': sent,
                          'final': final, 'expected': expected},
            'controller': {'node': 'force controller', 'ns': ctrl_ns, 'log': ctrl_log,
                           'sent': ctrl_sent, 'after': after, 'expected_pw': expected_pw}}


@pytest.fixture(scope='module')
def unpaced_runs(tmp_path_factory) -> dict:
    """:func:`garbage_runs` sent as fast as the probe can: the behaviour."""
    return garbage_runs(tmp_path_factory, 0.0)


@pytest.fixture(scope='module')
def paced_runs(tmp_path_factory) -> dict:
    """:func:`garbage_runs` paced :data:`PACE_S` apart: the realtime claims."""
    return garbage_runs(tmp_path_factory, PACE_S)


@pytest.fixture(scope='module')
def simulator_run(unpaced_runs) -> dict:
    return unpaced_runs['simulator']


@pytest.fixture(scope='module')
def controller_run(unpaced_runs) -> dict:
    return unpaced_runs['controller']


def test_simulator_ignores_garbage_on_every_input_and_keeps_the_last_good_value(simulator_run):
    assert simulator_run['final'] == pytest.approx(simulator_run['expected'], abs=STEADY_TOL_N)


@pytest.mark.realtime
def test_simulator_warns_or_counts_every_paced_bad_value(paced_runs, realtime_claim):
    assert_every_bad_value_accounted(paced_runs['simulator'], realtime_claim)



def test_controller_ignores_garbage_on_every_input_and_keeps_the_last_good_value(
        controller_run):
    assert set(controller_run['after']) == {controller_run['expected_pw']}


@pytest.mark.realtime
def test_controller_warns_or_counts_every_paced_bad_value(paced_runs, realtime_claim):
    assert_every_bad_value_accounted(paced_runs['controller'], realtime_claim)
