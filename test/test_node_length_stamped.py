"""The simulator's ``length_command_stamped``: dl_MT knots sent ahead, applied on time.

Every simulator runs at 1 kHz in a namespace of its own, without /clock: the
outputs are stamped with the node clock at start-up plus simulated time, the
clock the knots are stamped in, so a knot for step k is the stamp of a wrench
plus k ms.
"""
import math
import re

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped, WrenchStamped
from rclpy.qos import QoSProfile
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from hill_muscle_ros.model import Muscle, MuscleParams
from ros_helpers import Probe, ProcessGroup, node_command

pytestmark = pytest.mark.ros

RATE_HZ = 1000.0
STEP_NS = 1_000_000
DEFAULTS = MuscleParams()
#: Reliable with room for a whole burst of knots and seconds of 1 kHz wrenches.
DEEP_QOS = QoSProfile(depth=10_000)
#: [-] recruitment held during the exact ramp test: constant, set before the ramp
RECRUITMENT = 0.5
#: [s] of wall time the knots are sent ahead: far more than the DDS latency
LEAD_WALL_S = 0.5
#: Steps of the ramp (10 mm/s, as in the paper's protocols) and of the hold after it.
RAMP_STEPS, HOLD_STEPS = 300, 200
RAMP_M_PER_STEP = 0.010 / RATE_HZ
#: [N] the node and the offline core run the same float operations on the same
#: inputs (each step's dl_MT is a knot exactly: the interpolation at a knot's
#: own time returns its value), so they agree to rounding; 1e-9 N leaves room
#: for nothing but a different input.
EXACT_TOL_N = 1e-9
#: [m] a stretch well inside the FL range, and its force with nothing recruited
STRETCH_M = 0.010
PE_FORCE_N = DEFAULTS.k_pe_n_per_m * STRETCH_M
#: [N] tolerance on a force that should be constant
FORCE_TOL_N = 1e-6
#: [s] of wall time a value that must not change is watched
WATCH_S = 0.5


def _publish_every(rtf: float) -> int:
    """Steps per published wrench: one a millisecond of wall time at either
    real-time factor, which the probe (a Python node) keeps up with. Every step
    at 10x (10 kHz) lost about 1000 wrenches to the simulator's keep-last 1000
    while a compiler ran on the other core; and a history deep enough to keep
    them all (20000) slowed the simulator itself to 4,100 steps/s on a fresh
    clone, as the probe's unacknowledged samples piled up."""
    return max(1, round(rtf))


_STATS_LATE_RE = re.compile(r'(\d+) late length_command_stamped knots')


def _stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _knot(stamp_ns: int, value: float, frame_id: str = '') -> PointStamped:
    msg = PointStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    msg.header.frame_id = frame_id
    msg.point.x = float(value)
    return msg


class _Sim:
    """One simulator in its own namespace, with the probe's recordings."""

    def __init__(self, procs, probe, ns, rtf=1.0):
        self.ns, self.probe = ns, probe
        self.wrench = probe.record(f'{ns}/wrench', WrenchStamped, qos=DEEP_QOS)
        # A wrench every millisecond of wall time (_publish_every): the exact
        # test below finds the step the recruitment acted at between two.
        self.proc = procs.start(ns.strip('/'), node_command('simulator', ns=ns, params={
            'rate_hz': RATE_HZ, 'real_time_factor': rtf, 'input_timeout_s': 0.0,
            'publish_every_n_steps': _publish_every(rtf)}))
        self.knots = probe.node.create_publisher(PointStamped, f'{ns}/length_command_stamped',
                                                 DEEP_QOS)

    def wait_ready(self):
        self.probe.wait_for_messages(self.wrench, procs=[self.proc])
        self.probe.spin_until(lambda: self.knots.get_subscription_count() > 0,
                              'the simulator to subscribe to length_command_stamped',
                              procs=[self.proc])

    def latest_stamp_ns(self) -> int:
        return _stamp_ns(self.wrench.messages[-1].header.stamp)

    def publish(self, topic, value):
        self.probe.publish_when_matched(f'{self.ns}/{topic}', Float64(data=value),
                                        procs=[self.proc])

    def wait_force(self, predicate, what):
        mark = self.wrench.mark()
        return self.probe.spin_until(
            lambda: next((m for m in self.wrench.since(mark) if predicate(m.wrench.force.x)),
                         None), what, procs=[self.proc])

    def wait_stamp(self, stamp_ns):
        self.probe.spin_until(lambda: self.latest_stamp_ns() >= stamp_ns,
                              f'a wrench stamped at or after {stamp_ns} ns', procs=[self.proc])

    def forces_since(self, mark):
        return [m.wrench.force.x for m in self.wrench.since(mark)]


