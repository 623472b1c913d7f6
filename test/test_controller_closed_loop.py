"""The force controller closing the loop around the simulator over real DDS.

Three processes: the simulator (1 kHz), the force controller (100 Hz), and
this test, which plays the user (``force_target``) and the length rig
(``length_command``). Every time below is simulated time, read from the
``wrench`` stamps, never from when a message happened to arrive here.

- Step: ``force_target`` 0 -> 20 N at ``dl_mt`` = 0. The step instant t0 is
  the stamp of the last wrench received before the target was published (the
  simulator may already be a step or two further: the measured times are then
  slightly long, never short). Settling time: from t0 to the last sample
  outside 20 N +- 2 %. Overshoot: ``max(F) / 20 N - 1``.
- Stretch: 15 N held, then a ramp of 10 mm at 10 mm/s. The rig is a
  programmed one, as a dynamometer is: for each wrench it receives it sends
  the set point :data:`RIG_LOOKAHEAD_S` ahead on ``length_command_stamped``
  (stamped with the simulated time it is for), so the ramp follows simulated
  time. The simulator and the controller both read it.
  "Stays within 1 N after it settles" is checked strictly: within 1 N over
  the last :data:`PRE_RAMP_WINDOW_S` before the ramp (the hold has settled),
  and within 1 N at every sample from :data:`SETTLE_WINDOW_S` after the
  ramp's onset on (one 100 Hz control period and a DDS hop are needed to see
  the onset at all), through the ramp, its end and the hold after it. The
  controller knows the imposed length: it subscribes the same
  ``length_command`` as the simulator (its default ``model`` feedforward).

Both the ``initial`` and the ``instantaneous`` model variants are run.

On a shared 2-core machine a process can be descheduled for 0.1-0.3 s. A
failed run is repeated only if the stall watcher (``stall_watch``), a
process of its own, measured the machine leaving it unscheduled during that
run; the stall is printed. A failed run without one fails at once, so a
stall of the nodes themselves is a failure. The longest gap in the
simulator's stamps and the controller's output is printed with the
measurements (``pytest -s``).
"""
from __future__ import annotations

import gc
import itertools
import os

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped, WrenchStamped
from rclpy.time import Time
from std_msgs.msg import Float64

from ros_helpers import Probe, ProcessGroup, node_command
from hill_muscle_ros.timebase import NS_PER_S
from stall_watch import repeat_only_on_external_stall

pytestmark = [pytest.mark.ros, pytest.mark.realtime]

VARIANTS = ('initial', 'instantaneous')
_RUNS = itertools.count()

STEP_TARGET_N = 20.0
#: Settling band of the step: +-2 % of the target.
SETTLE_BAND = 0.02
MAX_SETTLING_S = 1.5
MAX_OVERSHOOT = 0.10
#: [s] of simulated time watched after the step.
STEP_WATCH_S = 3.0

HOLD_TARGET_N = 15.0
HOLD_TOL_N = 1.0
#: [s] holding time before the ramp starts, so the step response is over.
HOLD_BEFORE_RAMP_S = 1.5
RAMP_M_PER_S = 0.010
RAMP_TO_M = 0.010
#: [s] after the ramp onset: the error in this first window is the onset peak.
SETTLE_WINDOW_S = 0.1
#: [s] before the ramp over which the settled hold is checked.
PRE_RAMP_WINDOW_S = 0.5
#: [s] after the ramp's end from which the hold must be back within 1 N
#: (less than the step's 1.5 s settling bound).
RECOVERY_S = 1.0
#: [s] of simulated time watched after the ramp's end.
WATCH_AFTER_RAMP_S = 1.5
#: [s] window over which the steady pulse width is averaged.
PW_AVERAGE_S = 0.5
#: [s] how far ahead the rig sends its set points, as a programmed
#: dynamometer knows its program. The rig runs in this test process, which
#: can pause for ~0.2 s without waiting for a CPU (a fresh-clone run: wrench
#: and pulse-width arrivals here both stopped 0.19 s, no process waited 50 ms
#: for a CPU, and with 0.05 s ahead the simulator ran out of knots mid-ramp:
#: 11 N off). Half a second rides through such a pause.
RIG_LOOKAHEAD_S = 0.5


