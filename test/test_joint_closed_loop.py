"""The joint controller closing the loop around the limb over real DDS.

Three processes: the limb node on the knee preset (1 kHz, real time), the
joint controller (100 Hz) and this test, which plays the user on
``angle_target``. The target follows simulated time: for each joint state
received, the target of its stamp (since the first one after the loop was
ready) is sent, every :data:`TARGET_EVERY_N`-th state (100 Hz).

The profile: hanging, then a step to 35 deg held for :data:`STEP_S`, then a
0.2 Hz sine of 15 deg around 30 deg for two periods. Measured on the joint
states' stamps (the limb's own step times):

- the step: settling time into +-2 deg, and the overshoot above 35 deg;
- the sine: the RMS error over its second period (the first carries the
  move from 35 deg onto the sine).

Both the ``initial`` and the ``instantaneous`` length memory are run, on
both muscles; the pulse widths they need are printed (``pytest -s``) and
reported in doc/control.md. A failed run is repeated only if the stall watcher
measured the machine leaving a process of the test unscheduled during it.
"""
from __future__ import annotations

import gc
import itertools
import math
import os

import numpy as np
import pytest
import yaml
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from conftest import REPO
from hill_muscle_ros.timebase import NS_PER_S
from ros_helpers import DEFAULT_TIMEOUT_S, Probe, ProcessGroup, node_command
from stall_watch import repeat_only_on_external_stall

pytestmark = [pytest.mark.ros, pytest.mark.slow, pytest.mark.realtime]

KNEE_YAML = REPO / 'config' / 'knee.yaml'
MUSCLES = ('quadriceps', 'hamstrings')
VARIANTS = ('initial', 'instantaneous')
_RUNS = itertools.count()

STEP_RAD = math.radians(35.0)
#: [s] the step is held this long before the sine starts.
STEP_S = 3.0
SETTLE_BAND_RAD = math.radians(2.0)
MAX_SETTLING_S = 2.0
MAX_OVERSHOOT_RAD = math.radians(6.0)
SINE_MEAN_RAD, SINE_AMPLITUDE_RAD, SINE_HZ = math.radians(30.0), math.radians(15.0), 0.2
SINE_PERIOD_S = 1.0 / SINE_HZ
MAX_SINE_RMS_RAD = math.radians(3.0)
#: A target every this many joint states: 100 Hz at the limb's 1 kHz.
TARGET_EVERY_N = 10
#: [s] the pulse widths of the hold are averaged over its last this long.
PW_AVERAGE_S = 1.0


def target_rad(t_s: float) -> float:
    """[rad] the profile at ``t_s`` since its start."""
    if t_s < STEP_S:
        return STEP_RAD
    return SINE_MEAN_RAD + SINE_AMPLITUDE_RAD * math.sin(2 * math.pi * SINE_HZ * (t_s - STEP_S))


def stamp_s(msg: JointState) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec / NS_PER_S