@pytest.mark.parametrize('rtf', [1.0, 10.0])
def test_stamped_ramp_sent_ahead_gives_the_offline_force_exactly(tmp_path, rtf):
    ns = f'/stamped_exact_{int(rtf)}'
    with ProcessGroup(tmp_path) as procs, Probe() as probe:
        sim = _Sim(procs, probe, ns, rtf)
        sim.wait_ready()
        sim.publish('recruitment', RECRUITMENT)
        sim.wait_force(lambda f: f > 0.0, 'force from the recruitment')
        # Knots at every step of a ramp that starts LEAD_WALL_S of wall time
        # ahead of the newest wrench, then one at the end of the hold.
        start_ns = sim.latest_stamp_ns() + round(LEAD_WALL_S * rtf * RATE_HZ) * STEP_NS
        ramp = {start_ns + k * STEP_NS: k * RAMP_M_PER_STEP for k in range(RAMP_STEPS + 1)}
        end_ns = start_ns + (RAMP_STEPS + HOLD_STEPS) * STEP_NS
        ramp[end_ns] = RAMP_STEPS * RAMP_M_PER_STEP
        for stamp_ns, value in ramp.items():
            sim.knots.publish(_knot(stamp_ns, value))
        sim.wait_stamp(end_ns)
        sim.proc.stop()
        assert '0 late length_command_stamped knots' in sim.proc.output(), sim.proc.describe()

    stamps = np.array([_stamp_ns(m.header.stamp) for m in sim.wrench.messages])
    force = np.array([m.wrench.force.x for m in sim.wrench.messages])
    every_ns = _publish_every(rtf) * STEP_NS
    gaps = np.flatnonzero(np.diff(stamps) != every_ns)
    assert not gaps.size, (f'{gaps.size} gaps in the wrench stamps (wrenches lost), the first '
                           f'after stamp index {gaps[:1]}')
    first = int(np.argmax(force > 0.0))
    # The recruitment acted at one of the steps between the last wrench without
    # force and the first with it (published every n-th step): each candidate
    # is the offline core from rest, R from the step after it on, dl_MT the
    # knots (0 before the ramp, held after it) at each step's end time. Only
    # the step it acted at gives every force to rounding.
    knot_ns = np.array(sorted(ramp), dtype=np.int64)
    knot_m = np.array([ramp[s] for s in knot_ns])
    errors = {}
    for rest_ns in range(int(stamps[first - 1]), int(stamps[first]), STEP_NS):
        steps = (stamps[first:] - rest_ns) // STEP_NS
        muscle, offline = Muscle(DEFAULTS), [0.0]
        for k in range(1, int(steps[-1]) + 1):
            dl = float(np.interp(rest_ns + k * STEP_NS, knot_ns, knot_m, left=0.0))
            offline.append(muscle.step(RECRUITMENT, dl, 1.0 / RATE_HZ).force_n)
        errors[rest_ns] = np.abs(force[first:] - np.array(offline)[steps]).max()
    on_ramp = (stamps[first:] >= start_ns)
    assert on_ramp.sum() > 10, 'no wrench during or after the ramp'
    best = min(errors, key=errors.get)
    assert errors[best] <= EXACT_TOL_N, (
        f'no onset step reproduces the forces: largest errors {sorted(errors.values())[:3]} N')


@pytest.fixture(scope='module')
def shared(tmp_path_factory):
    """Two simulators at real time for the tests below, started together; the
    tests take them in turn, each reset before its test. A node warns of bad
    input once a second per topic: a test whose warning finds the other
    simulator's second unused need not wait for it."""
    with ProcessGroup(tmp_path_factory.mktemp('stamped')) as procs, Probe() as probe:
        sims = [_Sim(procs, probe, '/stamped'), _Sim(procs, probe, '/stamped_b')]
        for sim in sims:
            sim.wait_ready()
        yield {'sims': sims, 'taken': 0}


@pytest.fixture
def sim(shared):
    """The next of the shared simulators in turn, at rest."""
    sim = shared['sims'][shared['taken'] % len(shared['sims'])]
    shared['taken'] += 1
    response = sim.probe.call(Trigger, f'{sim.ns}/reset', Trigger.Request(),
                              procs=[sim.proc])
    assert response.success
    sim.wait_force(lambda f: f == 0.0, 'zero force at rest')
    return sim


