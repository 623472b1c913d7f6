"""ROS benchmarks (the performance targets): the simulator node at 1 kHz, and DDS latency.

Runs the package's ``simulator`` node and a bare rclpy echo node as separate
processes and observes them from this process through DDS:

- the node at ``rate_hz`` 1000 for ``--seconds`` (30 by default): achieved
  step rate, the period between its ``wrench`` messages (one per step: a
  late tick's steps arrive as a burst) as seen by a subscriber (p50, p99,
  max), late arrivals, messages received and gaps in their stamps, CPU % of
  one core (from /proc), and the drift between simulated time (the wrench
  stamps) and the clock;
- latency from a ``pulse_width`` publish to the first ``force`` message that
  reflects it (R toggled between 0, where the force is exactly 0, and 0.5),
  against a bare rclpy echo node (``ping`` -> ``pong``) measured the same way.

Latency ends when the reply reaches the observer's DDS reader: the
``received_timestamp`` that rmw stamps on every message (system clock, like
``time.time_ns()`` at the publish). The observer's own executor is not part of
it: while it processes the 1 kHz ``force`` stream one message per wait, a
reply can sit behind earlier ones for milliseconds, and the echo path, which
has no stream, never waits like that. The time the observer's callback saw
the reply is reported too, and for the simulator the ``source_timestamp`` of
the reply splits the path into "until the simulator published it" and DDS.

The simulator runs under the executor named by ``HILL_MUSCLE_EXECUTOR``
(``--executor``; the package's default is ``events``).

Usage (also called by run_all.py)::

    .venv/bin/python benchmarks/bench_node.py [--seconds 30] [--executor events]
"""
from __future__ import annotations

import argparse
import itertools
import os
import random
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from hill_muscle_ros.supervisor import (GraphProbe, ProcessGroup, node_command,  # noqa: E402
                                        ros_environment)
from hill_muscle_ros.timebase import NS_PER_S  # noqa: E402

#: DDS domain for the benchmark: above the range the tests draw from (1..100).
DOMAIN_RANGE = (101, 200)
RATE_HZ = 1000.0
STEP_NS = round(NS_PER_S / RATE_HZ)
STARTUP_TIMEOUT_S = 60.0
EDGE_TIMEOUT_S = 2.0
LATENCY_EDGES = 200
#: [s] random pause between latency probes, so they fall at every tick phase.
PROBE_PAUSE_S = (0.005, 0.02)
#: A pulse width that gives R = 0.5 with the default PW_max of 0.5 ms.
PULSE_WIDTH_S = 0.00025
#: A message arrives late if it comes this many periods after the previous one:
#: a late tick (its steps then follow as a burst), or a delay in DDS or in this
#: observer.
LATE_FACTOR = 2.0
QUEUE_DEPTH = 1000
#: [s] longest one spin of the observer waits while it pauses between probes.
SPIN_SLICE_S = 0.001
CONTROL_PERIOD_S = 0.01
_RUNS = itertools.count()

ECHO_NODE = '''
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64

class Echo(Node):
    def __init__(self):
        super().__init__('echo')
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.create_publisher(Float64, 'pong', qos)
        self.create_subscription(Float64, 'ping', self.pub.publish, qos)

rclpy.init()
node = Echo()
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
finally:
    node.destroy_node()
    rclpy.try_shutdown()
'''


