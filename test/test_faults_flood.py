"""Fault case 2: the simulator flooded with pulse widths (20 kHz for 10 s).

What must hold while a separate process publishes ``pulse_width`` as fast as
it can, up to 20 kHz, for 10 s: the simulator keeps its step rate within 5 %
(simulated seconds per wall-clock second, from the ``wrench`` stamps), its
memory stays flat (VmRSS growth < 10 MB, from /proc/<pid>/status), and every
output is finite. The rate the flooder really reached is measured and
reported: one Python publisher may not reach 20 kHz on a small machine.
The step rate is measured from outside: simulated time gained (stamps)
over wall-clock time passed (arrivals here), taking the smallest delivery
delay at each end of the flood so that this busy process's own lag does
not count.
"""
from __future__ import annotations

import itertools
import os
import sys
import time

import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped

from ros_helpers import Probe, ProcessGroup, node_command
from hill_muscle_ros.timebase import NS_PER_S

# alone: the flooder and the simulator take both cores; beside another ROS
# module under xdist the simulator fell to 0.915 simulated s per wall s
# (a fresh clone's `make test` on four workers), against the 5 % it is held to.
pytestmark = [pytest.mark.faults, pytest.mark.ros, pytest.mark.realtime]

_RUNS = itertools.count()
FLOOD_RATE_HZ = 20_000.0
FLOOD_S = 10.0
MAX_RATE_ERROR = 0.05
MAX_RSS_GROWTH_KB = 10 * 1024
#: [s] the simulator runs before the first RSS reading (imports and DDS
#: discovery done, queues at their size).
WARM_UP_S = 2.0
#: [s] at each end of the flood, where the smallest delivery delay is taken.
LAG_WINDOW_S = 0.5
#: [s] deadline for the flooder to start, publish and report.
FLOOD_DEADLINE_S = FLOOD_S + 60.0

#: The flooder: publishes valid pulse widths (0 to PW_max, so the muscle
#: really moves) paced at the given rate, then prints how many it sent.
FLOODER = r'''
import sys, time
import rclpy
from std_msgs.msg import Float64
from hill_muscle_ros.qos import RELIABLE_QOS
topic, rate_hz, duration_s = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
rclpy.init()
node = rclpy.create_node('flooder')
pub = node.create_publisher(Float64, topic, RELIABLE_QOS)
deadline = time.monotonic() + 30.0
while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.01)
msg = Float64()
sent = 0
start = time.monotonic()
end = start + duration_s
period = 1.0 / rate_hz
while True:
    now = time.monotonic()
    if now >= end:
        break
    due = int((now - start) / period) + 1
    while sent < due:
        msg.data = 5e-4 * ((sent % 100) / 100.0)
        pub.publish(msg)
        sent += 1
print(f'FLOODED {sent} {time.monotonic() - start:.6f}', flush=True)
node.destroy_node()
rclpy.shutdown()
'''


def rss_kb(pid: int) -> int:
    """[kB] resident set size of a process, from /proc/<pid>/status."""
    for line in open(f'/proc/{pid}/status', encoding='ascii'):
        if line.startswith('VmRSS:'):
            return int(line.split()[1])
    raise RuntimeError(f'no VmRSS in /proc/{pid}/status')


def stamp_s(msg: WrenchStamped) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec / NS_PER_S


def test_pulse_width_flood_keeps_step_rate_memory_and_outputs(tmp_path, realtime_claim):
    ns = f'/flood_{os.getpid()}_{next(_RUNS)}'
    with ProcessGroup(tmp_path) as procs, Probe('flood_probe') as probe:
        sim = procs.start('simulator', node_command('simulator', ns=ns))
        wrench = probe.record(f'{ns}/wrench', WrenchStamped)
        probe.wait_for_messages(wrench, procs=[sim])
        t_warm = stamp_s(wrench.messages[-1]) + WARM_UP_S
        probe.spin_until(lambda: stamp_s(wrench.messages[-1]) >= t_warm, 'warm-up',
                         procs=[sim])
        rss_before = rss_kb(sim.popen.pid)
        flooder = procs.start('flooder', [sys.executable, '-c', FLOODER, f'{ns}/pulse_width',
                                          str(FLOOD_RATE_HZ), str(FLOOD_S)])
        probe.spin_until(lambda: 'FLOODED' in flooder.output() or flooder.returncode is not None
                         and 'FLOODED' in flooder.output(), 'the flood to end',
                         timeout_s=FLOOD_DEADLINE_S, procs=[sim, flooder])
        rss_after = rss_kb(sim.popen.pid)
        sent, elapsed = flooder.output().split('FLOODED ')[1].split()[:2]
        sent, elapsed = int(sent), float(elapsed)
        assert sim.returncode is None
        # The flood window in this process's wall clock and the simulator's stamps.
        stamps = np.array([stamp_s(m) for m in wrench.messages])
        arrivals = np.array(wrench.times_s)
        forces = np.array([m.wrench.force.x for m in wrench.messages])
    flood_end = arrivals[-1]
    in_flood = arrivals >= flood_end - elapsed
    t_sim = stamps[in_flood]
    t_wall = arrivals[in_flood]
    # Delivery delay varies (this process is busy too): compare the smallest
    # delay at the start of the flood with the smallest at its end, which are
    # both close to the bare transport time.
    lag = t_wall - t_sim
    head = t_wall < t_wall[0] + LAG_WINDOW_S
    tail = t_wall > t_wall[-1] - LAG_WINDOW_S
    span = t_wall[tail][np.argmin(lag[tail])] - t_wall[head][np.argmin(lag[head])]
    rate_ratio = 1.0 - (lag[tail].min() - lag[head].min()) / span
    achieved_hz = sent / elapsed
    growth_kb = rss_after - rss_before
    print(f'\nMEASURED flood: {sent} messages in {elapsed:.2f} s = {achieved_hz:.0f} Hz '
          f'(asked {FLOOD_RATE_HZ:.0f} Hz); simulated/wall time {rate_ratio:.4f}; '
          f'RSS {rss_before} kB -> {rss_after} kB ({growth_kb:+d} kB); '
          f'{in_flood.sum()} wrenches received during the flood; '
          f'force range {forces[in_flood].min():.3f}..{forces[in_flood].max():.3f} N')
    realtime_claim(f'1 kHz stepping under a {FLOOD_RATE_HZ / 1e3:g} kHz pulse_width flood '
                   '(simulated/wall time)', f'{rate_ratio:.4f}', f'1 +- {MAX_RATE_ERROR}')
    assert np.all(np.isfinite(forces))
    assert abs(rate_ratio - 1.0) <= MAX_RATE_ERROR
    assert growth_kb < MAX_RSS_GROWTH_KB