def unique_namespace() -> str:
    """A namespace of this test alone: the loop must hear only itself, even
    from other tests of the same run (conftest's domain is per run)."""
    return f'/cl_{os.getpid()}_{next(_RUNS)}'


def stamp_s(msg: WrenchStamped) -> float:
    """[s] header stamp of a wrench."""
    return msg.header.stamp.sec + msg.header.stamp.nanosec / NS_PER_S


class Loop:
    """Simulator + controller processes, and the probe's view of them."""

    def __init__(self, procs: ProcessGroup, probe: Probe, length: str,
                 sim_params: dict | None = None, ctrl_params: dict | None = None) -> None:
        self.probe = probe
        ns = unique_namespace()
        self.sim = procs.start('simulator', node_command(
            'simulator', ns=ns, params={'length': length, **(sim_params or {})}))
        self.ctrl = procs.start('controller', node_command(
            'force_controller', ns=ns, params=ctrl_params or {}))
        self.procs = [self.sim, self.ctrl]
        self.wrench = probe.record(f'{ns}/wrench', WrenchStamped)
        self.pulse_width = probe.record(f'{ns}/pulse_width', Float64)
        self.target_pub = probe.publisher(f'{ns}/force_target', Float64)
        self.length_pub = probe.publisher(f'{ns}/length_command_stamped', PointStamped)
        # Ready: both nodes publish, and the controller and simulator listen to us.
        probe.wait_for_messages(self.wrench, procs=self.procs)
        probe.wait_for_messages(self.pulse_width, procs=self.procs)
        probe.spin_until(lambda: (self.target_pub.get_subscription_count() > 0
                                  and self.length_pub.get_subscription_count() > 1),
                         'controller and simulator subscribed', procs=self.procs)

    def now_s(self) -> float:
        """[s] the latest simulated time seen here."""
        return stamp_s(self.wrench.messages[-1])

    def run_until(self, t_s: float) -> None:
        """Spin until a wrench stamped at or after ``t_s`` arrives."""
        self.probe.spin_until(lambda: self.now_s() >= t_s, f'simulated time {t_s:.3f} s',
                              procs=self.procs)

    def force_since(self, mark: int) -> tuple[np.ndarray, np.ndarray]:
        """Stamps [s] and forces [N] of the wrenches since ``mark``."""
        msgs = self.wrench.since(mark)
        return (np.array([stamp_s(m) for m in msgs]),
                np.array([m.wrench.force.x for m in msgs]))

    def stall_s(self, t_from_s: float, t_to_s: float) -> float:
        """[s] longest gap, while the simulator was in [t_from, t_to], between
        two wrench stamps (a simulator stall) or two pulse-width arrivals here
        (a controller stall, or this process's own)."""
        stamps = np.array([stamp_s(m) for m in self.wrench.messages])
        arrivals = np.array(self.wrench.times_s)
        sel = (stamps >= t_from_s) & (stamps <= t_to_s)
        sim_gap = np.diff(stamps[sel]).max()
        lo, hi = arrivals[sel][0], arrivals[sel][-1]
        pw_t = np.array(self.pulse_width.times_s)
        pw_t = pw_t[(pw_t >= lo) & (pw_t <= hi)]
        return float(max(sim_gap, np.diff(np.concatenate([[lo], pw_t, [hi]])).max()))

    def stop(self) -> None:
        for proc in self.procs:
            proc.stop()

    def timing(self) -> str:
        """How regularly the loop ran: gaps between wrench stamps (the
        simulator's ticks) and between pulse widths (the controller's ticks),
        as seen here. On a loaded machine these, not the gains, decide."""
        stamps = np.diff([stamp_s(m) for m in self.wrench.messages])
        pw = np.diff(self.pulse_width.times_s)
        return (f'simulator tick gaps p99 {np.percentile(stamps, 99) * 1e3:.0f} ms, max '
                f'{stamps.max() * 1e3:.0f} ms; controller output gaps p99 '
                f'{np.percentile(pw, 99) * 1e3:.0f} ms, max {pw.max() * 1e3:.0f} ms')

    def mean_pulse_width(self, t_from_s: float, t_to_s: float) -> float:
        """[s] mean pulse width received while the simulator was in [t_from, t_to].

        Pulse widths carry no stamp: they are matched to simulated time by
        arrival order against the wrenches (good to a few milliseconds).
        """
        stamps = np.array([stamp_s(m) for m in self.wrench.messages])
        arrivals = np.array(self.wrench.times_s)
        lo = arrivals[np.searchsorted(stamps, t_from_s)]
        hi = arrivals[min(np.searchsorted(stamps, t_to_s), len(arrivals) - 1)]
        pw_t = np.array(self.pulse_width.times_s)
        pw = np.array([m.data for m in self.pulse_width.messages])
        return float(pw[(pw_t >= lo) & (pw_t <= hi)].mean())