def run_profile(procs: ProcessGroup, probe: Probe, tmp, length: str) -> dict:
    """One closed-loop run of the profile; its measurements."""
    ns = f'/jcl_{os.getpid()}_{next(_RUNS)}'
    overrides = tmp / f'{length}.yaml'
    overrides.write_text(yaml.safe_dump({'/**': {'ros__parameters': {
        **{f'{m}.length': length for m in MUSCLES}}}}))
    files = [KNEE_YAML, overrides]
    limb = procs.start('limb', node_command('limb_simulator', ns=ns, params_files=files))
    ctrl = procs.start('controller', node_command('joint_controller', ns=ns, params_files=files))
    nodes = [limb, ctrl]
    joint = probe.record(f'{ns}/joint_states', JointState)
    pws = {m: probe.record(f'{ns}/{m}/pulse_width', Float64) for m in MUSCLES}
    target_pub = probe.publisher(f'{ns}/angle_target', Float64)
    # Discovery both ways: the controller hears the limb and us, the limb the controller.
    probe.wait_for_endpoints(f'{ns}/joint_states', publisher=f'{ns}/limb',
                             subscriber=f'{ns}/joint_controller', timeout_s=DEFAULT_TIMEOUT_S,
                             watch=nodes)
    for m in MUSCLES:
        probe.wait_for_endpoints(f'{ns}/{m}/pulse_width', publisher=f'{ns}/joint_controller',
                                 subscriber=f'{ns}/limb', timeout_s=DEFAULT_TIMEOUT_S,
                                 watch=nodes)
        probe.wait_for_messages(pws[m], procs=nodes)
    probe.spin_until(lambda: target_pub.get_subscription_count() > 0,
                     'the controller subscribed to angle_target', procs=nodes)
    probe.wait_for_messages(joint, procs=nodes)

    start = {'t0': None, 'n': 0}

    def user(msg: JointState) -> None:
        t = stamp_s(msg)
        if start['t0'] is None:
            start['t0'] = t
        if start['n'] % TARGET_EVERY_N == 0:
            target_pub.publish(Float64(data=target_rad(t - start['t0'])))
        start['n'] += 1

    mark = joint.mark()
    joint.add_listener(user)
    end_s = STEP_S + 2 * SINE_PERIOD_S
    probe.spin_until(lambda: start['t0'] is not None
                     and stamp_s(joint.messages[-1]) - start['t0'] >= end_s,
                     f'{end_s:g} s of the profile', timeout_s=end_s + DEFAULT_TIMEOUT_S,
                     procs=nodes)
    for proc in nodes:
        proc.stop()
    msgs = joint.since(mark)
    t = np.array([stamp_s(m) for m in msgs]) - start['t0']
    theta = np.array([m.position[0] for m in msgs])
    arrivals = np.array(joint.times_s[mark:])
    goal = np.array([target_rad(x) for x in t])

    step = t < STEP_S
    outside = np.flatnonzero(np.abs(theta[step] - STEP_RAD) > SETTLE_BAND_RAD)
    settling = math.inf if len(outside) and outside[-1] == step.sum() - 1 else (
        float(t[outside[-1] + 1]) if len(outside) else 0.0)
    second = t >= STEP_S + SINE_PERIOD_S

    def mean_pw(m, lo_s, hi_s):
        """[s] mean pulse width received while the limb was in [lo, hi)."""
        sel = (t >= lo_s) & (t < hi_s)
        a_lo, a_hi = arrivals[sel][0], arrivals[sel][-1]
        times = np.array(pws[m].times_s)
        values = np.array([x.data for x in pws[m].messages])
        return float(values[(times >= a_lo) & (times <= a_hi)].mean())

    metrics = {
        'settling_s': settling,
        'overshoot_deg': math.degrees(theta[step].max() - STEP_RAD),
        'sine_rms_deg': math.degrees(float(np.sqrt(np.mean((theta[second] - goal[second]) ** 2)))),
        'hold_pw_quadriceps_us': 1e6 * mean_pw('quadriceps', STEP_S - PW_AVERAGE_S, STEP_S),
        'sine_pw_quadriceps_us': 1e6 * mean_pw('quadriceps', STEP_S + SINE_PERIOD_S, end_s),
        'sine_pw_hamstrings_us': 1e6 * mean_pw('hamstrings', STEP_S + SINE_PERIOD_S, end_s),
        'longest_joint_state_gap_ms': 1e3 * float(np.diff(arrivals).max()),
    }
    print(f'\nMEASURED knee {length}: '
          + ', '.join(f'{k} {v:.4g}' for k, v in metrics.items()))
    return metrics


@pytest.fixture
def loop_env(tmp_path, stall_watcher):
    # The earlier tests' recordings are garbage by now: collect them before the
    # loop runs, not in a pause of this process (the probe and the rig) during it.
    gc.collect()
    with ProcessGroup(tmp_path) as procs, Probe('joint_loop_probe') as probe:
        yield procs, probe, tmp_path, stall_watcher


@pytest.mark.parametrize('length', VARIANTS)
def test_a_35_deg_step_settles_within_2_deg_in_2_s_and_a_0_2_hz_sine_tracks_within_3_deg_rms(
        loop_env, length, realtime_claim):
    def report(m):
        realtime_claim(f'knee loop ({length}): 35 deg step settles', f'{m["settling_s"]:.3f} s',
                       f'< {MAX_SETTLING_S} s')
        realtime_claim(f'knee loop ({length}): 0.2 Hz sine RMS error',
                       f'{m["sine_rms_deg"]:.2f} deg', f'<= {math.degrees(MAX_SINE_RMS_RAD):.1f} deg')

    def check(m):
        if not m['settling_s'] < MAX_SETTLING_S:
            return f'settling {m["settling_s"]:.3f} s'
        if not m['overshoot_deg'] < math.degrees(MAX_OVERSHOOT_RAD):
            return f'overshoot {m["overshoot_deg"]:.2f} deg'
        if not m['sine_rms_deg'] <= math.degrees(MAX_SINE_RMS_RAD):
            return f'sine RMS {m["sine_rms_deg"]:.2f} deg'
        return None
    procs, probe, tmp, watcher = loop_env
    repeat_only_on_external_stall(lambda: run_profile(procs, probe, tmp, length), check, watcher,
                                  report=report)