def set_ros_env() -> dict[str, str]:
    """Isolate the benchmark's DDS traffic on this host; subprocesses inherit it."""
    if 'ROS_DOMAIN_ID' not in os.environ or int(os.environ['ROS_DOMAIN_ID']) < DOMAIN_RANGE[0]:
        os.environ['ROS_DOMAIN_ID'] = str(random.Random(os.getpid()).randint(*DOMAIN_RANGE))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    return ros_environment()


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process [s], from /proc/<pid>/stat."""
    with open(f'/proc/{pid}/stat', encoding='ascii') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    # Fields 14 and 15 of stat(5); the split drops the first two.
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def percentiles(values, *qs):
    return [float(np.percentile(values, q)) for q in qs]


@dataclass
class NodeResult:
    seconds: float
    steps: int
    rate_hz: float
    period_ms: tuple[float, float, float]   # p50, p99, max between messages
    #: messages that arrived more than LATE_FACTOR periods after the previous one
    late_arrivals: int
    #: gaps in the received wrench stamps (more than one step between two
    #: messages): each is one or more messages this observer missed, since
    #: the simulator publishes every step at 1 kHz
    stamp_gaps: int
    #: wrench messages received (one per step)
    messages: int
    cpu_percent: float
    drift_steps: float
    lag_ms: tuple[float, float, float]      # stamp -> receipt, p50, p99, max
    pubs_subs: str


@dataclass
class LatencyResult:
    """Latency percentiles [ms] over ``samples`` probes, to the observer's DDS reader."""

    samples: int
    p50_ms: float
    p99_ms: float
    max_ms: float
    #: p50, p99 [ms] to the observer's callback (includes its own executor).
    callback_ms: tuple[float, float]
    #: p50, p99 [ms] to the reply's source_timestamp (the replying node published it).
    published_ms: tuple[float, float]

    @classmethod
    def of(cls, probes: list[tuple[int, int, int, int]]) -> 'LatencyResult':
        """From (publish, source, received, callback) times [ns] of each probe."""
        t = np.array(probes, dtype=np.int64)
        received = (t[:, 2] - t[:, 0]) / 1e6
        return cls(len(t), *percentiles(received, 50, 99), float(received.max()),
                   tuple(percentiles((t[:, 3] - t[:, 0]) / 1e6, 50, 99)),
                   tuple(percentiles((t[:, 1] - t[:, 0]) / 1e6, 50, 99)))


def reply_times(msg_info: dict, callback_ns: int) -> tuple[int, int, int]:
    """(source, received, callback) times [ns] of a reply, from its rmw MessageInfo."""
    return msg_info['source_timestamp'], msg_info['received_timestamp'], callback_ns