def step_metrics(t: np.ndarray, f: np.ndarray, t0: float, target: float) -> dict:
    """Settling time [s] (into +-2 %), overshoot [-], and the final error [N]."""
    outside = np.flatnonzero(np.abs(f - target) > SETTLE_BAND * target)
    settling = (t[outside[-1]] - t0) if outside.size else 0.0
    return {'settling_s': float(settling), 'overshoot': float(f.max() / target - 1.0),
            'final_error_n': float(f[-1] - target)}


def run_step(procs, probe, length: str) -> tuple[dict, Loop]:
    loop = Loop(procs, probe, length)
    t0 = loop.now_s()
    mark = loop.wrench.mark()
    loop.target_pub.publish(Float64(data=STEP_TARGET_N))
    loop.run_until(t0 + STEP_WATCH_S)
    t, f = loop.force_since(mark)
    metrics = step_metrics(t, f, t0, STEP_TARGET_N)
    metrics['pw_steady_s'] = loop.mean_pulse_width(t0 + STEP_WATCH_S - PW_AVERAGE_S,
                                                    t0 + STEP_WATCH_S)
    metrics['stall_s'] = loop.stall_s(t0, t0 + STEP_WATCH_S)
    metrics['timing'] = loop.timing()
    loop.stop()
    print(f'\nMEASURED step {length}: ' + ', '.join(f'{k} {v:.4g}' if isinstance(v, float)
                                                  else v for k, v in metrics.items()))
    return metrics, loop


def ramp_dl_m(t_s: float, t_ramp_s: float) -> float:
    """[m] the rig's length command at simulated time ``t_s``."""
    return float(np.clip((t_s - t_ramp_s) * RAMP_M_PER_S, 0.0, RAMP_TO_M))


