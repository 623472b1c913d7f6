"""Limb fault case: the joint controller is killed (SIGKILL) in mid-motion.

The limb node and the joint controller run the knee preset in a closed loop
towards 45 deg. Once the knee is above 35 deg the controller is killed. What
must hold, in simulated time (the stamps of the limb's outputs):

- until the limb's stimulation watchdog trips (``input_timeout_s`` after the
  last pulse width arrived) the held pulse width keeps the knee up, and the
  quadriceps' force is the stimulated one, not the passive one;
- the knee falls only after that, and soon after (the offline fall time);
- once the activation has died away, the quadriceps' force is, at every
  step, the passive force of the model at that step's angle (its parallel
  spring; the unstimulated series element carries nothing else);
- the leg comes to rest where the offline model's passive knee (no
  stimulation, :func:`simulate_limb`) rests.

The moment the last pulse width reached the limb is taken from the probe,
which hears the same pulse widths: the newest joint-state stamp the probe had
seen when it received the controller's last one. The two readers hear it at
nearly the same time; :data:`DDS_SLACK_S` covers the difference. That time,
not the instant of SIGKILL, is what the watchdog counts from (a controller
the machine held up before the kill sent its last pulse width earlier).

The garbage and flood cases of the limb's inputs are in test_node_limb.py
(garbage on every input, an external torque flood).
"""
from __future__ import annotations

import copy
import functools
import itertools
import math
import os
import signal

import numpy as np
import pytest
import yaml
from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from conftest import REPO
from hill_muscle_ros.control.joint import JointController
from hill_muscle_ros.model.equations import parallel_force
from hill_muscle_ros.model.limb import Limb, LimbProtocol, simulate_limb
from hill_muscle_ros.model.stimulus import command_from_pulse_width
from hill_muscle_ros.params_file import load_plant
from hill_muscle_ros.timebase import NS_PER_S
from ros_helpers import Probe, ProcessGroup, node_command
from stall_watch import repeat_only_on_external_stall

pytestmark = [pytest.mark.faults, pytest.mark.ros]

_RUNS = itertools.count()
KNEE_YAML = REPO / 'config' / 'knee.yaml'
PLANT, _ = load_plant(KNEE_YAML)
QUAD = PLANT.muscles[0]
#: [Hz] the limb's step rate: 200 Hz, as test_node_limb, to spare the CPU
#: (the offline references step at the same rate).
RATE_HZ = 200.0
DT_S = 1.0 / RATE_HZ
#: [s] the limb's stimulation watchdog (its default, set explicitly).
INPUT_TIMEOUT_S = 0.5
TARGET_RAD = math.radians(45.0)
#: [rad] the knee must be above this when the controller is killed.
KILL_ABOVE_RAD = math.radians(35.0)
#: [rad] "fallen": below this. Offline, a pulse width held from any moment
#: after the knee passed 35 deg keeps it above 35 deg for the 0.5 s of the
#: watchdog (test_offline_held_pulse_width_keeps_the_knee_up).
FALLEN_RAD = math.radians(30.0)
#: [s] allowance for the DDS hops (pulse width to limb and to probe, joint
#: state to probe) and the probe's processing order.
DDS_SLACK_S = 0.03
#: [s] the knee takes at most this long from the watchdog's trip to below
#: FALLEN_RAD. Offline, killed at any step of the approach to 45 deg (every
#: 10 ms from the first step above 35 deg to the settled loop), it takes 0.13
#: to 0.20 s; the margin FALL_MARGIN_S covers the loop over DDS reaching the
#: kill in another state, and the probe's view of the last pulse width
#: lagging the limb's (which makes the trip look earlier).
FALL_S = 0.3
#: [s] the margin in FALL_S over the offline fall times (checked on a coarser
#: grid of kills by test_offline_held_pulse_width_keeps_the_knee_up_...).
FALL_MARGIN_S = 0.1
#: [s] after the trip, the force is the passive force to PASSIVE_FORCE_TOL_N
#: (the activation has died away): offline within 0.3 s, checked by
#: test_offline_force_is_the_passive_force_once_the_activation_has_died_away,
#: with PASSIVE_MARGIN_S of margin here.
PASSIVE_AFTER_S = 0.4
PASSIVE_MARGIN_S = 0.1
#: [s] offline kills: the first step above 35 deg, then every KILL_EVERY_S
#: until the loop has settled at 45 deg (it settles within 1 s).
KILL_EVERY_S = 0.25
KILL_UNTIL_S = 2.0
#: [s] simulated from each offline kill: the held pulse width, the trip, the
#: fall and PASSIVE_AFTER_S, with the swing that follows.
OFFLINE_RELEASE_S = 1.5
#: [N] until the trip the quadriceps' force exceeds the passive force by
#: more than this (offline, it holds the knee near 45 deg with ~500 N).
ACTIVE_ABOVE_N = 10.0
#: [N] the node and the model step the same equations at the same dt.
PASSIVE_FORCE_TOL_N = 1e-6
#: [rad] "at rest": the knee swings less than this over a window of
#: REST_WINDOW_S. The passive knee is barely damped (damping ratio 0.06), so
#: it rings for seconds: less than 1 deg of swing is ~10 s after the fall.
#: The rest angle lies inside the band of a full swing, so the offline rest
#: must too: a residual quadriceps recruitment of 1 % (0.6 N m, 1.3 deg)
#: would already put it outside.
REST_BAND_RAD = math.radians(1.0)
#: [s] longer than the passive knee's swing period (0.80 s, checked below), so
#: the window holds a whole swing around the rest angle.
REST_WINDOW_S = 1.0
#: [s] deadline for the knee to come to rest after the kill (wall time; the
#: limb runs in real time, and needs ~11 s).
REST_DEADLINE_S = 20.0
#: [s] offline passive run: long past its settling (from hanging, in ~1 s).
OFFLINE_REST_S = 10.0