def test_late_knot_is_applied_at_the_next_step_and_reported(tmp_path):
    with ProcessGroup(tmp_path) as procs, Probe() as probe:
        sim = _Sim(procs, probe, '/stamped_late')
        sim.wait_ready()
        late_ns = sim.latest_stamp_ns() - 200 * STEP_NS
        sim.knots.publish(_knot(late_ns, STRETCH_M))
        sim.wait_force(lambda f: abs(f - PE_FORCE_N) < FORCE_TOL_N, 'the late knot\'s PE force')
        probe.spin_until(lambda: 'late (simulated time' in sim.proc.output(),
                         'the late-knot warning', procs=[sim.proc])
        sim.proc.stop()
        log = sim.proc.output()
    warning = next(line for line in log.splitlines() if 'late (simulated time' in line)
    assert '/stamped_late/length_command_stamped' in warning
    assert f'stamped {late_ns // 10**9}.{late_ns % 10**9:09d} s' in warning
    assert 'lookahead_s' in warning
    late_ms = float(re.search(r'arrived ([\d.]+) ms', warning).group(1))
    assert late_ms >= 200.0
    assert [int(n) for n in _STATS_LATE_RE.findall(log)] == [1]


def test_plain_length_command_drops_the_knots_sent_ahead(sim):
    sim.knots.publish(_knot(sim.latest_stamp_ns() + 1000 * STEP_NS, STRETCH_M))
    sim.wait_force(lambda f: f > 0.1 * PE_FORCE_N, 'the ramp towards the knot')
    held_m = 0.2 * STRETCH_M
    sim.publish('length_command', held_m)
    held_n = DEFAULTS.k_pe_n_per_m * held_m
    sim.wait_force(lambda f: abs(f - held_n) < FORCE_TOL_N, 'the plain command\'s force')
    mark = sim.wrench.mark()
    sim.wait_stamp(sim.latest_stamp_ns() + 1000 * STEP_NS)   # past the knot's time
    forces = sim.forces_since(mark)
    assert forces and max(abs(f - held_n) for f in forces) < FORCE_TOL_N


def test_reset_drops_the_knots_sent_ahead(sim):
    sim.knots.publish(_knot(sim.latest_stamp_ns() + 1000 * STEP_NS, STRETCH_M))
    sim.wait_force(lambda f: f > 0.1 * PE_FORCE_N, 'the ramp towards the knot')
    assert sim.probe.call(Trigger, f'{sim.ns}/reset', Trigger.Request(),
                          procs=[sim.proc]).success
    sim.wait_force(lambda f: f == 0.0, 'zero force after the reset')
    mark = sim.wrench.mark()
    sim.wait_stamp(sim.latest_stamp_ns() + 1000 * STEP_NS)
    assert set(sim.forces_since(mark)) == {0.0}


@pytest.mark.parametrize('make_bad, needle', [
    (lambda now: _knot(now, math.nan), '= nan stamped'),
    (lambda now: _knot(now, math.inf), '= inf stamped'),
    (lambda now: _knot(now, -1.5), '/length_command_stamped` must be finite and within'),
    (lambda now: _knot(0, 0.0), '`header.stamp` is 0 (unset)'),
    (lambda now: _knot(now + 7200 * 10**9, 0.0), 'more than 3600 s'),
    (lambda now: _knot(now, 0.0, frame_id='world'), "`header.frame_id` must be empty or"),
], ids=['nan', 'inf', 'beyond_1_m', 'zero_stamp', 'far_future', 'other_frame'])
def test_bad_stamped_knot_is_rejected_and_the_state_kept(sim, make_bad, needle):
    sim.publish('length_command', STRETCH_M)
    sim.wait_force(lambda f: abs(f - PE_FORCE_N) < FORCE_TOL_N, 'the PE force')
    log_start = len(sim.proc.output())
    mark = sim.wrench.mark()

    def rejected():
        # Warnings are throttled per topic (1 s): the previous case may have
        # used this second's, so the bad knot is sent until one names it.
        if needle in sim.proc.output()[log_start:]:
            return True
        sim.knots.publish(make_bad(sim.latest_stamp_ns() + 100 * STEP_NS))
        return False

    sim.probe.spin_until(rejected, f'the rejection ({needle})', procs=[sim.proc])
    sim.wait_stamp(sim.latest_stamp_ns() + 200 * STEP_NS)
    forces = sim.forces_since(mark)
    assert forces and max(abs(f - PE_FORCE_N) for f in forces) < FORCE_TOL_N
    assert f'ignoring {sim.ns}/length_command_stamped' in sim.proc.output()[log_start:]