def run_stretch(procs, probe, length: str) -> dict:
    loop = Loop(procs, probe, length)
    loop.target_pub.publish(Float64(data=HOLD_TARGET_N))
    t_ramp = loop.now_s() + HOLD_BEFORE_RAMP_S
    ramp_end = t_ramp + RAMP_TO_M / RAMP_M_PER_S

    def rig(msg: WrenchStamped) -> None:
        t_s = stamp_s(msg) + RIG_LOOKAHEAD_S
        point = PointStamped()
        point.header.stamp = Time(nanoseconds=round(t_s * NS_PER_S)).to_msg()
        point.header.frame_id = msg.header.frame_id
        point.point.x = ramp_dl_m(t_s, t_ramp)
        loop.length_pub.publish(point)

    loop.wrench.add_listener(rig)
    pre_mark = loop.wrench.mark()
    loop.run_until(t_ramp)
    mark = loop.wrench.mark()
    loop.run_until(ramp_end + WATCH_AFTER_RAMP_S)
    t, f = loop.force_since(mark)
    err = f - HOLD_TARGET_N
    onset = (t >= t_ramp) & (t < t_ramp + SETTLE_WINDOW_S)
    settled = t >= t_ramp + SETTLE_WINDOW_S
    during = settled & (t < ramp_end)
    t_pre, f_pre = loop.force_since(pre_mark)
    pre = (t_pre >= t_ramp - PRE_RAMP_WINDOW_S) & (t_pre < t_ramp)
    metrics = {
        'max_abs_error_before_ramp_n': float(np.abs(f_pre[pre] - HOLD_TARGET_N).max()),
        'max_abs_error_after_recovery_n': float(np.abs(err[t >= ramp_end + RECOVERY_S]).max()),
        'onset_peak_error_n': float(err[onset][np.argmax(np.abs(err[onset]))]),
        'max_abs_error_after_settling_n': float(np.abs(err[settled]).max()),
        'max_abs_error_during_ramp_n': float(np.abs(err[during]).max()),
        'pw_before_s': loop.mean_pulse_width(t_ramp - PW_AVERAGE_S, t_ramp),
        'pw_after_s': loop.mean_pulse_width(ramp_end + WATCH_AFTER_RAMP_S - PW_AVERAGE_S,
                                            ramp_end + WATCH_AFTER_RAMP_S),
    }
    metrics["stall_s"] = loop.stall_s(t_ramp - PRE_RAMP_WINDOW_S, ramp_end + WATCH_AFTER_RAMP_S)
    metrics['timing'] = loop.timing()
    loop.stop()
    print(f'\nMEASURED stretch {length}: '
          + ', '.join(f'{k} {v:.4g}' if isinstance(v, float) else v for k, v in metrics.items()))
    return metrics


@pytest.fixture
def loop_env(tmp_path, stall_watcher):
    # The earlier tests' recordings are garbage by now: collect them before the
    # loop runs, not in a pause of this process (the probe and the rig) during it.
    gc.collect()
    with ProcessGroup(tmp_path) as procs, Probe('closed_loop_probe') as probe:
        yield procs, probe, stall_watcher


@pytest.mark.parametrize('length', VARIANTS)
def test_step_to_20N_settles_within_2_percent_in_under_1_5_s_with_under_10_percent_overshoot(
        loop_env, length, realtime_claim):
    def report(m):
        realtime_claim(f'force loop ({length}): 20 N step settles', f'{m["settling_s"]:.3f} s',
                       f'< {MAX_SETTLING_S} s')
        realtime_claim(f'force loop ({length}): 20 N step overshoot', f'{m["overshoot"]:.3f}',
                       f'< {MAX_OVERSHOOT}')

    def check(m):
        if not m['settling_s'] < MAX_SETTLING_S:
            return f'settling {m["settling_s"]:.3f} s'
        if not m['overshoot'] < MAX_OVERSHOOT:
            return f'overshoot {m["overshoot"]:.3f}'
        return None
    procs, probe, watcher = loop_env
    repeat_only_on_external_stall(lambda: run_step(procs, probe, length)[0], check, watcher,
                                  report=report)


@pytest.mark.parametrize('length', VARIANTS)
def test_15N_is_held_within_1N_through_a_stretch_once_settled(loop_env, length, realtime_claim):
    def report(m):
        worst = max(m['max_abs_error_before_ramp_n'], m['max_abs_error_after_settling_n'])
        realtime_claim(f'force loop ({length}): 15 N held through a stretch', f'{worst:.3f} N',
                       f'<= {HOLD_TOL_N} N')

    def check(m):
        for key in ('max_abs_error_before_ramp_n', 'max_abs_error_after_settling_n'):
            if not m[key] <= HOLD_TOL_N:
                return f'{key} {m[key]:.3f} N'
        return None
    procs, probe, watcher = loop_env
    repeat_only_on_external_stall(lambda: run_stretch(procs, probe, length), check, watcher,
                                  report=report)