def stamp_s(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec / NS_PER_S


def step_of(msg) -> int:
    return round(stamp_s(msg) * RATE_HZ)


@functools.lru_cache(maxsize=None)
def passive_rest_rad() -> float:
    """[rad] where the offline passive knee (no stimulation) rests."""
    protocol = LimbProtocol.from_mapping({'name': 'passive', 'duration_s': OFFLINE_REST_S,
                                          'muscles': {QUAD.name: {'recruitment': [[0.0, 0.0]]}}})
    return float(simulate_limb(PLANT, protocol, RATE_HZ)['theta_rad'][-1])


def swing_period_s() -> float:
    """[s] the passive knee's small-swing period about hanging, undamped:
    2 pi sqrt(I / (m g l_c + K)) (the muscles' parallel springs are 1 % of K)."""
    j = PLANT.joint
    return 2 * math.pi * math.sqrt(j.inertia_kg_m2 / (
        j.mass_kg * j.gravity_m_per_s2 * j.com_distance_m + j.stiffness_n_m_per_rad))


def _release(limb: Limb, widths: list[float], duration_s: float) -> dict:
    """Step ``limb`` with ``widths`` held for INPUT_TIMEOUT_S, then none."""
    trip = round(INPUT_TIMEOUT_S * RATE_HZ)
    theta, force, dl = [], [], []
    for k in range(round(duration_s * RATE_HZ)):
        held = widths if k < trip else [0.0] * len(widths)
        out = limb.step([command_from_pulse_width(w, m.params)
                         for w, m in zip(held, PLANT.muscles)], 0.0, DT_S)
        theta.append(out.theta_rad)
        force.append(out.force_n[0])
        dl.append(out.dl_mt_m[0])
    return {'trip': trip, 'theta': np.array(theta), 'force': np.array(force),
            'passive': np.array([parallel_force(QUAD.params.k_pe_n_per_m, d) for d in dl])}


@functools.lru_cache(maxsize=None)
def offline_releases(duration_s: float) -> list[dict]:
    """Offline: the loop of the nodes (as :func:`~hill_muscle_ros.control.joint.simulate_joint_control`), killed
    at the first step above 35 deg and then every KILL_EVERY_S until
    KILL_UNTIL_S; each time the pulse widths are held for INPUT_TIMEOUT_S
    (the watchdog), then none, for ``duration_s``. Steps from each kill."""
    controller = JointController(PLANT)
    limb = Limb(PLANT)
    every = round(RATE_HZ / controller.params.control_rate_hz)
    widths = [0.0] * len(PLANT.muscles)
    runs, first = [], None
    for k in range(round(KILL_UNTIL_S * RATE_HZ)):
        if k % every == 0:
            widths = controller.update(TARGET_RAD, limb.theta_rad, limb.omega_rad_per_s,
                                       every * DT_S)
        if first is None and limb.theta_rad > KILL_ABOVE_RAD:
            first = k
        if first is not None and (k - first) % round(KILL_EVERY_S * RATE_HZ) == 0:
            runs.append(_release(copy.deepcopy(limb), list(widths), duration_s))
        limb.step([command_from_pulse_width(w, m.params)
                   for w, m in zip(widths, PLANT.muscles)], 0.0, DT_S)
    return runs


# -- the offline claims the bounds rest on ----------------------------------------


def test_offline_held_pulse_width_keeps_the_knee_up_and_it_falls_within_fall_s():
    for i, run in enumerate(offline_releases(OFFLINE_RELEASE_S)):
        trip = run['trip']
        assert run['theta'][:trip].min() > KILL_ABOVE_RAD, i
        fallen = trip + int(np.argmax(run['theta'][trip:] < FALLEN_RAD))
        assert run['theta'][fallen] < FALLEN_RAD
        assert (fallen - trip) * DT_S <= FALL_S - FALL_MARGIN_S, i


def test_offline_force_is_the_passive_force_once_the_activation_has_died_away():
    for i, run in enumerate(offline_releases(OFFLINE_RELEASE_S)):
        trip = run['trip']
        after = trip + round((PASSIVE_AFTER_S - PASSIVE_MARGIN_S) * RATE_HZ)
        np.testing.assert_allclose(run['force'][after:], run['passive'][after:], rtol=0.0,
                                   atol=PASSIVE_FORCE_TOL_N, err_msg=str(i))
        assert (run['force'][:trip] - run['passive'][:trip]).min() > ACTIVE_ABOVE_N, i


def test_rest_window_holds_a_whole_swing():
    assert REST_WINDOW_S > swing_period_s()


# -- over DDS -----------------------------------------------------------------------


def one_kill(tmp_path) -> dict:
    """Close the loop, kill the controller above 35 deg, watch the leg come to rest."""
    ns = f'/limb_kill_{os.getpid()}_{next(_RUNS)}'
    overrides = tmp_path / 'limb.yaml'
    overrides.write_text(yaml.safe_dump({'/**': {'ros__parameters': {
        'rate_hz': RATE_HZ, 'input_timeout_s': INPUT_TIMEOUT_S, 'publish_clock': True}}}))
    with ProcessGroup(tmp_path) as procs, Probe('limb_kill_probe') as probe:
        limb = procs.start('limb', node_command('limb_simulator', ns=ns,
                                                params_files=[KNEE_YAML, overrides]))
        ctrl = procs.start('controller', node_command('joint_controller', ns=ns,
                                                      params_files=[KNEE_YAML]))
        joint = probe.record(f'{ns}/joint_states', JointState)
        wrench = probe.record(f'{ns}/{QUAD.name}/wrench', WrenchStamped)
        pw = probe.record(f'{ns}/{QUAD.name}/pulse_width', Float64)
        #: the newest joint-state step the probe had when each pulse width came
        heard_at = []
        pw.add_listener(lambda _msg: heard_at.append(step_of(joint.messages[-1])
                                                     if joint.messages else None))
        # Discovery both ways: the limb hears the controller's pulse widths.
        probe.spin_until(lambda: len(probe.subscribers(f'{ns}/{QUAD.name}/pulse_width')) >= 2,
                         'the limb and the probe subscribed to the pulse width',
                         procs=[limb, ctrl])
        probe.publish_when_matched(f'{ns}/angle_target', Float64(data=TARGET_RAD),
                                   procs=[limb, ctrl])
        probe.spin_until(lambda: joint.messages and joint.messages[-1].position[0]
                         > KILL_ABOVE_RAD, 'the knee above 35 deg', procs=[limb, ctrl])
        kill_step = step_of(joint.messages[-1])
        ctrl.popen.send_signal(signal.SIGKILL)
        mark = joint.mark()
        window = round(REST_WINDOW_S * RATE_HZ)

        def at_rest():
            pos = [m.position[0] for m in joint.messages[-window:]]
            return (len(joint.since(mark)) > window + FALL_S * RATE_HZ
                    and max(pos) - min(pos) < REST_BAND_RAD)
        probe.spin_until(at_rest, 'the knee at rest', timeout_s=REST_DEADLINE_S, procs=[limb])
        assert limb.returncode is None
        last_pw_step = heard_at[-1]
        steps = np.array([step_of(m) for m in joint.messages])
        theta = np.array([m.position[0] for m in joint.messages])
        force = {step_of(m): m.wrench.force.x for m in wrench.messages}
        log = limb.output()

    # Assertions without timing: on the whole record.
    assert np.all(np.isfinite(theta))
    assert f'no {QUAD.name}/pulse_width or recruitment message for 0.5 s' in log
    rest = theta[-window:]
    assert rest.min() <= passive_rest_rad() <= rest.max(), (
        f'offline passive rest {math.degrees(passive_rest_rad()):.3f} deg outside the swing '
        f'[{math.degrees(rest.min()):.3f}, {math.degrees(rest.max()):.3f}] deg')
    trip_step = last_pw_step + round(INPUT_TIMEOUT_S * RATE_HZ)
    fallen = int(np.flatnonzero((steps > kill_step) & (theta < FALLEN_RAD))[0])
    passive_from = trip_step + round((PASSIVE_AFTER_S + DDS_SLACK_S) * RATE_HZ)
    checked = 0
    for k, th in zip(steps, theta):
        if k >= passive_from and k in force:
            expected = parallel_force(QUAD.params.k_pe_n_per_m, QUAD.dl_mt(float(th)))
            assert force[k] == pytest.approx(expected, abs=PASSIVE_FORCE_TOL_N), k
            checked += 1
    assert checked > window   # at least the whole rest window was paired
    before = [force[k] - parallel_force(QUAD.params.k_pe_n_per_m, QUAD.dl_mt(float(th)))
              for k, th in zip(steps, theta)
              if kill_step <= k < trip_step - round(DDS_SLACK_S * RATE_HZ) and k in force]
    print(f'\nMEASURED limb kill: last pulse width at {last_pw_step * DT_S:.3f} s, knee '
          f'{math.degrees(theta[steps == kill_step][0]) if kill_step in steps else math.nan:.1f}'
          f' deg at the kill ({kill_step * DT_S:.3f} s); below 30 deg at '
          f'{steps[fallen] * DT_S:.3f} s ({(steps[fallen] - trip_step) * DT_S:.3f} s after the '
          f'expected trip); rest swing [{math.degrees(rest.min()):.3f}, '
          f'{math.degrees(rest.max()):.3f}] deg, offline {math.degrees(passive_rest_rad()):.3f}')
    return {'kill_step': kill_step, 'trip_step': trip_step, 'fallen_step': int(steps[fallen]),
            'min_before_trip_rad': float(theta[(steps >= kill_step)
                                               & (steps < trip_step - round(DDS_SLACK_S
                                                                            * RATE_HZ))].min()),
            'min_active_n': min(before) if before else None}


def timing_outside_bounds(run: dict) -> str | None:
    """Why the fall came too early or too late, or None."""
    slack = round(DDS_SLACK_S * RATE_HZ)
    if run['min_before_trip_rad'] <= FALLEN_RAD:
        return f'the knee fell below 30 deg before the watchdog could trip: {run}'
    if run['min_active_n'] is None or run['min_active_n'] <= ACTIVE_ABOVE_N:
        return f'the quadriceps force was not above the passive one until the trip: {run}'
    low = run['trip_step'] - slack
    high = run['trip_step'] + 1 + slack + round(FALL_S * RATE_HZ)
    if not low <= run['fallen_step'] <= high:
        return (f'the knee fell below 30 deg at step {run["fallen_step"]}, outside '
                f'[{low}, {high}] (watchdog trip expected at step {run["trip_step"]}): {run}')
    return None


@pytest.mark.realtime
def test_killed_controller_lets_the_knee_fall_after_the_watchdog_to_the_passive_rest(
        tmp_path, stall_watcher, realtime_claim):
    def report(m):
        slack = round(DDS_SLACK_S * RATE_HZ)
        realtime_claim('knee falls after the limb watchdog trips (steps)',
                       f'{m["fallen_step"] - m["trip_step"]:+d} from the trip',
                       f'{-slack:+d}..{1 + slack + round(FALL_S * RATE_HZ):+d}')

    runs = iter(range(10))

    def run() -> dict:
        run_dir = tmp_path / f'run{next(runs)}'
        run_dir.mkdir()
        return one_kill(run_dir)

    repeat_only_on_external_stall(run, timing_outside_bounds, stall_watcher, report=report)