def run(seconds: float, log_dir: Path, executor: str | None = None
        ) -> tuple[NodeResult, LatencyResult, LatencyResult]:
    """Run items 4 and 5; ``executor`` sets ``HILL_MUSCLE_EXECUTOR`` for the simulator."""
    env = set_ros_env()
    if executor is not None:
        env['HILL_MUSCLE_EXECUTOR'] = executor
    from geometry_msgs.msg import WrenchStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64

    ns = f'/bench_{os.getpid()}_{next(_RUNS)}'   # a namespace of its own per run
    log_dir.mkdir(parents=True, exist_ok=True)
    with ProcessGroup(log_dir, env) as procs, \
            GraphProbe('bench_observer', namespace=ns, executor='single') as probe:
        # single: the MessageInfo callbacks below (GraphProbe.PROBE_EXECUTORS)
        sim = procs.start('simulator', node_command(
            'simulator', ns=ns, params={'rate_hz': RATE_HZ, 'input_timeout_s': 0.0}))
        echo = procs.start('echo', [sys.executable, '-c', ECHO_NODE,
                                    '--ros-args', '-r', f'__ns:={ns}'])
        node = probe.node
        qos = QoSProfile(depth=QUEUE_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        recv_ns, stamp_ns, forces, pongs = [], [], [], []
        # Only the topics a phase needs are subscribed, so that this Python
        # observer is not what falls behind.
        wrench_sub = node.create_subscription(
            WrenchStamped, 'wrench',
            lambda m: (recv_ns.append(time.time_ns()),
                       stamp_ns.append(m.header.stamp.sec * NS_PER_S
                                       + m.header.stamp.nanosec)), qos)
        node.create_subscription(
            Float64, 'pong',
            lambda m, info: pongs.append((m.data, reply_times(info, time.time_ns()))), qos)
        pub_r = node.create_publisher(Float64, 'recruitment', qos)
        pub_pw = node.create_publisher(Float64, 'pulse_width', qos)
        pub_ping = node.create_publisher(Float64, 'ping', qos)

        def spin_until(cond, timeout_s, what):
            probe.spin_until(cond, what, timeout_s, [sim, echo])

        def spin_for(duration_s):
            """Keep taking messages for ``duration_s``: the pause between probes.

            A sleep here would leave the 1 kHz ``force`` stream queued, and the
            observer would work through that backlog exactly while a probe is
            timed (the echo path has no stream, so only the simulator's probes
            paid for it, about 2 ms at the median in the first BENCHMARKS.md).
            """
            deadline = time.monotonic() + duration_s
            while time.monotonic() < deadline:
                probe.spin_once(SPIN_SLICE_S)

        spin_until(lambda: len(recv_ns) > 0 and pub_r.get_subscription_count() > 0
                   and pub_ping.get_subscription_count() > 0, STARTUP_TIMEOUT_S,
                   'the simulator and echo nodes')

        # -- the node at 1 kHz, with a controller-like recruitment stream -----
        pub_r.publish(Float64(data=0.5))
        del recv_ns[:], stamp_ns[:]
        cpu0 = cpu_seconds(sim.pid)
        t0 = time.monotonic()
        next_control = t0
        while time.monotonic() - t0 < seconds:
            if time.monotonic() >= next_control:
                pub_r.publish(Float64(data=0.5))
                next_control += CONTROL_PERIOD_S
            probe.spin_once(0.001)
        cpu1 = cpu_seconds(sim.pid)
        wall = time.monotonic() - t0
        recv = np.array(recv_ns, dtype=np.int64)
        stamp = np.array(stamp_ns, dtype=np.int64)
        periods_ms = np.diff(recv) / 1e6
        step_gaps = np.diff(stamp) // STEP_NS
        lag = (recv - stamp) / 1e6
        steps = int((stamp[-1] - stamp[0]) // STEP_NS)
        wall_span_s = (recv[-1] - recv[0]) / NS_PER_S
        # Drift: how far the simulated time fell behind the clock over the run
        # (the change of stamp -> receipt lag; its constant part is DDS latency).
        n_edge = max(1, len(lag) // 20)
        drift_ms = float(np.median(lag[-n_edge:]) - np.median(lag[:n_edge]))
        node_result = NodeResult(
            seconds=wall, steps=steps, rate_hz=steps / wall_span_s,
            period_ms=tuple(percentiles(periods_ms, 50, 99)) + (float(periods_ms.max()),),
            late_arrivals=int(np.sum(periods_ms > LATE_FACTOR * 1e3 / RATE_HZ)),
            stamp_gaps=int(np.sum(step_gaps > 1)), messages=len(recv),
            cpu_percent=100.0 * (cpu1 - cpu0) / wall,
            drift_steps=drift_ms * RATE_HZ / 1e3,
            lag_ms=tuple(percentiles(lag, 50, 99)) + (float(lag.max()),),
            pubs_subs=('simulator: 6 publishers (force, ce_length, wrench, recruitment_state, '
                       'fitness, /diagnostics), '
                       '4 subscriptions '
                       '(pulse_width, recruitment, length_command, length_command_stamped), '
                       'the reset and parameter services; one observer subscribed to wrench '
                       'and publishing recruitment at 100 Hz'))

        # -- latency pulse_width -> force ------------------------------------
        node.destroy_subscription(wrench_sub)
        force_sub = node.create_subscription(
            Float64, 'force',
            lambda m, info: forces.append((m.data, reply_times(info, time.time_ns()))), qos)
        spin_until(lambda: len(forces) > 0, STARTUP_TIMEOUT_S, 'force messages')
        rng = random.Random(1)
        probes = []
        active = False
        for _ in range(LATENCY_EDGES):
            spin_for(rng.uniform(*PROBE_PAUSE_S))
            active = not active
            mark = len(forces)
            t_pub = time.time_ns()
            pub_pw.publish(Float64(data=PULSE_WIDTH_S if active else 0.0))

            def reflected():
                return any((f > 0.0) == active for f, _ in forces[mark:])
            spin_until(reflected, EDGE_TIMEOUT_S, 'force to reflect pulse_width')
            probes.append((t_pub, *next(t for f, t in forces[mark:] if (f > 0.0) == active)))
        sim_latency = LatencyResult.of(probes)
        node.destroy_subscription(force_sub)

        probes = []
        for i in range(LATENCY_EDGES):
            spin_for(rng.uniform(*PROBE_PAUSE_S))
            t_pub = time.time_ns()
            pub_ping.publish(Float64(data=float(i)))
            spin_until(lambda: pongs and pongs[-1][0] == float(i), EDGE_TIMEOUT_S, 'pong')
            probes.append((t_pub, *pongs[-1][1]))
        echo_latency = LatencyResult.of(probes)
    return node_result, sim_latency, echo_latency


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=30.0)
    parser.add_argument('--logs', type=Path, default=REPO / 'runs' / 'bench_node')
    parser.add_argument('--executor', default=None,
                        help='HILL_MUSCLE_EXECUTOR for the simulator (default: the package\'s)')
    args = parser.parse_args(argv)
    node, lat, echo = run(args.seconds, args.logs, args.executor)
    print(node)
    print('pulse_width -> force', lat)
    print('echo', echo)
    return 0


if __name__ == '__main__':
    sys.exit(main())
